"""What the two ways of storing a garment's shared weights cost at run time (docs/performance.md, "Bundle bytes").

    .venv/bin/python scripts/bundle_layout_costs.py --shared S.vtb --embedded E.vtb --trusted-keys KEYS \\
        --json out/layout.json

1. One multi-output graph instead of one graph per need: is the unused branch skipped when only one output is
   asked for? The shared bundle's full graph asked for `tactile` alone, against its tactile graph, in ONNX Runtime
   and OpenVINO (OpenVINO computes every output of a compiled model, so the full graph there is both outputs).
2. Shared against embedded weights: unpack and verify, load the three graphs, peak RSS, and a hash of the outputs,
   each repeat in a fresh process (RSS and load are per process).
Prints Markdown tables (median and p95 beside each other) and writes JSON with the CPU model and ISA.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_LOAD = r'''
import hashlib, json, sys, tempfile, time
from pathlib import Path
from kiosk.bundle.archive import open_bundle
from kiosk.bundle.signature import load_trusted_keys
from kiosk.contract.graph import feeds
from kiosk.contract.sketch import letterbox, network_input, object_mask
from kiosk.inference.backends import open_graph
path, engine, keys = sys.argv[1:4]
with tempfile.TemporaryDirectory() as tmp:
    t0 = time.perf_counter()
    b = open_bundle(Path(path), load_trusted_keys(Path(keys)), workdir=Path(tmp))
    verify = time.perf_counter() - t0
    fitted, _ = letterbox(b.asset("sketch"), (256, 256))
    x = network_input(fitted, object_mask(fitted))
    h, load = hashlib.sha256(), 0.0
    for kind, spec in b.manifest.graphs.items():
        t1 = time.perf_counter()
        runner = open_graph(engine, b.graph_path(kind), threads=1)
        load += time.perf_counter() - t1
        for out in runner.run(spec.outputs, feeds(x.sketch, x.mask)):
            h.update(out.tobytes())
print(json.dumps({"verify_ms": 1e3 * verify, "load_ms": 1e3 * load,
                  # VmHWM: this process image's own peak (ru_maxrss would carry the forking parent's)
                  "peak_rss_mib": int(next(l for l in open("/proc/self/status") if l.startswith("VmHWM")).split()[1])
                  / 1024,
                  "outputs_sha256": h.hexdigest()[:16]}))
'''


def _stats(xs: list[float]) -> tuple[float, float]:
    xs = sorted(xs)
    return statistics.median(xs), xs[min(len(xs) - 1, round(0.95 * (len(xs) - 1)))]


def branch_skip(bundle, size: int, runs: int, engines: list[str]) -> list[dict]:
    import numpy as np

    from kiosk.contract.graph import feeds
    from kiosk.inference.backends import open_graph

    rng = np.random.default_rng(0)
    sketch = (rng.random((1, 1, size, size)) > 0.9).astype(np.float32)
    f = feeds(sketch, np.ones_like(sketch))
    rows = []
    for engine in engines:
        cases = [("full", ["visual", "tactile"]), ("full", ["tactile"]), ("tactile", ["tactile"])]
        if engine == "openvino":
            cases = cases[::2]
        for kind, outs in cases:
            runner = open_graph(engine, bundle.graph_path(kind), threads=1)
            runner.run(outs, f)
            ts = []
            for _ in range(runs):
                t0 = time.perf_counter()
                runner.run(outs, f)
                ts.append(1e3 * (time.perf_counter() - t0))
            p50, p95 = _stats(ts)
            rows.append({"engine": engine, "graph": kind, "outputs": outs, "size": size, "p50_ms": p50,
                         "p95_ms": p95, "times_ms": ts})
    return rows


def load_costs(shared: Path, embedded: Path, keys: Path, repeats: int, engines: list[str]) -> list[dict]:
    rows = []
    for _ in range(repeats):
        for layout, path in (("embedded", embedded), ("shared", shared)):
            for engine in engines:
                out = subprocess.run([sys.executable, "-c", _LOAD, str(path), engine, str(keys)], check=True,
                                     capture_output=True, text=True).stdout
                rows.append({"layout": layout, "engine": engine, "bytes": path.stat().st_size,
                             **json.loads(out.strip().splitlines()[-1])})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--shared", type=Path, required=True)
    p.add_argument("--embedded", type=Path, required=True)
    p.add_argument("--trusted-keys", type=Path, required=True)
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--runs", type=int, default=9)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", type=Path, default=None)
    a = p.parse_args(argv)
    from kiosk.bundle.archive import open_bundle
    from kiosk.bundle.signature import load_trusted_keys
    from kiosk.inference.backends import available
    from kiosk.inference.cpu import describe

    engines = list(available())
    with tempfile.TemporaryDirectory() as tmp:
        bundle = open_bundle(a.shared, load_trusted_keys(a.trusted_keys), workdir=Path(tmp))
        skip = branch_skip(bundle, a.size, a.runs, engines)
    load = load_costs(a.shared, a.embedded, a.trusted_keys, a.repeats, engines)
    print(f"| engine | graph | outputs asked | {a.size} px p50 ms | p95 ms |\n|---|---|---|---:|---:|")
    for r in skip:
        print(f"| {r['engine']} | {r['graph']} | {', '.join(r['outputs'])} | {r['p50_ms']:.1f} | {r['p95_ms']:.1f} |")
    print("\n| layout | engine | bundle MB | verify ms p50 / p95 | load 3 graphs ms p50 / p95 | peak RSS MiB | outputs |"
          "\n|---|---|---:|---:|---:|---:|---|")
    for layout in ("embedded", "shared"):
        for engine in engines:
            rs = [r for r in load if r["layout"] == layout and r["engine"] == engine]
            v, ld = _stats([r["verify_ms"] for r in rs]), _stats([r["load_ms"] for r in rs])
            print(f"| {layout} | {engine} | {rs[0]['bytes'] / 1e6:.2f} | {v[0]:.0f} / {v[1]:.0f} | "
                  f"{ld[0]:.0f} / {ld[1]:.0f} | {max(r['peak_rss_mib'] for r in rs):.0f} | "
                  f"{', '.join(sorted({r['outputs_sha256'] for r in rs}))} |")
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"cpu": describe(), "threads": 1, "branch_skip": skip, "load": load},
                                     indent=1) + "\n")
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
