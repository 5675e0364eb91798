"""`vtkiosk study ...`: expected failures are one line on stderr and exit status 2, never a traceback."""
from __future__ import annotations

import subprocess
import sys

import pytest

from .conftest import write_study
from .simulate import ROOT
from .study_bundles import make_study_bundles


def _vtkiosk(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vtkiosk.cli", "study", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def _one_line_error(proc: subprocess.CompletedProcess, text: str) -> None:
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("vtkiosk study: error:")]
    assert len(lines) == 1 and text in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


def test_malformed_config(tmp_path, study_env):
    bad = write_study(tmp_path, study_env, name="bad", time_limit_s=-3)
    _one_line_error(_vtkiosk("run", "--config", str(bad)), "time_limit_s must be between 1 and 3600")
    (tmp_path / "x.yaml").write_text("id: [")
    _one_line_error(_vtkiosk("run", "--config", str(tmp_path / "x.yaml")), "not valid YAML")


def test_bundle_without_reference_assets(tmp_path):
    make_study_bundles(tmp_path, ["ours", "pix2pix"], ["g00", "g01"], drop_asset=("ours", "g00", "mask"))
    cfg = write_study(tmp_path, (tmp_path, tmp_path / "trusted"), name="noasset", garments=["g00", "g01"],
                      test_garments=1,
                      conditions={c: str(tmp_path / "bundles" / c / "{garment}.vtb") for c in ("ours", "pix2pix")})
    _one_line_error(_vtkiosk("run", "--config", str(cfg)), "has no reference asset(s) mask")
    assert not (tmp_path / "noasset.sock").exists() and not (tmp_path / "noasset.jsonl").exists()


@pytest.mark.parametrize("args, text", [
    (["report", "--log", "{tmp}/none.jsonl"], "no study log at"),
    (["export", "--log", "{tmp}/none.jsonl", "--out", "{tmp}/t.csv"], "no study log at"),
    (["start", "--config", "{cfg}", "--participant", "P01"], "no kiosk daemon is listening"),
    (["status", "--socket", "{tmp}/nothing.sock"], "no kiosk daemon is listening"),
])
def test_operator_and_analysis_errors(tmp_path, study_env, args, text):
    cfg = write_study(tmp_path, study_env)
    _one_line_error(_vtkiosk(*[a.format(tmp=tmp_path, cfg=cfg) for a in args]), text)
