"""`vtkiosk bench infer` on a real (briefly trained) run: table, JSON, PNG, errors, references; and the pure parts
(Pareto front, goal verdicts, table) on their own."""
import json
import math
import shutil

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from exporter.bench.plot import pareto
from exporter.bench.report import goals, markdown_table
from exporter.export import ExportConfig, export_run
from tests.exporter.conftest import vtk

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _export(run, out, precision, sizes=((256, 256), (512, 512))):
    cfg = ExportConfig(precision=precision, sizes=list(sizes), calibration_per_size=2, error_per_size=1,
                       graphs=("full", "tactile"), force=True)
    export_run(run, out, cfg, progress=lambda *_: None)
    return out


@pytest.fixture(scope="module")
def fp32_bundle(run_dir, tmp_path_factory):
    return _export(run_dir, tmp_path_factory.mktemp("bench") / "g32.vtb", "fp32")


@pytest.mark.slow
def test_bench_fp32_bundle_with_run(fp32_bundle, run_dir, tmp_path):
    out_json, out_png = tmp_path / "b.json", tmp_path / "b.png"
    # the manifest names its run relative to the export's working folder (or by a hash): name it here
    proc = vtk("bench", "infer", "--bundle", fp32_bundle, "--run", run_dir, "--precisions", "fp32,int8", "--runs", 3, "--warmup", 1,
               "--error-sketches", 1, "--json", out_json, "--plot", out_png, "--profile", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "| graph | size | prec |" in proc.stdout and "goals at the bundle's precision (fp32)" in proc.stdout
    assert "profile full 512x512 fp32" in proc.stdout
    assert out_png.read_bytes()[:8] == PNG_MAGIC and out_png.stat().st_size > 10_000
    res = json.loads(out_json.read_text())
    assert res["schema"] == "vtkiosk-bench-infer/1" and res["settings"]["runs"] == 3
    assert res["settings"]["wait"] == "passive" and "2 threads, passive wait" in proc.stdout
    assert res["reference"] == "the bundle's own fp32 graphs"
    rows = res["rows"]
    # 2 sizes x 2 graphs x (fp32 from the bundle, int8 built from the run, PyTorch eager)
    assert len(rows) == 12
    assert {(r["precision"], r["source"]) for r in rows} == {("fp32", "bundle"), ("int8", "run"), ("fp32", "torch")}
    for r in rows:
        assert len(r["times_ms"]) == 3 and 0 < r["p50_ms"] <= r["p95_ms"]
        assert 0 < r["base_rss_mb"] < r["peak_rss_mb"]
        for key in ("tactile_mae", "friction_mae_levels", "friction_max_levels"):
            assert math.isfinite(r[key]) and r[key] >= 0
        assert ("visual_psnr_db" in r) == (r["graph"] == "full")
        torch = r["provider"] == "torch-eager"
        assert (r["speedup_vs_torch"] is None) == torch
    ref = [r for r in rows if r["source"] == "bundle"]
    for r in ref:  # the reference against itself: exactly zero, PSNR at its 'identical' sentinel
        assert r["tactile_mae"] == 0.0 and r["friction_mae_levels"] == 0.0 and r["friction_max_levels"] == 0.0
        if r["graph"] == "full":
            assert r["visual_psnr_db"] == 99.0
    eager = [r for r in rows if r["provider"] == "torch-eager"]
    assert all(r["tactile_mae"] < 1e-4 for r in eager)  # parity: PyTorch and ONNX fp32 agree
    int8 = [r for r in rows if r["precision"] == "int8"]
    assert all(r["tactile_mae"] > 0 for r in int8)
    # full-field ground truth: the synthetic garment fits a 512 canvas at its training scale
    at512 = [r for r in rows if r["size"] == "512x512"]
    assert all(math.isfinite(r["full_angle_deg"]) and math.isfinite(r["full_friction_mae"]) for r in at512)
    assert {r["goal"].split(":")[0] for r in res["goals"]} >= {"full graph (both outputs) at 1536x1536"}
    assert res["goals"][0]["met"] is None  # 1536 not measured here
    assert res["profiles"][0]["ops"] and abs(sum(o["share"] for o in res["profiles"][0]["ops"]) - 1) < 1e-6


@pytest.mark.slow
def test_bench_without_run_uses_reference_bundle(run_dir, fp32_bundle, tmp_path):
    gone = tmp_path / "gone"
    shutil.copytree(run_dir, gone)
    int8 = _export(gone, tmp_path / "g8.vtb", "int8", sizes=((256, 256),))
    shutil.rmtree(gone)  # the bundle's source run is no longer here
    args = ["bench", "infer", "--bundle", int8, "--runs", 2, "--warmup", 0, "--error-sketches", 1, "--no-progress",
            "--graphs", "tactile", "--json", tmp_path / "a.json"]
    proc = vtk(*args)
    assert proc.returncode == 0, proc.stderr
    res = json.loads((tmp_path / "a.json").read_text())
    assert [(r["precision"], r["source"]) for r in res["rows"]] == [("int8", "bundle")]
    assert res["rows"][0].get("friction_mae_levels") is None
    assert any("no fp32 reference" in n for n in res["notes"]) and "note: " in proc.stdout
    proc = vtk(*args[:-1], tmp_path / "b.json", "--reference", fp32_bundle)
    assert proc.returncode == 0, proc.stderr
    res = json.loads((tmp_path / "b.json").read_text())
    # the reference bundle was exported from the same checkpoint: it becomes the fp32 row and the reference
    assert {(r["precision"], r["source"]) for r in res["rows"]} == {("int8", "bundle"), ("fp32", "reference")}
    row = next(r for r in res["rows"] if r["precision"] == "int8")
    assert 0 < row["tactile_mae"] < 1 and math.isfinite(row["friction_mae_levels"])


@pytest.mark.slow
def test_bench_errors_are_one_line(fp32_bundle, run_dir, tmp_path):
    other = tmp_path / "other"
    shutil.copytree(run_dir, other)
    ck = other / "checkpoints" / "best.pt"
    ck.write_bytes(ck.read_bytes() + b"\0")  # a different checkpoint than the bundle's
    for extra, match in ((["--run", other], "SHA-256"), (["--run", tmp_path / "nope"], "no checkpoints"),
                         (["--providers", "NoSuchExecutionProvider"], "not present"),
                         (["--sizes", "300"], "multiples of 256")):
        proc = vtk("bench", "infer", "--bundle", fp32_bundle, "--runs", 1, "--no-progress", *extra)
        assert proc.returncode == 2, (extra, proc.stdout, proc.stderr)
        assert match in proc.stderr and "Traceback" not in proc.stderr


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.1, 1e4), st.floats(0, 100)), min_size=1, max_size=30))
def test_pareto_front_is_exactly_the_non_dominated_points(points):
    front = set(pareto(points))

    def dominated(i):
        return any(j != i and points[j][0] <= points[i][0] and points[j][1] <= points[i][1]
                   and points[j] != points[i] for j in range(len(points)))
    for i in range(len(points)):
        if dominated(i):
            assert i not in front
    for i in range(len(points)):  # every point is matched or beaten by one on the front
        assert any(points[j][0] <= points[i][0] and points[j][1] <= points[i][1] for j in front)


def _row(graph, size, precision, p50, source="bundle", provider="CPUExecutionProvider", **kw):
    return {"graph": graph, "size": size, "precision": precision, "provider": provider, "source": source,
            "p50_ms": p50, "p95_ms": p50 * 1.1, "peak_rss_mb": 100.0, **kw}


def test_goal_verdicts():
    rows = [_row("full", "1536x1536", "int8", 450.0, speedup_vs_torch=2.5, visual_psnr_db=50.0,
                 friction_mae_levels=0.8),
            _row("tactile", "512x512", "int8", 40.0, speedup_vs_torch=6.0, friction_mae_levels=1.3),
            _row("full", "1536x1536", "fp32", 700.0, source="run", speedup_vs_torch=1.6, friction_mae_levels=0.0),
            _row("full", "1536x1536", "fp32", 1100.0, source="torch", provider="torch-eager")]
    g = {x["goal"].split(":")[0].split(" <=")[0].split(" >=")[0]: x for x in goals(rows, {"full": "int8",
                                                                                         "tactile": "int8"})}
    speed = g["full graph (both outputs) at 1536x1536"]
    assert speed["met"] is False and speed["value"] == 450.0 and "5.0x the budget" in speed["note"]
    ratio = next(x for x in g.values() if "PyTorch" in x["goal"])
    assert ratio["met"] is False and ratio["value"] == 2.5  # the worst of the bundle's own rows
    fr = next(x for x in g.values() if "friction" in x["goal"])
    assert fr["met"] is False and fr["value"] == 1.3 and "tactile 512x512" in fr["note"]
    ps = next(x for x in g.values() if "PSNR" in x["goal"])
    assert ps["met"] is True and ps["value"] == 50.0
    assert all(x["met"] is None for x in goals([], {"full": "int8"}))


def test_markdown_table_marks_undeclared_sizes_and_missing_values():
    text = markdown_table([_row("full", "768x768", "fp16", 12.345, declared=False)])
    line = text.splitlines()[2]
    assert "768x768*" in line and "12.3" in line and "| - |" in line
    assert len(text.splitlines()[0].split("|")) == len(line.split("|"))
