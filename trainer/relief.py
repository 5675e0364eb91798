"""One entry for every relief calibration rule, so evaluation and the exporter wrap a generator the same way.

`rms`, `ls`, `lift`: one gain (trainer/calibration.py, trainer/models/relief_gain.py). `shade`, `shade-lift`: the
model's relief mixed with its own photo's shading (trainer/shading_fit.py, trainer/models/shading_relief.py). All
are fitted on the garment's training touches only.

`auto` fits each of AUTO_CANDIDATES (`lift`, `shade-lift`) and keeps the one whose relief is closer to the garment's
validation touches (mean angle, as the held-out touches are scored), the cheaper one unless the other is closer by
AUTO_MARGIN. Why: the shading relief gains where the photo's weave shading carries the relief (KnitJacket) and costs
where it does not (SatinShirt's sheen), and the validation touches, which neither the training nor the fits see, tell
the two apart (docs/training.md, "Choosing the rule on the validation touches"). With no validation touch in the
crop it keeps the cheaper one and says so.
"""
from __future__ import annotations

import torch
from torch import nn

from trainer import calibration
from trainer.augment import eval_crop_origin
from trainer.data.touchclothing import Garment
from trainer.heldout import heldout_errors
from trainer.models.relief_gain import ReliefGain
from trainer.relief_rules import AUTO_CANDIDATES, RULES
from trainer.sampling import crop_tensors

# A costlier candidate must bring the validation touches' mean angle this much (relative) below the cheaper one's.
AUTO_MARGIN = 0.02


def calibrate(net: nn.Module, g: Garment, side: int, rule: str) -> tuple[nn.Module, dict, str]:
    """(the wrapped generator, its JSON-able fit, a one-line summary). Raises CalibrationError when the garment's
    training touches cannot fit it, ValueError for an unknown rule."""
    if rule not in RULES or rule == "none":
        raise ValueError(f"relief rule must be one of {', '.join(r for r in RULES if r != 'none')}; got {rule!r}")
    if rule == "auto":
        return _auto(net, g, side)
    if rule.startswith("shade"):
        from trainer.shading_fit import fit_shading

        fit = fit_shading(net, g, side, floor=1.0 if rule == "shade-lift" else None)
        return fit.wrap(net), {**fit.as_dict(), "rule": rule}, (
            f"{rule}: model x{fit.model_weight:.4f} + its photo's shading, from {fit.touches} training touches")
    fit = calibration.fit_relief_gain(net, g, side, rule)   # by module: one place to stand in for it in tests
    return ReliefGain(net, fit.gain).eval(), fit.as_dict(), f"{rule} x{fit.gain:.4f} from {fit.touches} training touches"


@torch.no_grad()
def validation_angle(net: nn.Module, g: Garment, side: int) -> float | None:
    """Mean angle (deg) of `net`'s relief on the garment's validation touches in the evaluation crop; None when
    none is in it."""
    origin = eval_crop_origin(g.mask, side)
    sketch, mask, _ = crop_tensors(g, origin, side)
    _, tac = net(sketch, mask)
    return heldout_errors(g, "val", origin, side, tac[0, 0].numpy(), tac[0, 1].numpy()).scores().get(
        "tactile_angle_deg")


def choose(angles: dict[str, float | None]) -> str:
    """The candidate to keep, from each fitted candidate's validation angle (in AUTO_CANDIDATES order, cheapest
    first): the cheapest, unless a costlier one is below the best so far by AUTO_MARGIN."""
    names = [c for c in AUTO_CANDIDATES if c in angles]
    best = names[0]
    for c in names[1:]:
        a, b = angles[c], angles[best]
        if a is not None and b is not None and a < (1 - AUTO_MARGIN) * b:
            best = c
    return best


def _auto(net: nn.Module, g: Garment, side: int) -> tuple[nn.Module, dict, str]:
    fitted, refused = {}, {}
    for c in AUTO_CANDIDATES:
        try:
            fitted[c] = calibrate(net, g, side, c)
        except calibration.CalibrationError as exc:
            refused[c] = str(exc)
    if not fitted:
        raise calibration.CalibrationError("auto: no candidate fits: " + "; ".join(refused.values()))
    angles = {c: validation_angle(w, g, side) for c, (w, _, _) in fitted.items()}
    pick = choose(angles)
    wrapped, info, line = fitted[pick]
    seen = ", ".join(f"{c} {a:.2f}" for c, a in angles.items() if a is not None) or "no validation touch in the crop"
    return wrapped, {**info, "rule": "auto", "chose": pick, "validation_angle_deg": angles,
                     **({"refused": refused} if refused else {})}, f"auto chose {line} (validation angle: {seen})"
