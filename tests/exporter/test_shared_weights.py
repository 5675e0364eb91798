"""exporter.shared_weights and the export's shared layout: each distinct tensor is written once, the graphs read
back the same tensors, and an int8 export of a trained run states the same error as the embedded layout with
about half the bytes."""
from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

from exporter.export import ExportConfig, export_run
from exporter.shared_weights import ALIGN, share_weights
from kiosk.bundle.archive import open_bundle
from kiosk.bundle.manifest import EMBEDDED_SCHEMA, SCHEMA_VERSION
from kiosk.bundle.weights import external_refs
from kiosk.contract.graph import feeds
from kiosk.contract.sketch import letterbox, network_input, object_mask
from kiosk.inference.backends import available, open_graph
from tests.kiosk.bundle_factory import conv_graph


def _tensors(path) -> dict[str, np.ndarray]:
    return {t.name: numpy_helper.to_array(t) for t in onnx.load(str(path)).graph.initializer}


def test_each_distinct_tensor_is_written_once_and_read_back_unchanged(tmp_path):
    (tmp_path / "g").mkdir()
    graphs = {"full": conv_graph(tmp_path / "g" / "full.onnx", ["visual", "tactile"]),
              "tactile": conv_graph(tmp_path / "g" / "tactile.onnx", ["tactile"]),
              "visual": conv_graph(tmp_path / "g" / "visual.onnx", ["visual"])}
    out, weights, report = share_weights(graphs, tmp_path / "s")
    before = {k: _tensors(p) for k, p in graphs.items()}
    for kind, path in out.items():   # onnx reads the external data back: every tensor equals the embedded one
        after = _tensors(path)
        assert after.keys() == before[kind].keys()
        assert all(np.array_equal(after[n], before[kind][n]) and after[n].dtype == before[kind][n].dtype
                   for n in after)
    distinct = {(a.dtype.str, a.shape, a.tobytes()) for b in before.values() for a in b.values()}
    assert report.distinct == len(distinct) and report.tensors == sum(len(b) for b in before.values())
    assert report.weights_bytes == weights.stat().st_size < report.embedded_bytes
    assert sum(len(d[2]) for d in distinct) <= report.weights_bytes < sum(len(d[2]) + ALIGN for d in distinct)
    # the tactile decoder's weights differ between the full and the tactile graph (drawn in another order)
    assert report.differing == ["w_tactile"]
    refs = [r for p in out.values() for r in external_refs(p.read_bytes())]
    assert all(r.offset % ALIGN == 0 for r in refs)


def test_small_tensors_stay_inside_their_graph(tmp_path):
    (tmp_path / "g").mkdir()
    graphs = {"full": conv_graph(tmp_path / "g" / "full.onnx", ["visual", "tactile"])}
    out, _, report = share_weights(graphs, tmp_path / "s", min_bytes=100)
    refs = {r.tensor for r in external_refs(out["full"].read_bytes())}
    assert refs == {"w1", "w_visual", "w_tactile"}      # b1 (16 floats, 64 bytes) stays embedded
    with pytest.raises(ValueError, match="must differ"):
        share_weights({"a": graphs["full"], "b": graphs["full"]}, tmp_path / "t")


@pytest.mark.slow
def test_int8_export_shares_weights_at_the_same_stated_error(run_dir, tmp_path):
    """The same run exported twice at int8, shared and embedded: identical stated errors, identical outputs in
    both engines, and the shared bundle holds each shared-encoder tensor once (no per-graph calibration drift)."""
    cfg = dict(precision="int8", sizes=[(256, 256)], calibration_per_size=3, error_per_size=2, force=True)
    shared = export_run(run_dir, tmp_path / "s.vtb", ExportConfig(**cfg), progress=lambda *_: None)
    embedded = export_run(run_dir, tmp_path / "e.vtb", ExportConfig(**cfg, share_weights=False),
                          progress=lambda *_: None)
    assert shared.errors == embedded.errors
    assert shared.manifest.schema_version == SCHEMA_VERSION and embedded.manifest.schema_version == EMBEDDED_SCHEMA
    assert "differing" not in shared.manifest.provenance["weights"]
    assert (tmp_path / "s.vtb").stat().st_size < 0.7 * (tmp_path / "e.vtb").stat().st_size
    s = open_bundle(tmp_path / "s.vtb", None, workdir=tmp_path / "ws", allow_unsigned=True)
    e = open_bundle(tmp_path / "e.vtb", None, workdir=tmp_path / "we", allow_unsigned=True)
    assert all(g.weights == "graphs/weights.bin" for g in s.manifest.graphs.values())
    fitted, _ = letterbox(s.asset("sketch"), (256, 256))
    x = network_input(fitted, object_mask(fitted))
    for engine in available():
        for kind, spec in s.manifest.graphs.items():
            got = open_graph(engine, s.graph_path(kind), threads=1).run(spec.outputs, feeds(x.sketch, x.mask))
            want = open_graph(engine, e.graph_path(kind), threads=1).run(spec.outputs, feeds(x.sketch, x.mask))
            assert all(np.array_equal(a, b) for a, b in zip(got, want)), (engine, kind)


def test_a_graph_reading_shared_weights_lowers_like_its_embedded_twin(tmp_path):
    """The benchmark builds int8/fp16 graphs from a bundle's graphs, which may read a shared weights file."""
    import cv2

    from exporter.calibration import calibration_set
    from exporter.quantize import convert_fp16, quantize_int8
    from tests.kiosk.bundle_factory import make_assets

    (tmp_path / "g").mkdir()
    plain = conv_graph(tmp_path / "g" / "full.onnx", ["visual", "tactile"])
    shared = share_weights({"full": plain}, tmp_path / "s")[0]["full"]
    sketch = cv2.imread(str(make_assets(tmp_path / "a")["sketch"]), cv2.IMREAD_GRAYSCALE)
    cal = calibration_set(sketch, [(256, 256)], 2, 0)
    x = cal[0]
    for lower in (lambda src, name: quantize_int8(src, tmp_path / f"{name}.int8.onnx", cal),
                  lambda src, name: convert_fp16(src, tmp_path / f"{name}.fp16.onnx")):
        a, b = lower(plain, "plain"), lower(shared, "shared")
        got = open_graph("onnxruntime", b, threads=1).run(["visual", "tactile"], feeds(x.sketch, x.mask))
        want = open_graph("onnxruntime", a, threads=1).run(["visual", "tactile"], feeds(x.sketch, x.mask))
        assert all(np.array_equal(g, w) for g, w in zip(got, want))
