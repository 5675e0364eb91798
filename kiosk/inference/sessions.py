"""Session settings of the two engines, in one place: what the kiosk, `auto` and the benchmarks all open graphs with.

On a 2-core kiosk every knob here trades the shopper's preview against the refinement and the browser, so each
default is the one `vtkiosk bench threads` measured best (docs/performance.md, "Threads, arenas and lanes"), not a
library's default:

- ONNX Runtime: intra-op threads; idle threads sleep instead of spinning (a spinning pool takes the core the HTTP,
  haptic and browser threads need); the CPU memory arena and the memory-pattern planner (both only decide where
  activations live, never what is computed); sequential or parallel execution of independent nodes.
- OpenVINO: inference threads, streams and the performance hint (LATENCY runs one request on every thread,
  THROUGHPUT splits the threads between streams for many requests at once).

None of these changes the arithmetic of a single run beyond the order of float reductions across threads, so a
setting's error against fp32 is the graph's own precision error (measured, not assumed, by the benchmark).
"""
from __future__ import annotations

from dataclasses import dataclass

EXECUTION_MODES = ("sequential", "parallel")
OPENVINO_HINTS = ("latency", "throughput")


@dataclass(frozen=True)
class SessionSettings:
    """How one engine session is opened. `threads`: intra-op (ONNX Runtime) or inference (OpenVINO) threads."""

    threads: int = 2
    spinning: bool = False
    mem_arena: bool = True
    mem_pattern: bool = True
    execution_mode: str = "sequential"
    streams: int = 1
    hint: str = "latency"

    def __post_init__(self) -> None:
        if not (isinstance(self.threads, int) and 1 <= self.threads <= 64):
            raise ValueError(f"session threads must be an integer from 1 to 64; got {self.threads!r}")
        if self.execution_mode not in EXECUTION_MODES:
            raise ValueError(f"execution mode must be one of {', '.join(EXECUTION_MODES)}; got "
                             f"{self.execution_mode!r}")
        if not (isinstance(self.streams, int) and 1 <= self.streams <= 16):
            raise ValueError(f"OpenVINO streams must be an integer from 1 to 16; got {self.streams!r}")
        if self.hint not in OPENVINO_HINTS:
            raise ValueError(f"OpenVINO hint must be one of {', '.join(OPENVINO_HINTS)}; got {self.hint!r}")

    def ort_options(self):
        """`onnxruntime.SessionOptions` for these settings (imported here: the OpenVINO path never needs it)."""
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = self.threads
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        opts.enable_cpu_mem_arena = self.mem_arena
        opts.enable_mem_pattern = self.mem_pattern
        opts.execution_mode = (ort.ExecutionMode.ORT_PARALLEL if self.execution_mode == "parallel"
                               else ort.ExecutionMode.ORT_SEQUENTIAL)
        opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if self.spinning else "0")
        return opts

    def openvino_config(self) -> dict:
        """The CPU plugin's compile properties. f32 precision hint: on bf16/AMX CPUs the plugin would otherwise
        compute in bf16, outside the bundle's stated error."""
        return {"INFERENCE_NUM_THREADS": self.threads, "NUM_STREAMS": self.streams,
                "PERFORMANCE_HINT": self.hint.upper(), "INFERENCE_PRECISION_HINT": "f32"}

    def label(self, engine: str) -> str:
        """A short name of what differs from the defaults, for tables and plots."""
        if engine == "openvino":
            return f"{self.threads}t {self.streams}s {self.hint}"
        parts = [f"{self.threads}t", self.execution_mode[:3]]
        if not self.mem_arena:
            parts.append("no-arena")
        if not self.mem_pattern:
            parts.append("no-pattern")
        if self.spinning:
            parts.append("spin")
        return " ".join(parts)

    def to_json(self) -> dict:
        return {"threads": self.threads, "spinning": self.spinning, "mem_arena": self.mem_arena,
                "mem_pattern": self.mem_pattern, "execution_mode": self.execution_mode, "streams": self.streams,
                "hint": self.hint}
