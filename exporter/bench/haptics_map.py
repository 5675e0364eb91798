"""The friction map's cost at the sizes the planner produces (`vtkiosk bench haptics --map-sweep`).

For each model grid (square, 256..1536 px) and panel region (1280 x 800, 1920 x 1080 panel pixels) and each mapping
the kiosk ships (perceptual, calibrated), `friction_map` is timed on one thread mapped at the finer of the model's
and the panel's pixels (supersample 1, as earlier kiosks did) and on the grid `SUPERSAMPLE` times finer than the
model's (the kiosk's default): median, p95 and IQR after a warm-up, and their ratio. Beside each timing: the largest
level difference of the float32 map against the same map computed in float64 (the error of the fast path), and
the trivial reference (a map of zeros: its level difference to the float64 map) so a reader can tell small from
large. The field is a diagonal twill at 3 model pixels per period plus noise, the finest texture a model draws.
"""
from __future__ import annotations

import resource
import time
from pathlib import Path

import cv2
import numpy as np

from kiosk.contract.haptics import SUPERSAMPLE, friction_map, perceptual_constants

GRIDS = (256, 512, 768, 1024, 1536)
PANELS = ((1280, 800), (1920, 1080))
MAPPINGS = ("perceptual", "calibrated")
TWILL_PERIOD_PX = 3.0


def twill(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Slopes of a diagonal twill (the finest period a model draws) with 10 % noise, float32 (n, n)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n].astype(np.float32)
    ridge = 0.05 * np.cos(2.0 * np.pi * (x + y) / TWILL_PERIOD_PX)
    gx = (ridge + 0.005 * rng.standard_normal((n, n))).astype(np.float32)
    gy = (ridge + 0.005 * rng.standard_normal((n, n))).astype(np.float32)
    return gx, gy


def _time(kwargs: dict, runs: int) -> dict[str, float]:
    friction_map(**kwargs)
    t = []
    for _ in range(runs):
        t0 = time.perf_counter()
        friction_map(**kwargs)
        t.append(1e3 * (time.perf_counter() - t0))
    a = np.array(t)
    return {"median_ms": round(float(np.median(a)), 2), "p95_ms": round(float(np.quantile(a, 0.95)), 2),
            "iqr_ms": round(float(np.subtract(*np.quantile(a, (0.75, 0.25)))), 2)}


def sweep(runs: int, grids: tuple[int, ...] = GRIDS, panels: tuple[tuple[int, int], ...] = PANELS) -> list[dict]:
    """One row per (grid, panel, mapping); see the module docstring."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    rows = []
    try:
        for n in grids:
            gx, gy = twill(n)
            scale = 2.0 * float(np.quantile(gx * gx + gy * gy, 0.98))
            constants = perceptual_constants(gx, gy)
            for panel in panels:
                for mapping in MAPPINGS:
                    kw = {"gx": gx, "gy": gy, "scale": scale, "size": panel, "normalization": mapping,
                          "constants": constants if mapping == "perceptual" else None}
                    row = {"grid": n, "panel": list(panel), "mapping": mapping}
                    for ss in sorted({1, SUPERSAMPLE}):
                        row[f"supersample_{ss}"] = _time({**kw, "supersample": ss}, runs)
                    old, now = row["supersample_1"]["median_ms"], row[f"supersample_{SUPERSAMPLE}"]["median_ms"]
                    row["ratio"] = round(now / old, 2) if old > 0 else None
                    ref = friction_map(**kw, precision="float64").astype(np.int16)
                    row["max_level_diff_vs_float64"] = int(np.abs(friction_map(**kw).astype(np.int16) - ref).max())
                    row["max_level_diff_zeros_vs_float64"] = int(np.abs(ref).max())
                    rows.append(row)
    finally:
        cv2.setNumThreads(threads)
    return rows


def peak_rss_mib() -> float:
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)


def table(rows: list[dict]) -> str:
    head = (f"| grid | panel | mapping | ss1 median / p95 (IQR) ms | ss{SUPERSAMPLE} median / p95 (IQR) ms | "
            f"ss{SUPERSAMPLE} / ss1 | max level diff vs float64 | zeros (trivial) vs float64 |")
    lines = [head, "|" + "---|" * 8]
    for r in rows:
        a, b = r["supersample_1"], r[f"supersample_{SUPERSAMPLE}"]
        lines.append(f"| {r['grid']} | {r['panel'][0]}x{r['panel'][1]} | {r['mapping']} | "
                     f"{a['median_ms']} / {a['p95_ms']} ({a['iqr_ms']}) | {b['median_ms']} / {b['p95_ms']} "
                     f"({b['iqr_ms']}) | {r['ratio']} | {r['max_level_diff_vs_float64']} | "
                     f"{r['max_level_diff_zeros_vs_float64']} |")
    return "\n".join(lines)


def plot(rows: list[dict], out: Path) -> Path | None:
    """Median time against model grid, one line per panel, mapping and supersample; p95 as the error bar's top."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    fig, axes = plt.subplots(1, len(MAPPINGS), figsize=(6 * len(MAPPINGS), 4), sharey=True)
    for ax, mapping in zip(np.atleast_1d(axes), MAPPINGS):
        for panel in sorted({tuple(r["panel"]) for r in rows}):
            sel = [r for r in rows if r["mapping"] == mapping and tuple(r["panel"]) == panel]
            for ss, style in ((1, "--"), (SUPERSAMPLE, "-")):
                med = [r[f"supersample_{ss}"]["median_ms"] for r in sel]
                p95 = [r[f"supersample_{ss}"]["p95_ms"] for r in sel]
                ax.errorbar([r["grid"] for r in sel], med, yerr=[np.zeros(len(med)), np.subtract(p95, med)],
                            fmt=style, marker="o", capsize=3, label=f"{panel[0]}x{panel[1]}, supersample {ss}")
        ax.set(title=f"friction map, {mapping}", xlabel="model grid (px per side)", ylabel="ms (median, p95 bar)")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
