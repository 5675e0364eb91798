"""The paper's baselines (pix2pix, pix2pixHD, GauGAN): networks at tiny size learn through forward and backward,
each trains through the real `vtkiosk train` path and leaves a self-describing checkpoint, the GAN objectives give
their known values, and the paper's widths are the defaults while the cpu preset says it narrows them."""
from __future__ import annotations

import json

import pytest
import torch
from torch import nn

from trainer.checkpoint import load_generator
from trainer.config import BaselineConfig, load_config
from trainer.data.synthetic import generate_dataset
from trainer.losses.gan_modes import d_loss, g_loss
from trainer.methods import METHODS, get_method
from trainer.models.discriminators import MultiScaleD
from trainer.models.pix2pix_generator import ResnetGenerator
from trainer.models.pix2pixhd_generator import Pix2PixHDGenerator
from trainer.models.spade_generator import SpadeGenerator
from vtkiosk.cli import main as vtkiosk

torch.set_num_threads(1)
TINY = {
    "pix2pix": lambda: ResnetGenerator(ngf=4, n_blocks=1, norm="batch", dropout=0.5),
    "pix2pixhd": lambda: Pix2PixHDGenerator(ngf=4, global_blocks=1, local_blocks=1),
    "gaugan": lambda: SpadeGenerator(ngf=2, hidden=4),
}


@pytest.mark.parametrize("name", sorted(TINY))
def test_forward_and_backward_at_tiny_size(name: str) -> None:
    torch.manual_seed(0)
    g = TINY[name]()
    sketch = torch.rand(4, 1, 32, 32) * 2 - 1
    mask = torch.ones_like(sketch)
    mask[:, :, :, :6] = 0
    vis, tac = g(sketch, mask)
    assert vis.shape == (4, 3, 32, 32) and tac.shape == (4, 2, 32, 32)
    assert vis.abs().max() <= 1 and (vis[..., :6] == 0).all() and (tac[..., :6] == 0).all()
    (vis.square().mean() + (tac - 0.3).square().mean()).backward()
    grads = [p.grad for p in g.parameters() if p.requires_grad]
    assert all(gr is not None and torch.isfinite(gr).all() for gr in grads)
    assert sum(float(gr.abs().sum()) > 0 for gr in grads) >= 0.9 * len(grads)
    # fully convolutional: the patch-trained net runs on a whole crop; single-output graphs agree with the pair
    g.eval()
    s, m = torch.rand(1, 1, 64, 96), torch.ones(1, 1, 64, 96)
    v, t = g(s, m)
    assert v.shape == (1, 3, 64, 96) and torch.allclose(g(s, m, "tactile"), t)
    assert torch.allclose(g(s, m, "visual"), v)


def test_generators_refuse_sizes_they_cannot_take() -> None:
    s = torch.rand(1, 1, 48, 48)
    with pytest.raises(AssertionError, match="multiples of 32"):
        SpadeGenerator(ngf=2, hidden=4)(s, torch.ones_like(s))
    s = torch.rand(1, 1, 40, 40)
    with pytest.raises(AssertionError, match="multiples of 16"):
        Pix2PixHDGenerator(ngf=4, global_blocks=1, local_blocks=1)(s, torch.ones_like(s))


def test_gan_objectives_have_their_known_values() -> None:
    real, fake = [[torch.full((2, 1, 3, 3), 2.0)]], [[torch.full((2, 1, 3, 3), -2.0)]]
    assert float(d_loss("hinge", real, fake)) == 0.0  # both beyond the margin
    assert float(g_loss("hinge", fake)) == pytest.approx(2.0)
    ones, zeros = [[torch.ones(1, 1, 2, 2)]], [[torch.zeros(1, 1, 2, 2)]]
    assert float(d_loss("lsgan", ones, zeros)) == 0.0 and float(g_loss("lsgan", zeros)) == pytest.approx(1.0)
    log2 = torch.log(torch.tensor(2.0))
    assert float(d_loss("vanilla", zeros, zeros)) == pytest.approx(float(log2))  # 0.5 x (log 2 + log 2)
    with pytest.raises(ValueError, match="unknown GAN mode"):
        d_loss("wgan", real, fake)


def test_paper_widths_are_the_defaults_and_the_cpu_preset_is_labelled_reduced() -> None:
    paper, cpu = load_config("paper", method="pix2pix"), load_config("cpu", method="pix2pix")
    assert paper.baseline == BaselineConfig() and (paper.baseline.ngf, paper.baseline.ndf) == (64, 64)
    assert cpu.baseline.ngf < 64 and cpu.baseline.ndf < 64
    method = get_method("pix2pix")(cpu, side=256)
    assert method.info["baseline_widths"].startswith("reduced")
    g = method.generator
    assert g.config.ngf == cpu.baseline.ngf and g.config.norm == "batch" and g.config.dropout == 0.5
    assert any(isinstance(m, nn.Dropout) for m in g.modules())
    assert set(method.nets) == {"DV", "DT"}
    dv, dt = method.nets["DV"], method.nets["DT"]
    assert isinstance(dv, MultiScaleD) and dv.scales[0].blocks[0][0].in_channels == 4  # sketch + RGB
    assert dt.scales[0].blocks[0][0].in_channels == 3 and dt.scales[0].blocks[0][0].out_channels == cpu.baseline.ndf
    hd = get_method("pix2pixhd")(cpu, side=256)
    assert len(hd.nets["DV"].scales) == 2 and hd.gan_mode == "lsgan" and hd.feature_matching_weight == 10
    gau = get_method("gaugan")(cpu, side=256)
    assert gau.gan_mode == "hinge" and len(gau.nets["DT"].scales) == 2
    assert any("parametrizations" in n for n, _ in gau.nets["DV"].named_parameters())  # spectral norm


@pytest.fixture(scope="module")
def garment_data(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    generate_dataset(root, garments=1, seed=0, frame=(192, 144), progress=False)
    return root


@pytest.mark.parametrize("method", ["pix2pix", "pix2pixhd", "gaugan"])
def test_short_train_through_the_cli_leaves_a_self_describing_checkpoint(garment_data, tmp_path, method) -> None:
    assert method in METHODS
    out = tmp_path / method
    assert vtkiosk(["train", "--data", str(garment_data), "--garment", "DenimShorts", "--method", method,
                    "--preset", "tiny", "--steps", "3", "--set", "train.threads=1", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())["train"]
    assert metrics["step"] == 3 and metrics["method"] == method and metrics["data_profile"] == "hard"
    ck = torch.load(out / "checkpoints" / "latest.pt", map_location="cpu", weights_only=False)
    assert ck["method"] == method and ck["model_config"] and ck["generator_class"] in (
        "ResnetGenerator", "Pix2PixHDGenerator", "SpadeGenerator")
    assert all(torch.isfinite(torch.tensor(v)).all() for h in ck["train_state"]["history"] for v in h.values())
    net, info = load_generator(out, "latest")
    crop = info["crop"]
    s = torch.rand(1, 1, crop, crop)
    assert net(s, torch.ones_like(s), "tactile").shape == (1, 2, crop, crop)


def test_baked_spectral_norm_gives_the_same_outputs_and_nothing_left_to_recompute():
    from torch.nn.utils import parametrize

    from trainer.checkpoint import bake_parametrizations
    from trainer.models.spade_generator import SpadeGenerator
    g = SpadeGenerator().eval()
    s, m = torch.rand(1, 1, 64, 64), torch.ones(1, 1, 64, 64)
    with torch.no_grad():
        before = g(s, m)
        bake_parametrizations(g)
        after = g(s, m)
    assert not any(parametrize.is_parametrized(x) for x in g.modules())
    assert all(torch.equal(a, b) for a, b in zip(before, after))


def test_spade_normalises_with_the_inputs_own_statistics_in_eval_as_in_training():
    """GauGAN's norm evaluated with running statistics drifted from any one crop's and broke the baseline: the
    evaluated SPADE must compute what it computed while training, whatever crops it saw before."""
    from trainer.models.spade_generator import SPADE
    torch.manual_seed(0)
    spade = SPADE(channels=4, label_nc=1, hidden=4).train()
    seg = torch.rand(1, 1, 16, 16)
    with torch.no_grad():
        for scale in (0.1, 10.0, 3.0):                    # crops with very different statistics
            spade(scale * torch.randn(1, 4, 16, 16) + scale, seg)
        x = 5.0 * torch.randn(1, 4, 16, 16) - 2.0
        trained = spade(x, seg)
        evaluated = spade.eval()(x, seg)
    assert torch.allclose(trained, evaluated, atol=1e-6)


def test_a_gaugan_checkpoint_with_the_old_running_statistics_loads_as_trained():
    """Generators trained before the norm fix carry running-statistics buffers that evaluation used and training did
    not: they load without them (the same network); any other unexpected key still fails."""
    from trainer.checkpoint import _drop_spade_running_stats
    from trainer.models.spade_generator import SpadeGenerator
    g = SpadeGenerator(ngf=2, hidden=4)
    state = dict(g.state_dict())
    old = dict(state, **{"head.norm_0.norm.running_mean": torch.zeros(1), "head.norm_0.norm.running_var":
                         torch.ones(1), "head.norm_0.norm.num_batches_tracked": torch.tensor(7)})
    SpadeGenerator(ngf=2, hidden=4).load_state_dict(_drop_spade_running_stats("SpadeGenerator", old), strict=True)
    assert _drop_spade_running_stats("ResnetGenerator", old) is old          # only SPADE's norm is forgiven
    with pytest.raises(RuntimeError, match="Unexpected"):
        SpadeGenerator(ngf=2, hidden=4).load_state_dict(
            _drop_spade_running_stats("SpadeGenerator", dict(state, **{"head.conv_0.extra": torch.zeros(1)})))
