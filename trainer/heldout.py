"""Tactile error on every valid held-out patch centre (not one patch per touch): per touch, the sums that all its
32x32 patches contribute, computed with integral images instead of cutting thousands of overlapping patches.

A patch follows the published rules (trainer.data.touchclothing.extract_patches): centred on an allowed centre of
the touch, fully inside the evaluation crop, with at least one object pixel; it is scored on its contact pixels
(sensor contact x object mask). The pooled score over all patches weighs each pixel by how many patches cover it,
exactly as scoring every patch and pooling their contact pixels would. The touch is the resampling unit of the
bootstrap: the patches of one touch overlap, so resampling them one by one would overstate the evidence.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trainer.bootstrap import Units
from trainer.data.touchclothing import PATCH, Garment, valid_centres
from trainer.metrics import angle_map


@dataclass
class HeldOut:
    """Per held-out touch: sums of angle and squared error over its patches' contact pixels, the contact-pixel count
    and the number of patches. Shape: all (T,), index = touch index in the split."""

    touch: np.ndarray
    angle: np.ndarray
    sse: np.ndarray
    contact: np.ndarray
    patches: np.ndarray

    def scores(self) -> dict:
        n = float(self.contact.sum())
        if not n > 0:
            return {}
        return {"tactile_angle_deg": float(self.angle.sum() / n), "tactile_mse": float(self.sse.sum() / (2 * n)),
                "test_patches": int(self.patches.sum()), "test_touches": int((self.patches > 0).sum())}

    def units(self) -> dict[str, Units]:
        return {"tactile_angle_deg": Units(self.touch, self.angle, self.contact),
                "tactile_mse": Units(self.touch, self.sse / 2.0, self.contact)}


def _window_sums(a: np.ndarray, rows: np.ndarray, cols: np.ndarray, patch: int) -> np.ndarray:
    """Sum of `a` over the patch x patch window a[r - h:r + h, c - h:c + h] at each centre (float64 integral)."""
    s = np.zeros((a.shape[0] + 1, a.shape[1] + 1))
    s[1:, 1:] = np.cumsum(np.cumsum(a, 0), 1)
    h = patch // 2
    r0, r1, c0, c1 = rows - h, rows + h, cols - h, cols + h
    return s[r1, c1] - s[r0, c1] - s[r1, c0] + s[r0, c0]


def heldout_errors(g: Garment, split: str, origin: tuple[int, int], side: int, gx: np.ndarray, gy: np.ndarray,
                   *, centres: str = "all", patch: int = PATCH) -> HeldOut:
    """Score a predicted field on `split`'s touches.

    gx, gy (side, side): the prediction on the crop at `origin` (x, y) of the padded frame. `centres` "all" scores
    every valid centre; "middle" only the one nearest each touch's middle (what extract_patches(mode="centre")
    takes: the old protocol, kept to check the two agree).
    """
    if centres not in ("all", "middle"):
        raise ValueError(f"centres must be 'all' or 'middle'; got {centres!r}")
    cx0, cy0 = origin
    obj = g.mask[cy0:cy0 + side, cx0:cx0 + side]
    half = patch // 2
    rows = []
    for ti, t in enumerate(g.touches.get(split, [])):
        cen = valid_centres(t, patch)
        ox = t.rect.x + cen[:, 1] - half - cx0
        oy = t.rect.y + cen[:, 0] - half - cy0
        cen = cen[(ox >= 0) & (oy >= 0) & (ox + patch <= side) & (oy + patch <= side)]
        if len(cen) == 0:
            continue
        h, w = t.gx.shape
        # the touch rectangle in crop coordinates; parts outside the crop are never inside a kept patch
        ys = np.arange(h) + t.rect.y - cy0
        xs = np.arange(w) + t.rect.x - cx0
        iy, ix = np.clip(ys, 0, side - 1), np.clip(xs, 0, side - 1)
        valid = ((ys >= 0) & (ys < side))[:, None] & ((xs >= 0) & (xs < side))[None, :]
        o = obj[np.ix_(iy, ix)] & valid
        # drop centres whose patch holds no object pixel (the published rule)
        cen = cen[_window_sums(o.astype(np.float64), cen[:, 0], cen[:, 1], patch) > 0]
        if len(cen) == 0:
            continue
        if centres == "middle":
            mid = np.array([h / 2, w / 2])
            cen = cen[[int(np.argsort(((cen - mid) ** 2).sum(1), kind="stable")[0])]]
        pgx, pgy = gx[np.ix_(iy, ix)], gy[np.ix_(iy, ix)]
        wgt = (t.contact & o).astype(np.float64)
        ang = angle_map(pgx, pgy, t.gx, t.gy) * wgt
        sse = ((np.asarray(pgx, np.float64) - t.gx) ** 2 + (np.asarray(pgy, np.float64) - t.gy) ** 2) * wgt
        r, c = cen[:, 0], cen[:, 1]
        rows.append((ti, _window_sums(ang, r, c, patch).sum(), _window_sums(sse, r, c, patch).sum(),
                     _window_sums(wgt, r, c, patch).sum(), len(cen)))
    if not rows:
        z = np.zeros(0)
        return HeldOut(z.astype(int), z, z, z, z.astype(int))
    a = np.array(rows, dtype=np.float64)
    return HeldOut(a[:, 0].astype(int), a[:, 1], a[:, 2], a[:, 3], a[:, 4].astype(int))


def touch_rect_mask(g: Garment, split: str = "train") -> np.ndarray:
    """(P, P) bool: the union of `split`'s touch rectangles (where the model saw tactile examples)."""
    m = np.zeros(g.mask.shape, bool)
    for t in g.touches.get(split, []):
        r = t.rect
        m[max(r.y, 0):max(r.y + r.h, 0), max(r.x, 0):max(r.x + r.w, 0)] = True
    return m
