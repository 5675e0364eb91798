"""The Fidelity II target, checked on a comparison instead of by eye.

`ours` must be better than every other method on the tactile angle outside the training touches and on the
full-field tactile FB-SIFID on unseen sketches, each with a paired bootstrap interval of `ours - X` that excludes 0,
on at least TARGET_GARMENTS of the garments (and on at least 3 of 4: TARGET_SHARE), and close at least TARGET_GAP of
the flat-to-oracle gap on full-field angle (mean over garments). A garment where some method has no run cannot be
won: "better than every baseline" is not shown by a baseline that was not trained. An ordering from fewer than
TARGET_SEEDS runs of `ours` is reported but does not count towards the target: its interval resamples the held-out
touches and sketches, not training, and on this project's tables one-seed leads of 0.4-0.8 deg have vanished with
seeds 1 and 2 (docs/training.md, Fidelity II). The pooled seed-to-seed SD beside it says how far a seed moves a figure.
"""
from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence

import numpy as np

from trainer.bootstrap import Units, paired_bootstrap, value

TARGET_METRICS = ("full_angle_deg_outside", "full_fbsifid_unseen")
TARGET_GAP = 0.60
TARGET_GAP_METRIC = "full_angle_deg"
TARGET_GARMENTS = 3
TARGET_SHARE = 0.75
TARGET_SEEDS = 3      # the issue's "3 seeds for the close pairs": fewer runs of `ours` order a garment provisionally
LABELS = {"full_angle_deg_outside": "outside°", "full_fbsifid_unseen": "Full FB-SIFID unseen"}

Grouped = Mapping[str, Mapping[str, Sequence[Mapping[str, Units]]]]   # method -> garment -> runs' units


def seed_sd(runs: Mapping[str, Sequence[Mapping[str, Units]]], metric: str) -> float | None:
    """Pooled within-method SD of `metric` across seeds: sqrt(sum (n_i - 1) s_i^2 / sum (n_i - 1)) over the methods
    with at least two runs (`runs`: method -> its runs on one garment). None when no method has two."""
    ss, dof = 0.0, 0
    for rs in runs.values():
        vals = np.array([value(metric, u[metric]) for u in rs if metric in u and len(u[metric])])
        vals = vals[np.isfinite(vals)]
        if len(vals) >= 2:
            ss += float(np.sum((vals - vals.mean()) ** 2))
            dof += len(vals) - 1
    return math.sqrt(ss / dof) if dof else None


def check(grouped: Grouped, results: Sequence[dict], ours: str, competitors: Sequence[str], *,
          n_boot: int = 2000, seed: int = 0) -> dict:
    """Per garment: `ours - X` with its interval for each competitor X and target metric, whether every interval
    lies below 0, and the gap `ours` closed; then the overall verdict. JSON-able."""
    gaps: dict[str, list[float]] = defaultdict(list)
    for r in results:
        g = (r.get("gap_closed") or {}).get(TARGET_GAP_METRIC)
        if r["method"] == ours and g is not None and np.isfinite(g):
            gaps[r["garment"]].append(float(g))
    garments = []
    for g in sorted(grouped.get(ours, {})):
        rows, missing, won = [], [], True
        for x in competitors:
            if not grouped.get(x, {}).get(g):
                missing.append(x)
                won = False
                continue
            row = {"method": x}
            for k in TARGET_METRICS:
                a = {g: [u[k] for u in grouped[ours][g] if k in u]}
                b = {g: [u[k] for u in grouped[x][g] if k in u]}
                d = paired_bootstrap(k, a, b, n_boot=n_boot, seed=seed)
                row[k] = None if d is None else d.as_dict()
                won = won and d is not None and d.hi < 0
            rows.append(row)
        gap = float(np.mean(gaps[g])) if gaps.get(g) else None
        here = {m: grouped[m][g] for m in [ours, *competitors] if grouped.get(m, {}).get(g)}
        n_ours = len(grouped[ours][g])
        won = won and bool(rows)
        garments.append({"garment": g, "won": won, "settled": won and n_ours >= TARGET_SEEDS, "against": rows,
                         "missing": missing, "gap_closed": gap, "runs": {m: len(r) for m, r in here.items()},
                         "seed_sd": {k: seed_sd(here, k) for k in TARGET_METRICS}})
    n = len(garments)
    wins = sum(x["won"] for x in garments)
    settled = sum(x["settled"] for x in garments)
    needed = max(TARGET_GARMENTS, math.ceil(TARGET_SHARE * n))
    gap_vals = [x["gap_closed"] for x in garments if x["gap_closed"] is not None]
    mean_gap = float(np.mean(gap_vals)) if gap_vals else None
    return {"ours": ours, "metrics": list(TARGET_METRICS), "competitors": list(competitors), "garments": garments,
            "wins": wins, "settled_wins": settled, "seeds_needed": TARGET_SEEDS, "garments_needed": needed,
            "mean_gap_closed": mean_gap, "gap_needed": TARGET_GAP,
            "met": bool(n and settled >= needed and mean_gap is not None and mean_gap >= TARGET_GAP)}


def markdown(v: dict) -> str:
    if not v["garments"]:
        return ""
    ours = v["ours"]
    lines = ["### Target check", "",
             f"`{ours}` must beat every other method on " + " and ".join(LABELS[k] for k in v["metrics"]) +
             f" (paired 95 % interval of {ours} − X below 0) on at least {v['garments_needed']} garments, and close "
             f"at least {v['gap_needed']:.0%} of the flat-to-oracle gap on full-field angle.", "",
             "| garment | X | " + " | ".join(f"{LABELS[k]} {ours} − X" for k in v["metrics"]) + " |",
             "|---|---|" + "---|" * len(v["metrics"])]
    for gv in v["garments"]:
        for row in gv["against"]:
            cells = []
            for k in v["metrics"]:
                d = row.get(k)
                mark = "" if d is None or d["hi"] >= 0 else " ✓"
                cells.append("–" if d is None else f"{d['diff']:+.3g} [{d['lo']:+.3g}, {d['hi']:+.3g}]{mark}")
            lines.append(f"| {gv['garment']} | {row['method']} | " + " | ".join(cells) + " |")
        for x in gv["missing"]:
            lines.append(f"| {gv['garment']} | {x} | " + " | ".join("not run" for _ in v["metrics"]) + " |")
    lines += ["", f"| garment | ordered against every X | runs of {ours} | seed-to-seed SD ("
              + " / ".join(LABELS[k] for k in v["metrics"]) + ") | gap closed (full angle) |", "|---|---|---|---|---|"]
    for gv in v["garments"]:
        gap = "–" if gv["gap_closed"] is None else f"{gv['gap_closed']:.0%}"
        n_ours = gv["runs"][ours]
        order = "no" if not gv["won"] else "yes" if gv["settled"] else f"provisional (needs {v['seeds_needed']} runs)"
        sds = " / ".join("–" if gv["seed_sd"][k] is None else f"{gv['seed_sd'][k]:.3g}" for k in v["metrics"])
        lines.append(f"| {gv['garment']} | {order} | {n_ours} | {sds} | {gap} |")
    gap = "–" if v["mean_gap_closed"] is None else f"{v['mean_gap_closed']:.0%}"
    provisional = v["wins"] - v["settled_wins"]
    note = f", {provisional} more on fewer than {v['seeds_needed']} runs of {ours}" if provisional else ""
    lines += ["", f"**{'Met' if v['met'] else 'Not met'}**: {ours} is ordered first on {v['settled_wins']} of "
              f"{len(v['garments'])} garments{note} (needs {v['garments_needed']}, each on {v['seeds_needed']} runs); "
              f"mean gap closed {gap} (needs {v['gap_needed']:.0%})."]
    if any(gv["runs"][ours] < v["seeds_needed"] for gv in v["garments"]):
        lines += ["", f"Fewer than {v['seeds_needed']} runs of {ours}: its intervals resample the held-out data, not "
                  "training; the seed-to-seed SD (pooled over the methods with two or more runs on the garment) says "
                  "how far another seed may move a figure."]
    return "\n".join(lines) + "\n"
