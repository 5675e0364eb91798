"""One entry for every relief calibration rule, so evaluation and the exporter wrap a generator the same way.

`rms`, `ls`, `lift`: one gain (trainer/calibration.py, trainer/models/relief_gain.py). `shade`, `shade-lift`: the
model's relief mixed with its own photo's shading (trainer/shading_fit.py, trainer/models/shading_relief.py). All
are fitted on the garment's training touches only.
"""
from __future__ import annotations

from torch import nn

from trainer import calibration
from trainer.data.touchclothing import Garment
from trainer.models.relief_gain import ReliefGain
from trainer.relief_rules import RULES


def calibrate(net: nn.Module, g: Garment, side: int, rule: str) -> tuple[nn.Module, dict, str]:
    """(the wrapped generator, its JSON-able fit, a one-line summary). Raises CalibrationError when the garment's
    training touches cannot fit it, ValueError for an unknown rule."""
    if rule not in RULES or rule == "none":
        raise ValueError(f"relief rule must be one of {', '.join(r for r in RULES if r != 'none')}; got {rule!r}")
    if rule.startswith("shade"):
        from trainer.shading_fit import fit_shading

        fit = fit_shading(net, g, side, floor=1.0 if rule == "shade-lift" else None)
        return fit.wrap(net), {**fit.as_dict(), "rule": rule}, (
            f"{rule}: model x{fit.model_weight:.4f} + its photo's shading, from {fit.touches} training touches")
    fit = calibration.fit_relief_gain(net, g, side, rule)   # by module: one place to stand in for it in tests
    return ReliefGain(net, fit.gain).eval(), fit.as_dict(), f"{rule} x{fit.gain:.4f} from {fit.touches} training touches"
