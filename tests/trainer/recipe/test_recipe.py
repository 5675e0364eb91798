"""Recipe pieces: the lr policy's shape, DiffAugment's contract, the weight average, the texture loss, and a
resumed run with every piece switched on continuing bit for bit."""
from __future__ import annotations

import json

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer.checkpoint import CheckpointError, load_generator
from trainer.config import ConfigError, load_config
from trainer.data.synthetic import generate_dataset
from trainer.loop import Trainer
from trainer.recipe.diffaug import DiffAugment, _translation, parse_policy
from trainer.recipe.ema import EMA
from trainer.recipe.schedule import apply_lr, lr_factor
from trainer.recipe.texture import TextureStatsLoss

torch.set_num_threads(2)
RECIPE = ["optim.lr_policy=linear", "loss.diffaug=color,translation,cutout", "train.ema=0.9",
          "loss.tactile_texture=5", "loss.visual_weave=10", "loss.tactile_shading=1", "model.weave_waves=2"]


@given(steps=st.integers(1, 5000), frac=st.floats(0, 1), data=st.data())
@settings(max_examples=200, deadline=None)
def test_linear_policy_holds_then_decays_monotonically(steps, frac, data):
    s = data.draw(st.integers(0, steps - 1))
    f = lr_factor("linear", s, steps, frac)
    assert 0.0 < f <= 1.0
    if s < round(frac * steps):
        assert f == 1.0
    if s + 1 < steps:
        assert lr_factor("linear", s + 1, steps, frac) <= f
    assert lr_factor("constant", s, steps, frac) == 1.0


def test_linear_policy_reaches_near_zero_and_apply_keeps_base_rates():
    assert lr_factor("linear", 999, 1000, 0.5) < 0.01
    p = torch.nn.Parameter(torch.zeros(1))
    opts = {"a": torch.optim.Adam([p], lr=1e-3), "b": torch.optim.Adam([p], lr=5e-4)}
    apply_lr(opts, 0.5)
    apply_lr(opts, 0.25)
    assert opts["a"].param_groups[0]["lr"] == pytest.approx(2.5e-4)
    assert opts["b"].param_groups[0]["lr"] == pytest.approx(1.25e-4)
    with pytest.raises(ValueError, match="unknown lr policy"):
        lr_factor("cosine", 0, 10, 0.5)


def test_diffaug_same_transform_for_paired_batches_and_differentiable():
    aug = DiffAugment("color,translation,cutout", rgb=slice(1, 4), seed=3)
    x = torch.randn(6, 5, 32, 32, requires_grad=True)
    a, b = aug(x, x.detach().clone())
    assert torch.equal(a, b) and not torch.equal(a, x)
    a.sum().backward()
    assert x.grad is not None and x.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="one size"):
        aug(torch.zeros(2, 5, 8, 8), torch.zeros(3, 5, 8, 8))


def test_diffaug_colour_touches_only_rgb_and_empty_policy_is_identity():
    aug = DiffAugment("color", rgb=slice(1, 4), seed=0)
    x = torch.randn(4, 6, 16, 16)
    (y,) = aug(x)
    assert torch.equal(y[:, 0], x[:, 0]) and torch.equal(y[:, 4:], x[:, 4:]) and not torch.equal(y[:, 1:4], x[:, 1:4])
    off = DiffAugment("", rgb=slice(1, 4))
    assert not off.active and torch.equal(off(x)[0], x)
    with pytest.raises(ValueError, match="unknown DiffAugment op"):
        parse_policy("color,flip")


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 4), c=st.integers(1, 7), h=st.integers(1, 20), w=st.integers(1, 20), seed=st.integers(0, 999))
def test_translation_is_a_zero_filled_shift_in_the_standard_layout(n, c, h, w, seed):
    """Each sample moves by its own integer offset, vacated pixels are 0, and the result is a plain NCHW tensor: the
    channels-last view the earlier indexing returned is what CUDA's avg_pool2d differentiated wrongly under R1."""
    x = torch.randn(n, c, h, w, dtype=torch.float64, requires_grad=True)
    y = _translation(x, torch.Generator().manual_seed(seed))
    assert y.shape == x.shape and y.is_contiguous()
    g = torch.Generator().manual_seed(seed)          # the same draws, in the same order
    sh, sw = max(1, int(h * 0.125 + 0.5)), max(1, int(w * 0.125 + 0.5))
    ty, tx = torch.randint(-sh, sh + 1, (n,), generator=g), torch.randint(-sw, sw + 1, (n,), generator=g)
    ref = torch.zeros_like(x)
    for i in range(n):
        dy, dx = int(ty[i]), int(tx[i])
        ys, xs = slice(max(0, dy), min(h, h + dy)), slice(max(0, dx), min(w, w + dx))
        yd, xd = slice(max(0, -dy), min(h, h - dy)), slice(max(0, -dx), min(w, w - dx))
        ref[i, :, ys, xs] = x[i, :, yd, xd]
    assert torch.equal(y, ref)
    weight = torch.randn_like(x)
    (gy,) = torch.autograd.grad((y * weight).sum(), x)
    (gr,) = torch.autograd.grad((ref * weight).sum(), x)
    assert torch.equal(gy, gr)


def test_diffaug_reseed_repeats():
    aug = DiffAugment("translation,cutout", rgb=None, seed=0)
    x = torch.randn(3, 2, 16, 16)
    aug.reseed(7)
    a = aug(x)[0]
    aug(x)
    aug.reseed(7)
    assert torch.equal(a, aug(x)[0])


def test_ema_tracks_with_warmup_and_refuses_bad_decay():
    net = torch.nn.Linear(2, 2)
    ema = EMA(net, 0.99)
    with torch.no_grad():
        net.weight.fill_(1.0)
    before = ema.model.weight.clone()
    for s in range(1, 2000):
        ema.update(net, s)
    assert torch.allclose(ema.model.weight, net.weight, atol=1e-3) and not torch.equal(before, net.weight)
    assert not any(p.requires_grad for p in ema.model.parameters())
    for bad in (0.0, 1.0, -0.5):
        with pytest.raises(ValueError):
            EMA(net, bad)


def test_ema_first_update_is_the_warmup_blend():
    net = torch.nn.Linear(1, 1, bias=False)
    with torch.no_grad():
        net.weight.fill_(0.0)
    ema = EMA(net, 0.999)
    with torch.no_grad():
        net.weight.fill_(1.0)
    ema.update(net, 0)
    assert ema.model.weight.item() == pytest.approx(0.9)       # d = 0.1 at step 0


@settings(max_examples=40, deadline=None)
@given(values=st.lists(st.floats(-10, 10, allow_nan=False), min_size=1, max_size=60))
def test_ema_ramp_two_is_the_plain_mean_of_every_step_so_far(values):
    """Ramp 2 gives d = (1 + s) / (2 + s): weight 1 / (s + 2) on step s's weights, the running mean with the initial
    weights as one more sample; the decay cap is far off for these few steps."""
    net = torch.nn.Linear(1, 1, bias=False)
    with torch.no_grad():
        net.weight.fill_(0.0)
    ema = EMA(net.double(), 0.9999, ramp=2.0)
    for s, v in enumerate(values):
        with torch.no_grad():
            net.weight.fill_(v)
        ema.update(net, s)
    assert ema.model.weight.item() == pytest.approx(sum(values) / (len(values) + 1), abs=1e-9)
    for bad in (1.0, 0.5, -3.0):
        with pytest.raises(ValueError, match="ramp"):
            EMA(net, 0.99, ramp=bad)


def test_a_probe_average_rides_along_resumes_and_scores_as_at_probe(synth, tmp_path):
    """A probe average changes nothing the run learns (its main average and raw weights equal a run without it), is
    a different average from the main one, resumes bit for bit, and is scored as RUN@probe beside the average."""
    def cfg(*extra):
        return load_config("tiny", overrides=["train.steps=4", "train.deterministic=true", "train.ckpt_every=2",
                                              "train.threads=1", "train.ema=0.999", *extra])
    plain = Trainer(cfg(), synth, tmp_path / "plain")
    plain.run()
    probed = Trainer(cfg("train.ema_probe_ramp=2"), synth, tmp_path / "probed")
    probed.run()
    for a, b in ((plain.method.generator, probed.method.generator), (plain.method.ema.model, probed.method.ema.model)):
        assert all(torch.equal(v, b.state_dict()[k]) for k, v in a.state_dict().items())
    probe = probed.method.ema_probe.model.state_dict()
    assert any(not torch.equal(v, probe[k]) for k, v in probed.method.ema.model.state_dict().items())
    part = Trainer(cfg("train.ema_probe_ramp=2"), synth, tmp_path / "part")
    part.run(until=2)
    resumed = Trainer(cfg("train.ema_probe_ramp=2"), synth, tmp_path / "part", resume=True)
    resumed.run()
    assert all(torch.equal(v, probe[k]) for k, v in resumed.method.ema_probe.model.state_dict().items())
    net, info = load_generator(tmp_path / "probed", "latest", "probe")
    assert info["weights"] == "probe" and all(torch.equal(v, probe[k]) for k, v in net.state_dict().items())
    with pytest.raises(CheckpointError, match="no probe average"):
        load_generator(tmp_path / "plain", "latest", "probe")
    from vtkiosk.cli import main as vtkiosk
    assert vtkiosk(["eval", "--run", f"{tmp_path / 'probed'}@probe", "--no-swap"]) == 0
    assert json.loads((tmp_path / "probed" / "eval" / "metrics-probe.json").read_text())["weights"] == "probe"


@pytest.mark.parametrize("overrides, message", [
    (["train.ema=0.999", "train.ema_ramp=1"], "train.ema_ramp must be > 1"),
    (["train.ema=0.999", "train.ema_probe_ramp=0.5"], "train.ema_probe_ramp is > 1, or 0"),
    (["train.ema=0", "train.ema_probe_ramp=3"], "needs train.ema"),
])
def test_bad_ema_ramps_are_refused_by_name(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_config("tiny", overrides=overrides)


def test_texture_loss_zero_on_equal_and_grows_with_contrast_error():
    t = TextureStatsLoss()
    g = torch.Generator().manual_seed(0)
    real = torch.randn(16, 2, 32, 32, generator=g)
    mask = torch.ones(16, 1, 32, 32)
    assert t(real, real, mask).item() == pytest.approx(0.0, abs=1e-6)
    errs = [t(real * k, real, mask).item() for k in (0.9, 0.6, 0.2)]
    assert errs[0] < errs[1] < errs[2]
    fake = (real * 0.5).requires_grad_(True)
    t(fake, real, mask).backward()
    assert torch.isfinite(fake.grad).all() and fake.grad.abs().sum() > 0
    assert torch.isfinite(t(real, real, torch.zeros_like(mask)))  # no contact at all: defined, no division by 0


def test_recipe_options_are_validated():
    for bad in ("optim.lr_policy=cosine", "optim.decay_from=1.5", "train.ema=1", "loss.tactile_texture=-1",
                "loss.visual_weave=-1", "loss.tactile_shading=-1", "loss.diffaug=color,warp", "model.weave_waves=-1",
                "model.weave_waves=33", "model.weave_waves_heads=tactile"):
        with pytest.raises(ConfigError):
            load_config("tiny", overrides=[bad])


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    generate_dataset(root, garments=1, seed=0, frame=(192, 144), progress=False)
    return next(p for p in root.iterdir() if p.is_dir())


def _same_state(full, resumed, *, nets=False):
    """An uninterrupted run and a resumed one end in the same weights (and discriminators) with the same losses."""
    a, b = full.method.state_dict(), resumed.method.state_dict()
    for key in ("generator", "ema"):
        for k, v in a[key].items():
            assert torch.equal(v, b[key][k]), (key, k)
    for name in a["nets"] if nets else ():
        for k, v in a["nets"][name].items():
            assert torch.equal(v, b["nets"][name][k]), (name, k)
    assert [h["g_total"] for h in full.history] == [h["g_total"] for h in resumed.history]


def test_resume_with_full_recipe_is_bit_identical_and_exports_the_average(synth, tmp_path):
    def cfg():
        return load_config("tiny", overrides=["train.steps=4", "train.deterministic=true", "train.ckpt_every=2",
                                              *RECIPE])
    full = Trainer(cfg(), synth, tmp_path / "full")
    full.run()
    part = Trainer(cfg(), synth, tmp_path / "part")
    part.run(until=2)
    resumed = Trainer(cfg(), synth, tmp_path / "part", resume=True)
    resumed.run()
    _same_state(full, resumed)
    assert "t_tex" in full.history[-1] and "v_weave" in full.history[-1] and "t_shade" in full.history[-1]
    assert full.history[-1]["lr_factor"] < 1.0
    net, _ = load_generator(tmp_path / "full", "latest")
    ema = full.method.ema.model.state_dict()
    assert all(torch.equal(v, ema[k]) for k, v in net.state_dict().items())
    raw = full.method.generator.state_dict()
    assert any(not torch.equal(v, raw[k]) for k, v in net.state_dict().items())
    raw_net, info = load_generator(tmp_path / "full", "latest", "raw")   # the EMA's ablation, from the same run
    assert info["weights"] == "raw"
    assert all(torch.equal(v, raw[k]) for k, v in raw_net.state_dict().items())


def test_a_stop_on_request_mid_interval_resumes_bit_for_bit_with_the_close_pair_recipe(synth, tmp_path):
    """The GPU table's `ours` runs stop at the lease's deadline (SIGTERM's flag) between checkpoints and resume in the
    next call; the stop must save a state the resume continues exactly, validation and sample sheets in between."""
    def cfg():
        return load_config("tiny", method="ours", overrides=[
            "train.steps=6", "train.deterministic=true", "train.ckpt_every=3", "train.val_every=2",
            "train.sample_every=2", "train.ema=0.999", "loss.tactile_r1=10", "loss.diffaug=color,translation,cutout"])
    full = Trainer(cfg(), synth, tmp_path / "full")
    full.run()
    part = Trainer(cfg(), synth, tmp_path / "part")
    part.run(should_stop=lambda: part.step >= 4)
    assert part.stopped and part.step == 4
    assert torch.load(tmp_path / "part" / "checkpoints" / "latest.pt", weights_only=False)["step"] == 4
    resumed = Trainer(cfg(), synth, tmp_path / "part", resume=True)
    resumed.run()
    _same_state(full, resumed, nets=True)
    assert any("d_tactile_r1" in h for h in full.history)   # the penalty ran: the double backward is resumed too


def test_raw_weights_need_the_training_state_and_a_known_name(synth, tmp_path):
    cfg = load_config("tiny", overrides=["train.steps=1", "train.threads=1"])
    Trainer(cfg, synth, tmp_path / "r").run()
    ck_path = tmp_path / "r" / "checkpoints" / "best.pt"
    with pytest.raises(CheckpointError, match="weights must be one of average, raw, probe"):
        load_generator(tmp_path / "r", "best", "ema")
    from vtkiosk.cli import main as vtkiosk
    assert vtkiosk(["eval", "--run", f"{tmp_path / 'r'}@raw", "--no-swap"]) == 0   # scored beside, never over
    assert json.loads((tmp_path / "r" / "eval" / "metrics-raw.json").read_text())["weights"] == "raw"
    assert "eval_raw" in json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert not (tmp_path / "r" / "eval" / "metrics.json").exists()
    ck = torch.load(ck_path, map_location="cpu", weights_only=False)
    del ck["train_state"]   # a compacted checkpoint (the catalogue's): its average still loads, raw is refused
    torch.save(ck, ck_path)
    load_generator(tmp_path / "r", "best")
    with pytest.raises(CheckpointError, match="no raw weights"):
        load_generator(tmp_path / "r", "best", "raw")
