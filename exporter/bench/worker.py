"""One latency measurement in a fresh process: `python -m exporter.bench.worker SPEC.json` prints one JSON line.

A fresh process per configuration makes peak RSS honest (no earlier session's memory, allocator caches or imported
torch in the number) and keeps one configuration's threads from disturbing the next. The spec names an ONNX graph
(+ ONNX Runtime execution provider, or OpenVINO: kind `openvino`, with the `outputs` to fetch) or a training run for
PyTorch eager, the input (.npz with `sketch` and `mask`), runs,
warm-up runs, threads and the threads' wait policy (`passive` or `active` spinning, for both runtimes); optionally
`session` (the kiosk's `SessionSettings` as JSON: arena, memory pattern, execution mode, OpenVINO streams and hint;
it then decides the threads and waiting too), `profile` (ONNX Runtime per-op-type time shares) and `dump` (an .npz
the last run's outputs are written to, for the error column).

Output: latencies in ms, session load time, `base_rss_mb` (the process after imports, before the model) and
`peak_rss_mb` (the process's peak resident set, VmHWM, at the end: interpreter + runtime + model + activations).
"""
from __future__ import annotations

import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

from kiosk.contract.graph import feeds, unpack


def _rss_mb(field: str = "VmHWM") -> float:
    """Peak (VmHWM) or current (VmRSS) resident set of this process in MiB (Linux /proc; ru_maxrss elsewhere)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _profile_summary(path: str, runs: int) -> dict:
    """Per-op-type share of kernel time from an ONNX Runtime profile (the timed runs only)."""
    events = json.loads(Path(path).read_text())
    per_op: Counter = Counter()
    for e in events:
        if e.get("cat") == "Node" and str(e.get("name", "")).endswith("_kernel_time"):
            per_op[e.get("args", {}).get("op_name", "?")] += int(e.get("dur", 0))
    total = sum(per_op.values()) or 1
    return {"kernel_ms_per_run": total / 1e3 / max(runs, 1),
            "ops": [{"op": op, "share": us / total, "ms_per_run": us / 1e3 / max(runs, 1)}
                    for op, us in per_op.most_common()]}


def _onnx_runner(spec: dict, feed: dict):
    import onnxruntime as ort
    from kiosk.bundle.probe import session_options
    # passive: idle worker threads sleep instead of spinning (ORT's default spins; on a shared CPU that doubles
    # latency here). PyTorch gets the same through OMP_WAIT_POLICY, set by the parent before this process starts.
    opts = session_options(int(spec["threads"]), spinning=spec.get("wait") != "passive")
    if spec.get("session"):
        from kiosk.inference.sessions import SessionSettings
        opts = SessionSettings(**spec["session"]).ort_options()
    if spec.get("profile"):
        opts.enable_profiling = True
        opts.profile_file_prefix = str(Path(spec["profile"]) / "ort")
    sess = ort.InferenceSession(spec["path"], opts, providers=[spec.get("provider", "CPUExecutionProvider")])
    outputs = [o.name for o in sess.get_outputs()]
    return (lambda: sess.run(outputs, feed)), sess


def _openvino_runner(spec: dict, feed: dict):
    from kiosk.inference.backends import OpenVinoRunner
    from kiosk.inference.sessions import SessionSettings
    settings = SessionSettings(**spec["session"]) if spec.get("session") else int(spec["threads"])
    runner = OpenVinoRunner(Path(spec["path"]), settings)
    outputs = list(spec["outputs"])
    runner.run(outputs, feed)  # compile for this shape now, so load_ms includes it (as the kiosk's activation does)
    return (lambda: runner.run(outputs, feed)), None


def _torch_runner(spec: dict, feed: dict):
    import torch
    from exporter.graphs import eager_module
    from trainer.checkpoint import load_generator
    torch.set_num_threads(int(spec["threads"]))
    generator, _ = load_generator(Path(spec["run"]), spec.get("which", "best"))
    module = eager_module(generator, spec["graph"])
    x = tuple(torch.from_numpy(a) for a in unpack(feed))

    def run():
        with torch.inference_mode():
            return module(*x)
    return run, None


def measure(spec: dict) -> dict:
    with np.load(spec["input"]) as z:
        feed = feeds(*unpack(z))
    if spec["kind"] == "torch":
        import torch  # noqa: F401 - imported before the baseline so the baseline includes the framework
    elif spec["kind"] == "openvino":
        import openvino  # noqa: F401
    else:
        import onnxruntime  # noqa: F401
    base = _rss_mb("VmRSS")
    t0 = time.perf_counter()
    make = {"torch": _torch_runner, "openvino": _openvino_runner}.get(spec["kind"], _onnx_runner)
    run, sess = make(spec, feed)
    load_ms = 1e3 * (time.perf_counter() - t0)
    for _ in range(int(spec["warmup"])):
        run()
    times, last = [], None
    for _ in range(int(spec["runs"])):
        t = time.perf_counter()
        last = run()
        times.append(1e3 * (time.perf_counter() - t))
    if spec.get("dump") and last is not None:
        np.savez(spec["dump"], *[np.asarray(o) for o in last])
    out = {"times_ms": times, "load_ms": load_ms, "base_rss_mb": base, "peak_rss_mb": _rss_mb("VmHWM")}
    if sess is not None and spec.get("profile"):
        out["profile"] = _profile_summary(sess.end_profiling(), int(spec["runs"]) + int(spec["warmup"]))
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m exporter.bench.worker SPEC.json", file=sys.stderr)
        return 2
    spec = json.loads(Path(argv[0]).read_text())
    print(json.dumps(measure(spec)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
