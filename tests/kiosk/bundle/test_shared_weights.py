"""Bundles whose graphs share one weights file: they verify, load in both engines with the outputs of the graphs
that embed their tensors, and every way a graph could point an engine elsewhere is refused before any engine
opens it. Real signed bundles written by the exporter's own sharing code; the hostile ones are signed too, so the
refusal comes from the external-data check and not from a hash."""
from __future__ import annotations

import dataclasses
import io
import re
import tarfile
from pathlib import Path

import numpy as np
import onnx
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from exporter.shared_weights import WEIGHTS_FILE
from kiosk.bundle.archive import open_bundle
from kiosk.bundle.manifest import EMBEDDED_SCHEMA, BundleError, manifest_to_dict, parse_manifest
from kiosk.bundle.probe import probe_bundle
from kiosk.bundle.store import BundleStore
from kiosk.bundle.weights import check_graph_weights, external_refs
from kiosk.contract.graph import feeds
from kiosk.contract.sketch import letterbox, network_input, object_mask
from kiosk.inference.backends import available, open_graph
from tests.kiosk.bundle_factory import base_manifest, conv_graph, make_bundle, shared_manifest

KINDS = (("full", ["visual", "tactile"]), ("tactile", ["tactile"]), ("visual", ["visual"]))


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A shared-weights bundle, its embedded twin (the same graphs, schema 1) and the trusted keys."""
    tmp = tmp_path_factory.mktemp("shared")
    shared, trusted = make_bundle(tmp, name="shared.vtb", shared=True)
    embedded, _ = make_bundle(tmp, name="embedded.vtb", graph=conv_graph,
                              manifest=base_manifest(schema_version=EMBEDDED_SCHEMA))
    return {"tmp": tmp, "shared": shared, "embedded": embedded, "trusted": trusted}


def _open(path, trusted, tmp: Path, name: str):
    from kiosk.bundle.signature import load_trusted_keys
    return open_bundle(path, load_trusted_keys(trusted), workdir=tmp / name)


def test_shared_bundle_verifies_and_stores_each_tensor_once(made, tmp_path):
    b = _open(made["shared"], made["trusted"], tmp_path, "s")
    assert b.manifest.schema_version == 2
    assert {g.weights for g in b.manifest.graphs.values()} == {f"graphs/{WEIGHTS_FILE}"}
    assert f"graphs/{WEIGHTS_FILE}" in b.manifest.files
    refs = {k: external_refs(b.graph_path(k).read_bytes()) for k in b.manifest.graphs}
    # w1 and b1 (the shared encoder) sit at one offset in all three graphs
    encoder = {k: {(r.offset, r.length) for r in v if r.tensor in ("w1", "b1")} for k, v in refs.items()}
    assert len(encoder["full"]) == 2 and encoder["full"] == encoder["tactile"] == encoder["visual"]
    assert [r.graph for r in probe_bundle(b)] == ["full", "tactile", "visual"]
    from kiosk.bundle.cli import _summary
    assert re.search(r"\nweights +graphs/weights.bin +[0-9.]+ MB, read by full, tactile, visual\n", _summary(b))


@pytest.mark.parametrize("engine", ["onnxruntime", "openvino"])
def test_both_engines_give_the_embedded_graphs_outputs_bit_for_bit(made, tmp_path, engine):
    if engine not in available():
        pytest.skip("OpenVINO is not installed (pip install 'vtkiosk[openvino]')")
    s = _open(made["shared"], made["trusted"], tmp_path, "s")
    e = _open(made["embedded"], made["trusted"], tmp_path, "e")
    assert e.manifest.schema_version == EMBEDDED_SCHEMA and all(g.weights is None for g in e.manifest.graphs.values())
    fitted, _ = letterbox(s.asset("sketch"), (256, 256))
    x = network_input(fitted, object_mask(fitted))
    for kind, outs in KINDS:
        got = open_graph(engine, s.graph_path(kind), threads=1).run(outs, feeds(x.sketch, x.mask))
        want = open_graph(engine, e.graph_path(kind), threads=1).run(outs, feeds(x.sketch, x.mask))
        assert all(np.array_equal(a, b) for a, b in zip(got, want)), kind
        assert all(float(np.abs(a).max()) > 0 for a in got)


def _entry(key: str, value: str):
    def edit(model):
        t = next(t for t in model.graph.initializer if t.name == "w1")
        for e in t.external_data:
            if e.key == key:
                e.value = value
                return
        e = t.external_data.add()
        e.key, e.value = key, value
    return edit


def _drop(key: str):
    def edit(model):
        t = next(t for t in model.graph.initializer if t.name == "w1")
        kept = [(e.key, e.value) for e in t.external_data if e.key != key]
        del t.external_data[:]
        for k, v in kept:
            e = t.external_data.add()
            e.key, e.value = k, v
    return edit


@pytest.mark.parametrize("edit, match", [
    (_entry("location", "/etc/passwd"), "may read only its bundle's weights file"),
    (_entry("location", "../weights.bin"), "may read only its bundle's weights file"),
    (_entry("location", "../assets/visual.png"), "may read only its bundle's weights file"),
    (_entry("location", "full.onnx"), "may read only its bundle's weights file"),
    (_entry("location", "*/_ORT_MEM_ADDR_/*"), "may read only its bundle's weights file"),
    (_entry("offset", str(1 << 40)), "which has [0-9]+ bytes"),
    (_entry("length", "8"), "its shape and type need 1152"),
    (_entry("offset", "-1"), "not a plain decimal number"),
    (_entry("offset", " 0"), "not a plain decimal number"),
    (_entry("checksum", "0" * 40), "uses only location, offset, length"),
    (_drop("length"), "does not state its length"),
])
def test_hostile_references_are_refused_before_any_engine(made, tmp_path, monkeypatch, edit, match):
    bad, trusted = make_bundle(tmp_path, name="bad.vtb", shared=True, edit=edit)
    import onnxruntime

    def no_engine(*a, **k):
        raise AssertionError("an engine was given a graph that failed the external-data check")
    monkeypatch.setattr(onnxruntime, "InferenceSession", no_engine)
    with pytest.raises(BundleError, match=match):
        _open(bad, trusted, tmp_path, "w")
    store = BundleStore(tmp_path / "store", trusted)
    with pytest.raises(BundleError, match=match):
        store.install(bad)
    assert store.list() == []


def test_an_embedded_layout_manifest_may_not_reference_external_data(made, tmp_path):
    """Schema 1 names no weights file: a graph that reads one is refused even when the file is in the bundle."""
    bad, trusted = make_bundle(tmp_path, name="bad.vtb", shared=True,
                               manifest=base_manifest(schema_version=EMBEDDED_SCHEMA))
    with pytest.raises(BundleError, match="the manifest names no weights file for it"):
        _open(bad, trusted, tmp_path, "w")


def test_a_tampered_weights_file_is_refused(made, tmp_path):
    bad = tmp_path / "tampered.vtb"
    with tarfile.open(made["shared"]) as tin, tarfile.open(bad, "w") as tout:
        for m in tin.getmembers():
            data = tin.extractfile(m).read()
            if m.name == f"graphs/{WEIGHTS_FILE}":
                data = data[:100] + bytes([data[100] ^ 1]) + data[101:]
            tout.addfile(m, io.BytesIO(data))
    with pytest.raises(BundleError, match=f"graphs/{WEIGHTS_FILE} does not match its SHA-256"):
        _open(bad, made["trusted"], tmp_path, "w")


def test_the_store_installs_activates_and_refuses_a_weights_file_damaged_on_disk(made, tmp_path):
    store = BundleStore(tmp_path / "store", made["trusted"])
    s = store.install(made["shared"])            # install probes every graph in ONNX Runtime
    store.activate(s.garment, s.version)
    v2, _ = make_bundle(made["tmp"], name="v2.vtb", shared=True, manifest=shared_manifest(model_version="2026.12.1"))
    s2 = store.install(v2)
    weights = s2.path / "graphs" / WEIGHTS_FILE
    data = weights.read_bytes()
    weights.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
    with pytest.raises(BundleError, match=f"graphs/{WEIGHTS_FILE} does not match its SHA-256"):
        store.activate(s2.garment, s2.version)
    assert store.active()[s.garment].version == s.version


def _doc(**graph_fields):
    files = {f"graphs/{k}.onnx": "a" * 64 for k, _ in KINDS}
    files.update({f"assets/{k}.png": "b" * 64 for k in ("sketch", "mask", "visual")})
    files["graphs/weights.bin"] = "c" * 64
    d = manifest_to_dict(dataclasses.replace(shared_manifest(), files=files))
    for g in d["graphs"].values():
        g.update(graph_fields)
    return d


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(schema_version=1), "unknown key\\(s\\) in graphs.full: weights"),
    (lambda d: d["files"].pop("graphs/weights.bin"), "weights file graphs/weights.bin is not listed in files"),
    (lambda d: d["graphs"]["full"].update(weights="assets/weights.bin"), "same folder as its graph"),
    (lambda d: d["graphs"]["full"].update(weights="graphs/visual.onnx"), "is also a graph or an asset"),
    (lambda d: d["graphs"]["full"].update(weights="graphs/../x.bin"), "invalid form"),
    (lambda d: d["graphs"]["full"].update(weights=""), "non-empty string"),
])
def test_manifest_weights_field_errors(mutate, match):
    d = _doc()
    parse_manifest(yaml.safe_dump(d).encode())
    mutate(d)
    with pytest.raises(BundleError, match=match):
        parse_manifest(yaml.safe_dump(d).encode())


# -- the external-data reader, property-based ----------------------------------------------------------------

def _one_tensor_model(location: str, offset: str, length: str, dims=(3, 4)) -> bytes:
    t = onnx.TensorProto(name="w", data_type=onnx.TensorProto.FLOAT, dims=list(dims))
    t.data_location = onnx.TensorProto.EXTERNAL
    for k, v in (("location", location), ("offset", offset), ("length", length)):
        e = t.external_data.add()
        e.key, e.value = k, v
    node = onnx.helper.make_node("Identity", ["w"], ["y"])
    graph = onnx.helper.make_graph([node], "g", [], [onnx.helper.make_tensor_value_info("y", 1, list(dims))],
                                   initializer=[t])
    return onnx.helper.make_model(graph).SerializeToString()


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(location=st.one_of(st.sampled_from(["weights.bin", "../weights.bin", "/weights.bin", "./weights.bin",
                                           "weights.bin\0", "*/_ORT_MEM_ADDR_/*", ""]), st.text(max_size=20)),
       offset=st.integers(0, 10 ** 19 - 1), length=st.integers(0, 200), size=st.integers(0, 300))
def test_a_reference_is_accepted_exactly_when_it_lies_inside_the_weights_file(tmp_path, location, offset, length,
                                                                              size):
    graph, weights = tmp_path / "g.onnx", tmp_path / "weights.bin"
    graph.write_bytes(_one_tensor_model(location, str(offset), str(length)))
    weights.write_bytes(b"\0" * size)
    ok = location == "weights.bin" and offset + length <= size and length == 48
    try:
        n = check_graph_weights(graph, weights, graph_name="g", weights_name="graphs/weights.bin")
    except BundleError:
        assert not ok
    else:
        assert ok and n == 1


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_damaged_graph_bytes_give_a_bundle_error_or_a_true_reading(data):
    """Truncated, bit-flipped or random bytes: the reader says BundleError or reads references, never crashes."""
    base = _one_tensor_model("weights.bin", "64", "48")
    mode = data.draw(st.sampled_from(["cut", "flip", "random"]))
    if mode == "cut":
        blob = base[:data.draw(st.integers(0, len(base)))]
    elif mode == "flip":
        i = data.draw(st.integers(0, len(base) - 1))
        blob = base[:i] + bytes([base[i] ^ data.draw(st.integers(1, 255))]) + base[i + 1:]
    else:
        blob = data.draw(st.binary(max_size=300))
    try:
        refs = external_refs(blob)
    except BundleError:
        return
    assert all(isinstance(r.offset, int) and isinstance(r.length, int) for r in refs)


def test_the_reader_finds_tensors_wherever_a_model_can_hold_them():
    """Constant attributes, subgraphs (If branches) and sparse initializers are read as well as initializers."""
    def ext(name):
        t = onnx.TensorProto(name=name, data_type=onnx.TensorProto.FLOAT, dims=[2])
        t.data_location = onnx.TensorProto.EXTERNAL
        for k, v in (("location", f"{name}.bin"), ("offset", "0"), ("length", "8")):
            e = t.external_data.add()
            e.key, e.value = k, v
        return t
    const = onnx.helper.make_node("Constant", [], ["c"], value=ext("const"))
    branch = onnx.helper.make_graph([onnx.helper.make_node("Constant", [], ["b"], value=ext("sub"))], "b", [],
                                    [onnx.helper.make_tensor_value_info("b", 1, [2])])
    cond = onnx.helper.make_node("If", ["cond"], ["o"], then_branch=branch, else_branch=branch)
    sparse = onnx.SparseTensorProto(values=ext("sparse"), dims=[4])
    sparse.indices.CopyFrom(onnx.numpy_helper.from_array(np.array([0, 1], np.int64), "i"))
    graph = onnx.helper.make_graph([const, cond], "g", [onnx.helper.make_tensor_value_info("cond", 9, [])],
                                   [onnx.helper.make_tensor_value_info("o", 1, [2])], initializer=[ext("init")],
                                   sparse_initializer=[sparse])
    refs = external_refs(onnx.helper.make_model(graph).SerializeToString())
    assert sorted(r.location for r in refs) == ["const.bin", "init.bin", "sparse.bin", "sub.bin", "sub.bin"]


def test_old_layout_graphs_hold_no_references(made, tmp_path):
    e = _open(made["embedded"], made["trusted"], tmp_path, "e")
    assert all(external_refs(e.graph_path(k).read_bytes()) == [] for k in e.manifest.graphs)
