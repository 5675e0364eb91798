"""`train.device`: where a step runs is an execution setting, checked up front, and the data a step sees does not
depend on it (drawn on the CPU, seeded, then moved)."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from trainer import provenance
from trainer.config import ConfigError, load_config
from trainer.distributed import Dist
from trainer.errors import TrainerError
from trainer.loop import resolve_device
from trainer.recipe.diffaug import DiffAugment
from trainer.recipe.identity import recipe_differences
from trainer.sampling import Batch


@pytest.mark.parametrize("value", ["cpu", "cuda", "cuda:0", "cuda:3", "auto"])
def test_device_values_accepted(value):
    assert load_config("tiny", overrides=[f"train.device={value}"]).train.device == value


@given(st.text(max_size=12).filter(lambda s: s not in ("cpu", "cuda", "auto") and not
                                   (s.startswith("cuda:") and s[5:].isdigit() and s[5:].isascii())))
@settings(max_examples=60, deadline=None)
def test_any_other_device_is_a_clear_config_error(value):
    with pytest.raises(ConfigError, match="train.device must be cpu, cuda, cuda:N or auto"):
        load_config("tiny", overrides=[f"train.device={value!r}"])


def test_device_is_how_a_run_executes_not_its_recipe():
    old = load_config("cpu").to_dict()
    new = load_config("cpu", overrides=["train.device=cuda"]).to_dict()
    assert recipe_differences(old, new) == ([], [])
    del old["train"]["device"]   # a run saved before the key existed resumes on a GPU without a recipe change
    assert recipe_differences(old, new) == ([], [])


def test_auto_falls_back_to_the_cpu_and_cuda_without_a_gpu_says_so(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device("cpu") == torch.device("cpu")
    for name in ("cuda", "cuda:1"):
        with pytest.raises(TrainerError, match="sees no GPU"):
            resolve_device(name)


def test_each_torchrun_rank_takes_its_own_gpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("cuda") == torch.device("cuda:0")
    assert resolve_device("auto", Dist(rank=5, world=8, local_rank=1)) == torch.device("cuda:1")
    assert resolve_device("cuda:2", Dist(rank=0, world=2, local_rank=0)) == torch.device("cuda:2")


def _batch() -> Batch:
    t = lambda *s: torch.rand(*s)  # noqa: E731
    return Batch(t(1, 1, 256, 256), t(1, 1, 256, 256), t(1, 3, 256, 256), t(4, 1, 32, 32), t(4, 1, 32, 32),
                 t(4, 1, 32, 32), np.zeros((4, 2), int), np.zeros((2, 2), int), (10, 20))


def test_a_batch_moves_its_tensors_and_keeps_its_places():
    b = _batch()
    assert b.to(torch.device("cpu")) is b                  # already there: no copy
    m = b.to(torch.device("meta"))                         # a device every torch build has
    for k in ("sketch", "mask", "visual", "gx", "gy", "contact"):
        assert getattr(m, k).device.type == "meta" and getattr(m, k).shape == getattr(b, k).shape
    assert m.origin == b.origin and m.origins is b.origins and m.unpaired is b.unpaired
    assert b.sketch.device.type == "cpu"                   # the original is untouched


def test_diffaugment_draws_from_a_cpu_stream_whatever_the_device(monkeypatch):
    """The transform a step gets is fixed by the seed alone: the same draws on any device. The meta device stands
    in for a GPU, with CUDA's rule imposed (a generator may only draw on its own device), which the meta device
    itself does not enforce."""
    import trainer.recipe.diffaug as da

    def guarded(fn):
        def draw(*args, generator=None, device=None, **kw):
            if generator is not None and torch.device(device or "cpu") != generator.device:
                raise RuntimeError(f"Expected a '{torch.device(device).type}' device type for generator")
            return fn(*args, generator=generator, device=device, **kw)
        return draw
    monkeypatch.setattr(da.torch, "rand", guarded(torch.rand))
    monkeypatch.setattr(da.torch, "randint", guarded(torch.randint))
    x = torch.rand(3, 4, 64, 64)
    a = DiffAugment("color,translation,cutout", rgb=slice(1, 4), seed=7)
    b = DiffAugment("color,translation,cutout", rgb=slice(1, 4), seed=7)
    (out,) = a(x)
    (meta,) = b(x.to("meta"))
    assert meta.device.type == "meta" and meta.shape == out.shape
    assert a.g.get_state().equal(b.g.get_state())          # both streams advanced by exactly the same draws


def test_the_machine_record_names_a_gpu_only_when_one_trains():
    cpu = provenance.this_machine(1, torch.device("cpu"))
    assert "gpu" not in cpu and provenance.this_machine(1) == cpu
    gpu = cpu | {"gpu": "NVIDIA H200 (sm_90, CUDA 13.0)"}
    assert provenance.summary(gpu).endswith(" on NVIDIA H200 (sm_90, CUDA 13.0)")
    assert not provenance.same_kernels(cpu, gpu)           # a resume that moves to a GPU starts a new stretch


def test_tf32_is_an_execution_switch_and_off_by_default():
    assert load_config("cpu").train.tf32 is False
    old = load_config("cpu").to_dict()
    assert recipe_differences(old, load_config("cpu", overrides=["train.tf32=true"]).to_dict()) == ([], [])


def test_the_r1_check_agrees_with_itself_on_the_cpu(tmp_path):
    """scripts/gpu_r1_check.py, the prepared GPU check, run on the CPU alone: float32 must agree with float64 to
    float32's rounding (were the augmentation's draws tied to the dtype, the diffaug rows would differ by ~30 %)."""
    import json
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "r1.json"
    subprocess.run([sys.executable, str(root / "scripts" / "gpu_r1_check.py"), "--devices", "cpu", "--patches", "24",
                    "--out", str(out)], check=True, cwd=root, capture_output=True, timeout=300)
    doc = json.loads(out.read_text())
    rows = doc["rows"]
    policies = {"off", "color", "translation", "cutout", "color,translation,cutout"}
    assert {(r["dtype"], r["diffaug"]) for r in rows} == {(d, p) for d in ("float64", "float32") for p in policies}
    for r in rows:
        assert np.isfinite(r["r1"]) and r["r1"] > 0
        assert r["r1_rel_diff"] < 1e-4 and r["grad_rel_diff"] < 1e-2, r
    # the per-operation table: on the CPU a channels-last input changes nothing beyond float64's rounding (on an
    # H100 avg_pool2d's gradient did not survive it: docs/training.md, "On a GPU")
    ops = doc["channels_last_ops"]
    assert {r["op"] for r in ops} == {"conv2d", "batch_norm", "leaky_relu", "avg_pool2d"}
    for r in ops:
        assert r["out_rel_diff"] < 1e-12 and r["r1_rel_diff"] < 1e-8 and r["grad_rel_diff"] < 1e-7, r


def test_the_r1_probe_recomputes_the_run_s_own_penalty(tmp_path):
    """scripts/gpu_r1_probe.py on the CPU: its float32 copy of the D step must give the R1 the run itself logged
    (else its GPU rows would be compared with something the run never computed), and float64 must agree with it."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from trainer.data.synthetic import generate_dataset
    root = Path(__file__).resolve().parents[2]
    data = tmp_path / "data"
    generate_dataset(data, garments=1, seed=0, frame=(192, 144), progress=False)
    garment = next(p for p in data.iterdir() if p.is_dir()).name
    out = tmp_path / "probe"
    subprocess.run([sys.executable, str(root / "scripts" / "gpu_r1_probe.py"), "--data", str(data), "--garment",
                    garment, "--preset", "tiny", "--steps", "3", "--every", "1", "--out", str(out)],
                   check=True, cwd=root, capture_output=True, timeout=300)
    rows = [json.loads(line) for line in (out / "r1_probe.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [0, 1, 2]
    for r in rows:
        (cpu32,) = [v for v in r["variants"] if v["device"] == "cpu"]
        assert np.isfinite(r["r1_run"]) and r["r1_run"] > 0
        assert abs(cpu32["r1"] - r["r1_run"]) <= 1e-6 * r["r1_run"], r
        assert cpu32["r1_rel"] < 1e-4 and cpu32["r1_grad_rel"] < 1e-2, r
    assert (out / "metrics.json").exists()          # an ordinary run directory besides


def _gpu_table_env(tmp_path, *, garments, **env):
    """`garments` synthetic garments and the environment of a scripts/gpu_table.sh call on the CPU (`env` on top);
    returns the garments' names, that environment and the script."""
    import os
    import sys
    from pathlib import Path

    from trainer.data.synthetic import generate_dataset
    generate_dataset(tmp_path / "data", garments=garments, seed=0, frame=(192, 144), progress=False)
    names = sorted(p.name for p in (tmp_path / "data").iterdir() if p.is_dir())
    base = dict(os.environ, OUT=str(tmp_path / "out"), WORK=str(tmp_path / "work"), PY=sys.executable, DATA="data",
                GARMENTS=names[0], CROP="256", DEVICE="cpu", SCORE="0", PACK="weights")
    script = str(Path(__file__).resolve().parents[2] / "scripts" / "gpu_table.sh")
    return names, dict(base, **env), script


def _gpu_table_lease(tmp_path, *, garments, steps):
    """scripts/gpu_table.sh's first call on the CPU: `garments` synthetic garments, the first trained `steps` steps
    with `ours-no-gan`; returns the garments' names, the call's environment and the script."""
    import subprocess

    names, env, script = _gpu_table_env(tmp_path, garments=garments, STEPS=str(steps), METHODS="ours-no-gan")
    first = subprocess.run(["bash", script, "200"], cwd=tmp_path, env=env, capture_output=True, text=True,
                           timeout=300)
    assert first.returncode == 0, first.stdout + first.stderr
    return names, env, script


def test_the_gpu_table_script_packs_fp16_weights_and_never_repacks_an_old_folder(tmp_path):
    """scripts/gpu_table.sh, the prepared lease, end to end on the CPU (two steps): it packs each run's generator in
    fp16 with a garment path free of the machine's own folders, and it refuses a WORK folder that already holds runs
    (on a warm machine a second call once repacked the first call's runs as if they were its own)."""
    import subprocess
    import tarfile
    from pathlib import Path

    (garment,), env, script = _gpu_table_lease(tmp_path, garments=1, steps=2)
    out = tmp_path / "out"
    log = (out / "gpu_table.log").read_text()
    assert "training 1 runs (ours-no-gan) for 2 steps (given)" in log
    assert "deadlines: training 180 s" in log       # scored elsewhere: all but the packing's 20 s is training
    member = f"runs/{garment}/ours-no-gan/weights/latest.pt"
    with tarfile.open(out / "weights-ours-no-gan.tar") as tar:
        assert tar.getnames() == [str(Path(member).parent), member]
        tar.extract(member, tmp_path / "unpacked")
    ck = torch.load(tmp_path / "unpacked" / member, map_location="cpu", weights_only=False)
    assert ck["config"]["garment"] == f"data/{garment}" and "train_state" not in ck
    floats = [v for v in ck["generator"].values() if v.is_floating_point()]
    assert floats and all(v.dtype == torch.float16 and torch.isfinite(v).all() for v in floats)
    packed = (out / "weights-ours-no-gan.tar").stat().st_mtime_ns

    again = subprocess.run(["bash", script, "200"], cwd=tmp_path, env=env, capture_output=True, text=True,
                           timeout=60)
    assert again.returncode == 2 and "already holds runs" in again.stderr
    assert (out / "weights-ours-no-gan.tar").stat().st_mtime_ns == packed

    broken = subprocess.run(["bash", script, "200"], cwd=tmp_path, capture_output=True, text=True, timeout=60,
                            env=dict(env, WORK=str(tmp_path / "work2"), CROP="100"))
    assert broken.returncode == 1                   # a run that fails is a failed lease, not a quiet empty table
    assert "data.crop must be a multiple of 256" in (out / "gpu_table.log").read_text()


def test_the_gpu_table_script_continues_runs_a_deadline_stopped_and_leaves_finished_ones(tmp_path):
    """RESUME=1 on a warm machine's WORK folder: a run the deadline stopped short of STEPS continues from its
    checkpoint to STEPS, a finished run is not retrained, and both are packed (a lease once lost six 2 000-step
    `ours` runs stopped at about 1 570 steps, whose fp16 weights could not be resumed elsewhere)."""
    import json
    import subprocess
    import tarfile

    from trainer.loop import Trainer
    (done_g, stopped_g), env, script = _gpu_table_lease(tmp_path, garments=2, steps=4)
    data, out, work = tmp_path / "data", tmp_path / "out", tmp_path / "work"
    # the other garment as the deadline leaves a run: stopped at step 2 of 4, with the script's own command line
    overrides = ["data.crop=256", "train.threads=1", "train.progress=false", "train.device=cpu", "train.ema=0.999",
                 "optim.lr_policy=linear", "loss.diffaug=", "train.steps=4"]
    stopped = work / "runs" / stopped_g / "ours-no-gan"
    tr = Trainer(load_config("cpu", overrides=overrides, method="ours-no-gan"), data / stopped_g, stopped)
    tr.run(should_stop=lambda: tr.step >= 2)
    assert tr.stopped and tr.step == 2
    finished = work / "runs" / done_g / "ours-no-gan" / "checkpoints" / "latest.pt"
    kept = finished.stat().st_mtime_ns

    refused = subprocess.run(["bash", script, "200"], cwd=tmp_path, env=dict(env, GARMENTS=f"{done_g} {stopped_g}"),
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "RESUME=1 to continue them" in refused.stderr
    no_steps = {k: v for k, v in env.items() if k != "STEPS"}
    refused = subprocess.run(["bash", script, "200"], cwd=tmp_path, env=dict(no_steps, RESUME="1"),
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "RESUME=1 needs WORK" in refused.stderr

    again = subprocess.run(["bash", script, "200"], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                           env=dict(env, RESUME="1", GARMENTS=f"{done_g} {stopped_g}"))
    assert again.returncode == 0, again.stdout + again.stderr
    log = (out / "gpu_table.log").read_text()
    assert f"{stopped_g}/ours-no-gan: --resume at step 2 of 4" in log and f"{done_g}/ours-no-gan: --resume" not in log
    assert finished.stat().st_mtime_ns == kept
    ck = torch.load(stopped / "checkpoints" / "latest.pt", map_location="cpu", weights_only=False)
    assert ck["step"] == 4
    record = json.loads((stopped / "metrics.json").read_text())["train"]
    assert record["step"] == 4 and record["steps_this_session"] == 2 and not record["stopped_early"]
    with tarfile.open(out / "weights-ours-no-gan.tar") as tar:
        names = set(tar.getnames())
    assert {f"runs/{g}/ours-no-gan/weights/latest.pt" for g in (done_g, stopped_g)} <= names


def test_the_gpu_table_calibration_times_the_steady_steps_and_fits_the_schedule_to_the_budget(tmp_path):
    """Without STEPS the script times a short run of every method side by side from its second half, and fixes one
    schedule for all runs in 50-step units, capped by MAX_STEPS (the first steps' warm-up and 250-step units once
    left a fifth of a lease's training time unused); each calibration run's record carries its steady step time."""
    import json
    import os
    import re
    import subprocess
    import sys
    from pathlib import Path

    from trainer.data.synthetic import generate_dataset
    root = Path(__file__).resolve().parents[2]
    generate_dataset(tmp_path / "data", garments=1, seed=0, frame=(192, 144), progress=False)
    garment = next(p for p in (tmp_path / "data").iterdir() if p.is_dir()).name
    out = tmp_path / "out"
    env = dict(os.environ, OUT=str(out), WORK=str(tmp_path / "work"), PY=sys.executable, DATA="data",
               GARMENTS=garment, CROP="256", DEVICE="cpu", CAL_STEPS="8", MAX_STEPS="50", METHODS="ours-no-gan",
               SCORE="0", PACK="weights")
    done = subprocess.run(["bash", str(root / "scripts" / "gpu_table.sh"), "300"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    log = (out / "gpu_table.log").read_text()
    m = re.search(r"calibration: ([0-9.]+) s/step \(steady, \+10 %\) with all runs side by side; "
                  r"training 1 runs \(ours-no-gan\) for (\d+) steps", log)
    assert m, log
    assert float(m.group(1)) > 0 and int(m.group(2)) == 50
    cal = json.loads((tmp_path / "work" / "cal" / garment / "ours-no-gan" / "metrics.json").read_text())["train"]
    assert cal["step"] == 8 and 0 < cal["seconds_per_step_steady"] <= 2 * cal["seconds_per_step"]
    assert abs(float(m.group(1)) - 1.1 * cal["seconds_per_step_steady"]) < 1e-3
    run = json.loads((tmp_path / "work" / "runs" / garment / "ours-no-gan" / "metrics.json").read_text())["train"]
    assert run["step"] == 50 and not run["stopped_early"]


def test_the_gpu_table_script_trains_a_recipes_file_of_labelled_runs(tmp_path):
    """RECIPES: each line's label is a run folder trained with that line's own arguments (the blind test's twelve
    runs of one garment in one call), the weights pack in numbered files, and a label with no line is refused by
    name rather than trained with another recipe."""
    import subprocess
    import tarfile

    recipes = tmp_path / "recipes.txt"
    recipes.write_text("# two labelled runs\nono-s3 --method ours-no-gan --set train.seed=3\n\n"
                       "ono-s4 --method ours-no-gan --set train.seed=4\n")
    (garment,), env, script = _gpu_table_env(tmp_path, garments=1, STEPS="1", RECIPES=str(recipes))
    done = subprocess.run(["bash", script, "200"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "training 2 runs (ono-s3 ono-s4) for 1 steps (given)" in (tmp_path / "out" / "gpu_table.log").read_text()
    for label, seed in (("ono-s3", 3), ("ono-s4", 4)):
        command = (tmp_path / "work" / "runs" / garment / label / "command.txt").read_text()
        assert f"--method ours-no-gan --set train.seed={seed}" in command
    with tarfile.open(tmp_path / "out" / "weights-1.tar") as tar:
        names = set(tar.getnames())
    assert {f"runs/{garment}/{m}/weights/latest.pt" for m in ("ono-s3", "ono-s4")} <= names

    missing = subprocess.run(["bash", script, "200"], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                             env=dict(env, WORK=str(tmp_path / "work2"), METHODS="ono-s3 nowhere"))
    assert missing.returncode == 1
    log = (tmp_path / "out" / "gpu_table.log").read_text()
    assert f"{garment}/nowhere: no recipe; not trained" in log and f"{garment}/nowhere: failed" in log
    no_steps = {k: v for k, v in env.items() if k != "STEPS"}
    refused = subprocess.run(["bash", script, "200"], cwd=tmp_path, env=dict(no_steps, WORK=str(tmp_path / "w3")),
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "RECIPES needs STEPS" in (tmp_path / "out" / "gpu_table.log").read_text()
