"""The planner's own settings as benchmark rows: what the kiosk actually runs for the bundle's garment.

The bundle's reference sketch is laid out on the default haptic panel (`kiosk.contract.panels`) as the attract screen
does, and the kiosk's planner (`kiosk.inference.scene.Planner`, kiosk config defaults for the resolutions) plans it
twice: the quick first answer at stroke end (preview resolution) and the refinement, at physical scale (panel pitch
against the bundle's pitch) and without it (legacy: the panel's pixels). Each plan's network input is what gets timed.

Error against the truth is measured where the truth lives, in the garment's camera frame at its training pitch (the
exporter cuts the bundle's reference assets from that frame): the plan's tactile output is mapped back from the grid
through the planner's placement and scale, so a coarser preview is charged for the texture it cannot show.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from kiosk.contract.sketch import NetworkInput


@dataclass(frozen=True)
class PlannedInput:
    """One plan: its label, graph, grid (w, h), network input, and asset px -> grid px (g = k * a + t)."""

    setting: str
    graph: str
    grid: tuple[int, int]
    input: NetworkInput
    k: float
    t: tuple[float, float]
    felt_ratio: float | None


def planned_inputs(bundle, *, max_resolution: int = 512, preview_max_resolution: int = 256) -> list[PlannedInput]:
    """The quick (preview-resolution) and refined plans of the bundle's reference sketch on the default panel, at
    physical scale and at panel pixels. `bundle`: an opened `kiosk.bundle.archive.Bundle`."""
    from kiosk.inference.engine import LoadedBundle
    from kiosk.inference.scene import Panel, Planner, Scene, SketchInput
    from kiosk.contract.panels import DEFAULT_PANEL, KNOWN_PANELS

    panel_spec = KNOWN_PANELS[DEFAULT_PANEL]
    loaded = LoadedBundle(bundle)
    scene = Scene((Panel("main", (0, 0, panel_spec.width_px, panel_spec.height_px), loaded.key,
                         sketch="reference"),), (panel_spec.width_px, panel_spec.height_px))
    out: list[PlannedInput] = []
    for physical in (True, False):
        planner = Planner(max_resolution=max_resolution, preview_max_resolution=preview_max_resolution,
                          panel_pitch_mm=panel_spec.pitch_mm if physical else None)
        scale_name = "physical scale" if physical else "panel pixels"
        for quick, what in ((True, f"preview {preview_max_resolution}"), (False, f"refine {max_resolution}")):
            plan = planner.plan(scene, {"main": SketchInput(base=True)}, {loaded.key: loaded}, quick=quick)
            p = plan.panels[0]
            if p.inputs is None or p.placement is None or p.region is None:
                continue
            k = p.placement.scale * p.scale
            t = ((p.placement.x - p.region[0]) * p.scale, (p.placement.y - p.region[1]) * p.scale)
            out.append(PlannedInput(f"planner: {what}, {scale_name}", p.graph, p.grid, p.inputs, k, t,
                                    p.felt_ratio))
    return out


def to_asset_frame(field: np.ndarray, plan: PlannedInput, shape: tuple[int, int]) -> np.ndarray:
    """A (C, H, W) grid output resampled into the asset frame of `shape` = (H, W) (linear; outside the grid: 0)."""
    k, (tx, ty) = plan.k, plan.t
    # pixel centres: g + 0.5 = k (a + 0.5) + t
    m = np.float32([[k, 0, tx + 0.5 * k - 0.5], [0, k, ty + 0.5 * k - 0.5]])
    h, w = shape
    return np.stack([cv2.warpAffine(np.ascontiguousarray(c, np.float32), m, (w, h),
                                    flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0.0)
                     for c in field])


def asset_truth(garment_dir: Path):
    """(gx, gy, mask) of the synthetic garment's full-field truth in the camera frame (where the exporter cuts the
    reference assets from), or None without `fullT/`."""
    from trainer.data.touchclothing import load_garment

    g = load_garment(Path(garment_dir))
    if g.full_tactile is None:
        return None
    (fw, fh), (ox, oy) = g.frame, g.offset
    crop = (slice(oy, oy + fh), slice(ox, ox + fw))
    return g.full_tactile.gx[crop], g.full_tactile.gy[crop], g.mask[crop]
