"""`vtkiosk export`: a trained run -> a signed `.vtb` bundle with full/tactile/visual graphs at one precision,
its measured error against fp32, the garment's friction calibration and reference assets.
"""
from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import json
import platform
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

import exporter
from exporter.accuracy import compare_sessions
from exporter.bundle_writer import write_bundle
from exporter.calibration import calibration_set, held_out_set
from exporter.graphs import export_graph, ort_session, parity
from exporter.quantize import DEFAULT_FP32_ISLANDS, Calibrated, convert_fp16, quantize_int8
from exporter.shared_weights import WEIGHTS_FILE, share_weights
from kiosk.bundle.archive import sha256_file
from exporter.errors import ExportError
from kiosk.bundle.manifest import EMBEDDED_SCHEMA, SCHEMA_VERSION, GraphSpec, Manifest
from kiosk.contract.garment import garment_id
from kiosk.contract.graph import GRAPH_KINDS, GRAPH_OUTPUTS, GRID_MULTIPLE, feeds, is_grid
from kiosk.contract.haptics import NORMALIZATIONS

# A wrong export (a missing op, wrong weights) differs by 1e-2 and more. ONNX Runtime's fp32 kernels differ from
# PyTorch's by up to ~4e-4 on a ResNet-9 with stacked InstanceNorm (PyTorch fp32 agrees with fp64 to ~2e-6 there),
# about a tenth of one 8-bit level (2/255 in [-1, 1]); the two-branch U-Net stays below 1e-4.
PARITY_BOUND = 1e-3


@dataclass
class ExportConfig:
    precision: str = "int8"
    sizes: list[tuple[int, int]] = field(default_factory=lambda: [(512, 512), (768, 768)])
    graphs: tuple[str, ...] = GRAPH_KINDS
    calibration_per_size: int = 8
    error_per_size: int = 4
    calibration_method: str = "percentile"   # measured best for int8 error (docs/performance.md)
    fp32_islands: tuple[str, ...] = DEFAULT_FP32_ISLANDS   # int8 only: parts kept in fp32 (exporter/quantize.py)
    max_friction_mae: float = 1.0      # uint8 levels; int8 graphs above this are refused unless forced
    # the same over the garment alone (exporter/accuracy.py: the canvas figure is diluted by the paper); None: none
    max_friction_mae_garment: float | None = None
    force: bool = False
    which: str = "best"
    panel_size: tuple[int, int] = (1280, 800)
    normalization: str = "perceptual"   # friction mapping the bundle asks for (kiosk.contract.haptics)
    model_version: str | None = None
    display_name: str | None = None
    seed: int = 0
    runs_root: Path | None = None   # source_run is recorded relative to this (default: the working directory)
    share_weights: bool = True     # graphs keep their tensors in one shared weights file (manifest schema 2)
    relief: str = "none"           # "rms"/"ls": the tactile output's gain fitted on the training touches
    mirrors: str = "none"          # the tactile output averaged over mirrored views (before the relief gain)


@dataclass
class ExportReport:
    manifest: Manifest
    parity: dict[str, float]
    errors: dict[str, dict[str, float]]
    out: Path


def source_run_name(run_dir: Path, runs_root: Path | None = None) -> str:
    """How the manifest names the training run: its path relative to `runs_root` (default: the working directory),
    or, for a run outside it, `sha256:` and the first 16 hex digits of the SHA-256 of its resolved path. Never an
    absolute path: a bundle travels to kiosks and must not carry the build machine's layout."""
    run = Path(run_dir).resolve()
    root = Path(runs_root if runs_root is not None else Path.cwd()).resolve()
    try:
        rel = run.relative_to(root).as_posix()
    except ValueError:
        rel = ""
    if rel and rel != ".":
        return rel
    return "sha256:" + hashlib.sha256(str(run).encode()).hexdigest()[:16]


def model_branches(info: dict) -> int:
    """2 for the two-branch U-Net (one-modality graphs are cheaper than `full`); 1 for a generator that computes
    every channel with one network (the baselines): exporting `visual` or `tactile` graphs for it would only
    duplicate `full` at the same cost, so its bundle ships `full` alone and says so in the manifest."""
    return 2 if info.get("generator_class", "TwoBranchUNet") == "TwoBranchUNet" else 1


def rewrites_conv_transpose(precision: str) -> bool:
    """Only int8 graphs get the ConvTranspose -> Conv3x3 + DepthToSpace rewrite: it is what lets the decoder run
    int8 at all, but it costs 2.25x the multiply-adds, so fp32/fp16 keep ONNX Runtime's own ConvTranspose (measured
    faster on CPU: docs/performance.md)."""
    return precision == "int8"


def lower_precision(fp32: Path, precision: str, dst_dir: Path, calibration, cfg: ExportConfig,
                    ranges_from: Calibrated | None = None) -> Path:
    """The graph at `precision` made from the fp32 graph `fp32` (returned as is for fp32). int8: calibrated
    ranges are kept in `dst_dir` and taken from `ranges_from` where that graph computes every tensor of this one."""
    stem = Path(fp32).name.split(".")[0]
    if precision == "int8":
        return quantize_int8(fp32, Path(dst_dir) / f"{stem}.int8.onnx", calibration, method=cfg.calibration_method,
                             fp32_islands=cfg.fp32_islands, cache=Path(dst_dir) / f"{stem}.ranges.json",
                             ranges_from=ranges_from)
    if precision == "fp16":
        return convert_fp16(fp32, Path(dst_dir) / f"{stem}.fp16.onnx")
    return Path(fp32)


def _shared(paths: dict[str, Path], folder: Path, held_out, progress) -> tuple[dict[str, Path], Path, str]:
    """The graphs rewritten to share one weights file, checked to give bit-identical outputs to the graphs that
    embed their tensors (same nodes, same tensor bytes: any difference means the sharing is wrong)."""
    shared, weights, report = share_weights(paths, folder)
    x = held_out[0]
    for kind, path in paths.items():
        want = ort_session(path, threads=1).run(GRAPH_OUTPUTS[kind], feeds(x.sketch, x.mask))
        got = ort_session(shared[kind], threads=1).run(GRAPH_OUTPUTS[kind], feeds(x.sketch, x.mask))
        if not all(np.array_equal(a, b) for a, b in zip(want, got)):
            raise ExportError(f"the {kind} graph with shared weights does not reproduce the graph that embeds them; "
                              "export with --embed-weights and report this")
    note = report.line() + (f"; differing between graphs: {', '.join(report.differing)}" if report.differing else "")
    progress(f"export: shared weights: {note}")
    return shared, weights, note


def _numbers(doc, prefix: str = "") -> dict[str, float]:
    """The finite numbers of a run's metrics.json (nested: train, val, eval), keyed by dotted path."""
    out: dict[str, float] = {}
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.update(_numbers(v, f"{prefix}{k}."))
    elif isinstance(doc, (int, float)) and not isinstance(doc, bool) and np.isfinite(doc):
        out[prefix.rstrip(".")] = float(doc)
    return out


def _reference_assets(garment_dir: Path, folder: Path) -> dict[str, Path]:
    """Sketch, mask and visual of the camera frame (not the padding): what the A/B study and attract screen show."""
    from trainer.data.touchclothing import load_garment

    g = load_garment(garment_dir, tactile=False)
    (fw, fh), (ox, oy) = g.frame, g.offset
    crop = (slice(oy, oy + fh), slice(ox, ox + fw))
    folder.mkdir(parents=True, exist_ok=True)
    paths = {"sketch": folder / "sketch.png", "mask": folder / "mask.png", "visual": folder / "visual.png"}
    cv2.imwrite(str(paths["sketch"]), g.sketch[crop])
    cv2.imwrite(str(paths["mask"]), g.mask[crop].astype(np.uint8) * 255)
    if g.visual is None:
        raise ExportError(f"{garment_dir}: no ground-truth visual to ship as a reference asset")
    cv2.imwrite(str(paths["visual"]), cv2.cvtColor(g.visual[crop], cv2.COLOR_RGB2BGR))
    return paths


def _physical(garment_dir: Path, info: dict, normalization: str) -> tuple[float, dict[str, float]]:
    """The model's pixel pitch (recorded by the trainer; for older runs, the dataset's) and the friction mapping's
    constants, calibrated on the garment's measured contact pixels like its friction scale."""
    from trainer.data.touchclothing import load_garment
    from trainer.physical import dataset_pitch_mm, friction_constants

    g = load_garment(garment_dir, tactile=normalization == "perceptual")
    pitch = info.get("pixel_pitch_mm")
    if not (isinstance(pitch, (int, float)) and not isinstance(pitch, bool) and pitch > 0):
        pitch = dataset_pitch_mm(g)[0]
    return float(pitch), friction_constants(g, normalization)


def _recipe(cfg: ExportConfig) -> dict[str, str]:
    """How the graphs were made, in the manifest's provenance (the benchmark rebuilds other precisions the same way)."""
    out = {"rewrite": "ConvTranspose(4,2,1) -> Conv3x3 + DepthToSpace" if rewrites_conv_transpose(cfg.precision)
           else "none"}
    if cfg.precision == "int8":
        out["calibration"] = f"{cfg.calibration_method}, {cfg.calibration_per_size} sketches per size"
        out["int8_fp32_islands"] = ",".join(cfg.fp32_islands) or "none"
    return out


def _calibrated(generator, garment_dir: Path, side: int, rule: str):
    """The generator with its relief calibration (trainer/relief.py) as part of every graph, and the provenance line
    that says so. A garment that cannot calibrate it is an error: the operator asked for a calibrated bundle."""
    from trainer.calibration import CalibrationError
    from trainer.data.touchclothing import load_garment
    from trainer.relief import calibrate
    from trainer.relief_rules import RULES

    if rule not in RULES or rule == "none":
        raise ExportError(f"relief must be one of {', '.join(r for r in RULES if r != 'none')}; got {rule!r}")
    try:
        wrapped, _, line = calibrate(generator, load_garment(garment_dir), side, rule)
    except CalibrationError as exc:
        raise ExportError(f"cannot calibrate the relief: {exc}. Export without --relief") from None
    return wrapped, line


def export_run(run_dir: Path, out: Path, cfg: ExportConfig, *, signing_key=None, progress=print) -> ExportReport:
    """Export, measure, refuse or write. Raises ExportError/CheckpointError with an operator-facing message."""
    from trainer.checkpoint import load_generator
    from trainer.config import read_run_config

    run_dir = Path(run_dir)
    if cfg.precision not in ("int8", "fp16", "fp32"):
        raise ExportError(f"precision must be int8, fp16 or fp32; got {cfg.precision!r}")
    for w, h in cfg.sizes:
        if not (is_grid(w) and is_grid(h)):
            raise ExportError(f"sizes must be multiples of {GRID_MULTIPLE} (the generator halves the grid eight "
                              f"times); got {w}x{h}")
    generator, info = load_generator(run_dir, cfg.which)
    branches = model_branches(info)
    kinds = tuple(cfg.graphs) if branches == 2 else ("full",)
    run_cfg = read_run_config(run_dir)
    garment_dir = Path(run_cfg.garment)
    if not garment_dir.is_dir():
        raise ExportError(f"the run's garment folder {garment_dir} is not here; the exporter needs its sketch, "
                          "mask and visual as reference assets")
    scale = info.get("friction_scale")
    if not isinstance(scale, (int, float)) or not scale > 0:
        raise ExportError(f"run {run_dir} has no friction calibration (friction_scale) in its checkpoint")
    if cfg.normalization not in NORMALIZATIONS:
        raise ExportError(f"normalization must be one of {', '.join(NORMALIZATIONS)}; got {cfg.normalization!r}")
    pitch, constants = _physical(garment_dir, info, cfg.normalization)
    if cfg.mirrors != "none":
        from trainer.models.mirror_average import MODES, MirrorAverage
        if cfg.mirrors not in MODES:
            raise ExportError(f"mirrors must be one of {', '.join(MODES)}; got {cfg.mirrors!r}")
        generator = MirrorAverage(generator, cfg.mirrors).eval()
        progress(f"export: relief averaged over mirrored views ({cfg.mirrors})")
    relief = None
    if cfg.relief != "none":
        generator, relief = _calibrated(generator, garment_dir, int(info["crop"]), cfg.relief)
        progress(f"export: relief calibrated ({relief})")
    with tempfile.TemporaryDirectory(prefix="vtkiosk-export-") as tmp_s:
        tmp = Path(tmp_s)
        assets = _reference_assets(garment_dir, tmp / "assets")
        sketch = cv2.imread(str(assets["sketch"]), cv2.IMREAD_GRAYSCALE)
        calibration = calibration_set(sketch, cfg.sizes, cfg.calibration_per_size, cfg.seed)
        held_out = held_out_set(sketch, cfg.sizes, cfg.error_per_size, cfg.seed)
        sources: dict[str, Path] = {f"assets/{k}.png": p for k, p in assets.items()}
        graphs: dict[str, GraphSpec] = {}
        parities: dict[str, float] = {}
        errors: dict[str, dict[str, float]] = {}
        progress(f"export: {len(kinds)} graph(s) at {cfg.precision}, sizes "
                 + ", ".join(f"{w}x{h}" for w, h in cfg.sizes)
                 + ("" if branches == 2 else f" ({info.get('generator_class')} has no separate branches: the full "
                    "graph serves every need)"))
        ranges_from: Calibrated | None = None   # the first int8 graph's ranges serve the others (exporter.ranges)
        for kind in kinds:
            fp32 = export_graph(generator, kind, tmp / f"{kind}.fp32.onnx", size=cfg.sizes[0],
                                rewrite=rewrites_conv_transpose(cfg.precision))
            parities[kind] = parity(generator, kind, fp32, [(x.sketch, x.mask) for x in held_out[:2]])
            progress(f"export: {kind} graph fp32, max |ONNX - PyTorch| = {parities[kind]:.2e}")
            if parities[kind] > PARITY_BOUND:
                raise ExportError(f"{kind} graph differs from PyTorch by {parities[kind]:.2e} (> {PARITY_BOUND}); "
                                  "the export is wrong")
            path = lower_precision(fp32, cfg.precision, tmp, calibration, cfg, ranges_from)
            if cfg.precision == "int8" and ranges_from is None:
                ranges_from = Calibrated.beside(tmp / f"{kind}.ranges.json")
            if cfg.precision != "fp32":
                err = compare_sessions(ort_session(fp32), ort_session(path), GRAPH_OUTPUTS[kind], held_out, scale,
                                       normalization=cfg.normalization, constants=constants or None)
                errors.setdefault(cfg.precision, {}).update({f"{kind}_{k}": v for k, v in err.items()})
                progress(f"export: {kind} graph {cfg.precision} vs fp32: " +
                         ", ".join(f"{k} {v:.4g}" for k, v in err.items()))
                for key, bound, flag, where in (
                        ("friction_mae_levels", cfg.max_friction_mae, "--max-friction-mae", "over the canvas"),
                        ("friction_mae_garment_levels", cfg.max_friction_mae_garment, "--max-friction-mae-garment",
                         "in the garment")):
                    fmae = err.get(key)
                    if fmae is not None and bound is not None and fmae > bound and cfg.precision == "int8" \
                            and not cfg.force:
                        raise ExportError(f"int8 {kind} graph's friction-map error is {fmae:.2f} levels of 255 "
                                          f"{where} (bound {bound}); not writing it. Export fp32/fp16, raise "
                                          f"{flag}, or --force")
            rel = f"graphs/{kind}.{cfg.precision}.onnx"
            sources[rel] = path
            graphs[kind] = GraphSpec(rel, cfg.precision, list(GRAPH_OUTPUTS[kind]), [list(s) for s in cfg.sizes])
        sharing = {}
        if cfg.share_weights:
            paths = {kind: sources[g.file] for kind, g in graphs.items()}
            shared, weights, note = _shared(paths, tmp / "shared", held_out, progress)
            sources.update({graphs[kind].file: path for kind, path in shared.items()})
            sources[f"graphs/{WEIGHTS_FILE}"] = weights
            graphs = {k: dataclasses.replace(g, weights=f"graphs/{WEIGHTS_FILE}") for k, g in graphs.items()}
            sharing = {"weights": note}
        metrics_path = run_dir / "metrics.json"
        metrics = _numbers(json.loads(metrics_path.read_text())) if metrics_path.is_file() else {}
        ck_path = Path(info["path"])
        now = dt.datetime.now(dt.timezone.utc).replace(microsecond=0)
        manifest = Manifest(
            schema_version=SCHEMA_VERSION if cfg.share_weights else EMBEDDED_SCHEMA,
            garment_id=garment_id(garment_dir.name),
            display_name=cfg.display_name or garment_dir.name.removeprefix("singleskit_").split("_padded_")[0],
            model_version=cfg.model_version or f"{now:%Y%m%d}-{info.get('step', 0)}",
            method=str(info.get("method") or run_cfg.method),
            created_at=now.isoformat().replace("+00:00", "Z"),
            exporter_version=exporter.__version__,
            source_run=source_run_name(run_dir, cfg.runs_root),
            checkpoint_sha256=sha256_file(ck_path),
            graphs=graphs,
            friction_scale=float(scale),
            friction_normalization=cfg.normalization,
            friction_constants=constants,
            pixel_pitch_mm=pitch,
            panel_size=list(cfg.panel_size),
            assets={k: f"assets/{k}.png" for k in assets},
            files={},
            metrics=metrics,
            errors={**errors, "fp32": {f"{k}_onnx_vs_torch_max_abs": v for k, v in parities.items()}},
            branches=branches,
            provenance={"host": socket.gethostname(), "python": platform.python_version(),
                        "checkpoint": ck_path.name, **_recipe(cfg), **sharing,
                        **({"mirrors": cfg.mirrors} if cfg.mirrors != "none" else {}),
                        **({"relief": relief} if relief else {}),
                        "sizes": ",".join(f"{w}x{h}" for w, h in cfg.sizes)},
        )
        progress("export: writing" + (" and signing" if signing_key is not None else "") + " the bundle")
        written = write_bundle(out, manifest, sources, signing_key=signing_key)
    return ExportReport(written, parities, errors, Path(out))
