"""Where the flat-to-oracle gap on the outside angle goes, per garment, as one bar chart beside the 60 % target:
what `ours` closes in a comparison table, what the `shape-oracle` closes, and what the weave placed from the
touches adds to it (scripts/phase_from_touches.py, best of its wave counts, from each of its three sources).

Why a picture: the target's distance is the sum of three bounds measured in different places (the reference rows
of each table, the wave fits); side by side they show that no bar a model could reach from its touches comes near
the line.

    .venv/bin/python scripts/plot_gap_budget.py --ours txr-auto \
        --tables docs/compare_1k/mirrors/blind3_{kn,ss,ct,dn}/compare.json \
        --phase docs/compare_1k/phase_from_touches --out docs/compare_1k/phase_from_touches/gap_budget.png
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer.data.touchclothing import FOLDER_RE  # noqa: E402

GAP = "full_angle_deg_outside"
TARGET = 0.6
SOURCES = (("touches", "shape-oracle + weave placed from the recorded touches"),
           ("truth-at-touches", "shape-oracle + weave placed from perfect touches"),
           ("truth", "shape-oracle + weave fitted to the whole truth"))


def _short(garment: str) -> str:
    """singleskit_KnitJacket_padded_900_x1 -> KnitJacket (the material); other names unchanged."""
    m = FOLDER_RE.match(garment)
    return m["material"] if m else garment


def _mean(xs: list[float]) -> float | None:
    xs = [x for x in xs if isinstance(x, (int, float)) and math.isfinite(x)]
    return sum(xs) / len(xs) if xs else None


def table_bars(path: Path, ours: str) -> dict[str, dict[str, float | None]]:
    """garment -> {ours, shape-oracle}: `ours`'s mean gap closed over its runs, and the shape-oracle's."""
    d = json.loads(path.read_text())
    out: dict[str, dict[str, float | None]] = {}
    runs = [r for r in d.get("runs", []) if r.get("method") == ours]
    if not runs:
        methods = sorted({str(r.get("method")) for r in d.get("runs", [])})
        raise SystemExit(f"{path}: no runs of {ours!r} (methods: {', '.join(methods)})")
    for g in sorted({r["garment"] for r in runs}):
        mine = [r for r in runs if r["garment"] == g]
        shape = (mine[0].get("references", {}).get("shape-oracle", {}).get("gap_closed") or {}).get(GAP)
        out[_short(g)] = {"ours": _mean([(r.get("gap_closed") or {}).get(GAP) for r in mine]), "shape-oracle": shape}
    return out


def phase_bars(folder: Path) -> dict[str, dict[str, float | None]]:
    """garment -> source -> the best gap closed by shape-oracle + fitted waves (over the wave counts)."""
    out: dict[str, dict[str, float | None]] = {}
    for source, _ in SOURCES:
        path = folder / f"{source}.json"
        if not path.is_file():
            raise SystemExit(f"no {path}: run scripts/phase_from_touches.py --samples {source} --json {path}")
        for g in json.loads(path.read_text())["garments"]:
            gaps = [r["gap_closed_outside"] for k, r in g["rows"].items() if k.startswith("shape-oracle+waves-")]
            out.setdefault(_short(g["garment"]), {})[source] = max((x for x in gaps if x is not None), default=None)
    return out


def plot(bars: dict[str, dict[str, float | None]], ours: str, out: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = [("ours", f"{ours} (the table's runs)"), ("shape-oracle", "shape-oracle (every fold and seam)")]
    series += list(SOURCES)
    garments = list(bars)
    width = 0.8 / len(series)
    fig, ax = plt.subplots(figsize=(9, 4.8), dpi=120)
    for i, (key, label) in enumerate(series):
        xs = [j + (i - (len(series) - 1) / 2) * width for j in range(len(garments))]
        ys = [100 * (bars[g].get(key) if bars[g].get(key) is not None else math.nan) for g in garments]
        ax.bar(xs, ys, width, label=label)
    ax.axhline(100 * TARGET, color="k", ls="--", lw=1)
    ax.text(len(garments) - 0.5, 100 * TARGET + 1.5, "target 60 %", ha="right", va="bottom", fontsize=8)
    ax.axhline(0, color="0.5", lw=0.8)
    ax.set_xticks(range(len(garments)), garments)
    ax.set_ylabel("gap closed outside the touches (%)")
    ax.set_title("Where the flat-to-oracle gap goes (higher is better; flat 0 %, oracle 100 %)", fontsize=10)
    ax.set_ylim(min(0, ax.get_ylim()[0]), 100)
    fig.legend(fontsize=7, loc="lower center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0.13, 1, 1))
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ours", required=True, help="the method label of the tables' `ours` (e.g. txr-lift)")
    ap.add_argument("--tables", type=Path, nargs="+", required=True, help="compare.json of each garment's table")
    ap.add_argument("--phase", type=Path, required=True, help="folder of phase_from_touches' three JSON files")
    ap.add_argument("--out", type=Path, required=True, help="the PNG to write")
    a = ap.parse_args(argv)
    bars: dict[str, dict[str, float | None]] = {}
    for t in a.tables:
        for g, v in table_bars(t, a.ours).items():
            bars.setdefault(g, {}).update(v)
    for g, v in phase_bars(a.phase).items():
        if g in bars:
            bars[g].update(v)
    missing = [g for g, v in bars.items() if any(k not in v for k, _ in SOURCES)]
    if missing:
        raise SystemExit(f"no wave fits for {', '.join(missing)} in {a.phase}")
    # the target is on the mean over the garments: that group goes last
    keys = ["ours", "shape-oracle"] + [s for s, _ in SOURCES]
    bars["mean"] = {k: _mean([v[k] for v in bars.values() if v.get(k) is not None]) for k in keys}
    plot(bars, a.ours, a.out)
    print(f"{'garment':18s} {'ours':>6s} {'shape':>6s} " + " ".join(f"{s:>17s}" for s, _ in SOURCES))
    for g, v in bars.items():
        cells = [v.get("ours"), v.get("shape-oracle")] + [v.get(s) for s, _ in SOURCES]
        print(f"{g:18s} " + " ".join(f"{'-' if c is None else f'{100 * c:5.0f}%':>6s}" for c in cells[:2]) + " "
              + " ".join(f"{'-' if c is None else f'{100 * c:16.0f}%':>17s}" for c in cells[2:]))
    print(f"picture: {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
