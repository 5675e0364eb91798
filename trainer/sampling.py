"""What one training step sees, and the fixed validation set.

Per step (seeded by (seed, step, rank), so a resumed or distributed run draws exactly what an uninterrupted one
would): a random crop keeping the object inside; the masked sketch, mask and visual in [-1, 1]; `patches` paired
tactile patches from `extract_patches` (published rules), drawn among `candidates_per_touch` random centres per
touch with probability proportional to the variance of the sketch's Laplacian over the patch (+ a floor), as the
reference weights them; `unpaired` fake-patch origins drawn uniformly inside the object mask.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import torch

from kiosk.contract.sketch import network_input
from trainer.augment import eval_crop_origin, random_crop_origin, resolve_crop
from trainer.config import DataConfig
from trainer.data.touchclothing import PATCH, Garment, PatchSet, extract_patches, friction_scale, load_garment
from trainer.models.weave_waves import object_coords
from trainer.recipe.mirror import flip_batch, transpose_batch


@dataclass
class Batch:
    """Shape: sketch, mask (1, 1, C, C); visual (1, 3, C, C); gx, gy, contact (K, 1, 32, 32); origins (K, 2) and
    unpaired (U, 2) int (x, y) patch corners in crop px; origin (x, y) of the crop in the padded frame."""

    sketch: torch.Tensor
    mask: torch.Tensor
    visual: torch.Tensor
    gx: torch.Tensor
    gy: torch.Tensor
    contact: torch.Tensor
    origins: np.ndarray
    unpaired: np.ndarray
    origin: tuple[int, int]
    mirrored: bool = False   # mirrored across the crop's diagonal or left to right (data.transpose, data.flip)
    twin: "Batch | None" = None   # the same crop mirrored, trained beside it on the tactile side (data.mirror_extra)
    coords: torch.Tensor | None = None   # (1, 2, C, C) weave-wave coordinates of a mirrored crop; None: the mask's

    def wave_coords(self) -> torch.Tensor:
        """Each pixel's weave-wave (u, v) (trainer/models/weave_waves.py): a mirrored crop's are its pixels' own,
        mirrored with them; a plain crop's are what the generator computes from its mask anyway."""
        return object_coords(self.mask) if self.coords is None else self.coords

    def to(self, device: torch.device) -> "Batch":
        """The same batch with its tensors on `device` (data is drawn on the CPU, seeded, whatever trains it)."""
        if self.sketch.device == torch.device(device):
            return self
        moved = {k: getattr(self, k) for k in ("sketch", "mask", "visual", "gx", "gy", "contact", "coords")}
        return replace(self, **{k: (v.to(device) if v is not None else None) for k, v in moved.items()},
                       twin=None if self.twin is None else self.twin.to(device))


def crop_tensors(g: Garment, origin: tuple[int, int], side: int, *, sketch=None, mask=None, visual=None):
    x, y = origin
    s = (g.sketch if sketch is None else sketch)[y:y + side, x:x + side]
    m = (g.mask if mask is None else mask)[y:y + side, x:x + side]
    v = (g.visual if visual is None else visual)
    ni = network_input(s, m)
    sk, mk = torch.from_numpy(ni.sketch), torch.from_numpy(ni.mask)
    vis = None
    if v is not None:
        vis = torch.from_numpy(v[y:y + side, x:x + side].astype(np.float32) / 127.5 - 1.0).permute(2, 0, 1)[None]
        vis = vis * mk
    return sk, mk, vis


def window_variance(sketch_crop: np.ndarray) -> np.ndarray:
    """var(Laplacian of the sketch) over every 32x32 window, indexed [y, x] by the window's top-left corner.

    One pass per crop; paired and unpaired patch weights both read from it (integral images, float64)."""
    lap = cv2.Laplacian(sketch_crop.astype(np.float32) / 255.0, cv2.CV_32F, ksize=3)
    s1 = cv2.integral(lap, sdepth=cv2.CV_64F)
    s2 = cv2.integral(lap * lap, sdepth=cv2.CV_64F)

    def box(s):
        return s[PATCH:, PATCH:] - s[:-PATCH, PATCH:] - s[PATCH:, :-PATCH] + s[:-PATCH, :-PATCH]

    n = PATCH * PATCH
    return np.maximum(box(s2) / n - (box(s1) / n) ** 2, 0.0)


def window_weights(variance: np.ndarray, origins: np.ndarray, floor: float) -> np.ndarray:
    """Probability of each candidate window: its variance plus floor x the candidates' mean."""
    var = variance[origins[:, 1], origins[:, 0]]
    w = var + floor * (var.mean() if var.size else 0.0) + 1e-12
    return w / w.sum()


def laplacian_weights(sketch_crop: np.ndarray, origins: np.ndarray, floor: float) -> np.ndarray:
    """Probability of each candidate patch: var(Laplacian) over its 32x32 window, plus floor x mean."""
    return window_weights(window_variance(sketch_crop), origins, floor)


def patches_to_tensors(ps: PatchSet, idx: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    t = [torch.from_numpy(np.ascontiguousarray(a[idx]))[:, None] for a in (ps.gx, ps.gy, ps.contact)]
    return t[0], t[1], t[2]


class GarmentData:
    """One garment, ready to draw training batches and the fixed validation/evaluation set from."""

    def __init__(self, garment: Path | Garment, cfg: DataConfig, *, seed: int = 0):
        self.g = garment if isinstance(garment, Garment) else load_garment(Path(garment))
        assert self.g.visual is not None, f"{self.g.name}: an edited sketch has no visual to train on"
        self.cfg = cfg
        self.seed = seed
        self.side = resolve_crop(cfg.crop, self.g.mask, fit=cfg.fit_crop)
        self.friction_scale = friction_scale(self.g)
        ys, xs = np.nonzero(self.g.mask)
        self._obj = np.stack([xs, ys], 1)

    def rng(self, step: int, rank: int = 0) -> np.random.Generator:
        return np.random.default_rng([self.seed, step, rank])

    def batch(self, step: int, rank: int = 0) -> Batch:
        rng = self.rng(step, rank)
        side = self.side
        origin = random_crop_origin(self.g.mask, side, rng)
        sk, mk, vis = crop_tensors(self.g, origin, side)
        mcrop = self.g.mask[origin[1]:origin[1] + side, origin[0]:origin[0] + side]
        ps = extract_patches(self.g, "train", crop_origin=origin, crop_size=(side, side),
                             per_touch=self.cfg.candidates_per_touch, mode="random", rng=rng)
        assert len(ps) > 0, f"{self.g.name}: no training patch lands inside the crop"
        scrop = self.g.sketch[origin[1]:origin[1] + side, origin[0]:origin[0] + side]
        variance = window_variance(scrop)
        p = window_weights(variance, ps.origin, self.cfg.laplacian_floor)
        k = self.cfg.patches
        idx = rng.choice(len(ps), size=k, replace=len(ps) < k, p=p)
        gx, gy, c = patches_to_tensors(ps, idx)
        unpaired = self._unpaired(rng, side, mcrop, variance)
        plain = b = Batch(sk, mk, vis, gx, gy, c, ps.origin[idx], unpaired, origin)
        # drawn only when asked for, so runs without it keep the stream they always had
        if self.cfg.transpose > 0 and rng.random() < self.cfg.transpose:
            b = transpose_batch(b)
        if self.cfg.flip > 0 and rng.random() < self.cfg.flip:
            b = flip_batch(b)
        if self.cfg.mirror_extra and b.mirrored:
            return replace(plain, twin=b)
        return b

    def _unpaired(self, rng, side, mcrop, variance) -> np.ndarray:
        """Fake-patch corners whose centre pixel lies on the object, fully inside the crop; uniform, or weighted by
        the sketch's Laplacian variance exactly like the paired patches (`data.unpaired_sampling`)."""
        u = self.cfg.unpaired
        if u == 0:
            return np.zeros((0, 2), int)
        h = PATCH // 2
        ys, xs = np.nonzero(mcrop[h:side - h, h:side - h])
        corners = np.stack([xs, ys], 1).astype(int)
        if self.cfg.unpaired_sampling == "laplacian":
            pick = rng.choice(len(corners), size=u, p=window_weights(variance, corners, self.cfg.laplacian_floor))
        else:
            pick = rng.integers(0, len(corners), size=u)
        return corners[pick]

    def eval_set(self, split: str = "val") -> Batch:
        """The fixed set: the centre (object-keeping) crop and the patch nearest each touch's middle."""
        origin = eval_crop_origin(self.g.mask, self.side)
        sk, mk, vis = crop_tensors(self.g, origin, self.side)
        ps = extract_patches(self.g, split, crop_origin=origin, crop_size=(self.side, self.side), mode="centre")
        idx = np.arange(len(ps))
        gx, gy, c = patches_to_tensors(ps, idx)
        return Batch(sk, mk, vis, gx, gy, c, ps.origin, np.zeros((0, 2), int), origin)


def cut(x: torch.Tensor, origins: np.ndarray, size: int = PATCH) -> torch.Tensor:
    """Patches of an (1, C, H, W) map at (x, y) corners -> (K, C, size, size)."""
    assert x.dim() == 4 and x.shape[0] == 1, f"expected (1, C, H, W); got {tuple(x.shape)}"
    if len(origins) == 0:
        return x.new_zeros((0, x.shape[1], size, size))
    return torch.cat([x[:, :, y:y + size, xx:xx + size] for xx, y in origins.tolist()], 0)
