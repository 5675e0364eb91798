"""Two bench e2e settings side by side: percentiles over pooled stroke ends, ratio and a bootstrap interval."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.bench.e2e_ratio import compare, main, ratio


def _run(path, visual, friction, refined=None):
    finals = [{"visual_ms": v, "friction_ms": f, "refine_visual_ms": r, "refine_friction_ms": r}
              for v, f, r in zip(visual, friction, refined or [None] * len(visual))]
    path.write_text(json.dumps({"per_final": finals}))
    return path


def test_pooled_percentiles_and_ratio(tmp_path):
    a = [_run(tmp_path / "a1.json", [10, 20], [40, None]), _run(tmp_path / "a2.json", [30], [60])]
    b = [_run(tmp_path / "b1.json", [20, 40, 60], [20, 30, 40], [70, 80, 90])]
    res = compare(a, b)
    assert res["visual_ms"]["n"] == [3, 3] and res["friction_ms"]["n"] == [2, 3]  # None is no event, not 0
    p50 = res["visual_ms"]["p50"]
    assert p50["a"] == 20 and p50["b"] == 40 and p50["ratio"] == pytest.approx(0.5)
    assert p50["ci"][0] <= 0.5 <= p50["ci"][1]
    assert res["refine_visual_ms"]["p50"]["ratio"] is None  # A never refined: no ratio to state


@settings(max_examples=50, deadline=None)
@given(a=st.lists(st.floats(0.0, 1e4), min_size=1, max_size=40), b=st.lists(st.floats(0.0, 1e4), min_size=1,
                                                                            max_size=40))
def test_ratio_never_divides_by_zero_and_brackets_itself(a, b):
    r = ratio(np.asarray(a), np.asarray(b), 50, rounds=200)
    if np.percentile(b, 50) < 1e-6:
        assert r["ratio"] is None
    else:
        assert np.isfinite(r["ratio"])
        assert r["ci"] is None or (r["ci"][0] <= r["ci"][1] and all(np.isfinite(r["ci"])))


def test_command_prints_a_table_writes_json_and_refuses_a_bad_file(tmp_path, capsys):
    a = _run(tmp_path / "a.json", [10, 12], [20, 22])
    b = _run(tmp_path / "b.json", [20, 24], [10, 11])
    out, png = tmp_path / "r.json", tmp_path / "r.png"
    assert main(["--a", str(a), "--b", str(b), "--names", "new", "old", "--json", str(out), "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = capsys.readouterr().out
    assert "| measure (ms) | n | new p50 | old p50 |" in text and "stroke end -> visual available" in text
    assert json.loads(out.read_text())["measures"]["friction_ms"]["p50"]["ratio"] == pytest.approx(21 / 10.5)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["--a", str(bad), "--b", str(b)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "not a `vtkiosk bench e2e --json` file" in err


def test_it_is_a_vtkiosk_bench_subcommand(tmp_path):
    import subprocess
    import sys
    from pathlib import Path
    a = _run(tmp_path / "a.json", [10, 12], [20, 22])
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "bench", "e2e-compare", "--a", str(a), "--b", str(a)],
                          cwd=root, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "| stroke end -> visual available | 2 / 2 | 11.0 | 11.0 | 1.00" in proc.stdout
