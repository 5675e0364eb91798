"""`KioskDaemon`: the kiosk's parts, wired together and started and stopped in order.

The parts, each in its own module: `bundles` (what is served; reload = load beside, probe, swap), `jobs` (the
queue and the one inference loop), `frames` (carry out the planner's plan for a job, keep what is shown),
`device_output` (the haptic output thread), `routes` (the HTTP route table), `kiosk.ops` (health, watchdog,
control socket, metrics). Threads: the HTTP server (one per connection) parses requests and waits; the inference
loop plans and runs every job; the haptic output thread uploads friction frames (so a slow or lost device never
delays the visual); the watchdog runs the health checks; the control socket serves operators.

Failure policy: a graph that returns NaN/Inf or raises, or a device that drops, never reaches the screen or the
finger: the panel keeps its last good output, the failure is logged and counted, and the page shows a notice
(`degraded`) until it clears. The device is reconnected by the bridge; the kiosk stays visual-only meanwhile.
"""
from __future__ import annotations

import logging
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from kiosk.bundle.manifest import BundleError
from kiosk.contract.errors import InputError
from kiosk.inference.engine import LoadedBundle, OutputCache
from kiosk.inference.render import FrictionSource
from kiosk.inference.scene import Planner, Scene, SketchInput
from kiosk.ops.health import CheckResult, Heartbeat, HealthMonitor, device_check, health_metrics, http_check
from kiosk.ops.metrics import Registry
from kiosk.ops.notify import Notifier, Watchdog, watchdog_interval_s
from kiosk.service.api import RenderRequest
from kiosk.service.bundles import BundleSet, Sources, failure_reason
from kiosk.service.config import KioskConfig
from kiosk.service.device_output import DeviceOutput
from kiosk.service.frames import FrameRenderer, FrameResult
from kiosk.service.jobs import BusyError, InferenceLoop, Job, JobQueue
from kiosk.service.metrics import ServiceMetrics
from kiosk.service.routes import Routes
from kiosk.service.server import KioskServer

log = logging.getLogger(__name__)
REFINE_WAIT_S = 0.25  # longest a refinement waits for the quick answer's upload


class KioskDaemon:
    """The kiosk. `start()` loads bundles, opens the device, starts serving and sends READY; `stop()` undoes it."""

    def __init__(self, config: KioskConfig, *, notifier: Notifier | None = None, display=None,
                 bundle_sources: Sources | None = None):
        """`bundle_sources` replaces the store + configured bundles as what to serve (the A/B study serves each
        condition's bundle under its own name); it is asked again on every reload."""
        self.config = config
        inf = config.inference
        self.metrics = Registry()
        self.series = ServiceMetrics(self.metrics)
        self.usage = self.series.usage
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
                               panel_pitch_mm=config.panel.pitch_mm, quick_tactile=inf.quick_tactile)
        self.device = DeviceOutput(config.device, display=display, on_error=self._device_error,
                                   on_texture=self._texture_made)
        self.bundle_set = BundleSet(config, self.series, bundle_sources)
        self.frames = FrameRenderer(self.planner, self.cache, self.device, self.series, quick_first=inf.refine)
        self.jobs = JobQueue()
        lanes = inf.preview_threads > 0
        self.loop = InferenceLoop(self.jobs, Heartbeat(), self._execute, before=self._before_job,
                                  idle=self.bundle_set.close_retired, lane="main" if lanes else None)
        self.preview_loop = InferenceLoop(self.jobs, Heartbeat(), self._execute, lane="preview",
                                          name="vtkiosk-preview") if lanes else None
        self.heartbeat = self.loop.heartbeat
        self.notifier = notifier if notifier is not None else Notifier.from_env()
        self.watchdog: Watchdog | None = None
        self.control = None
        self._control_handlers: dict[str, Callable[[dict], dict]] = {}
        self.started = False
        self.series.device_up.set_function(lambda: 1.0 if self.device.up else 0.0)
        self.series.degraded.set_function(lambda: 1.0 if self.frames.degraded else 0.0)
        if config.fleet.enabled:
            from kiosk.fleet.state import STATE_FILE, register_metrics

            register_metrics(self.metrics, config.fleet.state_dir / STATE_FILE)

    def _device_error(self, kind: str, exc: BaseException) -> None:
        self.series.device_errors.inc(kind=kind)

    def _texture_made(self, source: FrictionSource) -> None:
        self.series.stage.observe(source.ms / 1e3, stage="friction")
        if source.nonfinite:
            self.series.nonfinite.inc(source.nonfinite)

    # -- bundles -------------------------------------------------------------------------------------------------
    @property
    def bundles(self) -> dict[str, LoadedBundle]:
        return dict(self.bundle_set.serving)

    def reload(self) -> dict:
        """Load what should be served beside what is served, probe it, and swap per garment only when it passes;
        a garment whose new bundle fails keeps its old one. Returns what happened, with reasons."""
        return self.bundle_set.reload()

    # -- life cycle ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        if self.started:
            return
        state = self.config.state_dir
        if state is not None:
            Path(state).mkdir(parents=True, exist_ok=True)
        self.bundle_set.workdir = Path(tempfile.mkdtemp(prefix="vtkiosk-bundles-", dir=state))
        try:
            report = self.reload()
            if not self.bundle_set.serving:
                reasons = "; ".join(f"{e['source']}: {e['reason']}" for e in report["failed"] + report["kept"])
                if not reasons:
                    where = f"the store {self.config.store.root} has no active bundle and " \
                        if self.config.store.root else ""
                    raise BundleError(f"nothing to serve: {where}no bundle is configured; install one with "
                                      "`vtkiosk bundle install FILE --activate`, or pass --bundle FILE")
                raise BundleError(f"no bundle could be loaded ({reasons})")
            self.device.start()
            self.loop.start()
            if self.preview_loop is not None:
                self.preview_loop.start()
            Routes(self.config, self.series, self.bundle_set, self.frames, self.device, self.health,
                   submit=self._submit, status=self.status).install(self.server)
            self.server.start()
            self._start_health()
            self._start_control()
            self.started = True
        except BaseException:
            self.stop()
            raise
        serving = ", ".join(sorted(self.bundle_set.serving))
        self.notifier.ready(f"serving {serving} on {self.server.url}")
        log.info("kiosk serving %s on %s", serving, self.server.url)

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
        self.loop.stop()
        if self.preview_loop is not None:
            self.preview_loop.stop()
        self.device.stop()
        self.bundle_set.close()
        if self.bundle_set.workdir is not None:
            shutil.rmtree(self.bundle_set.workdir, ignore_errors=True)
            self.bundle_set.workdir = None
        self.started = False

    def _start_health(self) -> None:
        h = self.config.health
        budget = self.config.inference.latency_budget_ms / 1e3
        self.add_health_check("inference", lambda: self.heartbeat.check(stale_after_s=h.stale_after_s,
                                                                        budget_s=budget))
        if self.preview_loop is not None:
            beat = self.preview_loop.heartbeat
            self.add_health_check("preview", lambda: beat.check(stale_after_s=h.stale_after_s, budget_s=budget))
        if h.require_device:
            dev = device_check(self._link_health, max_heartbeat_age_s=h.device_max_heartbeat_age_s)
            self.add_health_check("device", dev)
        self.add_health_check("server", http_check(self.server.url + "api/ping", timeout_s=1.0))
        self.add_health_check("bundle", self.bundle_set.check)
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
            return {"ok": ok, **report, **({} if ok else {"error": failure_reason(report)})}
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
            loops = [self.loop] + ([self.preview_loop] if self.preview_loop is not None else [])
            for loop in loops:
                (loop.hang.set if req.get("on", True) else loop.hang.clear)()
            return {"hang": self.loop.hang.is_set()}
        if op == "debug.nonfinite":
            for b in self.bundle_set.serving.values():
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
        timeout = self.config.server.request_timeout_s if timeout_s is None else timeout_s
        return self.jobs.submit(req, received_at, timeout)

    def _before_job(self, job: Job) -> None:
        if job.request.mode == "refine":
            # Let the quick answer's friction frame reach the finger first: on two cores a refinement
            # computed during its upload would delay it.
            self.device.wait_idle(REFINE_WAIT_S)

    def _execute(self, job: Job) -> FrameResult:
        return self.frames.render(job.request, job.received_at, self.bundle_set.serving)

    def put_friction(self, sources: list) -> int:
        """Put friction textures that need no model on the device (the study's familiarisation textures); returns
        the device frame for `wait_commit`. The next rendered scene replaces them."""
        return self.frames.put_friction(sources)

    def wait_commit(self, device_frame: int | None, timeout_s: float = 2.0):
        if device_frame is None:
            return None
        return self.device.wait_commit(device_frame, timeout_s)

    # -- state -----------------------------------------------------------------------------------------------------
    def notices(self) -> list[str]:
        return self.frames.notices()

    def status(self) -> dict:
        report = self.health.last()
        serving = self.bundle_set.serving
        return {"bundles": {g: b.info() for g, b in sorted(serving.items())},
                "device": self.device.state(), "notices": self.notices(), "degraded": bool(self.notices()),
                "scale": self.bundle_set.scale_info(),
                "health": report.to_json() if report else None, "last_reload": self.bundle_set.last_reload,
                "cache": {"entries": len(self.cache), "bytes": self.cache.nbytes, "hits": self.cache.hits,
                          "misses": self.cache.misses},
                "torch_imported": "torch" in sys.modules, "pid": os.getpid(), "rss_bytes": _rss_bytes(),
                "url": self.server.url}


class _Closed:
    """LinkHealth stand-in before the device was ever opened."""

    def __init__(self, error: str | None):
        self.state = "closed"
        self.last_error = error or "not opened yet"
        self.last_heartbeat_age_s = None



def _rss_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0
