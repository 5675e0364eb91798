"""`vtkiosk bench threads` end to end on a tiny real bundle (sweep + lanes in the kiosk's own daemon, JSON, PNG),
its one-line errors, and the pure parts (bootstrap interval, table, ratios)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from exporter.bench.threads import lanes_table, p50_interval, ratios, sweep_table
from tests.exporter.conftest import vtk
from tests.kiosk.bundle_factory import conv_graph, make_bundle

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_bench_threads_runs_end_to_end_and_writes_json(tmp_path):
    bundle, trusted = make_bundle(tmp_path, graph=conv_graph)
    out_json, out_png = tmp_path / "t.json", tmp_path / "t.png"
    proc = vtk("bench", "threads", "--bundle", bundle, "--trusted-keys", trusted, "--engines", "onnxruntime",
               "--sweep", "threads", "--splits", "previews-alone,refines-alone,one-loop,2+1", "--runs", 2, "--warmup", 0,
               "--rounds", 1, "--seconds", 0.5, "--json", out_json, "--plot", out_png, "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "| work | graph | grid | engine | setting |" in proc.stdout and "| split | preview fps |" in proc.stdout
    assert "CPU: " in proc.stdout and "ISA" in proc.stdout
    res = json.loads(out_json.read_text())
    assert res["schema"] == "vtkiosk-bench-threads/1" and res["environment"]["cpu"]
    assert isinstance(res["environment"]["isa"], list)
    assert res["work"]["preview"]["graph"] == "visual" and res["work"]["refine"]["graph"] == "full"
    timed = [r for r in res["sweep"] if r["setting"] != "oracle"]
    # the untuned reference, then the defaults at 1 and 2 threads, for both planned graphs
    assert sorted((r["work"], r["setting"]) for r in timed) == sorted(
        (w, s) for w in ("preview", "refine") for s in ("2t seq spin", "1t seq", "2t seq"))
    for r in timed:
        assert len(r["times_ms"]) == 2 and res["settings"]["rounds"] == 1
        assert 0 < r["p50_ms"] <= r["p95_ms"] and r["peak_rss_mb"] > 0
        assert r["precision"] == "fp32" and r["stated_friction_mae_levels"] == 0.0
        assert r["max_abs_diff_vs_ref_run"] is not None and r["scheduling_only"]  # thread count: same result
    assert {r["work"] for r in res["sweep"] if r["setting"] == "oracle"} == {"preview", "refine"}
    splits = {r["id"]: r for r in res["lanes"]}
    assert set(splits) == {"previews-alone", "refines-alone", "one-loop", "2+1"}
    assert splits["previews-alone"]["refines_per_s"] is None and splits["previews-alone"]["preview"]["n"] > 0
    assert splits["refines-alone"]["preview_fps"] is None and splits["refines-alone"]["refine"]["n"] > 0
    for key in ("one-loop", "2+1"):
        assert splits[key]["preview"]["n"] > 0 and splits[key]["refine"]["n"] > 0
        assert splits[key]["preview_grid"] == res["work"]["preview"]["grid"]
    assert splits["2+1"]["preview_threads"] == 1 and splits["one-loop"]["preview_threads"] == 0
    assert out_png.read_bytes()[:8] == PNG_MAGIC


@pytest.mark.parametrize("args, message", [
    (["--splits", "3+3"], "--splits: choose from"),
    (["--engines", "tensorrt"], "--engines: choose from"),
    (["--runs", "1"], "--runs must be at least 2"),
])
def test_bad_options_give_one_line_and_no_traceback(tmp_path, args, message):
    bundle, _ = make_bundle(tmp_path)
    proc = vtk("bench", "threads", "--bundle", bundle, *args, "--no-progress", timeout=120)
    assert proc.returncode != 0
    assert message in proc.stderr + proc.stdout and "Traceback" not in proc.stderr


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.1, 1e4), min_size=2, max_size=40))
def test_bootstrap_interval_lies_within_the_data(times):
    lo, hi = p50_interval(times, resamples=200)
    assert min(times) <= lo <= hi <= max(times)


def test_tables_say_what_the_error_column_means():
    row = {"work": "refine", "graph": "full", "grid": "512x512", "engine": "onnxruntime", "setting": "2t seq",
           "reference_row": None, "p50_ms": 10.0, "p95_ms": 12.0, "p50_ci_ms": [9.0, 11.0], "peak_rss_mb": 100.0,
           "precision": "int8", "stated_friction_mae_levels": 0.8, "stated_visual_psnr_db": 40.0,
           "max_abs_diff_vs_ref_run": 0.0, "max_abs_diff_vs_ort": 0.0, "scheduling_only": True}
    text = sweep_table([row, {**row, "max_abs_diff_vs_ref_run": 0.09, "scheduling_only": False}])
    assert "0 (scheduling only)" in text and "friction MAE 0.80 levels (int8)" in text
    assert "9.0e-02 (different kernels)" in text


def test_lane_ratios_are_against_the_one_loop_in_the_same_run():
    def row(split, fps, rps, ref=None):
        return {"split": split, "preview_fps": fps, "refines_per_s": rps, "reference_row": ref,
                "preview": {"p50_ms": 1.0, "p95_ms": 2.0, "p50_ci_ms": [1.0, 1.0]},
                "refine": {"p50_ms": None, "p95_ms": None}, "peak_rss_mb": 1.0}
    rows = [row("reference: previews alone (2 threads)", 8.0, None, "ref"),
            row("one loop, 2 threads (previews wait for the refinement)", 2.0, 1.0),
            row("lanes: refine 1 + preview 1", 4.0, 0.5)]
    assert ratios(rows) == ["lanes: refine 1 + preview 1: preview fps x2.00 the one loop's (50% of previews "
                            "alone), refinements/s x0.50"]
    assert lanes_table(rows).count("\n") == len(rows) + 1
    assert np.isfinite(rows[1]["preview_fps"])
