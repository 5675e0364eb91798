"""The demo catalogue: committed models match their recorded recipes and load; packing refuses what it cannot
reproduce; a tampered file or config is caught; the demo serves every garment of it."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from vtkiosk.catalogue import CATALOGUE, CatalogueError, check, load_index, pack

ROOT = Path(__file__).resolve().parents[1]


def test_committed_catalogue_matches_its_recipes_and_loads():
    entries = check(CATALOGUE)
    assert len(entries) >= 3 and len({e.garment for e in entries}) == len(entries)
    for e in entries:
        size = (CATALOGUE / e.file).stat().st_size
        assert size <= 4_000_000, f"{e.file} is {size} bytes"
        assert "{data}" in e.data_command and "{data}" in e.train_command and "vtkiosk train" in e.train_command
        assert e.step >= 2500, f"{e.id} is not a full-schedule model (step {e.step})"
        assert "/work/" not in e.train_command and "/tmp/" not in e.data_command
        assert "--profile" not in e.data_command, f"{e.id}: the catalogue is trained on the default (hard) profile"


def _copy(tmp_path) -> Path:
    dst = tmp_path / "catalogue"
    shutil.copytree(CATALOGUE, dst)
    return dst


def test_a_tampered_file_is_refused(tmp_path):
    folder = _copy(tmp_path)
    e = load_index(folder)[0]
    with open(folder / e.file, "ab") as f:
        f.write(b"\0")
    with pytest.raises(CatalogueError, match="does not match its recorded SHA-256"):
        check(folder)


def test_a_changed_training_config_is_refused(tmp_path):
    folder = _copy(tmp_path)
    e = load_index(folder)[0]
    ck = torch.load(folder / e.file, map_location="cpu", weights_only=False)
    ck["config"]["loss"]["tactile_gan"] = 0.0
    torch.save(ck, folder / e.file)
    doc = yaml.safe_load((folder / "catalogue.yaml").read_text())
    import hashlib
    doc["garments"][0]["sha256"] = hashlib.sha256((folder / e.file).read_bytes()).hexdigest()
    (folder / "catalogue.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(CatalogueError, match="recorded recipe hash"):
        check(folder)


def test_pack_round_trip_and_refusals(tmp_path):
    from trainer.config import load_config
    from trainer.data.synthetic import generate_dataset
    from trainer.loop import Trainer
    from vtkiosk.catalogue import materialise

    data = tmp_path / "data"
    garment = generate_dataset(data, garments=1, seed=0, frame=(192, 144), progress=False)[0]
    run = tmp_path / "run"
    Trainer(load_config("tiny", overrides=["train.steps=1"]), garment, run).run()
    cmd = "vtkiosk data synth --out {data} --garments 1 --seed 0 --frame 192x144 --no-progress"
    with pytest.raises(CatalogueError, match="command.txt"):
        pack(run, tmp_path / "cat", cmd)
    (run / "command.txt").write_text(f"vtkiosk train --data {data} --preset tiny --steps 1 --out {run}\n")
    with pytest.raises(CatalogueError, match=r"\{data\}"):
        pack(run, tmp_path / "cat", "vtkiosk data synth --out somewhere")
    e = pack(run, tmp_path / "cat", cmd)
    assert check(tmp_path / "cat")[0].id == e.id and str(data) not in e.train_command
    rebuilt = materialise(e, tmp_path / "cat", tmp_path / "regen", tmp_path / "run2")
    from trainer.checkpoint import load_generator
    a, _ = load_generator(run, "best")
    b, _ = load_generator(rebuilt, "best")
    for k, v in a.state_dict().items():  # fp16 storage: equal to within half precision
        assert torch.allclose(v, b.state_dict()[k], rtol=1e-3, atol=1e-4), k
    from vtkiosk.catalogue import drop
    with pytest.raises(CatalogueError, match=r"no catalogue entry 'nope' \(have: "):
        drop([e.id, "nope"], tmp_path / "cat")
    assert [x.id for x in check(tmp_path / "cat")] == [e.id]   # a refused drop removes nothing
    assert [x.id for x in drop([e.id], tmp_path / "cat")] == [e.id]
    assert load_index(tmp_path / "cat") == [] and not (tmp_path / "cat" / e.file).exists()


@pytest.mark.slow
def test_demo_serves_every_catalogue_garment(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "demo", "--workdir", str(tmp_path / "demo"),
                           "--exit-after-ready", "--port", "0"], cwd=ROOT, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    served = proc.stdout.split("kiosk serving ", 1)[1].split(" at http", 1)[0]
    for e in load_index(CATALOGUE):
        assert e.id in served, (e.id, served)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["garments"][0].update(step="many"), r"garments\[0\]\.step must be an integer"),
    (lambda d: d["garments"][0].update(colour="red"), r"unknown key\(s\) in garments\[0\]: colour"),
    (lambda d: d["garments"][0].pop("sha256"), r"missing key\(s\) in garments\[0\]: sha256"),
    (lambda d: d.update(garments="all"), "garments must be a list"),
])
def test_a_broken_index_is_one_line_naming_file_and_key(tmp_path, edit, message):
    folder = tmp_path / "catalogue"
    folder.mkdir()
    doc = yaml.safe_load((CATALOGUE / "catalogue.yaml").read_text())
    edit(doc)
    (folder / "catalogue.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(CatalogueError, match=message) as err:
        load_index(folder)
    assert str(err.value).startswith(f"{folder / 'catalogue.yaml'}: ") and "\n" not in str(err.value)


def test_the_check_command_refuses_a_broken_index_in_one_line(tmp_path):
    folder = tmp_path / "catalogue"
    folder.mkdir()
    (folder / "catalogue.yaml").write_text("garments: [" * 200 + "]" * 200)
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "catalogue", "check", "--folder", str(folder)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "not valid YAML" in proc.stderr
