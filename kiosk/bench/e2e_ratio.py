"""Two `vtkiosk bench e2e` settings side by side: p50 and p95 of each latency and their ratio, with a bootstrap
95 % interval over stroke ends.

These machines are noisy, so a setting is compared with another measured in the same sitting (runs interleaved
A, B, A, B) and the figure quoted is the ratio. The interval resamples each setting's stroke ends independently
(the two settings replay the same sessions, but not at the same moments of load).

    vtkiosk bench e2e-compare --a A1.json A2.json --b B1.json B2.json [--json OUT] [--plot PNG]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from kiosk.contract.errors import InputError

MIN_MS = 1e-6  # denominators below this are no latency to divide by

MEASURES = (("visual_ms", "stroke end -> visual available"),
            ("friction_ms", "stroke end -> first friction frame committed"),
            ("refine_visual_ms", "stroke end -> refined visual"),
            ("refine_friction_ms", "stroke end -> refined friction frame committed"))


def stroke_ends(paths: list[Path]) -> dict[str, np.ndarray]:
    """Each measure's values over every stroke end of the runs (None: that stroke end had no such event)."""
    out: dict[str, list[float]] = {k: [] for k, _ in MEASURES}
    for p in paths:
        try:
            finals = json.loads(Path(p).read_text())["per_final"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(f"{p}: not a `vtkiosk bench e2e --json` file ({exc})") from exc
        for f in finals:
            for k, _ in MEASURES:
                v = f.get(k)
                if v is not None and np.isfinite(v):
                    out[k].append(float(v))
    return {k: np.asarray(v, np.float64) for k, v in out.items()}


def ratio(a: np.ndarray, b: np.ndarray, q: float, *, rounds: int = 4000, seed: int = 0) -> dict:
    """The q-th percentile of a over b's, with a bootstrap 95 % interval; None where either side is empty or b's
    percentile is below `MIN_MS` (no ratio to state: a latency of a nanosecond is a clock artefact)."""
    if len(a) == 0 or len(b) == 0:
        return {"a": None, "b": None, "ratio": None, "ci": None}
    pa, pb = float(np.percentile(a, q)), float(np.percentile(b, q))
    if pb < MIN_MS:
        return {"a": pa, "b": pb, "ratio": None, "ci": None}
    rng = np.random.default_rng(seed)
    ra = np.percentile(rng.choice(a, (rounds, len(a))), q, axis=1)
    rb = np.percentile(rng.choice(b, (rounds, len(b))), q, axis=1)
    keep = rb >= MIN_MS
    if not keep.any():
        return {"a": pa, "b": pb, "ratio": pa / pb, "ci": None}
    lo, hi = np.percentile(ra[keep] / rb[keep], [2.5, 97.5])
    return {"a": pa, "b": pb, "ratio": pa / pb, "ci": [float(lo), float(hi)]}


def compare(a_paths: list[Path], b_paths: list[Path]) -> dict:
    a, b = stroke_ends(a_paths), stroke_ends(b_paths)
    return {k: {"n": [len(a[k]), len(b[k])], "p50": ratio(a[k], b[k], 50), "p95": ratio(a[k], b[k], 95)}
            for k, _ in MEASURES}


def table(res: dict, a_name: str, b_name: str) -> str:
    f = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
    r = lambda d: ("-" if d["ratio"] is None else f"{d['ratio']:.2f}"  # noqa: E731
                   + (f" [{d['ci'][0]:.2f}, {d['ci'][1]:.2f}]" if d.get("ci") else ""))
    rows = [f"| measure (ms) | n | {a_name} p50 | {b_name} p50 | ratio p50 | {a_name} p95 | {b_name} p95 | ratio p95 |",
            "|---|---|---:|---:|---:|---:|---:|---:|"]
    for k, label in MEASURES:
        d = res[k]
        rows.append(f"| {label} | {d['n'][0]} / {d['n'][1]} | {f(d['p50']['a'])} | {f(d['p50']['b'])} | "
                    f"{r(d['p50'])} | {f(d['p95']['a'])} | {f(d['p95']['b'])} | {r(d['p95'])} |")
    return "\n".join(rows)


def plot(a_paths: list[Path], b_paths: list[Path], names: tuple[str, str], out: Path) -> None:
    """Cumulative distributions of each measure, both settings on one panel per measure (matplotlib, lazily)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a, b = stroke_ends(a_paths), stroke_ends(b_paths)
    fig, axes = plt.subplots(1, len(MEASURES), figsize=(4 * len(MEASURES), 3.2), sharey=True)
    for ax, (k, label) in zip(axes, MEASURES):
        for vals, name, style in ((a[k], names[0], "-"), (b[k], names[1], "--")):
            if len(vals):
                v = np.sort(vals)
                ax.step(v, np.arange(1, len(v) + 1) / len(v), style, where="post", label=f"{name} (n={len(v)})")
        ax.set_title(label.replace("stroke end -> ", ""), fontsize=9)
        ax.set_xlabel("ms after the stroke end")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:  # a measure neither setting had draws an empty panel
            ax.legend(fontsize=7, loc="lower right")
    axes[0].set_ylabel("share of stroke ends")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None, prog: str = "vtkiosk bench e2e-compare") -> int:
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--a", type=Path, nargs="+", required=True, help="bench e2e JSON files of setting A")
    ap.add_argument("--b", type=Path, nargs="+", required=True, help="bench e2e JSON files of setting B")
    ap.add_argument("--names", nargs=2, default=("A", "B"), help="the two settings' names in the table")
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    ap.add_argument("--plot", type=Path, default=None, help="draw the latency distributions into this PNG")
    args = ap.parse_args(argv)
    try:
        res = compare(args.a, args.b)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(table(res, *args.names))
    if args.json:
        args.json.write_text(json.dumps({"a": [str(p) for p in args.a], "b": [str(p) for p in args.b],
                                         "names": list(args.names), "measures": res}, indent=1))
    if args.plot:
        plot(args.a, args.b, tuple(args.names), args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
