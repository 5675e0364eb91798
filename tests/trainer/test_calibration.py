"""Relief calibration (trainer/calibration.py): the fitted gain undoes a known shrink of the relief exactly, only the
training touches are read, a flat or touch-less case is refused without a division by zero, and the wrapper scales
the tactile output of every graph kind and nothing else."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import nn

from trainer.augment import eval_crop_origin
from trainer.calibration import GAIN_RANGE, CalibrationError, fit_relief_gain, touch_pixels
from trainer.compare import RunSpec, parse_labelled, parse_run
from trainer.eval_cache import _paths
from trainer.models.relief_gain import ReliefGain

SIDE = 256


class FieldNet(nn.Module):
    """A stand-in generator with a fixed output (the calibration reads outputs only): visual zeros, tactile `field`."""

    def __init__(self, field: np.ndarray):
        super().__init__()
        self.field = torch.from_numpy(field.astype(np.float32))[None]

    def forward(self, sketch, mask, kind="full"):
        vis = torch.zeros(1, 3, *self.field.shape[-2:])
        return {"full": (vis, self.field), "visual": vis, "tactile": self.field}[kind]


def touch_field(g, split="train", scale=1.0, noise=0.0, seed=0):
    """(2, S, S): the split's measured slopes pasted where its touches lie in the evaluation crop, times `scale`."""
    f = np.zeros((2, SIDE, SIDE))
    for yy, xx, gx, gy in touch_pixels(g, eval_crop_origin(g.mask, SIDE), SIDE, split):
        f[0, yy, xx], f[1, yy, xx] = gx, gy
    return f * scale + np.random.default_rng(seed).normal(0, noise, f.shape)


def test_the_touches_in_the_crop_are_found(easy_garment):
    found = touch_pixels(easy_garment, eval_crop_origin(easy_garment.mask, SIDE), SIDE)
    assert found and sum(len(f[0]) for f in found) > 256
    for yy, xx, gx, gy in found:
        assert len(yy) == len(xx) == len(gx) == len(gy) and yy.min() >= 0 and xx.max() < SIDE


@settings(max_examples=15, deadline=None)
@given(shrink=st.floats(0.3, 3.0))
def test_a_known_shrink_is_undone_exactly_by_both_rules(easy_garment, shrink):
    net = FieldNet(touch_field(easy_garment, scale=shrink))
    for rule in ("rms", "ls"):
        fit = fit_relief_gain(net, easy_garment, SIDE, rule)
        # exact but for the few pixels where two touches overlap (the field holds one of their two readings)
        assert fit.gain == pytest.approx(1.0 / shrink, rel=1e-3)
        assert fit.rule == rule and fit.touches >= 1


def test_misplaced_bumps_get_a_smaller_least_squares_gain(easy_garment):
    """Noise of the touches' own strength, uncorrelated with them: rms keeps the energy, ls discounts it."""
    f = touch_field(easy_garment)
    rms = float(np.sqrt(np.mean(f[f != 0] ** 2)))
    net = FieldNet(touch_field(easy_garment, scale=0.5, noise=0.5 * rms, seed=3))
    g_rms = fit_relief_gain(net, easy_garment, SIDE, "rms").gain
    g_ls = fit_relief_gain(net, easy_garment, SIDE, "ls").gain
    assert g_ls < g_rms and 1.0 < g_rms < 2.0


@settings(max_examples=15, deadline=None)
@given(shrink=st.floats(0.3, 3.0), noise=st.floats(0.0, 0.5))
def test_lift_is_the_least_squares_gain_floored_at_one(easy_garment, shrink, noise):
    """It gives a shrunken relief its strength back as ls does, and where ls would flatten it (a relief too strong,
    or bumps misplaced) it leaves it as trained."""
    f = touch_field(easy_garment)
    rms = float(np.sqrt(np.mean(f[f != 0] ** 2)))
    net = FieldNet(touch_field(easy_garment, scale=shrink, noise=noise * rms, seed=3))
    ls, lift = fit_relief_gain(net, easy_garment, SIDE, "ls"), fit_relief_gain(net, easy_garment, SIDE, "lift")
    assert lift.rule == "lift" and (lift.pixels, lift.touches) == (ls.pixels, ls.touches)
    assert lift.gain == max(ls.gain, 1.0)
    if shrink < 0.9 and noise == 0.0:
        assert lift.gain == pytest.approx(1.0 / shrink, rel=1e-3)
    if shrink > 1.1:
        assert lift.gain == 1.0


def test_only_training_touches_are_read(easy_garment):
    """Two models that agree on the training touches' pixels and nowhere else (not on the held-out touches either)
    get the same gain."""
    base = touch_field(easy_garment, scale=0.7)
    seen = np.zeros((SIDE, SIDE), bool)
    for yy, xx, _, _ in touch_pixels(easy_garment, eval_crop_origin(easy_garment.mask, SIDE), SIDE, "train"):
        seen[yy, xx] = True
    other = np.where(seen, base, np.random.default_rng(5).normal(0, 3.0, base.shape))
    assert np.abs(other - base).max() > 1.0
    for rule in ("rms", "ls"):
        assert fit_relief_gain(FieldNet(other), easy_garment, SIDE, rule).gain == \
            pytest.approx(fit_relief_gain(FieldNet(base), easy_garment, SIDE, rule).gain, rel=1e-9)


@pytest.mark.parametrize("rule", ["rms", "ls", "lift"])
def test_a_flat_model_is_refused_without_dividing_by_zero(easy_garment, rule):
    with np.errstate(all="raise"):
        with pytest.raises(CalibrationError, match="undefined"):
            fit_relief_gain(FieldNet(np.zeros((2, SIDE, SIDE))), easy_garment, SIDE, rule)


def test_a_gain_beyond_the_range_is_refused(easy_garment):
    net = FieldNet(touch_field(easy_garment, scale=1.0 / (GAIN_RANGE[1] * 1.5)))
    with pytest.raises(CalibrationError, match="outside"):
        fit_relief_gain(net, easy_garment, SIDE, "rms")


def test_anti_correlated_relief_gets_no_least_squares_gain(easy_garment):
    with pytest.raises(CalibrationError, match="outside"):
        fit_relief_gain(FieldNet(touch_field(easy_garment, scale=-1.0)), easy_garment, SIDE, "ls")


def test_no_touches_in_the_crop_is_refused(easy_garment):
    bare = type(easy_garment).__new__(type(easy_garment))
    bare.__dict__.update(easy_garment.__dict__)
    bare.touches = {**easy_garment.touches, "train": []}
    with pytest.raises(CalibrationError, match="contact pixels"):
        fit_relief_gain(FieldNet(touch_field(easy_garment)), bare, SIDE, "rms")


def test_unknown_rule_is_an_error(easy_garment):
    for rule in ("none", "max"):
        with pytest.raises(ValueError, match="relief rule"):
            fit_relief_gain(FieldNet(touch_field(easy_garment)), easy_garment, SIDE, rule)


def test_the_wrapper_scales_the_tactile_output_of_every_kind_only():
    field = np.random.default_rng(0).normal(size=(2, 8, 8))
    net = ReliefGain(FieldNet(field), 1.5)
    vis, tac = net(None, None)
    assert torch.equal(vis, torch.zeros_like(vis))
    assert torch.allclose(tac, torch.from_numpy(field.astype(np.float32))[None] * 1.5)
    assert torch.allclose(net(None, None, "tactile"), tac)
    assert torch.equal(net(None, None, "visual"), vis)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="positive finite"):
            ReliefGain(FieldNet(field), bad)


def test_run_arguments_name_the_relief():
    assert parse_run("runs/a@rms") == RunSpec(Path_("runs/a"), "average", "rms")
    assert parse_run("runs/a@raw@ls") == parse_run("runs/a@ls@raw") == RunSpec(Path_("runs/a"), "raw", "ls")
    assert parse_run("runs/a", relief="rms") == RunSpec(Path_("runs/a"), "average", "rms")
    assert parse_run("runs/a@ls", relief="rms").relief == "ls"   # a run's own suffix wins over the flag's
    assert parse_run("runs/a@flip+transpose-energy@lift").relief == "lift"
    assert str(RunSpec(Path_("runs/a"), "raw", "rms")) == "runs/a@raw@rms"
    for bad in ("runs/a@raw@raw", "runs/a@rms@rms", "runs/a@ls@rms", "@rms", "runs/a@none", "runs/a@big"):
        with pytest.raises(ValueError):
            parse_run(bad)
    runs, labels = parse_labelled(["x=runs/a@rms", "runs/a"], relief="none")
    assert runs == [RunSpec(Path_("runs/a"), relief="rms"), RunSpec(Path_("runs/a"))]
    assert labels == {RunSpec(Path_("runs/a"), relief="rms"): "x"}


def test_calibrated_scores_are_stored_apart(tmp_path):
    names = {_paths(tmp_path, "latest", w, r)[0].name
             for w in ("average", "raw") for r in ("none", "rms", "ls", "lift")}
    assert len(names) == 8 and "compare-latest.json" in names and "compare-latest-raw-rms.json" in names


def Path_(s):
    from pathlib import Path
    return Path(s)


def test_both_command_lines_offer_exactly_the_rules():
    """The CLIs keep torch out of --help, so they read the rules from trainer.relief_rules; every rule is offered and
    the default is the model as trained."""
    from exporter.cli import build_parser as export_parser
    from trainer.eval_cli import build_parser as eval_parser
    from trainer.relief_rules import RULES
    for parser in (eval_parser("eval"), export_parser("export")):
        action = next(a for a in parser._actions if "--relief" in a.option_strings)
        assert tuple(action.choices) == RULES and action.default == "none"
