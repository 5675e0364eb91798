"""`--compare`: a methods x metrics table in the shape of the paper's Table 1/2 (mean over garments, best in bold),
as markdown + JSON, and a qualitative sheet per garment (sketch and ground truth, then each method's visual,
normal map, height map and friction map)."""
from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from trainer.evaluate import HIGHER_IS_BETTER, Prediction, evaluate_run
from trainer.sheets import grid, label, output_row, save_png, to_uint8

COLUMNS = [("visual_psnr", "PSNR ↑"), ("visual_ssim", "SSIM ↑"), ("visual_l1", "L1 ↓"),
           ("visual_lpips", "LPIPS ↓"), ("visual_sifid", "SIFID ↓"), ("visual_fbsifid", "FB-SIFID ↓"),
           ("tactile_mse", "T-MSE ↓"), ("tactile_angle_deg", "T-angle° ↓"), ("tactile_lpips", "T-LPIPS ↓"),
           ("tactile_sifid", "T-SIFID ↓"), ("tactile_fbsifid", "T-FB-SIFID ↓"),
           ("full_angle_deg", "Full angle° ↓"), ("full_friction_mae", "Friction MAE ↓"),
           ("full_fbsifid", "Full FB-SIFID ↓")]


def table(results: list[dict]) -> tuple[str, dict]:
    """Mean per method over its runs (garments, seeds); with several runs a cell reads `mean ± sd` (sample sd), so
    a difference can be read against the spread. Best mean per column in bold."""
    by_method: dict[str, list[dict]] = defaultdict(list)
    for r in results:
        by_method[r["method"]].append(r)
    cols = [(k, h) for k, h in COLUMNS if any(k in r for r in results)]
    values = {m: {k: [r[k] for r in rs if k in r] for k, _ in cols if any(k in r for r in rs)}
              for m, rs in by_method.items()}
    means = {m: {k: float(np.mean(v)) for k, v in row.items()} for m, row in values.items()}
    sds = {m: {k: float(np.std(v, ddof=1)) for k, v in row.items() if len(v) > 1} for m, row in values.items()}
    garments = {m: sorted({r["garment"] for r in rs}) for m, rs in by_method.items()}
    best = {}
    for k, _ in cols:
        vals = [means[m][k] for m in means if k in means[m]]
        best[k] = (max if k in HIGHER_IS_BETTER else min)(vals)
    lines = ["| method | garments | runs | " + " | ".join(h for _, h in cols) + " |",
             "|---|---|---|" + "---|" * len(cols)]
    for m, row in means.items():
        cells = []
        for k, _ in cols:
            if k not in row:
                cells.append("–")
                continue
            s = f"{row[k]:.4g}"
            s = f"**{s}**" if np.isclose(row[k], best[k]) else s
            cells.append(f"{s} ± {sds[m][k]:.2g}" if k in sds[m] else s)
        lines.append(f"| {m} | {len(garments[m])} | {len(by_method[m])} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n", {"mean": means, "sd": sds, "garments": garments, "best": best,
                                     "runs": results}


def qualitative_sheets(runs: list[Path], out_dir: Path, which: str = "best") -> list[Path]:
    per_garment: dict[str, list[Prediction]] = defaultdict(list)
    for r in runs:
        p = Prediction(r, which)
        per_garment[p.g.name].append(p)
    paths = []
    for name, preds in per_garment.items():
        p0 = preds[0]
        m = p0.crop(p0.g.mask)
        top = [label(to_uint8(p0.sketch[0, 0].numpy()), "sketch"),
               label(to_uint8(p0.visual[0].permute(1, 2, 0).numpy()), "ground truth visual")]
        rows = []
        ft = p0.g.full_tactile
        if ft is not None:
            rows.append(output_row("truth", p0.visual[0].permute(1, 2, 0).numpy(), p0.crop(ft.gx), p0.crop(ft.gy),
                                   m, float(p0.info["friction_scale"])))
        counts = Counter(p.info["method"] for p in preds)
        for p in preds:
            # several runs of one method (seeds): name each row by its run folder too
            name = p.info["method"] if counts[p.info["method"]] == 1 else f"{p.info['method']} ({p.run.name})"
            rows.append(output_row(name, p.vis[0].permute(1, 2, 0).numpy(), p.tac[0, 0].numpy(),
                                   p.tac[0, 1].numpy(), m, float(p.info["friction_scale"])))
        path = out_dir / f"sheet_{p0.g.material}.png"
        save_png(path, grid([top] + rows))
        paths.append(path)
    return paths


def compare(runs: list[Path], out_dir: Path, which: str = "best") -> tuple[str, dict]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results = [evaluate_run(r, which, swap=False) | {"run": str(r)} for r in runs]
    md, data = table(results)
    (out_dir / "compare.md").write_text(md)
    (out_dir / "compare.json").write_text(json.dumps(data, indent=2))
    data["sheets"] = [str(p) for p in qualitative_sheets(runs, out_dir, which)]
    return md, data
