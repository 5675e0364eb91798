"""Learning-rate policy: held, then decayed linearly to zero (the authors' `lr_policy linear`).

Their runs hold the rate for `n_epochs` and decay it over `n_epochs_decay` of equal length, i.e. the decay starts
half way. `optim.decay_from` is that point as a fraction of the schedule, so a shortened CPU schedule keeps the
same shape.
"""
from __future__ import annotations

import torch

POLICIES = ("constant", "linear")


def lr_factor(policy: str, step: int, steps: int, decay_from: float) -> float:
    """Multiplier of every optimizer's base rate before optimisation step `step` (0-based) of `steps`."""
    if policy == "constant":
        return 1.0
    if policy != "linear":
        raise ValueError(f"unknown lr policy {policy!r}; choose one of {', '.join(POLICIES)}")
    start = int(round(decay_from * steps))
    span = steps - start
    if step < start or span <= 0:
        return 1.0
    # (steps - step) / (span + 1): the last step still moves a little, and the rate never reaches a negative value
    return max(0.0, (steps - step) / (span + 1))


def apply_lr(opts: dict[str, torch.optim.Optimizer], factor: float) -> None:
    """Set every param group's rate to its base rate x factor (the base is kept in the group as `initial_lr`)."""
    for opt in opts.values():
        for group in opt.param_groups:
            group.setdefault("initial_lr", group["lr"])
            group["lr"] = group["initial_lr"] * factor
