"""Training loop: every method trains, resume is exact, checkpoints fail loudly, CLI train -> eval, DDP."""
from __future__ import annotations

import json
import os
import socket

import numpy as np
import pytest
import torch

from trainer.checkpoint import CheckpointError, load_generator
from trainer.config import load_config
from trainer.data.synthetic import generate_dataset
from trainer.evaluate import evaluate_run
from trainer.loop import Trainer
from trainer.methods import METHODS
from trainer.models.generator import TwoBranchUNet
from trainer.models.pix2pix_generator import ResnetGenerator
from trainer.models.pix2pixhd_generator import Pix2PixHDGenerator
from trainer.models.spade_generator import SpadeGenerator
from vtkiosk.cli import main as vtkiosk

torch.set_num_threads(2)
GENERATORS = {"pix2pix": ResnetGenerator, "pix2pix-joint-d": ResnetGenerator, "pix2pixhd": Pix2PixHDGenerator,
              "gaugan": SpadeGenerator}


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    generate_dataset(root, garments=2, seed=0, frame=(192, 144), progress=False)
    return root


def _garment(synth):
    return synth / "singleskit_DenimShorts_padded_270_x1"


@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_trains_and_checkpoints(synth, tmp_path, method):
    cfg = load_config("tiny", method=method, overrides=["train.steps=2"])
    tr = Trainer(cfg, _garment(synth), tmp_path / "run")
    init = {k: v.clone() for k, v in tr.method.generator.state_dict().items()}
    summary = tr.run()
    assert summary["step"] == 2 and all(torch.isfinite(torch.tensor(v)).all()
                                        for h in tr.history for k, v in h.items())
    net, info = load_generator(tmp_path / "run", "latest")
    assert info["method"] == method and info["step"] == 2 and info["friction_scale"] > 0
    assert isinstance(net, GENERATORS.get(method, TwoBranchUNet)) and not net.training
    assert any(not torch.equal(init[k], v) for k, v in net.state_dict().items())
    for f in ("config.yaml", "metrics.json", "curves.png", "samples/step_00002.png", "checkpoints/best.pt"):
        assert (tmp_path / "run" / f).is_file(), f


def test_a_wider_tactile_head_trains_and_its_checkpoint_rebuilds_it(synth, tmp_path):
    cfg = load_config("tiny", overrides=["train.steps=1", "model.tactile_mult=2"])
    Trainer(cfg, _garment(synth), tmp_path / "run").run()
    net, info = load_generator(tmp_path / "run", "latest")
    assert isinstance(net, TwoBranchUNet) and net.model_config()["tactile_mult"] == 2
    assert sum(p.numel() for p in net.tactile.parameters()) > 2 * sum(p.numel() for p in net.visual.parameters())


def test_a_tactile_head_that_reads_the_visual_head_trains_and_its_checkpoint_rebuilds_it(synth, tmp_path):
    cfg = load_config("tiny", overrides=["train.steps=1", "model.tactile_reads_visual=true"])
    Trainer(cfg, _garment(synth), tmp_path / "run").run()
    net, _ = load_generator(tmp_path / "run", "latest")
    assert isinstance(net, TwoBranchUNet) and net.model_config()["tactile_reads_visual"] is True


@pytest.mark.parametrize("mirror", ["transpose", "flip"])
def test_mirrored_crops_train_every_loss_of_ours(synth, tmp_path, mirror):
    """data.transpose=1 or data.flip=1: every step sees a mirrored crop; the tactile D, unpaired patches and every
    loss run on it."""
    cfg = load_config("tiny", overrides=["train.steps=2", f"data.{mirror}=1"])
    tr = Trainer(cfg, _garment(synth), tmp_path / "run")
    assert tr.data.batch(0).sketch.shape[-1] == tr.data.side
    tr.run()
    logs = tr.history[-1]
    assert all(np.isfinite(logs[k]) for k in ("t_l1", "t_gan", "v_l1", "d_tactile")), logs


@pytest.mark.parametrize("mirror", ["transpose", "flip"])
def test_mirrored_crops_can_train_the_tactile_side_alone(synth, tmp_path, mirror):
    """data.transpose_visual=false: a mirrored step (either mirror) leaves the visual head and the visual D untouched
    (no visual loss), while the tactile head and the tactile D learn from it."""
    cfg = load_config("tiny", overrides=["train.steps=2", f"data.{mirror}=1", "data.transpose_visual=false"])
    tr = Trainer(cfg, _garment(synth), tmp_path / "run")
    g = tr.method.G
    before = {k: {n: p.detach().clone() for n, p in m.named_parameters()}
              for k, m in (("visual", g.visual), ("tactile", g.tactile), ("DI", tr.method.nets["DI"]),
                           ("DT", tr.method.nets["DT"]))}
    tr.run()
    logs = tr.history[-1]
    assert "v_l1" not in logs and "v_gan" not in logs and "d_visual" not in logs
    assert np.isfinite(logs["t_l1"]) and np.isfinite(logs["t_gan"])
    for k, params in before.items():
        now = dict((g.visual if k == "visual" else g.tactile if k == "tactile" else tr.method.nets[k])
                   .named_parameters())
        moved = any(not torch.equal(p, now[n]) for n, p in params.items())
        assert moved == (k in ("tactile", "DT")), k


@pytest.mark.parametrize("twin_gan", [True, False])
def test_a_mirrored_twin_trains_beside_the_crop_and_its_tactile_terms_are_the_mean(synth, tmp_path, twin_gan):
    """data.mirror_extra: the step trains every loss on the crop as photographed (the visual head and D move) and
    the tactile terms on the mirrored twin too; each logged tactile term is the mean over the two crops. Under
    data.twin_gan=false the tactile D sees the crop as photographed only, and the twin adds no GAN term."""
    cfg = load_config("tiny", overrides=["train.steps=1", "data.flip=1", "data.mirror_extra=true",
                                         f"data.twin_gan={str(twin_gan).lower()}"])
    tr = Trainer(cfg, _garment(synth), tmp_path / "run")
    m = tr.method
    batch = tr.data.batch(0)
    assert batch.twin is not None and not batch.mirrored
    with torch.no_grad():
        fakes = m.G(batch.sketch, batch.mask), m.G(batch.twin.sketch, batch.twin.mask)
        one = m.generator_losses(batch, *fakes[0])
        two = m.generator_losses(batch.twin, *fakes[1], gan=twin_gan)
    tactile = {k for k in one if k.startswith("t_")}
    assert set(two) == (tactile if twin_gan else tactile - {"t_gan", "t_fm"})   # the twin adds no visual term
    assert abs(two["t_l1"] - one["t_l1"]) > 1e-4                  # so the mean below says something
    m.aug_tactile.reseed(cfg.train.seed * 1_000_003 + 1)           # the stream the step's tactile D draws from
    d_one = m.tactile_d_loss(batch, *fakes[0])[0].item()
    d_two = m.tactile_d_loss(batch.twin, *fakes[1])[0].item()
    visual_before = [p.detach().clone() for p in m.G.visual.parameters()]
    logs = m.step(batch, 0)
    assert logs["d_tactile"] == pytest.approx((d_one + d_two) / 2 if twin_gan else d_one, rel=1e-4)
    assert logs["t_l1"] == pytest.approx(float(one["t_l1"] + two["t_l1"]) / 2, rel=1e-4)
    assert logs["v_l1"] == pytest.approx(float(one["v_l1"]), rel=1e-4)
    assert "d_visual" in logs and np.isfinite(logs["d_tactile"])
    assert any(not torch.equal(a, b) for a, b in zip(visual_before, m.G.visual.parameters()))


@pytest.mark.parametrize("key", ["data.transpose_visual=false", "data.mirror_extra=true"])
def test_a_one_output_baseline_refuses_tactile_only_mirrors(synth, tmp_path, key):
    from trainer.config import ConfigError
    cfg = load_config("tiny", method="pix2pix", overrides=["data.transpose=0.5", key])
    with pytest.raises(ConfigError, match="needs a two-branch method"):
        Trainer(cfg, _garment(synth), tmp_path / "run")


def test_a_twin_without_a_mirror_is_refused():
    from trainer.config import ConfigError
    with pytest.raises(ConfigError, match="data.mirror_extra adds a mirrored twin"):
        load_config("tiny", overrides=["data.mirror_extra=true"])
    with pytest.raises(ConfigError, match="needs data.mirror_extra=true"):
        load_config("tiny", overrides=["data.flip=0.5", "data.twin_gan=false"])


def test_resume_is_bit_identical(synth, tmp_path):
    def cfg():
        return load_config("tiny", overrides=["train.steps=4", "train.deterministic=true", "train.ckpt_every=2"])
    full = Trainer(cfg(), _garment(synth), tmp_path / "full")
    full.run()
    part = Trainer(cfg(), _garment(synth), tmp_path / "part")
    part.run(until=2)
    resumed = Trainer(cfg(), _garment(synth), tmp_path / "part", resume=True)
    assert resumed.step == 2
    resumed.run()
    a, b = full.method.state_dict(), resumed.method.state_dict()
    for k, v in a["generator"].items():
        assert torch.equal(v, b["generator"][k]), k
    for name in a["nets"]:
        for k, v in a["nets"][name].items():
            assert torch.equal(v, b["nets"][name][k]), (name, k)
    assert [h["g_total"] for h in full.history] == [h["g_total"] for h in resumed.history]


def test_seeded_runs_repeat_and_seeds_differ(synth, tmp_path):
    def weights(seed, out):
        tr = Trainer(load_config("tiny", overrides=["train.steps=1", f"train.seed={seed}"]), _garment(synth), out)
        tr.run()
        return tr.method.generator.state_dict()
    a, b, c = weights(0, tmp_path / "a"), weights(0, tmp_path / "b"), weights(1, tmp_path / "c")
    assert all(torch.equal(a[k], b[k]) for k in a) and not all(torch.equal(a[k], c[k]) for k in a)


def test_refuses_to_overwrite_a_run(synth, tmp_path):
    Trainer(load_config("tiny", overrides=["train.steps=1"]), _garment(synth), tmp_path / "r").run()
    with pytest.raises(CheckpointError, match="--resume"):
        Trainer(load_config("tiny", overrides=["train.steps=1"]), _garment(synth), tmp_path / "r")


def test_resume_refuses_a_changed_recipe_and_allows_execution_changes(synth, tmp_path, caplog, capsys):
    base = ["train.steps=2", "train.ckpt_every=1"]
    Trainer(load_config("tiny", overrides=base), _garment(synth), tmp_path / "r").run(until=1)
    # a recipe key that differs (as a default changed between sessions would) is refused, naming key and values
    for extra, key in ((["loss.diffaug=color"], "loss.diffaug: 'color,translation,cutout' -> 'color'"),
                       (["optim.lr_policy=constant"], "optim.lr_policy: 'linear' -> 'constant'"),
                       (["train.steps=3"], "train.steps: 2 -> 3")):
        with pytest.raises(CheckpointError, match="differs from the run's recipe") as err:
            Trainer(load_config("tiny", overrides=[*base, *extra]), _garment(synth), tmp_path / "r", resume=True)
        assert key in str(err.value) and "--set" in str(err.value)
    with pytest.raises(CheckpointError, match="trained on garment 'singleskit_DenimShorts_padded_270_x1'"):
        Trainer(load_config("tiny", overrides=base), next(p for p in synth.iterdir() if p != _garment(synth)),
                tmp_path / "r", resume=True)
    # how the run is executed may change
    t = Trainer(load_config("tiny", overrides=[*base, "train.threads=1", "train.log_every=5", "train.progress=false",
                                                     "train.ckpt_every=3"]),
                _garment(synth), tmp_path / "r", resume=True)
    assert t.step == 1
    # through the command line: a clear error, the run untouched
    before = (tmp_path / "r" / "checkpoints" / "latest.pt").read_bytes()
    rc = vtkiosk(["train", "--data", str(synth), "--garment", "DenimShorts", "--preset", "tiny", "--steps", "2",
                  "--set", "train.ckpt_every=1", "--set", "loss.diffaug=color", "--set", "train.progress=false",
                  "--out", str(tmp_path / "r"), "--resume"])
    assert rc != 0 and "loss.diffaug" in capsys.readouterr().err
    assert (tmp_path / "r" / "checkpoints" / "latest.pt").read_bytes() == before
    # a run whose checkpoint predates a key resumes, with a warning naming the key
    ck = torch.load(tmp_path / "r" / "checkpoints" / "latest.pt", weights_only=False)
    del ck["config"]["loss"]["diffaug"]
    torch.save(ck, tmp_path / "r" / "checkpoints" / "latest.pt")
    with caplog.at_level("WARNING", logger="trainer"):
        Trainer(load_config("tiny", overrides=base), _garment(synth), tmp_path / "r", resume=True)
    assert "predates config keys loss.diffaug" in caplog.text


def test_missing_or_corrupt_checkpoint_is_a_clear_error(tmp_path):
    with pytest.raises(CheckpointError, match="no checkpoint"):
        load_generator(tmp_path, "best")
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "best.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="unreadable"):
        load_generator(tmp_path, "best")
    torch.save({"generator": {"x": torch.zeros(1)}, "model_config": {"base": 10}}, tmp_path / "checkpoints" / "best.pt")
    with pytest.raises(CheckpointError, match="do not fit"):
        load_generator(tmp_path, "best")
    assert getattr(CheckpointError, "user_facing", False)


@pytest.mark.slow
def test_real_layout_folder_trains_and_evaluates(real_layout_dir, tmp_path):
    out = tmp_path / "real"
    rc = vtkiosk(["train", "--data", str(real_layout_dir), "--preset", "tiny", "--set", "train.steps=2",
                  "--out", str(out)])
    assert rc == 0
    rc = vtkiosk(["eval", "--run", str(out), "--json", str(tmp_path / "m.json")])
    assert rc == 0
    m = json.loads((tmp_path / "m.json").read_text())
    # every valid centre of the 2 test touches is scored, not one patch per touch
    assert m["crop"] == 768 and m["test_touches"] == 2 and m["test_patches"] > 2
    for k in ("visual_psnr", "visual_ssim", "visual_l1", "tactile_mse", "tactile_angle_deg", "visual_fbsifid_seen",
              "tactile_fbsifid_seen"):
        assert isinstance(m[k], float) and m[k] == m[k]
    assert "full_angle_deg" not in m and "full_fbsifid_seen" not in m   # real data has no full-field ground truth
    # no full-field truth, no oracle: the trivial rows only, and no gap to close
    assert set(m["references"]) == {"flat", "mean-colour"} and "gap_closed" not in m
    assert json.loads((out / "metrics.json").read_text())["eval"]["step"] == 2


@pytest.mark.slow
def test_cli_all_eval_compare_on_synthetic(synth, tmp_path, capsys):
    out = tmp_path / "runs"
    assert vtkiosk(["train", "--data", str(synth), "--all", "--preset", "tiny", "--steps", "1",
                    "--out", str(out)]) == 0
    assert vtkiosk(["train", "--data", str(synth), "--garment", "DenimShorts", "--method", "pix2pix",
                    "--preset", "tiny", "--steps", "1", "--out", str(out / "DenimShorts" / "pix2pix")]) == 0
    runs = [out / "DenimShorts" / "ours", out / "CorduroyTrousers" / "ours"]
    assert all((r / "checkpoints" / "best.pt").is_file() for r in runs)
    m = evaluate_run(runs[0])
    assert {"full_angle_deg", "full_friction_mae", "full_fbsifid_seen", "full_fbsifid_unseen"} <= set(m)
    assert (runs[0] / "eval" / "swap.png").is_file()
    cmp_dir = tmp_path / "cmp"
    assert vtkiosk(["eval", "--compare", str(runs[0]), str(out / "DenimShorts" / "pix2pix"), "--bootstrap", "200",
                    "--out", str(cmp_dir)]) == 0
    md = (cmp_dir / "compare.md").read_text()
    assert "| ours |" in md and "| pix2pix |" in md and "**" in md
    assert "### Outside the touches: by the sketch's lines and in open cloth" in md and "open cloth° ↓" in md
    table = json.loads((cmp_dir / "compare.json").read_text())
    assert {"full_angle_deg_outside_lines", "full_angle_deg_outside_open"} <= set(table["mean"]["ours"])
    assert "full_angle_deg_outside_open" in table["differences"]["rows"]["pix2pix"]
    assert (cmp_dir / "sheet_DenimShorts.png").is_file()
    capsys.readouterr()
    assert vtkiosk(["eval", "--run", str(tmp_path / "nothing")]) == 2
    assert "no checkpoint" in capsys.readouterr().err


def _ddp_worker(rank, world, port, garment, out, results):
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), WORLD_SIZE=str(world), RANK=str(rank),
                      LOCAL_RANK=str(rank))
    from trainer.distributed import cleanup, init_from_env
    torch.set_num_threads(1)
    dist = init_from_env("gloo")
    cfg = load_config("tiny", overrides=["train.steps=2", "train.threads=1"])
    tr = Trainer(cfg, garment, out, dist=dist)
    tr.run()
    # Parameters must agree; BatchNorm running statistics of the Ds are per-rank (as in DDP without SyncBN).
    torch.save({"G": dict(tr.method.generator.named_parameters()), "DT": dict(tr.method.nets["DT"].named_parameters())},
               f"{results}/rank{rank}.pt")
    cleanup()


@pytest.mark.slow
def test_ddp_gloo_two_processes_stay_in_sync(synth, tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    torch.multiprocessing.spawn(_ddp_worker, args=(2, port, str(_garment(synth)), str(tmp_path / "run"),
                                                   str(tmp_path)), nprocs=2, join=True)
    r0, r1 = torch.load(tmp_path / "rank0.pt"), torch.load(tmp_path / "rank1.pt")
    for part in ("G", "DT"):
        for k, v in r0[part].items():
            assert torch.equal(v, r1[part][k]), (part, k)
    net, info = load_generator(tmp_path / "run", "latest")
    assert info["step"] == 2


def test_eval_with_local_inception_weights_reports_visual_and_tactile_sifid(synth, tmp_path):
    # Random-init weights in torchvision's key layout (plus a key of a later block, which is ignored): the path the
    # real inception_v3 .pth takes. Published definition: tactile SIFID per channel on each held-out patch.
    from trainer.models.inception import InceptionBlock1, sifid, sifid_channels
    torch.manual_seed(0)
    state = {**InceptionBlock1().state_dict(), "Mixed_5b.branch1x1.conv.weight": torch.zeros(1)}
    path = tmp_path / "inception_v3.pth"
    torch.save(state, path)
    net = InceptionBlock1.from_file(path)
    a = torch.rand(2, 2, 32, 32) * 2 - 1
    assert sifid_channels(net, a, a) == pytest.approx(0.0, abs=1e-6)
    assert sifid_channels(net, a, a.flip(-1) * 0.2) > 0
    assert sifid_channels(net, a, -a) == pytest.approx(
        sum(sifid(net, a[k:k + 1, c:c + 1].expand(1, 3, -1, -1), -a[k:k + 1, c:c + 1].expand(1, 3, -1, -1))
            for k in range(2) for c in range(2)) / 4)
    cfg = load_config("tiny", overrides=["train.steps=1", f"pretrained.inception={path}"])
    Trainer(cfg, _garment(synth), tmp_path / "run").run()
    m = evaluate_run(tmp_path / "run", swap=False)
    assert all(m[k] >= 0 and m[k] == m[k] for k in ("visual_sifid_seen", "visual_sifid_unseen", "tactile_sifid_seen",
                                                    "tactile_fbsifid_seen"))
    with pytest.raises(ValueError, match="not an InceptionV3 state_dict"):
        torch.save({"fc.weight": torch.zeros(1)}, tmp_path / "bad.pth")
        InceptionBlock1.from_file(tmp_path / "bad.pth")


def test_compare_table_shows_mean_and_spread_over_runs():
    from trainer.compare import table
    rs = [{"method": "ours", "garment": "A", "tactile_angle_deg": a} for a in (8.0, 9.0, 10.0)]
    rs.append({"method": "pix2pix", "garment": "A", "tactile_angle_deg": 9.5})
    md, data = table(rs)
    assert "| ours | 1 | 3 | **9** ± 1 |" in md and "| pix2pix | 1 | 1 | 9.5 |" in md and "### Tactile" in md
    assert data["sd"]["ours"]["tactile_angle_deg"] == pytest.approx(1.0) and data["sd"]["pix2pix"] == {}


def test_sigterm_during_training_saves_a_checkpoint_and_exits_unfinished(synth, tmp_path):
    import re
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    run = tmp_path / "run"
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen([sys.executable, "-m", "vtkiosk", "train", "--data", str(synth), "--garment", "DenimShorts",
                             "--preset", "tiny", "--steps", "100000", "--set", "train.ckpt_every=1",
                             "--set", "train.val_every=100000", "--set", "train.sample_every=100000",
                             "--set", "train.progress=false", "--set", "train.threads=1", "--out", str(run)],
                            cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + 120
        while not (run / "checkpoints" / "latest.pt").exists() and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 128 + signal.SIGTERM
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    step = int(re.search(r"stopped by signal at step (\d+); continue with --resume", err).group(1))
    _, info = load_generator(run, "latest")
    assert 1 <= step < 100000 and info["step"] == step
    assert json.loads((run / "metrics.json").read_text())["train"]["stopped_early"] is True
