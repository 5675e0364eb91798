"""Carrying out the planner's plan for one render job, and the page's binary frame.

The planner (`kiosk.inference.scene`) decides which graph runs, where and at what grid; this module only does what
the plan says: take the cached outputs it reuses, run the graph it names, turn tactile output into friction
sources, and put the frame on the device. If a cached output the plan relies on has vanished, the planner is asked
again; nothing here chooses a graph of its own.

Failure policy: a graph that returns NaN/Inf or raises never reaches the screen or the finger: the panel keeps its
last good output, the failure is counted, and the page shows a notice until it clears.
"""
from __future__ import annotations

import itertools
import json
import logging
import struct
import time
from dataclasses import dataclass, field

import numpy as np

from kiosk.inference.engine import InferenceError, LoadedBundle, NonFiniteOutput, OutputCache, visual_rgba
from kiosk.inference.render import FrictionSource
from kiosk.inference.scene import PanelPlan, Plan, Planner
from kiosk.service.api import RenderRequest
from kiosk.service.device_output import DeviceOutput
from kiosk.service.metrics import ServiceMetrics

log = logging.getLogger(__name__)
DEVICE_OFFLINE = "touch feedback is offline (visual only); reconnecting"


@dataclass
class PanelResult:
    panel: str
    status: str  # ok | kept | empty
    plan: PanelPlan
    visual: np.ndarray | None = None  # RGBA (H, W, 4) at the grid
    friction: FrictionSource | None = None  # made by the haptic output thread
    notice: str | None = None

    def to_json(self) -> dict:
        p = self.plan
        return {"panel": self.panel, "status": self.status, "notice": self.notice,
                "visual": None if self.visual is None else
                {"rect": list(p.region), "size": [int(self.visual.shape[1]), int(self.visual.shape[0])]},
                "reference": p.placement.to_json() if p.placement else None,
                "friction": None if self.friction is None or self.friction.rect is None else
                {"rect": list(self.friction.rect)},
                "clip": list(p.clip)}


@dataclass
class FrameResult:
    """What one render produced. `device_frame` is the frame id whose commit `wait_commit` reports."""

    frame: int
    mode: str
    plan: Plan
    panels: list[PanelResult]
    timings: dict[str, float]
    received_at: float
    ready_at: float = 0.0
    device_frame: int | None = None
    notices: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"frame": self.frame, "mode": self.mode, "preview": self.mode == "preview",
                "refine": self.plan.refinable, "plan": self.plan.to_json(),
                "panels": [p.to_json() for p in self.panels], "timings": {k: round(v, 3) for k, v in
                                                                          self.timings.items()},
                "received_at": self.received_at, "ready_at": self.ready_at, "device_frame": self.device_frame,
                "notices": self.notices}


class FrameRenderer:
    """Plans and renders jobs (the inference loops' `execute`); keeps what the page and device show. With a preview
    lane two jobs render at once, a preview beside a stroke end or refinement: a preview never touches the device's
    textures, and shared state is replaced whole, never mutated in place."""

    def __init__(self, planner: Planner, cache: OutputCache, device: DeviceOutput, metrics: ServiceMetrics, *,
                 quick_first: bool):
        self.planner, self.cache, self.device, self.metrics = planner, cache, device, metrics
        self.quick_first = quick_first          # a stroke end is answered at the preview grid first, then refined
        self.frame_ids = itertools.count(1)
        self.last_plan: dict | None = None
        self.textures: dict[str, FrictionSource] = {}   # panel -> the friction source on the device
        self.texture_garment: dict[str, str] = {}       # panel -> the garment (bundle id) that texture belongs to
        self._notices: dict[str, str] = {}

    def notices(self) -> list[str]:
        out = list(dict.fromkeys(self._notices.values()))
        if not self.device.up:
            out.append(DEVICE_OFFLINE)
        return out

    @property
    def degraded(self) -> bool:
        return bool(self._notices)

    def put_friction(self, sources: list) -> int:
        """Put friction textures that need no model on the device; returns the device frame for `wait_commit`."""
        frame = next(self.frame_ids)
        self.device.submit(frame, list(sources))
        return frame

    def render(self, req: RenderRequest, received_at: float, bundles: dict[str, LoadedBundle]) -> FrameResult:
        """`bundles`: the served set at the time the job runs (a reload swaps the dict, never mutates it)."""
        t_start = time.monotonic()
        quick = req.mode == "final" and self.quick_first
        plan = self.planner.plan(req.scene, req.sketches, bundles, preview=req.preview, quick=quick)
        held = self._take_reused(plan)
        if held is None:  # an entry the plan reuses left the cache since: the planner decides again
            plan = self.planner.plan(req.scene, req.sketches, bundles, preview=req.preview, quick=quick)
            held = self._take_reused(plan) or {}
        frame = next(self.frame_ids)
        timings = {"queue_ms": 1e3 * (t_start - received_at), "rasterize_ms": plan.rasterize_ms,
                   "plan_ms": plan.plan_ms, "inference_ms": 0.0, "visual_ms": 0.0}
        notices: dict[str, str] = {}
        lane = "preview" if req.preview else "main"
        results = [self._render_panel(pp, bundles[pp.bundle], timings, notices, held, lane) for pp in plan.panels]
        plan_json = plan.to_json()
        self.last_plan = plan_json
        self.metrics.pixels.inc(plan.computed_pixels, plan="planned")
        self.metrics.pixels.inc(plan.naive_pixels, plan="naive")
        device_frame = None
        if not plan.preview and any("tactile" in p.plan.needs or p.status == "empty" or self._stale(p)
                                    for p in results):
            device_frame = frame
            self._update_device(frame, req, results)
        # Notices: inference trouble is per job; the device's state is live.
        # Replaced, never mutated: HTTP threads read it.
        self._notices = {**{k: v for k, v in self._notices.items() if not k.startswith("panel:")}, **notices}
        ready = time.monotonic()
        timings["total_ms"] = 1e3 * (ready - received_at)
        for stage in ("rasterize", "plan", "inference", "visual"):
            self.metrics.stage.observe(timings[f"{stage}_ms"] / 1e3, stage=stage)
        self.metrics.frames.inc(kind=req.mode)
        self.metrics.e2e.observe(ready - received_at, target="visual")
        # The plan of every stroke end is logged (previews only at debug level), with structured fields.
        log.log(logging.DEBUG if req.preview else logging.INFO, "frame %d %s in %.0f ms: %s", frame, req.mode,
                timings["total_ms"], "; ".join(f"{p.panel}: {p.reason}" for p in plan.panels),
                extra={"BUNDLE_ID": ",".join(sorted({bundles[p.bundle].key for p in plan.panels})),
                       "STAGE_MS": json.dumps({k: round(v, 2) for k, v in timings.items()}),
                       "PLAN": json.dumps(plan_json, separators=(",", ":"))})
        return FrameResult(frame, req.mode, plan, results, timings, received_at, ready, device_frame,
                           self.notices())

    def _stale(self, r: PanelResult) -> bool:
        """A quick answer left this panel's friction to the refinement, but the device holds another garment's."""
        return "tactile" in r.plan.deferred and r.panel in self.textures \
            and self.texture_garment.get(r.panel) != r.plan.bundle

    def _update_device(self, frame: int, req: RenderRequest, results: list[PanelResult]) -> None:
        for r in results:
            if "tactile" in r.plan.deferred:
                # A quick answer left friction to the refinement: the device keeps the garment's last frame (an
                # edit changes little of it), but never another garment's under this one's picture.
                if self._stale(r):
                    self.textures.pop(r.panel, None)
                continue
            if r.status == "ok" and "tactile" in r.plan.needs:
                if r.friction is not None:
                    self.textures[r.panel] = r.friction
                    self.texture_garment[r.panel] = r.plan.bundle
                else:
                    self.textures.pop(r.panel, None)
            elif r.status == "empty" or "tactile" not in r.plan.needs:
                self.textures.pop(r.panel, None)
        shown = {p.id for p in req.scene.panels}
        for gone in [k for k in self.textures if k not in shown]:
            del self.textures[gone]
        self.texture_garment = {k: v for k, v in self.texture_garment.items() if k in self.textures}
        self.device.submit(frame, [self.textures[p.id] for p in req.scene.panels if p.id in self.textures])

    def _take_reused(self, plan: Plan) -> dict[tuple[str, str], np.ndarray] | None:
        """The cached outputs the plan reuses, taken before any graph runs (a later put may evict them); None
        when one is gone already."""
        held: dict[tuple[str, str], np.ndarray] = {}
        for pp in plan.panels:
            for mod in pp.reused:
                v = self.cache.get(pp.cache_key, mod)
                if v is None:
                    return None
                held[(pp.panel, mod)] = v
        return held

    def _render_panel(self, pp: PanelPlan, bundle: LoadedBundle, timings: dict, notices: dict,
                      held: dict[tuple[str, str], np.ndarray], lane: str = "main") -> PanelResult:
        """Carry out the planner's decision for one panel: reuse what it reuses, run the graph it chose, make
        friction for what it needs (the planner leaves tactile out of a preview's needs)."""
        if pp.graph == "none" and not pp.reused:
            if pp.needs and pp.region is None:
                return PanelResult(pp.panel, "empty", pp)  # nothing drawn (yet): an empty, valid result
            return PanelResult(pp.panel, "ok" if not pp.needs else "empty", pp)
        have = {mod: held[(pp.panel, mod)] for mod in pp.reused if (pp.panel, mod) in held}
        self.metrics.cache.inc(len(have), result="hit")
        if len(have) < len(pp.reused):  # the cache was emptied twice while planning (a reload): keep last good
            return self._keep(pp, "exception", InferenceError(f"{bundle.garment_id}: cached output vanished"),
                              notices)
        if pp.graph != "none":
            self.metrics.cache.inc(len(pp.needs) - len(have), result="miss")
            try:
                t0 = time.perf_counter()
                run = bundle.run(pp.graph, pp.inputs, lane)
                timings["inference_ms"] += 1e3 * (time.perf_counter() - t0)
                self.metrics.graph_runs.inc(graph=pp.graph)
            except NonFiniteOutput as exc:
                return self._keep(pp, "nonfinite", exc, notices)
            except InferenceError as exc:
                return self._keep(pp, "exception", exc, notices)
            except Exception as exc:  # noqa: BLE001 - ORT or numpy blew up: same policy
                log.exception("inference failed")
                return self._keep(pp, "exception", exc, notices)
            t1 = time.perf_counter()
            if "visual" in run.outputs:
                have["visual"] = visual_rgba(run.outputs["visual"], pp.mask)
                self.cache.put(pp.cache_key, "visual", have["visual"])
            if "tactile" in run.outputs:
                have["tactile"] = run.outputs["tactile"]
                self.cache.put(pp.cache_key, "tactile", have["tactile"])
            timings["visual_ms"] += 1e3 * (time.perf_counter() - t1)
        res = PanelResult(pp.panel, "ok", pp, visual=have.get("visual") if "visual" in pp.needs else None)
        if "tactile" in pp.needs:
            res.friction = FrictionSource(pp.panel, have["tactile"], pp.region, pp.clip,
                                          scale=bundle.friction_scale, normalization=bundle.friction_normalization,
                                          constants=bundle.friction_constants)
        return res

    def _keep(self, pp: PanelPlan, reason: str, exc: BaseException, notices: dict) -> PanelResult:
        self.metrics.inference_errors.inc(reason=reason)
        log.warning("panel %s: %s", pp.panel, exc)
        msg = ("the model returned unusable values; showing the last good result" if reason == "nonfinite"
               else "the model failed; showing the last good result")
        notices[f"panel:{pp.panel}"] = msg
        return PanelResult(pp.panel, "kept", pp, notice=msg)


def frame_response_body(result: FrameResult) -> bytes:
    """The page's frame: u32 little-endian N, N bytes of JSON (space-padded so the pixels start 4-byte aligned),
    then each panel's RGBA visual; a panel's `visual.offset` counts from the end of the JSON. One round trip
    carries the plan, the rectangles and the pixels."""
    meta = result.to_json()
    blobs = []
    offset = 0
    for pj, pr in zip(meta["panels"], result.panels):
        if pr.visual is not None:
            data = pr.visual.tobytes()
            pj["visual"]["offset"], pj["visual"]["length"] = offset, len(data)
            offset += len(data)
            blobs.append(data)
    head = json.dumps(meta, separators=(",", ":"), allow_nan=False).encode("utf-8")
    head += b" " * ((-(4 + len(head))) % 4)
    return struct.pack("<I", len(head)) + head + b"".join(blobs)


def parse_frame(body: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """The inverse of `frame_response_body` (tests and the bench): (metadata, panel id -> RGBA visual)."""
    (n,) = struct.unpack_from("<I", body, 0)
    meta = json.loads(body[4:4 + n].decode("utf-8"))
    visuals = {}
    for pj in meta.get("panels", []):
        v = pj.get("visual")
        if v and "offset" in v:
            start = 4 + n + v["offset"]
            w, h = v["size"]
            visuals[pj["panel"]] = np.frombuffer(body, np.uint8, v["length"], start).reshape(h, w, 4)
    return meta, visuals
