"""`vtkiosk demo` (the README's main job) builds its assets once and reuses them."""
import subprocess
import sys


def test_demo_builds_then_reuses(tmp_path):
    cmd = [sys.executable, "-m", "vtkiosk", "demo", "--workdir", str(tmp_path), "--garments", "2"]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr
    assert "generating 2 synthetic garments" in first.stdout
    sheets = sorted((tmp_path / "sheets").glob("*.png"))
    assert len(sheets) == 2
    second = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert second.returncode == 0, second.stderr
    assert "reusing synthetic garments" in second.stdout
