"""A run's comparison scores kept beside it (`RUN/eval/compare-<which>.json` + `.npz`; `compare-<which>-raw.*` for
its raw weights), so `eval --compare` after one more run finishes re-scores only that run (scoring is minutes per
run on a CPU: unseen sketches, five reference rows).

The key is what the scores depend on: the checkpoint's bytes, every garment file in the run's dataset folder (name,
size, modification time: the unseen sketches are the other garments) and in the folder the unseen sketches come from
when one is named (`eval --unseen-from`, scored apart as compare-<which>-unseen_<folder>), and the scoring code:
every module of `trainer/` and `kiosk/contract/` that scoring imports, directly or not, found statically
(function-level imports included), so an edit to the training side (loop, methods, losses) does not re-score every
run, nor does one to the tables built from the scores (trainer.compare: wording, intervals, the target's verdict). Any
change to the scoring code re-scores. Stored as JSON and arrays, never pickled: a run folder may come from elsewhere.
"""
from __future__ import annotations

import ast
import hashlib
import json
import logging
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from trainer.bootstrap import Units
from trainer.checkpoint import read_checkpoint
from trainer.evaluate import Evaluation, evaluate

log = logging.getLogger(__name__)
ROOT = Path(__file__).resolve().parents[1]
# What computes and stores a run's scores; their imports are followed from here.
SCORING = ("trainer.evaluate", "trainer.eval_cache")
PACKAGES = ("trainer", "kiosk")
VERSION = 1


def _module_file(module: str, base: Path) -> Path | None:
    stem = base / module.replace(".", "/")
    for f in (stem.with_suffix(".py"), stem / "__init__.py"):
        if f.is_file():
            return f
    return None


def _imports(f: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(f.read_text(), str(f))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)   # `from pkg import mod` may name a module, so try both
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return {n for n in names if n.split(".")[0] in PACKAGES}


def scoring_files(roots: Iterable[str] = SCORING, base: Path = ROOT) -> list[Path]:
    """The project's source files `roots` import, transitively, with the packages' `__init__`s on the way."""
    seen: set[Path] = set()
    todo = list(roots)
    while todo:
        module = todo.pop()
        f = _module_file(module, base)
        if f is None or f in seen:
            continue
        seen.add(f)
        parts = module.split(".")
        todo.extend(".".join(parts[:i]) for i in range(1, len(parts)))
        todo.extend(_imports(f))
    return sorted(seen)


def _code_hash(files: Iterable[Path] | None = None, base: Path = ROOT) -> str:
    h = hashlib.sha256()
    for f in scoring_files() if files is None else sorted(files):
        h.update(f.relative_to(base).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def _hash_folder(h, data: Path) -> None:
    """Every garment file under `data` by name, size and modification time."""
    for d in sorted(p for p in data.iterdir() if p.is_dir()):
        for f in sorted(d.rglob("*")):
            if f.is_file():
                st = f.stat()
                h.update(f"{f.relative_to(data).as_posix()} {st.st_size} {st.st_mtime_ns}".encode())


def cache_key(run_dir: Path, which: str, weights: str = "average", relief: str = "none",
              mirrors: str = "none", unseen_from: Path | None = None) -> str:
    run_dir = Path(run_dir)
    h = hashlib.sha256(f"v{VERSION} {which}".encode())
    if weights != "average":   # raw weights are scored apart from the average (stored as compare-<which>-raw)
        h.update(f" weights={weights}".encode())
    if relief != "none":       # so is a calibrated relief (compare-<which>-<rule>)
        h.update(f" relief={relief}".encode())
    if mirrors != "none":      # and a mirror-averaged one (compare-<which>-<mode>)
        h.update(f" mirrors={mirrors}".encode())
    ck_path = run_dir / "checkpoints" / f"{which}.pt"
    with open(ck_path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    garment = Path(read_checkpoint(run_dir, which)["config"]["garment"])
    _hash_folder(h, garment.parent)
    if unseen_from is not None:   # the unseen sketches come from there (trainer.evaluate.find_unseen)
        h.update(b" unseen_from")
        _hash_folder(h, Path(unseen_from))
    h.update(_code_hash().encode())
    return h.hexdigest()


def variant(weights: str = "average", relief: str = "none", mirrors: str = "none") -> list[str]:
    """What sets a scoring apart from the plain one (the EMA, as trained), in the order names and files carry it
    (the mirrors before the relief gain, which is fitted on what they return)."""
    return [t for t, plain in ((weights, "average"), (mirrors, "none"), (relief, "none")) if t != plain]


def unseen_tag(unseen_from: Path | str | None) -> str:
    """What files scored on another folder's unseen sketches carry, so they never replace the plain scores."""
    return "" if unseen_from is None else f"-unseen_{Path(unseen_from).name}"


def _paths(run_dir: Path, which: str, weights: str = "average", relief: str = "none",
           mirrors: str = "none", unseen_from: Path | None = None) -> tuple[Path, Path]:
    name = f"compare-{which}" + "".join(f"-{t}" for t in variant(weights, relief, mirrors)) + unseen_tag(unseen_from)
    base = Path(run_dir) / "eval" / name
    return base.with_suffix(".json"), base.with_suffix(".npz")


def _pack(arrays: dict, prefix: str, units: dict[str, Units]) -> None:
    for metric, u in units.items():
        for part in ("key", "num", "den"):
            arrays[f"{prefix}/{metric}/{part}"] = getattr(u, part)


def _unpack(arrays, prefix: str) -> dict[str, Units]:
    metrics = sorted({k.split("/")[-2] for k in arrays.files if k.startswith(prefix + "/")})
    return {m: Units(arrays[f"{prefix}/{m}/key"], arrays[f"{prefix}/{m}/num"], arrays[f"{prefix}/{m}/den"])
            for m in metrics}


def save(run_dir: Path, which: str, key: str, e: Evaluation, weights: str = "average", relief: str = "none",
         mirrors: str = "none", unseen_from: Path | None = None) -> None:
    meta_path, arr_path = _paths(run_dir, which, weights, relief, mirrors, unseen_from)
    meta_path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {}
    _pack(arrays, "run", e.units)
    for name, units in e.ref_units.items():
        _pack(arrays, f"ref:{name}", units)
    np.savez(arr_path, **arrays)
    meta_path.write_text(json.dumps({"key": key, "result": e.result, "references": sorted(e.ref_units)}))


def load(run_dir: Path, which: str, key: str, weights: str = "average", relief: str = "none",
         mirrors: str = "none", unseen_from: Path | None = None) -> Evaluation | None:
    """The stored scores if their key is `key`; None (re-score) when missing, stale or unreadable."""
    meta_path, arr_path = _paths(run_dir, which, weights, relief, mirrors, unseen_from)
    if not (meta_path.is_file() and arr_path.is_file()):
        return None
    try:
        meta = json.loads(meta_path.read_text())
        if meta.get("key") != key:
            return None
        with np.load(arr_path, allow_pickle=False) as arrays:
            return Evaluation(meta["result"], _unpack(arrays, "run"),
                              {n: _unpack(arrays, f"ref:{n}") for n in meta["references"]})
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
        log.warning("eval: stored scores of %s unreadable (%s); scoring again", run_dir, exc)
        return None


def scored(run_dir: Path, which: str, weights: str = "average", *, cache: bool = True,
           relief: str = "none", mirrors: str = "none", unseen_from: Path | None = None) -> Evaluation:
    """The run's scores: stored ones while their key holds, else scored now (and stored unless `cache` is off).
    Scoring is called from here only, so the tables built from these scores (trainer.compare) can change wording
    without re-scoring every run."""
    key = cache_key(run_dir, which, weights, relief, mirrors, unseen_from) if cache else None
    e = load(run_dir, which, key, weights, relief, mirrors, unseen_from) if cache else None
    if e is not None:
        log.info("eval: %s unchanged since it was scored; its stored scores are used", run_dir)
        return e
    e = evaluate(run_dir, which, swap=False, weights=weights, relief=relief, mirrors=mirrors,
                 unseen_from=unseen_from)
    if cache:
        save(run_dir, which, key, e, weights, relief, mirrors, unseen_from)
    return e
