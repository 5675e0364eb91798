"""`vtkiosk bench infer --bundle FILE`: speed against error of a bundle's graphs.

For each size x precision x graph form (native ConvTranspose, or the int8 Conv + DepthToSpace rewrite) x engine
(ONNX Runtime per execution provider, OpenVINO), and for the kiosk planner's own settings (exporter/bench/planned.py):
latency (warm-up, then --runs timed runs: p50/p95) and peak RSS, each configuration in a fresh process
(exporter/bench/worker.py); graph GMAC (exporter/bench/macs.py) and bytes; error against the fp32 reference of the
same model on held-out sketches (visual PSNR, tactile MAE, friction-map MAE in levels: exporter/accuracy.py); on
synthetic garments the full-field error against ground truth with the garment filling the canvas
(exporter/bench/truth.py) beside the trivial answer (a flat garment), so quantization error sits beside model error;
and PyTorch eager fp32 at the same sizes with the speed ratio. Where the reference and the other precisions come
from: exporter/bench/sources.py. Prints a table and the goals' verdict, writes JSON, a speed-vs-error PNG and the
Pareto plot of latency against error vs truth.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from exporter.bench.bundle_bytes import bundle_layout, bundle_line
from exporter.bench.environment import environment
from exporter.bench.report import goal_lines, goals, markdown_table, profile_lines
from exporter.bench.result_file import write_result
from exporter.bench.sources import BenchError, Candidate, build_sources, open_measured, portable, torch_available
from exporter.shared_weights import graph_bytes
from kiosk.contract.errors import KioskError
from kiosk.contract.graph import GRAPH_OUTPUTS, GRID_MULTIPLE, feeds, is_grid, unpack

PRECISIONS = ("fp32", "fp16", "int8")
ENGINES = ("onnxruntime", "openvino")
NOT_COMPUTE = {"AzureExecutionProvider"}  # a remote-call provider, not a place to run a graph


def _sizes(text: str) -> list[tuple[int, int]]:
    from exporter.cli import _sizes as parse
    out = parse(text)
    for w, h in out:
        if not (is_grid(w) and is_grid(h)):
            raise argparse.ArgumentTypeError(f"sizes must be multiples of {GRID_MULTIPLE}; got {w}x{h}")
    return out


def _names(allowed: tuple[str, ...]):
    def parse(text: str) -> list[str]:
        items = [t.strip() for t in text.split(",") if t.strip()]
        bad = [t for t in items if t not in allowed]
        if bad or not items:
            raise argparse.ArgumentTypeError(f"choose from {', '.join(allowed)}; got {text!r}")
        return items
    return parse


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("--bundle", type=Path, required=True, help="the bundle (.vtb) to measure")
    p.add_argument("--sizes", type=_sizes, default=None,
                   help="input sizes, multiples of 256 (default: the sizes the bundle declares); undeclared sizes "
                        "are marked * (int8 was not calibrated there)")
    p.add_argument("--precisions", type=_names(PRECISIONS), default=list(PRECISIONS),
                   help="fp32,fp16,int8 (default all); the bundle's own precision is its shipped graph, the others "
                        "are rebuilt from the source run")
    p.add_argument("--graphs", type=_names(("full", "tactile", "visual")), default=["full", "tactile"])
    p.add_argument("--providers", type=lambda t: [s.strip() for s in t.split(",") if s.strip()], default=None,
                   help="ONNX Runtime execution providers (default: every one present)")
    p.add_argument("--runs", type=int, default=20, help="timed runs per configuration (default 20)")
    p.add_argument("--warmup", type=int, default=3, help="untimed runs first (default 3)")
    p.add_argument("--threads", type=int, default=2, help="intra-op threads, ONNX Runtime and PyTorch (default 2)")
    p.add_argument("--wait", choices=("passive", "active"), default="passive",
                   help="what idle worker threads do, in ONNX Runtime (allow_spinning) and PyTorch "
                        "(OMP_WAIT_POLICY) alike: passive sleeps (default; robust on a shared CPU), active spins")
    p.add_argument("--error-sketches", type=int, default=4, help="held-out sketches per size for errors (default 4)")
    p.add_argument("--run", type=Path, default=None,
                   help="the training run the bundle was exported from (default: the manifest's source_run); "
                        "gives the fp32 reference, other precisions and PyTorch eager")
    p.add_argument("--reference", type=Path, default=None, help="an fp32 bundle of the same checkpoint, as reference")
    p.add_argument("--garment", type=Path, default=None,
                   help="synthetic garment folder with fullT/ for errors against ground truth (default: the run's)")
    p.add_argument("--engines", type=_names(ENGINES), default=None,
                   help="onnxruntime,openvino (default: every installed one)")
    p.add_argument("--truth", choices=("filled", "padded"), default="filled",
                   help="GT canvas: filled (default) re-synthesises the garment on a frame of each size, so it fills "
                        "the canvas at the model's pitch, as a large drawing does in the kiosk; padded places the "
                        "training garment on blank paper")
    p.add_argument("--no-planner", action="store_true",
                   help="skip the rows of the kiosk planner's own settings (preview / refine, physical scale)")
    p.add_argument("--no-torch", action="store_true", help="skip PyTorch eager")
    p.add_argument("--profile", action="store_true",
                   help="also profile the bundle's precision at the largest size (ONNX Runtime per-op-type time)")
    p.add_argument("--trusted-keys", type=Path, default=None,
                   help="check the bundle's signature against these keys (default: hashes only)")
    p.add_argument("--json", type=Path, default=None, help="write the results here")
    p.add_argument("--plot", type=Path, default=None, help="write the speed-vs-error-against-fp32 PNG here")
    p.add_argument("--pareto", type=Path, default=None,
                   help="write the Pareto plot here: latency against error against the ground truth")
    p.add_argument("--no-progress", action="store_true")
    return p


class _Progress:
    """tqdm on a terminal when it is installed; otherwise one line per step on stderr (logs stay readable)."""

    def __init__(self, total: int, enabled: bool):
        self._bar = None
        self._enabled = enabled
        if enabled and sys.stderr.isatty():
            try:
                from tqdm import tqdm
                self._bar = tqdm(total=total, file=sys.stderr, unit="cfg", dynamic_ncols=True)
            except ImportError:
                pass

    def step(self, what: str) -> None:
        if self._bar is not None:
            self._bar.set_description_str(what)
            self._bar.update(1)
        elif self._enabled:
            print(f"bench: {what}", file=sys.stderr, flush=True)

    def note(self, msg: str) -> None:
        if self._bar is not None:
            self._bar.write(msg, file=sys.stderr)
        elif self._enabled:
            print(msg, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


class _TorchSession:
    """PyTorch eager behind ONNX Runtime's `run(names, feed)`, so the same error code measures it."""

    def __init__(self, run_dir: Path, which: str, graph: str, threads: int):
        import torch
        from exporter.graphs import eager_module
        from trainer.checkpoint import load_generator
        torch.set_num_threads(threads)
        self._torch = torch
        self._module = eager_module(load_generator(run_dir, which)[0], graph)
        self._outputs = GRAPH_OUTPUTS[graph]

    def run(self, names, feed):
        with self._torch.inference_mode():
            out = self._module(*(self._torch.from_numpy(a) for a in unpack(feed)))
        out = dict(zip(self._outputs, out if isinstance(out, tuple) else (out,)))
        return [out[n].numpy() for n in names]


def _worker(spec: dict, folder: Path) -> dict:
    path = folder / f"spec-{len(list(folder.glob('spec-*.json')))}.json"
    path.write_text(json.dumps(spec))
    env = dict(os.environ, OMP_NUM_THREADS=str(spec["threads"]), OMP_WAIT_POLICY=spec["wait"].upper())
    proc = subprocess.run([sys.executable, "-m", "exporter.bench.worker", str(path)], capture_output=True,
                          text=True, env=env, timeout=3600)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise BenchError(f"measuring {spec.get('path') or 'PyTorch eager'} at {spec['size']} failed: "
                         + " | ".join(tail))
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _latency(res: dict) -> dict:
    t = np.asarray(res["times_ms"], np.float64)
    return {"p50_ms": float(np.percentile(t, 50)), "p95_ms": float(np.percentile(t, 95)), "mean_ms": float(t.mean()),
            "min_ms": float(t.min()), "runs": int(t.size), "load_ms": res["load_ms"],
            "base_rss_mb": res["base_rss_mb"], "peak_rss_mb": res["peak_rss_mb"], "times_ms": [round(x, 3) for x in t]}


def _environment() -> dict:
    import onnxruntime as ort
    versions = {"onnxruntime": ort.__version__}
    if torch_available():
        import torch
        versions["torch"] = torch.__version__
    return environment(**versions)


def _session(path: Path, provider: str, threads: int):
    import onnxruntime as ort
    from kiosk.bundle.probe import session_options
    providers = [provider] + (["CPUExecutionProvider"] if provider != "CPUExecutionProvider" else [])
    return ort.InferenceSession(str(path), session_options(threads), providers=providers)


def _fmt_size(size: tuple[int, int]) -> str:
    return f"{size[0]}x{size[1]}"


ENGINE_ORDER = {"torch": 0, "onnxruntime": 1, "openvino": 2}
PRECISION_ORDER = {"fp32": 0, "fp16": 1, "int8": 2}


def _form(path: Path) -> str:
    """`native` when the graph keeps its transposed convolutions, `rewritten` when the exporter made them
    Conv + DepthToSpace (what lets ONNX Runtime run the decoder int8, at twice the MACs)."""
    import onnx
    model = onnx.load(str(path), load_external_data=False)
    return "native" if any(n.op_type == "ConvTranspose" for n in model.graph.node) else "rewritten"


def _candidates(kind: str, src, engines: list[str], providers: list[str], torch_on: bool) -> list[Candidate]:
    """Every graph file of `kind` on every engine (ONNX Runtime on each provider), plus PyTorch eager."""
    files = [(p, path, source) for (k, p), (path, source) in src.graphs.items() if k == kind]
    if kind in src.native_int8:
        files.append(("int8", src.native_int8[kind], "run"))
    out = []
    for precision, path, source in files:
        form = _form(path)
        for eng in engines:
            for pr in (providers if eng == "onnxruntime" else ["CPU"]):
                out.append(Candidate(kind, precision, pr, source, path, engine=eng, form=form))
    if torch_on:
        out.append(Candidate(kind, "fp32", "torch-eager", "torch", None, engine="torch", form="native"))
    return sorted(out, key=lambda c: (ENGINE_ORDER[c.engine], PRECISION_ORDER[c.precision], c.form != "native"))


def _planned_candidates(cands: list[Candidate], shipped: str) -> list[Candidate]:
    """At the planner's settings: what the kiosk would run (the bundle's own graphs, on every engine), the fp32
    graph in ONNX Runtime as the reference, and PyTorch eager for the ratio."""
    return [c for c in cands if c.source == "bundle" or c.engine == "torch"
            or (c.precision == "fp32" and c.engine == "onnxruntime" and shipped != "fp32")]


def _test_runner(c: Candidate, threads: int, src, ref_sess):
    """Something with ORT's `run(names, feed)` for the error columns (same engine and graph as the timing)."""
    if c.path is None:
        return _TorchSession(src.run_dir, src.which, c.graph, threads)
    if c.engine == "openvino":
        from kiosk.inference.backends import open_graph
        return open_graph("openvino", c.path, threads=threads)
    if ref_sess is not None and Path(c.path) == Path(src.reference[c.graph]) and c.provider == "CPUExecutionProvider":
        return ref_sess  # the reference itself: its error is exactly zero by definition
    return _session(c.path, c.provider, threads)


def _flat_row(kind: str, size: str, setting: str, errors: dict) -> dict:
    """The trivial answer (a flat garment: zero slopes) as a reference row of the GT columns."""
    return {"graph": kind, "size": size, "setting": setting, "precision": "-", "provider": "-", "engine": "flat",
            "form": "-", "source": "reference", "declared": True, "reference_row": "trivial: flat (zero slopes)",
            **errors}


def run_bench(args: argparse.Namespace, argv: list[str], prog: str) -> dict:
    import onnxruntime as ort

    from exporter.accuracy import compare_outputs, reference_outputs
    from exporter.bench.macs import graph_macs
    from exporter.calibration import held_out_set
    from kiosk.bundle.archive import open_bundle
    from kiosk.contract.sketch import letterbox, network_input, object_mask
    from kiosk.inference.backends import available

    progress_on = not args.no_progress
    env = _environment()
    installed = available()
    engines = args.engines or list(installed)
    missing = [e for e in engines if e not in installed]
    if missing:
        raise BenchError(f"engine(s) {', '.join(missing)} not installed (installed: {', '.join(installed)}; "
                         "OpenVINO: pip install 'vtkiosk[openvino]')")
    if "openvino" in installed:
        import openvino
        env["openvino"] = openvino.__version__
    with tempfile.TemporaryDirectory(prefix="vtkiosk-bench-") as tmp_s:
        tmp = Path(tmp_s)
        bundle, trusted = open_measured(args.bundle, args.trusted_keys, tmp / "bundle")
        m = bundle.manifest
        graphs = [g for g in args.graphs if g in m.graphs]
        if not graphs:
            raise BenchError(f"the bundle has none of the graphs {', '.join(args.graphs)} (it has "
                             f"{', '.join(m.graphs)})")
        reference = None
        if args.reference is not None:
            reference = open_bundle(args.reference, trusted, workdir=tmp / "reference",
                                    allow_unsigned=trusted is None)
        present = [p for p in ort.get_available_providers() if p not in NOT_COMPUTE]
        providers = args.providers or present
        absent = [p for p in providers if p not in present]
        if absent:
            raise BenchError(f"execution provider(s) {', '.join(absent)} not present (present: {', '.join(present)})")
        say = (lambda msg: print(msg, file=sys.stderr, flush=True)) if progress_on else (lambda msg: None)
        src = build_sources(bundle, graphs, list(args.precisions), tmp, run=args.run, reference=reference,
                            progress=say)
        torch_on = not args.no_torch and src.run_dir is not None
        if not args.no_torch and src.run_dir is None:
            src.notes.append("PyTorch eager not measured (needs torch and the source run)")
        declared = {k: {tuple(s) for s in m.graph(k).sizes} for k in graphs}
        sizes = args.sizes or sorted({s for k in graphs for s in declared[k]}, key=lambda s: s[0] * s[1])
        garment_dir = args.garment
        if garment_dir is None and src.run_dir is not None:
            from trainer.config import read_run_config
            if (src.run_dir / "config.yaml").is_file():
                garment_dir = Path(read_run_config(src.run_dir).garment or ".")
        truth_on = garment_dir is not None and (Path(garment_dir) / "fullT").is_dir() and torch_available()
        if not truth_on:
            src.notes.append("no full-field ground truth (needs a synthetic garment folder with fullT/ and the "
                             "trainer)")
        cands = {k: _candidates(k, src, engines, providers, torch_on) for k in graphs}
        planned = []
        if not args.no_planner:
            from exporter.bench.planned import planned_inputs
            try:
                planned = planned_inputs(bundle)
            except KioskError as exc:
                src.notes.append(f"no planner rows: {exc}")
            for pl in planned:
                if pl.graph not in cands and pl.graph in m.graphs:
                    cands[pl.graph] = _candidates(pl.graph, src, engines, providers, torch_on)
        total = sum(len(cands[k]) for k in graphs) * len(sizes) + (len(graphs) if args.profile else 0) + sum(
            len(_planned_candidates(cands[pl.graph], m.graph(pl.graph).precision)) for pl in planned
            if pl.graph in cands)
        bar = _Progress(total, progress_on)
        for note in src.notes:
            bar.note(f"bench: note: {note}")
        sketch = bundle.asset("sketch")
        rows: list[dict] = []
        macs: dict[tuple[str, tuple[int, int]], int | None] = {}

        def gmac(path: Path | None, kind: str, size: tuple[int, int]) -> float | None:
            path = Path(path) if path is not None else Path(src.reference[kind]) if kind in src.reference else None
            if path is None:
                return None
            key = (str(path), size)
            if key not in macs:
                shape = (1, 1, size[1], size[0])
                macs[key] = graph_macs(path, {"sketch": shape, "mask": shape})
            return None if macs[key] is None else macs[key] / 1e9

        def measure(c: Candidate, kind: str, size: tuple[int, int], feed_path: Path, base: dict,
                    ref_sess, ref_out, held_out, field) -> dict:
            bar.step(f"{kind} {base.get('setting') or _fmt_size(size)} {c.precision} {c.form} {c.engine}")
            spec = {"kind": {"torch": "torch", "openvino": "openvino"}.get(c.engine, "onnx"), "graph": kind,
                    "size": list(size), "runs": args.runs, "warmup": args.warmup, "threads": args.threads,
                    "wait": args.wait, "input": str(feed_path), "provider": c.provider,
                    "outputs": GRAPH_OUTPUTS[kind], "path": str(c.path) if c.path else None,
                    "run": str(src.run_dir) if src.run_dir else None, "which": src.which}
            row = {**base, "precision": c.precision, "provider": c.provider, "engine": c.engine, "form": c.form,
                   "source": c.source, "gmac": gmac(c.path, kind, size),
                   "graph_bytes": graph_bytes(c.path) if c.path else None, **_latency(_worker(spec, tmp))}
            test = _test_runner(c, args.threads, src, ref_sess)
            if ref_out is not None:
                row.update(compare_outputs(ref_out, test, GRAPH_OUTPUTS[kind], held_out, m.friction_scale,
                                           normalization=m.friction_normalization,
                                           constants=m.friction_constants or None))
            if field is not None and "tactile" in GRAPH_OUTPUTS[kind]:
                row.update(field(test))
            return row

        try:
            for size in sizes:
                truth = None
                if truth_on:
                    from exporter.bench.truth import filled_truth, garment_truth
                    truth = filled_truth(garment_dir, size, tmp / "filled") if args.truth == "filled" \
                        else garment_truth(garment_dir, size)
                    if truth is None:
                        src.notes.append(f"no ground truth at {_fmt_size(size)} (the garment does not fit)")
                if truth is not None:
                    x = truth.input  # the garment filling the canvas, as timed
                else:
                    fitted, _ = letterbox(sketch, size)
                    x = network_input(fitted, object_mask(fitted))
                feed_path = tmp / f"input-{_fmt_size(size)}.npz"
                np.savez(feed_path, sketch=x.sketch, mask=x.mask)
                held_out = held_out_set(sketch, [size], args.error_sketches)
                field = None
                if truth is not None:
                    from exporter.bench.truth import field_errors

                    def field(test, truth=truth):
                        tac = test.run(["tactile"], feeds(truth.input.sketch, truth.input.mask))[0]
                        return field_errors(tac, truth, m.friction_scale)
                for kind in graphs:
                    outputs = GRAPH_OUTPUTS[kind]
                    ref_sess = _session(src.reference[kind], "CPUExecutionProvider", args.threads) \
                        if kind in src.reference else None
                    ref_out = reference_outputs(ref_sess, outputs, held_out) if ref_sess is not None else None
                    base = {"graph": kind, "size": _fmt_size(size), "width": size[0], "height": size[1],
                            "setting": f"{_fmt_size(size)} canvas", "declared": tuple(size) in declared[kind]}
                    if truth is not None and "tactile" in outputs:
                        from exporter.bench.truth import field_errors
                        flat = np.zeros((1, 2, size[1], size[0]), np.float32)
                        rows.append(_flat_row(kind, _fmt_size(size), base["setting"],
                                              field_errors(flat, truth, m.friction_scale)))
                    for c in cands[kind]:
                        rows.append(measure(c, kind, size, feed_path, base, ref_sess, ref_out, held_out, field))
            if planned:
                from exporter.bench.planned import asset_truth, to_asset_frame
                from trainer.metrics import full_field_metrics
                at = asset_truth(garment_dir) if truth_on else None
                for i, pl in enumerate(planned):
                    kind = pl.graph
                    if kind not in cands:
                        continue
                    feed_path = tmp / f"planned-{i}.npz"
                    np.savez(feed_path, sketch=pl.input.sketch, mask=pl.input.mask)
                    ref_sess = _session(src.reference[kind], "CPUExecutionProvider", args.threads) \
                        if kind in src.reference else None
                    ref_out = reference_outputs(ref_sess, GRAPH_OUTPUTS[kind], [pl.input]) \
                        if ref_sess is not None else None
                    base = {"graph": kind, "size": _fmt_size(pl.grid), "width": pl.grid[0], "height": pl.grid[1],
                            "setting": pl.setting, "felt_ratio": pl.felt_ratio,
                            "declared": tuple(pl.grid) in {tuple(s) for s in m.graph(kind).sizes}}
                    field = None
                    if at is not None:
                        gx, gy, mask = at

                        def field(test, pl=pl):
                            tac = test.run(["tactile"], feeds(pl.input.sketch, pl.input.mask))[0]
                            back = to_asset_frame(tac[0], pl, gx.shape)
                            return full_field_metrics(back[0], back[1], gx, gy, mask, m.friction_scale)
                        rows.append(_flat_row(kind, base["size"], pl.setting, full_field_metrics(
                            np.zeros_like(gx), np.zeros_like(gy), gx, gy, mask, m.friction_scale)))
                    for c in _planned_candidates(cands[kind], m.graph(kind).precision):
                        rows.append(measure(c, kind, pl.grid, feed_path, base, ref_sess, ref_out, [pl.input],
                                            field))
            for r in rows:
                eager = [t for t in rows if t["engine"] == "torch" and t["graph"] == r["graph"]
                         and t["setting"] == r["setting"]]
                r["speedup_vs_torch"] = (eager[0]["p50_ms"] / r["p50_ms"]) \
                    if eager and r["engine"] not in ("torch", "flat") else None
            profiles = []
            if args.profile:
                size = max(sizes, key=lambda s: s[0] * s[1])
                for kind in graphs:
                    precision = m.graph(kind).precision
                    bar.step(f"profile {kind} {_fmt_size(size)} {precision}")
                    folder = tmp / f"profile-{kind}"
                    folder.mkdir()
                    spec = {"kind": "onnx", "graph": kind, "size": list(size), "runs": max(3, args.runs // 4),
                            "warmup": 1, "threads": args.threads, "wait": args.wait,
                            "provider": "CPUExecutionProvider",
                            "input": str(tmp / f"input-{_fmt_size(size)}.npz"), "path": str(bundle.graph_path(kind)),
                            "profile": str(folder)}
                    prof = _worker(spec, tmp)["profile"]
                    profiles.append({"graph": kind, "size": _fmt_size(size), "precision": precision, **prof})
            layout = bundle_layout(bundle)
        finally:
            bar.close()
    env["loadavg_end"] = list(os.getloadavg())
    default = {k: m.graph(k).precision for k in graphs}
    return {
        "schema": "vtkiosk-bench-infer/2",
        "command": " ".join([prog] + [shlex.quote(a) for a in argv]),
        "created_at": dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z"),
        "bundle": {"file": portable(args.bundle), "garment_id": m.garment_id, "model_version": m.model_version,
                   "checkpoint_sha256": m.checkpoint_sha256, "precision": default,
                   "bytes": Path(args.bundle).stat().st_size, **layout,
                   "declared_sizes": {k: [_fmt_size(tuple(s)) for s in m.graph(k).sizes] for k in graphs},
                   "manifest_errors": m.errors, "provenance": m.provenance, "signature_checked": trusted is not None},
        "reference": src.reference_from or None,
        "settings": {"runs": args.runs, "warmup": args.warmup, "threads": args.threads, "wait": args.wait,
                     "sizes": [_fmt_size(s) for s in sizes], "precisions": list(args.precisions), "graphs": graphs,
                     "engines": engines, "providers": providers, "error_sketches": args.error_sketches,
                     "ground_truth": str(garment_dir) if truth_on else None, "truth_canvas": args.truth,
                     "planner": not args.no_planner},
        "environment": env,
        "notes": src.notes,
        "rows": rows,
        "goals": goals(rows, default),
        "profiles": profiles,
    }


def main(argv: list[str], prog: str = "vtkiosk bench infer") -> int:
    args = build_parser(prog).parse_args(argv)
    if args.runs < 1 or args.warmup < 0 or args.threads < 1 or args.error_sketches < 1:
        raise BenchError("--runs, --threads and --error-sketches must be at least 1, --warmup at least 0")
    result = run_bench(args, argv, prog)
    print(markdown_table(result["rows"]))
    precisions = ", ".join(sorted(set(result["bundle"]["precision"].values())))
    print("\n" + "\n".join([f"goals at the bundle's precision ({precisions}):"] + goal_lines(result["goals"])))
    for prof in result["profiles"]:
        print("\n".join(profile_lines(prof)))
    b = result["bundle"]
    print(bundle_line(b))
    for note in result["notes"]:
        print(f"note: {note}")
    load = result["environment"]
    print(f"{args.threads} threads, {args.wait} wait; load average at start {load['loadavg_start'][0]:.2f}, at end "
          f"{load['loadavg_end'][0]:.2f} ({load['logical_cpus']} logical CPUs)")
    write_result(args.json, result)
    if args.plot is not None:
        from exporter.bench.plot import plot
        m, cpu = result["bundle"], result["environment"]["cpu"]
        plot(result["rows"], args.plot, title=f"{m['garment_id']} {m['model_version']}: speed against error "
                                              f"({cpu}, {args.threads} threads, {args.wait} wait)")
        print(f"wrote {args.plot}")
    if args.pareto is not None:
        from exporter.bench.plot import plot_pareto
        m, cpu = result["bundle"], result["environment"]["cpu"]
        plot_pareto(result["rows"], args.pareto, title=f"{m['garment_id']} {m['model_version']}: latency against "
                                                        f"error vs ground truth ({cpu}, {args.threads} threads)")
        print(f"wrote {args.pareto}")
    return 0
