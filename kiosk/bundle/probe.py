"""Probe a bundle's graphs in ONNX Runtime: they load, run, and give finite outputs of the declared shapes.

Used by `vtkiosk bundle verify`, by install, and by the daemon before it swaps to a new bundle.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import onnxruntime as ort

from kiosk.bundle.archive import Bundle
from kiosk.bundle.manifest import BundleError
from kiosk.contract.graph import INPUT_NAMES, OUTPUT_CHANNELS, feeds
from kiosk.contract.sketch import letterbox, network_input, object_mask


@dataclass(frozen=True)
class ProbeResult:
    graph: str
    size: tuple[int, int]
    precision: str
    load_ms: float
    run_ms: float


def session_options(threads: int, *, spinning: bool = False) -> ort.SessionOptions:
    """The kiosk's ONNX Runtime settings. Idle intra-op threads sleep rather than spin by default: the HTTP and haptic
    threads share the cores, and a spinning pool takes the CPU they need (docs/performance.md, thread spinning)."""
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    return opts


def probe_bundle(bundle: Bundle, *, threads: int = 2, providers: list[str] | None = None,
                 every_size: bool = False, report=None) -> list[ProbeResult]:
    """Run every graph once on the bundle's own sketch: at its smallest declared size (install and the daemon's
    swap, which must stay within a latency budget), or at every declared size (`every_size`, what `bundle verify`
    does: a graph can load and pass at 256 px and still fail at a larger size it declares). `report` gets each
    result as it passes, so a failure is shown after what did pass. Raises BundleError."""
    sketch = bundle.asset("sketch")
    results = []
    for kind, spec in bundle.manifest.graphs.items():
        sizes = sorted({(w, h) for w, h in spec.sizes}, key=lambda s: (s[0] * s[1], s))
        sess, load_ms = None, 0.0
        for w, h in sizes if every_size else sizes[:1]:
            sess, load_ms = _probe_one(bundle, kind, spec, sketch, (w, h), threads, providers, sess, load_ms,
                                       results)
            if report is not None:
                report(results[-1])
    return results


def _probe_one(bundle, kind, spec, sketch, size, threads, providers, sess, load_ms, results):
    """One (graph, size) probe; the session is created on the graph's first size and reused for the others."""
    w, h = size
    fitted, _ = letterbox(sketch, (w, h))
    x = network_input(fitted, object_mask(fitted))
    if sess is None:
        t0 = time.perf_counter()
        try:
            sess = ort.InferenceSession(str(bundle.graph_path(kind)), session_options(threads),
                                        providers=providers or ["CPUExecutionProvider"])
        except Exception as exc:  # noqa: BLE001 - ORT raises its own exception types; all mean "unusable"
            raise BundleError(f"graph {spec.file} does not load in ONNX Runtime: {exc}") from exc
        load_ms = 1e3 * (time.perf_counter() - t0)
    names = {i.name for i in sess.get_inputs()}
    if names != set(INPUT_NAMES):
        raise BundleError(f"graph {spec.file} takes inputs {sorted(names)}; expected {sorted(INPUT_NAMES)}")
    t1 = time.perf_counter()
    try:
        outs = sess.run(spec.outputs, feeds(x.sketch, x.mask))
    except Exception as exc:  # noqa: BLE001
        raise BundleError(f"graph {spec.file} failed on a {w}x{h} probe sketch: {exc}") from exc
    t2 = time.perf_counter()
    for name, out in zip(spec.outputs, outs):
        want = (1, OUTPUT_CHANNELS[name], h, w)
        if tuple(out.shape) != want:
            raise BundleError(f"graph {spec.file} output {name} has shape {tuple(out.shape)}; expected {want}")
        if not np.isfinite(out).all():
            raise BundleError(f"graph {spec.file} output {name} has non-finite values on the {w}x{h} probe sketch")
    results.append(ProbeResult(kind, (w, h), spec.precision, load_ms, 1e3 * (t2 - t1)))
    return sess, load_ms
