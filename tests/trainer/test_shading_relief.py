"""The shading relief (trainer/shading_fit.py, trainer/models/shading_relief.py): read from a photo lit like the
easy_garment, it finds relief the model never had off the touches; its weights come from the training touches only; it
never divides by a data-dependent zero; the wrapper keeps every graph kind's contract."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer.augment import eval_crop_origin
from trainer.calibration import CalibrationError, touch_pixels
from trainer.metrics import angle_map
from trainer.models.shading_relief import ShadingRelief, filter_bank, log_luminance, shading_slopes
from trainer.relief import calibrate
from trainer.sampling import crop_tensors
from trainer.shading_fit import fit_shading, solve

SIDE = 256


class PhotoNet(torch.nn.Module):
    """A stand-in generator: the garment's own photo as its visual output, `tactile` (2, S, S) as its relief."""

    def __init__(self, g, tactile: np.ndarray):
        super().__init__()
        _, mask, vis = crop_tensors(g, eval_crop_origin(g.mask, SIDE), SIDE)
        self.vis, self.mask = vis, mask
        self.tac = torch.from_numpy(tactile.astype(np.float32))[None] * mask

    def forward(self, sketch, mask, kind="full"):
        return {"full": (self.vis, self.tac), "visual": self.vis, "tactile": self.tac}[kind]


def touch_field(g, scale=1.0, noise=0.0, seed=0):
    """(2, S, S): the training touches' slopes where they lie in the evaluation crop, times `scale`, plus noise."""
    f = np.zeros((2, SIDE, SIDE))
    for yy, xx, gx, gy in touch_pixels(g, eval_crop_origin(g.mask, SIDE), SIDE, "train"):
        f[0, yy, xx], f[1, yy, xx] = gx, gy
    return f * scale + np.random.default_rng(seed).normal(0, noise, f.shape)


def _outside_angle(g, gx, gy) -> float:
    origin = eval_crop_origin(g.mask, SIDE)
    x, y = origin
    ft = g.full_tactile
    crop = (slice(y, y + SIDE), slice(x, x + SIDE))
    seen = np.zeros((SIDE, SIDE), bool)
    for yy, xx, _, _ in touch_pixels(g, origin, SIDE, "train"):
        seen[yy, xx] = True
    out = g.mask[crop] & ~seen
    return float(angle_map(gx, gy, ft.gx[crop], ft.gy[crop])[out].mean())


def _coarse_truth(g) -> np.ndarray:
    """(2, S, S): the full-field truth on the evaluation crop without its fine relief (Gaussian, 3 px): a model that
    knows every fold and seam and no weave, right on the touches and off them alike."""
    x, y = eval_crop_origin(g.mask, SIDE)
    ft = g.full_tactile
    return np.stack([cv2.GaussianBlur(a[y:y + SIDE, x:x + SIDE].astype(np.float64), (0, 0), 3.0)
                     for a in (ft.gx, ft.gy)])


def _shaded_outside(g, net) -> tuple[float, object]:
    fit = fit_shading(net, g, SIDE)
    with torch.no_grad():
        _, tac = fit.wrap(net)(net.vis, net.mask)
    tac = tac[0].numpy()
    return _outside_angle(g, tac[0], tac[1]), fit


def test_the_photo_gives_back_the_fine_relief_a_coarse_model_lacks(easy_garment):
    """The garment's own photo beside a model with no fine relief: fitted on the training touches only, the mix is
    nearer the truth off those touches than the model alone, by a margin (measured: 8.9 -> 6.0 deg)."""
    coarse = _coarse_truth(easy_garment)
    net = PhotoNet(easy_garment, coarse)
    shaded, fit = _shaded_outside(easy_garment, net)
    assert shaded < 0.8 * _outside_angle(easy_garment, coarse[0], coarse[1])
    assert fit.touches >= 1 and fit.pixels >= 256 and len(fit.weights) == len(filter_bank())


@settings(max_examples=6, deadline=None)
@given(light=st.floats(0.0, 2 * np.pi))
def test_a_photo_lit_from_any_side_is_integrated_back(easy_garment, light):
    """A photo that is exactly the relief's shading under a lamp from direction `light`: the filters' directions and
    weights find it whatever the lamp's side (measured over 48 directions: 8.9 -> 2.7-5.2 deg)."""
    coarse = _coarse_truth(easy_garment)
    x, y = eval_crop_origin(easy_garment.mask, SIDE)
    ft = easy_garment.full_tactile
    gx, gy = (a[y:y + SIDE, x:x + SIDE].astype(np.float64) for a in (ft.gx, ft.gy))
    lit = 0.5 * np.exp(-0.3 * (np.cos(light) * gx + np.sin(light) * gy))
    net = PhotoNet(easy_garment, coarse)
    net.vis = torch.from_numpy(np.clip(2 * lit - 1, -1, 1).astype(np.float32))[None, None].repeat(1, 3, 1, 1)
    net.vis = net.vis * net.mask
    shaded, _ = _shaded_outside(easy_garment, net)
    assert shaded < 0.65 * _outside_angle(easy_garment, coarse[0], coarse[1])


def test_only_training_touches_are_read(easy_garment):
    """Two models that agree on the training touches' pixels and nowhere else get the same weights."""
    rng = np.random.default_rng(5)
    base = touch_field(easy_garment, scale=0.5, noise=0.05, seed=5)
    seen = np.zeros((SIDE, SIDE), bool)
    for yy, xx, _, _ in touch_pixels(easy_garment, eval_crop_origin(easy_garment.mask, SIDE), SIDE, "train"):
        seen[yy, xx] = True
    other = np.where(seen, base, rng.normal(0, 1.0, base.shape))
    a, b = fit_shading(PhotoNet(easy_garment, base), easy_garment, SIDE), fit_shading(PhotoNet(easy_garment, other), easy_garment, SIDE)
    assert a.model_weight == pytest.approx(b.model_weight, rel=1e-6)
    assert np.allclose(a.weights, b.weights, rtol=1e-5, atol=1e-9)


def test_no_touches_or_an_unrelated_model_is_refused(easy_garment):
    bare = type(easy_garment).__new__(type(easy_garment))
    bare.__dict__.update(easy_garment.__dict__)
    bare.touches = {**easy_garment.touches, "train": []}
    with pytest.raises(CalibrationError, match="contact pixels"):
        fit_shading(PhotoNet(easy_garment, touch_field(easy_garment)), bare, SIDE)
    with pytest.raises(CalibrationError, match="unrelated"):   # a flat model has no relief to weigh
        fit_shading(PhotoNet(easy_garment, np.zeros((2, SIDE, SIDE))), easy_garment, SIDE)
    # the model's relief is the touches' upside down: it would get a negative weight
    anti = np.zeros((2, SIDE, SIDE))
    for yy, xx, gx, gy in touch_pixels(easy_garment, eval_crop_origin(easy_garment.mask, SIDE), SIDE, "train"):
        anti[0, yy, xx], anti[1, yy, xx] = -gx, -gy
    for floor in (None, 1.0):   # shade-lift too: the weight is judged before the floor lifts it
        with pytest.raises(CalibrationError, match="unrelated"):
            fit_shading(PhotoNet(easy_garment, anti), easy_garment, SIDE, floor=floor)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(40, 200), k=st.integers(1, 6), seed=st.integers(0, 10_000))
def test_solve_recovers_exact_weights_and_leaves_dead_columns_at_zero(n, k, seed):
    rng = np.random.default_rng(seed)
    cols = rng.normal(0, 1, (n, k + 1))
    cols[:, -1] = 0.0                        # a dead column (a flat photo)
    w = rng.normal(0, 1, k + 1)
    w[-1] = 0.0
    with np.errstate(all="raise"):
        got = solve(cols, cols @ w, ridge=0.0)
        assert np.allclose(got, w, atol=1e-6)
        assert got[-1] == 0.0
        shrunk = solve(cols, cols @ w, ridge=10.0)
        assert np.isfinite(shrunk).all() and abs(shrunk[1:]).sum() < abs(w[1:]).sum() + 1e-9
        assert (solve(np.zeros((n, k)), rng.normal(0, 1, n)) == 0).all()


@settings(max_examples=20, deadline=None)
@given(level=st.floats(-1.0, 1.0), hole=st.booleans(), seed=st.integers(0, 1000))
def test_the_photo_term_is_finite_on_black_white_and_empty_inputs(level, hole, seed):
    """A black or saturated photo, or no object at all: finite, and 0 off the object."""
    rng = np.random.default_rng(seed)
    vis = torch.full((1, 3, 64, 64), level) + torch.from_numpy(rng.normal(0, 0.01, (1, 3, 64, 64)).astype(np.float32))
    vis = vis.clamp(-1, 1)
    mask = torch.zeros(1, 1, 64, 64)
    if not hole:
        mask[..., 10:50, 12:40] = 1
    bank = torch.from_numpy(filter_bank())
    lum = log_luminance(vis, mask)
    out = shading_slopes(vis, mask, bank)
    assert torch.isfinite(lum).all() and torch.isfinite(out).all()
    assert (out * (1 - mask) == 0).all()


@settings(max_examples=20, deadline=None)
@given(level=st.floats(-0.95, 0.95), seed=st.integers(0, 1000))
def test_a_uniform_object_of_any_shape_and_brightness_reads_no_slope_at_its_silhouette(level, seed):
    """The fill reaches as far as the filters do: a silhouette is no cliff (KERNEL and FILL_SIGMA kept in step), and
    what lies on the background never reaches the object."""
    rng = np.random.default_rng(seed)
    mask = torch.from_numpy(cv2.GaussianBlur(rng.random((64, 64)), (0, 0), 4.0) > 0.5).float()[None, None]
    vis = torch.full((1, 3, 64, 64), level)
    vis = vis * mask + torch.from_numpy(rng.uniform(-1, 1, (1, 3, 64, 64)).astype(np.float32)) * (1 - mask)
    out = shading_slopes(vis, mask, torch.from_numpy(filter_bank()))
    assert out.abs().max() < 1e-4


def test_the_bank_is_finite_odd_and_zero_mean():
    """Zero mean: a photo's uniform brightness (the lamp's level, the dye's shade) is no slope."""
    bank = filter_bank()
    assert bank.shape[1] == 2 and bank.shape[2] == bank.shape[3] and bank.shape[2] % 2 == 1
    assert np.isfinite(bank).all() and np.abs(bank.sum((2, 3))).max() < 1e-3 * np.abs(bank).sum((2, 3)).max()


def test_the_wrapper_keeps_each_graph_kind_and_rejects_bad_kernels(easy_garment):
    net = PhotoNet(easy_garment, touch_field(easy_garment, scale=0.5, noise=0.05))
    fit = fit_shading(net, easy_garment, SIDE)
    wrapped = fit.wrap(net)
    with torch.no_grad():
        vis, tac = wrapped(net.vis, net.mask, "full")
        assert torch.equal(vis, net.vis)
        assert torch.equal(wrapped(net.vis, net.mask, "tactile"), tac)
        assert torch.equal(wrapped(net.vis, net.mask, "visual"), vis)
    assert (tac * (1 - net.mask) == 0).all() and torch.isfinite(tac).all()
    for bad in (np.full((2, 5, 5), np.nan), np.zeros((2, 4, 4)), np.zeros((3, 5, 5))):
        with pytest.raises(ValueError, match="kernel"):
            ShadingRelief(net, 1.0, bad)
    with pytest.raises(ValueError, match="model weight"):
        ShadingRelief(net, float("inf"), np.zeros((2, 5, 5)))


def test_calibrate_names_the_rule_and_its_fit(easy_garment):
    net = PhotoNet(easy_garment, touch_field(easy_garment, scale=0.5, noise=0.05, seed=1))
    wrapped, info, line = calibrate(net, easy_garment, SIDE, "shade")
    assert isinstance(wrapped, ShadingRelief) and info["rule"] == "shade" and line.startswith("shade: model x")
    with pytest.raises(ValueError, match="relief rule"):
        calibrate(net, easy_garment, SIDE, "none")


@settings(max_examples=25, deadline=None)
@given(n=st.integers(40, 200), k=st.integers(1, 5), model=st.floats(-0.5, 3.0), seed=st.integers(0, 10_000))
def test_a_floored_model_weight_never_falls_below_the_floor(n, k, model, seed):
    """shade-lift: an unconstrained model weight at or above 1 is kept as found; below 1 it is held at 1 and the
    other weights explain what is left."""
    rng = np.random.default_rng(seed)
    cols = rng.normal(0, 1, (n, k + 1))
    w = np.concatenate([[model], rng.normal(0, 1, k)])
    target = cols @ w
    free, floored = solve(cols, target, ridge=0.0), solve(cols, target, ridge=0.0, floor=1.0)
    assert floored[0] >= 1.0
    if free[0] >= 1.0:
        assert np.array_equal(free, floored)
    else:
        assert floored[0] == 1.0
        rest = solve(np.concatenate([np.zeros((n, 1)), cols[:, 1:]], 1), target - cols[:, 0], ridge=0.0)
        assert np.allclose(floored[1:], rest[1:])


def test_shade_lift_names_itself_and_keeps_the_relief_at_full_strength(easy_garment):
    """A model whose relief is twice the touches' would get weight 1/2 under `shade`; `shade-lift` keeps 1."""
    net = PhotoNet(easy_garment, touch_field(easy_garment, scale=2.0))
    _, free, _ = calibrate(net, easy_garment, SIDE, "shade")
    wrapped, info, line = calibrate(net, easy_garment, SIDE, "shade-lift")
    assert free["model_weight"] < 0.9 and info["model_weight"] == 1.0
    assert info["rule"] == "shade-lift" and line.startswith("shade-lift: model x1.0000")


def _exact_truth(g) -> np.ndarray:
    x, y = eval_crop_origin(g.mask, SIDE)
    return np.stack([a[y:y + SIDE, x:x + SIDE].astype(np.float64) for a in (g.full_tactile.gx, g.full_tactile.gy)])


@pytest.mark.parametrize("field, chosen", [(_coarse_truth, "shade-lift"), (_exact_truth, "lift")])
def test_auto_keeps_the_shading_only_where_the_validation_touches_want_it(easy_garment, field, chosen):
    """A model with no weave gains from its photo's shading on touches no fit saw, so `auto` keeps `shade-lift`; a
    model already right there gains nothing, so the cheaper `lift` stays. What it keeps is that rule's own wrap."""
    net = PhotoNet(easy_garment, field(easy_garment))
    wrapped, info, line = calibrate(net, easy_garment, SIDE, "auto")
    angles = info["validation_angle_deg"]
    assert info["rule"] == "auto" and info["chose"] == chosen and set(angles) == {"lift", "shade-lift"}
    assert line.startswith(f"auto chose {chosen}") and "validation angle: lift" in line
    own, _, _ = calibrate(net, easy_garment, SIDE, chosen)
    with torch.no_grad():
        assert torch.equal(wrapped(net.vis, net.mask)[1], own(net.vis, net.mask)[1])
    if chosen == "shade-lift":
        assert angles["shade-lift"] < 0.98 * angles["lift"]


def test_auto_with_no_validation_touch_keeps_the_cheaper_rule(easy_garment):
    bare = type(easy_garment).__new__(type(easy_garment))
    bare.__dict__.update(easy_garment.__dict__)
    bare.touches = {**easy_garment.touches, "val": []}
    _, info, line = calibrate(PhotoNet(bare, _coarse_truth(bare)), bare, SIDE, "auto")
    assert info["chose"] == "lift" and info["validation_angle_deg"] == {"lift": None, "shade-lift": None}
    assert "no validation touch in the crop" in line


def test_auto_takes_the_rule_that_fits_and_refuses_when_none_does(easy_garment, monkeypatch):
    from trainer import calibration, shading_fit

    def refuse(*a, **k):
        raise CalibrationError("stood in: refused")

    net = PhotoNet(easy_garment, _coarse_truth(easy_garment))
    monkeypatch.setattr(calibration, "fit_relief_gain", refuse)
    _, info, _ = calibrate(net, easy_garment, SIDE, "auto")
    assert info["chose"] == "shade-lift" and info["refused"] == {"lift": "stood in: refused"}
    monkeypatch.setattr(shading_fit, "fit_shading", refuse)
    with pytest.raises(CalibrationError, match="auto: no candidate fits"):
        calibrate(net, easy_garment, SIDE, "auto")


@settings(max_examples=100, deadline=None)
@given(cheap=st.one_of(st.none(), st.floats(0, 90)), dear=st.one_of(st.none(), st.floats(0, 90)),
       fitted=st.sampled_from([("lift", "shade-lift"), ("lift",), ("shade-lift",)]))
def test_the_choice_keeps_the_cheaper_rule_unless_the_other_is_clearly_closer(cheap, dear, fitted):
    from trainer.relief import AUTO_MARGIN, choose

    angles = {k: v for k, v in (("lift", cheap), ("shade-lift", dear)) if k in fitted}
    pick = choose(angles)
    assert pick in fitted
    if len(fitted) == 2:
        clearly = cheap is not None and dear is not None and dear < (1 - AUTO_MARGIN) * cheap
        assert pick == ("shade-lift" if clearly else "lift")
