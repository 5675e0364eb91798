"""Contact sheet of one garment: what a person looks at to judge a dataset folder at a glance.

Tiles: sketch, visual, mask, gx, gy, normal map, height map, friction map, and the tactile rectangles drawn on the
visual (train green, val yellow, test red). Real garments have gradients only under their touches, so the gradient
tiles show those touches in place; synthetic garments show their full-field ground truth.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from kiosk.contract.haptics import friction_map, height_from_gradients, normals_from_gradients
from trainer.data.touchclothing import Garment, friction_scale

SPLIT_COLOURS = {"train": (60, 200, 60), "val": (230, 200, 40), "test": (230, 60, 60)}  # RGB


def _frame_crop(g: Garment, a: np.ndarray) -> np.ndarray:
    (fw, fh), (ox, oy) = g.frame, g.offset
    return a[oy:oy + fh, ox:ox + fw]


def touch_mosaic(g: Garment) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gradients of every touch pasted at its rectangle (padded frame); the third array marks covered pixels."""
    p = g.padded_size
    gx = np.zeros((p, p), np.float32)
    gy = np.zeros((p, p), np.float32)
    covered = np.zeros((p, p), bool)
    for touches in g.touches.values():
        for t in touches:
            r = t.rect
            y0, x0 = max(r.y, 0), max(r.x, 0)
            y1, x1 = min(r.y + t.gx.shape[0], p), min(r.x + t.gx.shape[1], p)
            if y1 <= y0 or x1 <= x0:
                continue
            sl = (slice(y0 - r.y, y1 - r.y), slice(x0 - r.x, x1 - r.x))
            gx[y0:y1, x0:x1] = t.gx[sl]
            gy[y0:y1, x0:x1] = t.gy[sl]
            covered[y0:y1, x0:x1] = True
    return gx, gy, covered


def _signed_colour(a: np.ndarray, limit: float) -> np.ndarray:
    """Diverging colour map for signed slopes: blue negative, white zero, red positive."""
    t = np.clip(a / max(limit, 1e-6), -1.0, 1.0)
    rgb = np.empty(a.shape + (3,), np.float32)
    rgb[..., 0] = np.where(t > 0, 1.0, 1.0 + t)
    rgb[..., 1] = 1.0 - np.abs(t)
    rgb[..., 2] = np.where(t < 0, 1.0, 1.0 - t)
    return (rgb * 255).astype(np.uint8)


def _gray(a: np.ndarray) -> np.ndarray:
    return np.repeat(a[..., None], 3, axis=2)


def _label(tile: np.ndarray, text: str) -> np.ndarray:
    out = tile.copy()
    cv2.rectangle(out, (0, 0), (out.shape[1], 26), (0, 0, 0), -1)
    cv2.putText(out, text, (6, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def render_contact_sheet(g: Garment, *, tile_width: int = 480) -> np.ndarray:
    """The sheet as an RGB uint8 image (3 columns x 3 rows of tiles at `tile_width`)."""
    if g.full_tactile is not None:
        gx, gy, covered = g.full_tactile.gx, g.full_tactile.gy, g.mask
        pitch, source = g.full_tactile.pixel_pitch_mm, "full-field ground truth"
    else:
        gx, gy, covered = touch_mosaic(g)
        pitch, source = 0.3, "measured touches only"
    gx, gy, covered = (_frame_crop(g, a) for a in (gx, gy, covered))
    sketch, mask = _frame_crop(g, g.sketch), _frame_crop(g, g.mask)
    visual = _frame_crop(g, g.visual) if g.visual is not None else _gray(sketch)
    limit = float(np.quantile(np.abs(np.concatenate([gx[covered], gy[covered]])), 0.99)) if covered.any() else 1.0
    normals = normals_from_gradients(gx, gy)
    normal_rgb = np.clip((normals * np.array([1, 1, -1]) + np.array([1, 1, 0])) * np.array([127.5, 127.5, 255]),
                         0, 255).astype(np.uint8)
    normal_rgb[~covered] = 0
    height = height_from_gradients(gx, gy, pixel_pitch=pitch) if g.full_tactile is not None else None
    if height is not None:
        hv = height[mask] if mask.any() else height.ravel()
        lo, hi = np.quantile(hv, [0.01, 0.99])
        hmap = np.clip((height - lo) / max(hi - lo, 1e-9), 0, 1)
        height_rgb = cv2.applyColorMap((hmap * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1].copy()
        height_rgb[~mask] = 0
        height_label = f"height ({hi - lo:.2f} mm range, p1-p99)"
    else:
        height_rgb = np.zeros_like(visual)
        cv2.putText(height_rgb, "no full-field tactile data", (20, visual.shape[0] // 2),
                    cv2.FONT_HERSHEY_SIMPLEX, 1.0, (200, 200, 200), 2, cv2.LINE_AA)
        height_label = "height (needs full-field data)"
    scale = friction_scale(g) if g.touches.get("train") else None
    fmap = friction_map(gx, gy, scale) if scale is not None else np.zeros(gx.shape, np.uint8)
    rects = visual.copy()
    thickness = max(1, visual.shape[1] // 400)
    for split, touches in g.touches.items():
        for t in touches:
            x0, y0 = t.rect.x - g.offset[0], t.rect.y - g.offset[1]
            cv2.rectangle(rects, (x0, y0), (x0 + t.rect.w - 1, y0 + t.rect.h - 1), SPLIT_COLOURS[split], thickness)
    counts = g.touch_count()
    tiles = [
        (_gray(sketch), "sketch"),
        (visual, "visual"),
        (_gray(mask.astype(np.uint8) * 255), "mask"),
        (_signed_colour(gx, limit), f"gx ({source}, +-{limit:.2f})"),
        (_signed_colour(gy, limit), f"gy (+-{limit:.2f})"),
        (normal_rgb, "normal map"),
        (height_rgb, height_label),
        (_gray(fmap), f"friction map (scale {scale:.4f})" if scale else "friction map (no calibration)"),
        (rects, f"touches: train {counts['train']} / val {counts['val']} / test {counts['test']}"),
    ]
    h = int(round(visual.shape[0] * tile_width / visual.shape[1]))
    resized = [_label(cv2.resize(t, (tile_width, h), interpolation=cv2.INTER_AREA), text) for t, text in tiles]
    rows = [np.concatenate(resized[i:i + 3], axis=1) for i in range(0, 9, 3)]
    sheet = np.concatenate(rows, axis=0)
    title = np.zeros((36, sheet.shape[1], 3), np.uint8)
    cv2.putText(title, f"{g.name}", (8, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2, cv2.LINE_AA)
    return np.concatenate([title, sheet], axis=0)


def write_contact_sheet(g: Garment, out: Path, *, tile_width: int = 480) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet = render_contact_sheet(g, tile_width=tile_width)
    if not cv2.imwrite(str(out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {out} (is the extension an image format?)")
    return out
