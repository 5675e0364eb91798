"""Speed against error. `plot`: one panel per graph, p50 latency (log) against friction-map error vs fp32, colour
per engine, marker per precision and graph form, the size written beside it, and each setting's Pareto front
(nothing else there is both faster and at least as accurate); the goal lines (90 ms at 1536 px, 1 level) are drawn
for orientation. `plot_pareto`: latency against error against the ground truth, the figure that says what speed
costs in fidelity."""
from __future__ import annotations

from pathlib import Path

from exporter.bench.report import GOAL_FRICTION_MAE, GOAL_P50_MS

ENGINE_COLOURS = {"torch": "tab:red", "onnxruntime": "tab:blue", "openvino": "tab:purple"}
FORM_MARKERS = {("fp32", "native"): "o", ("fp16", "native"): "s", ("int8", "native"): "^",
                ("int8", "rewritten"): "v"}


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
    plt = _pyplot("--plot")
    usable = [r for r in rows if r.get("friction_mae_levels") is not None and r.get("p50_ms")]
    graphs = sorted({r["graph"] for r in usable}, key=["full", "tactile", "visual"].index) or ["full"]
    fig, axes = plt.subplots(1, len(graphs), figsize=(6.5 * len(graphs), 5), squeeze=False)
    for ax, graph in zip(axes[0], graphs):
        sel = [r for r in usable if r["graph"] == graph]
        for r in sel:
            torch = r["engine"] == "torch"
            ax.scatter(r["p50_ms"], r["friction_mae_levels"], color=ENGINE_COLOURS.get(r["engine"], "k"), s=45,
                       marker="x" if torch else FORM_MARKERS.get((r["precision"], r.get("form", "native")), "o"),
                       zorder=3)
            ax.annotate(r["size"].split("x")[0], (r["p50_ms"], r["friction_mae_levels"]), fontsize=7,
                        xytext=(4, 3), textcoords="offset points")
        for setting in sorted({r["setting"] for r in sel}):
            at = [r for r in sel if r["setting"] == setting]
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
    lines = [plt.Line2D([], [], color="0.6", label="Pareto front per setting")]
    return _legend_and_save(plt, fig, lines, out, title=title, fontsize=8, bottom=0.06)


def plot_pareto(rows: list[dict], out: Path, *, title: str) -> Path:
    """Latency against error against the ground truth (full-field tactile angle): left, the fixed canvases (the
    garment filling each); right, the kiosk planner's settings. Each panel draws its Pareto front over all
    engines, precisions and sizes, and the trivial answer (a flat garment) of each setting as a dashed line."""
    plt = _pyplot("--pareto")
    with_truth = [r for r in rows if r.get("full_angle_deg") is not None]
    groups = [("fixed canvases (garment filling each)", [r for r in with_truth
                                                          if str(r.get("setting", "")).endswith("canvas")]),
              ("kiosk planner settings", [r for r in with_truth if str(r.get("setting", "")).startswith("planner")])]
    groups = [g for g in groups if g[1]] or [("no ground truth", [])]
    fig, axes = plt.subplots(1, len(groups), figsize=(7 * len(groups), 5.2), squeeze=False)
    for ax, (name, sel) in zip(axes[0], groups):
        timed = [r for r in sel if r.get("p50_ms")]
        for r in timed:
            ax.scatter(r["p50_ms"], r["full_angle_deg"], color=ENGINE_COLOURS.get(r["engine"], "k"),
                       marker="x" if r["engine"] == "torch" else FORM_MARKERS.get((r["precision"], r["form"]), "o"),
                       s=40, zorder=3)
            label = r["size"].split("x")[0] if r["setting"].endswith("canvas") else \
                r["setting"].removeprefix("planner: ").replace("physical scale", "phys").replace("panel pixels", "px")
            ax.annotate(label, (r["p50_ms"], r["full_angle_deg"]), fontsize=6, xytext=(3, 2),
                        textcoords="offset points")
        idx = pareto([(r["p50_ms"], r["full_angle_deg"]) for r in timed])
        ax.plot([timed[i]["p50_ms"] for i in idx], [timed[i]["full_angle_deg"] for i in idx], "-", color="0.5",
                lw=1, zorder=2)
        flats: dict[float, list[str]] = {}
        for r in sel:
            if r["engine"] == "flat":  # settings that share a truth share one line
                flats.setdefault(round(r["full_angle_deg"], 2), []).append(r["setting"].removeprefix("planner: "))
        for angle, names in flats.items():
            ax.axhline(angle, ls="--", color="0.7", lw=0.8)
            ax.text(1.0, angle, "flat, " + (names[0] if len(names) == 1 else "every setting") + " ",
                    transform=ax.get_yaxis_transform(), fontsize=6, color="0.4", ha="right", va="bottom")
        ax.set_xscale("log")
        ax.set_xlabel("p50 latency (ms, log)")
        ax.set_ylabel("full-field tactile angle vs ground truth (deg)")
        ax.set_title(name, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    lines = [plt.Line2D([], [], color="0.5", label="Pareto front"),
             plt.Line2D([], [], color="0.7", ls="--", label="flat garment (trivial answer)")]
    return _legend_and_save(plt, fig, lines, out, title=title, fontsize=7, bottom=0.1)


def _pyplot(flag: str):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ImportError(f"{flag} needs matplotlib (install vtkiosk[export])") from exc
    return plt


def _legend_and_save(plt, fig, lines: list, out: Path, *, title: str, fontsize: int, bottom: float) -> Path:
    """One legend for the figure: engine colours, precision and form markers, then the panel's own lines."""
    handles = [plt.Line2D([], [], ls="", marker="o", color=c, label=e) for e, c in ENGINE_COLOURS.items()]
    handles += [plt.Line2D([], [], ls="", marker=mk, color="k", label=f"{p} {f}") for (p, f), mk in
                FORM_MARKERS.items()]
    fig.legend(handles=handles + lines, loc="lower center", ncol=5, fontsize=fontsize, frameon=False)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, bottom, 1, 0.95))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
