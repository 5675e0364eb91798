"""`vtkiosk bench haptics`: is the fabric felt at its true size, and can a finger tell fabrics apart?

Synthetic fabrics (trainer/data/synth_fabrics.py) have a known full-field truth. Each is drawn as a garment (a
60 x 80 mm outline at 100 %, with its cloth edge and two seams) on panels of 0.17 / 0.25 / 0.30 mm/px at 50 / 100 /
150 % size. The real planner (kiosk.inference.scene) plans it; the model's place is taken by the truth: the
fabric's gradients at the bundle's pitch on the planned grid (a perfect model draws exactly that), which then goes
through the real friction path (kiosk.inference.render: friction map, resampled to the region's panel pixels,
cropped, composed into the device frame; the bridge carries it losslessly). Two pipelines are compared:
- today: planner at screen pixels (no panel pitch), the bundle's calibrated mapping (98th percentile scale);
- new: planner at physical scale, the perceptual mapping (docs/haptics.md).
The paper's per-frame min-max mapping (quantile) is reported beside them for contrast.

Measures: felt period (spectral peak of the device frame over plain fabric, in mm, against the same measure of the
truth's friction at the bundle's pitch over the same patch of cloth); contrast (interquartile range of levels over
plain fabric in just-noticeable steps); distinguishability (FB-SIFID between the friction textures of two regions
of every fabric pair against two regions of one fabric, and the nearest-neighbour confusion matrix); pixels
inferred per plan and, with --bundle, the refined plan's graph latency at those grids (ONNX Runtime, 1 thread).
Prints tables, writes JSON and the side-by-side picture (truth | today | new at one physical scale).
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import resource
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from kiosk.bench.felt import contrast_steps, dominant_period_px, felt_scale
from exporter.bench import haptics_map
from exporter.bench.environment import environment
from exporter.bench.result_file import write_result
from exporter.errors import ExportError
from kiosk.contract.haptics import SUPERSAMPLE, calibrate_scale, friction_map, jnd_steps, perceptual_constants
from kiosk.inference.render import compose, friction_texture
from kiosk.inference.scene import Panel, Planner, Scene, SketchInput
from trainer.data.synth_fabrics import FABRICS, FabricParams, sample_fabric, texture
from trainer.data.synth_render import gradients
from trainer.data.synthetic import PITCH_MM
from trainer.texture_distance import fb_sifid

PANELS_MM = (0.17, 0.25, 0.30)
SIZES = (0.5, 1.0, 1.5)
DEFAULT_PANEL_MM, DEFAULT_SIZE = 0.17, 1.0
SCREEN = (1280, 800)
GARMENT_MM = (60.0, 80.0)      # outline (w, h) at 100 %: at 150 % it still fits a 0.17 mm/px panel
DECLARED_SIZES = ((512, 512), (768, 768))  # the exporter's default graph sizes
MAX_RESOLUTION = 768
SEAM_MM, SEAM_SIGMA_MM = 0.4, 0.8  # seam ridge height and width
FLAT_NOISES = {"flat": 0.0007, "flat-noisy": 0.0015}  # slope noise std of the flat garments (a model's residual)
PERIOD_TOLERANCE = 0.10
NYQUIST_PX = 2.0               # the shortest period a panel can show, in its own pixels
TRUTH_UPSAMPLE = 3             # the true friction texture is mapped from the truth's slopes at a third of its pitch
TRUTH_PITCH_MM = PITCH_MM / TRUTH_UPSAMPLE
MAX_TEXTURE_PERIOD_MM = 8.0    # texture is what varies within a fingertip's contact; longer is garment shape
TARGET_STEPS = 4.0
# mode: (physical planner, friction mapping, supersample of the friction map; 1 = how earlier kiosks mapped)
MODES = {"today": (False, "calibrated", 1), "paper": (False, "quantile", 1), "new": (True, "perceptual", SUPERSAMPLE)}


class HapticsBenchError(ExportError):
    """A bench run that cannot be measured as asked; the message says why."""


@dataclass(frozen=True)
class TruthBundle:
    """What the planner knows of a bundle (kiosk.inference.scene.BundleInfo) for one synthetic fabric."""

    key: str
    pixel_pitch_mm: float
    sizes: tuple[tuple[int, int], ...] = DECLARED_SIZES

    def graphs(self) -> tuple[str, ...]:
        return ("full", "tactile", "visual")

    def cap(self, kind: str) -> tuple[int, int]:
        return max(w for w, _ in self.sizes), max(h for _, h in self.sizes)

    def reference_sketch(self) -> np.ndarray:
        raise HapticsBenchError("the haptics bench draws its garments as strokes")

    def reference_bbox(self):
        raise HapticsBenchError("the haptics bench draws its garments as strokes")


def fabric_params(seed: int) -> list[FabricParams]:
    """One parameter draw per synthetic fabric, plus the flat garment (no texture)."""
    rng = np.random.default_rng(seed)
    out = [sample_fabric(f, rng) for f in FABRICS]
    out += [FabricParams(name, 1.0, 0.0, 0.8, 0.0, 0.0) for name in FLAT_NOISES]
    return out


def garment_height(params: FabricParams, mask: np.ndarray, pitch: float, seed: int) -> np.ndarray:
    """Height (mm) of a garment on a grid: fabric texture + cloth thickness at its edge + two seams."""
    shape = mask.shape
    if params.name in FLAT_NOISES:
        h = np.zeros(shape, np.float32)
    else:
        h = texture(params, shape, pitch_mm=pitch, angle_deg=0.0, rng=np.random.default_rng(seed))
    m = mask.astype(np.float32)
    edge = cv2.GaussianBlur(m, (0, 0), max(0.5 / pitch, 0.3))
    ys = np.flatnonzero(mask.any(axis=1))
    seams = np.zeros(shape, np.float32)
    if ys.size:
        rows = np.arange(shape[0], dtype=np.float32)[:, None]
        for frac in (0.12, 0.88):
            r = ys[0] + frac * (ys[-1] - ys[0])
            seams += SEAM_MM * np.exp(-0.5 * ((rows - r) * pitch / SEAM_SIGMA_MM) ** 2)
    return (h + params.thickness_mm * edge + seams * m).astype(np.float32)


def truth_gradients(params: FabricParams, mask: np.ndarray, pitch: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    gx, gy = gradients(garment_height(params, mask, pitch, seed), pitch)
    if params.name in FLAT_NOISES:
        rng = np.random.default_rng(seed + 1)
        gx = gx + rng.normal(0.0, FLAT_NOISES[params.name], gx.shape).astype(np.float32)
        gy = gy + rng.normal(0.0, FLAT_NOISES[params.name], gy.shape).astype(np.float32)
    return gx * mask, gy * mask


def calibrate(params: FabricParams, pitch: float, seed: int) -> dict:
    """The bundle's friction calibration for this fabric, as the trainer/exporter would compute it (over the
    garment's own pixels at the dataset's pitch): the 98th-percentile scale and the perceptual constants."""
    w, h = (round(v / pitch) for v in GARMENT_MM)
    pad = 16
    mask = np.zeros((h + 2 * pad, w + 2 * pad), bool)
    mask[pad:pad + h, pad:pad + w] = True
    gx, gy = truth_gradients(params, mask, pitch, seed)
    return {"scale": calibrate_scale(gx, gy, mask), "constants": perceptual_constants(gx, gy, mask)}


def outline(panel_mm: float, size: float) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """The garment's outline stroke (screen px), centred, and its rectangle (x0, y0, x1, y1)."""
    w, h = (v * size / panel_mm for v in GARMENT_MM)
    cx, cy = SCREEN[0] / 2, SCREEN[1] / 2
    x0, y0, x1, y1 = cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2
    pts = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]], np.float64)
    return pts, (x0, y0, x1, y1)


def plain_window(rect: tuple[float, float, float, float]) -> tuple[int, int, int, int]:
    """Plain fabric (x0, y0, x1, y1) in screen px: the garment's middle, away from its edge and seams, on screen."""
    x0, y0, x1, y1 = rect
    w, h = x1 - x0, y1 - y0
    a = (max(x0 + 0.2 * w, 0), max(y0 + 0.25 * h, 0), min(x1 - 0.2 * w, SCREEN[0]), min(y1 - 0.25 * h, SCREEN[1]))
    return tuple(int(round(v)) for v in a)


@dataclass
class Case:
    fabric: str
    panel_mm: float
    size: float
    mode: str
    grid: tuple[int, int]
    scale: float
    computed_pixels: int
    frame: np.ndarray           # device frame (SCREEN), uint8
    window: tuple[int, int, int, int]
    truth_levels: np.ndarray    # true friction texture over the same cloth, at TRUTH_PITCH_MM
    oracle: np.ndarray          # the true friction texture averaged over each panel pixel of the window
    truth_gx: np.ndarray
    truth_gy: np.ndarray
    map_args: dict              # the friction_map call that made the frame (for timing it)


def run_case(params: FabricParams, cal: dict, panel_mm: float, size: float, mode: str, seed: int,
             refine_grid_only: bool = True) -> Case:
    physical, normalization, supersample = MODES[mode]
    bundle = TruthBundle(f"truth-{params.name}", PITCH_MM)
    planner = Planner(max_resolution=MAX_RESOLUTION, panel_pitch_mm=panel_mm if physical else None)
    pts, rect = outline(panel_mm, size)
    scene = Scene((Panel("main", (0, 0) + SCREEN, bundle.key),), SCREEN)
    plan = planner.plan(scene, {"main": SketchInput((pts,))}, {bundle.key: bundle})
    pp = plan.panels[0]
    if pp.grid is None or pp.mask is None or pp.region is None:
        raise HapticsBenchError(f"{params.name}: the planner found no garment ({pp.reason})")
    gx, gy = truth_gradients(params, pp.mask, PITCH_MM, seed)
    tactile = np.stack([gx, gy])[None]
    tex = friction_texture("main", tactile, pp.region, pp.clip, scale=cal["scale"], normalization=normalization,
                           constants=cal["constants"] if normalization == "perceptual" else None,
                           supersample=supersample)
    frame = compose([tex] if tex is not None else [], SCREEN)
    win = plain_window(rect)
    # The same cloth on the grid: screen -> grid is (x - region x) * grid / region size.
    rx, ry, rw, rh = pp.region
    kx, ky = pp.grid[0] / rw, pp.grid[1] / rh
    g0 = (int(round((win[0] - rx) * kx)), int(round((win[1] - ry) * ky)))
    g1 = (int(round((win[2] - rx) * kx)), int(round((win[3] - ry) * ky)))
    sl = (slice(g0[1], g1[1]), slice(g0[0], g1[0]))
    tgx, tgy = gx[sl], gy[sl]
    fine = (tgx.shape[1] * TRUTH_UPSAMPLE, tgx.shape[0] * TRUTH_UPSAMPLE)
    fm = friction_map(tgx, tgy, cal["scale"], size=fine, normalization=normalization,
                      constants=cal["constants"] if normalization == "perceptual" else None)
    oracle = cv2.resize(fm.astype(np.float32), (win[2] - win[0], win[3] - win[1]), interpolation=cv2.INTER_AREA)
    map_args = {"gx": gx, "gy": gy, "scale": cal["scale"], "size": (rw, rh), "normalization": normalization,
                "constants": cal["constants"] if normalization == "perceptual" else None}
    return Case(params.name, panel_mm, size, mode, pp.grid, pp.scale, pp.computed_pixels, frame, win, fm, oracle,
                tgx, tgy, map_args)


def map_timing(c: Case, runs: int) -> dict[str, dict]:
    """Time of the friction map that made this frame (1 thread), mapped at the model's and panel's pixels
    (supersample 1, as earlier kiosks did) and as the kiosk maps now: median, p95, IQR over `runs` after a warm-up."""
    out = {}
    for ss in sorted({1, SUPERSAMPLE}):
        friction_map(**c.map_args, supersample=ss)
        t = []
        for _ in range(runs):
            t0 = time.perf_counter()
            friction_map(**c.map_args, supersample=ss)
            t.append(1e3 * (time.perf_counter() - t0))
        a = np.array(t)
        out[f"supersample_{ss}"] = {"median_ms": round(float(np.median(a)), 2),
                                    "p95_ms": round(float(np.quantile(a, 0.95)), 2),
                                    "iqr_ms": round(float(np.subtract(*np.quantile(a, (0.75, 0.25)))), 2)}
    return out


def window_of(frame: np.ndarray, win: tuple[int, int, int, int]) -> np.ndarray:
    x0, y0, x1, y1 = win
    return frame[y0:y1, x0:x1]


def _error(measured: float, true: float) -> float:
    ok = np.isfinite(measured) and np.isfinite(true) and true > 0
    return (measured - true) / true if ok else float("nan")


def period_row(c: Case, params: FabricParams) -> dict:
    """Felt period against the truth's, with the panel's Nyquist limit (a period under 2 panel px cannot be shown
    by any frame of that panel) and the oracle: the truth averaged over each panel pixel, the best frame a panel of
    that pitch can hold. An oracle that misses too says the miss is the measure's, not the kiosk's."""
    longest = MAX_TEXTURE_PERIOD_MM / c.panel_mm
    felt = dominant_period_px(window_of(c.frame, c.window).astype(np.float64), longest) * c.panel_mm
    true = dominant_period_px(c.truth_levels.astype(np.float64),
                              MAX_TEXTURE_PERIOD_MM / TRUTH_PITCH_MM) * TRUTH_PITCH_MM
    oracle = dominant_period_px(c.oracle.astype(np.float64), longest) * c.panel_mm
    err, oracle_err = _error(felt, true), _error(oracle, true)
    nyquist = NYQUIST_PX * c.panel_mm
    k = felt_scale(window_of(c.frame, c.window).astype(np.float64), c.panel_mm, c.truth_levels.astype(np.float64),
                   TRUTH_PITCH_MM, max_period_mm=MAX_TEXTURE_PERIOD_MM)
    return {"fabric": c.fabric, "panel_mm": c.panel_mm, "size": c.size, "mode": c.mode, "grid": list(c.grid),
            "scale": round(c.scale, 4), "computed_pixels": c.computed_pixels, "fabric_period_mm": params.period_mm,
            "true_friction_period_mm": round(true, 4), "felt_period_mm": round(felt, 4),
            "error": round(err, 4) if np.isfinite(err) else None,
            "nyquist_mm": round(nyquist, 4), "true_period_panel_px": round(true / c.panel_mm, 3),
            "renderable": bool(np.isfinite(true) and true >= nyquist),
            "oracle_period_mm": round(oracle, 4),
            "oracle_error": round(oracle_err, 4) if np.isfinite(oracle_err) else None,
            "spectrum_scale_error": round(k - 1.0, 4) if np.isfinite(k) else None}


def contrast_row(c: Case) -> dict:
    levels = window_of(c.frame, c.window)
    steps = jnd_steps(levels)
    return {"fabric": c.fabric, "panel_mm": c.panel_mm, "size": c.size, "mode": c.mode,
            "iqr_steps": round(contrast_steps(levels), 3), "median_steps": round(float(np.median(steps)), 3),
            "p95_steps": round(float(np.quantile(steps, 0.95)), 3),
            "median_level": float(np.median(levels)), "oracle_iqr_steps": round(contrast_steps(c.truth_levels), 3)}


def halves(c: Case) -> tuple[np.ndarray, np.ndarray]:
    w = window_of(c.frame, c.window).astype(np.float64) / 255.0
    half = w.shape[1] // 2
    side = min(half, w.shape[0])
    return w[:side, :side], w[:side, half:half + side]


def distinguishability(cases: list[Case]) -> dict:
    """FB-SIFID between region A of fabric i and region B of fabric j; separated when every between-fabric
    distance exceeds both within-fabric distances; nearest-neighbour confusion (A of i -> nearest B, and back)."""
    names = [c.fabric for c in cases]
    regions = [halves(c) for c in cases]
    n = len(cases)
    d = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            d[i, j] = fb_sifid(regions[i][0], regions[j][1])
    confusion = np.zeros((n, n), int)
    for i in range(n):
        confusion[i, int(np.argmin(d[i, :]))] += 1   # A of i against every B
        confusion[i, int(np.argmin(d[:, i]))] += 1   # B of i against every A
    pairs = []
    for i in range(n):
        for j in range(i + 1, n):
            between = min(d[i, j], d[j, i])
            within = max(d[i, i], d[j, j])
            pairs.append({"a": names[i], "b": names[j], "between": float(between), "within": float(within),
                          "separated": bool(between > within)})
    return {"fabrics": names, "distance": d.round(5).tolist(), "confusion": confusion.tolist(), "pairs": pairs,
            "all_separated": all(p["separated"] for p in pairs)}


def _within(error: float | None) -> bool:
    return error is not None and abs(error) <= PERIOD_TOLERANCE


def _miss(r: dict) -> str:
    err = "none" if r["error"] is None else f"{r['error']:+.0%}"
    oracle = "none" if r["oracle_error"] is None else f"{r['oracle_error']:+.0%}"
    return f"{r['fabric']}@{r['panel_mm']}mm/{r['size']:g}x: {err} (oracle {oracle})"


def latency(bundle_path: Path, grids: list[tuple[int, int]], runs: int) -> dict[str, dict]:
    """Tactile-graph latency of a real bundle at each grid (1 thread): median, p95, and the run-to-run spread."""
    import tempfile

    from kiosk.bundle.archive import open_bundle
    from kiosk.contract.sketch import NetworkInput
    from kiosk.inference.engine import LoadedBundle

    with tempfile.TemporaryDirectory(prefix="vtkiosk-bench-haptics-") as tmp:
        b = open_bundle(bundle_path, None, workdir=Path(tmp), allow_unsigned=True)
        lb = LoadedBundle(b, threads=1)
        kind = "tactile" if "tactile" in lb.graphs() else "full"
        out = {}
        for gw, gh in sorted(set(grids)):
            x = NetworkInput(np.zeros((1, 1, gh, gw), np.float32), np.ones((1, 1, gh, gw), np.float32))
            lb.run(kind, x)  # warm-up: session creation and first-shape allocation
            t = []
            for _ in range(runs):
                t0 = time.perf_counter()
                lb.run(kind, x)
                t.append(1e3 * (time.perf_counter() - t0))
            a = np.array(t)
            out[f"{gw}x{gh}"] = {"graph": kind, "median_ms": round(float(np.median(a)), 2),
                                 "p95_ms": round(float(np.quantile(a, 0.95)), 2),
                                 "iqr_ms": round(float(np.subtract(*np.quantile(a, (0.75, 0.25)))), 2),
                                 "runs": runs}
        lb.close()
    return out


def picture(rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]], path: Path, *, patch_mm: float = 24.0,
            px_per_mm: float = 12.0) -> None:
    """One row per fabric: true friction texture (bundle pitch) | today's device frame | new device frame, each a
    patch_mm square shown at px_per_mm (nearest neighbour, so device pixels stay visible)."""
    side = int(round(patch_mm * px_per_mm))
    label_w = 110
    tiles = []
    for name, truth, today, new in rows:
        cells = [np.full((side, label_w), 255, np.uint8)]
        cv2.putText(cells[0], name, (6, side // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.6, 0, 1, cv2.LINE_AA)
        for img, pitch in ((truth, TRUTH_PITCH_MM), (today, DEFAULT_PANEL_MM), (new, DEFAULT_PANEL_MM)):
            n = int(round(patch_mm / pitch))
            crop = img[:n, :n]
            cell = cv2.resize(crop, (side, side), interpolation=cv2.INTER_NEAREST)
            cells.append(np.pad(cell, ((2, 2), (2, 2)), constant_values=255)[2:-2, 2:-2])
        tiles.append(np.concatenate([np.concatenate([c, np.full((side, 6), 255, np.uint8)], 1) for c in cells], 1))
    head = np.full((34, tiles[0].shape[1]), 255, np.uint8)
    for k, text in enumerate(("true friction", "today (0.17 mm/px panel)", "new (0.17 mm/px panel)")):
        cv2.putText(head, text, (label_w + k * (side + 6) + 4, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 0, 1, cv2.LINE_AA)
    img = np.concatenate([head] + [np.concatenate([t, np.full((6, t.shape[1]), 255, np.uint8)], 0) for t in tiles])
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def run_bench(args) -> dict:
    env = environment()
    t_start = time.perf_counter()
    fabrics = fabric_params(args.seed)
    cals = {p.name: calibrate(p, PITCH_MM, args.seed) for p in fabrics}
    periods, contrasts, pixels = [], [], []
    default_cases: dict[str, dict[str, Case]] = {m: {} for m in MODES}
    for p in fabrics:
        for panel_mm in args.panels:
            for size in args.sizes:
                for mode in MODES:
                    default = panel_mm == DEFAULT_PANEL_MM and size == DEFAULT_SIZE
                    if mode == "paper" and not default:
                        continue  # the paper's mapping shares today's planner: only its contrast is new
                    c = run_case(p, cals[p.name], panel_mm, size, mode, args.seed)
                    if p.name not in FLAT_NOISES and mode != "paper":
                        periods.append(period_row(c, p))
                    contrasts.append(contrast_row(c))
                    if p.name == fabrics[0].name and mode != "paper":
                        pixels.append({"panel_mm": panel_mm, "size": size, "mode": mode, "grid": list(c.grid),
                                       "computed_pixels": c.computed_pixels, "region_px": list(c.map_args["size"]),
                                       "friction_map": map_timing(c, args.runs)})
                    if default:
                        default_cases[mode][p.name] = c
    textured = [p.name for p in fabrics if p.name not in FLAT_NOISES]
    dist = {m: distinguishability([default_cases[m][f] for f in textured]) for m in ("today", "new")}
    lat = None
    if args.bundle is not None:
        grids = [tuple(r["grid"]) for r in pixels]
        lat = latency(args.bundle, grids, args.runs)
        for r in pixels:
            r["latency"] = lat[f"{r['grid'][0]}x{r['grid'][1]}"]
    new_periods = [r for r in periods if r["mode"] == "new" and r["renderable"]]
    unrenderable = [r for r in periods if r["mode"] == "new" and not r["renderable"]]
    new_textured = [r for r in contrasts if r["mode"] == "new" and r["fabric"] not in FLAT_NOISES]
    flat_new = [r for r in contrasts if r["mode"] == "new" and r["fabric"] == "flat"]
    noisy_new = [r for r in contrasts if r["mode"] == "new" and r["fabric"] == "flat-noisy"]
    verdict = {
        "felt_period_max_abs_error_new": max((abs(r["error"]) for r in new_periods if r["error"] is not None),
                                             default=None),
        "felt_period_cells_within_10pct_new": f"{sum(_within(r['error']) for r in new_periods)} of {len(new_periods)}"
                                              f" renderable ({len(unrenderable)} unrenderable)",
        "oracle_cells_within_10pct": f"{sum(_within(r['oracle_error']) for r in new_periods)} of {len(new_periods)}",
        "felt_period_max_abs_error_today": max(abs(r["error"]) for r in periods
                                               if r["mode"] == "today" and r["error"] is not None),
        "felt_period_within_10pct": all(r["error"] is not None and abs(r["error"]) <= PERIOD_TOLERANCE
                                        for r in new_periods),
        "felt_period_misses_new": [_miss(r) for r in new_periods
                                   if r["error"] is None or abs(r["error"]) > PERIOD_TOLERANCE],
        "felt_period_unrenderable": [
            f"{r['fabric']}@{r['panel_mm']}mm/{r['size']:g}x: true period {r['true_friction_period_mm']:.3g} mm is "
            f"under the panel's Nyquist limit {r['nyquist_mm']:.3g} mm; felt {r['felt_period_mm']:.3g} mm"
            for r in unrenderable],
        "spectrum_scale_max_abs_error_new": max(abs(r["spectrum_scale_error"]) for r in new_periods
                                                if r["spectrum_scale_error"] is not None),
        "spectrum_scale_max_abs_error_today": max(abs(r["spectrum_scale_error"]) for r in periods
                                                  if r["mode"] == "today" and r["spectrum_scale_error"] is not None),
        "spectrum_scale_within_10pct_new": all(r["spectrum_scale_error"] is not None
                                               and abs(r["spectrum_scale_error"]) <= PERIOD_TOLERANCE
                                               for r in new_periods),
        "min_fabric_iqr_steps_new": min(r["iqr_steps"] for r in new_textured),
        "fabrics_span_4_steps": all(r["iqr_steps"] >= TARGET_STEPS for r in new_textured),
        "flat_p95_steps_new": max(r["p95_steps"] for r in flat_new),
        "flat_within_1_step": all(r["p95_steps"] <= 1.0 for r in flat_new),
        "flat_noisy_p95_steps_new": max(r["p95_steps"] for r in noisy_new),
        "all_pairs_separated_new": dist["new"]["all_separated"],
        "all_pairs_separated_today": dist["today"]["all_separated"],
    }
    if args.picture is not None:
        rows = []
        for p in fabrics:
            t, n = default_cases["today"][p.name], default_cases["new"][p.name]
            rows.append((p.name, n.truth_levels, window_of(t.frame, t.window), window_of(n.frame, n.window)))
        picture(rows, args.picture)
    env["loadavg_end"] = list(os.getloadavg())
    env["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
    env["seconds"] = round(time.perf_counter() - t_start, 1)
    return {"created_at": dt.datetime.now(dt.timezone.utc).replace(microsecond=0).isoformat(),
            "bundle_pitch_mm": PITCH_MM, "garment_mm": list(GARMENT_MM), "seed": args.seed,
            "calibration": {k: {"scale": v["scale"], "constants": v["constants"]} for k, v in cals.items()},
            "periods": periods, "contrast": contrasts, "pixels": pixels, "latency": lat,
            "distinguishability": dist, "verdict": verdict, "environment": env}


def _table(rows: list[dict], cols: list[str]) -> str:
    def cell(v):
        if isinstance(v, float):
            return f"{v:.3g}"
        return str(v)
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(cell(r.get(c)) for c in cols) + " |" for r in rows]
    return "\n".join(out)


def report(result: dict) -> str:
    lines = ["## felt period (plain fabric, spectral peak) against the true friction texture"]
    lines.append("(oracle = the true texture averaged over each panel pixel; nyquist = 2 panel px, the shortest "
                 "period the panel can show)")
    lines.append(_table(result["periods"], ["fabric", "panel_mm", "size", "mode", "grid", "true_friction_period_mm",
                                            "nyquist_mm", "felt_period_mm", "error", "oracle_error",
                                            "spectrum_scale_error"]))
    lines.append("\n## contrast over plain fabric (just-noticeable steps; oracle = truth at the bundle pitch)")
    lines.append(_table([r for r in result["contrast"] if r["panel_mm"] == DEFAULT_PANEL_MM and r["size"] == 1.0],
                        ["fabric", "mode", "iqr_steps", "median_steps", "p95_steps", "median_level",
                         "oracle_iqr_steps"]))
    for mode, d in result["distinguishability"].items():
        lines.append(f"\n## distinguishability ({mode}, {DEFAULT_PANEL_MM} mm/px, 100 %): all pairs separated = "
                     f"{d['all_separated']}")
        names = d["fabrics"]
        lines.append("| A \\ nearest B | " + " | ".join(names) + " |")
        lines.append("|" + "---|" * (len(names) + 1))
        for n, row in zip(names, d["confusion"]):
            lines.append(f"| {n} | " + " | ".join(str(v) for v in row) + " |")
        bad = [f"{p['a']}/{p['b']}" for p in d["pairs"] if not p["separated"]]
        if bad:
            lines.append("not separated: " + ", ".join(bad))
    lines.append("\n## pixels inferred per refined plan (and tactile-graph latency with --bundle); friction map "
                 f"time at the region's panel pixels, supersample 1 (earlier kiosks) and {SUPERSAMPLE} (now)")
    rows = []
    for r in result["pixels"]:
        lat = r.get("latency") or {}
        fm = r["friction_map"]
        old, now = fm["supersample_1"], fm[f"supersample_{SUPERSAMPLE}"]
        rows.append({**r, "median_ms": lat.get("median_ms"), "p95_ms": lat.get("p95_ms"),
                     "iqr_ms": lat.get("iqr_ms"),
                     "map_ms_ss1": f"{old['median_ms']:.3g} (p95 {old['p95_ms']:.3g}, IQR {old['iqr_ms']:.2g})",
                     f"map_ms_ss{SUPERSAMPLE}": f"{now['median_ms']:.3g} (p95 {now['p95_ms']:.3g}, "
                                                f"IQR {now['iqr_ms']:.2g})"})
    lines.append(_table(rows, ["panel_mm", "size", "mode", "grid", "computed_pixels", "median_ms", "p95_ms",
                               "iqr_ms", "region_px", "map_ms_ss1", f"map_ms_ss{SUPERSAMPLE}"]))
    lines.append("\n## verdict")
    lines += [f"- {k}: {v}" for k, v in result["verdict"].items()]
    env = result["environment"]
    lines.append(f"\n{env['cpu']} ({', '.join(env['isa'])}), peak RSS {env['peak_rss_mb']} MB, {env['seconds']} s, "
                 f"load average {env['loadavg_start'][0]:.2f} -> {env['loadavg_end'][0]:.2f}")
    return "\n".join(lines)


def _floats(text: str) -> tuple[float, ...]:
    try:
        out = tuple(float(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers; got {text!r}") from None
    if not out or not all(0.01 <= v <= 10 for v in out):
        raise argparse.ArgumentTypeError(f"expected numbers from 0.01 to 10; got {text!r}")
    return out


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("--panels", type=_floats, default=PANELS_MM, help="panel pitches in mm/px (default 0.17,0.25,0.3)")
    p.add_argument("--sizes", type=_floats, default=SIZES, help="drawing sizes as fractions (default 0.5,1,1.5)")
    p.add_argument("--seed", type=int, default=0, help="fabric parameter draw")
    p.add_argument("--bundle", type=Path, default=None, help="a real bundle to time the refined plans' graphs with")
    p.add_argument("--runs", type=int, default=5, help="timed runs per grid and per friction map (after one warm-up)")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--map-sweep", action="store_true",
                   help="only time the friction map at the planner's grid and panel sizes, supersample 1 vs "
                        f"{SUPERSAMPLE}, with its float32 error (exporter/bench/haptics_map.py)")
    p.add_argument("--plot", type=Path, default=None, help="PNG of the --map-sweep timings")
    p.add_argument("--picture", type=Path, default=None, help="PNG: truth | today | new at one physical scale")
    return p


def main(argv: list[str], prog: str = "vtkiosk bench haptics") -> int:
    args = build_parser(prog).parse_args(argv)
    if args.runs < 1:
        raise HapticsBenchError("--runs must be at least 1")
    if args.map_sweep:
        return map_sweep(args)
    if DEFAULT_PANEL_MM not in args.panels or DEFAULT_SIZE not in args.sizes:
        raise HapticsBenchError(f"--panels must include {DEFAULT_PANEL_MM} and --sizes 1 (the default garment)")
    if args.bundle is not None and not args.bundle.exists():
        raise HapticsBenchError(f"{args.bundle}: no such bundle")
    result = run_bench(args)
    print(report(result))
    write_result(args.json, result)
    if args.picture is not None:
        print(f"wrote {args.picture}")
    return 0


def map_sweep(args) -> int:
    env = environment()
    rows = haptics_map.sweep(args.runs)
    result = {"environment": env, "runs": args.runs, "threads": 1, "rows": rows,
              "peak_rss_mib": haptics_map.peak_rss_mib(), "loadavg_end": list(os.getloadavg())}
    print(f"friction map, {args.runs} runs after a warm-up, 1 thread; {env['cpu']} ({' '.join(env['isa'])}); "
          f"load {env['loadavg_start'][0]:.1f} -> {result['loadavg_end'][0]:.1f}; "
          f"peak RSS {result['peak_rss_mib']} MiB")
    print(haptics_map.table(rows))
    write_result(args.json, result)
    if args.plot is not None:
        print(f"wrote {args.plot}" if haptics_map.plot(rows, args.plot) else "no plot: matplotlib is not installed")
    return 0
