"""The kiosk's HTTP route table, in one place: what the page, operators and Prometheus can ask.

    GET  /api/ping                      liveness of the server itself (the health check's probe)
    GET  /api/bundles[/<id>/<a>.png]    the served garments, and their reference assets
    POST /api/render                    strokes in, the page's binary frame out (`kiosk.service.frames`)
    GET  /api/page                      the page's timings and texts (config `page`)
    POST /api/usage                     anonymous usage events (counted in /metrics)
    GET  /api/plan                      the last frame's plan
    GET  /api/status                    everything `vtkiosk status` shows
    GET  /api/commit?frame=N[&wait=S]   when a friction frame reached the device
    GET  /api/debug/device-frame        the emulated device's committed frame (PNG; in-process emulator only)
    GET  /healthz                       the health checks (503 when one fails)
    GET  /metrics                       Prometheus text format

Another room mounts its own prefix beside these (the study mounts `/api/study/` on `daemon.server`).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2

from kiosk.contract.errors import InputError
from kiosk.ops.health import HealthMonitor
from kiosk.service.api import parse_render_request
from kiosk.service.bundles import BundleSet
from kiosk.service.config import KioskConfig
from kiosk.service.device_output import DeviceOutput
from kiosk.service.frames import FrameRenderer, FrameResult, frame_response_body
from kiosk.service.jobs import BusyError, Superseded
from kiosk.service.metrics import ServiceMetrics
from kiosk.service.server import KioskServer, Request, Response
from kiosk.service.usage import parse_usage_event

PROMETHEUS_TEXT = "text/plain; version=0.0.4; charset=utf-8"


@dataclass
class Routes:
    """The handlers, given the parts of the daemon they read. `submit(request, received_at)` runs a render job;
    `status()` is the daemon's status document."""

    config: KioskConfig
    metrics: ServiceMetrics
    bundles: BundleSet
    frames: FrameRenderer
    device: DeviceOutput
    health: HealthMonitor
    submit: Callable
    status: Callable[[], dict]

    def install(self, s: KioskServer) -> None:
        s.route("GET", "/api/ping", lambda req: Response.json({"ok": True}))
        s.route("GET", "/api/bundles", self.bundles_api)
        s.route("POST", "/api/render", self.render)
        s.route("GET", "/api/page", lambda req: Response.json(self.config.page.to_json()))
        s.route("POST", "/api/usage", self.usage)
        s.route("GET", "/api/plan", lambda req: Response.json({"plan": self.frames.last_plan}))
        s.route("GET", "/api/status", lambda req: Response.json(self.status()))
        s.route("GET", "/api/commit", self.commit)
        s.route("GET", "/api/debug/device-frame", self.device_frame)
        s.route("GET", "/healthz", self.healthz)
        s.route("GET", "/metrics", lambda req: Response.text(self.metrics.registry.render(), PROMETHEUS_TEXT))
        s.on_request = lambda method, route, status, secs: self.metrics.requests.observe(secs, route=route)

    def healthz(self, req: Request) -> Response:
        report = self.health.run()  # fresh: the checks only read state the working threads keep
        body = {**report.to_json(), "scale": self.bundles.scale_info(), "engines": self.bundles.engine_info()}
        if self.config.fleet.enabled:
            from kiosk.fleet.state import STATE_FILE, section

            body["fleet"] = section(self.config.fleet.state_dir / STATE_FILE, self.config.fleet.stale_after_s)
        return Response.json(body, 200 if report.ok else 503)

    def bundles_api(self, req: Request) -> Response:
        parts = req.path.split("/")  # /api/bundles[/<id>/<asset>.png]
        bundles = self.bundles.serving
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

    def render(self, req: Request) -> Response:
        parsed = parse_render_request(req.json())
        try:
            result = self.submit(parsed, req.received_at)
        except Superseded:
            return Response.json({"superseded": True}, 200)
        except BusyError as exc:
            return Response.error(503, str(exc))
        return frame_response(result)

    def usage(self, req: Request) -> Response:
        self.metrics.usage.record(parse_usage_event(req.json()))
        return Response(204)

    def commit(self, req: Request) -> Response:
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

    def device_frame(self, req: Request) -> Response:
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


def frame_response(result: FrameResult) -> Response:
    """The page's binary frame (`kiosk.service.frames.frame_response_body`) as an uncached response."""
    return Response(200, frame_response_body(result), "application/octet-stream", {"Cache-Control": "no-store"})
