"""`vtkiosk bench e2e` runs against a real daemon process and reports what it promises (numbers are measured by the
benchmark, never asserted here)."""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kiosk.bench.e2e import write_section
from kiosk.bench.strokes import SPEED_PX_S, sessions
from tests.kiosk.bundle_factory import make_bundle

ROOT = Path(__file__).resolve().parents[3]


def test_sessions_are_deterministic_and_timed():
    a, b = sessions(0), sessions(0)
    assert [s.name for s in a] == ["shirt", "shorts", "skirt"]
    for sa, sb in zip(a, b):
        for x, y in zip(sa.actions, sb.actions):
            assert x.kind == y.kind and (x.stroke is None or np.array_equal(x.stroke, y.stroke))
    stroke = a[0].actions[0].stroke
    length = np.hypot(*np.diff(stroke[:, :2], axis=0).T).sum()
    assert stroke[-1, 2] == pytest.approx(1e3 * length / SPEED_PX_S, rel=1e-3)  # t in ms at the drawing speed
    assert np.all(np.diff(stroke[:, 2]) >= 0)


def test_write_section_replaces_only_the_table(tmp_path):
    doc = tmp_path / "performance.md"
    doc.write_text("# P\n\n<!-- section: e2e -->\nprose\n<!-- e2e table -->\nold\n<!-- end e2e table -->\nmore\n"
                   "<!-- end section: e2e -->\n")
    write_section(doc, "| new |")
    text = doc.read_text()
    assert "old" not in text and "| new |" in text and "prose" in text and "more" in text
    fresh = tmp_path / "fresh.md"
    write_section(fresh, "| t |")
    assert "<!-- section: e2e -->" in fresh.read_text() and "| t |" in fresh.read_text()


@pytest.mark.slow
@pytest.mark.parametrize("engine", [None, "openvino"])
def test_bench_runs_against_a_daemon_process(tmp_path, engine):
    if engine == "openvino" and importlib.util.find_spec("openvino") is None and os.environ.get("CI") != "true":
        pytest.skip("OpenVINO (vtkiosk[openvino]) is not installed")
    bundle, trusted = make_bundle(tmp_path)
    out = tmp_path / "e2e.json"
    doc = tmp_path / "perf.md"
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "bench", "e2e", "--bundle", str(bundle), "--trusted-keys",
                           str(trusted), "--repeats", "1", "--json", str(out), "--doc", str(doc)]
                          + (["--engine", engine] if engine else []), cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    s = json.loads(out.read_text())
    assert {b["engine"] for b in s["bundles"].values()} == {engine or "onnxruntime"}
    assert f"engine {engine or 'onnxruntime'}" in proc.stdout
    assert s["torch_imported"] is False and s["cpu"]["model"] and isinstance(s["cpu"]["isa"], list)
    assert s["finals"] == sum(len(x.actions) for x in sessions())
    assert s["visual_ms"]["n"] == s["finals"] and s["friction_ms"]["n"] >= s["finals_with_inference"] > 0
    assert set(s["stages_ms"]) >= {"rasterize", "plan", "inference", "friction map", "upload"}
    assert s["preview"]["frames"] > 0 and s["preview"]["fps"] > 0 and s["rss_mb"] > 0
    assert 0 < s["pixels"]["computed"] < s["pixels"]["naive_full_frame_full_graph"]
    assert set(s["goals"]) == {"p95_ms", "preview_fps", "rss_mb", "no_torch"}
    assert "stroke end -> friction frame committed on the device" in proc.stdout
    # the factory's bundle at the default panel needs more than the 256 px quick grid for its physical scale
    deferred = sum(f["deferred"] for f in s["per_final"])
    assert s["deferred_friction"] == deferred > 0 and f"refinement (texture felt > 1.1x coarser at the quick grid): " \
        f"{deferred} of {s['finals']}" in proc.stdout
    assert "stroke end -> visual available" in doc.read_text()


def test_bench_without_a_bundle_says_what_to_do(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "bench", "e2e", "--bundle", str(tmp_path / "x.vtb"),
                           "--allow-unsigned", "--repeats", "1"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "did not start" in proc.stderr
