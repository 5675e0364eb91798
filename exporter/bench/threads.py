"""`vtkiosk bench threads --bundle FILE`: which session settings and which preview/refine thread split to run.

Two measurements, both on the graphs and grid sizes the kiosk's planner picks for the bundle on the default panel
(a preview while drawing: the visual graph at the preview resolution; a refinement: the full graph at full
resolution):

1. Sweep: each engine's session settings that matter on a small CPU (ONNX Runtime: intra-op threads 1/2, CPU memory
   arena, memory-pattern planning, sequential/parallel execution, spinning; OpenVINO: inference threads, streams,
   performance hint), each configuration in a fresh process (`exporter/bench/worker.py`) for honest peak RSS: p50,
   p95, a bootstrap 95 % interval of the p50, peak RSS, and the error column (the bundle's stated error against fp32
   of the same graph, beside the measured largest output difference to a 1-thread ONNX Runtime run of the same
   graph: zero or float-reduction noise for a setting that only changes scheduling). Reference rows: the engine
   library's own defaults (untuned) and the oracle of perfect 2-thread scaling (1-thread p50 / 2).
2. Lanes: preview frames/s and latency while refinements run back to back, per thread split, in the kiosk itself
   (`kiosk/bench/lanes.py`: `vtkiosk serve` driven over loopback HTTP): one loop for everything (previews wait for
   a running refinement), or a preview lane beside the refinement with its own threads. Reference rows: previews
   alone (the oracle for the preview) and refinements alone.

Each configuration and split is measured in `--rounds` fresh processes, the order reversed every other round, so
a load that drifts over minutes (two training runs share this project's machine) does not favour whichever ran
first. Prints both tables, writes JSON and a PNG. The measuring processes import no torch (the parent reads its
version for the environment record, as `bench infer` does, when it is installed).
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

from exporter.bench.result_file import write_result
from exporter.bench.sources import BenchError, portable
from kiosk.inference.sessions import SessionSettings

ENGINES = ("onnxruntime", "openvino")
SCHEDULING_NOISE = 1e-4  # largest output difference that float reduction order across threads can explain


def ort_settings(full: bool = True) -> list[tuple[str, SessionSettings]]:
    """One factor at a time around the kiosk's defaults, at 1 and 2 threads (`full` False: the defaults only);
    ONNX Runtime's own defaults (spinning threads) as the untuned reference."""
    out = [("reference: ONNX Runtime defaults (2 threads, spinning)", SessionSettings(threads=2, spinning=True))]
    for t in (1, 2):
        out.append(("", SessionSettings(threads=t)))
        if full:
            out += [("", SessionSettings(threads=t, mem_arena=False)),
                    ("", SessionSettings(threads=t, mem_pattern=False)),
                    ("", SessionSettings(threads=t, execution_mode="parallel"))]
    return out


def openvino_settings(full: bool = True) -> list[tuple[str, SessionSettings]]:
    out = [("", SessionSettings(threads=1, hint="latency")), ("", SessionSettings(threads=2, hint="latency"))]
    if full:
        out += [("", SessionSettings(threads=2, hint="throughput")),
                ("", SessionSettings(threads=2, streams=2, hint="throughput"))]
    return out


SPLITS = {  # id: (label, main threads, preview threads, refinements: True beside previews, None alone, False none)
    "previews-alone": ("reference: previews alone (2 threads)", 2, 0, False),
    "refines-alone": ("reference: refinements alone (2 threads)", 2, 0, None),
    "one-loop": ("one loop, 2 threads (previews wait for the refinement)", 2, 0, True),
    "2+2": ("lanes: refine 2 + preview 2", 2, 2, True),
    "2+1": ("lanes: refine 2 + preview 1", 2, 1, True),
    "1+1": ("lanes: refine 1 + preview 1", 1, 1, True),
}


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("--bundle", type=Path, required=True, help="the bundle (.vtb) to measure")
    p.add_argument("--trusted-keys", type=Path, default=None,
                   help="check the bundle's signature against these keys (default: hashes only)")
    p.add_argument("--engines", default=None, help="onnxruntime,openvino (default: every installed one)")
    p.add_argument("--runs", type=int, default=5, help="timed runs per sweep process (default 5)")
    p.add_argument("--warmup", type=int, default=1, help="untimed runs first, per process (default 1)")
    p.add_argument("--rounds", type=int, default=2,
                   help="fresh processes per sweep configuration and per thread split, in alternating order "
                        "(default 2)")
    p.add_argument("--seconds", type=float, default=4.0,
                   help="measuring window per thread split and round (default 4 s)")
    p.add_argument("--lanes-engine", choices=ENGINES, default="onnxruntime",
                   help="the engine the lanes measurement serves with (default onnxruntime)")
    p.add_argument("--sweep", choices=("full", "threads", "none"), default="full",
                   help="session settings to sweep: full (default), threads (the defaults at 1 and 2 threads and "
                        "the untuned reference only), none")
    p.add_argument("--splits", default=",".join(SPLITS),
                   help=f"thread splits for the lanes measurement, comma-separated from {', '.join(SPLITS)} "
                        "(default all); 'none' skips it")
    p.add_argument("--json", type=Path, default=None, help="write the results here")
    p.add_argument("--plot", type=Path, default=None, help="write the PNG here")
    p.add_argument("--no-progress", action="store_true")
    return p


def planned_work(bundle) -> dict[str, tuple[str, tuple[int, int], object]]:
    """{"preview": (graph, grid, NetworkInput), "refine": ...}: the kiosk planner's choices, at the kiosk config's
    default resolutions and physical scale, for the bundle's reference sketch filling the default panel."""
    from kiosk.contract.panels import DEFAULT_PANEL, KNOWN_PANELS
    from kiosk.inference.engine import LoadedBundle
    from kiosk.inference.scene import Panel, Planner, Scene, SketchInput

    p = KNOWN_PANELS[DEFAULT_PANEL]
    loaded = LoadedBundle(bundle)
    scene = Scene((Panel("main", (0, 0, p.width_px, p.height_px), loaded.key, sketch="reference"),),
                  (p.width_px, p.height_px))
    planner = Planner(panel_pitch_mm=p.pitch_mm)  # the planner's defaults are the kiosk config's
    out = {}
    for what, preview in (("preview", True), ("refine", False)):
        pp = planner.plan(scene, {"main": SketchInput(base=True)}, {loaded.key: loaded}, preview=preview).panels[0]
        if pp.inputs is None or pp.grid is None:
            raise BenchError(f"the planner computes nothing for the bundle's reference sketch ({pp.reason})")
        out[what] = (pp.graph, pp.grid, pp.inputs)
    return out


def p50_interval(times: list[float], *, resamples: int = 1000, seed: int = 0) -> tuple[float, float]:
    """Bootstrap 95 % interval of the median."""
    t = np.asarray(times, np.float64)
    rng = np.random.default_rng(seed)
    meds = np.median(t[rng.integers(0, t.size, (resamples, t.size))], axis=1)
    return float(np.percentile(meds, 2.5)), float(np.percentile(meds, 97.5))


def stated_error(manifest, graph: str) -> dict:
    """The bundle's own error against fp32 for this graph (what the exporter measured), or exactly 0 for fp32."""
    precision = manifest.graph(graph).precision
    if precision == "fp32":
        return {"precision": precision, "stated_friction_mae_levels": 0.0, "stated_visual_psnr_db": None}
    errs = manifest.errors.get(precision, {})
    return {"precision": precision, "stated_friction_mae_levels": errs.get(f"{graph}_friction_mae_levels"),
            "stated_visual_psnr_db": errs.get(f"{graph}_visual_psnr_db")}


def _run(module: str, spec: dict, folder: Path, what: str) -> dict:
    path = folder / f"spec-{len(list(folder.glob('spec-*.json')))}.json"
    path.write_text(json.dumps(spec))
    env = {k: v for k, v in os.environ.items() if k != "NOTIFY_SOCKET"}
    proc = subprocess.run([sys.executable, "-m", module, str(path)], capture_output=True, text=True, env=env,
                          timeout=900)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise BenchError(f"measuring {what} failed: " + " | ".join(tail))
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _stats(times: list[float]) -> dict:
    t = np.asarray(times, np.float64)
    if t.size == 0:
        return {"p50_ms": None, "p95_ms": None, "p50_ci_ms": None, "n": 0}
    return {"p50_ms": float(np.percentile(t, 50)), "p95_ms": float(np.percentile(t, 95)),
            "p50_ci_ms": list(p50_interval(times)), "n": int(t.size)}


def sweep(bundle, work: dict, engines: list[str], args, tmp: Path, step) -> list[dict]:
    """Every configuration in `args.rounds` fresh processes, the order reversed every other round, times pooled:
    a machine whose load drifts over minutes then tilts no configuration more than another."""
    from kiosk.contract.graph import GRAPH_OUTPUTS

    m = bundle.manifest
    rows: list[dict] = []
    full = args.sweep == "full"
    for what, (graph, grid, x) in work.items():
        feed = tmp / f"{what}.npz"
        np.savez(feed, sketch=x.sketch, mask=x.mask)
        configs = [("onnxruntime", label, s) for label, s in ort_settings(full)] if "onnxruntime" in engines else []
        configs += [("openvino", label, s) for label, s in openvino_settings(full)] if "openvino" in engines else []
        times: list[list[float]] = [[] for _ in configs]
        peak = [0.0] * len(configs)
        base = [0.0] * len(configs)
        outs: list[list[np.ndarray] | None] = [None] * len(configs)
        for rnd in range(args.rounds):
            order = list(range(len(configs)))[::-1 if rnd % 2 else 1]
            for i in order:
                engine, _, s = configs[i]
                step(f"{what} {graph} {grid[0]}x{grid[1]} {engine} {s.label(engine)} (round {rnd + 1})")
                dump = tmp / f"out-{what}-{i}.npz"
                spec = {"kind": "openvino" if engine == "openvino" else "onnx", "graph": graph,
                        "size": list(grid), "runs": args.runs, "warmup": args.warmup, "threads": s.threads,
                        "wait": "active" if s.spinning else "passive", "input": str(feed),
                        "path": str(bundle.graph_path(graph)), "outputs": GRAPH_OUTPUTS[graph],
                        "provider": "CPUExecutionProvider", "session": s.to_json(), "dump": str(dump)}
                res = _run("exporter.bench.worker", spec, tmp, f"{graph} {engine} {s.label(engine)}")
                times[i] += res["times_ms"]
                peak[i], base[i] = max(peak[i], res["peak_rss_mb"]), res["base_rss_mb"]
                if outs[i] is None:
                    with np.load(dump) as z:
                        outs[i] = [z[k] for k in sorted(z.files, key=lambda n: int(n.split("_")[1]))]
        # each engine's 1-thread run with the kiosk's other defaults is the reference of its difference column
        refs = {e: outs[i] for i, (e, _, s) in enumerate(configs) if s == SessionSettings(threads=1)}
        err = stated_error(m, graph)
        first = len(rows)
        for i, (engine, label, s) in enumerate(configs):
            diff = max(float(np.max(np.abs(a - b))) for a, b in zip(outs[i], refs[engine])) \
                if engine in refs else None
            ort_diff = max(float(np.max(np.abs(a - b))) for a, b in zip(outs[i], refs["onnxruntime"])) \
                if "onnxruntime" in refs else None
            rows.append({"work": what, "graph": graph, "grid": f"{grid[0]}x{grid[1]}", "engine": engine,
                         "setting": s.label(engine), "reference_row": label or None, "session": s.to_json(),
                         **_stats(times[i]), "times_ms": [round(v, 3) for v in times[i]],
                         "peak_rss_mb": peak[i], "base_rss_mb": base[i], **err, "max_abs_diff_vs_ref_run": diff,
                         "max_abs_diff_vs_ort": ort_diff,
                         "scheduling_only": None if diff is None else diff <= SCHEDULING_NOISE})
        for engine in engines:
            mine = [r for r in rows[first:] if r["engine"] == engine and r["reference_row"] is None]
            default = next((r for r in mine if r["session"] == SessionSettings(threads=2).to_json()), None)
            for r in mine + [r for r in rows[first:] if r["engine"] == engine and r["reference_row"]]:
                r["x_default"] = r["p50_ms"] / default["p50_ms"] if default else None
            one = next((r for r in mine if r["session"] == SessionSettings(threads=1).to_json()), None)
            if one:
                rows.append({"work": what, "graph": graph, "grid": one["grid"], "engine": engine,
                             "setting": "oracle",
                             "reference_row": "oracle: perfect 2-thread scaling (1-thread p50 / 2)",
                             "p50_ms": one["p50_ms"] / 2, "p95_ms": None, "p50_ci_ms": None, "n": 0,
                             "peak_rss_mb": None, **err, "max_abs_diff_vs_ref_run": None,
                             "max_abs_diff_vs_ort": None, "scheduling_only": None,
                             "x_default": one["p50_ms"] / 2 / default["p50_ms"] if default else None})
    return rows


def lanes(args, engine: str, splits: list[str], tmp: Path, step) -> list[dict]:
    """Every split in `args.rounds` fresh daemons, the order reversed every other round, counts pooled."""
    got: dict[str, dict] = {k: {"previews": [], "refines": [], "window_s": 0.0, "peak_rss_mb": 0.0}
                            for k in splits}
    for rnd in range(args.rounds):
        for split in splits[::-1 if rnd % 2 else 1]:
            label, main_t, preview_t, refine = SPLITS[split]
            step(f"lanes {engine}: {label} (round {rnd + 1})")
            spec = {"bundle": str(args.bundle.resolve()), "engine": engine, "threads": main_t,
                    "preview_threads": preview_t, "seconds": args.seconds, "refine": refine is not False,
                    "previews": refine is not None,
                    "trusted_keys": str(args.trusted_keys.resolve()) if args.trusted_keys else None}
            res = _run("kiosk.bench.lanes", spec, tmp, f"lanes {label}")
            g = got[split]
            g["previews"] += res["previews"]
            g["refines"] += res["refines"]
            g["window_s"] += res["window_s"]
            g["peak_rss_mb"] = max(g["peak_rss_mb"], res["peak_rss_mb"])
            g["engine"] = res["engine"]
    rows = []
    for split in splits:
        label, main_t, preview_t, refine = SPLITS[split]
        g = got[split]
        pv, rf, window = g["previews"], g["refines"], g["window_s"]
        rows.append({"split": label, "id": split, "engine": g["engine"], "main_threads": main_t,
                     "preview_threads": preview_t, "refining": refine is not False, "previewing": refine is not None,
                     "window_s": window, "preview_fps": len(pv) / window if refine is not None else None,
                     "refines_per_s": len(rf) / window if refine is not False else None,
                     "preview": _stats([e["ms"] for e in pv]), "refine": _stats([e["ms"] for e in rf]),
                     "preview_grid": pv[0]["grid"] if pv else None, "refine_grid": rf[0]["grid"] if rf else None,
                     "peak_rss_mb": g["peak_rss_mb"],
                     "reference_row": label if label.startswith("reference") else None})
    return rows


def _cell(v, fmt: str) -> str:
    return "-" if v is None else fmt.format(v)


def sweep_table(rows: list[dict]) -> str:
    head = ("| work | graph | grid | engine | setting | p50 ms | p50 95% CI | p95 ms | x default | peak RSS MiB | "
            "error vs fp32 (bundle's stated) | max abs diff vs the engine's 1-thread run | vs ORT 1-thread |")
    lines = [head, "|---|---|---|---|---|---:|---:|---:|---:|---:|---:|---|---:|"]
    for r in rows:
        ci = r.get("p50_ci_ms")
        if r["max_abs_diff_vs_ref_run"] is None:
            diff = "-"
        elif r["max_abs_diff_vs_ref_run"] == 0.0:
            diff = "0 (scheduling only)"
        elif r["scheduling_only"]:
            diff = f"{r['max_abs_diff_vs_ref_run']:.1e} (float order: scheduling only)"
        else:
            diff = f"{r['max_abs_diff_vs_ref_run']:.1e} (different kernels)"
        stated, psnr = r.get("stated_friction_mae_levels"), r.get("stated_visual_psnr_db")
        if r["precision"] == "fp32":
            stated_s = "0 (fp32 graph)"
        elif stated is not None:
            stated_s = f"friction MAE {stated:.2f} levels ({r['precision']})"
        elif psnr is not None:
            stated_s = f"PSNR {psnr:.1f} dB ({r['precision']})"
        else:
            stated_s = f"not stated ({r['precision']})"
        name = r["reference_row"] or r["setting"]
        lines.append(f"| {r['work']} | {r['graph']} | {r['grid']} | {r['engine']} | {name} | "
                     f"{_cell(r['p50_ms'], '{:.1f}')} | "
                     f"{'-' if not ci else f'{ci[0]:.1f}-{ci[1]:.1f}'} | {_cell(r['p95_ms'], '{:.1f}')} | "
                     f"{_cell(r.get('x_default'), '{:.2f}')} | "
                     f"{_cell(r['peak_rss_mb'], '{:.0f}')} | {stated_s} | {diff} | "
                     f"{_cell(r.get('max_abs_diff_vs_ort'), '{:.1e}')} |")
    return "\n".join(lines)


def lanes_table(rows: list[dict]) -> str:
    lines = ["| split | preview fps | preview p50 ms | p50 95% CI | preview p95 ms | refines/s | refine p50 ms | "
             "refine p95 ms | peak RSS MiB |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        pv, rf = r["preview"], r["refine"]
        ci = pv.get("p50_ci_ms")
        lines.append(f"| {r['split']} | {_cell(r['preview_fps'], '{:.2f}')} | {_cell(pv['p50_ms'], '{:.0f}')} | "
                     f"{'-' if not ci else f'{ci[0]:.0f}-{ci[1]:.0f}'} | {_cell(pv['p95_ms'], '{:.0f}')} | "
                     f"{_cell(r['refines_per_s'], '{:.2f}')} | {_cell(rf['p50_ms'], '{:.0f}')} | "
                     f"{_cell(rf['p95_ms'], '{:.0f}')} | {_cell(r['peak_rss_mb'], '{:.0f}')} |")
    return "\n".join(lines)


def ratios(rows: list[dict]) -> list[str]:
    """Within-run ratios against the one-loop split (the kiosk without a preview lane), which load cannot fake."""
    base = next((r for r in rows if r["split"].startswith("one loop")), None)
    alone = next((r for r in rows if r["split"].startswith("reference: previews alone")), None)
    out = []
    for r in rows:
        if r["reference_row"] or base is None or r is base or not r["preview_fps"] or not base["preview_fps"]:
            continue
        line = f"{r['split']}: preview fps x{r['preview_fps'] / base['preview_fps']:.2f} the one loop's"
        if alone and alone["preview_fps"]:
            line += f" ({r['preview_fps'] / alone['preview_fps']:.0%} of previews alone)"
        if r["refines_per_s"] and base["refines_per_s"]:
            line += f", refinements/s x{r['refines_per_s'] / base['refines_per_s']:.2f}"
        out.append(line)
    return out


def run_bench(args, argv: list[str], prog: str) -> dict:
    from exporter.bench.infer import _environment
    from exporter.bench.sources import open_measured
    from kiosk.inference.backends import available

    installed = available()
    engines = [e.strip() for e in args.engines.split(",") if e.strip()] if args.engines else list(installed)
    bad = [e for e in engines if e not in ENGINES]
    if bad or not engines:
        raise BenchError(f"--engines: choose from {', '.join(ENGINES)}; got {args.engines!r}")
    splits = [] if args.splits.strip() == "none" else [t.strip() for t in args.splits.split(",") if t.strip()]
    unknown = [t for t in splits if t not in SPLITS]
    if unknown or (not splits and args.splits.strip() != "none"):
        raise BenchError(f"--splits: choose from {', '.join(SPLITS)} or none; got {args.splits!r}")
    missing = [e for e in engines + ([args.lanes_engine] if splits else []) if e not in installed]
    if missing:
        raise BenchError(f"engine(s) {', '.join(sorted(set(missing)))} not installed (installed: "
                         f"{', '.join(installed)}; OpenVINO: pip install 'vtkiosk[openvino]')")
    env = _environment()
    if "openvino" in installed:
        import openvino
        env["openvino"] = openvino.__version__
    say = (lambda msg: print(f"bench: {msg}", file=sys.stderr, flush=True)) if not args.no_progress \
        else (lambda msg: None)
    with tempfile.TemporaryDirectory(prefix="vtkiosk-threads-") as tmp_s:
        tmp = Path(tmp_s)
        bundle, _ = open_measured(args.bundle, args.trusted_keys, tmp / "bundle")
        work = planned_work(bundle)
        sweep_rows = [] if args.sweep == "none" else sweep(bundle, work, engines, args, tmp, say)
        lane_rows = lanes(args, args.lanes_engine, splits, tmp, say)
        m = bundle.manifest
    env["loadavg_end"] = list(os.getloadavg())
    return {
        "schema": "vtkiosk-bench-threads/1",
        "command": " ".join([prog] + [shlex.quote(a) for a in argv]),
        "created_at": dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", "Z"),
        "bundle": {"file": portable(args.bundle), "garment_id": m.garment_id, "model_version": m.model_version,
                   "precision": {k: g.precision for k, g in m.graphs.items()}},
        "work": {k: {"graph": g, "grid": list(grid)} for k, (g, grid, _) in work.items()},
        "settings": {"runs": args.runs, "warmup": args.warmup, "rounds": args.rounds, "seconds": args.seconds,
                     "engines": engines,
                     "sweep": args.sweep, "splits": splits, "lanes_engine": args.lanes_engine if splits else None},
        "environment": env,
        "sweep": sweep_rows,
        "lanes": lane_rows,
        "lane_ratios": ratios(lane_rows),
    }


def plot(result: dict, out: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweep_rows = [r for r in result["sweep"] if r["p95_ms"] is not None]
    lane_rows = result["lanes"]
    fig, axes = plt.subplots(1, 2, figsize=(15, max(4.0, 0.28 * len(sweep_rows) + 1.5)),
                             gridspec_kw={"width_ratios": [3, 2]})
    ax = axes[0]
    short = {"onnxruntime": "ORT", "openvino": "OV"}
    labels = [f"{r['work']} {r['grid']} {short[r['engine']]} {r['setting']}" for r in sweep_rows]
    y = np.arange(len(sweep_rows))
    colours = ["tab:blue" if r["engine"] == "onnxruntime" else "tab:orange" for r in sweep_rows]
    ax.barh(y, [r["p50_ms"] for r in sweep_rows], color=colours, alpha=0.8, label="p50")
    ax.scatter([r["p95_ms"] for r in sweep_rows], y, color="black", marker="|", s=80, label="p95", zorder=3)
    ax.set_yticks(y, labels, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("ms per run (lower is better)")
    ax.set_title("session settings (blue: ONNX Runtime, orange: OpenVINO)", fontsize=9)
    ax.legend(fontsize=7)
    ax = axes[1]
    if lane_rows:
        names = [r["split"].replace(" (previews wait for the refinement)", "").replace("reference: ", "ref: ")
                 for r in lane_rows]
        y = np.arange(len(lane_rows))
        ax.barh(y - 0.2, [r["preview_fps"] or 0 for r in lane_rows], height=0.4, color="tab:green",
                label="previews/s")
        ax.barh(y + 0.2, [r["refines_per_s"] or 0 for r in lane_rows], height=0.4, color="tab:purple",
                label="refinements/s")
        ax.set_yticks(y, names, fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel("completed per second (higher is better)")
        ax.legend(fontsize=7)
    ax.set_title("previews while refinements run back to back", fontsize=9)
    env = result["environment"]
    fig.suptitle(f"{result['bundle']['garment_id']}: {env['cpu']} ({', '.join(env['isa'])}, "
                 f"{env['logical_cpus']} CPUs), load {env['loadavg_start'][0]:.1f}-{env['loadavg_end'][0]:.1f}",
                 fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main(argv: list[str], prog: str = "vtkiosk bench threads") -> int:
    args = build_parser(prog).parse_args(argv)
    if args.runs < 2 or args.warmup < 0 or not 1 <= args.rounds <= 20 or not (0.5 <= args.seconds <= 600):
        raise BenchError("--runs must be at least 2, --warmup at least 0, --rounds from 1 to 20, --seconds from "
                         "0.5 to 600")
    if not args.bundle.exists():
        raise BenchError(f"no bundle at {args.bundle}")
    result = run_bench(args, argv, prog)
    env = result["environment"]
    print(f"CPU: {env['cpu']} ({env['arch']}, ISA {', '.join(env['isa']) or 'none listed'}, "
          f"{env['logical_cpus']} logical CPUs); load average {env['loadavg_start'][0]:.2f} at start, "
          f"{env['loadavg_end'][0]:.2f} at end")
    w = result["work"]
    print(f"planner's work: preview = {w['preview']['graph']} graph at {'x'.join(map(str, w['preview']['grid']))}, "
          f"refine = {w['refine']['graph']} graph at {'x'.join(map(str, w['refine']['grid']))}")
    if result["sweep"]:
        print("\n" + sweep_table(result["sweep"]))
    if result["lanes"]:
        print("\n" + lanes_table(result["lanes"]))
        for line in result["lane_ratios"]:
            print(f"  {line}")
    write_result(args.json, result)
    if args.plot is not None:
        print(f"wrote {plot(result, args.plot)}")
    return 0
