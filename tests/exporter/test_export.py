"""`vtkiosk export` on a real (briefly trained) run: parity, precisions, the error-bound refusal, verify."""
import numpy as np
import pytest
import torch

from exporter.export import ExportConfig, ExportError, export_run
from exporter.graphs import export_graph, ort_session, torch_outputs
from kiosk.bundle.archive import open_bundle
from kiosk.bundle.probe import probe_bundle
from kiosk.contract.sketch import letterbox, network_input, object_mask

from tests.exporter.conftest import vtk

pytestmark = pytest.mark.slow


def test_fp32_parity_and_dynamic_size(run_dir, tmp_path):
    from trainer.checkpoint import load_generator
    gen, _ = load_generator(run_dir)
    path = export_graph(gen, "full", tmp_path / "full.onnx", size=(256, 256))
    sess = ort_session(path)
    rng = np.random.default_rng(0)
    for w, h in ((256, 256), (512, 256)):  # one graph, several sizes
        s = np.where(rng.random((h, w)) < 0.05, 0, 255).astype(np.uint8)
        s[:8] = 0
        s[-8:] = 0
        s[:, :8] = 0
        s[:, -8:] = 0
        x = network_input(s, object_mask(s))
        ref = torch_outputs(gen, "full", x.sketch, x.mask)
        got = sess.run(["visual", "tactile"], {"sketch": x.sketch, "mask": x.mask})
        assert got[0].shape == (1, 3, h, w) and got[1].shape == (1, 2, h, w)
        assert max(float(np.abs(a - b).max()) for a, b in zip(ref, got)) < 1e-4


def test_tactile_graph_equals_full_graphs_tactile(run_dir, tmp_path):
    from trainer.checkpoint import load_generator
    gen, _ = load_generator(run_dir)
    full = ort_session(export_graph(gen, "full", tmp_path / "f.onnx", size=(256, 256)))
    tac = ort_session(export_graph(gen, "tactile", tmp_path / "t.onnx", size=(256, 256)))
    s, _ = letterbox(np.full((240, 320), 255, np.uint8), (256, 256))
    s[40:200, 40] = 0
    s[40:200, 210] = 0
    s[40, 40:211] = 0
    s[200, 40:211] = 0
    x = network_input(s, object_mask(s))
    a = full.run(["tactile"], {"sketch": x.sketch, "mask": x.mask})[0]
    b = tac.run(["tactile"], {"sketch": x.sketch, "mask": x.mask})[0]
    assert np.abs(a - b).max() < 1e-5


def test_export_fp16_bundle_verifies(run_dir, tmp_path):
    report = export_run(run_dir, tmp_path / "g.vtb", ExportConfig(precision="fp16", sizes=[(256, 256)],
                                                                 calibration_per_size=2, error_per_size=2),
                        progress=lambda *_: None)
    assert report.errors["fp16"]["tactile_friction_mae_levels"] < 1.0
    assert all(v < 1e-4 for v in report.parity.values())
    b = open_bundle(tmp_path / "g.vtb", None, workdir=tmp_path / "w", allow_unsigned=True)
    assert set(b.manifest.graphs) == {"full", "tactile", "visual"}
    assert b.manifest.friction_scale > 0 and b.asset("visual").ndim == 3
    # The trainer recorded the synthetic garment's own pitch; the mapping and its calibrated constants travel along.
    assert b.manifest.pixel_pitch_mm == 0.3
    c = b.manifest.friction_constants
    assert b.manifest.friction_normalization == "perceptual" and 0 < c["gz_low"] < c["gz_high"]
    assert [r.graph for r in probe_bundle(b)] == ["full", "tactile", "visual"]


def test_int8_error_bound_refusal_and_force(run_dir, tmp_path):
    cfg = ExportConfig(precision="int8", sizes=[(256, 256)], calibration_per_size=3, error_per_size=2,
                       graphs=("tactile",), max_friction_mae=0.0)
    with pytest.raises(ExportError, match="friction-map error"):
        export_run(run_dir, tmp_path / "q.vtb", cfg, progress=lambda *_: None)
    assert not (tmp_path / "q.vtb").exists()
    cfg.force = True
    report = export_run(run_dir, tmp_path / "q.vtb", cfg, progress=lambda *_: None)
    assert "tactile_friction_mae_levels" in report.errors["int8"]
    assert (tmp_path / "q.vtb").exists()


def test_int8_garment_error_bound(run_dir, tmp_path):
    """The garment figure is stated beside the canvas one (never smaller: the paper around the garment has no
    error) and can be bounded on its own; a canvas bound that passes does not let a garment bound through."""
    cfg = ExportConfig(precision="int8", sizes=[(256, 256)], calibration_per_size=3, error_per_size=2,
                       graphs=("tactile",), max_friction_mae=255.0, max_friction_mae_garment=0.0)
    with pytest.raises(ExportError, match="in the garment .*--max-friction-mae-garment"):
        export_run(run_dir, tmp_path / "g.vtb", cfg, progress=lambda *_: None)
    assert not (tmp_path / "g.vtb").exists()
    cfg.max_friction_mae_garment = 255.0
    errors = export_run(run_dir, tmp_path / "g.vtb", cfg, progress=lambda *_: None).errors["int8"]
    assert errors["tactile_friction_mae_garment_levels"] >= errors["tactile_friction_mae_levels"] > 0


@pytest.mark.parametrize("value", ["nan", "-1", "inf", "two"])
def test_cli_rejects_a_bound_that_is_not_a_level(run_dir, tmp_path, value):
    for flag in ("--max-friction-mae", "--max-friction-mae-garment"):
        bad = vtk("export", "--run", run_dir, "--out", tmp_path / "x.vtb", flag, value)
        assert bad.returncode == 2 and "friction levels" in bad.stderr and "Traceback" not in bad.stderr
        assert not (tmp_path / "x.vtb").exists()


def test_cli_signed_export_and_errors(run_dir, tmp_path):
    assert vtk("keys", "generate", "--out", tmp_path / "keys").returncode == 0
    (tmp_path / "trusted").mkdir()
    (tmp_path / "trusted" / "operator.pub").write_bytes((tmp_path / "keys" / "operator.pub").read_bytes())
    proc = vtk("export", "--run", run_dir, "--out", tmp_path / "s.vtb", "--precision", "fp32", "--sizes", "256",
               "--sign-key", tmp_path / "keys" / "operator.key")
    assert proc.returncode == 0, proc.stderr
    assert "signed" in proc.stdout
    ok = vtk("bundle", "verify", tmp_path / "s.vtb", "--trusted-keys", tmp_path / "trusted")
    assert ok.returncode == 0 and "verified    ok" in ok.stdout
    bad = vtk("export", "--run", tmp_path / "nope", "--out", tmp_path / "x.vtb")
    assert bad.returncode == 2 and "no checkpoint" in bad.stderr and "Traceback" not in bad.stderr
    bad = vtk("export", "--run", run_dir, "--out", tmp_path / "x.vtb", "--sizes", "300")
    assert bad.returncode == 2 and "multiples of 256" in bad.stderr


def test_run_metrics_are_flattened_for_the_manifest():
    from exporter.export import _numbers
    doc = {"train": {"step": 500, "val": {"psnr": 25.7, "nan": float("nan")}, "method": "ours", "ok": True},
           "eval": {"full_angle_deg": 15.4}, "list": [1, 2]}
    assert _numbers(doc) == {"train.step": 500.0, "train.val.psnr": 25.7, "eval.full_angle_deg": 15.4}


def test_cli_int8_export_prints_progress_only(run_dir, tmp_path):
    """An int8 export (the chattiest path: torch.onnx, the quantiser) shows our stage lines and nothing else; the
    libraries' output is kept in the log beside the bundle."""
    proc = vtk("export", "--run", run_dir, "--out", tmp_path / "q.vtb", "--precision", "int8", "--sizes", "256",
               "--force")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    lines = proc.stdout.strip().splitlines()
    assert all(line.startswith(("export: ", "wrote ")) for line in lines), lines
    assert any("graph int8 vs fp32" in line for line in lines) and lines[-1].startswith("wrote ")
    assert (tmp_path / "q.vtb.log").is_file()


def _exported_outputs(run_dir, tmp_path, name: str, x, **cfg):
    """Export a 256 px fp32 bundle with `cfg` and run its full graph on network input `x` in ONNX Runtime."""
    export_run(run_dir, tmp_path / f"{name}.vtb", ExportConfig(precision="fp32", sizes=[(256, 256)],
                                                             calibration_per_size=2, error_per_size=2, **cfg),
               progress=lambda *_: None)
    b = open_bundle(tmp_path / f"{name}.vtb", None, workdir=tmp_path / name, allow_unsigned=True)
    return b, ort_session(b.graph_path("full")).run(["visual", "tactile"], {"sketch": x.sketch, "mask": x.mask})


def test_relief_calibrated_bundle_scales_the_tactile_output_only(run_dir, tmp_path):
    """--relief rms: the gain fitted on the training touches is one Mul in every graph (the tactile output is the
    uncalibrated bundle's times it, the visual untouched) and the manifest says so."""
    from trainer.calibration import fit_relief_gain
    from trainer.checkpoint import load_generator
    from trainer.config import read_run_config
    from trainer.data.touchclothing import load_garment

    gen, info = load_generator(run_dir)
    gain = fit_relief_gain(gen, load_garment(read_run_config(run_dir).garment), int(info["crop"]), "rms").gain
    s, _ = letterbox(np.full((240, 320), 255, np.uint8), (256, 256))
    s[40:200, 40], s[40:200, 210], s[40, 40:211], s[200, 40:211] = 0, 0, 0, 0
    x = network_input(s, object_mask(s))
    outs = {}
    for relief in ("none", "rms"):
        b, outs[relief] = _exported_outputs(run_dir, tmp_path, relief, x, relief=relief)
        assert ("relief" in b.manifest.provenance) == (relief != "none")
        if relief == "rms":
            assert b.manifest.provenance["relief"].startswith(f"rms x{gain:.4f} from ")
    assert np.abs(outs["rms"][0] - outs["none"][0]).max() < 1e-6
    assert np.abs(outs["rms"][1] - gain * outs["none"][1]).max() < 1e-5 and np.abs(outs["none"][1]).max() > 0
    with pytest.raises(ExportError, match="relief must be one of"):
        export_run(run_dir, tmp_path / "x.vtb", ExportConfig(precision="fp32", sizes=[(256, 256)], relief="max"),
                   progress=lambda *_: None)
    assert not (tmp_path / "x.vtb").exists()


def test_shading_relief_runs_inside_the_graph(run_dir, tmp_path):
    """--relief shade: the fitted photo filter is one convolution in every graph, so ONNX Runtime returns what the
    wrapper returns in torch; the visual output is the plain bundle's, and the manifest says so."""
    from trainer.checkpoint import load_generator
    from trainer.config import read_run_config
    from trainer.data.touchclothing import load_garment
    from trainer.shading_fit import fit_shading

    s, _ = letterbox(np.full((240, 320), 255, np.uint8), (256, 256))
    s[40:200, 40], s[40:200, 210], s[40, 40:211], s[200, 40:211] = 0, 0, 0, 0
    x = network_input(s, object_mask(s))
    outs = {}
    for relief in ("none", "shade"):
        b, outs[relief] = _exported_outputs(run_dir, tmp_path, f"s-{relief}", x, relief=relief)
    assert b.manifest.provenance["relief"].startswith("shade: model x")
    gen, info = load_generator(run_dir)
    fit = fit_shading(gen.eval(), load_garment(read_run_config(run_dir).garment), int(info["crop"]))
    with torch.no_grad():
        _, want = fit.wrap(gen.eval())(torch.from_numpy(x.sketch), torch.from_numpy(x.mask))
    assert np.abs(outs["shade"][1] - want.numpy()).max() < 1e-4
    assert np.abs(outs["shade"][0] - outs["none"][0]).max() < 1e-6
    assert np.abs(outs["shade"][1] - outs["none"][1]).max() > 1e-4


def test_auto_relief_exports_the_rule_it_chose_and_says_which(run_dir, tmp_path):
    """--relief auto: the bundle holds the wrap of whichever rule the validation touches chose, in every graph, and
    the provenance names it beside both rules' validation angles."""
    from trainer.checkpoint import load_generator
    from trainer.config import read_run_config
    from trainer.data.touchclothing import load_garment
    from trainer.relief import calibrate

    s, _ = letterbox(np.full((240, 320), 255, np.uint8), (256, 256))
    s[40:200, 40], s[40:200, 210], s[40, 40:211], s[200, 40:211] = 0, 0, 0, 0
    x = network_input(s, object_mask(s))
    b, out = _exported_outputs(run_dir, tmp_path, "auto", x, relief="auto")
    gen, info = load_generator(run_dir)
    wrapped, fit, _ = calibrate(gen.eval(), load_garment(read_run_config(run_dir).garment), int(info["crop"]), "auto")
    line = b.manifest.provenance["relief"]
    assert line.startswith(f"auto chose {fit['chose']}") and "validation angle" in line
    with torch.no_grad():
        _, want = wrapped(torch.from_numpy(x.sketch), torch.from_numpy(x.mask))
    assert np.abs(out[1] - want.numpy()).max() < 1e-4


def test_mirrored_bundle_averages_the_relief_inside_the_graph(run_dir, tmp_path):
    """--mirrors: every view runs inside the graph (ONNX Transpose / flip), so ONNX Runtime returns what the wrapper
    returns in torch; the visual output is the plain bundle's, and the manifest says which views."""
    from trainer.checkpoint import load_generator
    from trainer.models.mirror_average import MirrorAverage

    s, _ = letterbox(np.full((240, 320), 255, np.uint8), (256, 256))
    s[40:200, 40], s[40:120, 210], s[40, 40:211], s[200, 40:150] = 0, 0, 0, 0   # no symmetry to hide an error
    s[120, 150:211], s[120:201, 150] = 0, 0   # closed, so the mask holds open cloth away from the strokes
    x = network_input(s, object_mask(s))
    outs = {}
    for mode in ("none", "flip+transpose", "flip+transpose-low", "flip+transpose-lines", "flip+transpose-energy"):
        b, outs[mode] = _exported_outputs(run_dir, tmp_path, mode, x, mirrors=mode)
        assert b.manifest.provenance.get("mirrors", "none") == mode
    gen, _ = load_generator(run_dir)
    for mode in ("flip+transpose", "flip+transpose-low", "flip+transpose-lines",
                 "flip+transpose-energy"):   # the blur, band and gain in-graph
        with torch.no_grad():
            _, want = MirrorAverage(gen.eval(), mode)(torch.from_numpy(x.sketch), torch.from_numpy(x.mask))
        assert np.abs(outs[mode][1] - want.numpy()).max() < 1e-4
    for mode in ("flip+transpose-low", "flip+transpose-lines", "flip+transpose-energy"):
        assert np.abs(outs[mode][1] - outs["flip+transpose"][1]).max() > 1e-4
    assert np.abs(outs["flip+transpose"][0] - outs["none"][0]).max() < 1e-6
    assert np.abs(outs["flip+transpose"][1] - outs["none"][1]).max() > 1e-3   # the views do differ
    with pytest.raises(ExportError, match="mirrors must be one of"):
        export_run(run_dir, tmp_path / "m.vtb", ExportConfig(precision="fp32", sizes=[(256, 256)], mirrors="spin"),
                   progress=lambda *_: None)
    assert not (tmp_path / "m.vtb").exists()


def test_relief_that_cannot_be_fitted_is_an_export_error(run_dir, tmp_path, monkeypatch):
    import trainer.calibration as calibration

    def refuse(*_a, **_k):
        raise calibration.CalibrationError("DenimShorts: rms relief gain undefined is outside [0.25, 4.0]")
    monkeypatch.setattr(calibration, "fit_relief_gain", refuse)
    with pytest.raises(ExportError, match="cannot calibrate the relief: .*Export without --relief"):
        export_run(run_dir, tmp_path / "y.vtb", ExportConfig(precision="fp32", sizes=[(256, 256)], relief="rms"),
                   progress=lambda *_: None)
    assert not (tmp_path / "y.vtb").exists()
