"""Speed against error: one panel per graph, p50 latency (log) against friction-map error vs fp32, a marker per
precision/provider, the size written beside it, and each size's Pareto front (nothing else there is both faster
and at least as accurate). The goal lines (90 ms at 1536 px, 1 level) are drawn for orientation."""
from __future__ import annotations

from pathlib import Path

from exporter.bench.report import GOAL_FRICTION_MAE, GOAL_P50_MS

MARKERS = {"fp32": "o", "fp16": "s", "int8": "^"}
COLOURS = {"fp32": "tab:blue", "fp16": "tab:orange", "int8": "tab:green", "torch": "tab:red"}


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats in both coordinates (lower is better in both), by latency."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], float("inf")
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def plot(rows: list[dict], out: Path, *, title: str) -> Path:
    """Write the scatter PNG. Rows without an error value (no fp32 reference) are skipped."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ImportError("--plot needs matplotlib (install vtkiosk[export])") from exc
    usable = [r for r in rows if r.get("friction_mae_levels") is not None and r.get("p50_ms")]
    graphs = sorted({r["graph"] for r in usable}, key=["full", "tactile", "visual"].index) or ["full"]
    fig, axes = plt.subplots(1, len(graphs), figsize=(6.5 * len(graphs), 5), squeeze=False)
    for ax, graph in zip(axes[0], graphs):
        sel = [r for r in usable if r["graph"] == graph]
        for r in sel:
            torch = r["provider"] == "torch-eager"
            key = "torch" if torch else r["precision"]
            ax.scatter(r["p50_ms"], r["friction_mae_levels"], marker="x" if torch else MARKERS.get(r["precision"], "o"),
                       color=COLOURS.get(key, "k"), s=45, zorder=3)
            ax.annotate(r["size"].split("x")[0], (r["p50_ms"], r["friction_mae_levels"]), fontsize=7,
                        xytext=(4, 3), textcoords="offset points")
        for size in sorted({r["size"] for r in sel}):
            at = [r for r in sel if r["size"] == size]
            idx = pareto([(r["p50_ms"], r["friction_mae_levels"]) for r in at])
            ax.plot([at[i]["p50_ms"] for i in idx], [at[i]["friction_mae_levels"] for i in idx], "-", color="0.6",
                    lw=1, zorder=2)
        ax.axhline(GOAL_FRICTION_MAE, ls="--", color="tab:red", lw=0.8)
        ax.axvline(GOAL_P50_MS, ls=":", color="tab:red", lw=0.8)
        ax.text(GOAL_P50_MS, 1.0, f" {GOAL_P50_MS:.0f} ms goal (1536 px)", transform=ax.get_xaxis_transform(),
                fontsize=7, color="tab:red", va="top")
        ax.text(1.0, GOAL_FRICTION_MAE, f"{GOAL_FRICTION_MAE:g} level goal ", transform=ax.get_yaxis_transform(),
                fontsize=7, color="tab:red", ha="right", va="bottom")
        ax.set_xscale("log")
        ax.set_xlabel("p50 latency (ms, log)")
        ax.set_ylabel("friction-map MAE vs fp32 (levels of 255)")
        ax.set_title(f"{graph} graph")
        ax.grid(True, which="both", alpha=0.3)
    handles = [plt.Line2D([], [], ls="", marker=MARKERS[p], color=COLOURS[p], label=p) for p in MARKERS]
    handles.append(plt.Line2D([], [], ls="", marker="x", color=COLOURS["torch"], label="PyTorch eager fp32"))
    handles.append(plt.Line2D([], [], color="0.6", label="Pareto front per size"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 0.95))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
