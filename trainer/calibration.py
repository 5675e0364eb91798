"""Relief calibration: one gain that gives a trained model's tactile output the strength of the garment's own
training touches.

Why: a generator trained with per-pixel and perceptual losses returns a shrunken relief (the mean of what a crop
could hold). On the hard synthetic garments the 1 000-step runs' slopes have about 0.6x the truth's RMS, on their
own training touches as much as off them, so the fabric's texture statistics are far from the truth and the kiosk's
friction map sits low. The gain is fitted on the training touches only (never the held-out or validation ones), so
it is part of the method, not a peek at the test.

Over the contact pixels of every training touch inside the evaluation crop, r the touch's measured slopes and p the
model's (gx and gy together: one gain keeps the slope's direction):
- `rms`: gain = sqrt(sum r^2 / sum p^2), the relief's energy matched (what sets the friction a finger feels);
- `ls`: gain = sum p r / sum p^2, the least-squares gain (smaller when the prediction's bumps are misplaced);
- `lift`: the `ls` gain, but never below 1. Why: below 1 the least-squares gain flattens bumps it finds misplaced,
  which lowers the angle error and takes the weave's strength with it (the texture statistic: SatinShirt and
  KnitJacket after `-energy` mirroring, gains 0.79-0.93); above 1 it gives a shrunken relief back the strength both
  figures want (CorduroyTrousers, 1.43). So it only ever gives strength back. The floor was set after those tables
  (docs/training.md, "One gain rule for the four garments").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from trainer.augment import eval_crop_origin
from trainer.data.touchclothing import Garment
from trainer.relief_rules import GAIN_RULES
from trainer.sampling import crop_tensors


# A gain outside this range means the model's relief is (nearly) flat on the touches: scaling it would amplify
# noise, not restore texture, so the fit is refused and the model is used as trained.
GAIN_RANGE = (0.25, 4.0)
# Fewer measured contact pixels than this and the energy ratio is not worth a fit.
MIN_PIXELS = 256


class CalibrationError(ValueError):
    """The garment's training touches cannot calibrate this model (none in the crop, or a flat model)."""


@dataclass(frozen=True)
class Fit:
    gain: float
    pixels: int
    touches: int
    rule: str

    def as_dict(self) -> dict:
        return {"rule": self.rule, "gain": self.gain, "pixels": self.pixels, "touches": self.touches}


def touch_pixels(g: Garment, origin: tuple[int, int], side: int, split: str = "train"):
    """Per training touch inside the crop: (rows, cols) in crop pixels and the measured (gx, gy) there, over the
    touch's contact pixels that are on the object."""
    x0, y0 = origin
    out = []
    for t in g.touches.get(split, []):
        r = t.rect
        rr, cc = np.nonzero(t.contact)
        yy, xx = rr + r.y - y0, cc + r.x - x0
        keep = (yy >= 0) & (yy < side) & (xx >= 0) & (xx < side)
        rr, cc, yy, xx = rr[keep], cc[keep], yy[keep], xx[keep]
        on = g.mask[yy + y0, xx + x0] > 0
        if on.any():
            out.append((yy[on], xx[on], t.gx[rr[on], cc[on]], t.gy[rr[on], cc[on]]))
    return out


@torch.no_grad()
def fit_inputs(net: nn.Module, g: Garment, side: int, what: str):
    """What every relief calibration fits on: the training touches' contact pixels in the evaluation crop
    (`touch_pixels`), their count, and the model's mask, visual and tactile outputs on that crop. Raises
    CalibrationError when too few pixels are measured to fit `what`."""
    origin = eval_crop_origin(g.mask, side)
    found = touch_pixels(g, origin, side)
    n = sum(len(f[0]) for f in found)
    if n < MIN_PIXELS:
        raise CalibrationError(f"{g.name}: {n} training-touch contact pixels inside the {side} px evaluation crop "
                               f"(at least {MIN_PIXELS} are needed to fit {what})")
    sketch, mask, _ = crop_tensors(g, origin, side)
    vis, tac = net(sketch, mask)
    return found, n, mask, vis, tac


@torch.no_grad()
def fit_relief_gain(net: nn.Module, g: Garment, side: int, rule: str = "rms") -> Fit:
    """The gain of `rule` for `net` on garment `g` at crop `side` (the evaluation crop). Raises CalibrationError."""
    if rule not in GAIN_RULES:
        raise ValueError(f"relief rule must be one of {', '.join(GAIN_RULES)}; got {rule!r}")
    found, n, _, _, tac = fit_inputs(net, g, side, "a relief gain")
    tac = tac[0].double().numpy()
    rr = pp = pr = 0.0
    for yy, xx, gx, gy in found:
        r = np.stack([gx, gy]).astype(np.float64)
        p = np.stack([tac[0, yy, xx], tac[1, yy, xx]])
        rr, pp, pr = rr + float((r * r).sum()), pp + float((p * p).sum()), pr + float((p * r).sum())
    num, den = (rr, pp) if rule == "rms" else (pr, pp)
    power = 2 if rule == "rms" else 1   # compare num with lo^power * den: no division before the range check
    lo, hi = GAIN_RANGE
    # den == 0 (a flat model) or num <= 0 (flat touches, or bumps anti-correlated) land outside: never a 0 division
    if not (den > 0 and num > 0 and lo ** power * den <= num <= hi ** power * den):
        ratio = "undefined" if den <= 0 else f"{(num / den) ** (1 / power) if num > 0 else num / den:.3g}"
        raise CalibrationError(f"{g.name}: {rule} relief gain {ratio} is outside [{lo}, {hi}]: the model's relief "
                               "is (nearly) flat on the training touches, or unrelated to them; it is used as trained")
    gain = (num / den) ** (1 / power)
    return Fit(max(gain, 1.0) if rule == "lift" else gain, n, len(found), rule)
