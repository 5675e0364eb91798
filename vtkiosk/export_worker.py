"""One warm process that exports catalogue garments one after another, for the demo's first start.

A `vtkiosk export` child pays Python's start and the torch + exporter imports (about 3 s of one core) before any
work, and the demo's three exports on two cores put two of them on the critical path. A worker imports once, while
the parent is still setting up, and then takes jobs: regenerate a garment's data and materialise its run
(`vtkiosk.catalogue.materialise`), then run the exporter's own command line in-process. The parent, which goes on
to serve, never imports torch.

Protocol: one JSON object per line. The worker writes `{"ready": true}` once its imports are done; each job line
`{"id", "entry", "data_dir", "run_dir", "argv", "log"}` gets exactly one reply `{"id", "ok", "error"}`. A job's
output (prints, logging, C-level writes) goes to its `log` file; the protocol keeps its own copy of stdout. A job
that fails replies with the error and the worker takes the next; a line that is not a job is answered with
`"id": null` and an error. End of input ends the worker.
"""
from __future__ import annotations

import contextlib
import json
import os
import sys
import traceback
from pathlib import Path
from typing import IO, Iterator

JOB_KEYS = ("id", "entry", "data_dir", "run_dir", "argv", "log")


@contextlib.contextmanager
def _output_to(log: IO[bytes]) -> Iterator[None]:
    """fds 1 and 2 into `log` for the duration (so child processes and C libraries land there too)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    os.dup2(log.fileno(), 1)
    os.dup2(log.fileno(), 2)
    try:
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])


def parse_job(line: str) -> dict:
    job = json.loads(line)
    if not isinstance(job, dict):
        raise ValueError("a job is a JSON object")
    missing = [k for k in JOB_KEYS if k not in job]
    if missing:
        raise ValueError(f"a job needs {', '.join(missing)}")
    if not isinstance(job["argv"], list) or not all(isinstance(a, str) for a in job["argv"]):
        raise ValueError("argv must be a list of strings")
    return job


def run_job(job: dict) -> None:
    """Materialise the entry's run, then export it; raises on any failure."""
    from exporter.cli import main as export_main
    from vtkiosk.catalogue import CATALOGUE, load_index, materialise

    entry = next((e for e in load_index(CATALOGUE) if e.id == job["entry"]), None)
    if entry is None:
        raise ValueError(f"no catalogue entry {job['entry']!r}")
    materialise(entry, CATALOGUE, Path(job["data_dir"]), Path(job["run_dir"]))
    try:
        rc = export_main(job["argv"])
    except SystemExit as e:   # argparse refusals
        rc = e.code if isinstance(e.code, int) else 2
    if rc != 0:
        raise RuntimeError(f"vtkiosk export exited {rc}")


def main() -> int:
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    import exporter.export  # noqa: F401  (torch and the exporter: the warm-up this worker exists for)
    import vtkiosk.catalogue  # noqa: F401
    reply.write(json.dumps({"ready": True}) + "\n")
    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            job = parse_job(line)
        except ValueError as e:   # json.JSONDecodeError is a ValueError
            reply.write(json.dumps({"id": None, "ok": False, "error": f"bad job line: {e}"}) + "\n")
            continue
        error = ""
        with open(job["log"], "ab") as log, _output_to(log):
            try:
                run_job(job)
            except Exception as e:   # reported to the parent; the worker stays up for the next job
                traceback.print_exc()
                error = f"{type(e).__name__}: {e}"
        reply.write(json.dumps({"id": job["id"], "ok": not error, "error": error}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
