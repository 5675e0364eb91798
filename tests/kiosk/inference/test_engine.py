"""Inference engine: real ONNX Runtime sessions from real bundles, finite checks, the output cache."""
from __future__ import annotations

import numpy as np
import pytest

from kiosk.bundle.archive import open_bundle
from kiosk.inference.engine import InferenceError, LoadedBundle, NonFiniteOutput, OutputCache, visual_rgba
from kiosk.bundle.manifest import BundleError, GraphSpec
from kiosk.bundle.signature import load_trusted_keys
from kiosk.contract.sketch import network_input, object_mask, rasterize
from tests.kiosk.bundle_factory import base_manifest, make_bundle


def _load(tmp_path, **kw) -> LoadedBundle:
    path, trusted = make_bundle(tmp_path, **{k: v for k, v in kw.items() if k in ("poison", "manifest", "name")})
    return LoadedBundle(open_bundle(path, load_trusted_keys(trusted), workdir=tmp_path / "w"),
                        **{k: v for k, v in kw.items() if k == "precisions"})


def _inputs(size=256):
    s = rasterize([[(40, 40), (200, 40), (200, 200), (40, 200), (40, 40)]], (size, size))
    return network_input(s, object_mask(s))


def test_graphs_run_lazily_and_compute_the_declared_outputs(tmp_path):
    lb = _load(tmp_path)
    assert lb._sessions == {}
    x = _inputs()
    full = lb.run("full", x)
    assert set(full.outputs) == {"visual", "tactile"} and set(lb._sessions) == {("full", "main")}
    assert full.outputs["visual"].shape == (1, 3, 256, 256) and full.outputs["tactile"].shape == (1, 2, 256, 256)
    # The factory graph: tactile = 0.1 * (s, -s) * mask, visual = tanh(s, m, s) * mask.
    np.testing.assert_allclose(full.outputs["tactile"][0, 0], 0.1 * x.sketch[0, 0] * x.mask[0, 0], atol=1e-6)
    np.testing.assert_allclose(full.outputs["visual"][0, 1], np.tanh(x.mask[0, 0]) * x.mask[0, 0], atol=1e-6)
    tac = lb.run("tactile", x)
    assert set(tac.outputs) == {"tactile"}
    np.testing.assert_array_equal(tac.outputs["tactile"], full.outputs["tactile"])
    assert lb.cap("full") == (512, 512) and lb.cap("tactile") == (256, 256)
    assert lb.key.startswith("denim-shorts@2026.11.21-1#")
    lb.close()


def test_nonfinite_outputs_never_leave_the_engine(tmp_path):
    lb = _load(tmp_path, poison=True)
    with pytest.raises(NonFiniteOutput, match="non-finite values"):
        lb.run("full", _inputs())
    assert issubclass(NonFiniteOutput, InferenceError)
    lb.close()


def test_debug_hook_poisons_outputs(tmp_path):
    lb = _load(tmp_path)
    lb.fault_nonfinite = True
    with pytest.raises(NonFiniteOutput):
        lb.run("visual", _inputs())
    lb.fault_nonfinite = False
    assert np.isfinite(lb.run("visual", _inputs()).outputs["visual"]).all()
    lb.close()


def test_wrong_input_size_is_an_inference_error(tmp_path):
    lb = _load(tmp_path)
    bad = network_input(np.full((10, 12), 255, np.uint8), np.zeros((10, 12), bool))
    lb.session("full")
    from kiosk.contract.sketch import NetworkInput

    with pytest.raises(InferenceError):
        lb.run("full", NetworkInput(bad.sketch, bad.mask[:, :, :5]))  # mismatched inputs: ORT refuses
    lb.close()


def test_precisions_the_kiosk_does_not_run_are_refused(tmp_path):
    m = base_manifest()
    graphs = dict(m.graphs)
    graphs["full"] = GraphSpec("graphs/full.onnx", "fp16", ["visual", "tactile"], [[256, 256]])
    with pytest.raises(BundleError, match="full graph is fp16"):
        _load(tmp_path, manifest=base_manifest(graphs=graphs), precisions=("int8", "fp32"))


def test_warm_creates_and_runs_every_session(tmp_path):
    lb = _load(tmp_path)
    runs = lb.warm(("full", "visual"), [(256, 256), (512, 256)])
    assert [(k, g) for k, g, _ in runs] == [("full", (256, 256)), ("full", (512, 256)), ("visual", (256, 256)),
                                           ("visual", (512, 256))]
    assert all(ms > 0 for *_, ms in runs)
    lb.close()


def test_close_removes_an_owned_folder(tmp_path):
    path, trusted = make_bundle(tmp_path)
    b = open_bundle(path, load_trusted_keys(trusted), workdir=tmp_path / "w")
    lb = LoadedBundle(b, owned_dir=b.root)
    assert b.root.is_dir()
    lb.close()
    assert not b.root.exists()


def test_visual_rgba_matches_the_definition():
    rng = np.random.default_rng(0)
    v = rng.uniform(-1.3, 1.3, (1, 3, 64, 48)).astype(np.float32)
    m = rng.random((64, 48)) > 0.4
    got = visual_rgba(v, m)
    want = np.clip(np.rint((np.clip(v[0], -1, 1).transpose(1, 2, 0) + 1) * 127.5), 0, 255)
    assert got.shape == (64, 48, 4) and got.dtype == np.uint8
    assert np.abs(got[..., :3].astype(int) - want).max() <= 1
    np.testing.assert_array_equal(got[..., 3], np.where(m, 255, 0))


def test_cache_is_lru_and_bounded_in_bytes():
    c = OutputCache(max_bytes=3 * 1000)
    arrays = {k: np.full(1000, i, np.uint8) for i, k in enumerate("abcd")}
    for k in "abc":
        c.put(k, "visual", arrays[k])
    assert c.get("a", "visual") is not None  # a is now the most recent
    c.put("d", "visual", arrays["d"])  # evicts b, the least recent
    assert c.has("a", "visual") and not c.has("b", "visual") and c.has("d", "visual")
    assert c.nbytes == 3000 and len(c) == 3
    assert c.get("b", "visual") is None and c.misses == 1 and c.hits == 1
    stored = c.get("a", "visual")
    with pytest.raises(ValueError):
        stored[0] = 9  # read-only: a consumer cannot corrupt the cache
    c.put("huge", "tactile", np.zeros(5000, np.uint8))  # larger than the cache: not kept
    assert not c.has("huge", "tactile") and not c.has(None, "visual")
