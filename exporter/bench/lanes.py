"""One preview-while-refining measurement in a fresh process: `python -m exporter.bench.lanes SPEC.json` prints one
JSON line.

It runs the kiosk itself (`kiosk.service.daemon.KioskDaemon`, in this process, loopback only, emulated device): the
same job queue, inference loops, lanes, planner and frame renderer as a serving kiosk, so what is measured is the
kiosk's scheduling, not a model of it. Two client threads, each with one request in flight (as the page keeps one):
a drawer asking for previews (visual, preview resolution) back to back, and, unless `refine` is false, a refiner
asking for refinements (visual and friction at full resolution) back to back. The output cache is off so every
request computes. Spec: bundle, trusted_keys (or null: unsigned allowed), engine, threads, preview_threads,
seconds, refine, previews (default true).
"""
from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

from kiosk.contract.errors import KioskError


def _rss_mb(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024.0
    return 0.0


def _client(daemon, scene, mode: str, name: str, stop: threading.Event, out: list) -> None:
    from kiosk.service.jobs import Superseded

    while not stop.is_set():
        t0 = time.monotonic()
        try:
            res = daemon.show(scene, {}, client=name, mode=mode, timeout_s=60.0)
        except Superseded:
            continue
        t1 = time.monotonic()
        out.append({"start": t0, "end": t1, "ms": 1e3 * (t1 - t0), "queue_ms": res.timings["queue_ms"],
                    "inference_ms": res.timings["inference_ms"],
                    "grid": list(res.plan.panels[0].grid or ()), "graph": res.plan.panels[0].graph})


def measure(spec: dict) -> dict:
    from kiosk.contract.panels import DEFAULT_PANEL, KNOWN_PANELS
    from kiosk.inference.scene import Panel, Scene
    from kiosk.ops.notify import Notifier
    from kiosk.service.config import config_from_mapping
    from kiosk.service.daemon import KioskDaemon

    store = {"allow_unsigned": spec["trusted_keys"] is None}
    if spec["trusted_keys"] is not None:
        store["trusted_keys"] = spec["trusted_keys"]
    cfg = config_from_mapping({
        "bundles": [spec["bundle"]], "store": store, "server": {"port": 0},
        "inference": {"threads": spec["threads"], "preview_threads": spec["preview_threads"], "cache_mb": 0,
                      "engine": {"type": spec["engine"]}, "latency_budget_ms": 60_000},
        "health": {"require_device": False, "stale_after_s": 120}, "log_level": "WARNING"})
    base = _rss_mb("VmRSS")
    daemon = KioskDaemon(cfg, notifier=Notifier(None))
    daemon.start()
    try:
        garment = next(iter(daemon.bundles))
        p = KNOWN_PANELS[DEFAULT_PANEL]
        scene = Scene((Panel("main", (0, 0, p.width_px, p.height_px), garment, sketch="reference"),),
                      (p.width_px, p.height_px))
        # one of each first: sessions and first-shape allocations are not part of the measurement
        daemon.show(scene, {}, client="drawer", mode="preview", timeout_s=120.0)
        daemon.show(scene, {}, client="refiner", mode="refine", timeout_s=120.0)
        stop = threading.Event()
        previews: list[dict] = []
        refines: list[dict] = []
        workers = []
        if spec.get("previews", True):
            workers.append(threading.Thread(target=_client, args=(daemon, scene, "preview", "drawer", stop,
                                                                  previews)))
        if spec["refine"]:
            workers.append(threading.Thread(target=_client, args=(daemon, scene, "refine", "refiner", stop,
                                                                  refines)))
        t0 = time.monotonic()
        for w in workers:
            w.start()
        time.sleep(float(spec["seconds"]))
        stop.set()
        for w in workers:
            w.join(timeout=120.0)
        t1 = time.monotonic()
        engine = daemon.bundles[garment].engine
    finally:
        daemon.stop()
    return {"previews": previews, "refines": refines, "window_s": t1 - t0, "engine": engine,
            "base_rss_mb": base, "peak_rss_mb": _rss_mb("VmHWM")}


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m exporter.bench.lanes SPEC.json", file=sys.stderr)
        return 2
    try:
        out = measure(json.loads(Path(argv[0]).read_text()))
    except KioskError as exc:
        print(f"lanes: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
