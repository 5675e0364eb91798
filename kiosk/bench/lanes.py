"""One preview-while-refining measurement: `python -m kiosk.bench.lanes SPEC.json` prints one JSON line.

It runs the kiosk itself (`vtkiosk serve`, loopback, emulated device) with the spec's thread split, so what is
measured is the kiosk's own scheduling (job queue, inference loops, lanes, planner, frame renderer, HTTP), not a
model of it. Two clients, each with one request in flight as the page keeps one: a drawer asking for previews
(visual, preview resolution) back to back and, unless `refine` is false, a refiner asking for refinements (visual
and friction at full resolution) back to back. The output cache is off so every request computes.

Spec: bundle, trusted_keys (null: unsigned allowed), engine, threads, preview_threads, seconds, refine, previews.
"""
from __future__ import annotations

import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

from kiosk.bench.e2e import BenchError, Client, _frame, _proc_mem, daemon_process
from kiosk.contract.errors import KioskError
from kiosk.contract.panels import DEFAULT_PANEL, KNOWN_PANELS


def _body(garment: str, mode: str, client: str) -> dict:
    p = KNOWN_PANELS[DEFAULT_PANEL]
    return {"garment": garment, "panel": {"x": 0, "y": 0, "w": p.width_px, "h": p.height_px},
            "screen": [p.width_px, p.height_px], "strokes": [], "base": True, "mode": mode, "client": client}


def _render(client: Client, body: dict) -> dict | None:
    """The frame's metadata, or None when the request was superseded."""
    status, data = client.request("POST", "/api/render", body)
    if status != 200:
        raise BenchError(f"{body['mode']} failed: HTTP {status}: {data[:200]!r}")
    if data.startswith(b"{\"superseded\""):
        return None  # {"superseded": true}
    return _frame(data)


def _loop(url: str, body: dict, stop: threading.Event, out: list, errors: list) -> None:
    client = Client(url)
    try:
        while not stop.is_set():
            t0 = time.monotonic()
            meta = _render(client, body)
            t1 = time.monotonic()
            if meta is None:
                continue
            panel = meta["plan"]["panels"][0]
            out.append({"ms": 1e3 * (t1 - t0), "queue_ms": meta["timings"]["queue_ms"],
                        "inference_ms": meta["timings"]["inference_ms"], "grid": panel["grid"],
                        "graph": panel["graph"]})
    except (BenchError, KioskError, OSError) as exc:
        errors.append(str(exc))


def measure(spec: dict) -> dict:
    config = {"inference": {"threads": spec["threads"], "preview_threads": spec["preview_threads"], "cache_mb": 0,
                            "engine": {"type": spec["engine"]}, "latency_budget_ms": 60_000},
              "health": {"stale_after_s": 120}}
    trusted = Path(spec["trusted_keys"]) if spec["trusted_keys"] else None
    with tempfile.TemporaryDirectory(prefix="vtkiosk-lanes-") as tmp:
        cfg = Path(tmp) / "kiosk.yaml"
        cfg.write_text(yaml.safe_dump(config))
        with daemon_process(Path(spec["bundle"]), trusted, trusted is None, cfg) as (url, pid):
            status = Client(url).json("/api/status")
            garment = next(iter(status["bundles"]))
            engine = status["bundles"][garment]["engine"]
            warm = Client(url)  # sessions and first-shape allocations are not part of the measurement
            _render(warm, _body(garment, "preview", "drawer"))
            _render(warm, _body(garment, "refine", "refiner"))
            stop = threading.Event()
            previews: list[dict] = []
            refines: list[dict] = []
            errors: list[str] = []
            jobs = ([("preview", "drawer", previews)] if spec.get("previews", True) else []) + \
                ([("refine", "refiner", refines)] if spec["refine"] else [])
            workers = [threading.Thread(target=_loop, args=(url, _body(garment, mode, name), stop, out, errors))
                       for mode, name, out in jobs]
            t0 = time.monotonic()
            for w in workers:
                w.start()
            time.sleep(float(spec["seconds"]))
            stop.set()
            for w in workers:
                w.join(timeout=120.0)
            window = time.monotonic() - t0
            _, peak = _proc_mem(pid)
    if errors:
        raise BenchError(errors[0])
    return {"previews": previews, "refines": refines, "window_s": window, "engine": engine, "peak_rss_mb": peak}


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m kiosk.bench.lanes SPEC.json", file=sys.stderr)
        return 2
    try:
        out = measure(json.loads(Path(argv[0]).read_text()))
    except (BenchError, KioskError) as exc:
        print(f"lanes: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
