"""Procedural friction maps and stroke edits, for the bench and the soak test (no data files needed).

A realistic friction map for a 1280x800 panel: a garment-shaped mask (body, sleeves, collar), inside it a fabric
weave (product of sinusoids with a slow gradient), seams along the outline (higher friction) and mild quantised
noise; outside the mask 0 (natural friction). A stroke edit changes the garment near a random stroke: the mask
grows or shrinks along it and the fabric is re-rendered in the stroke's neighbourhood, like the kiosk re-inferring
the region a stroke changed. Shapes: uint8 (h, w).
"""
from __future__ import annotations

import numpy as np


def garment_mask(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """bool (h, w): a T-shirt-like silhouette, randomly scaled and shifted."""
    yy, xx = np.mgrid[0:h, 0:w]
    cx = w / 2 + rng.uniform(-0.05, 0.05) * w
    top, bottom = h * rng.uniform(0.12, 0.2), h * rng.uniform(0.85, 0.95)
    half = w * rng.uniform(0.14, 0.2)
    body = (abs(xx - cx) < half + (yy - top) * 0.04) & (yy > top) & (yy < bottom)
    sleeve_y = top + (bottom - top) * 0.3
    sleeves = (abs(xx - cx) < half * 2.1) & (yy > top) & (yy < sleeve_y) & (abs(xx - cx) > half * 0.5) \
        & (yy - top > (abs(xx - cx) - half) * 0.35)
    collar = ((xx - cx) ** 2 / (half * 0.45) ** 2 + (yy - top) ** 2 / (h * 0.05) ** 2) < 1
    return (body | sleeves) & ~collar


def fabric(h: int, w: int, rng: np.random.Generator, y0: int = 0, x0: int = 0, phase: float = 0.0) -> np.ndarray:
    """float32 (h, w) in [0, 1]: weave + gradient + mild noise, for the window at (y0, x0) of a larger panel."""
    yy, xx = np.mgrid[y0:y0 + h, x0:x0 + w].astype(np.float32)
    weave = 0.5 + 0.25 * np.sin(2 * np.pi * xx / 9.0 + phase) * np.sin(2 * np.pi * yy / 7.0) \
        + 0.15 * np.sin(2 * np.pi * (xx + yy) / 23.0)
    gradient = 0.2 * (yy / 800.0) + 0.1 * (xx / 1280.0)
    noise = rng.normal(0.0, 0.02, size=(h, w)).astype(np.float32)
    return np.clip(0.15 + 0.6 * weave + gradient + noise, 0.0, 1.0)


def seams(mask: np.ndarray) -> np.ndarray:
    """bool: a 3-pixel band along the inside of the mask's outline."""
    m = mask.copy()
    edge = np.zeros_like(mask)
    for _ in range(3):
        inner = m.copy()
        inner[1:, :] &= m[:-1, :]
        inner[:-1, :] &= m[1:, :]
        inner[:, 1:] &= m[:, :-1]
        inner[:, :-1] &= m[:, 1:]
        edge |= m & ~inner
        m = inner
    return edge


def render(mask: np.ndarray, tex: np.ndarray) -> np.ndarray:
    frame = np.where(mask, tex * 200.0 + 20.0, 0.0)
    frame[seams(mask)] = 250.0
    return frame.astype(np.uint8)


def friction_frame(h: int = 800, w: int = 1280, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(frame uint8 (h, w), mask bool (h, w)) of a garment on the panel."""
    rng = np.random.default_rng(seed)
    mask = garment_mask(h, w, rng)
    return render(mask, fabric(h, w, rng)), mask


def stroke_edit(frame: np.ndarray, mask: np.ndarray, rng: np.random.Generator, width: int = 14,
                margin: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """One stroke: a random polyline near the garment outline adds to (or erases from) the mask, and the fabric is
    re-rendered in the stroke's bounding box + margin. Returns the new (frame, mask); inputs are not modified."""
    h, w = frame.shape
    ys, xs = np.nonzero(seams(mask)) if mask.any() else (np.array([h // 2]), np.array([w // 2]))
    i = rng.integers(len(ys))
    pts = [(float(ys[i]), float(xs[i]))]
    angle = rng.uniform(0, 2 * np.pi)
    for _ in range(int(rng.integers(3, 8))):
        angle += rng.normal(0, 0.5)
        step = rng.uniform(10, 30)
        y, x = pts[-1]
        pts.append((float(np.clip(y + step * np.sin(angle), 0, h - 1)),
                    float(np.clip(x + step * np.cos(angle), 0, w - 1))))
    p = np.array(pts)
    y0 = int(max(p[:, 0].min() - width - margin, 0))
    y1 = int(min(p[:, 0].max() + width + margin + 1, h))
    x0 = int(max(p[:, 1].min() - width - margin, 0))
    x1 = int(min(p[:, 1].max() + width + margin + 1, w))
    yy, xx = np.mgrid[y0:y1, x0:x1]
    near = np.zeros((y1 - y0, x1 - x0), bool)
    for (ay, ax), (by, bx) in zip(p[:-1], p[1:]):
        d = np.array([by - ay, bx - ax])
        L2 = max(float(d @ d), 1e-6)
        t = np.clip(((yy - ay) * d[0] + (xx - ax) * d[1]) / L2, 0, 1)
        near |= (yy - (ay + t * d[0])) ** 2 + (xx - (ax + t * d[1])) ** 2 <= (width / 2) ** 2
    new_mask = mask.copy()
    new_mask[y0:y1, x0:x1] = (mask[y0:y1, x0:x1] | near) if rng.random() < 0.6 else (mask[y0:y1, x0:x1] & ~near)
    new = frame.copy()
    ry0, ry1, rx0, rx1 = max(y0 - 4, 0), min(y1 + 4, h), max(x0 - 4, 0), min(x1 + 4, w)
    tex = fabric(ry1 - ry0, rx1 - rx0, rng, ry0, rx0, phase=rng.uniform(0, 0.3))
    new[ry0:ry1, rx0:rx1] = render(new_mask[ry0:ry1, rx0:rx1], tex)
    return new, new_mask
