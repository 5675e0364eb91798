"""`vtkiosk demo`: the README's main job: the kiosk serving trained garments with the emulated haptic screen.

By default it serves the committed demo catalogue (`catalogue/`, full-schedule models trained by this repository's
trainer, see vtkiosk/catalogue.py): on first start each garment's data is regenerated and its model exported to a
signed int8 bundle with a demo key generated here, by two warm worker processes (vtkiosk/export_worker.py), and the
bundles cached (keyed by the model file, its recipe and the exporter's source), so later starts take seconds.

`--quick` instead builds one demo-quality bundle the way an operator would, with our own commands in child processes:
`vtkiosk data synth` (one synthetic garment), `vtkiosk train --preset demo` (a short schedule: a demo-quality
model in a few minutes on 2 CPU cores), `vtkiosk export --precision int8` signed with a demo key generated into the
work folder (0600). The bundle is cached under `out/demo/bundles/<key>/`, keyed by a hash of everything that made
it (the demo's settings, the preset, and the source of the trainer, exporter and runtime contract), so later runs
start in seconds. Then it serves that bundle (or `--bundle FILE`, e.g. a properly trained one) with the emulated
device, prints the URL and runs until Ctrl-C. The serving process never imports torch: training and export run in
child processes.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEMO_VERSION = "2"  # bump when the recipe below changes in a way the source hash cannot see
FRAME = (320, 240)
SIZES = "256,512"
# What makes the bundle: the whole trainer, the exporter modules `vtkiosk export` uses, the runtime contract.
CODE = ("trainer", "exporter/__init__.py", "exporter/cli.py", "exporter/export.py", "exporter/graphs.py",
        "exporter/rewrite.py", "exporter/quantize.py", "exporter/calibration.py", "exporter/accuracy.py",
        "exporter/bundle_writer.py", "exporter/keys.py", "kiosk/contract/sketch.py", "kiosk/contract/haptics.py", "kiosk/bundle/manifest.py",
        "kiosk/bundle/archive.py", "kiosk/bundle/signature.py", "kiosk/bundle/probe.py", "kiosk/contract/validate.py",
        "kiosk/contract/graph.py", "kiosk/config/loader.py")


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    p.add_argument("--workdir", type=Path, default=Path("out/demo"),
                   help="where the demo bundle, its key and the serving state live (default out/demo)")
    p.add_argument("--bundle", type=Path, default=None,
                   help="serve this bundle instead of building the demo one (give --trusted-keys or --allow-unsigned)")
    p.add_argument("--trusted-keys", type=Path, default=None, help="trusted keys folder for --bundle")
    p.add_argument("--allow-unsigned", action="store_true", help="development only: serve an unsigned --bundle")
    p.add_argument("--port", type=int, default=8765, help="HTTP port on 127.0.0.1 (default 8765; 0: any free)")
    p.add_argument("--quick", action="store_true",
                   help="serve a 100-step model built here instead of the trained catalogue (CI, smoke tests)")
    p.add_argument("--steps", type=int, default=None, help="with --quick: training steps (default: the demo preset's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rebuild", action="store_true", help="ignore the cache and build the demo bundle again")
    p.add_argument("--build-only", action="store_true", help="build (or find) the demo bundle, then exit")
    p.add_argument("--exit-after-ready", action="store_true", help="start serving, report the URL, then stop")
    return p


def _source_hash(h: "hashlib._Hash") -> None:
    for entry in CODE:
        path = ROOT / entry
        files = sorted(path.rglob("*.py")) + sorted(path.rglob("*.yaml")) if path.is_dir() else \
            [path] if path.exists() else []
        for f in files:
            if "__pycache__" in f.parts:
                continue
            h.update(f.relative_to(ROOT).as_posix().encode())
            h.update(f.read_bytes())


def cache_key(seed: int, steps: int | None) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({"version": DEMO_VERSION, "frame": FRAME, "sizes": SIZES, "seed": seed, "steps": steps,
                         "python": sys.version_info[:2]}).encode())
    _source_hash(h)
    return h.hexdigest()[:16]


def _run(cmd: list[str], log: Path, what: str) -> None:
    """Run one build stage; its output goes to the log and, indented, to the terminal (the trainer's periodic
    progress lines and the exporter's one line per step), so a slow stage on a busy machine never looks hung."""
    t0 = time.perf_counter()
    print(f"demo: {what} ...", flush=True)
    with open(log, "ab") as out:
        out.write(("\n$ " + " ".join(cmd) + "\n").encode())
        out.flush()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=ROOT)
        assert proc.stdout is not None
        for line in proc.stdout:
            out.write(line)
            out.flush()
            text = line.decode(errors="replace").rstrip()
            if text:
                print(f"demo:   | {text}", flush=True)
        rc = proc.wait()
    if rc != 0:
        tail = log.read_text(errors="replace").strip().splitlines()[-5:]
        raise DemoError(f"{what} failed (exit {rc}); see {log}:\n  " + "\n  ".join(tail))
    print(f"demo: {what} done in {time.perf_counter() - t0:.0f} s", flush=True)


class DemoError(Exception):
    user_facing = True


def demo_keys(workdir: Path) -> tuple[Path, Path]:
    """The demo signing key (generated once, 0600) and a trusted-keys folder holding its public half."""
    from exporter.keys import generate_keypair

    keys = workdir / "keys"
    if not (keys / "demo.key").exists():
        generate_keypair(keys, "demo")
    trusted = workdir / "trusted-keys"
    trusted.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(keys / "demo.pub", trusted / "demo.pub")
    return keys / "demo.key", trusted


def build_bundle(workdir: Path, *, seed: int = 0, steps: int | None = None, rebuild: bool = False) -> Path:
    """The cached demo bundle, built first if needed. Returns the .vtb path."""
    workdir = Path(workdir).resolve()
    key = cache_key(seed, steps)
    folder = workdir / "bundles" / key
    bundle = folder / "demo.vtb"
    if bundle.is_file() and not rebuild:
        print(f"demo: reusing the demo bundle {bundle}")
        return bundle
    signing_key, _ = demo_keys(workdir)
    build = workdir / "build" / key
    shutil.rmtree(build, ignore_errors=True)
    build.mkdir(parents=True)
    log = build / "build.log"
    py = [sys.executable, "-m", "vtkiosk"]
    t0 = time.perf_counter()
    print(f"demo: building a demo bundle (cache key {key}); log in {log}")
    _run(py + ["data", "synth", "--out", str(build / "data"), "--garments", "1", "--seed", str(seed),
               "--frame", f"{FRAME[0]}x{FRAME[1]}", "--no-progress"], log, "[1/3] synthesising a garment")
    # progress on: not a terminal here, so the trainer prints a plain line (step, losses, time left) every 30 s
    train = py + ["train", "--data", str(build / "data"), "--preset", "demo", "--out", str(build / "run"),
                  "--set", "train.progress=true"]
    if steps is not None:
        train += ["--steps", str(steps)]
    _run(train, log, "[2/3] training a demo-quality model (preset demo)")
    # int8 at the serving sizes; the demo model is barely trained, so its int8 friction error bound is relaxed
    # (the export still measures it and records it in the manifest).
    _run(py + ["export", "--run", str(build / "run"), "--out", str(build / "demo.vtb"), "--precision", "int8",
               "--sizes", SIZES, "--sign-key", str(signing_key), "--max-friction-mae", "8",
               "--display-name", "Demo denim shorts"], log, "[3/3] exporting a signed int8 bundle")
    folder.mkdir(parents=True, exist_ok=True)
    shutil.move(str(build / "demo.vtb"), bundle)
    (folder / "build.log").write_bytes(log.read_bytes())
    for other in (workdir / "bundles").iterdir():
        if other.name != key:
            shutil.rmtree(other, ignore_errors=True)  # one cached bundle: the current one
    shutil.rmtree(workdir / "build", ignore_errors=True)
    print(f"demo: demo bundle ready in {time.perf_counter() - t0:.0f} s: {bundle}")
    return bundle


CATALOGUE_SIZES = "256,512,768"
# The catalogue's int8 friction-error bound, in levels of 255 (the exporter's default is 1): since the device map
# averages a 2x supersampled friction grid per panel pixel, the hard-profile denim shorts' int8 full graph measures
# 1.06 levels from fp32 (1.56 for the earlier gamma-1 model); each bundle records its measured figure in its manifest.
CATALOGUE_MAX_FRICTION_MAE = "2.0"
EXPORT_SLOTS = 2   # exports side by side: the two cores of the machines this was measured on
# the exporter modules a catalogue bundle depends on (the model itself is keyed by its file hash and recipe)
EXPORT_CODE = tuple(c for c in CODE if c != "trainer") + ("trainer/checkpoint.py", "trainer/models",
                                                         "trainer/data/touchclothing.py")


def _export_key(entry) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({"version": DEMO_VERSION, "sizes": CATALOGUE_SIZES, "file": entry.sha256,
                         "recipe": entry.recipe_sha256, "python": sys.version_info[:2]}).encode())
    for e in EXPORT_CODE:
        path = ROOT / e
        for f in (sorted(path.rglob("*.py")) if path.is_dir() else [path] if path.exists() else []):
            h.update(f.relative_to(ROOT).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


class _Worker:
    """A `vtkiosk.export_worker` child: one job at a time, replies read line by line."""

    def __init__(self, log: Path) -> None:
        self.log = log
        with open(log, "wb") as err:   # what the worker says outside a job (an import failing, say)
            self.proc = subprocess.Popen([sys.executable, "-m", "vtkiosk.export_worker"], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=err, cwd=ROOT, text=True, bufsize=1)

    def send(self, job: dict) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(job) + "\n")
        self.proc.stdin.flush()

    def read_reply(self) -> dict | None:
        """The next reply; None when the worker has gone (it died or was killed)."""
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        return json.loads(line) if line else None

    def close(self, kill: bool = False) -> None:
        if kill:
            self.proc.kill()
        elif self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait()


def build_catalogue(workdir: Path, *, rebuild: bool = False) -> list[Path]:
    """One signed int8 bundle per catalogue garment, exported on first use and cached. Returns the .vtb paths.

    Exports run in up to EXPORT_SLOTS warm worker processes (vtkiosk/export_worker.py), started before anything
    else so their imports overlap with the set-up; each takes the next garment as soon as it is free."""
    from vtkiosk.catalogue import CATALOGUE, load_index

    workdir = Path(workdir).resolve()
    entries = load_index(CATALOGUE)
    todo, bundles = [], []
    for e in entries:
        bundle = workdir / "catalogue" / _export_key(e) / f"{e.id}.vtb"
        bundles.append(bundle)
        if rebuild or not bundle.is_file():
            todo.append((e, bundle))
        else:
            print(f"demo: reusing {e.display_name} ({bundle.parent.name})")
    if not todo:
        return bundles
    t0 = time.perf_counter()
    build = workdir / "build" / "catalogue"
    shutil.rmtree(build, ignore_errors=True)
    build.mkdir(parents=True)
    workers = [_Worker(build / f"worker{i}.log") for i in range(min(EXPORT_SLOTS, len(todo)))]
    try:
        signing_key, _ = demo_keys(workdir)
        print(f"demo: exporting {len(todo)} catalogue garment(s) to signed int8 bundles (first start only); "
              f"logs in {build}", flush=True)
        pending = []
        for i, (e, _bundle) in enumerate(todo):
            argv = ["--run", str(build / "runs" / e.id), "--out", str(build / f"{e.id}.vtb"), "--precision", "int8",
                    "--sizes", CATALOGUE_SIZES, "--sign-key", str(signing_key),
                    "--max-friction-mae", CATALOGUE_MAX_FRICTION_MAE, "--display-name", e.display_name]
            pending.append({"id": i, "entry": e.id, "data_dir": str(build / "data"),
                            "run_dir": str(build / "runs" / e.id), "argv": argv, "log": str(build / f"{e.id}.log")})
        busy: dict[int, _Worker] = {}
        started = 0

        def start_next(w: _Worker) -> None:
            nonlocal started
            job = pending.pop(0)
            started += 1
            e = todo[job["id"]][0]
            print(f"demo: [{started}/{len(todo)}] regenerating the data of {e.display_name} and exporting it",
                  flush=True)
            w.send(job)
            busy[job["id"]] = w

        for w in workers:   # each announces its imports are done, then takes its first garment
            if w.read_reply() is None:
                tail = w.log.read_text(errors="replace").strip().splitlines()[-5:]
                raise DemoError("an export worker failed to start:\n  " + "\n  ".join(tail))
            if pending:
                start_next(w)
        while busy:
            w, reply = _first_reply(list(busy.values()))
            if reply is None or reply.get("id") not in busy:
                raise DemoError(f"an export worker stopped unexpectedly (reply {reply!r})")
            del busy[reply["id"]]
            e, bundle = todo[reply["id"]]
            if not reply["ok"]:
                tail = (build / f"{e.id}.log").read_text(errors="replace").strip().splitlines()[-5:]
                raise DemoError(f"exporting {e.id} failed ({reply['error']}):\n  " + "\n  ".join(tail))
            bundle.parent.mkdir(parents=True, exist_ok=True)
            shutil.move(str(build / f"{e.id}.vtb"), bundle)
            print(f"demo: {e.display_name} exported", flush=True)
            if pending:
                start_next(w)
    except BaseException:   # a failed export or data step, or Ctrl-C: leave no export running behind
        for w in workers:
            w.close(kill=True)
        raise
    for w in workers:
        w.close()
    keep = {b.parent.name for b in bundles}
    for other in (workdir / "catalogue").iterdir():
        if other.name not in keep:
            shutil.rmtree(other, ignore_errors=True)
    shutil.rmtree(build, ignore_errors=True)
    print(f"demo: catalogue ready in {time.perf_counter() - t0:.0f} s", flush=True)
    return bundles


def _first_reply(workers: list[_Worker]) -> tuple[_Worker, dict | None]:
    """Block until one of `workers` replies (or exits); that worker and its reply."""
    import selectors

    sel = selectors.DefaultSelector()
    for w in workers:
        assert w.proc.stdout is not None
        sel.register(w.proc.stdout, selectors.EVENT_READ, w)
    try:
        key, _ = sel.select()[0]
    finally:
        sel.close()
    w = key.data
    return w, w.read_reply()


def main(argv: list[str], prog: str = "vtkiosk demo") -> int:
    args = build_parser(prog).parse_args(argv)
    workdir = args.workdir.resolve()
    if args.steps is not None and not args.quick:
        raise DemoError("--steps sets the --quick build's schedule; add --quick (the catalogue is already trained)")
    if args.bundle is not None:
        bundles = [args.bundle.resolve()]
        trusted = args.trusted_keys.resolve() if args.trusted_keys else None
    elif args.quick:
        bundles = [build_bundle(workdir, seed=args.seed, steps=args.steps, rebuild=args.rebuild)]
        _, trusted = demo_keys(workdir)
    else:
        bundles = build_catalogue(workdir, rebuild=args.rebuild)
        _, trusted = demo_keys(workdir)
    if args.build_only:
        return 0
    from kiosk.service.config import load_config
    from kiosk.service.daemon import KioskDaemon
    from kiosk.ops.logsetup import configure_logging, say_line
    from kiosk.service.cli import run

    store = {"allow_unsigned": bool(args.allow_unsigned)}
    if trusted is not None:
        store["trusted_keys"] = str(trusted)
    config = load_config(None, {
        "bundles": [str(b) for b in bundles], "store": store, "state_dir": str(workdir / "state"),
        "server": {"host": "127.0.0.1", "port": args.port},
        "device": {"type": "emulated", "report_size": 1024, "emulator": {"link": "hs-hid"}},
        "log_level": "WARNING"})
    configure_logging(level=config.log_level)
    t0 = time.perf_counter()
    daemon = KioskDaemon(config)

    def say(text: str) -> None:
        say_line(f"demo: {text} (started in {time.perf_counter() - t0:.1f} s)")
        if not args.exit_after_ready:
            say_line("demo: open the URL in a browser and draw a garment; the emulated haptic screen feels it. "
                     "Ctrl-C stops.")

    return run(daemon, exit_after_ready=args.exit_after_ready, out=say)
