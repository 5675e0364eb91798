"""`vtkiosk demo` (the README's main job): builds a signed demo bundle with our trainer and exporter, caches it,
and serves it with the emulated haptic device; once built it starts in seconds."""
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kiosk.bundle.archive import open_bundle
from kiosk.bundle.signature import load_trusted_keys
from tests.kiosk.daemon_fixtures import demo_build

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_demo_builds_a_signed_bundle_then_starts_from_cache(tmp_path_factory, tmp_path):
    bundle, trusted, out = demo_build(tmp_path_factory)
    if "reusing the demo bundle" not in out:        # a kept build (VTKIOSK_TEST_DEMO_DIR) shows no stages
        stages = [line for line in out.splitlines() if line.startswith("demo: [")]
        assert [s[:11] for s in stages if s.endswith("...")] == ["demo: [1/3]", "demo: [2/3]", "demo: [3/3]"], out
        assert any(line.startswith("demo:   | ") and "step 2/2" in line for line in out.splitlines()), out
    workdir = bundle.parents[2]
    key = workdir / "keys" / "demo.key"
    assert stat.S_IMODE(key.stat().st_mode) == 0o600
    b = open_bundle(bundle, load_trusted_keys(trusted), workdir=tmp_path)  # signature, hashes, schema
    m = b.manifest
    assert b.key_id is not None and set(m.graphs) == {"full", "tactile", "visual"}
    assert all(g.precision == "int8" for g in m.graphs.values()) and m.friction_scale > 0
    log = (bundle.parent / "build.log").read_text()
    assert "train --data" in log and "--preset demo" in log and "export --run" in log  # our own tools built it
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "demo", "--quick", "--workdir", str(workdir), "--steps", "2",
                           "--exit-after-ready", "--port", "0"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    took = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr
    assert "reusing the demo bundle" in proc.stdout
    assert "kiosk serving denim-shorts at http://127.0.0.1:" in proc.stdout
    print(f"cached demo start-up: {took:.1f} s")  # measured, not asserted (the machine is shared)


def test_demo_refuses_a_missing_bundle(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "demo", "--bundle", str(tmp_path / "nope.vtb"),
                           "--allow-unsigned", "--exit-after-ready", "--port", "0"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2 and "no such bundle" in proc.stderr
