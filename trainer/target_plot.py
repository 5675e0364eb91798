"""The target's two figures as one picture (`target.png` beside a comparison): per garment, each run's tactile
angle outside the training touches against its full-field FB-SIFID on unseen sketches, both lower-is-better, with
the reference rows.

Why: the target asks `ours` to sit below and left of every other method at once, and the two figures pull against
each other: a weave rendered where the sketch does not say its phase costs per-pixel angle and earns texture
statistics (the `texture-oracle` row is worse than `flat` on angle). The intervals say whether `ours` is ordered;
this says where every method sits on that trade, and how far the corner it must reach is from where it is.
"""
from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

from trainer.verdict import LABELS, TARGET_METRICS

X, Y = TARGET_METRICS
# reference rows with only the angle (the oracles exist on the training sketch alone): vertical lines
ANGLE_ONLY_REFERENCES = ("oracle", "shape-oracle", "texture-oracle")


def is_score(v) -> bool:
    """A stored score worth using: a finite number (a table's JSON keeps null for a figure a run has not got, and
    a bool is no score)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def points(results: list[dict]) -> dict[str, dict[str, list[tuple[float, float]]]]:
    """garment -> method -> the (outside angle, FB-SIFID unseen) of each run that has both figures."""
    out: dict[str, dict[str, list[tuple[float, float]]]] = defaultdict(lambda: defaultdict(list))
    for r in results:
        if is_score(r.get(X)) and is_score(r.get(Y)):
            out[r["garment"]][r["method"]].append((float(r[X]), float(r[Y])))
    return {g: dict(m) for g, m in out.items()}


def reference_points(results: list[dict]) -> dict[str, dict[str, tuple[float | None, float | None]]]:
    """garment -> reference row -> (outside angle, FB-SIFID unseen), None where the row has no such figure."""
    out: dict[str, dict[str, tuple[float | None, float | None]]] = {}
    for r in results:
        if r["garment"] in out or not r.get("references"):
            continue
        out[r["garment"]] = {name: tuple(float(ref[k]) if is_score(ref.get(k)) else None for k in (X, Y))
                             for name, ref in r["references"].items() if is_score(ref.get(X)) or is_score(ref.get(Y))}
    return out


def corner(methods: dict[str, list[tuple[float, float]]], ours: str) -> tuple[float, float] | None:
    """The best mean of every other method on each figure: `ours` must be below and left of it. None with no
    other method."""
    means = [_mean(p) for m, p in methods.items() if m != ours and p]
    if not means:
        return None
    return min(x for x, _ in means), min(y for _, y in means)


def _mean(p: list[tuple[float, float]]) -> tuple[float, float]:
    return sum(x for x, _ in p) / len(p), sum(y for _, y in p) / len(p)


def _short(garment: str) -> str:
    """`singleskit_KnitJacket_padded_900_x1` -> `KnitJacket` (the material); other names unchanged."""
    parts = [p for p in garment.split("_") if p[:1].isupper()]
    return parts[0] if len(parts) == 1 else garment


def plot(results: list[dict], out: Path, ours: str, target: dict | None = None) -> Path | None:
    """Write the figure; None (nothing written) when no run has both figures. `target`: the verdict's dict, whose
    per-garment outcome goes in each panel's title."""
    pts = points(results)
    if not pts:
        return None
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle
    refs = reference_points(results)
    outcome = {x["garment"]: x for x in (target or {}).get("garments", [])}
    names = sorted({m for g in pts.values() for m in g} - {ours})
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(names)}
    garments = sorted(pts)
    cols = math.ceil(math.sqrt(len(garments)))
    rows = math.ceil(len(garments) / cols)
    # at least 7.5 in wide: the two-line title does not fit one 4.6 in panel
    fig, axes = plt.subplots(rows, cols, figsize=(max(4.6 * cols, 7.5), 4.2 * rows), squeeze=False)
    for ax, g in zip(axes.flat, garments):
        methods = pts[g]
        for m, p in methods.items():
            col = "black" if m == ours else colours[m]
            ax.scatter([x for x, _ in p], [y for _, y in p], s=14, facecolors="none", edgecolors=[col], lw=0.8)
            mx, my = _mean(p)
            ax.scatter([mx], [my], s=70 if m == ours else 40, marker="*" if m == ours else "o", color=col,
                       label=f"{m} ({len(p)})", zorder=3)
        for name, (x, y) in refs.get(g, {}).items():
            if x is not None and y is not None:
                ax.scatter([x], [y], marker="x", color="0.3", s=40, zorder=2)
                ax.annotate(name, (x, y), fontsize=7, color="0.3", xytext=(3, 3), textcoords="offset points")
            elif x is not None and name in ANGLE_ONLY_REFERENCES:
                ax.axvline(x, color="0.45", lw=0.8, ls=":")
                ax.annotate(name, (x, 1.0), xycoords=("data", "axes fraction"), fontsize=7, color="0.3",
                            rotation=90, va="top", ha="right")
        ys = [y for p in methods.values() for _, y in p] + [y for _, y in refs.get(g, {}).values() if y is not None]
        ax.set_ylim(0, 1.15 * max(ys) if max(ys) > 0 else 1.0)
        c = corner(methods, ours)
        if c is not None:
            (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
            ax.add_patch(Rectangle((x0, y0), c[0] - x0, c[1] - y0, color="0.9", zorder=0, lw=0))
            ax.set_xlim(x0, x1)
            ax.set_ylim(y0, y1)
        title = _short(g)
        if g in outcome:
            o = outcome[g]
            title += f": {ours} " + ("ordered first" if o["settled"] else "ordered first (provisional)"
                                     if o["won"] else "not ordered first")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(f"{LABELS[X]} (lower is better)", fontsize=8)
        ax.set_ylabel(f"{LABELS[Y]} (lower is better)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6, loc="best")
    for ax in list(axes.flat)[len(garments):]:
        ax.axis("off")
    fig.suptitle(f"The target's two figures: {ours} must lie below and left of every other method's mean\n"
                 "(shaded: below the best mean on both). Hollow: runs; filled: means; x and dotted: reference rows.",
                 fontsize=9)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def beside_table(results: list[dict], data: dict, out_dir: Path, ours: str) -> Path | None:
    """`target.png` beside a comparison table just written to `out_dir` (`data`: its JSON; the verdict in it names
    the method the intervals were taken for, which may differ from the `ours` asked for)."""
    target = data.get("target")
    return plot(results, Path(out_dir) / "target.png", (target or {}).get("ours", ours), target)
