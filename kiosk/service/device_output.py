"""The haptic output thread: puts the latest friction textures on the device, survives losing it.

The daemon hands over a frame (one texture per panel, in screen pixels) with `submit()`; this thread uploads each
as a texture + sprite at its screen position and commits (firmware_bridge sends only the changed tiles, the device
swaps atomically). Latest wins: a frame submitted while another uploads replaces any not yet started.

Device trouble never stops the kiosk: a device that is absent at start is opened again every
`reconnect_interval_s`; a link lost mid-run is reconnected by the bridge's own heartbeat thread, which re-sends the
current frame. Meanwhile `state()` says what is wrong (the page shows "visual only") and the counters count it.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from firmware_bridge.config import BridgeConfig
from firmware_bridge.display import HapticDisplay, LinkState
from firmware_bridge.errors import BridgeError, CommitError, LinkDownError
from kiosk.inference.render import FrictionSource, intersect

log = logging.getLogger(__name__)
KEEP_COMMITS = 256


@dataclass(frozen=True)
class Commit:
    frame: int
    at: float | None  # time.monotonic() when the device made it active; None when superseded or failed
    tiles: int = 0
    wire_bytes: int = 0
    upload_ms: float = 0.0
    friction_ms: float = 0.0
    status: str = "committed"  # committed | superseded | failed | pending


class DeviceOutput:
    def __init__(self, config: BridgeConfig, *, display: HapticDisplay | None = None, on_error=None,
                 on_texture=None):
        self.config = config
        self.display = display or HapticDisplay(config)
        self.on_error = on_error or (lambda kind, exc: None)
        self.on_texture = on_texture or (lambda source: None)
        self._cond = threading.Condition()
        self._wanted: tuple[int, list[FrictionSource]] | None = None
        self._applied_panels: set[str] = set()
        self._commits: OrderedDict[int, Commit] = OrderedDict()
        self._pending_since_down: int | None = None
        self._busy = False
        self._opened = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.last_error: str | None = None
        self.errors = 0

    # -- life cycle ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        self._try_open()
        self._thread = threading.Thread(target=self._run, name="vtkiosk-haptic-output", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._opened:
            try:
                self.display.close()  # blanks the output: the safe state
            except BridgeError as exc:
                log.warning("closing the haptic display: %s", exc)
            self._opened = False

    def _try_open(self) -> bool:
        if self._opened:
            return True
        try:
            info = self.display.open()
        except BridgeError as exc:
            self._note_error("open", exc)
            return False
        self._opened = True
        self.last_error = None
        log.info("haptic display open: %s %dx%d, firmware %s, serial %s", info.transport, info.panel_w,
                 info.panel_h, info.firmware, info.serial)
        return True

    def _note_error(self, kind: str, exc: BaseException) -> None:
        msg = f"{exc}"
        if msg != self.last_error:
            log.warning("haptic device %s: %s", kind, msg)
        self.last_error = msg
        self.errors += 1
        self.on_error(kind, exc)

    # -- frames --------------------------------------------------------------------------------------------------
    def submit(self, frame: int, sources: list[FrictionSource]) -> None:
        """Make these friction textures (one per panel, later ones on top) the device's frame."""
        with self._cond:
            if self._wanted is not None:
                self._record(Commit(self._wanted[0], None, status="superseded"))
            self._wanted = (frame, list(sources))
            self._record(Commit(frame, None, status="pending"))
            self._cond.notify_all()

    def _record(self, c: Commit) -> None:
        with self._cond:  # re-entrant (Condition's default lock is an RLock)
            self._commits[c.frame] = c
            self._commits.move_to_end(c.frame)
            while len(self._commits) > KEEP_COMMITS:
                self._commits.popitem(last=False)
            self._cond.notify_all()

    def commit_of(self, frame: int) -> Commit | None:
        with self._cond:
            return self._commits.get(frame)

    def wait_commit(self, frame: int, timeout_s: float) -> Commit | None:
        """Block until `frame` is committed, superseded or failed (or the timeout); None if unknown."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                c = self._commits.get(frame)
                if c is None or c.status != "pending":
                    return c
                left = deadline - time.monotonic()
                if left <= 0:
                    return c
                self._cond.wait(left)

    def wait_idle(self, timeout_s: float) -> bool:
        """Block until no frame is waiting or uploading (or the timeout). True when idle."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._busy or (self._wanted is not None and self._opened):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def _run(self) -> None:
        interval = max(0.05, self.config.reconnect_interval_s)
        while not self._stop.is_set():
            with self._cond:
                if self._wanted is None:
                    self._cond.wait(interval)
                job, self._wanted = self._wanted, None
                self._busy = job is not None
            if self._stop.is_set():
                return
            if not self._opened and not self._try_open():
                if job is not None:
                    self._record(Commit(job[0], None, status="failed"))
                    self._pending_since_down = job[0]
                    self._keep_for_later(job)
                self._stop.wait(interval)
                continue
            if job is None:
                self._check_recovered()
                continue
            try:
                self._apply(*job)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()

    def _keep_for_later(self, job: tuple[int, list[FrictionSource]]) -> None:
        """A frame that could not be sent because the device is absent: sent once it opens."""
        with self._cond:
            if self._wanted is None:
                self._wanted = job

    def _check_recovered(self) -> None:
        if self._pending_since_down is not None and self.display.link_state is LinkState.UP:
            log.info("haptic link up again; the current frame was re-sent")
            self._pending_since_down = None
            self.last_error = None

    def _apply(self, frame: int, sources: list[FrictionSource]) -> None:
        t_f = time.perf_counter()
        textures = []
        for src in sources:
            t = src.texture()
            self.on_texture(src)
            if t is not None:
                textures.append(t)
        t0 = time.perf_counter()
        friction_ms = 1e3 * (t0 - t_f)
        d = self.display
        try:
            info = d.info
            panel = (0, 0, info.panel_w, info.panel_h)
            names = set()
            for depth, t in enumerate(textures):
                vis = intersect(t.rect, panel)
                if vis is None:
                    continue
                x, y, w, h = vis
                px = np.ascontiguousarray(t.pixels[y - t.y:y - t.y + h, x - t.x:x - t.x + w])
                name = f"panel-{t.panel}"
                d.upload_texture(name, px)
                d.add_sprite(name, name, x, y, depth=depth)
                names.add(name)
            for gone in self._applied_panels - names:
                d.remove_sprite(gone)
            self._applied_panels = names
            result = d.commit()
        except LinkDownError as exc:
            self._note_error("link", exc)
            self._pending_since_down = frame
            self._record(Commit(frame, None, status="failed"))
            return
        except (CommitError, BridgeError, ValueError, KeyError, TypeError) as exc:
            self._note_error("commit", exc)
            self._record(Commit(frame, None, status="failed"))
            return
        self.last_error = None
        self._pending_since_down = None
        self._record(Commit(frame, time.monotonic(), result.tiles_sent, result.wire_bytes,
                            1e3 * (time.perf_counter() - t0), friction_ms))

    # -- state ---------------------------------------------------------------------------------------------------
    @property
    def up(self) -> bool:
        return self._opened and self.display.link_state is LinkState.UP

    def state(self) -> dict:
        h = self.health()
        return {"up": self.up, "state": h.state if h else "closed", "error": self.last_error,
                "reconnects": h.reconnects if h else 0, "frames_committed": h.frames_committed if h else 0,
                "type": self.config.type}

    def health(self):
        """firmware_bridge's LinkHealth (None before the device was ever opened)."""
        if not self._opened:
            return None
        return self.display.health()

    def composed(self) -> np.ndarray | None:
        """The frame the host wants felt (what the device holds once committed)."""
        if not self._opened:
            return None
        return self.display.compose()

    # -- emulator access (tests, bench, fault injection) -----------------------------------------------------------
    @property
    def emulator(self):
        """The in-process emulated device, or None for real hardware / a socket emulator."""
        return getattr(self.display.transport, "emulator", None)
