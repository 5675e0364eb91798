"""One briefly trained run shared by the exporter tests (training is the slow part; nothing is downloaded)."""
import subprocess
import sys

import pytest


def vtk(*args, timeout=900):
    return subprocess.run([sys.executable, "-m", "vtkiosk", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="session")
def run_dir(tmp_path_factory):
    """A tiny-preset run on one synthetic garment (320x240 frame, with full-field ground truth)."""
    tmp = tmp_path_factory.mktemp("export")
    data = tmp / "data"
    proc = vtk("data", "synth", "--out", data, "--garments", 1, "--frame", "320x240", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    run = tmp / "run"
    proc = vtk("train", "--data", data, "--garment", "DenimShorts", "--preset", "tiny", "--steps", 2, "--out", run)
    assert proc.returncode == 0, proc.stderr
    return run
