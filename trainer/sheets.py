"""Pictures: sample sheets during training, qualitative comparison sheets, the swap grid, training curves.

Tiles are uint8 RGB; a tactile field is shown as its normal map (Eq. 1, mapped to colours), its Poisson height map
and its calibrated friction map (what the screen renders).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from kiosk.contract.haptics import friction_map, height_from_gradients, normals_from_gradients

TILE = 256


def to_uint8(img: np.ndarray) -> np.ndarray:
    """[-1, 1] (H, W, 3) or (H, W) -> uint8 RGB."""
    a = np.clip((np.asarray(img, np.float32) + 1) * 127.5, 0, 255).astype(np.uint8)
    return np.repeat(a[..., None], 3, -1) if a.ndim == 2 else a


def normal_tile(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    n = normals_from_gradients(gx, gy)
    rgb = np.stack([n[..., 0], n[..., 1], -n[..., 2]], -1)
    return np.clip((rgb + 1) * 127.5, 0, 255).astype(np.uint8)


def height_tile(gx: np.ndarray, gy: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    h = height_from_gradients(gx, gy)
    m = mask if mask is not None else np.ones_like(h, bool)
    lo, hi = (np.percentile(h[m], [1, 99]) if m.any() else (0.0, 1.0))
    z = np.clip((h - lo) / max(hi - lo, 1e-9), 0, 1)
    col = cv2.applyColorMap((z * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1]
    col[~m] = 255
    return col


def friction_tile(gx: np.ndarray, gy: np.ndarray, scale: float) -> np.ndarray:
    return np.repeat(friction_map(gx, gy, scale)[..., None], 3, -1)


def label(tile: np.ndarray, text: str, size: int = TILE) -> np.ndarray:
    t = cv2.resize(np.ascontiguousarray(tile), (size, size), interpolation=cv2.INTER_AREA)
    t = np.ascontiguousarray(t)
    cv2.rectangle(t, (0, 0), (size, 18), (255, 255, 255), -1)
    cv2.putText(t, text[:34], (3, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return t


def grid(rows: list[list[np.ndarray]]) -> np.ndarray:
    width = max(len(r) for r in rows)
    blank = np.full_like(rows[0][0], 255)
    return np.concatenate([np.concatenate(r + [blank] * (width - len(r)), 1) for r in rows], 0)


def save_png(path: Path, rgb: np.ndarray) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))


def output_row(name: str, visual: np.ndarray, gx: np.ndarray, gy: np.ndarray, mask: np.ndarray,
               scale: float) -> list[np.ndarray]:
    """visual (H, W, 3) in [-1, 1]; gx, gy (H, W): visual | normal map | height map | friction map."""
    return [label(to_uint8(visual), f"{name}: visual"), label(normal_tile(gx, gy), f"{name}: normal"),
            label(height_tile(gx, gy, mask), f"{name}: height"), label(friction_tile(gx, gy, scale),
                                                                      f"{name}: friction")]


def curves_png(path: Path, history: list[dict], val: list[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    keys = sorted({k for h in history for k in h if k != "step"})
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for k in keys:
        xs = [h["step"] for h in history if k in h]
        ys = [h[k] for h in history if k in h]
        axes[0].plot(xs, ys, label=k, lw=0.8)
    axes[0].set_yscale("symlog", linthresh=1e-2)
    axes[0].set_xlabel("step")
    axes[0].set_title("training losses")
    axes[0].legend(fontsize=7, ncol=2)
    for k in ("val_visual_l1", "val_tactile_mse", "val_tactile_angle_deg"):
        xs = [v["step"] for v in val if k in v]
        if xs:
            axes[1].plot(xs, [v[k] for v in val if k in v], marker="o", label=k)
    axes[1].set_yscale("log")
    axes[1].set_xlabel("step")
    axes[1].set_title("fixed validation set")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
