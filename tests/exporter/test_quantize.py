"""int8 fp32 islands (found from the graph's structure) and which graphs get the ConvTranspose rewrite."""
import collections

import numpy as np
import onnx
import pytest

from exporter.calibration import calibration_set
from exporter.export import ExportConfig, export_run, rewrites_conv_transpose
from exporter.graphs import export_graph
from exporter.quantize import Calibrated, fp32_island_nodes, quantize_int8
from exporter.ranges import structural_keys, transfer
from kiosk.contract.graph import feeds
from kiosk.bundle.archive import open_bundle

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def graphs(run_dir, tmp_path_factory):
    from trainer.checkpoint import load_generator
    gen, _ = load_generator(run_dir)
    tmp = tmp_path_factory.mktemp("quant")
    return {kind: export_graph(gen, kind, tmp / f"{kind}.onnx", size=(256, 256))
            for kind in ("full", "tactile", "visual")}


def _box_sketch() -> np.ndarray:
    sketch = np.full((240, 320), 255, np.uint8)
    sketch[40:200, 60] = sketch[40:200, 260] = 0
    sketch[40, 60:261] = sketch[200, 60:261] = 0
    return sketch


def _ops(model, names):
    by = {n.name: n.op_type for n in model.graph.node}
    return collections.Counter(by[n] for n in names)


def test_islands_from_structure(graphs):
    full = onnx.load(str(graphs["full"]))
    pe = _ops(full, fp32_island_nodes(full, ["pe"]))
    assert pe["Sin"] == 2 and pe["Cos"] == 2 and pe["CumSum"] == 2 and "Conv" not in pe
    first = fp32_island_nodes(full, ["first-conv"])
    assert first == [next(n.name for n in full.graph.node if n.op_type == "Conv")]
    heads = _ops(full, fp32_island_nodes(full, ["heads"]))
    assert heads["Conv"] == 2 and heads["Tanh"] == 2 and heads["Mul"] == 2  # one chain per output
    tac = onnx.load(str(graphs["tactile"]))
    branch = fp32_island_nodes(tac, ["tactile-branch"])
    assert _ops(tac, branch)["Conv"] == 4 and _ops(tac, fp32_island_nodes(tac, ["heads"]))["Conv"] == 1
    assert fp32_island_nodes(full, []) == []
    with pytest.raises(ValueError, match="unknown fp32 island"):
        fp32_island_nodes(full, ["encoder"])


def test_int8_keeps_islands_float(graphs, run_dir, tmp_path):
    sketch = _box_sketch()
    cal = calibration_set(sketch, [(256, 256)], per_size=2)
    q = onnx.load(str(quantize_int8(graphs["full"], tmp_path / "q.onnx", cal)))
    producer = {o: n for n in q.graph.node for o in n.output}
    for node in q.graph.node:
        if node.op_type in ("Sin", "Cos", "Tanh"):  # fp32 in, not fed by a dequantized tensor
            assert all(producer.get(i) is None or producer[i].op_type != "DequantizeLinear" for i in node.input)
    convs = [n for n in q.graph.node if n.op_type == "Conv"]
    assert producer[convs[0].input[0]].op_type != "DequantizeLinear"  # first conv sees the exact PE
    assert any(producer[c.input[0]].op_type == "DequantizeLinear" for c in convs[1:])  # the rest is int8
    plain = onnx.load(str(quantize_int8(graphs["full"], tmp_path / "p.onnx", cal, fp32_islands=())))
    assert sum(n.op_type == "QuantizeLinear" for n in plain.graph.node) > \
        sum(n.op_type == "QuantizeLinear" for n in q.graph.node)


def test_histogram_calibration_over_several_sizes(graphs, tmp_path):
    """ORT's percentile/entropy calibrators fail on mixed sizes in one batch; fed one size at a time they work."""
    sketch = _box_sketch()
    cal = calibration_set(sketch, [(256, 256), (512, 256)], per_size=2)
    for method in ("percentile", "entropy"):
        out = quantize_int8(graphs["tactile"], tmp_path / f"{method}.onnx", cal, method=method)
        assert any(n.op_type == "QuantizeLinear" for n in onnx.load(str(out)).graph.node)
    with pytest.raises(ValueError, match="same number of sketches per size"):
        quantize_int8(graphs["tactile"], tmp_path / "x.onnx", cal[:3], method="percentile")


def test_rewrite_only_for_int8_and_recorded(run_dir, tmp_path):
    assert rewrites_conv_transpose("int8") and not rewrites_conv_transpose("fp32")
    assert not rewrites_conv_transpose("fp16")
    for precision in ("fp32", "int8"):
        out = tmp_path / f"{precision}.vtb"
        export_run(run_dir, out, ExportConfig(precision=precision, sizes=[(256, 256)], graphs=("tactile",),
                                              calibration_per_size=2, error_per_size=1, force=True),
                   progress=lambda *_: None)
        b = open_bundle(out, None, workdir=tmp_path / f"w{precision}", allow_unsigned=True)
        ops = {n.op_type for n in onnx.load(str(b.graph_path("tactile"))).graph.node}
        assert ("ConvTranspose" in ops) == (precision == "fp32")
        assert ("DepthToSpace" in ops) == (precision == "int8")
        prov = b.manifest.provenance
        if precision == "int8":
            assert prov["int8_fp32_islands"] == "pe,first-conv,heads" and prov["calibration"].startswith("percentile")
        else:
            assert prov["rewrite"] == "none" and "int8_fp32_islands" not in prov


def test_int8_study_table_and_json(run_dir, tmp_path, capsys):
    from exporter.bench.int8_study import main
    out = tmp_path / "study.json"
    assert main(["--run", str(run_dir), "--sizes", "256", "--variants", "minmax:;percentile:pe,heads",
                 "--per-size", "2", "--error-sketches", "1", "--timing-size", "256", "--rounds", "1",
                 "--json", str(out), "--normalization", "perceptual"]) == 0
    text = capsys.readouterr().out
    assert "| percentile:pe,heads | 256x256 |" in text and "x fp32" in text
    assert "friction in the perceptual mapping" in text and "interior max" in text
    import json
    res = json.loads(out.read_text())
    assert res["normalization"] == "perceptual"
    assert [r["fp32_islands"] for r in res["rows"]] == ["none", "pe,heads"]
    assert all(np.isfinite(r["friction_mae_levels"]) and r["tactile_mae"] > 0 for r in res["rows"])
    for r in res["rows"]:  # off-edge errors are part of the grid's, so never above its maximum
        assert 0 <= r["friction_max_interior_levels"] <= r["friction_max_levels"]
        assert 0 <= r["friction_interior_big_saturated"] <= 1 and 0 <= r["worst_interior_slope_percentile"] <= 100
    assert set(res["timing_ms"]) == {"fp32", "minmax:", "percentile:pe,heads"}


def _outputs(path, inputs):
    import onnxruntime as ort
    s = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return [s.run(None, feeds(x.sketch, x.mask)) for x in inputs]


@pytest.fixture(scope="module")
def full_ranges(graphs, tmp_path_factory):
    """The full graph calibrated once, its ranges kept: what the branch graphs take theirs from."""
    tmp = tmp_path_factory.mktemp("ranges")
    cal = calibration_set(_box_sketch(), [(256, 256)], per_size=2)
    quantize_int8(graphs["full"], tmp / "full.int8.onnx", cal, cache=tmp / "full.json")
    return cal, Calibrated.beside(tmp / "full.json")


def test_branch_graphs_take_the_full_graphs_ranges_and_come_out_identical(graphs, full_ranges, tmp_path):
    """Ranges moved by structural key give the same int8 tactile graph as calibrating it on its own (the tactile
    graph is the one whose tensor names clash with the full graph's): same scales, bit-identical outputs."""
    cal, full = full_ranges
    assert full.model.is_file() and full.cache.is_file()
    shared = quantize_int8(graphs["tactile"], tmp_path / "shared.onnx", cal, cache=tmp_path / "t.json",
                           ranges_from=full)
    alone = quantize_int8(graphs["tactile"], tmp_path / "alone.onnx", cal)
    scales = [{i.name: i.raw_data for i in onnx.load(str(p)).graph.initializer if "scale" in i.name}
              for p in (shared, alone)]
    assert scales[0] == scales[1] and scales[0]
    held = calibration_set(_box_sketch(), [(256, 256)], per_size=2, seed=7)
    for a, b in zip(_outputs(shared, held), _outputs(alone, held)):
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
    vis_pre = tmp_path / "v.pre.onnx"   # every visual tensor is in the full graph too
    from onnxruntime.quantization.shape_inference import quant_pre_process
    quant_pre_process(str(graphs["visual"]), str(vis_pre), skip_symbolic_shape=True)
    assert transfer(onnx.load(str(full.model)), full.cache, onnx.load(str(vis_pre)), tmp_path / "v.json")


def test_a_graph_computing_something_new_calibrates_itself(graphs, full_ranges, tmp_path):
    cal, _ = full_ranges
    quantize_int8(graphs["tactile"], tmp_path / "t.onnx", cal, cache=tmp_path / "t.json")
    tac = Calibrated.beside(tmp_path / "t.json")
    vis_pre = tmp_path / "v.pre.onnx"
    from onnxruntime.quantization.shape_inference import quant_pre_process
    quant_pre_process(str(graphs["visual"]), str(vis_pre), skip_symbolic_shape=True)
    # the visual decoder is not in the tactile graph: no transfer, nothing written
    assert not transfer(onnx.load(str(tac.model)), tac.cache, onnx.load(str(vis_pre)), tmp_path / "none.json")
    assert not (tmp_path / "none.json").exists()
    out = quantize_int8(graphs["visual"], tmp_path / "v.onnx", cal, cache=tmp_path / "v.json", ranges_from=tac)
    assert any(n.op_type == "QuantizeLinear" for n in onnx.load(str(out)).graph.node)
    assert (tmp_path / "v.json").is_file()   # calibrated on its own, and kept for the next graph


def _tiny(names: tuple[str, str], order: tuple[str, str] = ("Relu", "Sigmoid")) -> onnx.ModelProto:
    from onnx import TensorProto, helper
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4])
    y = helper.make_tensor_value_info(names[1], TensorProto.FLOAT, [1, 4])
    w = helper.make_tensor("w", TensorProto.FLOAT, [1, 4], [1.0, 2.0, 3.0, 4.0])
    nodes = [helper.make_node("Mul", ["x", "w"], [names[0]], name="a"),
             helper.make_node(order[0], [names[0]], ["r"], name="b"),
             helper.make_node(order[1], ["r"], [names[1]], name="c")]
    return helper.make_model(helper.make_graph(nodes, "g", [x], [y], [w]))


def test_structural_keys_follow_the_computation_not_the_names():
    a, b = structural_keys(_tiny(("m", "y"))), structural_keys(_tiny(("other", "out")))
    assert a["m"] == b["other"] and a["y"] == b["out"] and a["r"] == b["r"]
    c = structural_keys(_tiny(("m", "y"), order=("Sigmoid", "Relu")))   # same names, other computation
    assert c["m"] == a["m"] and c["r"] != a["r"] and c["y"] != a["y"]
