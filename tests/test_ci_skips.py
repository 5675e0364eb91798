"""Under CI=true a test that would skip (no browser, no systemd-analyze, not root) fails instead."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = '''
import pytest
import os

def test_runs():
    pass

@pytest.mark.skipif(True, reason="needs root")
def test_marked():
    pass

def test_skips_inside():
    pytest.skip("no browser here")

@pytest.mark.xfail(reason="known")
def test_xfail():
    assert False
'''
MODULE_SKIP = "import pytest\npytest.importorskip('no_such_module_for_ci_test')\n\ndef test_x():\n    pass\n"


def _pytest(folder: Path, ci: str | None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    if ci is not None:
        env["CI"] = ci
    return subprocess.run([sys.executable, "-m", "pytest", "-p", "tests.ci_skips", "-q", "-p", "no:cacheprovider",
                           "--continue-on-collection-errors", "--rootdir", str(folder), str(folder)], cwd=ROOT,
                          env={**env, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=300)


@pytest.fixture()
def sample(tmp_path) -> Path:
    (tmp_path / "test_sample.py").write_text(SAMPLE)
    (tmp_path / "test_module_skip.py").write_text(MODULE_SKIP)
    return tmp_path


def test_locally_a_skip_stays_a_skip(sample):
    out = _pytest(sample, None)
    assert out.returncode == 0, out.stdout
    assert "1 passed, 3 skipped, 1 xfailed" in out.stdout


def test_under_ci_every_skip_fails_and_names_its_reason(sample):
    out = _pytest(sample, "true")
    assert out.returncode == 1
    assert "1 failed, 1 passed, 1 xfailed, 2 errors" in out.stdout and "skipped" not in out.stdout.splitlines()[-1]
    for reason in ("needs root", "no browser here", "no_such_module_for_ci_test"):
        assert reason in out.stdout
