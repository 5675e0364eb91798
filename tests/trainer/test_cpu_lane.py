"""scripts/cpu_lane.sh: the blind test's CPU lanes, which must survive the end of a session."""
import os
import subprocess
import sys
from pathlib import Path

SCRIPT = str(Path(__file__).resolve().parents[2] / "scripts" / "cpu_lane.sh")


def _lane(tmp_path, *labels, **env):
    full = dict(os.environ, PY=sys.executable, DATA="data", RECIPES="recipes.txt", GARMENT=env.pop("garment"),
                ROOT="runs", EXTRA="--set data.crop=256")
    full.update(env)
    return subprocess.run(["bash", SCRIPT, *labels], cwd=tmp_path, env=full, capture_output=True, text=True,
                          timeout=300)


def test_a_lane_trains_its_labels_skips_finished_runs_and_resumes_short_ones(tmp_path):
    """Each label is trained with its own recipe line; called again, a finished run is left alone and a run short of
    STEPS continues from its checkpoint, so a lane stopped by the end of a session restarts with the same command."""
    from trainer.data.synthetic import generate_dataset
    generate_dataset(tmp_path / "data", garments=1, seed=0, frame=(192, 144), progress=False)
    (garment_dir,) = [p for p in (tmp_path / "data").iterdir() if p.is_dir()]
    garment = garment_dir.name
    (tmp_path / "recipes.txt").write_text("# two labelled runs\nono-s3 --method ours-no-gan --set train.seed=3\n\n"
                                          "ono-s4 --method ours-no-gan --set train.seed=4\n")
    first = _lane(tmp_path, "ono-s4", garment=garment, STEPS="2")
    assert first.returncode == 0, first.stdout + first.stderr
    assert "ono-s4: starting at step 0" in first.stdout and "ono-s4: finished at step 2" in first.stdout
    command = (tmp_path / "runs" / "ono-s4" / "command.txt").read_text()
    assert "--method ours-no-gan --set train.seed=4" in command and "--steps 2" in command
    finished = tmp_path / "runs" / "ono-s4" / "checkpoints" / "latest.pt"
    kept = finished.stat().st_mtime_ns

    # ono-s3 as the end of a session leaves it: its lane's recipe, stopped at step 1 of 2
    from trainer.config import load_config
    from trainer.loop import Trainer
    overrides = ["train.steps=2", "train.ema=0.999", "train.threads=1", "train.progress=false", "data.crop=256",
                 "train.seed=3"]
    tr = Trainer(load_config("cpu", overrides=overrides, method="ours-no-gan"), garment_dir,
                 tmp_path / "runs" / "ono-s3")
    tr.run(should_stop=lambda: tr.step >= 1)
    assert tr.stopped and tr.step == 1

    again = _lane(tmp_path, "ono-s3", "ono-s4", garment=garment, STEPS="2")
    assert again.returncode == 0, again.stdout + again.stderr
    assert "ono-s3: --resume at step 1" in again.stdout and "ono-s3: finished at step 2" in again.stdout
    assert "ono-s4: done (2 steps); skipped" in again.stdout
    assert finished.stat().st_mtime_ns == kept

    missing = _lane(tmp_path, "ono-s4", "nowhere", garment=garment, STEPS="2")
    assert missing.returncode == 1
    assert "nowhere: no recipe in recipes.txt; skipped" in missing.stdout
    assert (tmp_path / "runs" / "lane.log").read_text().count("finished at step 2") == 2


def test_a_lane_refuses_a_bad_call_before_training_anything(tmp_path):
    (tmp_path / "data").mkdir()
    (tmp_path / "recipes.txt").write_text("a --method pix2pix\n")
    for env, message in ((dict(STEPS="0"), "STEPS must be a positive whole number, not 0"),
                         (dict(STEPS="1e3"), "STEPS must be a positive whole number"),
                         (dict(RECIPES="nowhere.txt"), "no recipes file nowhere.txt"),
                         (dict(DATA="nodata"), "no data folder nodata")):
        done = _lane(tmp_path, "a", garment="G", **env)
        assert done.returncode == 2 and message in done.stderr, done.stderr
    assert _lane(tmp_path, garment="G").stderr.strip().endswith("name the LABELs of recipes.txt to train")
    assert not (tmp_path / "runs").exists()
