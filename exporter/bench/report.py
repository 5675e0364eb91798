"""The benchmark's table and its verdict on the speed and error goals (pure functions of the result rows)."""
from __future__ import annotations

GOAL_SIZE = (1536, 1536)
GOAL_P50_MS = 90.0
GOAL_SPEEDUP = 4.0
GOAL_FRICTION_MAE = 1.0
GOAL_PSNR_DB = 35.0

COLUMNS = [("setting", "setting", "{}"), ("size", "grid", "{}"), ("graph", "graph", "{}"),
           ("engine", "engine", "{}"), ("precision", "prec", "{}"), ("form", "form", "{}"),
           ("p50_ms", "p50 ms", "{:.1f}"), ("p95_ms", "p95 ms", "{:.1f}"), ("speedup_vs_torch", "x torch", "{:.2f}"),
           ("peak_rss_mb", "peak RSS MiB", "{:.0f}"), ("gmac", "GMAC", "{:.2f}"), ("graph_bytes", "graph MB", "{:.2f}"),
           ("visual_psnr_db", "PSNR dB", "{:.1f}"), ("friction_mae_levels", "friction MAE", "{:.2f}"),
           ("friction_mae_garment_levels", "in garment", "{:.2f}"), ("friction_max_levels", "friction max", "{:.0f}"),
           ("friction_felt_garment_fraction", "felt px %", "{:.1f}"), ("full_angle_deg", "GT angle deg", "{:.2f}"),
           ("full_friction_mae", "GT friction MAE", "{:.2f}")]
TEXT_COLUMNS = 6


def _cell(row: dict, key: str, fmt: str) -> str:
    v = row.get(key)
    if v is None:
        return "-"
    if key == "size" and not row.get("declared", True):
        return f"{v}*"
    if key == "graph_bytes":
        v = v / 1e6
    if key == "friction_felt_garment_fraction":   # share of garment pixels a just-noticeable step off, in per cent
        v = 100 * v
    if key == "engine" and v == "onnxruntime" and row.get("provider") not in (None, "CPUExecutionProvider"):
        return f"onnxruntime {row['provider']}"
    if key == "engine" and v == "torch":
        return "torch eager"
    return fmt.format(v)


def markdown_table(rows: list[dict]) -> str:
    """The result rows as a Markdown table (also what the command prints)."""
    head = "| " + " | ".join(h for _, h, _ in COLUMNS) + " |"
    sep = "|" + "|".join("---" if i < TEXT_COLUMNS else "---:" for i in range(len(COLUMNS))) + "|"
    lines = [head, sep]
    for r in rows:
        lines.append("| " + " | ".join(_cell(r, k, f) for k, _, f in COLUMNS) + " |")
    return "\n".join(lines)


def _label(r: dict) -> str:
    return f"{r['engine']} {r['precision']} {r['form']}"


def goals(rows: list[dict], default_precision: dict[str, str]) -> list[dict]:
    """Each goal (docs/performance.md): value, target, met (None = not measured). Speed goals take the best engine
    and graph variant whose friction error against fp32 stays within the goal; error goals take the bundle's own
    graphs, worst engine."""
    canvas = [r for r in rows if str(r.get("setting", "")).endswith("canvas") and r["engine"] not in ("torch", "flat")]
    own = [r for r in canvas if r["source"] == "bundle" and r["precision"] == default_precision.get(r["graph"])]
    out = []
    size = f"{GOAL_SIZE[0]}x{GOAL_SIZE[1]}"
    ok = [r for r in canvas if r["graph"] == "full" and r["size"] == size
          and (r.get("friction_mae_levels") is None or r["friction_mae_levels"] <= GOAL_FRICTION_MAE)]
    best = min(ok, key=lambda r: r["p50_ms"]) if ok else None
    out.append({"goal": f"full graph (both outputs) at {size}: best p50 <= {GOAL_P50_MS:.0f} ms",
                "value": best["p50_ms"] if best else None, "target": GOAL_P50_MS,
                "met": (best["p50_ms"] <= GOAL_P50_MS) if best else None,
                "note": (f"{_label(best)}; {best['p50_ms'] / GOAL_P50_MS:.1f}x the budget"
                         if best and best["p50_ms"] > GOAL_P50_MS else _label(best) if best
                         else f"{size} full graph not measured")})
    sp = best["speedup_vs_torch"] if best else None
    out.append({"goal": f"best engine >= {GOAL_SPEEDUP:.0f}x PyTorch eager fp32 (full graph, {size}, same run)",
                "target": GOAL_SPEEDUP, "value": sp, "met": (sp >= GOAL_SPEEDUP) if sp is not None else None,
                "note": _label(best) if sp is not None else "no PyTorch eager row at that size"})
    fr = [r for r in own if r.get("friction_mae_levels") is not None]
    worst = max(fr, key=lambda r: r["friction_mae_levels"]) if fr else None
    out.append({"goal": f"bundle's graphs: friction-map MAE vs fp32 <= {GOAL_FRICTION_MAE:g} level",
                "target": GOAL_FRICTION_MAE, "value": worst["friction_mae_levels"] if worst else None,
                "met": (worst["friction_mae_levels"] <= GOAL_FRICTION_MAE) if worst else None,
                "note": (f"worst: {worst['graph']} {worst['size']} {worst['engine']}" + _garment(worst))
                if worst else "no fp32 reference"})
    ps = [r for r in own if r.get("visual_psnr_db") is not None]
    worst = min(ps, key=lambda r: r["visual_psnr_db"]) if ps else None
    out.append({"goal": f"bundle's graphs: visual PSNR vs fp32 >= {GOAL_PSNR_DB:g} dB", "target": GOAL_PSNR_DB,
                "value": worst["visual_psnr_db"] if worst else None,
                "met": (worst["visual_psnr_db"] >= GOAL_PSNR_DB) if worst else None,
                "note": f"worst: {worst['graph']} {worst['size']} {worst['engine']}" if worst else "no fp32 reference"})
    return out


def _garment(row: dict) -> str:
    """The goal is stated over the whole canvas (blank paper included); say what it is over the garment alone."""
    v = row.get("friction_mae_garment_levels")
    return "" if v is None else f"; {v:.2f} in the garment"


def goal_lines(items: list[dict]) -> list[str]:
    lines = []
    for g in items:
        verdict = {True: "met", False: "MISSED", None: "not measured"}[g["met"]]
        value = "-" if g["value"] is None else f"{g['value']:.2f}"
        lines.append(f"  {verdict:12s} {g['goal']}: {value}" + (f" ({g['note']})" if g.get("note") else ""))
    return lines


def profile_lines(profile: dict, top: int = 8) -> list[str]:
    lines = [f"  profile {profile['graph']} {profile['size']} {profile['precision']}: "
             f"{profile['kernel_ms_per_run']:.0f} ms of kernels per run"]
    for op in profile["ops"][:top]:
        lines.append(f"    {op['op']:24s} {100 * op['share']:5.1f} %  {op['ms_per_run']:8.1f} ms")
    return lines
