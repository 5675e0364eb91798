"""The scene planner: model only what the scene needs.

A `Scene` says what the screen shows: panels, each a screen rectangle with a garment bundle, a sketch source, and
which modalities it shows from which source (the model, the bundle's reference image, or nothing). `Planner.plan`
turns a scene plus the panels' sketches into the work, per panel:

- graph: `full` when the panel shows the model's visual and tactile, `visual` or `tactile` when only one, `none`
  when nothing comes from the model (the A/B study shows reference visuals with model tactile: `tactile` only).
  Modalities already in the output cache are not recomputed, so a visual cached by the last preview turns a
  `full` run into a `tactile` one.
- region: the object's bounding box (filled outer contour, `kiosk.contract.sketch.object_mask`, found on a coarse raster of
  the panel) plus `margin_px`, rounded so the network grid is a multiple of 256 (every exported graph needs that).
- resolution, at physical scale (the planner knows the panel's pitch, `panel_pitch_mm`): one model pixel covers
  the bundle's pitch (`pixel_pitch_mm`, what its model learned at) on this panel, so grid px per screen px =
  panel pitch / bundle pitch and a 2 mm weave is felt as 2 mm on any panel and at any drawing size. Each grid side
  is rounded up to the sizes the graphs take (multiples of 256), the region growing with background, so rounding
  never changes the scale. When the object needs more than the bundle's largest declared size (or
  `inference.max_resolution`) allows, the scale drops to what fits, the texture is felt coarser than the fabric,
  and the planner logs one warning per bundle and cause. Previews and the quick first answer at stroke end use
  `preview_max_resolution` and may drop the scale the same way (silently: the refinement restores it). A quick
  answer whose texture would be felt more than `QUICK_FELT_TOLERANCE` coarser leaves the friction to the refinement
  (`quick_tactile: at-scale`, `PanelPlan.deferred`): a finger lifted at the stroke's end rarely comes back to feel
  within the ~100 ms the refinement takes.
- resolution, without a panel pitch (legacy): the panel's own pixels (scale <= 1), capped as above; a grid side is
  rounded down to a multiple of 256 when that costs at most `MAX_ROUNDING_LOSS` of linear resolution, else up.
- reuse: the cache key is the network input's content (sketch and mask bytes at the grid) + grid + bundle +
  modality; the region's position on screen is not part of it because the network input does not depend on it.

Incremental regions (recomputing only the window around a stroke) are not used: the U-Net's bottleneck sees the
whole grid and InstanceNorm statistics are global, so a window result differs from the whole-grid result by far
more than the int8 error (measured by `vtkiosk bench e2e`, see docs/performance.md); an edit recomputes the
object's region, and everything unchanged comes from the cache.

Coordinates: screen pixels, x = column from the left, y = row from the top; rectangles are (x, y, w, h).
"""
from __future__ import annotations

import hashlib
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np

from kiosk.contract.errors import InputError
from kiosk.contract.graph import GRID_MULTIPLE
from kiosk.contract.sketch import INK, LINE_PX, PAPER, NetworkInput, network_input, object_mask, rasterize

PLAN_SIDE = 320          # the coarse raster that finds the object's bounding box: longest side in pixels
MAX_ROUNDING_LOSS = 0.15  # rounding a grid side down may lose at most this much linear resolution
REFERENCE_FILL = 0.8     # a reference sketch fills this fraction of its panel (the rest is margin)
GAP_FRACTION = 0.08      # outline gaps up to 8 % of the panel's shorter side are closed (kiosk.contract.sketch default)
FINE_MAX_GAP = 11        # at the network grid only gaps up to this are closed; larger ones come from the coarse mask
QUICK_FELT_TOLERANCE = 1.1  # a quick answer whose texture would be felt more than this much coarser defers tactile
QUICK_TACTILE = ("at-scale", "always")
VISUAL_SOURCES = ("model", "reference", "none")
TACTILE_SOURCES = ("model", "none")
SKETCH_SOURCES = ("strokes", "reference")
HALVES = ("full", "left", "right")
GRAPHS = ("full", "tactile", "visual", "none")

Rect = tuple[int, int, int, int]
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Panel:
    """One screen rectangle showing one garment. `half` crops the garment to its left or right half (A/B study)."""

    id: str
    rect: Rect
    bundle: str
    visual: str = "model"
    tactile: str = "model"
    sketch: str = "strokes"
    half: str = "full"

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id or len(self.id) > 64:
            raise InputError("panel id must be a non-empty string of at most 64 characters")
        if not (isinstance(self.rect, tuple) and len(self.rect) == 4
                and all(isinstance(v, int) and not isinstance(v, bool) for v in self.rect)):
            raise InputError(f"panel {self.id}: rect must be (x, y, w, h) integers; got {self.rect!r}")
        x, y, w, h = self.rect
        if not (1 <= w <= 16384 and 1 <= h <= 16384 and -16384 <= x <= 16384 and -16384 <= y <= 16384):
            raise InputError(f"panel {self.id}: rect {self.rect} is out of range (1..16384 px sides)")
        for name, allowed in (("visual", VISUAL_SOURCES), ("tactile", TACTILE_SOURCES),
                              ("sketch", SKETCH_SOURCES), ("half", HALVES)):
            if getattr(self, name) not in allowed:
                raise InputError(f"panel {self.id}: {name} must be one of {', '.join(allowed)}; "
                                 f"got {getattr(self, name)!r}")

    @property
    def needs(self) -> tuple[str, ...]:
        """The modalities this panel needs from the model."""
        return tuple(m for m, src in (("visual", self.visual), ("tactile", self.tactile)) if src == "model")


@dataclass(frozen=True)
class Scene:
    panels: tuple[Panel, ...]
    screen: tuple[int, int]

    def __post_init__(self) -> None:
        if not self.panels or len(self.panels) > 16:
            raise InputError("a scene has 1 to 16 panels")
        ids = [p.id for p in self.panels]
        if len(set(ids)) != len(ids):
            raise InputError(f"panel ids must be unique; got {ids}")
        w, h = self.screen
        if not (1 <= w <= 16384 and 1 <= h <= 16384):
            raise InputError(f"screen size {self.screen} is out of range")


@dataclass(frozen=True)
class SketchInput:
    """What a panel's sketch is made of: touch strokes (each (N, 2) float, screen pixels) over, optionally, the
    garment's own reference sketch laid out in the panel (`base`)."""

    strokes: tuple[np.ndarray, ...] = ()
    base: bool = False


class BundleInfo(Protocol):
    """What the planner needs to know about a loaded bundle (`kiosk.inference.engine.LoadedBundle` provides it)."""

    key: str
    pixel_pitch_mm: float

    def graphs(self) -> tuple[str, ...]: ...
    def cap(self, kind: str) -> tuple[int, int]: ...
    def reference_sketch(self) -> np.ndarray: ...
    def reference_bbox(self) -> Rect: ...


@dataclass(frozen=True)
class Placement:
    """Where the bundle's reference assets land on screen: asset pixel (u, v) -> (u * scale + x, v * scale + y)."""

    scale: float
    x: float
    y: float
    size: tuple[int, int]  # asset (width, height)

    @property
    def rect(self) -> Rect:
        return (round(self.x), round(self.y), round(self.size[0] * self.scale), round(self.size[1] * self.scale))

    def to_json(self) -> dict:
        return {"scale": self.scale, "x": self.x, "y": self.y, "rect": list(self.rect)}


@dataclass
class PanelPlan:
    """The work for one panel. `inputs` (network input at the grid) is not serialised."""

    panel: str
    bundle: str
    graph: str
    needs: tuple[str, ...]
    reused: tuple[str, ...] = ()
    region: Rect | None = None
    grid: tuple[int, int] | None = None
    scale: float = 0.0
    cache_key: str | None = None
    reason: str = ""
    clip: Rect = (0, 0, 0, 0)
    placement: Placement | None = None
    computed_pixels: int = 0
    naive_pixels: int = 0
    refine_grid: tuple[int, int] | None = None  # quick plans: the grid a full-resolution plan would use
    target_scale: float | None = None  # physical scale: grid px per screen px at which texture is felt true
    felt_ratio: float | None = None    # felt / true texture size (1.0 at physical scale; > 1 coarser)
    deferred: tuple[str, ...] = ()     # quick plans: modalities left to the refinement (the device keeps its frame)
    inputs: NetworkInput | None = field(default=None, repr=False)
    mask: np.ndarray | None = field(default=None, repr=False)

    @property
    def outputs(self) -> tuple[str, ...]:
        """What the planned graph computes."""
        return {"full": ("visual", "tactile"), "visual": ("visual",), "tactile": ("tactile",)}.get(self.graph, ())

    def to_json(self) -> dict:
        return {"panel": self.panel, "bundle": self.bundle, "graph": self.graph, "needs": list(self.needs),
                "reused": list(self.reused), "region": list(self.region) if self.region else None,
                "grid": list(self.grid) if self.grid else None, "scale": round(self.scale, 4),
                "cache_key": self.cache_key, "reason": self.reason, "clip": list(self.clip),
                "placement": self.placement.to_json() if self.placement else None,
                "computed_pixels": self.computed_pixels, "naive_pixels": self.naive_pixels,
                "refine_grid": list(self.refine_grid) if self.refine_grid else None,
                "target_scale": None if self.target_scale is None else round(self.target_scale, 4),
                "felt_ratio": None if self.felt_ratio is None else round(self.felt_ratio, 4),
                "deferred": list(self.deferred)}


@dataclass
class Plan:
    panels: list[PanelPlan]
    preview: bool
    quick: bool = False
    rasterize_ms: float = 0.0
    plan_ms: float = 0.0

    @property
    def refinable(self) -> bool:
        """A quick plan whose result a full-resolution plan would improve."""
        return self.quick and any(p.refine_grid is not None and p.refine_grid != p.grid for p in self.panels)

    @property
    def computed_pixels(self) -> int:
        return sum(p.computed_pixels for p in self.panels)

    @property
    def naive_pixels(self) -> int:
        return sum(p.naive_pixels for p in self.panels)

    def to_json(self) -> dict:
        return {"preview": self.preview, "quick": self.quick, "refinable": self.refinable,
                "panels": [p.to_json() for p in self.panels],
                "computed_pixels": self.computed_pixels, "naive_pixels": self.naive_pixels,
                "rasterize_ms": round(self.rasterize_ms, 3), "plan_ms": round(self.plan_ms, 3)}


# -- pure geometry ---------------------------------------------------------------------------------------------------

def choose_graph(needs: Sequence[str], available: Sequence[str]) -> str:
    """The cheapest graph that computes `needs`: a single-branch graph when one modality is needed (asking the
    two-output graph for one output would still run both branches), `full` for both or when the bundle has no
    one-branch graph (a single-branch model: one modality costs as much as both), `none` for nothing."""
    want = set(needs)
    if not want:
        return "none"
    if want == {"visual", "tactile"}:
        order = ["full"]
    else:
        order = [next(iter(want)), "full"]
    for kind in order:
        if kind in available:
            return kind
    raise InputError(f"the bundle has no graph that computes {', '.join(sorted(want))} "
                     f"(has: {', '.join(available)})")


def _round_options(side: float, cap: int) -> list[int]:
    lo = max(GRID_MULTIPLE, int(side // GRID_MULTIPLE) * GRID_MULTIPLE)
    hi = max(GRID_MULTIPLE, int(math.ceil(side / GRID_MULTIPLE)) * GRID_MULTIPLE)
    return sorted({min(lo, cap), min(hi, cap)})


def grid_for(box: tuple[float, float], cap: tuple[int, int]) -> tuple[tuple[int, int], float]:
    """Network grid (multiples of 256, within `cap`) and scale (grid px per screen px, <= 1) for a box of
    (w, h) screen pixels. Keeps the panel's resolution unless the cap forces less; rounds a side down only when
    that loses at most MAX_ROUNDING_LOSS of resolution."""
    bw, bh = max(float(box[0]), 1.0), max(float(box[1]), 1.0)
    cw, ch = cap
    if cw < GRID_MULTIPLE or ch < GRID_MULTIPLE or cw % GRID_MULTIPLE or ch % GRID_MULTIPLE:
        raise InputError(f"resolution cap {cap} must be multiples of {GRID_MULTIPLE}")
    s0 = min(1.0, cw / bw, ch / bh)
    best: tuple[int, float, tuple[int, int]] | None = None
    for gw in _round_options(bw * s0, cw):
        for gh in _round_options(bh * s0, ch):
            s = min(1.0, gw / bw, gh / bh)
            if s < (1.0 - MAX_ROUNDING_LOSS) * s0 - 1e-9:
                continue
            cand = (gw * gh, -s, (gw, gh))
            if best is None or cand < best:
                best = cand
    assert best is not None, "rounding up always keeps the full scale"
    return best[2], -best[1]


def physical_grid(box: tuple[float, float], target: float, cap: tuple[int, int]) -> tuple[tuple[int, int], float]:
    """Network grid and scale for a box of (w, h) screen pixels at the physical scale `target` (grid px per screen
    px): each side rounded up to a multiple of 256 (the region grows, the scale stays). When that exceeds `cap`, the
    largest scale whose grid fits (the texture is then felt target/scale times coarser)."""
    bw, bh = max(float(box[0]), 1.0), max(float(box[1]), 1.0)
    cw, ch = cap
    if cw < GRID_MULTIPLE or ch < GRID_MULTIPLE or cw % GRID_MULTIPLE or ch % GRID_MULTIPLE:
        raise InputError(f"resolution cap {cap} must be multiples of {GRID_MULTIPLE}")
    if not (target > 0 and math.isfinite(target)):
        raise InputError(f"physical scale must be a positive finite number; got {target!r}")
    s = min(float(target), cw / bw, ch / bh)
    # ceil with a tolerance: bw * s may land a hair above a multiple of 256 through rounding
    gw = min(cw, max(GRID_MULTIPLE, int(math.ceil(bw * s / GRID_MULTIPLE - 1e-9)) * GRID_MULTIPLE))
    gh = min(ch, max(GRID_MULTIPLE, int(math.ceil(bh * s / GRID_MULTIPLE - 1e-9)) * GRID_MULTIPLE))
    return (gw, gh), s


def place_region(box: tuple[float, float, float, float], size: tuple[int, int], clip: Rect) -> Rect:
    """A region of `size` that covers `box` (x0, y0, x1, y1), centred on it, shifted towards the inside of `clip`
    as far as it still covers the box (computed pixels then show on screen)."""
    out = []
    for lo, hi, n, c0, cn in ((box[0], box[2], size[0], clip[0], clip[2]), (box[1], box[3], size[1], clip[1], clip[3])):
        v = (lo + hi) / 2.0 - n / 2.0
        cover_lo, cover_hi = hi - n, lo          # positions that still cover [lo, hi]
        inside_lo, inside_hi = c0, c0 + cn - n   # positions inside the clip
        a, b = max(cover_lo, inside_lo), min(cover_hi, inside_hi)
        if a <= b:
            v = min(max(v, a), b)
        out.append(int(round(v)))
    return (out[0], out[1], int(size[0]), int(size[1]))


def reference_placement(panel: Panel, asset_size: tuple[int, int], bbox: Rect) -> Placement:
    """Lay the garment's reference assets into the panel: the object's bounding box (or its left/right half)
    scaled to fill REFERENCE_FILL of the panel, centred; a half is cut at the garment's centre line, which is put
    on the panel's inner edge (left half: right edge), so two half panels side by side show one garment."""
    bx, by, bw, bh = bbox
    half_w = bw / 2.0 if panel.half in ("left", "right") else bw
    px, py, pw, ph = panel.rect
    s = REFERENCE_FILL * min(pw / max(half_w, 1.0), ph / max(bh, 1.0))
    centre_line = bx + bw / 2.0
    if panel.half == "left":
        x = px + pw - centre_line * s
    elif panel.half == "right":
        x = px - centre_line * s
    else:
        x = px + pw / 2.0 - centre_line * s
    y = py + ph / 2.0 - (by + bh / 2.0) * s
    return Placement(s, x, y, asset_size)


@dataclass(frozen=True)
class Transform:
    """Screen -> raster: (x - x0) * kx, (y - y0) * ky; the raster is `size` = (width, height)."""

    x0: float
    y0: float
    kx: float
    ky: float
    size: tuple[int, int]


def render_sketch(sketch: SketchInput, t: Transform, base: np.ndarray | None, placement: Placement | None, *,
                  width_px: int = LINE_PX) -> np.ndarray:
    """The panel's sketch on the raster `t`: the reference sketch (resampled by area, re-binarised so lines
    survive) under the strokes (rasterized there with `kiosk.contract.sketch.rasterize`, the contract)."""
    w, h = t.size
    canvas = np.full((h, w), PAPER, np.uint8)
    if sketch.base and base is not None and placement is not None:
        sx, sy = placement.scale * t.kx, placement.scale * t.ky
        bh_, bw_ = base.shape
        nw, nh = max(1, round(bw_ * sx)), max(1, round(bh_ * sy))
        interp = cv2.INTER_AREA if sx < 1 else cv2.INTER_NEAREST
        scaled = cv2.resize(base, (nw, nh), interpolation=interp)
        scaled = np.where(scaled < 224, INK, PAPER).astype(np.uint8)
        ox, oy = round((placement.x - t.x0) * t.kx), round((placement.y - t.y0) * t.ky)
        x0, y0, x1, y1 = max(ox, 0), max(oy, 0), min(ox + nw, w), min(oy + nh, h)
        if x0 < x1 and y0 < y1:
            canvas[y0:y1, x0:x1] = np.minimum(canvas[y0:y1, x0:x1], scaled[y0 - oy:y1 - oy, x0 - ox:x1 - ox])
    strokes = []
    for s in sketch.strokes:
        pts = np.asarray(s, np.float64)[:, :2]
        strokes.append(np.stack([(pts[:, 0] - t.x0) * t.kx, (pts[:, 1] - t.y0) * t.ky], axis=1))
    if strokes:
        canvas = rasterize(strokes, (w, h), width_px=width_px, base=canvas)
    return canvas


def _mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    ys = np.flatnonzero(mask.any(axis=1))
    xs = np.flatnonzero(mask.any(axis=0))
    if ys.size == 0:
        return None
    return int(xs[0]), int(ys[0]), int(xs[-1]) + 1, int(ys[-1]) + 1


def content_key(bundle_key: str, grid: tuple[int, int], sketch: np.ndarray, mask: np.ndarray) -> str:
    h = hashlib.blake2b(digest_size=16)
    h.update(f"{bundle_key}|{grid[0]}x{grid[1]}|".encode())
    h.update(np.ascontiguousarray(sketch).tobytes())
    h.update(np.packbits(mask).tobytes())
    return h.hexdigest()


def naive_pixels(panel: Panel) -> int:
    """The baseline the planner is measured against: the full graph over the whole panel at its pixels."""
    _, _, w, h = panel.rect
    return int(math.ceil(w / GRID_MULTIPLE) * GRID_MULTIPLE * math.ceil(h / GRID_MULTIPLE) * GRID_MULTIPLE)


class Planner:
    """Plans scenes for the daemon. `cached(key, modality) -> bool` tells what the output cache holds."""

    def __init__(self, *, max_resolution: int = 512, preview_max_resolution: int = 256, margin_px: int = 16,
                 cached: Callable[[str, str], bool] | None = None, panel_pitch_mm: float | None = None,
                 quick_tactile: str = "at-scale"):
        """`panel_pitch_mm`: the screen's physical pitch (mm per screen pixel, from the kiosk config's panel);
        None plans at screen pixels (legacy, the texture's felt size then depends on the panel).
        `quick_tactile`: at-scale computes friction in a quick answer only when its grid is at the physical scale
        (felt at most QUICK_FELT_TOLERANCE coarser) or no refinement would come closer; the refinement brings it
        otherwise. always: every quick answer carries friction, at whatever scale its grid allows. Without a panel
        pitch there is no physical scale to miss, and every quick answer carries friction."""
        if quick_tactile not in QUICK_TACTILE:
            raise InputError(f"quick_tactile must be one of {', '.join(QUICK_TACTILE)}; got {quick_tactile!r}")
        self.quick_tactile = quick_tactile
        if panel_pitch_mm is not None and not (isinstance(panel_pitch_mm, (int, float))
                                               and math.isfinite(panel_pitch_mm) and panel_pitch_mm > 0):
            raise InputError(f"panel pitch must be a positive number of mm per pixel; got {panel_pitch_mm!r}")
        self.max_resolution = max_resolution
        self.preview_max_resolution = preview_max_resolution
        self.margin_px = margin_px
        self.cached = cached or (lambda key, modality: False)
        self.panel_pitch_mm = panel_pitch_mm
        self.warned: set[tuple[str, str]] = set()

    def target_scale(self, bundle: BundleInfo) -> float | None:
        """Grid px per screen px at which one model pixel covers the bundle's pitch on this panel."""
        pitch = getattr(bundle, "pixel_pitch_mm", None)
        if self.panel_pitch_mm is None or not pitch:
            return None
        return self.panel_pitch_mm / float(pitch)

    def _warn_once(self, bundle: BundleInfo, cause: str, msg: str) -> None:
        if (bundle.key, cause) not in self.warned:
            self.warned.add((bundle.key, cause))
            log.warning("%s", msg)

    def plan(self, scene: Scene, sketches: Mapping[str, SketchInput], bundles: Mapping[str, BundleInfo], *,
             preview: bool = False, quick: bool = False) -> Plan:
        """`preview`: while drawing (visual only, preview resolution). `quick`: every modality, but at the preview
        resolution (the first answer at stroke end; `refine_grid` says what a full-resolution plan would use)."""
        out = Plan([], preview, quick and not preview)
        for panel in scene.panels:
            bundle = bundles.get(panel.bundle)
            if bundle is None:
                raise InputError(f"no garment {panel.bundle!r} is installed (have: {', '.join(sorted(bundles))})")
            sketch = sketches.get(panel.id, SketchInput(base=panel.sketch == "reference"))
            if panel.sketch == "reference":
                sketch = SketchInput(sketch.strokes, base=True)
            out.panels.append(self._plan_panel(panel, scene, sketch, bundle, preview, out.quick, out))
        return out

    def _defer_tactile(self, quick: bool, needs: tuple[str, ...], felt_ratio: float, refinable: bool) -> bool:
        """Leave friction to the refinement? Only in a quick plan that also shows a visual (a tactile-only panel
        keeps its quick friction), when the quick grid feels the texture too coarse and the refinement's is larger."""
        return (quick and self.quick_tactile == "at-scale" and "tactile" in needs and len(needs) > 1
                and refinable and felt_ratio > QUICK_FELT_TOLERANCE)

    def _cap(self, bundle: BundleInfo, kind: str, preview: bool) -> tuple[int, int]:
        limit = self.preview_max_resolution if preview else self.max_resolution
        bw, bh = bundle.cap(kind)
        return (max(GRID_MULTIPLE, min(bw, limit) // GRID_MULTIPLE * GRID_MULTIPLE),
                max(GRID_MULTIPLE, min(bh, limit) // GRID_MULTIPLE * GRID_MULTIPLE))

    def _plan_panel(self, panel: Panel, scene: Scene, sketch: SketchInput, bundle: BundleInfo, preview: bool,
                    quick: bool, acc: Plan) -> PanelPlan:
        t0 = time.perf_counter()
        sw, sh = scene.screen
        px, py, pw, ph = panel.rect
        # What is visible: the panel, clipped to the screen.
        cx0, cy0 = max(px, 0), max(py, 0)
        cx1, cy1 = min(px + pw, sw), min(py + ph, sh)
        clip = (cx0, cy0, max(0, cx1 - cx0), max(0, cy1 - cy0))
        needs = panel.needs
        if preview:
            needs = tuple(m for m in needs if m == "visual")  # while drawing: see it now, feel it at stroke end
        placement = None
        base = None
        if sketch.base or panel.visual == "reference":
            base = bundle.reference_sketch()
            placement = reference_placement(panel, (base.shape[1], base.shape[0]), bundle.reference_bbox())
        pp = PanelPlan(panel.id, panel.bundle, "none", needs, clip=clip, placement=placement,
                       naive_pixels=naive_pixels(panel))
        if not needs:
            pp.reason = "nothing on this panel comes from the model"
            return pp
        if clip[2] == 0 or clip[3] == 0:
            pp.reason = "the panel is off screen"
            return pp
        # 1. The object's bounding box, on a coarse raster of the panel (and of the whole reference garment when
        #    the panel shows only part of it, so its outline stays closed).
        ax, ay, aw, ah = px, py, pw, ph
        if placement is not None and sketch.base:
            qx, qy, qw, qh = placement.rect
            ax, ay = min(px, qx), min(py, qy)
            aw, ah = max(px + pw, qx + qw) - ax, max(py + ph, qy + qh) - ay
        k = min(1.0, PLAN_SIDE / max(aw, ah))
        coarse = Transform(ax, ay, k, k, (max(1, math.ceil(aw * k)), max(1, math.ceil(ah * k))))
        t1 = time.perf_counter()
        raster = render_sketch(sketch, coarse, base, placement, width_px=1)
        t2 = time.perf_counter()
        acc.rasterize_ms += 1e3 * (t2 - t1)
        gap = max(3, round(GAP_FRACTION * min(pw, ph) * k))
        coarse_mask = object_mask(raster, max_gap_px=gap)
        box = _mask_bbox(coarse_mask)
        if box is None:
            pp.reason = "no closed outline yet (nothing to synthesise)"
            acc.plan_ms += 1e3 * (time.perf_counter() - t0 - (t2 - t1))
            return pp
        m = self.margin_px
        x0, y0 = ax + box[0] / k - m, ay + box[1] / k - m
        x1, y1 = ax + box[2] / k + m, ay + box[3] / k + m
        # 2. Graph: what is needed and not cached. 3. Grid and region.
        kind0 = choose_graph(needs, bundle.graphs())
        extent = (x1 - x0, y1 - y0)
        target = self.target_scale(bundle)
        if target is None:
            grid, scale = grid_for(extent, self._cap(bundle, kind0, preview or quick))
            if quick:
                pp.refine_grid = grid_for(extent, self._cap(bundle, kind0, False))[0]
        else:
            grid, scale = physical_grid(extent, target, self._cap(bundle, kind0, preview or quick))
            full_grid, full_scale = physical_grid(extent, target, self._cap(bundle, kind0, False))
            if self._defer_tactile(quick, needs, target / scale, full_grid != grid):
                # Felt at the wrong size, and replaced by the refinement before a finger can come back to feel
                # it: the quick answer shows the garment and the device keeps what it had until the refinement.
                needs = tuple(m for m in needs if m != "tactile")
                pp.needs, pp.deferred = needs, ("tactile",)
                # The refinement computes every modality: its grid (refine_grid, the warning below) stays the
                # one planned with them.
                kind0 = choose_graph(needs, bundle.graphs())
                grid, scale = physical_grid(extent, target, self._cap(bundle, kind0, True))
            if quick:
                pp.refine_grid = full_grid
            pp.target_scale, pp.felt_ratio = target, target / scale
            if full_scale < target * (1.0 - 1e-6):
                mult = GRID_MULTIPLE
                need = (math.ceil(extent[0] * target / mult) * mult, math.ceil(extent[1] * target / mult) * mult)
                cap = self._cap(bundle, kind0, False)
                self._warn_once(bundle, "cap", f"garment {panel.bundle}: at this panel's {self.panel_pitch_mm:.3f} "
                                f"mm/px and the bundle's {bundle.pixel_pitch_mm:.3f} mm/px the drawn garment needs a "
                                f"{need[0]}x{need[1]} grid but at most {cap[0]}x{cap[1]} is available (bundle sizes, "
                                f"inference.max_resolution); its texture is felt {target / full_scale:.2f}x coarser "
                                f"than the fabric")
        rw, rh = round(grid[0] / scale), round(grid[1] / scale)
        region = place_region((x0, y0, x1, y1), (rw, rh), clip)
        t = Transform(region[0], region[1], grid[0] / rw, grid[1] / rh, grid)
        t3 = time.perf_counter()
        net_sketch = render_sketch(sketch, t, base, placement)
        t4 = time.perf_counter()
        acc.rasterize_ms += 1e3 * (t4 - t3)
        # At the grid only small gaps are closed (a closing's cost grows with its kernel, and a large one at the
        # grid would cost more than the inference); the coarse raster already closed the large ones.
        fine_gap = min(FINE_MAX_GAP, max(3, round(GAP_FRACTION * min(pw, ph) * t.kx)))
        mask = object_mask(net_sketch, max_gap_px=fine_gap)
        if not mask.any():
            # The coarse raster closed the outline, the fine one did not: use the coarse mask at the grid.
            warp = np.array([[t.kx / k, 0, (ax - region[0]) * t.kx],
                             [0, t.ky / k, (ay - region[1]) * t.ky]], np.float64)
            mask = cv2.warpAffine(coarse_mask.astype(np.uint8) * 255, warp, grid, flags=cv2.INTER_LINEAR) >= 128
        key = content_key(bundle.key, grid, net_sketch, mask)
        reused = tuple(mod for mod in needs if self.cached(key, mod))
        todo = tuple(mod for mod in needs if mod not in reused)
        pp.graph = choose_graph(todo, bundle.graphs())
        pp.reused, pp.region, pp.grid, pp.scale, pp.cache_key = reused, region, grid, scale, key
        pp.inputs, pp.mask = network_input(net_sketch, mask), mask
        pp.computed_pixels = grid[0] * grid[1] if todo else 0
        pp.reason = ("all from cache" if not todo else
                     f"{'+'.join(todo)} at {grid[0]}x{grid[1]} (scale {scale:.2f})"
                     + (f", {'+'.join(reused)} from cache" if reused else ""))
        if pp.graph == "full" and len(todo) == 1:
            pp.reason += "; the bundle has no separate branches, so the full graph runs (the cost of both)"
        acc.plan_ms += 1e3 * (time.perf_counter() - t0 - (t2 - t1) - (t4 - t3))
        return pp
