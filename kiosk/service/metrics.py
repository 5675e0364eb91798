"""Every series the kiosk daemon exports on /metrics, named in one place (the parts that update them share it)."""
from __future__ import annotations

from kiosk.ops.metrics import Registry
from kiosk.service.usage import UsageMetrics


class ServiceMetrics:
    def __init__(self, r: Registry):
        self.registry = r
        self.frames = r.counter("vtkiosk_frames_total", "Render jobs completed.", labels=("kind",))
        self.stage = r.histogram("vtkiosk_stage_seconds", "Time per pipeline stage.", labels=("stage",))
        self.e2e = r.histogram("vtkiosk_e2e_seconds", "Request received -> visual ready / friction committed.",
                               labels=("target",))
        self.inference_errors = r.counter("vtkiosk_inference_errors_total",
                                          "Inference failures (the last good frame stayed).", labels=("reason",))
        self.device_errors = r.counter("vtkiosk_device_errors_total", "Haptic device errors.", labels=("kind",))
        self.device_up = r.gauge("vtkiosk_device_up", "1 while the haptic link is up.")
        self.degraded = r.gauge("vtkiosk_degraded", "1 while the kiosk shows a degraded notice.")
        self.engine = r.gauge("vtkiosk_engine_selected", "1 for the inference engine each garment runs on.",
                              labels=("garment", "engine"))
        self.engine_ms = r.gauge("vtkiosk_engine_bench_ms", "Activation benchmark (engine: auto): median ms per "
                                 "pass over the bundle's graphs.", labels=("garment", "engine"))
        self.engine_err = r.gauge("vtkiosk_engine_bench_error_levels", "Activation benchmark: friction-map mean "
                                  "|diff| vs ONNX Runtime, levels, worst graph.", labels=("garment", "engine"))
        self.cache = r.counter("vtkiosk_cache_total", "Output cache lookups by the planner.", labels=("result",))
        self.pixels = r.counter("vtkiosk_pixels_total", "Network pixels computed vs the naive full-frame plan.",
                                labels=("plan",))
        self.graph_runs = r.counter("vtkiosk_graph_runs_total", "Graph runs by kind.", labels=("graph",))
        self.reloads = r.counter("vtkiosk_reloads_total", "Bundle reloads by outcome.", labels=("result",))
        self.requests = r.histogram("vtkiosk_http_request_seconds", "HTTP request latency.", labels=("route",))
        self.nonfinite = r.counter("vtkiosk_nonfinite_values_total",
                                   "Non-finite tactile values replaced by 0 in friction maps.")
        self.usage = UsageMetrics(r)
