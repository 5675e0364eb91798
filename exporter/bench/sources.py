"""Which graphs `vtkiosk bench infer` measures, and where each comes from.

A bundle ships one precision per graph (what the kiosk runs). Everything else the benchmark needs is rebuilt from
the bundle's source training run with the exporter's own code, after checking that the run's checkpoint has the
SHA-256 the manifest names (so the reference really is the same model):
- the fp32 reference that errors are measured against (bundles do not carry it: it would double their size for a
  number the exporter already wrote into the manifest);
- other precisions, made with the recipe the manifest's provenance records (calibration method, sketches per size,
  int8 fp32 islands) at the bundle's declared sizes;
- PyTorch eager fp32, for the speed ratio.
Without the run (e.g. on a kiosk without torch), `--reference REF.vtb` (an fp32 bundle of the same checkpoint) gives
the reference, and only the bundle's own precision is measured against it.
"""
from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from pathlib import Path

from kiosk.bundle.archive import Bundle, sha256_file
from exporter.errors import ExportError


class BenchError(ExportError):
    """A benchmark that cannot run as asked; the message says what to give instead."""


@dataclass(frozen=True)
class Candidate:
    """One graph to measure: an ONNX file at a precision in an engine (ONNX Runtime on a provider, OpenVINO), or
    PyTorch eager (path None). form: native (ConvTranspose) or rewritten (Conv + DepthToSpace)."""

    graph: str
    precision: str
    provider: str
    source: str           # bundle | run | reference | torch
    path: Path | None
    engine: str = "onnxruntime"
    form: str = "native"


@dataclass
class Sources:
    reference: dict[str, Path] = field(default_factory=dict)      # graph -> fp32 ONNX reference
    reference_from: str = ""
    graphs: dict[tuple[str, str], tuple[Path, str]] = field(default_factory=dict)  # (graph, precision) -> (path, src)
    # int8 of the native graph (ConvTranspose kept, quantised as QDQ ConvTranspose): graph -> path. The int8 in
    # `graphs` is the exporter's, on the Conv + DepthToSpace rewrite (2x the MACs, but ONNX Runtime runs it int8).
    native_int8: dict[str, Path] = field(default_factory=dict)
    run_dir: Path | None = None
    which: str = "best"
    notes: list[str] = field(default_factory=list)


def portable(path: Path | str | None) -> str | None:
    """A path as a JSON that may be committed should hold it: relative to the working directory when inside it,
    else `<outside>/NAME` (a temporary folder of this machine means nothing on another; the name still says which)."""
    if path is None:
        return None
    p = Path(path).resolve()
    try:
        return p.relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return f"<outside>/{p.name}"


def open_measured(path: Path, trusted_keys: Path | None, workdir: Path):
    """(bundle, trusted keys or None): checked against `trusted_keys` when given; unsigned bundles are allowed
    otherwise, because a benchmark measures a bundle and never serves it."""
    from kiosk.bundle.archive import open_bundle
    trusted = None
    if trusted_keys is not None:
        from kiosk.bundle.signature import load_trusted_keys
        trusted = load_trusted_keys(trusted_keys)
    return open_bundle(path, trusted, workdir=workdir, allow_unsigned=trusted is None), trusted


def torch_available() -> bool:
    return importlib.util.find_spec("torch") is not None


def matching_run(bundle: Bundle, run: Path | None) -> tuple[Path | None, str, str]:
    """(run folder, checkpoint name, why not) for the run whose checkpoint the bundle was exported from.

    An explicit `run` that does not match is an error; the manifest's own `source_run` that is gone or has moved on
    (a newer checkpoint) is only a note, and the benchmark continues without it.
    """
    m = bundle.manifest
    explicit = run is not None
    folder = Path(run) if explicit else Path(m.source_run)
    name = m.provenance.get("checkpoint", "best.pt")
    candidates = [name] + [n for n in ("best.pt", "latest.pt") if n != name]
    if not (folder / "checkpoints").is_dir():
        why = f"run {folder} has no checkpoints/ folder"
        if explicit:
            raise BenchError(why)
        return None, name, f"the bundle's source run is not here ({why})"
    for cand in candidates:
        path = folder / "checkpoints" / cand
        if path.is_file() and sha256_file(path) == m.checkpoint_sha256:
            return folder, cand, ""
    why = (f"no checkpoint in {folder}/checkpoints has the bundle's SHA-256 {m.checkpoint_sha256[:12]}... "
           "(trained further since the export?)")
    if explicit:
        raise BenchError(why + "; re-export the bundle from this run, or give the run it came from")
    return None, name, why


def recipe(bundle: Bundle):
    """The exporter configuration that reproduces the bundle's graphs at other precisions."""
    from exporter.export import ExportConfig
    from exporter.quantize import DEFAULT_FP32_ISLANDS

    prov = bundle.manifest.provenance
    sizes = sorted({tuple(s) for g in bundle.manifest.graphs.values() for s in g.sizes}, key=lambda s: s[0] * s[1])
    cfg = ExportConfig(sizes=[(int(w), int(h)) for w, h in sizes])
    calib = prov.get("calibration", "")
    if calib:
        method, _, rest = calib.partition(",")
        if method.strip() in ("minmax", "percentile", "entropy"):
            cfg.calibration_method = method.strip()
        digits = "".join(c for c in rest.split("sketches")[0] if c.isdigit())
        if digits:
            cfg.calibration_per_size = int(digits)
    islands = prov.get("int8_fp32_islands")
    cfg.fp32_islands = DEFAULT_FP32_ISLANDS if islands is None else tuple(
        t for t in islands.split(",") if t and t != "none")
    return cfg


def build_sources(bundle: Bundle, graphs: list[str], precisions: list[str], workdir: Path, *,
                  run: Path | None, reference: Bundle | None, progress=lambda msg: None) -> Sources:
    """Collect or build every graph file the benchmark needs (see the module docstring)."""
    src = Sources()
    m = bundle.manifest
    for kind in graphs:
        spec = m.graph(kind)
        src.graphs[(kind, spec.precision)] = (bundle.graph_path(kind), "bundle")
    own = {m.graph(k).precision for k in graphs}
    run_dir, ck_name, why = (None, "", "")
    if torch_available():
        run_dir, ck_name, why = matching_run(bundle, run)
    elif run is not None:
        raise BenchError("--run needs the training extra (torch); install vtkiosk[train] or drop --run")
    else:
        why = "torch is not installed: no PyTorch eager row, no graphs rebuilt from the run"
    if why:
        src.notes.append(why)
    src.run_dir, src.which = run_dir, ck_name.removesuffix(".pt") if ck_name else "best"
    if reference is not None:
        if reference.manifest.checkpoint_sha256 != m.checkpoint_sha256:
            raise BenchError("the --reference bundle was exported from another checkpoint than the bundle "
                             f"({reference.manifest.checkpoint_sha256[:12]}... vs {m.checkpoint_sha256[:12]}...)")
        for kind in graphs:
            spec = reference.manifest.graph(kind)
            if spec.precision != "fp32":
                raise BenchError(f"the --reference bundle's {kind} graph is {spec.precision}; it must be fp32")
            src.reference[kind] = reference.graph_path(kind)
            src.graphs.setdefault((kind, "fp32"), (reference.graph_path(kind), "reference"))
        src.reference_from = "--reference bundle (same checkpoint SHA-256)"
    for kind in graphs:
        if m.graph(kind).precision == "fp32" and kind not in src.reference:
            src.reference[kind] = bundle.graph_path(kind)
            src.reference_from = src.reference_from or "the bundle's own fp32 graphs"
    if run_dir is None:
        missing = [p for p in precisions if p not in own and not (p == "fp32" and src.reference)]
        if missing:
            src.notes.append(f"precision(s) {', '.join(missing)} skipped: they are built from the source run, "
                             "which is not available")
        if not src.reference:
            src.notes.append("no fp32 reference (give --run or --reference): error columns are empty")
        return src
    return _build_from_run(bundle, graphs, precisions, workdir, src, progress)


def _build_from_run(bundle: Bundle, graphs: list[str], precisions: list[str], workdir: Path, src: Sources,
                    progress) -> Sources:
    from exporter.calibration import calibration_set
    from exporter.export import lower_precision, rewrites_conv_transpose
    from exporter.graphs import export_graph
    from trainer.checkpoint import load_generator

    generator, _ = load_generator(src.run_dir, src.which)
    cfg = recipe(bundle)
    sketch = bundle.asset("sketch")
    calibration = None
    folder = Path(workdir) / "built"
    folder.mkdir(parents=True, exist_ok=True)
    for kind in graphs:
        plain = folder / f"{kind}.fp32.onnx"
        if kind not in src.reference:
            progress(f"bench: exporting the fp32 {kind} reference from {src.run_dir}")
            src.reference[kind] = export_graph(generator, kind, plain, size=cfg.sizes[0],
                                               rewrite=rewrites_conv_transpose("fp32"))
            src.reference_from = f"fp32 graphs exported from {src.run_dir} ({src.which}.pt, SHA-256 matches)"
        for precision in precisions:
            if (kind, precision) in src.graphs:
                continue
            if precision == "fp32":
                src.graphs[(kind, "fp32")] = (src.reference[kind], "run")
                continue
            progress(f"bench: building the {precision} {kind} graph from the run")
            base = src.reference[kind]
            if rewrites_conv_transpose(precision) != rewrites_conv_transpose("fp32"):
                base = export_graph(generator, kind, folder / f"{kind}.rewritten.onnx", size=cfg.sizes[0],
                                    rewrite=rewrites_conv_transpose(precision))
            if precision == "int8" and calibration is None:
                calibration = calibration_set(sketch, cfg.sizes, cfg.calibration_per_size, cfg.seed)
            out = folder / precision
            out.mkdir(exist_ok=True)
            src.graphs[(kind, precision)] = (lower_precision(base, precision, out, calibration, cfg), "run")
        if "int8" in precisions and not rewrites_conv_transpose("fp32"):
            if calibration is None:
                calibration = calibration_set(sketch, cfg.sizes, cfg.calibration_per_size, cfg.seed)
            progress(f"bench: building the native int8 {kind} graph (QDQ ConvTranspose) from the run")
            out = folder / "int8-native"
            out.mkdir(exist_ok=True)
            src.native_int8[kind] = lower_precision(src.reference[kind], "int8", out, calibration, cfg)
    return src
