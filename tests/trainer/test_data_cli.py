"""`vtkiosk data synth|show|check` end to end, through the real command line."""
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from tests.conftest import write_real_layout


def vtk(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "vtkiosk", *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth")
    proc = vtk("data", "synth", "--out", out, "--garments", 2, "--seed", 3, "--frame", "320x240", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "wrote 2 garment(s)" in proc.stdout
    return out


def test_check_synthetic_set(synth_dir):
    proc = vtk("data", "check", synth_dir)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "2 garment(s), 0 failed" in proc.stdout and "yes" in proc.stdout


def test_show_writes_sheets(synth_dir, tmp_path):
    garment = sorted(Path(synth_dir).iterdir())[0]
    proc = vtk("data", "show", "--garment", garment, "--out", tmp_path / "one.png")
    assert proc.returncode == 0, proc.stderr
    img = cv2.imread(str(tmp_path / "one.png"))
    assert img is not None and img.shape[1] == 3 * 480
    proc = vtk("data", "show", "--garment", synth_dir, "--out", tmp_path / "all")
    assert proc.returncode == 0, proc.stderr
    assert len(list((tmp_path / "all").glob("*.png"))) == 2


def test_show_real_layout_without_full_field(tmp_path):
    g = write_real_layout(tmp_path, touches=(3, 1, 1))
    proc = vtk("data", "show", "--garment", g, "--out", tmp_path / "real.png")
    assert proc.returncode == 0, proc.stderr
    assert cv2.imread(str(tmp_path / "real.png")) is not None


def test_check_reports_broken_folder_and_fails(tmp_path):
    g = write_real_layout(tmp_path, touches=(1, 1, 1))
    for f in (g / "trainM").rglob("*.png"):
        f.unlink()
    proc = vtk("data", "check", tmp_path)
    assert proc.returncode == 1
    assert "FAIL" in proc.stdout and "trainM/: must hold exactly one image; found none" in proc.stdout


@pytest.mark.parametrize("args, message", [
    (["data", "check", "/nonexistent/dir"], "no such dataset folder"),
    (["data", "synth", "--out", "{tmp}/x", "--garments", "0"], "--garments must be at least 1"),
    (["data", "synth", "--out", "{tmp}/x", "--frame", "10x10"], "frame"),
])
def test_bad_input_is_one_line(tmp_path, args, message):
    proc = vtk(*[a.replace("{tmp}", str(tmp_path)) for a in args])
    assert proc.returncode == 2
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_bad_frame_syntax_is_a_usage_error(tmp_path):
    proc = vtk("data", "synth", "--out", tmp_path, "--frame", "big")
    assert proc.returncode == 2 and "frame must look like 1280x960" in proc.stderr


def test_only_writes_the_named_garment_exactly_as_the_whole_set(synth_dir, tmp_path):
    second = sorted(p.name for p in synth_dir.iterdir() if p.is_dir())[1]
    material = second.removeprefix("singleskit_").split("_padded_")[0]
    proc = vtk("data", "synth", "--out", tmp_path, "--garments", 2, "--seed", 3, "--frame", "320x240",
               "--no-progress", "--only", material)
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in tmp_path.iterdir()] == [second]
    for f in sorted((synth_dir / second).rglob("*")):
        if f.is_file():
            assert (tmp_path / second / f.relative_to(synth_dir / second)).read_bytes() == f.read_bytes(), f
    bad = vtk("data", "synth", "--out", tmp_path / "x", "--garments", 2, "--seed", 3, "--frame", "320x240",
              "--no-progress", "--only", "SilkCape")
    assert bad.returncode != 0 and "no garment SilkCape in this set" in bad.stderr and material in bad.stderr
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())
