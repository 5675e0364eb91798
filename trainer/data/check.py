"""`vtkiosk data check`: validate dataset folders and summarise them on one screen."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trainer.data.layout import layout_problems, looks_like_garment
from trainer.data.touchclothing import FOLDER_RE, SPLITS, DatasetError, Garment, friction_scale, load_garment, \
    valid_centres


@dataclass
class GarmentReport:
    name: str
    ok: bool
    error: str = ""
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    material: str = ""
    padded: int = 0
    frame: str = ""
    touches: dict[str, int] = field(default_factory=dict)
    centres: int = 0
    mask_pct: float = 0.0
    slope_p99: float = 0.0
    scale: float = 0.0
    full: bool = False


def check_garment(g: Garment) -> GarmentReport:
    """Consistency checks beyond what loading already enforces; problems become warnings, not failures."""
    r = GarmentReport(name=g.name, ok=True, material=g.material, padded=g.padded_size,
                      frame=f"{g.frame[0]}x{g.frame[1]}", touches=g.touch_count(), full=g.full_tactile is not None)
    r.mask_pct = 100.0 * float(g.mask.mean())
    if not g.mask.any():
        r.warnings.append("object mask is empty")
    p = g.padded_size
    slopes = []
    for split in SPLITS:
        for t in g.touches.get(split, []):
            rect = t.rect
            if rect.x < 0 or rect.y < 0 or rect.x + rect.w > p or rect.y + rect.h > p:
                r.warnings.append(f"{t.name}: rectangle outside the padded frame")
                continue
            if (rect.h, rect.w) != t.gx.shape:
                r.warnings.append(f"{t.name}: rectangle {rect.w}x{rect.h} differs from gradients {t.gx.shape[::-1]}")
            if not g.mask[min(rect.y + rect.h // 2, p - 1), min(rect.x + rect.w // 2, p - 1)]:
                r.warnings.append(f"{t.name}: rectangle centre is outside the object mask")
            r.centres += len(valid_centres(t))
            slopes.append(np.abs(np.concatenate([t.gx[t.contact], t.gy[t.contact]])))
    if slopes:
        allv = np.concatenate(slopes)
        r.slope_p99 = float(np.quantile(allv, 0.99)) if allv.size else 0.0
        if r.slope_p99 > 5:
            r.warnings.append(f"99th percentile slope {r.slope_p99:.2f} is implausibly steep (units?)")
    if g.touches.get("train"):
        r.scale = friction_scale(g)
    if g.full_tactile is not None and g.full_tactile.gx.shape != g.mask.shape:
        r.warnings.append("full-field tactile shape differs from the mask")
    return r


def garment_folders(data_dir: Path) -> list[Path]:
    """The garment folders in `data_dir` (or `data_dir` itself), including misnamed ones so their names get a fix."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise DatasetError(f"{data_dir}: no such dataset folder")
    if FOLDER_RE.match(data_dir.name) or (looks_like_garment(data_dir) and not any(
            FOLDER_RE.match(p.name) for p in data_dir.iterdir())):
        return [data_dir]
    found = sorted(p for p in data_dir.iterdir() if p.is_dir() and (FOLDER_RE.match(p.name) or looks_like_garment(p)))
    if not found:
        raise DatasetError(f"{data_dir}: no garment folders (singleskit_<Material>_padded_<P>_x1) inside; "
                           "see docs/real-garments.md for the layout")
    return found


def check_dataset(data_dir: Path) -> list[GarmentReport]:
    """One report per garment folder: every layout problem with its fix, else the loaded garment's summary."""
    reports = []
    for root in garment_folders(data_dir):
        problems = layout_problems(root)
        fatal = [str(p) for p in problems if p.fatal]
        if fatal:
            reports.append(GarmentReport(name=root.name, ok=False, error=f"{len(fatal)} problem(s), fix them first",
                                         problems=fatal))
            continue
        try:
            report = check_garment(load_garment(root))
        except DatasetError as exc:
            reports.append(GarmentReport(name=root.name, ok=False, error=str(exc)))
            continue
        report.warnings[:0] = [str(p) for p in problems]
        reports.append(report)
    return reports


def format_reports(reports: list[GarmentReport]) -> str:
    head = f"{'garment':44} {'frame':>9} {'train/val/test':>14} {'centres':>8} {'mask%':>6} " \
           f"{'p99|g|':>7} {'scale':>8} {'full':>4}  status"
    lines = [head, "-" * len(head)]
    for r in reports:
        if not r.ok:
            lines.append(f"{r.name:44} {'':>9} {'':>14} {'':>8} {'':>6} {'':>7} {'':>8} {'':>4}  FAIL: {r.error}")
            lines += [f"    problem: {p}" for p in r.problems]
            continue
        t = r.touches
        status = "ok" if not r.warnings else f"{len(r.warnings)} warning(s)"
        lines.append(f"{r.name:44} {r.frame:>9} {t.get('train', 0):>4}/{t.get('val', 0):>3}/{t.get('test', 0):>3}"
                     f"   {r.centres:>8} {r.mask_pct:6.1f} {r.slope_p99:7.3f} {r.scale:8.4f} "
                     f"{'yes' if r.full else 'no':>4}  {status}")
        lines += [f"    warning: {w}" for w in r.warnings[:5]]
        if len(r.warnings) > 5:
            lines.append(f"    ... and {len(r.warnings) - 5} more warnings")
    failed = sum(not r.ok for r in reports)
    lines.append(f"{len(reports)} garment(s), {failed} failed")
    return "\n".join(lines)
