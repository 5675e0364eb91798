"""Loss wiring, including the three defects of the published code that we fix."""
from __future__ import annotations

import logging

import pytest
import torch
from torch import nn

from trainer.config import load_config
from trainer.data.synthetic import generate_dataset
from trainer.losses.perceptual import Perceptual, VGG16Features
from trainer.methods import get_method
from trainer.sampling import GarmentData

torch.set_num_threads(2)


@pytest.fixture(scope="module")
def garment(tmp_path_factory):
    return generate_dataset(tmp_path_factory.mktemp("synth"), garments=1, seed=0, frame=(192, 144),
                            progress=False)[0]


def _setup(garment, method="ours", overrides=()):
    cfg = load_config("tiny", method=method, overrides=list(overrides))
    torch.manual_seed(0)
    data = GarmentData(garment, cfg.data)
    m = get_method(method)(cfg, side=data.side)
    return m, data.batch(0)


def _grad_norm(module: nn.Module) -> float:
    return sum(float(p.grad.abs().sum()) for p in module.parameters() if p.grad is not None)


def test_tactile_gan_trains_tactile_branch_but_not_visual_branch(garment):
    m, b = _setup(garment)
    vis, tac = m.generator(b.sketch, b.mask)
    terms = m.generator_losses(b, vis, tac)
    m.generator.zero_grad()
    terms["t_gan"].backward()
    assert _grad_norm(m.generator.tactile) > 0        # the published code detached this term: zero here
    assert _grad_norm(m.generator.visual) == 0        # paper: no gradient into G_I from the tactile D
    assert _grad_norm(m.generator.downs) > 0          # the shared encoder learns from touch too


@pytest.mark.parametrize("shown", ["generated", "real", "none"])
def test_tactile_d_conditioning(garment, shown):
    m, b = _setup(garment, overrides=[f"loss.tactile_d_visual={shown}", "loss.unpaired_contact=borrowed"])
    vis, tac = m.generator(b.sketch, b.mask)
    real, fake, unpaired = m.tactile_inputs(b, vis, tac)
    # sketch and contact channels always match between a real patch and its fake twin
    assert torch.equal(real[:, 2:3], fake[:, 2:3]) and torch.equal(real[:, 6:], fake[:, 6:])
    same_visual = torch.equal(real[:, 3:6], fake[:, 3:6])
    assert same_visual == (shown in ("real", "none"))
    if shown == "none":   # no colour anywhere: D cannot link the tactile channels to the print
        assert not real[:, 3:6].any() and not fake[:, 3:6].any() and not unpaired[:, 3:6].any()
    # borrowed contact: unpaired patch i wears paired patch i's sensor footprint, cut to the object
    k = len(b.contact)
    assert len(unpaired) > 0
    for i in range(len(unpaired)):
        x, y = b.unpaired[i]
        obj = b.mask[0, :, y:y + 32, x:x + 32]
        assert torch.equal(unpaired[i, 6:], b.contact[i % k] * obj)
        assert torch.equal(unpaired[i, :2], tac[0, :, y:y + 32, x:x + 32] * b.contact[i % k] * obj)


def test_unpaired_contact_object_is_the_object_mask(garment):
    m, b = _setup(garment, overrides=["loss.unpaired_contact=object"])
    vis, tac = m.generator(b.sketch, b.mask)
    _, _, unpaired = m.tactile_inputs(b, vis, tac)
    x, y = b.unpaired[0]
    assert torch.equal(unpaired[0, 6:], b.mask[0, :, y:y + 32, x:x + 32])


def test_tactile_d_options_are_validated():
    from trainer.config import ConfigError
    with pytest.raises(ConfigError, match="loss.tactile_d_visual must be one of generated, real, none; got .ground-truth."):
        load_config("tiny", overrides=["loss.tactile_d_visual=ground-truth"])
    with pytest.raises(ConfigError, match="data.unpaired_sampling must be one of laplacian, uniform"):
        load_config("tiny", overrides=["data.unpaired_sampling=grid"])


def test_r1_penalty_is_the_squared_input_gradient_of_the_logits():
    from trainer.losses.gan import r1_penalty
    torch.manual_seed(0)
    w = torch.randn(1, 3, 4, 4)
    x = torch.randn(5, 3, 4, 4, requires_grad=True)
    logits = (x * w).sum((1, 2, 3)).view(5, 1, 1, 1) + (x ** 2).sum((1, 2, 3)).view(5, 1, 1, 1)
    # d/dx = w + 2x per sample; penalty = mean over samples of |w + 2x|^2
    expected = (w + 2 * x).pow(2).flatten(1).sum(1).mean()
    got = r1_penalty([[logits]], x)
    assert torch.allclose(got, expected)
    got.backward()                                     # create_graph: the penalty itself is differentiable
    assert torch.allclose(x.grad, (4 * (w + 2 * x) / 5).detach())


def test_tactile_r1_trains_the_tactile_d_and_is_logged(garment):
    plain, b = _setup(garment, overrides=["loss.tactile_r1=0"])     # the published loss
    m, _ = _setup(garment, overrides=["loss.tactile_r1=10"])
    logs = m.step(b, 0)
    assert logs["d_tactile_r1"] > 0
    # same seed, same batch: the R1 term changes what the tactile D learns, nothing else in the D loss
    plain_logs = plain.step(b, 0)
    assert "d_tactile_r1" not in plain_logs and logs["d_tactile"] == pytest.approx(plain_logs["d_tactile"])
    moved = [not torch.equal(p, q) for p, q in zip(m.nets["DT"].parameters(), plain.nets["DT"].parameters())]
    assert any(moved)


def test_tactile_gan_ramp_scales_the_generator_term(garment):
    m, _ = _setup(garment, overrides=["loss.tactile_gan_ramp=0.5", "train.steps=100"])
    w = m.cfg.loss.tactile_gan
    assert [m.tactile_gan_weight(s) for s in (0, 25, 50, 99)] == [0.0, w / 2, w, w]
    flat, _ = _setup(garment)
    assert flat.tactile_gan_weight(0) == w


def test_tactile_gan_stabilisers_are_validated():
    from trainer.config import ConfigError
    with pytest.raises(ConfigError, match="loss.tactile_r1 must be >= 0"):
        load_config("tiny", overrides=["loss.tactile_r1=-1"])
    with pytest.raises(ConfigError, match="loss.tactile_gan_ramp is a fraction"):
        load_config("tiny", overrides=["loss.tactile_gan_ramp=2"])


def test_visual_losses_do_not_reach_tactile_branch(garment):
    m, b = _setup(garment)
    vis, tac = m.generator(b.sketch, b.mask)
    terms = m.generator_losses(b, vis, tac)
    m.generator.zero_grad()
    (terms["v_gan"] + terms["v_l1"]).backward()
    assert _grad_norm(m.generator.visual) > 0 and _grad_norm(m.generator.tactile) == 0


@pytest.mark.parametrize("term", ["v_fm", "t_fm"])
def test_feature_matching_is_active_and_has_gradient(garment, term):
    m, b = _setup(garment)
    vis, tac = m.generator(b.sketch, b.mask)
    terms = m.generator_losses(b, vis, tac)
    assert term in terms and terms[term].item() > 0
    m.generator.zero_grad()
    terms[term].backward()
    assert _grad_norm(m.generator) > 0


def test_generator_step_leaves_discriminators_untouched_by_generator_loss(garment):
    m, b = _setup(garment)
    m.step(b, 0)
    for net in m.nets.values():
        assert all(p.requires_grad for p in net.parameters())


def test_ablation_flags_remove_terms(garment):
    m, b = _setup(garment, "ours-no-gan")
    vis, tac = m.generator(b.sketch, b.mask)
    assert set(m.generator_losses(b, vis, tac)) == {"v_l1", "v_perc", "t_l1", "t_perc"}
    m, b = _setup(garment, "no-tactile-rec")
    vis, tac = m.generator(b.sketch, b.mask)
    assert "t_l1" not in m.generator_losses(b, vis, tac) and "t_gan" in m.generator_losses(b, vis, tac)


class _TinyEncoder(nn.Module):
    def __init__(self):
        super().__init__()
        self.conv = nn.Conv2d(3, 4, 8, 8)

    def forward(self, x):
        return self.conv(x).mean(dim=(2, 3))


def test_clip_head_has_optimizer_and_learns(garment, tmp_path):
    path = tmp_path / "enc.pt"
    torch.jit.script(_TinyEncoder()).save(str(path))
    m, b = _setup(garment, overrides=[f"pretrained.clip_encoder={path}", "loss.clip_start=0"])
    assert m.clip.active and "CLIP" in m.opts
    before = [p.detach().clone() for p in m.clip.net.head.parameters()]
    enc_before = [p.detach().clone() for p in m.clip.net.encoder.parameters()]
    logs = m.step(b, 0)
    assert "d_clip" in logs and "v_clip" in logs
    assert any(not torch.equal(a, p) for a, p in zip(before, m.clip.net.head.parameters()))
    assert all(torch.equal(a, p) for a, p in zip(enc_before, m.clip.net.encoder.parameters()))


def test_no_clip_path_skips_with_one_log_line(garment, caplog):
    with caplog.at_level(logging.INFO):
        m, _ = _setup(garment)
    assert not m.clip.active and m.info["clip_d"] == "skipped"
    assert sum("clip-d" in r.message for r in caplog.records) == 1


def test_vgg_keys_match_torchvision_and_lpips_loads(tmp_path, caplog):
    vgg = VGG16Features()
    keys = [k for k in vgg.state_dict()]
    convs = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28]   # torchvision vgg16().features conv indices
    assert keys == [f"features.{i}.{w}" for i in convs for w in ("weight", "bias")]
    torch.manual_seed(0)
    state = {**vgg.state_dict(), "classifier.0.weight": torch.zeros(2, 2)}   # a full torchvision file has more
    torch.save(state, tmp_path / "vgg16.pth")
    lin = {f"lin{i}.model.1.weight": torch.rand(1, c, 1, 1) for i, c in enumerate((64, 128, 256, 512, 512))}
    torch.save(lin, tmp_path / "lin.pth")
    p = Perceptual(vgg16_path=str(tmp_path / "vgg16.pth"), lpips_lin_path=str(tmp_path / "lin.pth"))
    assert p.kind == "lpips-vgg"
    assert torch.equal(p.vgg.features[28].weight, vgg.features[28].weight)
    x = torch.rand(1, 3, 64, 64) * 2 - 1
    assert float(p(x, x)) == pytest.approx(0.0, abs=1e-7) and float(p(x, -x)) > 0
    assert not any(q.requires_grad for q in p.parameters())


def test_perceptual_substitute_when_weights_absent(caplog):
    with caplog.at_level(logging.WARNING):
        p = Perceptual(vgg16_path="/nonexistent/vgg16.pth")
    assert p.kind == "ssim-gradient" and any("substitute" in r.message for r in caplog.records)
    x = torch.rand(1, 3, 64, 64) * 2 - 1
    assert float(p(x, x)) == pytest.approx(0.0, abs=1e-6) and float(p(x, x.flip(-1))) > 0.1
