"""`engine: auto`: time every installed engine on the bundle once, at activation, and keep the fastest that agrees.

Speed order between engines depends on the CPU (ISA, cache) and on the graph, so it is measured where it matters:
on this kiosk, on this bundle's graphs, on its own reference sketch. ONNX Runtime is the reference (the exporter
states the bundle's error with it); another engine is eligible only if its outputs differ from ONNX Runtime's by
no more than the bundle already accepts from quantization, in the units the exporter states it in:
- tactile: the friction map the finger gets (the bundle's own mapping), mean absolute difference in its levels,
  over the grid (`<kind>_friction_mae_levels`) and, where the bundle states it, over the garment
  (`<kind>_friction_mae_garment_levels`);
- visual: PSNR against ONNX Runtime's image at least the stated `<kind>_visual_psnr_db`.
Each engine's figures also carry the share of the garment's pixels a just-noticeable friction step away from ONNX
Runtime's (`felt_garment_fraction`). Where the bundle states that share for its precision
(`<kind>_friction_felt_garment_fraction`, which the exporter writes for quantized graphs), it is a bound too: a mean
can stay small while the differences gather on a few felt pixels, and the bundle already told the operator how much
of the garment its quantization lets a finger notice. Where it states none (fp32), the share is reported only.
A bundle that states no error for its graphs' precision (fp32) gets `DEFAULT_BOUND_LEVELS` friction levels and
`DEFAULT_VISUAL_LEVELS` colour levels of mean difference. An engine that fails to load or run, or returns NaN/Inf,
is recorded with its reason and skipped.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from kiosk.bundle.archive import Bundle
from kiosk.contract.accuracy import IDENTICAL_DB, deviation
from kiosk.contract.graph import feeds, unpack
from kiosk.contract.sketch import letterbox, network_input, object_mask
from kiosk.inference.backends import available, open_graph
from kiosk.inference.sessions import SessionSettings
from kiosk.inference.cpu import describe

DEFAULT_BOUND_LEVELS = 0.5      # friction levels, for a bundle that states no error at its precision
DEFAULT_VISUAL_LEVELS = 0.5     # 8-bit colour levels of mean difference, likewise


@dataclass(frozen=True)
class EngineFigures:
    engine: str
    ms_p50: float | None = None           # summed over the bundle's graphs, median of the timed runs
    err_levels: float | None = None       # worst graph's friction-map mean |diff| vs ONNX Runtime, levels
    err_garment_levels: float | None = None  # the same over the garment (mask) alone
    visual_psnr_db: float | None = None   # worst graph's visual PSNR against ONNX Runtime's (99 = identical)
    eligible: bool = False
    reason: str = ""
    felt_garment_fraction: float | None = None  # worst graph's share of garment pixels a JND step off, in [0, 1]


@dataclass(frozen=True)
class EngineChoice:
    engine: str
    bound_levels: float
    grids: dict[str, list[int]]
    runs: int
    figures: list[EngineFigures] = field(default_factory=list)
    cpu: dict = field(default_factory=dict)  # kiosk.inference.cpu.describe(): the figures hold on this CPU only
    bounds: dict[str, dict[str, float]] = field(default_factory=dict)  # per graph: what an engine must stay within

    def to_json(self) -> dict:
        return asdict(self)


def _stated(bundle: Bundle, kind: str, name: str) -> float | None:
    """`<kind>_<name>` (what the exporter writes) or `<name>` under the graph's precision, if finite."""
    g = bundle.manifest.graph(kind)
    errs = bundle.manifest.errors.get(g.precision, {})
    v = errs.get(f"{kind}_{name}", errs.get(name))
    return float(v) if v is not None and np.isfinite(v) else None


def graph_bounds(bundle: Bundle, kind: str) -> dict[str, float]:
    """What another engine may differ from ONNX Runtime by on one graph: the bundle's stated quantization error."""
    spec = bundle.manifest.graph(kind)
    out: dict[str, float] = {}
    if "tactile" in spec.outputs:
        canvas = _stated(bundle, kind, "friction_mae_levels")
        out["friction_mae_levels"] = canvas if canvas is not None and canvas > 0 else DEFAULT_BOUND_LEVELS
        garment = _stated(bundle, kind, "friction_mae_garment_levels")
        if garment is not None and garment > 0:
            out["friction_mae_garment_levels"] = garment
        felt = _stated(bundle, kind, "friction_felt_garment_fraction")
        if felt is not None and felt > 0:
            out["friction_felt_garment_fraction"] = felt
    if "visual" in spec.outputs:
        psnr_db = _stated(bundle, kind, "visual_psnr_db")
        if psnr_db is not None and psnr_db > 0:
            out["visual_psnr_db"] = psnr_db
        else:
            out["visual_mae_levels"] = DEFAULT_VISUAL_LEVELS
    return out


def error_bound(bundle: Bundle) -> float:
    """The tightest friction MAE (levels) the bundle states for its graphs: `<kind>_friction_mae_levels` (what the
    exporter writes) or `friction_mae_levels` under each graph's precision."""
    m = bundle.manifest
    bounds = []
    for kind, g in m.graphs.items():
        errs = m.errors.get(g.precision, {})
        bounds.append(errs.get(f"{kind}_friction_mae_levels", errs.get("friction_mae_levels")))
    bounds = [float(b) for b in bounds if b is not None and np.isfinite(b) and b > 0]
    return min(bounds) if bounds else DEFAULT_BOUND_LEVELS


def bench_grid(bundle: Bundle, kind: str, max_side: int) -> tuple[int, int]:
    """The largest declared size within max_side (what the kiosk will serve), else the smallest declared."""
    sizes = [(int(w), int(h)) for w, h in bundle.manifest.graph(kind).sizes]
    fit = [s for s in sizes if max(s) <= max_side]
    return max(fit, key=lambda s: s[0] * s[1]) if fit else min(sizes, key=lambda s: s[0] * s[1])


def _feed(bundle: Bundle, grid: tuple[int, int]) -> dict[str, np.ndarray]:
    w, h = grid
    if "sketch" in bundle.manifest.assets:
        fitted, _ = letterbox(bundle.asset("sketch"), (w, h))
        x = network_input(fitted, object_mask(fitted))
        return feeds(x.sketch, x.mask)
    return feeds(np.zeros((1, 1, h, w), np.float32), np.ones((1, 1, h, w), np.float32))


def _breaches(dev: dict[str, float], bounds: dict[str, float]) -> list[str]:
    """The bounds `dev` breaks, worded; PSNR must reach its bound, every other figure stay within its own."""
    bad = []
    for key, bound in bounds.items():
        v = dev.get(key)
        if v is None:
            continue
        if (v < bound) if key == "visual_psnr_db" else (v > bound):
            bad.append(f"{key} {v:.3g} against the bound {bound:g}")
    return bad


def choose_engine(bundle: Bundle, *, threads: int, providers: list[str] | None = None, max_side: int = 512,
                  runs: int = 3, engines: tuple[str, ...] | None = None,
                  settings: SessionSettings | None = None) -> EngineChoice:
    """Benchmark the engines on every graph of the bundle and pick one (ONNX Runtime if nothing else qualifies)."""
    engines = tuple(engines or available())
    kinds = list(bundle.manifest.graphs)
    bounds = {k: graph_bounds(bundle, k) for k in kinds}
    grids = {k: bench_grid(bundle, k, max_side) for k in kinds}
    inputs = {k: _feed(bundle, grids[k]) for k in kinds}
    reference: dict[str, list[np.ndarray]] = {}
    figures: list[EngineFigures] = []
    order = ["onnxruntime"] + [e for e in engines if e != "onnxruntime"]
    for engine in order:
        total: list[float] = [0.0] * runs
        worst: dict[str, float] = {}
        breaches: list[str] = []
        try:
            for kind in kinds:
                spec = bundle.manifest.graph(kind)
                runner = open_graph(engine, bundle.graph_path(kind), threads=threads, providers=providers,
                                    settings=settings)
                outs = runner.run(spec.outputs, inputs[kind])  # warm-up: first-shape allocation is not timed
                for i in range(runs):
                    t0 = time.perf_counter()
                    runner.run(spec.outputs, inputs[kind])
                    total[i] += 1e3 * (time.perf_counter() - t0)
                if not all(np.isfinite(o).all() for o in outs):
                    raise ValueError("non-finite output")
                if engine == "onnxruntime":
                    reference[kind] = outs
                    continue
                m = bundle.manifest
                dev = deviation(dict(zip(spec.outputs, reference[kind])), dict(zip(spec.outputs, outs)),
                                unpack(inputs[kind])[1], m.friction_scale, normalization=m.friction_normalization,
                                constants=m.friction_constants)
                breaches += [f"{kind}: {b}" for b in _breaches(dev, bounds[kind])]
                for key, v in dev.items():
                    worse = min if key == "visual_psnr_db" else max
                    worst[key] = worse(worst.get(key, v), v)
        except Exception as exc:  # noqa: BLE001 - any engine failure makes it ineligible, with its reason
            if engine == "onnxruntime":
                raise
            figures.append(EngineFigures(engine, reason=f"failed: {str(exc).splitlines()[0][:200]}"))
            continue
        if engine == "onnxruntime":  # the reference: no deviation from itself, in the figures the others get
            outputs = {o for k in kinds for o in bundle.manifest.graph(k).outputs}
            worst = ({"friction_mae_levels": 0.0, "friction_mae_garment_levels": 0.0,
                      "friction_felt_garment_fraction": 0.0} if "tactile" in outputs
                     else {}) | ({"visual_psnr_db": IDENTICAL_DB} if "visual" in outputs else {})

        def fig(key: str) -> float | None:
            return float(f"{worst[key]:.4g}") if key in worst else None

        figures.append(EngineFigures(engine, round(statistics.median(total), 3), fig("friction_mae_levels"),
                                     fig("friction_mae_garment_levels"), fig("visual_psnr_db"), not breaches,
                                     "; ".join(breaches)[:400], fig("friction_felt_garment_fraction")))
    best = min((f for f in figures if f.eligible), key=lambda f: f.ms_p50)
    return EngineChoice(best.engine, error_bound(bundle), {k: list(g) for k, g in grids.items()}, runs, figures,
                        describe(), bounds)


def main(argv: list[str] | None = None) -> int:
    """`python -m kiosk.inference.autoselect BUNDLE`: what `engine: auto` would pick here, as JSON."""
    import argparse
    import json
    import sys
    import tempfile
    from pathlib import Path

    from kiosk.bundle.archive import open_bundle
    from kiosk.bundle.signature import load_trusted_keys
    from kiosk.contract.errors import KioskError

    ap = argparse.ArgumentParser(prog="python -m kiosk.inference.autoselect", description=main.__doc__)
    ap.add_argument("bundle", type=Path)
    ap.add_argument("--trusted-keys", type=Path, help="folder of trusted public keys (default: accept unsigned)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--max-side", type=int, default=512)
    a = ap.parse_args(argv)
    try:
        with tempfile.TemporaryDirectory() as work:
            trusted = load_trusted_keys(a.trusted_keys) if a.trusted_keys else None
            b = open_bundle(a.bundle, trusted, workdir=Path(work), allow_unsigned=trusted is None)
            choice = choose_engine(b, threads=a.threads, runs=a.runs, max_side=a.max_side)
    except (KioskError, OSError) as exc:
        print(f"error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    print(json.dumps(choice.to_json(), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
