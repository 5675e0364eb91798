"""The Fidelity II target, checked on a comparison instead of by eye.

`ours` must be better than every other method on the tactile angle outside the training touches and on the
full-field tactile FB-SIFID on unseen sketches, each with a paired bootstrap interval of `ours - X` that excludes 0,
on at least TARGET_GARMENTS of the garments (and on at least 3 of 4: TARGET_SHARE), and close at least TARGET_GAP of
the flat-to-oracle gap on full-field angle (mean over garments). A garment where some method has no run cannot be
won: "better than every baseline" is not shown by a baseline that was not trained.
"""
from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence

import numpy as np

from trainer.bootstrap import Units, paired_bootstrap

TARGET_METRICS = ("full_angle_deg_outside", "full_fbsifid_unseen")
TARGET_GAP = 0.60
TARGET_GAP_METRIC = "full_angle_deg"
TARGET_GARMENTS = 3
TARGET_SHARE = 0.75
LABELS = {"full_angle_deg_outside": "outside°", "full_fbsifid_unseen": "Full FB-SIFID unseen"}

Grouped = Mapping[str, Mapping[str, Sequence[Mapping[str, Units]]]]   # method -> garment -> runs' units


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
        garments.append({"garment": g, "won": won and bool(rows), "against": rows, "missing": missing,
                         "gap_closed": gap})
    n = len(garments)
    wins = sum(x["won"] for x in garments)
    needed = max(TARGET_GARMENTS, math.ceil(TARGET_SHARE * n))
    gap_vals = [x["gap_closed"] for x in garments if x["gap_closed"] is not None]
    mean_gap = float(np.mean(gap_vals)) if gap_vals else None
    return {"ours": ours, "metrics": list(TARGET_METRICS), "competitors": list(competitors), "garments": garments,
            "wins": wins, "garments_needed": needed, "mean_gap_closed": mean_gap, "gap_needed": TARGET_GAP,
            "met": bool(n and wins >= needed and mean_gap is not None and mean_gap >= TARGET_GAP)}


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
    lines += ["", "| garment | ordered against every X | gap closed (full angle) |", "|---|---|---|"]
    for gv in v["garments"]:
        gap = "–" if gv["gap_closed"] is None else f"{gv['gap_closed']:.0%}"
        lines.append(f"| {gv['garment']} | {'yes' if gv['won'] else 'no'} | {gap} |")
    gap = "–" if v["mean_gap_closed"] is None else f"{v['mean_gap_closed']:.0%}"
    lines += ["", f"**{'Met' if v['met'] else 'Not met'}**: {ours} is ordered first on {v['wins']} of "
              f"{len(v['garments'])} garments (needs {v['garments_needed']}); mean gap closed {gap} "
              f"(needs {v['gap_needed']:.0%})."]
    return "\n".join(lines) + "\n"
