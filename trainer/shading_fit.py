"""Fit the shading relief (trainer/models/shading_relief.py) of a trained model on its garment's training touches.

Over the contact pixels of every training touch inside the evaluation crop, the measured slopes are regressed on
the model's own relief (one weight, not shrunk) and on each filter of the bank applied to the model's own visual
output (ridge-shrunk on standardised columns, so a filter the touches do not support stays near 0). Only the
training touches are used: it is part of the method, like the relief gain (trainer/calibration.py).

`shade-lift` holds the model's weight at 1 or above, as `lift` holds the gain: below 1 the fit buys per-pixel angle
by flattening the model's weave, which the texture statistic pays for (docs/training.md, "Shading relief").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from trainer.calibration import CalibrationError, fit_inputs
from trainer.data.touchclothing import Garment
from trainer.models.shading_relief import ShadingRelief, filter_bank, shading_slopes

RIDGE = 0.1   # per sample, on columns scaled to unit RMS
TINY = 1e-8   # a column below this RMS (a flat photo or a flat model) is left out of the fit


@dataclass(frozen=True)
class ShadingFit:
    model_weight: float
    weights: tuple[float, ...]      # one per filter of the bank
    kernel: np.ndarray              # (2, K, K): the bank mixed by `weights`
    pixels: int
    touches: int

    def as_dict(self) -> dict:
        return {"model_weight": self.model_weight, "filter_weights": list(self.weights),
                "pixels": self.pixels, "touches": self.touches}

    def wrap(self, net: nn.Module) -> ShadingRelief:
        return ShadingRelief(net, self.model_weight, self.kernel).eval()


def solve(columns: np.ndarray, target: np.ndarray, ridge: float = RIDGE, floor: float | None = None) -> np.ndarray:
    """Ridge least squares, column 0 (the model's relief) unshrunk. Columns below TINY RMS get weight 0. With
    `floor`, a model weight below it is held at it and the other weights refitted to what is left."""
    w = _ridge(columns, target, ridge)
    return w if floor is None or w[0] >= floor else _held(columns, target, floor, ridge)


def _held(columns: np.ndarray, target: np.ndarray, model_weight: float, ridge: float) -> np.ndarray:
    """The filters' weights refitted with the model's weight held at `model_weight`."""
    rest = _ridge(np.concatenate([np.zeros((len(target), 1)), columns[:, 1:]], 1),
                  target - model_weight * columns[:, 0], ridge)
    rest[0] = model_weight
    return rest


def _ridge(columns: np.ndarray, target: np.ndarray, ridge: float) -> np.ndarray:
    rms = np.sqrt((columns * columns).mean(0))
    live = rms > TINY
    w = np.zeros(columns.shape[1])
    if not live.any():
        return w
    a = columns[:, live] / rms[live]
    pen = np.where(np.arange(columns.shape[1])[live] == 0, 0.0, ridge * len(target))
    w[live] = np.linalg.solve(a.T @ a + np.diag(pen) + TINY * np.eye(a.shape[1]), a.T @ target) / rms[live]
    return w


@torch.no_grad()
def fit_shading(net: nn.Module, g: Garment, side: int, ridge: float = RIDGE, floor: float | None = None
                ) -> ShadingFit:
    """The shading relief of `net` on garment `g` at crop `side`. Raises CalibrationError (too few touch pixels,
    or a model and photo with no relief to weigh)."""
    found, n, mask, vis, tac = fit_inputs(net, g, side, "a shading relief")
    bank = filter_bank()
    feats = shading_slopes(vis.float(), mask, torch.from_numpy(bank))[0].double().numpy()
    tac = tac[0].double().numpy()
    yy = np.concatenate([f[0] for f in found])
    xx = np.concatenate([f[1] for f in found])
    target = np.concatenate([np.concatenate([f[2] for f in found]), np.concatenate([f[3] for f in found])])
    cols = [np.concatenate([tac[0, yy, xx], tac[1, yy, xx]])]
    cols += [np.concatenate([feats[2 * j, yy, xx], feats[2 * j + 1, yy, xx]]) for j in range(len(bank))]
    a, target = np.stack(cols, 1), target.astype(np.float64)
    w = solve(a, target, ridge)
    if not np.isfinite(w).all() or w[0] <= 0:   # judged before any floor, as `lift` judges the ls gain
        raise CalibrationError(f"{g.name}: the model's relief gets weight {w[0]:.3g} beside its photo's shading on "
                               "the training touches (unrelated to them); it is used as trained")
    if floor is not None and w[0] < floor:   # the free fit judged above is not solved again
        w = _held(a, target, floor, ridge)
    kernel = np.tensordot(w[1:], bank, axes=1).astype(np.float32)
    return ShadingFit(float(w[0]), tuple(float(v) for v in w[1:]), kernel, n, len(found))
