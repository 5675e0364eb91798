"""Rasterise a garment layout into one height field (mm) and an albedo, then shade and photograph it.

One height field drives everything: the visual shading (normals from its slopes), and the tactile ground truth
(slopes = central differences of the same field at the pixel pitch). Prints change albedo only; seams, layers,
buttons and appliques change height.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trainer.data.synth_fabrics import FabricParams, band_noise, texture
from trainer.data.synth_realism import Realism, camera, fold_height, lamp, mottle, print_alpha
from trainer.data.synth_shapes import Layout

SHIFT = 4  # cv2 sub-pixel bits for polygon vertices
LIGHT = np.array([-0.45, -0.55, 0.70], dtype=np.float32)  # from the upper left (x right, y down, z to camera)
EXAGGERATION = 3.0  # slopes are scaled up for shading so mm-scale texture shows at 0.3 mm/px
EDGE_RAMP_PX = 4.0  # the cloth edge rises to full thickness over this many px inside the mask


@dataclass(frozen=True)
class Decor:
    """Decorations of one garment: applique flowers (count, petal/centre RGB 0..1) and a printed word."""

    flowers: int
    petal_rgb: tuple[float, float, float]
    centre_rgb: tuple[float, float, float]
    text: str
    print_rgb: tuple[float, float, float]
    stripes: bool
    stripe_rgb: tuple[float, float, float]
    button_rgb: tuple[float, float, float]
    thread_rgb: tuple[float, float, float]


@dataclass
class Rendered:
    """Frame-sized outputs: rgb uint8 (H, W, 3), mask bool, height_mm float32, gx/gy float32 slopes (0 outside).

    With a `Realism`: sketch_rgb, the clean construction image the sketch is drawn from (no print, folds, lamp or
    camera: what the paper's manual clean-up of the edge map keeps), and fold_mm, the low-frequency fold height
    that shades the photo but is not in the tactile truth.
    """

    rgb: np.ndarray
    mask: np.ndarray
    height_mm: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    sketch_rgb: np.ndarray | None = None
    fold_mm: np.ndarray | None = None


def _px(pts: list[tuple[float, float]]) -> np.ndarray:
    return np.round(np.asarray(pts, dtype=np.float64) * (1 << SHIFT)).astype(np.int32).reshape(-1, 1, 2)


def _fill(canvas: np.ndarray, polys: list, value: int = 255, aa: bool = True) -> None:
    """Union of filled polygons (one call each: a single fillPoly call would XOR overlaps)."""
    for p in polys:
        cv2.fillPoly(canvas, [_px(p)], value, cv2.LINE_AA if aa else cv2.LINE_8, SHIFT)


def _lines(canvas: np.ndarray, lines: list, thickness: int, closed: bool = False) -> None:
    if lines:
        cv2.polylines(canvas, [_px(p) for p in lines], closed, 255, thickness, cv2.LINE_AA, SHIFT)


def _dashes(canvas: np.ndarray, line: list[tuple[float, float]], on: float, off: float) -> None:
    """Dashed polyline (top-stitching): dashes `on` px long with `off` px gaps along the arc length."""
    pts = np.asarray(line, dtype=np.float64)
    seg = np.diff(pts, axis=0)
    lens = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(lens)])
    if cum[-1] <= 0:
        return
    starts = np.arange(0.0, cum[-1], on + off)

    def at(s: float) -> np.ndarray:
        i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(lens) - 1))
        t = (s - cum[i]) / max(lens[i], 1e-9)
        return pts[i] + seg[i] * t

    for s in starts:
        a, b = at(s), at(min(s + on, cum[-1]))
        cv2.line(canvas, tuple(np.round(a * 16).astype(int)), tuple(np.round(b * 16).astype(int)), 255, 1,
                 cv2.LINE_AA, SHIFT)


def _f(u8: np.ndarray) -> np.ndarray:
    return u8.astype(np.float32) * np.float32(1 / 255)


def _ridge(u8: np.ndarray, sigma: float) -> np.ndarray:
    """Rounded ridge profile from drawn lines, normalised so a line's crest is 1."""
    r = cv2.GaussianBlur(_f(u8), (0, 0), sigma)
    peak = float(r.max())
    return r / np.float32(peak) if peak > 0 else r


def _buttons(shape: tuple[int, int], buttons: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raised discs (mm): a 1 mm body with a rolled rim, dished centre and four holes; alpha, hole alpha."""
    h = np.zeros(shape, np.float32)
    alpha = np.zeros(shape, np.float32)
    holes = np.zeros(shape, np.float32)
    for bx, by, r in buttons:
        r = max(r, 3.0)
        x0, x1 = int(max(bx - r - 3, 0)), int(min(bx + r + 4, shape[1]))
        y0, y1 = int(max(by - r - 3, 0)), int(min(by + r + 4, shape[0]))
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
        d = np.hypot(xx - bx, yy - by) / r
        inside = np.clip((1.0 - d) * r / 1.5, 0, 1)  # ~1.5 px anti-aliased rim
        body = 0.8 + 0.25 * np.exp(-((d - 0.8) / 0.12) ** 2) - 0.15 * np.exp(-(d / 0.45) ** 2)
        hole = np.zeros_like(d)
        for ang in (45, 135, 225, 315):
            hx = bx + 0.28 * r * np.cos(np.deg2rad(ang))
            hy = by + 0.28 * r * np.sin(np.deg2rad(ang))
            hole = np.maximum(hole, np.clip((0.12 * r - np.hypot(xx - hx, yy - hy)) / 0.8 + 0.5, 0, 1))
        bh = inside * (body - 0.5 * hole)
        h[y0:y1, x0:x1] = np.maximum(h[y0:y1, x0:x1], bh)
        alpha[y0:y1, x0:x1] = np.maximum(alpha[y0:y1, x0:x1], inside)
        holes[y0:y1, x0:x1] = np.maximum(holes[y0:y1, x0:x1], hole * inside)
    return h, alpha, holes


def _flowers(shape: tuple[int, int], centres: list[tuple[float, float, float, float]]
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Applique flowers: petals as AA ellipses around a centre disc. Returns petal alpha, centre alpha, outlines."""
    petals = np.zeros(shape, np.uint8)
    centre = np.zeros(shape, np.uint8)
    outline = np.zeros(shape, np.uint8)
    for cx, cy, r, rot in centres:
        n = 5 + int(rot * 10) % 3
        for k in range(n):
            a = rot * 360 + k * 360.0 / n
            px = cx + 0.55 * r * np.cos(np.deg2rad(a))
            py = cy + 0.55 * r * np.sin(np.deg2rad(a))
            box = ((float(px), float(py)), (float(1.0 * r), float(0.55 * r)), float(a))
            cv2.ellipse(petals, box, 255, -1, cv2.LINE_AA)
            cv2.ellipse(outline, box, 255, 1, cv2.LINE_AA)
        cv2.circle(centre, (int(round(cx * 16)), int(round(cy * 16))), int(round(0.3 * r * 16)), 255, -1,
                   cv2.LINE_AA, SHIFT)
        cv2.circle(outline, (int(round(cx * 16)), int(round(cy * 16))), int(round(0.3 * r * 16)), 255, 1,
                   cv2.LINE_AA, SHIFT)
    return _f(petals), _f(centre), outline


def _print(shape: tuple[int, int], text: str, box: tuple[float, float, float, float]) -> np.ndarray:
    """Printed word (albedo only) filling the width of box; alpha float32."""
    canvas = np.zeros(shape, np.uint8)
    if not text:
        return _f(canvas)
    x0, y0, x1, y1 = box
    font = cv2.FONT_HERSHEY_DUPLEX
    (tw, th), _ = cv2.getTextSize(text, font, 1.0, 2)
    scale = min((x1 - x0) * 0.9 / tw, (y1 - y0) * 0.8 / th)
    thick = max(1, int(round(scale * 2.2)))
    (tw, th), _ = cv2.getTextSize(text, font, scale, thick)
    org = (int(round((x0 + x1 - tw) / 2)), int(round((y0 + y1 + th) / 2)))
    cv2.putText(canvas, text, org, font, scale, 255, thick, cv2.LINE_AA)
    return _f(canvas)


def _mix(img: np.ndarray, alpha: np.ndarray, rgb: tuple[float, float, float]) -> np.ndarray:
    a = alpha[..., None]
    return img * (1 - a) + np.asarray(rgb, np.float32) * a


def gradients(height_mm: np.ndarray, pitch_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Slopes (mm/mm) of a height field by central differences at the pixel pitch (one-sided at the border)."""
    gy, gx = np.gradient(height_mm.astype(np.float32), np.float32(pitch_mm))
    return gx.astype(np.float32), gy.astype(np.float32)


def render(layout: Layout, garment_px: float, fabric: FabricParams, base_rgb: tuple[float, float, float],
           decor: Decor, background_rgb: tuple[float, float, float], frame: tuple[int, int], pitch_mm: float,
           rng: np.random.Generator, realism: Realism | None = None) -> Rendered:
    """Render one garment (layout already in frame pixels) into height, slopes, mask and a camera RGB image.

    `realism` (the hard profile) adds folds, a print, dye mottling, a lamp with falloff and a camera model; None
    (the easy profile) renders exactly as the generator did before profiles.
    """
    w, h = frame
    shape = (h, w)
    s = max(w / 1280.0, 0.25)  # feature widths follow the frame; texture follows the pitch

    # silhouette and panel grain
    cover_u8 = np.zeros(shape, np.uint8)
    _fill(cover_u8, [p for p, _ in layout.panels])
    mask = cover_u8 > 127
    grain = np.zeros(shape, np.uint8)
    for k, (poly, _) in enumerate(layout.panels):
        _fill(grain, [poly], k + 1, aa=False)
    grain[~mask] = 0

    # fabric texture per panel grain angle (panels sharing an angle share one evaluation)
    tex = np.zeros(shape, np.float32)
    tex_rng = np.random.default_rng(rng.integers(2**63))
    angles = sorted({a for _, a in layout.panels})
    u_map = np.zeros(shape, np.float32)
    for a in angles:
        sel = np.isin(grain, [k + 1 for k, (_, ak) in enumerate(layout.panels) if ak == a])
        if not sel.any():
            continue
        rows, cols = np.nonzero(sel.any(axis=1))[0], np.nonzero(sel.any(axis=0))[0]
        r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        t = texture(fabric, (r1 - r0, c1 - c0), pitch_mm=pitch_mm, angle_deg=a, rng=tex_rng, origin=(r0, c0))
        yy = (np.arange(r0, r1, dtype=np.float32)[:, None]) * pitch_mm
        xx = (np.arange(c0, c1, dtype=np.float32)[None, :]) * pitch_mm
        ar = np.deg2rad(a)
        u = xx * np.float32(np.cos(ar)) - yy * np.float32(np.sin(ar))
        sub = sel[r0:r1, c0:c1]
        tex[r0:r1, c0:c1][sub] = t[sub]
        u_map[r0:r1, c0:c1][sub] = u[sub]

    # construction: extra layers, seams, stitching, buttons, appliques
    layers_u8 = np.zeros(shape, np.uint8)
    _fill(layers_u8, layout.layers)
    layers = cv2.GaussianBlur(_f(layers_u8), (0, 0), 1.0)
    edges_u8 = np.zeros(shape, np.uint8)
    _lines(edges_u8, layout.layers, max(1, round(2 * s)), closed=True)
    seams_u8 = np.zeros(shape, np.uint8)
    _lines(seams_u8, layout.seams, max(1, round(3 * s)))
    stitch_u8 = np.zeros(shape, np.uint8)
    for line in layout.stitches:
        _dashes(stitch_u8, line, on=max(2.0, 7 * s), off=max(1.0, 3 * s))
    stitch = cv2.GaussianBlur(_f(stitch_u8), (0, 0), 0.6)
    btn_h, btn_a, btn_holes = _buttons(shape, layout.buttons)

    drng = np.random.default_rng(rng.integers(2**63))
    boxes = list(layout.decor_boxes)
    centres: list[tuple[float, float, float, float]] = []
    text_alpha = np.zeros(shape, np.float32)
    if boxes:
        x0, y0, x1, y1 = boxes[0]
        split = y0 + (y1 - y0) * (0.35 if decor.text else 0.0)
        if decor.text:
            text_alpha = _print(shape, decor.text, (x0, y0, x1, split))
        r = 0.05 * garment_px
        for _ in range(decor.flowers):
            for _try in range(20):
                cx = drng.uniform(x0 + r, max(x1 - r, x0 + r + 1))
                cy = drng.uniform(split + r, max(y1 - r, split + r + 1))
                rr = r * drng.uniform(0.7, 1.1)
                if all(np.hypot(cx - a, cy - b) > rr + c for a, b, c, _ in centres) \
                        and mask[int(np.clip(cy, 0, h - 1)), int(np.clip(cx, 0, w - 1))]:
                    centres.append((cx, cy, rr, float(drng.uniform())))
                    break
    petal_a, centre_a, fl_outline = _flowers(shape, centres)
    flower_a = np.maximum(petal_a, centre_a)

    # height field (mm): cloth thickness with a soft edge, texture, layers, ridges, grooves, buttons, appliques
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    e = np.clip(dist / np.float32(EDGE_RAMP_PX), 0, 1)
    edge = e * e * (3 - 2 * e)
    hem = np.exp(-((dist - 6.0) / 2.0) ** 2).astype(np.float32)  # rolled hem along the silhouette
    felt = band_noise(drng, shape, 1.2) * np.float32(0.03)
    t = fabric.thickness_mm
    height = (np.float32(t) + tex * (1 - flower_a)
              + layers * np.float32(0.6 * t + 0.15)
              + _ridge(edges_u8, 1.0) * np.float32(0.3)
              + _ridge(seams_u8, 1.2) * np.float32(0.45)
              + hem * np.float32(0.3)
              - stitch * np.float32(0.12)
              + cv2.GaussianBlur(flower_a, (0, 0), 1.0) * np.float32(0.5) + flower_a * felt
              + _ridge(fl_outline, 0.8) * np.float32(0.2))
    height = np.where(btn_a > 0, np.maximum(height, np.float32(t) + btn_h), height)  # buttons sit on the cloth
    height_mm = (height * edge).astype(np.float32)
    height_mm[~mask] = 0.0
    gx, gy = gradients(height_mm, pitch_mm)
    gx[~mask] = 0.0
    gy[~mask] = 0.0

    folds = fold_height(shape, mask, realism, pitch_mm) if realism is not None else None

    # albedo
    amp = max(fabric.amplitude_mm, 1e-6)
    sign = -1.0 if fabric.name == "denim" else 1.0  # denim: white weft shows in the valleys
    mod = 1 + np.float32(sign * fabric.albedo_mod) * np.clip(tex / np.float32(amp), -1, 1)
    alb = np.asarray(base_rgb, np.float32)[None, None, :] * mod[..., None]
    if fabric.name == "satin":  # satin sheen: broad light/dark bands from drape, albedo only
        alb *= (1 + 0.18 * band_noise(drng, shape, 40.0 * s, 90.0 * s))[..., None]
    if decor.stripes:
        period = drng.uniform(6.0, 12.0)
        stripe = (np.mod(u_map / np.float32(period), 1.0) < 0.3).astype(np.float32)
        stripe = cv2.GaussianBlur(stripe, (0, 0), 0.7) * mask
        alb = _mix(alb, stripe * np.float32(0.85), decor.stripe_rgb)

    def on_cloth(alb: np.ndarray) -> np.ndarray:
        """Seams, stitching, the printed word, appliques and buttons: what sits on the cloth."""
        if realism is None:
            alb *= (1 - 0.05 * layers - 0.10 * _ridge(seams_u8, 1.0))[..., None]
        else:  # seams in matching thread: relief, no colour of their own
            alb = alb * (1 - 0.05 * layers)[..., None]
        alb = _mix(alb, stitch * np.float32(0.8), decor.thread_rgb)
        alb = _mix(alb, text_alpha * mask, decor.print_rgb)
        fl_mod = (1 + 0.15 * felt / 0.03 * 0.3)[..., None]
        alb = _mix(alb, petal_a, decor.petal_rgb) * np.where(flower_a[..., None] > 0, fl_mod, 1)
        alb = _mix(alb, centre_a, decor.centre_rgb)
        return _mix(alb, btn_a, decor.button_rgb) * (1 - 0.6 * btn_holes)[..., None]

    clean_alb = None
    if realism is not None:
        clean_alb = on_cloth(alb.copy())
        alb = alb * mottle(shape, realism, pitch_mm)
        alb = _mix(alb, print_alpha(shape, realism, pitch_mm, u_map) * mask, realism.print_rgb)
    alb = on_cloth(alb)

    # shading: Lambert from the height field's normals (exaggerated), a little Blinn-Phong for shiny fabric
    k = np.float32(EXAGGERATION)
    nx, ny = -k * gx, -k * gy
    inv = 1 / np.sqrt(nx * nx + ny * ny + 1)
    lv = LIGHT / np.linalg.norm(LIGHT)
    ndl = np.clip((nx * lv[0] + ny * lv[1] + lv[2]) * inv, 0, None) / np.float32(lv[2])
    shade = np.float32(0.3) + np.float32(0.7) * ndl
    hv = (lv + np.array([0, 0, 1], np.float32))
    hv = hv / np.linalg.norm(hv)
    ndh = np.clip((nx * hv[0] + ny * hv[1] + hv[2]) * inv, 0, None)
    spec = np.float32(fabric.specular) * ndh ** np.float32(30)
    garment = alb * shade[..., None] + spec[..., None]
    clean = None
    falloff = None
    if realism is not None:
        clean = clean_alb * shade[..., None] + spec[..., None]
        garment, falloff = _lamp_shading(alb, gx, gy, folds, height_mm, realism, fabric.specular, pitch_mm)

    # background table with a soft contact shadow; blend by the anti-aliased coverage
    bg = np.asarray(background_rgb, np.float32)[None, None, :] * (
        1 + 0.03 * band_noise(drng, shape, 30.0 * s))[..., None]
    off = max(2, int(round(8 * s)))
    shadow = np.zeros(shape, np.float32)
    shadow[off:, off:] = _f(cover_u8)[:-off, :-off]
    shadow = cv2.GaussianBlur(shadow, (0, 0), 10.0 * s)
    bg = bg * (1 - 0.3 * shadow)[..., None]
    cover = _f(cover_u8)[..., None]
    if realism is not None:
        sketch_img = cv2.GaussianBlur((clean * cover + bg * (1 - cover)).astype(np.float32), (0, 0), 0.6)
        table = bg * (np.float32(0.3) + np.float32(0.6) * falloff)[..., None]  # the lamp lights the table too
        img = camera(garment * cover + table * (1 - cover), realism)
        return Rendered(rgb=np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8), mask=mask, height_mm=height_mm,
                        gx=gx, gy=gy, sketch_rgb=np.clip(sketch_img * 255 + 0.5, 0, 255).astype(np.uint8),
                        fold_mm=folds)
    img = garment * cover + bg * (1 - cover)

    # camera: mild blur and sensor noise
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.6)
    img += drng.normal(0.0, 1.8 / 255, img.shape).astype(np.float32)
    rgb = np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)
    return Rendered(rgb=rgb, mask=mask, height_mm=height_mm, gx=gx, gy=gy)


def _lamp_shading(alb: np.ndarray, gx: np.ndarray, gy: np.ndarray, folds: np.ndarray, height_mm: np.ndarray,
                  realism: Realism, specular: float, pitch_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Garment radiance under the fixed lamp: normals from the weave (exaggerated as in the easy profile) tilted
    by the folds' true slopes; Lambert x inverse-square falloff plus ambient, Blinn-Phong towards the camera."""
    fgy, fgx = np.gradient(folds, np.float32(pitch_mm))
    k = np.float32(EXAGGERATION)
    nx, ny = -k * gx - fgx.astype(np.float32), -k * gy - fgy.astype(np.float32)
    inv = 1 / np.sqrt(nx * nx + ny * ny + 1)
    ldir, falloff = lamp(gx.shape, realism, pitch_mm, height_mm + folds)
    ndl = np.clip((nx * ldir[..., 0] + ny * ldir[..., 1] + ldir[..., 2]) * inv, 0, None)
    shade = np.float32(0.25) + np.float32(0.85) * ndl * falloff
    hv = ldir + np.array([0, 0, 1], np.float32)
    hv /= np.linalg.norm(hv, axis=-1, keepdims=True)
    ndh = np.clip((nx * hv[..., 0] + ny * hv[..., 1] + hv[..., 2]) * inv, 0, None)
    spec = np.float32(specular) * ndh ** np.float32(30) * falloff
    return alb * shade[..., None] + spec[..., None], falloff
