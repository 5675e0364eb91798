"""Render jobs: the queue between the HTTP threads and the inference loops, with latest-wins cancellation.

The main loop runs stroke ends and refinements one at a time, so they never compete with each other for the cores.
Previews while drawing run either in that loop too, in turn (a preview that arrives during a refinement waits for
all of it), or in a preview loop of their own (`inference.preview_threads`), beside the refinement on a thread
budget of their own, so drawing stays fluid while the last stroke end is refined. An HTTP thread submits a job and
waits for it; a newer request from the same client cancels that client's queued previews and refinements (a stroke
end is never dropped), and a job not answered in time is withdrawn so the page keeps its last frame.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from kiosk.contract.errors import KioskError
from kiosk.ops.health import Heartbeat
from kiosk.service.api import RenderRequest

log = logging.getLogger(__name__)
IDLE_BEAT_S = 0.25
CANCELLABLE = ("preview", "refine")


class BusyError(KioskError):
    """The inference loop did not answer in time (it is hung or overloaded); the page keeps its last frame."""


class Superseded(Exception):
    """A preview or refinement replaced by a newer request before it ran."""


@dataclass(eq=False)  # a job is itself: comparing requests field by field would compare their sketch arrays
class Job:
    request: RenderRequest
    received_at: float
    done: threading.Event = field(default_factory=threading.Event)
    result: Any = None
    error: BaseException | None = None
    superseded: bool = False


def lane_of(job: Job) -> str:
    """`preview` for a preview while drawing, `main` for everything else (the engine lane it runs in)."""
    return "preview" if job.request.mode == "preview" else "main"


class JobQueue:
    """Jobs waiting for the inference loop, oldest first."""

    def __init__(self) -> None:
        self._jobs: list[Job] = []
        self._cond = threading.Condition()

    def __len__(self) -> int:
        return len(self._jobs)

    def submit(self, request: RenderRequest, received_at: float, timeout_s: float) -> Any:
        """Queue a job and wait for its result; raises Superseded, BusyError or the job's own error."""
        job = Job(request, received_at)
        with self._cond:
            for old in self._jobs:
                if old.request.mode in CANCELLABLE and old.request.client == request.client:
                    old.superseded = True
                    old.done.set()
            self._jobs = [j for j in self._jobs if not j.superseded]
            self._jobs.append(job)
            self._cond.notify_all()
        if not job.done.wait(timeout_s):
            with self._cond:
                if job in self._jobs:
                    self._jobs.remove(job)
            raise BusyError(f"the inference loop did not answer within {timeout_s:.1f} s; showing the last frame")
        if job.superseded:
            raise Superseded()
        if job.error is not None:
            raise job.error
        return job.result

    def take(self, wait_s: float, lane: str | None = None) -> Job | None:
        """The oldest job of `lane` (`preview`: previews, `main`: everything else, None: any), waiting up to
        `wait_s` for one."""
        with self._cond:
            job = self._first(lane)
            if job is None:
                self._cond.wait(wait_s)
                job = self._first(lane)
            if job is not None:
                self._jobs.remove(job)
            return job

    def _first(self, lane: str | None) -> Job | None:
        return next((j for j in self._jobs if lane is None or lane_of(j) == lane), None)

    def put_back(self, job: Job) -> None:
        with self._cond:
            self._jobs.insert(0, job)

    def wake(self) -> None:
        with self._cond:
            self._cond.notify_all()


class InferenceLoop:
    """The thread that runs jobs one at a time: `execute(job) -> result`, `before(job)` first (a refinement waits
    for the quick answer's upload there), `idle()` between jobs. It beats the heartbeat while idle too, so a hung
    loop, not a quiet shop, fails the health check. `lane`: the jobs this loop takes (`JobQueue.take`)."""

    def __init__(self, queue: JobQueue, heartbeat: Heartbeat, execute: Callable[[Job], Any], *,
                 before: Callable[[Job], None] = lambda job: None, idle: Callable[[], None] = lambda: None,
                 lane: str | None = None, name: str = "vtkiosk-inference"):
        self.queue, self.heartbeat = queue, heartbeat
        self.lane, self.name = lane, name
        self._execute, self._before, self._idle = execute, before, idle
        self.hang = threading.Event()  # fault injection: no beats, no work (the watchdog must notice)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stop.set()
        self.hang.clear()
        self.queue.wake()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
            self._thread = None

    def _run(self) -> None:
        self.heartbeat.beat()
        while not self._stop.is_set():
            while self.hang.is_set() and not self._stop.is_set():
                time.sleep(0.02)
            job = self.queue.take(IDLE_BEAT_S, self.lane)
            if job is None:
                self.heartbeat.beat()
                self._idle()
                continue
            if self.hang.is_set():
                self.queue.put_back(job)
                continue
            t0 = time.monotonic()
            self._before(job)
            try:
                job.result = self._execute(job)
            except BaseException as exc:  # noqa: BLE001 - the loop must survive anything one job does
                if not isinstance(exc, KioskError):
                    log.exception("render job failed")
                job.error = exc
            finally:
                job.done.set()
            self.heartbeat.beat(time.monotonic() - t0)
