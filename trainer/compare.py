"""`--compare`: methods x metrics in the shape of the paper's Tables 1/2, with the reference rows (flat,
mean-colour, oracle) and the gap closed beside every method, as markdown + JSON; paired bootstrap intervals of
"ours - X" for every other method and reference; the target check (trainer.verdict); a qualitative sheet per
garment (sketch and ground truth, the reference rows, then each method's visual, normal map, height map and friction
map)."""
from __future__ import annotations

import json
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from trainer import eval_cache, provenance, target_plot, verdict
from trainer.bootstrap import paired_bootstrap
from trainer.relief_rules import RULES
from trainer.checkpoint import WEIGHTS
from trainer.evaluate import HIGHER_IS_BETTER, Evaluation, Prediction, reference_predictions
from trainer.models.mirror_modes import MODES as MIRROR_MODES
from trainer.references import REFERENCE_ROWS
from trainer.sheets import grid, label, output_row, save_png, to_uint8


VISUAL_COLUMNS = [("visual_psnr", "PSNR ↑"), ("visual_ssim", "SSIM ↑"), ("visual_l1", "L1 ↓"),
                  ("visual_lpips", "LPIPS ↓"), ("visual_fbsifid_unseen", "FB-SIFID unseen ↓"),
                  ("visual_sifid_unseen", "SIFID unseen ↓"), ("visual_fbsifid_seen", "FB-SIFID seen ↓"),
                  ("visual_sifid_seen", "SIFID seen ↓")]
TACTILE_COLUMNS = [("tactile_mse", "T-MSE ↓"), ("tactile_angle_deg", "T-angle° ↓"),
                   ("full_angle_deg", "Full angle° ↓"), ("full_angle_deg_inside", "inside° ↓"),
                   ("full_angle_deg_outside", "outside° ↓"), ("full_friction_mae", "Friction MAE ↓"),
                   ("full_friction_mae_inside", "inside ↓"), ("full_friction_mae_outside", "outside ↓"),
                   ("tactile_lpips", "T-LPIPS ↓"), ("tactile_sifid_seen", "T-SIFID seen ↓"),
                   ("tactile_fbsifid_seen", "T-FB-SIFID seen ↓"), ("full_fbsifid_seen", "Full FB-SIFID seen ↓"),
                   ("full_fbsifid_unseen", "Full FB-SIFID unseen ↓")]
# the outside angle split where the sketch draws relief and where it leaves open cloth (trainer.evaluate.near_strokes)
WHERE_COLUMNS = [("full_angle_deg_outside", "outside° ↓"), ("gap:full_angle_deg_outside", "gap"),
                 ("full_angle_deg_outside_lines", "by a line° ↓"), ("gap:full_angle_deg_outside_lines", "gap"),
                 ("full_angle_deg_outside_open", "open cloth° ↓"), ("gap:full_angle_deg_outside_open", "gap")]
# gap-closed columns follow these (tactile, lower is better)
GAP_AFTER = ("tactile_mse", "tactile_angle_deg", "full_angle_deg", "full_angle_deg_outside", "full_friction_mae",
             "full_friction_mae_outside")
DIFF_METRICS = ("visual_psnr", "visual_ssim", "visual_l1", "visual_fbsifid_unseen", "tactile_mse",
                "tactile_angle_deg", "full_angle_deg", "full_angle_deg_inside", "full_angle_deg_outside",
                "full_angle_deg_outside_lines", "full_angle_deg_outside_open", "full_friction_mae",
                "full_friction_mae_outside", "full_fbsifid_unseen")
COLUMNS = VISUAL_COLUMNS + TACTILE_COLUMNS + [c for c in WHERE_COLUMNS if not c[0].startswith("gap:")]
HEADERS = dict(COLUMNS)
UNITS_RESAMPLED = ("held-out touches (tactile patches), 32 px blocks (visual, full field) or unseen sketches "
                   "(FB-SIFID unseen), then garments, then each method's seeds")


def _gap(r: dict, k: str):
    return (r.get("gap_closed") or {}).get(k)


def _reference_rows(results: list[dict]) -> dict[str, list[dict]]:
    """One reference result per garment (the first run's; references do not depend on the run)."""
    out: dict[str, list[dict]] = defaultdict(list)
    seen: set[str] = set()
    for r in results:
        if r["garment"] in seen or not r.get("references"):
            continue
        seen.add(r["garment"])
        for name, ref in r["references"].items():
            out[name].append(ref | {"garment": r["garment"]})
    return {n: out[n] for n in REFERENCE_ROWS if n in out}


def _stats(rows: list[dict], keys: list[str]) -> tuple[dict, dict]:
    means, sds = {}, {}
    for k in keys:
        if k.startswith("gap:"):
            v = [g for g in (_gap(r, k[4:]) for r in rows) if g is not None]
        else:
            v = [r[k] for r in rows if k in r and r[k] is not None and np.isfinite(r[k])]
        if v:
            means[k] = float(np.mean(v))
            if len(v) > 1:
                sds[k] = float(np.std(v, ddof=1))
    return means, sds


def _section(title: str, cols: list[tuple[str, str]], methods: dict[str, list[dict]],
             refs: dict[str, list[dict]]) -> tuple[str, dict, dict, dict]:
    keys = [k for k, _ in cols]
    stats = {m: _stats(rs, keys) for m, rs in methods.items()}
    rstats = {m: _stats(rs, keys) for m, rs in refs.items()}
    cols = [(k, h) for k, h in cols if any(k in s[0] for s in list(stats.values()) + list(rstats.values()))]
    if not cols:
        return "", {}, {}, {}
    best = {}
    for k, _ in cols:
        vals = [s[0][k] for s in stats.values() if k in s[0]]
        if vals and not k.startswith("gap:"):
            best[k] = (max if k in HIGHER_IS_BETTER else min)(vals)
    lines = [f"### {title}", "", "| method | garments | runs | " + " | ".join(h for _, h in cols) + " |",
             "|---|---|---|" + "---|" * len(cols)]

    def row(name, rs, mean, sd, bold):
        cells = []
        for k, _ in cols:
            if k not in mean:
                cells.append("–")
                continue
            s = f"{mean[k]:.2f}" if k.startswith("gap:") else f"{mean[k]:.4g}"
            s = f"**{s}**" if bold and k in best and np.isclose(mean[k], best[k]) else s
            cells.append(f"{s} ± {sd[k]:.2g}" if k in sd else s)
        n_g = len({r["garment"] for r in rs})
        return f"| {name} | {n_g} | {len(rs)} | " + " | ".join(cells) + " |"

    for m, rs in methods.items():
        lines.append(row(m, rs, *stats[m], True))
    for m, rs in refs.items():
        lines.append(row(f"*{m}* (reference)", rs, *rstats[m], False))
    return "\n".join(lines) + "\n", {m: s[0] for m, s in stats.items()}, {m: s[1] for m, s in stats.items()}, \
        {"mean": {m: s[0] for m, s in rstats.items()}, "sd": {m: s[1] for m, s in rstats.items()}, "best": best}


def table(results: list[dict], diffs: dict | None = None, ours: str = "ours", *,
          resampled: str = UNITS_RESAMPLED) -> tuple[str, dict]:
    """Mean per method over its runs (garments, seeds); with several runs a cell reads `mean ± sd` (sample sd).
    Best method mean per column in bold (reference rows are never bold: the oracle is not a competitor). `gap`
    columns: mean over runs of (flat - method) / (flat - oracle) on the same garment."""
    by_method: dict[str, list[dict]] = defaultdict(list)
    for r in results:
        by_method[r["method"]].append(r)
    refs = _reference_rows(results)
    tcols = []
    for k, h in TACTILE_COLUMNS:
        tcols.append((k, h))
        if k in GAP_AFTER:
            tcols.append((f"gap:{k}", "gap"))
    md_v, mv, sv, rv = _section("Visual (inside the object mask)", VISUAL_COLUMNS,
                                by_method, {k: v for k, v in refs.items() if k == "mean-colour"})
    md_t, mt, st, rt = _section("Tactile", tcols, by_method, {k: v for k, v in refs.items() if k != "mean-colour"})
    md_w, mw, sw, rw = _section("Outside the touches: by the sketch's lines and in open cloth", WHERE_COLUMNS,
                              by_method, {k: v for k, v in refs.items() if k != "mean-colour"})
    md = "\n".join(s for s in (md_v, md_t, md_w) if s)
    trained_on = machines(results)
    md += "\n" + machines_markdown(trained_on)
    md += unseen_markdown(results)
    if diffs:
        md += "\n" + ci_table(diffs, ours, resampled)
    means = {m: mv.get(m, {}) | mt.get(m, {}) | mw.get(m, {}) for m in by_method}
    gaps = {m: {k[4:]: v for k, v in row.items() if k.startswith("gap:")} for m, row in means.items()}
    means = {m: {k: v for k, v in row.items() if not k.startswith("gap:")} for m, row in means.items()}
    sds = {m: {k: v for k, v in (sv.get(m, {}) | st.get(m, {}) | sw.get(m, {})).items() if not k.startswith("gap:")}
           for m in by_method}
    ref_means = {n: (rv.get("mean", {}).get(n, {}) | rt.get("mean", {}).get(n, {}) | rw.get("mean", {}).get(n, {}))
                 for n in refs}
    data = {"mean": means, "sd": sds, "gap_closed": gaps,
            "garments": {m: sorted({r["garment"] for r in rs}) for m, rs in by_method.items()},
            "best": rv.get("best", {}) | rt.get("best", {}) | rw.get("best", {}),
            "references": {n: {k: v for k, v in row.items() if not k.startswith("gap:")}
                           for n, row in ref_means.items()},
            "reference_gap_closed": {n: {k[4:]: v for k, v in row.items() if k.startswith("gap:")}
                                     for n, row in ref_means.items()},
            "trained_on": trained_on, "runs": results}
    if diffs:
        data["differences"] = {"method": ours, "level": 0.95, "rows": diffs}
    return md, data


def unseen_markdown(results: list[dict]) -> str:
    """Where the unseen sketches came from, when not from each garment's own dataset (`eval --unseen-from`)."""
    folders = sorted({r["unseen_from"] for r in results if r.get("unseen_from")})
    if not folders:
        return ""
    counts = sorted({len(r.get("unseen_sketches") or []) for r in results})
    n = f"{counts[0]}" if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
    return (f"\nUnseen sketches (FB-SIFID unseen): {n} per run, from the dataset folder "
            f"{', '.join(f'`{f}`' for f in folders)} (`eval --unseen-from`), not each garment's own.\n")


def machines(results: list[dict]) -> dict:
    """{machine summary: number of runs trained (partly) on it}, how many runs mix kernel paths, and how many were
    resumed after a stretch whose machine went unrecorded. Rows trained on different kernels differ by more than
    their intervals say (docs/training.md), so the table names them."""
    counts: Counter = Counter()
    mixed = partly_unrecorded = 0
    for r in results:
        stretches = r.get("machines") or [{"from_step": 0, "machine": None}]
        names = [provenance.summary(s.get("machine")) for s in stretches]
        counts.update(set(names))
        recorded = {n for n, s in zip(names, stretches) if s.get("machine")}
        mixed += len(recorded) > 1
        partly_unrecorded += bool(recorded) and any(not s.get("machine") for s in stretches)
    return {"machines": dict(counts.most_common()), "runs_resumed_across_machines": mixed,
            "runs_resumed_after_unrecorded": partly_unrecorded}


def machines_markdown(trained_on: dict) -> str:
    parts = [f"{name}: {n} run{'s' if n != 1 else ''}" for name, n in trained_on["machines"].items()]
    line = "Trained on " + "; ".join(parts) + "."
    if trained_on["runs_resumed_across_machines"]:
        line += f" {trained_on['runs_resumed_across_machines']} run(s) were resumed on another kernel path."
    if trained_on.get("runs_resumed_after_unrecorded"):
        line += (f" {trained_on['runs_resumed_after_unrecorded']} run(s) began on an unrecorded machine and were "
                 "resumed on a recorded one (counted under both).")
    if len(trained_on["machines"]) > 1:
        line += (" Runs from different machines or kernel paths differ by more than the intervals below include "
                 "(docs/training.md).")
    return line + "\n"


def ci_table(diffs: dict[str, dict[str, dict]], ours: str, resampled: str = UNITS_RESAMPLED) -> str:
    """"ours - X [lo, hi]" per method or reference X and metric (paired bootstrap, 95 %)."""
    metrics = [k for k in DIFF_METRICS if any(k in d for d in diffs.values())]
    if not metrics:
        return ""
    lines = [f"### {ours} − X, paired bootstrap 95 % interval", "",
             f"Resampled: {resampled}. An interval that excludes 0 orders the two; for ↓ metrics a negative "
             f"difference means {ours} is better.", "",
             "| X | " + " | ".join(HEADERS[k] for k in metrics) + " |", "|---|" + "---|" * len(metrics)]
    for x, row in diffs.items():
        cells = []
        for k in metrics:
            d = row.get(k)
            cells.append("–" if d is None else f"{d['diff']:+.3g} [{d['lo']:+.3g}, {d['hi']:+.3g}]")
        name = f"*{x}*" if x in REFERENCE_ROWS else x
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def grouped_units(evals: list[Evaluation]) -> dict[str, dict[str, list]]:
    """method (or reference row) -> garment -> the per-unit sums of each of its runs (one reference per garment)."""
    runs: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for e in evals:
        runs[e.result["method"]][e.result["garment"]].append(e.units)
    for e in evals:
        for name, u in e.ref_units.items():
            if e.result["garment"] not in runs[name]:
                runs[name][e.result["garment"]].append(u)
    return runs


def differences(evals: list[Evaluation], ours: str, *, n_boot: int = 2000, seed: int = 0) -> dict:
    """Paired bootstrap of `ours` - X for every other method and every reference row, per DIFF_METRICS."""
    runs = grouped_units(evals)
    if ours not in runs:
        return {}
    out: dict[str, dict] = {}
    others = [m for m in runs if m != ours and m not in REFERENCE_ROWS] + [m for m in REFERENCE_ROWS if m in runs]
    for x in others:
        row = {}
        for k in DIFF_METRICS:
            a = {g: [u[k] for u in us if k in u] for g, us in runs[ours].items()}
            b = {g: [u[k] for u in us if k in u] for g, us in runs[x].items()}
            d = paired_bootstrap(k, a, b, n_boot=n_boot, seed=seed)
            if d is not None:
                row[k] = d.as_dict()
        if row:
            out[x] = row
    return out


@dataclass(frozen=True)
class RunSpec:
    """A run folder, which of its G weights are scored (`average`: the EMA, what is exported; `raw`; `probe`) and
    the relief calibration applied to its tactile output (`none` or a trainer.calibration rule), after the tactile
    output is averaged over mirrored views (`none` or a trainer.models.mirror_average mode)."""

    path: Path
    weights: str = "average"
    relief: str = "none"
    mirrors: str = "none"

    @property
    def tags(self) -> list[str]:
        return eval_cache.variant(self.weights, self.relief, self.mirrors)

    def __str__(self) -> str:
        return str(self.path) + "".join(f"@{t}" for t in self.tags)


def _spec(r: Path | RunSpec) -> RunSpec:
    return r if isinstance(r, RunSpec) else RunSpec(Path(r))


def qualitative_sheets(runs: list[Path | RunSpec], out_dir: Path, which: str = "best",
                       labels: dict[RunSpec, str] | None = None) -> list[Path]:
    labels = labels or {}
    per_garment: dict[str, list[Prediction]] = defaultdict(list)
    names: dict[int, str] = {}
    for r in map(_spec, runs):
        p = Prediction(r.path, which, unseen=False, weights=r.weights, relief=r.relief, mirrors=r.mirrors)
        per_garment[p.g.name].append(p)
        names[id(p)] = labels.get(r, _default_label(p.info["method"], r))
    paths = []
    for name, preds in per_garment.items():
        p0 = preds[0]
        ctx = p0.ctx
        m, scale = ctx.obj, ctx.scale
        truth_vis = ctx.visual[0].permute(1, 2, 0).numpy()
        top = [label(to_uint8(ctx.sketch[0, 0].numpy()), "sketch"), label(to_uint8(truth_vis), "ground truth visual")]
        rows = []
        truth = ctx.truth()
        if truth is not None:
            rows.append(output_row("truth", truth_vis, truth[0], truth[1], m, scale))
        refs = reference_predictions(ctx)
        flat_vis = refs["mean-colour"][0][0].permute(1, 2, 0).numpy()
        flat_tac = refs["flat"][1][0].numpy()
        rows.append(output_row("flat + mean-colour", flat_vis, flat_tac[0], flat_tac[1], m, scale))
        if "oracle" in refs:
            o = refs["oracle"][1][0].numpy()
            rows.append(output_row("oracle", truth_vis, o[0], o[1], m, scale))
        counts = Counter(names[id(p)] for p in preds)
        for p in preds:
            # several runs of one method (seeds): name each row by its run folder too
            name = names[id(p)] if counts[names[id(p)]] == 1 else f"{names[id(p)]} ({p.run.name})"
            rows.append(output_row(name, p.vis[0].permute(1, 2, 0).numpy(), p.tac[0, 0].numpy(),
                                   p.tac[0, 1].numpy(), m, scale))
        path = out_dir / f"sheet_{p0.g.material}.png"
        save_png(path, grid([top] + rows))
        paths.append(path)
    return paths


def _default_label(method: str, spec: RunSpec) -> str:
    return method + "".join(f"-{t}" for t in spec.tags)


def parse_run(arg: str, relief: str = "none", mirrors: str = "none") -> RunSpec:
    """`RUN`, then optional `@raw` / `@probe` (score the run's raw G weights, or its probe average, instead of their
    average), `@rms` (its relief calibrated on its training touches, trainer.calibration; else `relief`) and `@flip`
    (its relief averaged over mirrored views, trainer.models.mirror_average; else `mirrors`)."""
    path, weights, own_relief, own_mirrors = arg, "average", None, None
    while True:
        head, sep, tail = path.rpartition("@")
        if not sep or "/" in tail:
            break
        if not head:
            raise ValueError(f"{arg!r}: no run folder before the @")
        if tail in WEIGHTS and weights == "average":
            weights = tail
        elif tail in RULES and tail != "none" and own_relief is None:
            own_relief = tail
        elif tail in MIRROR_MODES and tail != "none" and own_mirrors is None:
            own_mirrors = tail
        else:
            raise ValueError(f"{arg!r}: RUN@X takes {', '.join(WEIGHTS)} (weights), "
                             f"{', '.join(r for r in RULES if r != 'none')} (relief) or "
                             f"{', '.join(m for m in MIRROR_MODES if m != 'none')} (mirrors) after an @, "
                             "each at most once")
        path = head
    return RunSpec(Path(path), weights, own_relief or relief, own_mirrors or mirrors)


def parse_labelled(args: list[str], relief: str = "none",
                   mirrors: str = "none") -> tuple[list[RunSpec], dict[RunSpec, str]]:
    """`[LABEL=]RUN[@raw][@flip][@ls]` arguments -> the runs and the labels given (a LABEL has no path separator). A
    run scored with its raw weights is named `<method>-raw` unless labelled (with a calibrated relief,
    `<method>-ls`; mirrored, `<method>-flip`); `relief` and `mirrors` are the settings of runs that name none."""
    runs, labels = [], {}
    for a in args:
        label, sep, path = a.partition("=")
        if sep and label and "/" not in label and path:
            spec = parse_run(path, relief, mirrors)
            labels[spec] = label
        elif sep and "/" not in label:
            raise ValueError(f"--compare: {a!r}: a labelled run is LABEL=RUN with both parts")
        else:
            spec = parse_run(a, relief, mirrors)
        if spec in runs:
            raise ValueError(f"--compare: {spec} is given twice")
        runs.append(spec)
    return runs, labels


def report(evals: list[Evaluation], ours: str, *, n_boot: int = 2000,
           resampled: str = UNITS_RESAMPLED) -> tuple[str, dict]:
    """The tables, the `ours - X` intervals and the target check of scored runs (`resampled`: what the intervals
    resample, said under them)."""
    methods = [e.result["method"] for e in evals]
    if ours not in methods:   # differences are taken against the first run's method then
        ours = methods[0]
    with torch.no_grad():
        diffs = differences(evals, ours, n_boot=n_boot)
    results = [e.result for e in evals]
    md, data = table(results, diffs, ours, resampled=resampled)
    competitors = sorted({m for m in methods if m != ours})
    if competitors:
        data["target"] = verdict.check(grouped_units(evals), results, ours, competitors, n_boot=n_boot)
        md += "\n" + verdict.markdown(data["target"])
    return md, data


def compare(runs: list[Path | RunSpec], out_dir: Path, which: str = "best", *, ours: str = "ours",
            n_boot: int = 2000, cache: bool = True, labels: dict[RunSpec, str] | None = None,
            unseen_from: Path | None = None) -> tuple[str, dict]:
    """Score `runs` (reusing each run's stored scores when nothing they depend on changed: trainer.eval_cache),
    write the tables, the target's picture (trainer.target_plot) and the sheets to `out_dir`. `labels`: run -> the
    name its rows get instead of its method. `unseen_from`: a dataset folder whose sketches are the unseen ones,
    instead of each garment's own dataset's."""
    labels = labels or {}
    runs = [_spec(r) for r in runs]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    evals = []
    for r in runs:
        e = eval_cache.scored(r.path, which, r.weights, cache=cache, relief=r.relief, mirrors=r.mirrors,
                              unseen_from=unseen_from)
        e.result["run"] = str(r)
        name = labels.get(r, _default_label(e.result["method"], r))
        if name != e.result["method"]:
            e.result["trained_method"], e.result["method"] = e.result["method"], name
        evals.append(e)
    md, data = report(evals, ours, n_boot=n_boot)
    (out_dir / "compare.md").write_text(md)
    (out_dir / "compare.json").write_text(json.dumps(data, indent=2))
    drawn = target_plot.beside_table([e.result for e in evals], data, out_dir, ours)
    data["target_plot"] = str(drawn) if drawn else None
    data["sheets"] = [str(p) for p in qualitative_sheets(runs, out_dir, which, labels)]
    return md, data


def write_eval(run_dir: Path, result: dict, json_out: Path | None = None) -> None:
    """eval/metrics.json, eval/summary.md (the run beside its reference rows), and the run's metrics.json; the raw
    weights' scores go beside them (metrics-raw.json, summary-raw.md, "eval_raw"), never over the average's; so do a
    calibrated relief's (metrics-rms.json, "eval_rms") and a mirrored one's (metrics-flip-ls.json, "eval_flip_ls")."""
    run_dir = Path(run_dir)
    tags = eval_cache.variant(result.get("weights", "average"), (result.get("relief") or {}).get("rule", "none"),
                              result.get("mirrors", "none"))
    suffix = "".join(f"-{t}" for t in tags) + eval_cache.unseen_tag(result.get("unseen_from"))
    (run_dir / "eval").mkdir(parents=True, exist_ok=True)
    (run_dir / "eval" / f"metrics{suffix}.json").write_text(json.dumps(result, indent=2))
    (run_dir / "eval" / f"summary{suffix}.md").write_text(table([result])[0])
    mpath = run_dir / "metrics.json"
    merged = json.loads(mpath.read_text()) if mpath.is_file() else {}
    merged["eval" + suffix.replace("-", "_")] = result
    mpath.write_text(json.dumps(merged, indent=2))
    if json_out is not None:
        Path(json_out).parent.mkdir(parents=True, exist_ok=True)
        Path(json_out).write_text(json.dumps(result, indent=2))
