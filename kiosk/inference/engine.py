"""Inference: a verified bundle's engine sessions, the output cache, and finite checks on every output.

One `LoadedBundle` per garment holds its sessions (created on first use per graph kind and lane, in the configured
engine (`kiosk.inference.backends`; `auto` picks one at construction by timing them), with the configured session
settings and provider; `warm()` creates and runs them ahead of the first stroke), its friction calibration and its
reference assets. A lane is who runs the graph: `main` (stroke ends, refinements) or `preview` (while drawing); with
`preview_threads` the preview lane has sessions of its own with that many threads, so a preview computed beside a
running refinement does not queue for the refinement's thread pool. Outputs are checked before anything downstream
sees them: a graph that returns NaN/Inf raises `NonFiniteOutput` and the daemon keeps its last good frame.
`OutputCache` keeps recent outputs by the planner's content key, so an unchanged sketch (undo, a re-layout, a device
reconnect) costs no inference.

Shapes: visual is kept as RGBA uint8 (H, W, 4) (alpha = the object mask: what the page draws), tactile as float32
(2, H, W) (gx, gy), both at the network grid.
"""
from __future__ import annotations

import hashlib
import shutil
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from kiosk.bundle.archive import MANIFEST, Bundle
from kiosk.contract.errors import KioskError
from kiosk.bundle.manifest import BundleError
from kiosk.inference.autoselect import EngineChoice, choose_engine
from kiosk.inference.backends import Runner, open_graph
from kiosk.inference.sessions import SessionSettings
from kiosk.contract.graph import OUTPUT_CHANNELS, feeds
from kiosk.contract.sketch import NetworkInput

MODALITIES = ("visual", "tactile")
LANES = ("main", "preview")


class InferenceError(KioskError):
    """A graph failed to run; the daemon keeps the last good frame."""


class NonFiniteOutput(InferenceError):
    """A graph returned NaN or Inf; nothing of it reaches the screen or the device."""


def visual_rgba(visual: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(1, 3, H, W) tanh output in [-1, 1] + (H, W) mask -> (H, W, 4) uint8 RGBA, alpha 255 on the object."""
    # clip first: convertScaleAbs would fold a value below -1 back up (|x|); it saturates and rounds above
    planes = [cv2.convertScaleAbs(np.clip(c, -1.0, 1.0), alpha=127.5, beta=127.5) for c in visual[0]]
    return cv2.merge(planes + [np.where(mask, np.uint8(255), np.uint8(0))])


class OutputCache:
    """LRU of model outputs keyed by (content key, modality), bounded in bytes. Thread-safe."""

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict[tuple[str, str], np.ndarray] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def has(self, key: str | None, modality: str) -> bool:
        with self._lock:
            return key is not None and (key, modality) in self._items

    def get(self, key: str, modality: str) -> np.ndarray | None:
        with self._lock:
            item = self._items.get((key, modality))
            if item is None:
                self.misses += 1
                return None
            self._items.move_to_end((key, modality))
            self.hits += 1
            return item

    def put(self, key: str, modality: str, value: np.ndarray) -> None:
        if value.nbytes > self.max_bytes:
            return
        value = value.copy()
        value.setflags(write=False)
        with self._lock:
            old = self._items.pop((key, modality), None)
            if old is not None:
                self._bytes -= old.nbytes
            self._items[(key, modality)] = value
            self._bytes += value.nbytes
            while self._bytes > self.max_bytes:
                _, dropped = self._items.popitem(last=False)
                self._bytes -= dropped.nbytes

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0

    @property
    def nbytes(self) -> int:
        return self._bytes

    def __len__(self) -> int:
        return len(self._items)


@dataclass(frozen=True)
class RunResult:
    outputs: dict[str, np.ndarray]  # modality -> (1, C, H, W) float32, finite
    ms: float


class LoadedBundle:
    """A verified bundle ready to serve: sessions (lazy), calibration, reference assets, and its cache identity.

    `owned_dir`: a folder this object removes on `close()` (an archive unpacked for serving).
    """

    def __init__(self, bundle: Bundle, *, threads: int = 2, providers: list[str] | None = None,
                 precisions: tuple[str, ...] = ("int8", "fp32", "fp16"), owned_dir: Path | None = None,
                 source: str = "", engine: str = "onnxruntime", auto_max_side: int = 512, auto_runs: int = 3,
                 preview_threads: int = 0, settings: SessionSettings | None = None):
        """`preview_threads`: threads of the preview lane's own sessions; 0: previews use the main lane's.
        `settings`: the engine's session settings (`threads` is replaced by the lane's)."""
        m = bundle.manifest
        for kind, spec in m.graphs.items():
            if spec.precision not in precisions:
                raise BundleError(f"bundle {m.garment_id}: the {kind} graph is {spec.precision}, which this kiosk "
                                  f"does not run (inference.precisions: {', '.join(precisions)})")
        self.bundle = bundle
        self.manifest = m
        self.source = source
        self.threads = threads
        self.preview_threads = preview_threads
        self.settings = settings or SessionSettings()
        self.providers = providers or ["CPUExecutionProvider"]
        self.owned_dir = owned_dir
        digest = hashlib.sha256((bundle.root / MANIFEST).read_bytes()).hexdigest()[:16]
        self.key = f"{m.garment_id}@{m.model_version}#{digest}"
        self._sessions: dict[tuple[str, str], Runner] = {}
        self.engine_choice: EngineChoice | None = None
        if engine == "auto":
            try:
                self.engine_choice = choose_engine(bundle, threads=threads, providers=self.providers,
                                                   max_side=auto_max_side, runs=auto_runs, settings=self.settings)
            except Exception as exc:  # noqa: BLE001 - the reference engine itself failed: the bundle is unusable
                raise InferenceError(f"{m.garment_id}: engine benchmark failed ({exc})") from exc
            engine = self.engine_choice.engine
        self.engine = engine
        self._lock = threading.Lock()
        self._sketch = bundle.asset("sketch") if "sketch" in m.assets else None
        mask = bundle.asset("mask") if "mask" in m.assets else None
        self._bbox = _bbox_of(mask) if mask is not None else _bbox_of(self._sketch < 128) \
            if self._sketch is not None else None
        self.fault_nonfinite = False  # debug hook: poison the next outputs (tests of the keep-last-good path)

    # -- what the planner asks -----------------------------------------------------------------------------------
    @property
    def garment_id(self) -> str:
        return self.manifest.garment_id

    def graphs(self) -> tuple[str, ...]:
        return tuple(self.manifest.graphs)

    def cap(self, kind: str) -> tuple[int, int]:
        """The largest declared input size of a graph (width, height): int8 graphs are calibrated only there."""
        sizes = self.manifest.graph(kind).sizes
        return max(w for w, _ in sizes), max(h for _, h in sizes)

    def reference_sketch(self) -> np.ndarray:
        if self._sketch is None:
            raise BundleError(f"bundle {self.garment_id} ships no reference sketch")
        return self._sketch

    def reference_bbox(self) -> tuple[int, int, int, int]:
        if self._bbox is None:
            raise BundleError(f"bundle {self.garment_id} ships no reference mask or sketch")
        return self._bbox

    @property
    def friction_scale(self) -> float:
        return self.manifest.friction_scale

    @property
    def friction_normalization(self) -> str:
        return self.manifest.friction_normalization

    @property
    def friction_constants(self) -> dict[str, float]:
        return self.manifest.friction_constants

    @property
    def pixel_pitch_mm(self) -> float:
        """The pitch (mm per model pixel) the bundle's model learned its texture at."""
        return self.manifest.pixel_pitch_mm

    def sizes(self, kind: str) -> list[tuple[int, int]]:
        """The input sizes (width, height) a graph declares."""
        return [(int(w), int(h)) for w, h in self.manifest.graph(kind).sizes]

    def info(self) -> dict:
        m = self.manifest
        return {"id": m.garment_id, "display_name": m.display_name, "model_version": m.model_version,
                "method": m.method, "branches": m.branches, "key": self.key, "signed_by": self.bundle.key_id,
                "graphs": {k: {"precision": g.precision, "sizes": g.sizes} for k, g in m.graphs.items()},
                "assets": sorted(m.assets), "friction_scale": m.friction_scale,
                "friction_normalization": m.friction_normalization, "pixel_pitch_mm": m.pixel_pitch_mm,
                "source": self.source, "engine": self.engine,
                "engine_choice": self.engine_choice.to_json() if self.engine_choice else None}

    # -- sessions ------------------------------------------------------------------------------------------------
    def lane_of(self, lane: str) -> str:
        """The lane whose sessions serve `lane`: the preview lane has its own only with `preview_threads`."""
        if lane not in LANES:
            raise ValueError(f"lane must be one of {', '.join(LANES)}; got {lane!r}")
        return "preview" if lane == "preview" and self.preview_threads > 0 else "main"

    def session(self, kind: str, lane: str = "main") -> Runner:
        lane = self.lane_of(lane)
        with self._lock:
            sess = self._sessions.get((kind, lane))
            if sess is None:
                path = self.bundle.graph_path(kind)
                threads = self.preview_threads if lane == "preview" else self.threads
                try:
                    sess = open_graph(self.engine, path, threads=threads, providers=self.providers,
                                      settings=self.settings)
                except Exception as exc:  # noqa: BLE001 - the engines' own exception types; all mean "unusable"
                    raise InferenceError(f"{self.garment_id}: graph {kind} does not load ({exc})") from exc
                self._sessions[(kind, lane)] = sess
            return sess

    def run(self, kind: str, inputs: NetworkInput, lane: str = "main") -> RunResult:
        """Run one graph in `lane`; raise NonFiniteOutput/InferenceError instead of returning anything unusable."""
        spec = self.manifest.graph(kind)
        sess = self.session(kind, lane)
        h, w = inputs.sketch.shape[2:]
        t0 = time.perf_counter()
        try:
            outs = sess.run(spec.outputs, feeds(inputs.sketch, inputs.mask))
        except Exception as exc:  # noqa: BLE001
            raise InferenceError(f"{self.garment_id}: graph {kind} failed at {w}x{h} ({exc})") from exc
        ms = 1e3 * (time.perf_counter() - t0)
        result: dict[str, np.ndarray] = {}
        for name, out in zip(spec.outputs, outs):
            want = (1, OUTPUT_CHANNELS[name], h, w)
            if tuple(out.shape) != want:
                raise InferenceError(f"{self.garment_id}: graph {kind} output {name} has shape "
                                     f"{tuple(out.shape)}, expected {want}")
            if self.fault_nonfinite:
                out = np.full_like(out, np.nan)
            bad = int(out.size - np.count_nonzero(np.isfinite(out)))
            if bad:
                raise NonFiniteOutput(f"{self.garment_id}: graph {kind} returned {bad} non-finite values at "
                                      f"{w}x{h}; keeping the last good frame")
            result[name] = out
        return RunResult(result, ms)

    def warm(self, kinds: tuple[str, ...], grids: list[tuple[int, int]], lane: str = "main"
             ) -> list[tuple[str, tuple[int, int], float]]:
        """Create the sessions of `lane` and run each (kind, grid) once on an empty sketch, so the first stroke does
        not pay session creation and first-shape allocation. Returns (kind, grid, ms) per run."""
        out = []
        for kind in kinds:
            if kind not in self.manifest.graphs:
                continue
            for gw, gh in grids:
                x = NetworkInput(np.zeros((1, 1, gh, gw), np.float32), np.zeros((1, 1, gh, gw), np.float32))
                out.append((kind, (gw, gh), self.run(kind, x, lane).ms))
        return out

    def close(self) -> None:
        with self._lock:
            self._sessions.clear()
        if self.owned_dir is not None:
            shutil.rmtree(self.owned_dir, ignore_errors=True)


def _bbox_of(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    ys = np.flatnonzero(mask.any(axis=1))
    xs = np.flatnonzero(mask.any(axis=0))
    if ys.size == 0:
        return (0, 0, mask.shape[1], mask.shape[0])
    return int(xs[0]), int(ys[0]), int(xs[-1] - xs[0] + 1), int(ys[-1] - ys[0] + 1)
