"""`KioskDaemon`: bundles + scene planner + inference loop + haptic output + HTTP server + health, composed.

Threads: the HTTP server (one per connection) parses requests and waits; one inference loop plans and runs every
job (so inference never competes with itself for the two cores); the haptic output thread uploads friction frames
(so a slow or lost device never delays the visual); the watchdog runs the health checks; the control socket
serves operators. Bundles are held in a dict that is replaced as a whole on reload (load beside, probe, swap),
so a job in flight finishes on the bundle it started with.

Failure policy: a graph that returns NaN/Inf or raises, or a device that drops, never reaches the screen or the
finger: the panel keeps its last good output, the failure is logged and counted, and the page shows a notice
(`degraded`) until it clears. The device is reconnected by the bridge; the kiosk stays visual-only meanwhile.
"""
from __future__ import annotations

import itertools
import json
import logging
import os
import shutil
import struct
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from kiosk.service.api import RenderRequest, parse_render_request
from kiosk.bundle.archive import open_bundle, verify_directory
from kiosk.service.config import KioskConfig
from kiosk.service.device_output import DeviceOutput
from kiosk.inference.engine import InferenceError, LoadedBundle, NonFiniteOutput, OutputCache, visual_rgba
from kiosk.inference.backends import ENGINES
from kiosk.contract.errors import InputError, KioskError
from kiosk.contract.graph import grid_floor
from kiosk.ops.health import CheckResult, Heartbeat, HealthMonitor, device_check, health_metrics, http_check
from kiosk.bundle.manifest import BundleError
from kiosk.ops.metrics import Registry
from kiosk.ops.notify import Notifier, Watchdog, watchdog_interval_s
from kiosk.inference.render import FrictionSource
from kiosk.inference.scene import PanelPlan, Plan, Planner, Scene, SketchInput
from kiosk.service.server import KioskServer, Request, Response
from kiosk.service.usage import UsageMetrics, parse_usage_event

log = logging.getLogger(__name__)
IDLE_BEAT_S = 0.25
RETIRE_GRACE_S = 10.0  # a swapped-out bundle stays open this long for jobs that started on it
REFINE_WAIT_S = 0.25  # longest a refinement waits for the quick answer's upload


class BusyError(KioskError):
    """The inference loop did not answer in time (it is hung or overloaded); the page keeps its last frame."""


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


@dataclass
class _Job:
    request: RenderRequest
    received_at: float
    done: threading.Event = field(default_factory=threading.Event)
    result: FrameResult | None = None
    error: BaseException | None = None
    superseded: bool = False


class KioskDaemon:
    """The kiosk. `start()` loads bundles, opens the device, starts serving and sends READY; `stop()` undoes it."""

    def __init__(self, config: KioskConfig, *, notifier: Notifier | None = None, display=None,
                 bundle_sources: Callable[[], list[tuple[str, Callable[[], LoadedBundle]]]] | None = None):
        """`bundle_sources` replaces the store + configured bundles as what to serve (the A/B study serves each
        condition's bundle under its own name); it is asked again on every reload."""
        self.config = config
        self._bundle_sources = bundle_sources
        inf = config.inference
        self.metrics = Registry()
        self._init_metrics()
        self.health = HealthMonitor()
        self.server = KioskServer(config.server.host, config.server.port,
                                  allow_non_loopback=config.server.allow_non_loopback,
                                  timeout_s=config.server.request_timeout_s,
                                  header_timeout_s=config.server.header_timeout_s,
                                  max_connections=config.server.max_connections,
                                  server_names=config.server.names)
        self.cache = OutputCache(inf.cache_mb << 20)
        self.planner = Planner(max_resolution=inf.max_resolution, preview_max_resolution=inf.preview_max_resolution,
                               margin_px=inf.margin_px, cached=self.cache.has,
                               panel_pitch_mm=config.panel.pitch_mm)
        self.device = DeviceOutput(config.device, display=display, on_error=self._device_error,
                                   on_texture=self._texture_made)
        self.notifier = notifier if notifier is not None else Notifier.from_env()
        self.heartbeat = Heartbeat()
        self.watchdog: Watchdog | None = None
        self.control = None
        self._bundles: dict[str, LoadedBundle] = {}
        self._retired: list[tuple[float, LoadedBundle]] = []  # swapped out: closed after RETIRE_GRACE_S
        self._reload_lock = threading.Lock()
        self._jobs: list[_Job] = []
        self._jobs_cond = threading.Condition()
        self._frame_ids = itertools.count(1)
        self._last_plan: dict | None = None
        self._last_good: dict[str, PanelResult] = {}
        self._textures: dict[str, FrictionSource] = {}
        self._notices: dict[str, str] = {}
        self._control_handlers: dict[str, Callable[[dict], dict]] = {}
        self._hang = threading.Event()
        self._stop = threading.Event()
        self._loop_thread: threading.Thread | None = None
        self._workdir: Path | None = None
        self._last_reload: dict | None = None
        self.started = False

    # -- metrics -------------------------------------------------------------------------------------------------
    def _init_metrics(self) -> None:
        r = self.metrics
        self.m_frames = r.counter("vtkiosk_frames_total", "Render jobs completed.", labels=("kind",))
        self.m_stage = r.histogram("vtkiosk_stage_seconds", "Time per pipeline stage.", labels=("stage",))
        self.m_e2e = r.histogram("vtkiosk_e2e_seconds", "Request received -> visual ready / friction committed.",
                                 labels=("target",))
        self.m_inference_errors = r.counter("vtkiosk_inference_errors_total",
                                            "Inference failures (the last good frame stayed).", labels=("reason",))
        self.m_device_errors = r.counter("vtkiosk_device_errors_total", "Haptic device errors.", labels=("kind",))
        self.m_device_up = r.gauge("vtkiosk_device_up", "1 while the haptic link is up.")
        self.m_degraded = r.gauge("vtkiosk_degraded", "1 while the kiosk shows a degraded notice.")
        self.m_engine = r.gauge("vtkiosk_engine_selected", "1 for the inference engine each garment runs on.",
                                labels=("garment", "engine"))
        self.m_engine_ms = r.gauge("vtkiosk_engine_bench_ms", "Activation benchmark (engine: auto): median ms per "
                                   "pass over the bundle's graphs.", labels=("garment", "engine"))
        self.m_engine_err = r.gauge("vtkiosk_engine_bench_error_levels", "Activation benchmark: mean |diff| vs "
                                    "ONNX Runtime in 8-bit levels.", labels=("garment", "engine"))
        self.m_cache = r.counter("vtkiosk_cache_total", "Output cache lookups by the planner.", labels=("result",))
        self.m_pixels = r.counter("vtkiosk_pixels_total", "Network pixels computed vs the naive full-frame plan.",
                                  labels=("plan",))
        self.m_graph_runs = r.counter("vtkiosk_graph_runs_total", "Graph runs by kind.", labels=("graph",))
        self.m_reloads = r.counter("vtkiosk_reloads_total", "Bundle reloads by outcome.", labels=("result",))
        self.m_requests = r.histogram("vtkiosk_http_request_seconds", "HTTP request latency.", labels=("route",))
        self.m_nonfinite = r.counter("vtkiosk_nonfinite_values_total",
                                     "Non-finite tactile values replaced by 0 in friction maps.")
        self.usage = UsageMetrics(r)
        self.m_device_up.set_function(lambda: 1.0 if self.device.up else 0.0)
        self.m_degraded.set_function(lambda: 1.0 if self._notices else 0.0)
        if self.config.fleet.enabled:
            from kiosk.fleet.state import STATE_FILE, register_metrics

            register_metrics(r, self.config.fleet.state_dir / STATE_FILE)

    def _device_error(self, kind: str, exc: BaseException) -> None:
        self.m_device_errors.inc(kind=kind)

    def _texture_made(self, source: FrictionSource) -> None:
        self.m_stage.observe(source.ms / 1e3, stage="friction")
        if source.nonfinite:
            self.m_nonfinite.inc(source.nonfinite)

    # -- bundles -------------------------------------------------------------------------------------------------
    @property
    def bundles(self) -> dict[str, LoadedBundle]:
        return dict(self._bundles)

    def _trusted(self):
        from kiosk.bundle.signature import load_trusted_keys

        keys = self.config.store.trusted_keys
        return load_trusted_keys(keys) if keys is not None else None

    def _candidates(self) -> list[tuple[str, Callable[[], LoadedBundle]]]:
        """(source description, loader) for every bundle the kiosk should serve now."""
        if self._bundle_sources is not None:
            return self._bundle_sources()
        inf, store = self.config.inference, self.config.store
        trusted = self._trusted()
        out: list[tuple[str, Callable[[], LoadedBundle]]] = []

        def make(bundle, source, owned=None) -> LoadedBundle:
            return LoadedBundle(bundle, threads=inf.threads, providers=inf.providers, precisions=inf.precisions,
                                owned_dir=owned, source=source, engine=inf.engine.type,
                                auto_max_side=inf.max_resolution, auto_runs=inf.engine.auto_runs)

        if store.root is not None:
            from kiosk.bundle.store import BundleStore

            active = BundleStore(store.root, store.trusted_keys, allow_unsigned=store.allow_unsigned).active()
            for garment, stored in sorted(active.items()):
                out.append((f"store:{garment}/{stored.version}",
                            lambda stored=stored, g=garment: make(
                                verify_directory(stored.path, trusted, allow_unsigned=store.allow_unsigned),
                                f"store:{g}/{stored.version}")))
        for path in self.config.bundles:
            def load(path=path) -> LoadedBundle:
                assert self._workdir is not None
                if Path(path).is_dir():
                    return make(verify_directory(path, trusted, allow_unsigned=store.allow_unsigned), str(path))
                b = open_bundle(path, trusted, workdir=self._workdir, allow_unsigned=store.allow_unsigned)
                return make(b, str(path), owned=b.root)
            out.append((str(path), load))
        return out

    def _probe(self, lb: LoadedBundle, *, enforce_budget: bool = True) -> dict:
        """Load every graph and run it at the largest grid the planner will use; the best of three runs must be
        within the latency budget (`enforce_budget`; at start-up, with nothing else to serve, an overrun is logged
        and the health check reports the loop's real latency instead)."""
        inf = self.config.inference
        budget = inf.latency_budget_ms
        results = {}
        for kind in lb.graphs():
            cw, ch = lb.cap(kind)
            grid = (grid_floor(min(cw, inf.max_resolution)), grid_floor(min(ch, inf.max_resolution)))
            preview = (min(grid[0], inf.preview_max_resolution), min(grid[1], inf.preview_max_resolution))
            runs = lb.warm((kind,), [preview, grid, grid, grid, grid])  # the first run at `grid` allocates
            ms = min(r[2] for r in runs[2:])
            results[kind] = {"grid": list(grid), "ms": round(ms, 1)}
            if ms > budget:
                msg = (f"bundle {lb.garment_id}: the {kind} graph takes {ms:.0f} ms at {grid[0]}x{grid[1]}, over the "
                       f"{budget:.0f} ms latency budget")
                if enforce_budget:
                    raise BundleError(msg)
                log.warning("%s; serving it anyway (nothing else to serve)", msg)
                results[kind]["over_budget"] = True
        return results

    def reload(self) -> dict:
        """Load what should be served beside what is served, probe it, and swap per garment only when it passes;
        a garment whose new bundle fails keeps its old one. Returns what happened, with reasons."""
        with self._reload_lock:
            self._close_retired()
            report: dict[str, list] = {"swapped": [], "loaded": [], "kept": [], "unchanged": [], "removed": [],
                                       "failed": []}
            current = dict(self._bundles)
            try:
                candidates = self._candidates()
            except KioskError as exc:
                report["failed"].append({"source": "config", "reason": str(exc)})
                self.m_reloads.inc(result="failed")
                self._last_reload = report
                return report
            new: dict[str, LoadedBundle] = {}
            seen: set[str] = set()
            for source, load in candidates:
                try:
                    lb = load()
                except (KioskError, OSError) as exc:
                    report["failed"].append({"source": source, "reason": str(exc)})
                    log.warning("bundle %s not loaded: %s", source, exc)
                    continue
                seen.add(lb.garment_id)
                old = current.get(lb.garment_id)
                if old is not None and old.key == lb.key:
                    lb.close()
                    report["unchanged"].append({"garment": lb.garment_id, "key": old.key})
                    continue
                try:
                    probe = self._probe(lb, enforce_budget=old is not None)
                except (KioskError, OSError) as exc:
                    lb.close()
                    entry = {"garment": lb.garment_id, "source": source, "reason": str(exc)}
                    (report["kept"] if old is not None else report["failed"]).append(entry)
                    log.warning("bundle %s failed its probe (%s); %s", source, exc,
                                f"keeping {old.key}" if old else "not serving it")
                    continue
                new[lb.garment_id] = lb
                entry = {"garment": lb.garment_id, "key": lb.key, "source": source, "probe": probe}
                if old is not None:
                    entry["replaced"] = old.key
                    report["swapped"].append(entry)
                else:
                    report["loaded"].append(entry)
            # Garments that were served but failed to load this time stay; only ones no longer configured go.
            failed_garments = {e.get("garment") for e in report["failed"] + report["kept"]}
            removed = [g for g in current if g not in seen and g not in new and g not in failed_garments
                       and not report["failed"]]
            merged = {g: b for g, b in current.items() if g not in removed}
            merged.update(new)
            if not merged and current:
                merged = current  # never swap to nothing
                removed = []
            self._bundles = merged  # the swap: one reference assignment; jobs in flight keep their snapshot
            for lb in new.values():
                self._record_engine(lb)
            for g in removed:
                report["removed"].append(g)
            now = time.monotonic()
            self._retired.extend((now, current[g]) for g in list(new) + removed if g in current)
            result = "swapped" if (report["swapped"] or report["loaded"] or removed) else \
                "kept" if (report["kept"] or report["failed"]) else "unchanged"
            self.m_reloads.inc(result=result)
            report["serving"] = {g: b.key for g, b in sorted(self._bundles.items())}
            self._last_reload = report
            log.info("reload: %s", json.dumps({k: v for k, v in report.items() if v}, default=str))
            return report

    def _close_retired(self) -> None:
        """Close bundles swapped out long enough ago that no job can still be using them."""
        now = time.monotonic()
        keep = []
        for at, b in self._retired:
            if now - at >= RETIRE_GRACE_S:
                b.close()
            else:
                keep.append((at, b))
        self._retired = keep

    # -- life cycle ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        if self.started:
            return
        state = self.config.state_dir
        if state is not None:
            Path(state).mkdir(parents=True, exist_ok=True)
        self._workdir = Path(tempfile.mkdtemp(prefix="vtkiosk-bundles-", dir=state))
        try:
            report = self.reload()
            if not self._bundles:
                reasons = "; ".join(f"{e['source']}: {e['reason']}" for e in report["failed"] + report["kept"])
                if not reasons:
                    where = f"the store {self.config.store.root} has no active bundle and " \
                        if self.config.store.root else ""
                    raise BundleError(f"nothing to serve: {where}no bundle is configured; install one with "
                                      "`vtkiosk bundle install FILE --activate`, or pass --bundle FILE")
                raise BundleError(f"no bundle could be loaded ({reasons})")
            self.device.start()
            self._stop.clear()
            self._loop_thread = threading.Thread(target=self._loop, name="vtkiosk-inference", daemon=True)
            self._loop_thread.start()
            self._routes()
            self.server.on_request = lambda method, route, status, s: self.m_requests.observe(s, route=route)
            self.server.start()
            self._start_health()
            self._start_control()
            self.started = True
        except BaseException:
            self.stop()
            raise
        self.notifier.ready(f"serving {', '.join(sorted(self._bundles))} on {self.server.url}")
        log.info("kiosk serving %s on %s", ", ".join(sorted(self._bundles)), self.server.url)

    def stop(self) -> None:
        try:
            self.notifier.stopping()
        except Exception:  # noqa: BLE001 - stopping must always complete
            log.exception("sd_notify STOPPING failed")
        if self.watchdog is not None:
            self.watchdog.stop()
            self.watchdog = None
        if self.control is not None:
            self.control.stop()
            self.control = None
        self.server.stop()
        self._stop.set()
        self._hang.clear()
        with self._jobs_cond:
            self._jobs_cond.notify_all()
        if self._loop_thread is not None:
            self._loop_thread.join(timeout=10.0)
            self._loop_thread = None
        self.device.stop()
        for b in list(self._bundles.values()) + [b for _, b in self._retired]:
            b.close()
        self._bundles, self._retired = {}, []
        if self._workdir is not None:
            shutil.rmtree(self._workdir, ignore_errors=True)
            self._workdir = None
        self.started = False

    def _start_health(self) -> None:
        h = self.config.health
        budget = self.config.inference.latency_budget_ms / 1e3
        self.add_health_check("inference", lambda: self.heartbeat.check(stale_after_s=h.stale_after_s,
                                                                        budget_s=budget))
        if h.require_device:
            dev = device_check(self._link_health, max_heartbeat_age_s=h.device_max_heartbeat_age_s)
            self.add_health_check("device", dev)
        self.add_health_check("server", http_check(self.server.url + "api/ping", timeout_s=1.0))
        self.add_health_check("bundle", self._bundle_check)
        if self.config.fleet.enabled:  # informational: an offline repository must not restart a serving kiosk
            from kiosk.fleet.state import STATE_FILE, fleet_check

            fleet = self.config.fleet
            self.add_health_check("fleet", fleet_check(fleet.state_dir / STATE_FILE, fleet.stale_after_s))
        interval = watchdog_interval_s() or h.interval_s
        self.watchdog = Watchdog(self.notifier, self.health, interval, on_report=health_metrics(self.metrics))
        self.watchdog.start()

    def _link_health(self):
        h = self.device.health()
        if h is None:
            return _Closed(self.device.last_error)
        return h

    def _bundle_check(self) -> CheckResult:
        if not self._bundles:
            return CheckResult(False, "no bundle loaded")
        return CheckResult(True, ", ".join(b.key.split("#")[0] for b in self._bundles.values()))

    def _start_control(self) -> None:
        path = self.config.control.socket
        if path is None:
            return
        from kiosk.ops.control import ControlServer

        self.control = ControlServer(Path(path), self.handle_control, group=self.config.control.group)
        self.control.start()

    # -- hooks for the study and operations ------------------------------------------------------------------------
    def add_control_handler(self, prefix: str, handler: Callable[[dict], dict]) -> None:
        """Ops whose name starts with `prefix` (e.g. "study.") go to `handler(request) -> reply`."""
        if not prefix or prefix in ("reload", "status", "debug."):
            raise ValueError(f"control prefix {prefix!r} is taken or empty")
        self._control_handlers[prefix] = handler

    def add_health_check(self, name: str, fn: Callable[[], CheckResult]) -> None:
        self.health.add_check(name, fn)

    def handle_control(self, req: dict) -> dict:
        op = req.get("op")
        if op == "reload":
            report = self.reload()
            ok = not (report["failed"] or report["kept"])
            return {"ok": ok, **report, **({} if ok else {"error": _reload_reason(report)})}
        if op == "status":
            return self.status()
        if isinstance(op, str) and op.startswith("debug."):
            return self._debug(op, req)
        for prefix, handler in self._control_handlers.items():
            if isinstance(op, str) and op.startswith(prefix):
                return handler(req)
        raise InputError(f"unknown control op {op!r} (reload, status"
                         f"{', debug.*' if self.config.debug.fault_injection else ''}"
                         f"{''.join(', ' + p + '*' for p in self._control_handlers)})")

    def _debug(self, op: str, req: dict) -> dict:
        """Fault injection for tests (config debug.fault_injection): break the kiosk on purpose, then mend it."""
        if not self.config.debug.fault_injection:
            raise InputError("fault injection is off (debug.fault_injection: false)")
        emu = self.device.emulator
        if op == "debug.hang":
            (self._hang.set if req.get("on", True) else self._hang.clear)()
            return {"hang": self._hang.is_set()}
        if op == "debug.nonfinite":
            for b in self._bundles.values():
                b.fault_nonfinite = bool(req.get("on", True))
            self.cache.clear()
            return {"nonfinite": bool(req.get("on", True))}
        if op in ("debug.unplug", "debug.replug"):
            if emu is None:
                raise InputError("unplug/replug needs the in-process emulated device (device.type: emulated)")
            (emu.unplug if op == "debug.unplug" else emu.replug)()
            return {"plugged": emu.link.plugged}
        raise InputError(f"unknown debug op {op!r} (debug.hang, debug.nonfinite, debug.unplug, debug.replug)")

    # -- rendering -----------------------------------------------------------------------------------------------
    def show(self, scene: Scene, sketches: dict[str, SketchInput] | None = None, *, preview: bool = False,
             client: str = "api", timeout_s: float | None = None) -> FrameResult:
        """Render a scene (what the study calls): plan, infer at full resolution in one step, put the friction
        frame on the device. Returns when the visual is ready; `wait_commit(result.device_frame)` waits for the
        device."""
        req = RenderRequest(scene, dict(sketches or {}), "preview" if preview else "full", client)
        return self._submit(req, time.monotonic(), timeout_s)

    def _submit(self, req: RenderRequest, received_at: float, timeout_s: float | None = None) -> FrameResult:
        if not self.started:
            raise BusyError("the kiosk is not running")
        job = _Job(req, received_at)
        with self._jobs_cond:
            # Latest wins: a newer request from the same client replaces its queued previews and refinements
            # (a stroke end is never dropped).
            for old in self._jobs:
                if old.request.mode in ("preview", "refine") and old.request.client == req.client:
                    old.superseded = True
                    old.done.set()
            self._jobs = [j for j in self._jobs if not j.superseded]
            self._jobs.append(job)
            self._jobs_cond.notify_all()
        timeout = self.config.server.request_timeout_s if timeout_s is None else timeout_s
        if not job.done.wait(timeout):
            with self._jobs_cond:
                if job in self._jobs:
                    self._jobs.remove(job)
            raise BusyError(f"the inference loop did not answer within {timeout:.1f} s; showing the last frame")
        if job.superseded:
            raise _Superseded()
        if job.error is not None:
            raise job.error
        assert job.result is not None
        return job.result

    def put_friction(self, sources: list) -> int:
        """Put friction textures that need no model on the device (the study's familiarisation textures); returns
        the device frame for `wait_commit`. The next rendered scene replaces them."""
        frame = next(self._frame_ids)
        self.device.submit(frame, list(sources))
        return frame

    def wait_commit(self, device_frame: int | None, timeout_s: float = 2.0):
        if device_frame is None:
            return None
        return self.device.wait_commit(device_frame, timeout_s)

    def _loop(self) -> None:
        self.heartbeat.beat()
        while not self._stop.is_set():
            while self._hang.is_set() and not self._stop.is_set():
                time.sleep(0.02)  # injected hang: no beats, no work (the watchdog must notice)
            with self._jobs_cond:
                if not self._jobs:
                    self._jobs_cond.wait(IDLE_BEAT_S)
                job = self._jobs.pop(0) if self._jobs else None
            if job is None:
                self.heartbeat.beat()
                if self._retired and self._reload_lock.acquire(blocking=False):
                    try:
                        self._close_retired()
                    finally:
                        self._reload_lock.release()
                continue
            if self._hang.is_set():
                with self._jobs_cond:
                    self._jobs.insert(0, job)
                continue
            t0 = time.monotonic()
            if job.request.mode == "refine":
                # Let the quick answer's friction frame reach the finger first: on two cores a refinement
                # computed during its upload would delay it.
                self.device.wait_idle(REFINE_WAIT_S)
            try:
                job.result = self._render(job)
            except BaseException as exc:  # noqa: BLE001 - the loop must survive anything one job does
                if not isinstance(exc, KioskError):
                    log.exception("render job failed")
                job.error = exc
            finally:
                job.done.set()
            self.heartbeat.beat(time.monotonic() - t0)

    def _render(self, job: _Job) -> FrameResult:
        req = job.request
        t_start = time.monotonic()
        bundles = self._bundles  # snapshot: a reload swaps the dict, never mutates it
        quick = req.mode == "final" and self.config.inference.refine
        plan = self.planner.plan(req.scene, req.sketches, bundles, preview=req.preview, quick=quick)
        held = self._take_reused(plan)
        if held is None:  # an entry the plan reuses left the cache since: the planner decides again
            plan = self.planner.plan(req.scene, req.sketches, bundles, preview=req.preview, quick=quick)
            held = self._take_reused(plan) or {}
        frame = next(self._frame_ids)
        timings = {"queue_ms": 1e3 * (t_start - job.received_at), "rasterize_ms": plan.rasterize_ms,
                   "plan_ms": plan.plan_ms, "inference_ms": 0.0, "visual_ms": 0.0}
        results: list[PanelResult] = []
        notices: dict[str, str] = {}
        for pp in plan.panels:
            res = self._render_panel(pp, bundles[pp.bundle], req.preview, timings, notices, held)
            results.append(res)
        plan_json = plan.to_json()
        self._last_plan = plan_json
        self.m_pixels.inc(plan.computed_pixels, plan="planned")
        self.m_pixels.inc(plan.naive_pixels, plan="naive")
        device_frame = None
        if not req.preview and any("tactile" in p.plan.needs or p.status == "empty" for p in results):
            device_frame = frame
            for r in results:
                if r.status == "ok" and "tactile" in r.plan.needs:
                    if r.friction is not None:
                        self._textures[r.panel] = r.friction
                    else:
                        self._textures.pop(r.panel, None)
                elif r.status == "empty" or "tactile" not in r.plan.needs:
                    self._textures.pop(r.panel, None)
            shown = {p.id for p in req.scene.panels}
            for gone in [k for k in self._textures if k not in shown]:
                del self._textures[gone]
            self.device.submit(frame, [self._textures[p.id] for p in req.scene.panels if p.id in self._textures])
        # Notices: inference trouble is per job; the device's state is live.
        # Replaced, never mutated: HTTP threads read it.
        self._notices = {**{k: v for k, v in self._notices.items() if not k.startswith("panel:")}, **notices}
        ready = time.monotonic()
        timings["total_ms"] = 1e3 * (ready - job.received_at)
        for stage in ("rasterize", "plan", "inference", "visual"):
            self.m_stage.observe(timings[f"{stage}_ms"] / 1e3, stage=stage)
        self.m_frames.inc(kind=req.mode)
        self.m_e2e.observe(ready - job.received_at, target="visual")
        # The plan of every stroke end is logged (previews only at debug level), with structured fields.
        log.log(logging.DEBUG if req.preview else logging.INFO, "frame %d %s in %.0f ms: %s", frame, req.mode,
                timings["total_ms"], "; ".join(f"{p.panel}: {p.reason}" for p in plan.panels),
                extra={"BUNDLE_ID": ",".join(sorted({bundles[p.bundle].key for p in plan.panels})),
                       "STAGE_MS": json.dumps({k: round(v, 2) for k, v in timings.items()}),
                       "PLAN": json.dumps(plan_json, separators=(",", ":"))})
        return FrameResult(frame, req.mode, plan, results, timings, job.received_at, ready, device_frame,
                           self.notices())

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

    def _render_panel(self, pp: PanelPlan, bundle: LoadedBundle, preview: bool, timings: dict,
                      notices: dict, held: dict[tuple[str, str], np.ndarray]) -> PanelResult:
        """Carry out the planner's decision for one panel: reuse what it reuses, run the graph it chose."""
        if pp.graph == "none" and not pp.reused:
            if pp.needs and pp.region is None:
                return PanelResult(pp.panel, "empty", pp)  # nothing drawn (yet): an empty, valid result
            return PanelResult(pp.panel, "ok" if not pp.needs else "empty", pp)
        have = {mod: held[(pp.panel, mod)] for mod in pp.reused if (pp.panel, mod) in held}
        self.m_cache.inc(len(have), result="hit")
        if len(have) < len(pp.reused):  # the cache was emptied twice while planning (a reload): keep last good
            return self._keep(pp, "exception", InferenceError(f"{bundle.garment_id}: cached output vanished"),
                              notices)
        if pp.graph != "none":
            self.m_cache.inc(len(pp.needs) - len(have), result="miss")
            try:
                t0 = time.perf_counter()
                run = bundle.run(pp.graph, pp.inputs)
                timings["inference_ms"] += 1e3 * (time.perf_counter() - t0)
                self.m_graph_runs.inc(graph=pp.graph)
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
        if "tactile" in pp.needs and not preview:
            res.friction = FrictionSource(pp.panel, have["tactile"], pp.region, pp.clip,
                                          scale=bundle.friction_scale, normalization=bundle.friction_normalization,
                                          constants=bundle.friction_constants)
        if not preview:
            self._last_good[pp.panel] = res
        return res

    def _keep(self, pp: PanelPlan, reason: str, exc: BaseException, notices: dict) -> PanelResult:
        self.m_inference_errors.inc(reason=reason)
        log.warning("panel %s: %s", pp.panel, exc)
        msg = ("the model returned unusable values; showing the last good result" if reason == "nonfinite"
               else "the model failed; showing the last good result")
        notices[f"panel:{pp.panel}"] = msg
        return PanelResult(pp.panel, "kept", pp, notice=msg)

    # -- state -----------------------------------------------------------------------------------------------------
    def notices(self) -> list[str]:
        out = list(dict.fromkeys(self._notices.values()))
        if not self.device.up:
            out.append("touch feedback is offline (visual only); reconnecting")
        return out

    def status(self) -> dict:
        report = self.health.last()
        return {"bundles": {g: b.info() for g, b in sorted(self._bundles.items())},
                "device": self.device.state(), "notices": self.notices(), "degraded": bool(self.notices()),
                "scale": self.scale_info(),
                "health": report.to_json() if report else None, "last_reload": self._last_reload,
                "cache": {"entries": len(self.cache), "bytes": self.cache.nbytes, "hits": self.cache.hits,
                          "misses": self.cache.misses},
                "torch_imported": "torch" in sys.modules, "pid": os.getpid(), "rss_bytes": _rss_bytes(),
                "url": self.server.url}

    # -- HTTP ------------------------------------------------------------------------------------------------------
    def _routes(self) -> None:
        s = self.server
        s.route("GET", "/api/ping", lambda req: Response.json({"ok": True}))
        s.route("GET", "/api/bundles", self._api_bundles)
        s.route("POST", "/api/render", self._api_render)
        s.route("GET", "/api/page", lambda req: Response.json(self.config.page.to_json()))
        s.route("POST", "/api/usage", self._api_usage)
        s.route("GET", "/api/plan", lambda req: Response.json({"plan": self._last_plan}))
        s.route("GET", "/api/status", lambda req: Response.json(self.status()))
        s.route("GET", "/api/commit", self._api_commit)
        s.route("GET", "/api/debug/device-frame", self._api_device_frame)
        s.route("GET", "/healthz", self._api_healthz)
        s.route("GET", "/metrics", lambda req: Response.text(self.metrics.render(),
                                                             "text/plain; version=0.0.4; charset=utf-8"))

    def _api_healthz(self, req: Request) -> Response:
        report = self.health.run()  # fresh: the checks only read state the working threads keep
        body = {**report.to_json(), "scale": self.scale_info(), "engines": self.engine_info()}
        if self.config.fleet.enabled:
            from kiosk.fleet.state import STATE_FILE, section

            body["fleet"] = section(self.config.fleet.state_dir / STATE_FILE, self.config.fleet.stale_after_s)
        return Response.json(body, 200 if report.ok else 503)

    def _record_engine(self, lb: LoadedBundle) -> None:
        for figures in (lb.engine_choice.figures if lb.engine_choice else []):
            if figures.ms_p50 is not None:
                self.m_engine_ms.set(figures.ms_p50, garment=lb.garment_id, engine=figures.engine)
                self.m_engine_err.set(figures.err_levels or 0.0, garment=lb.garment_id, engine=figures.engine)
        for engine in ENGINES:
            self.m_engine.set(1.0 if engine == lb.engine else 0.0, garment=lb.garment_id, engine=engine)

    def engine_info(self) -> dict:
        """Each garment's engine and, under engine: auto, the activation benchmark that chose it."""
        return {g: {"engine": b.engine, "choice": b.engine_choice.to_json() if b.engine_choice else None}
                for g, b in sorted(self._bundles.items())}

    def scale_info(self) -> dict:
        """Both pitches: the panel's (config) and each bundle's (what its model learned at), and the ratio the
        planner infers at (grid px per screen px)."""
        panel = self.config.panel.describe()
        return {"panel": panel, "bundles": {g: {"pixel_pitch_mm": b.pixel_pitch_mm,
                                                "grid_per_screen_px": round(panel["pitch_mm"] / b.pixel_pitch_mm, 4)}
                                            for g, b in sorted(self._bundles.items())}}

    def _api_bundles(self, req: Request) -> Response:
        parts = req.path.split("/")  # /api/bundles[/<id>/<asset>.png]
        bundles = self._bundles
        if len(parts) == 3 or (len(parts) == 4 and parts[3] == ""):
            return Response.json({"bundles": [b.info() for _, b in sorted(bundles.items())],
                                  "default": sorted(bundles)[0] if bundles else None})
        if len(parts) == 5 and parts[4].endswith(".png"):
            b = bundles.get(parts[3])
            name = parts[4][:-4]
            if b is None or name not in b.manifest.assets:
                return Response.error(404, f"no asset {name!r} for garment {parts[3]!r}")
            return Response(200, b.bundle.path(b.manifest.assets[name]).read_bytes(), "image/png",
                            {"Cache-Control": "max-age=60"})
        return Response.error(404, f"nothing at {req.path}")

    def _api_render(self, req: Request) -> Response:
        parsed = parse_render_request(req.json())
        try:
            result = self._submit(parsed, req.received_at)
        except _Superseded:
            return Response.json({"superseded": True}, 200)
        except BusyError as exc:
            return Response.error(503, str(exc))
        return frame_response(result)

    def _api_usage(self, req: Request) -> Response:
        self.usage.record(parse_usage_event(req.json()))
        return Response(204)

    def _api_commit(self, req: Request) -> Response:
        try:
            frame = int(req.arg("frame") or "")
            wait = min(max(float(req.arg("wait", "0") or 0), 0.0), 10.0)
        except ValueError:
            raise InputError("give ?frame=N (and optionally &wait=SECONDS)") from None
        c = self.device.wait_commit(frame, wait) if wait else self.device.commit_of(frame)
        if c is None:
            return Response.error(404, f"no device frame {frame}")
        return Response.json({"frame": c.frame, "status": c.status, "committed_at": c.at, "tiles": c.tiles,
                              "wire_bytes": c.wire_bytes, "friction_ms": round(c.friction_ms, 3),
                              "upload_ms": round(c.upload_ms, 3)})

    def _api_device_frame(self, req: Request) -> Response:
        """The emulated device's committed frame (PNG) and the host's composed frame: tests and the bench compare
        them with the friction maps. Only for the in-process emulator."""
        emu = self.device.emulator
        if emu is None:
            return Response.error(404, "only the in-process emulated device exposes its frame")
        which = req.arg("which", "device")
        frame = emu.active_frame if which == "device" else self.device.composed()
        if frame is None:
            return Response.error(404, "no frame yet")
        ok, png = cv2.imencode(".png", frame)
        return Response(200, png.tobytes(), "image/png")


class _Superseded(Exception):
    """A preview or refinement replaced by a newer request before it ran."""


class _Closed:
    """LinkHealth stand-in before the device was ever opened."""

    def __init__(self, error: str | None):
        self.state = "closed"
        self.last_error = error or "not opened yet"
        self.last_heartbeat_age_s = None


def _reload_reason(report: dict) -> str:
    items = report["kept"] + report["failed"]
    return "; ".join(f"{e.get('garment') or e.get('source')}: {e['reason']}" for e in items)


def frame_response(result: FrameResult) -> Response:
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
    return Response(200, struct.pack("<I", len(head)) + head + b"".join(blobs), "application/octet-stream",
                    {"Cache-Control": "no-store"})


def parse_frame(body: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """The inverse of `frame_response` (tests and the bench): (metadata, panel id -> RGBA visual)."""
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


def _rss_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0
