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
    out_json, out_png, out_pareto = tmp_path / "b.json", tmp_path / "b.png", tmp_path / "p.png"
    # the manifest names its run relative to the export's working folder (or by a hash): name it here
    proc = vtk("bench", "infer", "--bundle", fp32_bundle, "--run", run_dir, "--precisions", "fp32,int8",
               "--sizes", "512", "--graphs", "full", "--runs", 2, "--warmup", 1, "--error-sketches", 1,
               "--json", out_json, "--plot", out_png, "--pareto", out_pareto, "--profile", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "| setting | grid | graph | engine |" in proc.stdout
    assert "goals at the bundle's precision (fp32)" in proc.stdout
    assert "profile full 512x512 fp32" in proc.stdout and "bundle: " in proc.stdout
    for png in (out_png, out_pareto):
        assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size > 10_000
    res = json.loads(out_json.read_text())
    assert res["schema"] == "vtkiosk-bench-infer/2" and res["settings"]["runs"] == 2
    assert res["settings"]["wait"] == "passive" and "2 threads, passive wait" in proc.stdout
    assert res["reference"] == "the bundle's own fp32 graphs"
    assert res["bundle"]["bytes"] == fp32_bundle.stat().st_size
    b = res["bundle"]   # the exporter's shared layout: both graphs read one weights file
    assert list(b["weights_bytes"]) == ["graphs/weights.bin"] and "shared weights" in proc.stdout
    assert b["embedded_graph_bytes"] > 1.5 * (sum(b["graph_bytes"].values()) + b["weights_bytes"]["graphs/weights.bin"])
    canvas = [r for r in res["rows"] if r["setting"] == "512x512 canvas"]
    timed = [r for r in canvas if r["engine"] != "flat"]
    # every engine x (fp32 native, int8 on the rewrite, int8 native), plus PyTorch eager
    forms = (("fp32", "native"), ("int8", "rewritten"), ("int8", "native"))
    assert sorted((r["engine"], r["precision"], r["form"]) for r in timed) == sorted(
        [(e, p, f) for e in ("onnxruntime", "openvino") for p, f in forms] + [("torch", "fp32", "native")])
    for r in timed:
        assert len(r["times_ms"]) == 2 and 0 < r["p50_ms"] <= r["p95_ms"]
        assert 0 < r["base_rss_mb"] < r["peak_rss_mb"]
        for key in ("tactile_mae", "friction_mae_levels", "friction_max_levels", "full_angle_deg"):
            assert math.isfinite(r[key]) and r[key] >= 0
        assert 0.0 <= r["friction_felt_garment_fraction"] <= 1.0
        assert (r["speedup_vs_torch"] is None) == (r["engine"] == "torch")
        assert (r["graph_bytes"] is None) == (r["engine"] == "torch") and r["gmac"] > 0
    native = {r["gmac"] for r in timed if r["form"] == "native"}
    rewritten = {r["gmac"] for r in timed if r["form"] == "rewritten"}
    assert len(native) == 1 and len(rewritten) == 1 and 1.5 < rewritten.pop() / native.pop() < 2.5
    ref = next(r for r in timed if r["source"] == "bundle" and r["engine"] == "onnxruntime")
    assert ref["tactile_mae"] == 0.0 and ref["friction_mae_levels"] == 0.0 and ref["visual_psnr_db"] == 99.0
    assert ref["friction_felt_garment_fraction"] == 0.0 and "felt px %" in proc.stdout
    ov = next(r for r in timed if r["source"] == "bundle" and r["engine"] == "openvino")
    assert ov["friction_mae_levels"] < 0.1  # same fp32 graph in another engine: rounding only
    eager = next(r for r in timed if r["engine"] == "torch")
    assert eager["tactile_mae"] < 1e-4  # parity: PyTorch and ONNX fp32 agree
    assert all(r["tactile_mae"] > 0 for r in timed if r["precision"] == "int8")
    flat = [r for r in canvas if r["engine"] == "flat"]
    assert len(flat) == 1 and flat[0]["full_angle_deg"] > 0 and "p50_ms" not in flat[0]
    planner = [r for r in res["rows"] if r["setting"].startswith("planner: ")]
    assert {r["setting"].split(",")[1].strip() for r in planner} == {"physical scale", "panel pixels"}
    for r in planner:
        assert math.isfinite(r["full_angle_deg"]) and all(int(v) % 256 == 0 for v in r["size"].split("x"))
    assert {r["engine"] for r in planner} == {"flat", "torch", "onnxruntime", "openvino"}
    assert res["goals"][0]["met"] is None  # 1536 not measured here
    assert res["profiles"][0]["ops"] and abs(sum(o["share"] for o in res["profiles"][0]["ops"]) - 1) < 1e-6


@pytest.mark.slow
def test_bench_without_run_uses_reference_bundle(run_dir, fp32_bundle, tmp_path):
    gone = tmp_path / "gone"
    shutil.copytree(run_dir, gone)
    int8 = _export(gone, tmp_path / "g8.vtb", "int8", sizes=((256, 256),))
    shutil.rmtree(gone)  # the bundle's source run is no longer here
    args = ["bench", "infer", "--bundle", int8, "--runs", 2, "--warmup", 0, "--error-sketches", 1, "--no-progress",
            "--graphs", "tactile", "--engines", "onnxruntime", "--no-planner", "--json", tmp_path / "a.json"]
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
                         (["--sizes", "300"], "multiples of 256"), (["--engines", "tensorflow"], "choose from")):
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


def _row(graph, size, precision, p50, source="bundle", engine="onnxruntime", form="native", **kw):
    provider = {"onnxruntime": "CPUExecutionProvider", "openvino": "CPU", "torch": "torch-eager"}[engine]
    return {"graph": graph, "size": size, "setting": f"{size} canvas", "precision": precision, "provider": provider,
            "engine": engine, "form": form, "source": source, "p50_ms": p50, "p95_ms": p50 * 1.1,
            "peak_rss_mb": 100.0, **kw}


def test_goal_verdicts_take_the_best_engine_within_the_error_goal():
    rows = [_row("full", "1536x1536", "int8", 450.0, form="rewritten", speedup_vs_torch=2.5, visual_psnr_db=50.0,
                 friction_mae_levels=0.8),
            # faster, but outside the error goal: not eligible as "best"
            _row("full", "1536x1536", "int8", 100.0, engine="openvino", source="run", speedup_vs_torch=11.0,
                 friction_mae_levels=1.4),
            _row("full", "1536x1536", "fp32", 300.0, engine="openvino", source="run", speedup_vs_torch=3.7,
                 friction_mae_levels=0.0),
            _row("tactile", "512x512", "int8", 40.0, form="rewritten", speedup_vs_torch=6.0, friction_mae_levels=1.3),
            _row("full", "1536x1536", "fp32", 1100.0, source="torch", engine="torch"),
            {**_row("full", "1536x1536", "fp32", 10.0, engine="openvino", friction_mae_levels=0.0),
             "setting": "planner: refine 512, physical scale"}]  # planner rows are not the canvas goal
    g = goals(rows, {"full": "int8", "tactile": "int8"})
    speed, ratio, fr, ps = g
    assert speed["met"] is False and speed["value"] == 300.0 and "openvino fp32 native" in speed["note"]
    assert "3.3x the budget" in speed["note"]
    assert ratio["met"] is False and ratio["value"] == 3.7
    assert fr["met"] is False and fr["value"] == 1.3 and "tactile 512x512" in fr["note"]
    assert ps["met"] is True and ps["value"] == 50.0
    assert all(x["met"] is None for x in goals([], {"full": "int8"}))


def test_markdown_table_marks_undeclared_sizes_and_missing_values():
    text = markdown_table([_row("full", "768x768", "fp16", 12.345, declared=False, graph_bytes=2_500_000),
                           _row("full", "768x768", "fp32", 50.0, engine="torch")])
    line = text.splitlines()[2]
    assert "768x768*" in line and "12.3" in line and "| - |" in line and "| 2.50 |" in line
    assert "| torch eager |" in text.splitlines()[3]
    assert len(text.splitlines()[0].split("|")) == len(line.split("|"))
