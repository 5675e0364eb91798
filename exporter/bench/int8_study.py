"""Which int8 recipe: error against fp32 (and optionally relative speed) of quantization variants of one run.

`python -m exporter.bench.int8_study --run RUN --sizes 512,768,1024,1536 [--json OUT] [--timing-size 1536]`

A variant is `method:islands` (calibration method, and the graph parts kept in fp32, see exporter/quantize.py),
e.g. `percentile:pe,first-conv,heads`. Every variant is calibrated jointly at all sizes on the garment's own sketch
and its variants, as the exporter does, and measured per size on held-out sketches (exporter/accuracy.py). Variants
that share a method calibrate once. With --timing-size, the fp32 graph and every variant are timed round-robin in
one process (ratios to fp32 stay meaningful on a busy machine; absolute times come from `vtkiosk bench infer`).
The numbers behind docs/performance.md's "int8 accuracy" table come from this.

Friction figures use the `calibrated` mapping unless `--normalization perceptual` (the bundle's default; its
constants are calibrated on the garment as the exporter does). The `interior` columns set the place of edges aside
(exporter/accuracy.py `interior_errors`): the largest error on garment pixels off the outline and off the reference's
edges, how many such pixels are 64 levels or more off per sketch, and the share of those on seams (reference 255).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from exporter.bench.result_file import write_result
from exporter.bench.sources import portable
from kiosk.contract.graph import feeds

DEFAULT_VARIANTS = ("minmax:", "minmax:pe", "minmax:pe,heads", "minmax:pe,first-conv,heads",
                    "entropy:pe,first-conv,heads", "percentile:pe,heads", "percentile:pe,first-conv,heads",
                    "percentile:pe,first-conv,heads,tactile-branch")


def build_parser(prog: str) -> argparse.ArgumentParser:
    from exporter.cli import _sizes
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, required=True)
    p.add_argument("--which", choices=("best", "latest"), default="best")
    p.add_argument("--graph", choices=("full", "tactile"), default="full")
    p.add_argument("--sizes", type=_sizes, default=[(512, 512), (768, 768), (1024, 1024), (1536, 1536)])
    p.add_argument("--variants", default=";".join(DEFAULT_VARIANTS), help="method:islands;... (see docstring)")
    p.add_argument("--per-size", type=int, default=8, help="calibration sketches per size (exporter default 8)")
    p.add_argument("--error-sketches", type=int, default=4)
    p.add_argument("--timing-size", type=int, default=None, help="also time every variant at this square size")
    p.add_argument("--rounds", type=int, default=8, help="round-robin timing rounds (default 8)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--normalization", choices=("calibrated", "perceptual"), default="calibrated",
                   help="friction mapping the errors are measured in (default calibrated, as the committed table)")
    p.add_argument("--json", type=Path, default=None)
    return p


def _timings(paths: dict[str, Path], size: int, rounds: int, threads: int) -> dict[str, float]:
    from exporter.graphs import ort_session
    rng = np.random.default_rng(0)
    feed = feeds(np.where(rng.random((1, 1, size, size)) < 0.05, -1.0, 1.0).astype(np.float32),
                 np.ones((1, 1, size, size), np.float32))
    sessions = {k: ort_session(p, threads=threads) for k, p in paths.items()}
    for s in sessions.values():
        s.run(None, feed)
    times: dict[str, list[float]] = {k: [] for k in sessions}
    for _ in range(rounds):
        for k, s in sessions.items():
            t = time.perf_counter()
            s.run(None, feed)
            times[k].append(1e3 * (time.perf_counter() - t))
    return {k: float(np.median(v)) for k, v in times.items()}


def main(argv: list[str], prog: str = "python -m exporter.bench.int8_study") -> int:
    args = build_parser(prog).parse_args(argv)
    from exporter.accuracy import compare_tested, interior_errors, reference_outputs
    from exporter.calibration import calibration_set, held_out_set
    from exporter.export import _reference_assets, rewrites_conv_transpose
    from exporter.graphs import export_graph, ort_session
    from exporter.quantize import quantize_int8
    from kiosk.contract.graph import GRAPH_OUTPUTS
    from trainer.checkpoint import load_generator
    from trainer.config import read_run_config

    generator, info = load_generator(args.run, args.which)
    scale = float(info["friction_scale"])
    garment = Path(read_run_config(args.run).garment)
    constants = None
    if args.normalization == "perceptual":
        from exporter.export import _physical
        constants = _physical(garment, info, "perceptual")[1]
    mapping = {"normalization": args.normalization, "constants": constants}
    outputs = GRAPH_OUTPUTS[args.graph]
    rows = []
    with tempfile.TemporaryDirectory(prefix="vtkiosk-int8-study-") as tmp_s:
        tmp = Path(tmp_s)
        import cv2
        sketch = cv2.imread(str(_reference_assets(garment, tmp / "assets")["sketch"]), cv2.IMREAD_GRAYSCALE)
        ref = export_graph(generator, args.graph, tmp / "ref.onnx", size=args.sizes[0], rewrite=False)
        base = export_graph(generator, args.graph, tmp / "rewritten.onnx", size=args.sizes[0],
                            rewrite=rewrites_conv_transpose("int8"))
        calibration = calibration_set(sketch, args.sizes, args.per_size)
        ref_sess = ort_session(ref, threads=args.threads)
        held = {s: held_out_set(sketch, [s], args.error_sketches) for s in args.sizes}
        ref_out = {s: reference_outputs(ref_sess, outputs, held[s]) for s in args.sizes}
        paths = {"fp32": ref}
        for variant in [v for v in args.variants.split(";") if v.strip()]:
            method, _, islands = variant.strip().partition(":")
            parts = tuple(t for t in islands.split(",") if t)
            print(f"int8 study: {variant}", file=sys.stderr, flush=True)
            t0 = time.perf_counter()
            path = quantize_int8(base, tmp / f"v{len(paths)}.onnx", calibration, method=method, fp32_islands=parts,
                                 cache=tmp / f"ranges-{method}.json")
            quant_s = time.perf_counter() - t0
            paths[variant] = path
            sess = ort_session(path, threads=args.threads)
            for s in args.sizes:
                tested = reference_outputs(sess, outputs, held[s])
                err = compare_tested(ref_out[s], tested, held[s], scale, **mapping)
                err |= interior_errors(ref_out[s], tested, held[s], scale, **mapping)
                rows.append({"variant": variant, "method": method, "fp32_islands": ",".join(parts) or "none",
                             "size": f"{s[0]}x{s[1]}", "quantize_s": quant_s, **err})
        timing = _timings(paths, args.timing_size, args.rounds, args.threads) if args.timing_size else {}
    head = ["variant", "size", "PSNR dB", "tactile MAE", "friction MAE", "friction max", "interior max",
            "interior px >= 64", "garment px", "of those on seams", "worst's slope pct", "worst's slope / fp32"]
    print(f"friction in the {args.normalization} mapping")
    print("| " + " | ".join(head) + " |\n|---|---|" + "---:|" * (len(head) - 2))
    nan = float("nan")
    for r in rows:
        print(f"| {r['variant']} | {r['size']} | {r.get('visual_psnr_db', nan):.1f} | "
              f"{r['tactile_mae']:.4f} | {r['friction_mae_levels']:.2f} | {r['friction_max_levels']:.0f} | "
              f"{r.get('friction_max_interior_levels', nan):.0f} | {r.get('friction_interior_big_px', nan):.1f} | "
              f"{r.get('garment_px', nan):.0f} | {100 * r.get('friction_interior_big_saturated', nan):.0f} % | "
              f"{r.get('worst_interior_slope_percentile', nan):.1f} | {r.get('worst_interior_slope_ratio', nan):.2f} |")
    if timing:
        print(f"\nmedian ms at {args.timing_size}px, round-robin ({args.rounds} rounds, {args.threads} threads):")
        for k, v in timing.items():
            print(f"  {k:50s} {v:8.1f} ms  {v / timing['fp32']:.2f}x fp32")
    write_result(args.json, {"run": portable(args.run), "checkpoint": args.which, "step": info.get("step"),
                             "graph": args.graph, "normalization": args.normalization, "rows": rows,
                             "timing_size": args.timing_size, "timing_ms": timing})
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
