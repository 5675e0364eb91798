"""Engines behind one interface: real ONNX Runtime and real OpenVINO sessions on the same bundle graphs, parity
between them, and `engine: auto` choosing by measured speed inside the bundle's stated error bound."""
from __future__ import annotations

import numpy as np
import pytest

from kiosk.bundle.archive import open_bundle
from kiosk.bundle.signature import load_trusted_keys
from kiosk.contract.graph import feeds
from kiosk.contract.sketch import network_input, object_mask, rasterize
from kiosk.contract.accuracy import LEVELS_PER_UNIT
from kiosk.inference.autoselect import DEFAULT_BOUND_LEVELS, choose_engine, error_bound
from kiosk.inference.backends import ENGINES, EngineUnavailable, available, open_graph
from kiosk.inference.engine import InferenceError, LoadedBundle, NonFiniteOutput
from tests.kiosk.bundle_factory import base_manifest, conv_graph, make_bundle


def _bundle(tmp_path, *, errors=None, poison=False):
    manifest = base_manifest(errors=errors) if errors is not None else None
    path, trusted = make_bundle(tmp_path, graph=conv_graph, manifest=manifest, poison=poison)
    return open_bundle(path, load_trusted_keys(trusted), workdir=tmp_path / "w")


def _x(size=256):
    s = rasterize([[(30, 30), (220, 40), (200, 220), (40, 200), (30, 30)]], (size, size))
    return network_input(s, object_mask(s))


def test_openvino_is_installed_for_the_tests():
    assert available() == ENGINES  # the [openvino] extra is part of the test set-up; no silent skip


def test_openvino_matches_onnxruntime_on_a_conv_bundle(tmp_path):
    b = _bundle(tmp_path)
    x = _x(256)
    for kind, spec in b.manifest.graphs.items():
        ref = open_graph("onnxruntime", b.graph_path(kind), threads=1).run(spec.outputs, feeds(x.sketch, x.mask))
        got = open_graph("openvino", b.graph_path(kind), threads=1).run(spec.outputs, feeds(x.sketch, x.mask))
        for r, g in zip(ref, got):
            assert g.dtype == np.float32 and g.shape == r.shape
            assert float(np.abs(r).max()) > 0.1  # the graph computes something, not zeros on both sides
            np.testing.assert_allclose(g, r, atol=1e-4)
            assert LEVELS_PER_UNIT * float(np.mean(np.abs(g - r))) < 0.01


def test_openvino_runner_returns_independent_arrays(tmp_path):
    b = _bundle(tmp_path)
    r = open_graph("openvino", b.graph_path("tactile"), threads=1)
    a = r.run(["tactile"], feeds(_x().sketch, _x().mask))[0]
    z = np.zeros((1, 1, 256, 256), np.float32)
    r.run(["tactile"], feeds(z, z))
    assert float(np.abs(a).max()) > 0.1  # a later run did not overwrite the first one's output buffer


def test_loaded_bundle_runs_on_openvino_with_finite_checks(tmp_path):
    lb = LoadedBundle(_bundle(tmp_path), engine="openvino")
    ref = LoadedBundle(_bundle(tmp_path / "r"), engine="onnxruntime")
    x = _x(512)
    got, want = lb.run("full", x), ref.run("full", x)
    assert lb.info()["engine"] == "openvino" and lb.info()["engine_choice"] is None
    for name in ("visual", "tactile"):
        np.testing.assert_allclose(got.outputs[name], want.outputs[name], atol=1e-4)
    lb.fault_nonfinite = True
    with pytest.raises(NonFiniteOutput):
        lb.run("tactile", x)


def test_openvino_nan_graph_is_refused(tmp_path):
    lb = LoadedBundle(_bundle(tmp_path, poison=True), engine="openvino")
    with pytest.raises(NonFiniteOutput, match="non-finite"):
        lb.run("visual", _x())


def test_unknown_engine_is_a_clear_error(tmp_path):
    b = _bundle(tmp_path)
    with pytest.raises(EngineUnavailable, match="unknown inference engine 'tensorflow'"):
        open_graph("tensorflow", b.graph_path("full"), threads=1)
    with pytest.raises(InferenceError, match="graph full does not load"):
        LoadedBundle(b, engine="tensorflow").run("full", _x())


def test_auto_records_both_engines_and_picks_the_faster_eligible(tmp_path):
    lb = LoadedBundle(_bundle(tmp_path), engine="auto", auto_runs=2)
    choice = lb.engine_choice
    assert choice is not None and lb.engine == choice.engine
    figs = {f.engine: f for f in choice.figures}
    assert set(figs) == set(ENGINES)
    assert figs["onnxruntime"].err_levels == 0.0 and figs["onnxruntime"].eligible
    assert figs["onnxruntime"].felt_garment_fraction == 0.0
    # the other engine: how much of the garment a finger could tell from ONNX Runtime's, a share of its pixels
    assert 0.0 <= figs["openvino"].felt_garment_fraction <= 1.0
    assert all(f.ms_p50 is not None and f.ms_p50 > 0 for f in figs.values())
    eligible = [f for f in figs.values() if f.eligible]
    assert choice.engine == min(eligible, key=lambda f: f.ms_p50).engine
    assert choice.grids == {"full": [512, 512], "tactile": [256, 256], "visual": [256, 256]}
    info = lb.info()["engine_choice"]
    assert info["engine"] == choice.engine and len(info["figures"]) == 2
    lb.run("full", _x())  # the chosen engine serves


def test_auto_refuses_an_engine_outside_the_stated_bound(tmp_path):
    # the bundle states a visual error so small (PSNR above the 99 dB that identical images score) that no second
    # engine can meet it; ONNX Runtime, the reference, serves
    lb = LoadedBundle(_bundle(tmp_path, errors={"fp32": {"visual_psnr_db": 1e9}}), engine="auto", auto_runs=1)
    figs = {f.engine: f for f in lb.engine_choice.figures}
    assert figs["openvino"].visual_psnr_db <= 99.0 and not figs["openvino"].eligible
    assert "visual_psnr_db" in figs["openvino"].reason and "against the bound 1e+09" in figs["openvino"].reason
    assert lb.engine == "onnxruntime"
    assert lb.engine_choice.bounds["visual"] == {"visual_psnr_db": 1e9}


def test_auto_holds_engines_to_a_stated_felt_share(tmp_path):
    stated = {"fp32": {f"{k}_friction_felt_garment_fraction": 0.25 for k in ("full", "tactile")}}
    lb = LoadedBundle(_bundle(tmp_path, errors=stated), engine="auto", auto_runs=1)
    assert lb.engine_choice.bounds["full"]["friction_felt_garment_fraction"] == 0.25
    assert "friction_felt_garment_fraction" not in lb.engine_choice.bounds["visual"]  # no tactile output there
    ov = {f.engine: f for f in lb.engine_choice.figures}["openvino"]
    assert ov.felt_garment_fraction <= 0.25 and ov.eligible  # fp32 graphs: the engines agree to 1e-4


def test_breaches_name_the_bound_and_read_psnr_as_a_floor():
    from kiosk.inference.autoselect import _breaches
    dev = {"friction_mae_levels": 0.3, "friction_mae_garment_levels": 1.2, "visual_psnr_db": 45.0}
    assert _breaches(dev, {"friction_mae_levels": 0.9, "friction_mae_garment_levels": 3.0,
                           "visual_psnr_db": 40.0}) == []
    assert _breaches(dev, {"friction_mae_levels": 0.9, "friction_mae_garment_levels": 1.0,
                           "visual_psnr_db": 47.0}) == ["friction_mae_garment_levels 1.2 against the bound 1",
                                                        "visual_psnr_db 45 against the bound 47"]
    assert _breaches({}, {"visual_mae_levels": 0.5}) == []  # a figure the graph does not output breaks nothing
    # the felt share is a ceiling like the means: small mean, but the differences gather on felt pixels
    felt = {"friction_mae_levels": 0.3, "friction_felt_garment_fraction": 0.08}
    assert _breaches(felt, {"friction_mae_levels": 0.9, "friction_felt_garment_fraction": 0.062}) == [
        "friction_felt_garment_fraction 0.08 against the bound 0.062"]
    assert _breaches(felt, {"friction_felt_garment_fraction": 0.08}) == []


def test_graph_bounds_read_the_stated_errors_and_fall_back(tmp_path):
    from kiosk.inference.autoselect import DEFAULT_VISUAL_LEVELS, graph_bounds
    stated = {"fp32": {"full_friction_mae_levels": 0.9, "full_friction_mae_garment_levels": 3.0,
                       "full_friction_felt_garment_fraction": 0.062,
                       "full_visual_psnr_db": 47.0, "tactile_friction_mae_levels": 0.0,
                       "tactile_friction_felt_garment_fraction": 0.0}}
    b = _bundle(tmp_path / "a", errors=stated)
    assert graph_bounds(b, "full") == {"friction_mae_levels": 0.9, "friction_mae_garment_levels": 3.0,
                                       "friction_felt_garment_fraction": 0.062, "visual_psnr_db": 47.0}
    # 0 is no bound, as for the means
    assert graph_bounds(b, "tactile") == {"friction_mae_levels": DEFAULT_BOUND_LEVELS}
    assert graph_bounds(b, "visual") == {"visual_mae_levels": DEFAULT_VISUAL_LEVELS}


def test_error_bound_reads_the_bundle_and_falls_back(tmp_path):
    assert error_bound(_bundle(tmp_path / "a", errors={"fp32": {"friction_mae_levels": 0.3}})) == 0.3
    per_graph = {"fp32": {"full_friction_mae_levels": 0.9, "tactile_friction_mae_levels": 0.7}}
    assert error_bound(_bundle(tmp_path / "c", errors=per_graph)) == 0.7
    # the default manifest states an int8 bound only; its graphs are fp32
    assert error_bound(_bundle(tmp_path / "b")) == DEFAULT_BOUND_LEVELS


def test_choose_engine_with_only_onnxruntime(tmp_path):
    choice = choose_engine(_bundle(tmp_path), threads=1, runs=1, engines=("onnxruntime",))
    assert choice.engine == "onnxruntime" and [f.engine for f in choice.figures] == ["onnxruntime"]


def test_openvino_compiles_once_per_grid_and_bounds_the_cache(tmp_path):
    b = _bundle(tmp_path)
    r = open_graph("openvino", b.graph_path("tactile"), threads=1)
    for size in (256, 512, 256):
        out = r.run(["tactile"], feeds(_x(size).sketch, _x(size).mask))[0]
        assert out.shape == (1, 2, size, size)
    assert len(r._compiled) == 2
    r.MAX_SHAPES = 1
    r.run(["tactile"], feeds(_x(768).sketch, _x(768).mask))
    assert list(r._compiled) == [(("mask", (1, 1, 768, 768)), ("sketch", (1, 1, 768, 768)))]


X86 = "processor\t: 0\nmodel name\t: Intel(R) Xeon(R) Platinum 8480+\nflags\t\t: fpu sse4_2 avx avx2 fma avx512f " \
      "avx512_vnni amx_tile amx_int8\n"
ARM = "processor\t: 0\nBogoMIPS\t: 50.00\nFeatures\t: fp asimd evtstrm aes crc32\nCPU part\t: 0xd0c\n"


def test_cpu_description_names_model_and_isa_families():
    from kiosk.inference.cpu import describe
    d = describe(X86)
    assert d["model"] == "Intel(R) Xeon(R) Platinum 8480+"
    assert d["isa"] == ["avx2", "avx512", "vnni", "amx"]
    assert describe("flags : sse4_2 avx avx2 fma\n")["isa"] == ["avx2"]
    assert describe(ARM)["isa"] == ["neon"] and "asimd" in describe(ARM)["flags"]
    assert describe("")["model"]  # never empty: falls back to the platform's name
    live = describe()
    assert live["logical_cpus"] >= 1 and isinstance(live["isa"], list)


def test_autoselect_command_prints_the_choice_and_fails_in_one_line(tmp_path, capsys):
    from kiosk.inference.autoselect import main
    path, trusted = make_bundle(tmp_path, graph=conv_graph)
    assert main([str(path), "--trusted-keys", str(trusted), "--runs", "1", "--threads", "1"]) == 0
    import json
    out = json.loads(capsys.readouterr().out)
    assert out["engine"] in ENGINES and out["cpu"]["model"]
    assert main([str(tmp_path / "missing.vtb"), "--runs", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1

