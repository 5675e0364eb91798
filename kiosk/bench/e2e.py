"""`vtkiosk bench e2e`: stroke end -> friction frame committed on the device / visual available to the page.

Replays deterministic drawing sessions (`kiosk/bench/strokes.py`) against a running kiosk daemon over real HTTP
(keep-alive, like the page), with the in-process emulated haptic device: while a stroke is drawn, previews as fast
as the page asks for them (one in flight, each with all points so far); at stroke end the full render. Measured:

- visual: client clock, from sending the stroke-end request to having the frame (JSON + RGBA pixels) in hand;
- friction: from the same instant to the device's commit (the daemon's `time.monotonic()`, the same system-wide
  CLOCK_MONOTONIC as this process), read back from `GET /api/commit`;
- per stage (daemon-reported): rasterize, plan, inference, friction map, upload (host composition + delta tiles +
  emulated link; with a real clock the emulator does not model USB bandwidth, so the modelled high-speed HID link
  time of the bytes actually sent is reported beside it);
- preview frames per second while drawing; the daemon's RSS (current and peak) from /proc; computed network pixels
  against the naive full-frame full-graph plan; torch must not be imported in the daemon (checked).

By default it starts the daemon itself (`vtkiosk serve --bundle ... --device emulated --port 0`) so the daemon's
memory is its own; `--url` benchmarks one that is already running. `--incremental` also measures how far a
window-only recomputation around an edit is from recomputing the object's region (why the planner does not do it).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from http.client import HTTPConnection
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np

from kiosk.bench.strokes import Session, sessions
from kiosk.inference.cpu import describe
from kiosk.inference.scene import QUICK_FELT_TOLERANCE, QUICK_TACTILE

ROOT = Path(__file__).resolve().parents[2]
HS_HID_BYTES_PER_S = 24_576_000.0
GOALS = {"p95_ms": 100.0, "preview_fps": 15.0, "rss_mb": 400.0}
SECTION = "e2e"


class BenchError(Exception):
    user_facing = True


@dataclass
class Final:
    session: str
    label: str
    graph: str
    grid: list | None
    visual_ms: float
    friction_ms: float | None
    stages: dict
    friction_map_ms: float | None
    upload_ms: float | None
    wire_bytes: int
    computed_pixels: int
    naive_pixels: int
    refine_visual_ms: float | None = None
    refine_friction_ms: float | None = None
    refine_grid: list | None = None
    deferred: bool = False   # the quick answer left the friction to the refinement


@dataclass
class Results:
    finals: list[Final] = field(default_factory=list)
    previews: int = 0
    preview_ms: list[float] = field(default_factory=list)
    drawing_s: float = 0.0
    stroke_fps: list[float] = field(default_factory=list)
    garment_previews: int = 0   # previews that showed a synthesised garment (not "no closed outline yet")
    garment_drawing_s: float = 0.0


class Client:
    """One keep-alive HTTP connection, like the page's."""

    def __init__(self, url: str):
        parts = urlsplit(url)
        self.host, self.port = parts.hostname, parts.port
        self.conn = HTTPConnection(self.host, self.port, timeout=30)

    def request(self, method: str, path: str, body: dict | None = None) -> tuple[int, bytes]:
        data = None if body is None else json.dumps(body).encode()
        headers = {"Content-Type": "application/json"} if data is not None else {}
        for attempt in (1, 2):
            try:
                self.conn.request(method, path, data, headers)
                r = self.conn.getresponse()
                return r.status, r.read()
            except (ConnectionError, OSError):
                self.conn.close()
                self.conn = HTTPConnection(self.host, self.port, timeout=30)
                if attempt == 2:
                    raise
        raise AssertionError("unreachable")

    def json(self, path: str) -> dict:
        status, body = self.request("GET", path)
        if status != 200:
            raise BenchError(f"GET {path}: HTTP {status}: {body[:200]!r}")
        return json.loads(body)


def _frame(body: bytes) -> dict:
    (n,) = np.frombuffer(body[:4], "<u4")
    return json.loads(body[4:4 + int(n)])


def replay(client: Client, garment: str, sess: Session, res: Results, panel=(0, 0, 1280, 800)) -> None:
    strokes: list[list] = []
    base = {"garment": garment, "panel": dict(zip("xywh", panel)), "screen": [panel[0] + panel[2],
                                                                             panel[1] + panel[3]],
            "base": False, "client": "bench"}
    for action in sess.actions:
        if action.kind == "draw":
            pts = action.stroke
            t0 = time.monotonic()
            duration = float(pts[-1, 2]) / 1e3
            n = n_ok = 0
            while True:  # the page: one preview in flight, each with the points drawn so far
                elapsed = time.monotonic() - t0
                if elapsed >= duration:
                    break
                k = int(np.searchsorted(pts[:, 2], 1e3 * elapsed, side="right"))
                body = {**base, "strokes": strokes + [pts[:max(k, 1), :2].tolist()], "mode": "preview"}
                ts = time.monotonic()
                status, data = client.request("POST", "/api/render", body)
                if status != 200:
                    raise BenchError(f"preview failed: HTTP {status}: {data[:200]!r}")
                res.preview_ms.append(1e3 * (time.monotonic() - ts))
                n += 1
                if data[:1] != b"{" and _frame(data)["panels"][0]["status"] == "ok":
                    n_ok += 1
            time.sleep(max(0.0, duration - (time.monotonic() - t0)))
            t_stroke_end = t0 + duration  # a preview still in flight delays the stroke end's answer: counted
            res.previews += n
            res.drawing_s += duration
            res.stroke_fps.append(n / duration if duration > 0 else 0.0)
            if n_ok:
                res.garment_previews += n
                res.garment_drawing_s += duration
            strokes.append(pts[:, :2].tolist())
        elif action.kind == "undo":
            strokes.pop()
            t_stroke_end = time.monotonic()  # the tap
        elif action.kind == "clear":
            strokes = []
            t_stroke_end = time.monotonic()
        t_end = t_stroke_end
        status, data = client.request("POST", "/api/render", {**base, "strokes": strokes, "mode": "final"})
        t_visual = time.monotonic()
        if status != 200:
            raise BenchError(f"render failed: HTTP {status}: {data[:200]!r}")
        meta = _frame(data)
        rmeta, t_refined = None, None
        if meta.get("refine"):  # the page asks for the full resolution as soon as the quick answer is in
            status, rdata = client.request("POST", "/api/render", {**base, "strokes": strokes, "mode": "refine"})
            t_refined = time.monotonic()
            if status != 200:
                raise BenchError(f"refine failed: HTTP {status}: {rdata[:200]!r}")
            rmeta = _frame(rdata)
        commit = rcommit = None
        if meta.get("device_frame") is not None:
            commit = client.json(f"/api/commit?frame={meta['device_frame']}&wait=5")
        if rmeta is not None and rmeta.get("device_frame") is not None:
            rcommit = client.json(f"/api/commit?frame={rmeta['device_frame']}&wait=5")
        p = meta["plan"]["panels"][0]
        friction_ms = None
        if commit and commit["status"] == "committed":
            friction_ms = 1e3 * (commit["committed_at"] - t_end)
        elif (commit is None or commit["status"] == "superseded") and rcommit and rcommit["status"] == "committed":
            # the finger got the refined frame first: the quick one was superseded, or the quick answer left the
            # friction to the refinement (inference.quick_tactile: at-scale)
            friction_ms = 1e3 * (rcommit["committed_at"] - t_end)
        final = Final(sess.name, action.label, p["graph"], p["grid"], 1e3 * (t_visual - t_end),
                      friction_ms, meta["timings"], commit["friction_ms"] if commit else None,
                      commit["upload_ms"] if commit else None,
                      commit["wire_bytes"] if commit else 0, meta["plan"]["computed_pixels"],
                      meta["plan"]["naive_pixels"])
        final.deferred = "tactile" in p.get("deferred", [])
        if rmeta is not None:
            final.refine_visual_ms = 1e3 * (t_refined - t_end)
            final.refine_grid = rmeta["plan"]["panels"][0]["grid"]
            final.computed_pixels += rmeta["plan"]["computed_pixels"]
            if rcommit and rcommit["status"] == "committed":
                final.refine_friction_ms = 1e3 * (rcommit["committed_at"] - t_end)
        res.finals.append(final)


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def _stats(values: list[float]) -> dict:
    return {"n": len(values), "p50": _pct(values, 50), "p95": _pct(values, 95),
            "max": float(max(values)) if values else float("nan"), "mean": float(np.mean(values)) if values else
            float("nan")}


def _proc_mem(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of `pid` in MiB."""
    text = Path(f"/proc/{pid}/status").read_text()
    get = lambda k: int(re.search(rf"^{k}:\s+(\d+) kB", text, re.M).group(1)) / 1024.0  # noqa: E731
    return get("VmRSS"), get("VmHWM")


@contextmanager
def daemon_process(bundle: Path, trusted: Path | None, allow_unsigned: bool, config: Path | None = None):
    cmd = [sys.executable, "-m", "vtkiosk", "serve", "--bundle", str(bundle), "--device", "emulated", "--port", "0",
           "--log-level", "WARNING"]
    cmd += ["--config", str(config)] if config else []
    cmd += ["--trusted-keys", str(trusted)] if trusted else []
    cmd += ["--allow-unsigned"] if allow_unsigned else []
    env = {k: v for k, v in os.environ.items() if k != "NOTIFY_SOCKET"}
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        if " at http://" not in line:
            proc.wait(timeout=10)
            raise BenchError(f"the daemon did not start: {proc.stderr.read().strip()[-500:]}")
        yield line.split(" at ")[1].strip(), proc.pid
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def default_bundle() -> tuple[Path | None, Path | None]:
    """The demo bundle `vtkiosk demo` built (out/demo), if any."""
    found = sorted((ROOT / "out" / "demo" / "bundles").glob("*/demo.vtb"))
    trusted = ROOT / "out" / "demo" / "trusted-keys"
    return (found[-1] if found else None), (trusted if trusted.is_dir() else None)


def measure_incremental(bundle_path: Path, trusted: Path | None, allow_unsigned: bool, window: int = 256) -> dict:
    """For each detail stroke of the sessions: run the full graph on the planned object region, and on a
    `window`-px window around the stroke cut from the same network input; compare inside the window. The window
    result is what an incremental planner would show; the difference is its error."""
    import tempfile

    from kiosk.bundle.archive import open_bundle
    from kiosk.inference.engine import LoadedBundle, visual_rgba
    from kiosk.contract.haptics import friction_map
    from kiosk.inference.scene import Panel, Planner, Scene, SketchInput
    from kiosk.bundle.signature import load_trusted_keys
    from kiosk.contract.sketch import NetworkInput

    with tempfile.TemporaryDirectory() as tmp:
        lb = LoadedBundle(open_bundle(bundle_path, load_trusted_keys(trusted) if trusted else None,
                                      workdir=Path(tmp), allow_unsigned=allow_unsigned))
        planner = Planner(max_resolution=512)
        vis_err, fric_err = [], []
        scene = Scene((Panel("main", (0, 0, 1280, 800), lb.garment_id),), (1280, 800))
        for sess in sessions():
            strokes: list[np.ndarray] = []
            for i, action in enumerate(sess.actions):
                if action.kind != "draw":
                    continue
                strokes.append(action.stroke[:, :2])
                if i < 2 or "outline" in action.label:
                    continue
                pp = planner.plan(scene, {"main": SketchInput(tuple(strokes))}, {lb.garment_id: lb}).panels[0]
                if pp.region is None:
                    continue
                full = lb.run("full", pp.inputs).outputs
                rx, ry, rw, rh = pp.region
                gw, gh = pp.grid
                cx = int(np.clip((action.stroke[:, 0].mean() - rx) * gw / rw - window / 2, 0, gw - window))
                cy = int(np.clip((action.stroke[:, 1].mean() - ry) * gh / rh - window / 2, 0, gh - window))
                sl = (slice(None), slice(None), slice(cy, cy + window), slice(cx, cx + window))
                win = lb.run("full", NetworkInput(np.ascontiguousarray(pp.inputs.sketch[sl]),
                                                  np.ascontiguousarray(pp.inputs.mask[sl]))).outputs
                m = pp.mask[cy:cy + window, cx:cx + window]
                a = visual_rgba(full["visual"][sl], m)[..., :3].astype(int)
                b = visual_rgba(win["visual"], m)[..., :3].astype(int)
                vis_err.append(float(np.abs(a - b)[m].mean()) if m.any() else 0.0)
                ft = full["tactile"][sl][0]
                wt = win["tactile"][0]
                fa = friction_map(ft[0], ft[1], lb.friction_scale).astype(int)
                fb = friction_map(wt[0], wt[1], lb.friction_scale).astype(int)
                fric_err.append(float(np.abs(fa - fb)[m].mean()) if m.any() else 0.0)
        lb.close()
    return {"window": window, "edits": len(vis_err), "visual_mae_levels": _stats(vis_err),
            "friction_mae_levels": _stats(fric_err), "int8_friction_mae_levels":
                lb.manifest.errors.get("int8", {}).get("tactile_friction_mae_levels"),
            # the check above is measured in the garment: compare it with the bundle's garment figure (newer bundles)
            "int8_friction_mae_garment_levels":
                lb.manifest.errors.get("int8", {}).get("tactile_friction_mae_garment_levels")}


def summarize(res: Results, status: dict, mem: tuple[float, float] | None) -> dict:
    work = [f for f in res.finals if f.graph != "none"]
    vis = [f.visual_ms for f in res.finals]
    fric = [f.friction_ms for f in res.finals if f.friction_ms is not None]
    stages = {}
    for key in ("queue_ms", "rasterize_ms", "plan_ms", "inference_ms", "visual_ms"):
        stages[key.removesuffix("_ms")] = _stats([f.stages.get(key, 0.0) for f in res.finals])
    stages["friction map"] = _stats([f.friction_map_ms for f in res.finals if f.friction_map_ms is not None])
    stages["upload"] = _stats([f.upload_ms for f in res.finals if f.upload_ms is not None])
    stages["link_hs_hid_modelled"] = _stats([1e3 * f.wire_bytes / HS_HID_BYTES_PER_S for f in res.finals
                                             if f.upload_ms is not None])
    computed = sum(f.computed_pixels for f in res.finals) + 0
    naive = sum(f.naive_pixels for f in res.finals)
    fps = res.previews / res.drawing_s if res.drawing_s else 0.0
    refined = [f for f in res.finals if f.refine_visual_ms is not None]
    out = {"finals": len(res.finals), "finals_with_inference": len(work),
           "visual_ms": _stats(vis), "friction_ms": _stats(fric),
           "refined_visual_ms": _stats([f.refine_visual_ms for f in refined]),
           "refined_friction_ms": _stats([f.refine_friction_ms for f in refined if f.refine_friction_ms is not None]),
           "visual_ms_with_inference": _stats([f.visual_ms for f in work]),
           "friction_ms_with_inference": _stats([f.friction_ms for f in work if f.friction_ms is not None]),
           "stages_ms": stages, "preview": {"frames": res.previews, "drawing_s": res.drawing_s, "fps": fps,
                                            "garment_fps": res.garment_previews / res.garment_drawing_s
                                            if res.garment_drawing_s else 0.0,
                                            "min_stroke_fps": min(res.stroke_fps) if res.stroke_fps else 0.0,
                                            "latency_ms": _stats(res.preview_ms)},
           "deferred_friction": sum(f.deferred for f in res.finals),
           "grids": sorted({f"{f.graph} {f.grid[0]}x{f.grid[1]}" for f in work if f.grid}),
           "refine_grids": sorted({f"{g[0]}x{g[1]}" for g in (f.refine_grid for f in refined) if g}),
           "pixels": {"computed": computed, "naive_full_frame_full_graph": naive,
                      "ratio": computed / naive if naive else None},
           "torch_imported": status.get("torch_imported"),
           "bundles": {g: {k: b[k] for k in ("key", "graphs", "engine") if k in b}
                       for g, b in status.get("bundles", {}).items()},
           "rss_mb": mem[0] if mem else status.get("rss_bytes", 0) / 2**20,
           "peak_rss_mb": mem[1] if mem else None}
    p95 = max(out["visual_ms"]["p95"], out["friction_ms"]["p95"])
    worst = out["preview"]["min_stroke_fps"]  # judged on the slowest stroke, not the average
    out["goals"] = {"p95_ms": {"goal": GOALS["p95_ms"], "got": p95, "met": p95 <= GOALS["p95_ms"]},
                    "preview_fps": {"goal": GOALS["preview_fps"], "got": worst, "met": worst >= GOALS["preview_fps"]},
                    "rss_mb": {"goal": GOALS["rss_mb"], "got": out["peak_rss_mb"] or out["rss_mb"],
                               "met": (out["peak_rss_mb"] or out["rss_mb"]) <= GOALS["rss_mb"]},
                    "no_torch": {"met": out["torch_imported"] is False}}
    out["per_final"] = [f.__dict__ for f in res.finals]
    return out


def table(s: dict) -> str:
    f = lambda v: "-" if v is None or v != v else f"{v:.1f}"  # noqa: E731
    rows = ["| measure | n | p50 | p95 | max |", "| --- | ---: | ---: | ---: | ---: |"]
    for name, key in (("stroke end -> visual available to the page (ms)", "visual_ms"),
                      ("stroke end -> friction frame committed on the device (ms)", "friction_ms"),
                      ("  same, stroke ends that ran a graph: visual (ms)", "visual_ms_with_inference"),
                      ("  same, stroke ends that ran a graph: friction (ms)", "friction_ms_with_inference"),
                      ("stroke end -> refined visual at full resolution (ms)", "refined_visual_ms"),
                      ("stroke end -> refined friction frame committed (ms)", "refined_friction_ms")):
        v = s[key]
        rows.append(f"| {name} | {v['n']} | {f(v['p50'])} | {f(v['p95'])} | {f(v['max'])} |")
    for stage, v in s["stages_ms"].items():
        label = {"link_hs_hid_modelled": "link time, high-speed HID (modelled from bytes sent)"}.get(stage, stage)
        rows.append(f"| stage: {label} (ms) | {v['n']} | {f(v['p50'])} | {f(v['p95'])} | {f(v['max'])} |")
    pv = s["preview"]
    rows.append(f"| preview round trip while drawing (ms) | {pv['latency_ms']['n']} | {f(pv['latency_ms']['p50'])} "
                f"| {f(pv['latency_ms']['p95'])} | {f(pv['latency_ms']['max'])} |")
    g = s["goals"]
    lines = ["\n".join(rows), "",
             f"- preview: {pv['fps']:.1f} frames/s while drawing, {pv['garment_fps']:.1f} on strokes that showed a "
             f"garment, {pv['min_stroke_fps']:.1f} on the slowest stroke; goal >= {GOALS['preview_fps']:.0f} "
             f"(slowest stroke): {'met' if g['preview_fps']['met'] else 'MISSED'}",
             f"- p95 end to end (first answer): {g['p95_ms']['got']:.1f} ms (worse of visual and friction); goal <= "
             f"{GOALS['p95_ms']:.0f}: {'met' if g['p95_ms']['met'] else 'MISSED'}",
             f"- daemon RSS: {s['rss_mb']:.0f} MiB now, {f(s['peak_rss_mb'])} MiB peak; goal <= "
             f"{GOALS['rss_mb']:.0f}: {'met' if g['rss_mb']['met'] else 'MISSED'}",
             f"- torch imported in the daemon: {s['torch_imported']}",
             f"- first answers ran {', '.join(s['grids']) or 'nothing'}; refinements ran "
             f"{', '.join(s['refine_grids']) or 'nothing'}; network pixels computed {s['pixels']['computed']:,} vs "
             f"{s['pixels']['naive_full_frame_full_graph']:,} for the naive full-frame full-graph plan "
             f"({100 * (s['pixels']['ratio'] or 0):.1f} %)",
             f"- first answers that left the friction to the refinement (texture felt > "
             f"{QUICK_FELT_TOLERANCE:g}x coarser at the quick grid): {s.get('deferred_friction', 0)} of "
             f"{s['finals']}; the friction row above is then the refined frame's"]
    inc = s.get("incremental")
    if inc:
        lines.append(f"- incremental check ({inc['edits']} edits, {inc['window']} px window vs the object region): "
                     f"visual MAE p50 {inc['visual_mae_levels']['p50']:.1f} / max "
                     f"{inc['visual_mae_levels']['max']:.1f} levels, friction MAE p50 "
                     f"{inc['friction_mae_levels']['p50']:.1f} / max {inc['friction_mae_levels']['max']:.1f} levels "
                     f"(the bundle's int8 friction error: {f(inc.get('int8_friction_mae_garment_levels'))} levels in "
                     f"the garment, {f(inc['int8_friction_mae_levels'])} over the grid)")
    return "\n".join(lines)


def header(s: dict, bundle: Path | None) -> str:
    graphs = "; ".join(f"{g}: " + ", ".join(f"{k} {v['precision']} up to "
                                             f"{max(w for w, _ in v['sizes'])}x{max(h for _, h in v['sizes'])}"
                                             for k, v in b["graphs"].items())
                       + (f"; engine {b['engine']}" if b.get("engine") else "") for g, b in s["bundles"].items())
    load = os.getloadavg()
    return (f"Measured {time.strftime('%Y-%m-%d %H:%M')} on {os.cpu_count()} CPUs (load average "
            f"{load[0]:.1f} at the end), panel 1280x800, {s['finals']} stroke ends and "
            f"{s['preview']['frames']} previews; bundle {bundle.name if bundle else 'of the running daemon'} "
            f"({graphs}). Command: `{s['command']}`.")


def write_section(doc: Path, body: str) -> None:
    """Put `body` between the `<!-- e2e table -->` markers inside the document's `e2e` section (the prose around
    it is written by hand); a document without them gets a new section at its end."""
    start, end = "<!-- e2e table -->", "<!-- end e2e table -->"
    text = doc.read_text() if doc.exists() else "# Performance\n"
    block = f"{start}\n{body.rstrip()}\n{end}"
    if start in text and end in text:
        text = text[:text.index(start)] + block + text[text.index(end) + len(end):]
    else:
        text = (text.rstrip() + f"\n\n<!-- section: {SECTION} -->\n## Kiosk end to end (vtkiosk bench e2e)\n\n"
                f"{block}\n<!-- end section: {SECTION} -->\n")
    doc.write_text(text)


def main(argv: list[str], prog: str = "vtkiosk bench e2e") -> int:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    p.add_argument("--url", default=None, help="benchmark this running daemon instead of starting one")
    p.add_argument("--bundle", type=Path, default=None, help="bundle to serve (default: the demo bundle in out/demo)")
    p.add_argument("--trusted-keys", type=Path, default=None)
    p.add_argument("--allow-unsigned", action="store_true")
    p.add_argument("--garment", default=None, help="garment id (default: the daemon's first)")
    p.add_argument("--repeats", type=int, default=2, help="times the three drawing sessions are replayed")
    p.add_argument("--max-resolution", type=int, default=None,
                   help="the daemon's inference.max_resolution (default: the config default, 512)")
    p.add_argument("--no-refine", action="store_true",
                   help="answer stroke ends at full resolution in one step (inference.refine: false)")
    p.add_argument("--quick-tactile", choices=QUICK_TACTILE, default=None,
                   help="the daemon's inference.quick_tactile (default: the config default, at-scale)")
    p.add_argument("--engine", choices=("onnxruntime", "openvino", "auto"), default=None,
                   help="the daemon's inference.engine.type (default: the config default, onnxruntime)")
    p.add_argument("--incremental", action="store_true", help="also measure window-only recomputation error")
    p.add_argument("--json", type=Path, default=None, help="write all numbers here")
    p.add_argument("--doc", type=Path, default=None, help="write the table into this markdown file's e2e section")
    args = p.parse_args(argv)
    bundle, trusted = args.bundle, args.trusted_keys
    if args.url is None and bundle is None:
        bundle, found_trusted = default_bundle()
        trusted = trusted or found_trusted
        if bundle is None:
            raise BenchError("no bundle: pass --bundle FILE, or build the demo one with `vtkiosk demo --build-only`")

    def run(url: str, pid: int | None) -> dict:
        client = Client(url)
        status = client.json("/api/status")
        garment = args.garment or sorted(status["bundles"])[0]
        res = Results()
        for _ in range(max(1, args.repeats)):
            for sess in sessions():
                replay(client, garment, sess, res)
        status = client.json("/api/status")
        mem = _proc_mem(pid) if pid else None
        return summarize(res, status, mem)

    t0 = time.perf_counter()
    if args.url:
        summary = run(args.url, None)
    else:
        import tempfile

        with tempfile.TemporaryDirectory(prefix="vtkiosk-bench-") as tmp:
            config = None
            inference: dict = {}
            if args.max_resolution:
                inference.update(max_resolution=args.max_resolution,
                                 preview_max_resolution=min(256, args.max_resolution))
            if args.no_refine:
                inference["refine"] = False
            if args.quick_tactile:
                inference["quick_tactile"] = args.quick_tactile
            if args.engine:
                inference["engine"] = {"type": args.engine}
            if inference:
                config = Path(tmp) / "kiosk.yaml"
                config.write_text(json.dumps({"bundles": [str(bundle.resolve())], "inference": inference}))
            with daemon_process(bundle, trusted, args.allow_unsigned, config) as (url, pid):
                summary = run(url, pid)
    if args.incremental and bundle is not None:
        summary["incremental"] = measure_incremental(bundle, trusted, args.allow_unsigned)
    summary["wall_s"] = time.perf_counter() - t0
    summary["command"] = "vtkiosk bench e2e " + " ".join(argv)
    summary["cpu"] = describe()  # the figures hold on this CPU (model, ISA families) only
    if summary["torch_imported"] is not False:
        raise BenchError("torch was imported in the daemon process; the edge runtime must never load it")
    text = header(summary, bundle) + "\n\n" + table(summary)
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=1, default=float))
    if args.doc:
        write_section(args.doc, text)
    return 0
