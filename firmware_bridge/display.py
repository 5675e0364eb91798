"""`HapticDisplay`: the kiosk's handle on the haptic screen (textures, sprites, views) and on the link to it.

The vendor's concepts, composed on the host: a *texture* is an 8-bit friction map (uint8 (h, w), 0 = natural
friction, 255 = maximum); a *sprite* places a texture at a screen rectangle (x, y = top-left, pixels) with a depth
(higher depth is drawn on top) and a material ('1:1' clips, 'zoom' scales nearest-neighbour, 'tile' repeats);
a *view* groups sprites and is switched as a whole (`show_view`). `commit()` composes the active view into a
panel frame (uint8 (panel_h, panel_w)) and uploads only the tiles that differ from the device's frame; the device
makes it active atomically. `present(frame)` commits a ready panel frame (what the kiosk's friction map is).

Link life cycle: CLOSED -> (open) -> UP -> (I/O error, or `link_loss_after` missed heartbeats) -> DOWN ->
(reconnect every `reconnect_interval_s`: open, handshake, restore gain/blank, re-send the current frame) -> UP.
While DOWN, commit/blank/set_gain/clear record what is wanted, raise LinkDownError, and it is applied on reconnect;
the device's own watchdog blanks the screen when the host goes silent. A daemon heartbeat thread drives `poll()`
when `config.background` is true; tests with a modelled clock call `poll()` themselves.

Example::

    with HapticDisplay(BridgeConfig(type="emulated")) as d:
        d.upload_texture("denim", friction)            # uint8 (h, w)
        d.add_sprite("shirt", "denim", x=100, y=50)    # 1:1 at (100, 50)
        result = d.commit()                            # CommitResult(tiles_sent=..., wire_bytes=...)
"""
from __future__ import annotations

import enum
import threading
from dataclasses import dataclass, field

import numpy as np

from . import protocol as P
from .config import BridgeConfig
from .errors import BridgeError, CommitError, LinkDownError, LinkError, ProtocolError
from .session import LinkTimeout, Rejected, Session
from .tiles import Grid, changed_tiles, encode_tile
from .transports import create_transport

MATERIALS = ("1:1", "zoom", "tile")


class LinkState(str, enum.Enum):
    CLOSED = "closed"
    UP = "up"
    DOWN = "down"


@dataclass(frozen=True)
class DeviceInfo:
    """What the controller reported in its handshake. Sizes in pixels."""

    protocol_version: int
    panel_w: int
    panel_h: int
    max_texture_w: int
    max_texture_h: int
    tile_w: int
    tile_h: int
    firmware: str
    serial: str
    capabilities: tuple[str, ...]
    transport: str

    @classmethod
    def from_info(cls, info: P.Info, transport: str) -> "DeviceInfo":
        caps = tuple(c.name for c in P.Cap if info.capabilities & c)
        return cls(info.version, info.panel_w, info.panel_h, info.max_texture_w, info.max_texture_h, info.tile_w,
                   info.tile_h, info.firmware, info.serial, caps, transport)


@dataclass(frozen=True)
class Sprite:
    name: str
    texture: str
    x: int
    y: int
    width: int
    height: int
    depth: int = 0
    material: str = "1:1"


@dataclass(frozen=True)
class CommitResult:
    """One frame upload. Bytes: protocol messages (`payload_bytes`) and reports on the wire (`wire_bytes`);
    `link_time_s` is transport-clock time (modelled on a virtual clock, real otherwise)."""

    frame_id: int
    tiles_sent: int
    tiles_total: int
    payload_bytes: int
    wire_bytes: int
    retransmits: int
    attempts: int
    full: bool
    skipped: bool
    link_time_s: float


@dataclass(frozen=True)
class LinkHealth:
    state: str
    last_heartbeat_age_s: float | None
    heartbeat_rtt_s: float | None
    missed_heartbeats: int
    reconnects: int
    frames_committed: int
    device_active_id: int | None
    device_blanked: bool | None
    device_watchdog: bool | None
    last_error: str | None
    counters: dict = field(default_factory=dict)


class HapticDisplay:
    def __init__(self, config: BridgeConfig | None = None, *, transport=None, **inject) -> None:
        """`transport`: a ready transport (tests); else built from `config.type` with `inject` (hid_api=,
        usb_api=, emulator=, clock=) passed to the transport plugin."""
        self.config = config or BridgeConfig()
        self.transport = transport if transport is not None else create_transport(self.config, **inject)
        self.clock = self.transport.clock
        self.session = Session(self.transport, self.config)
        self._io = threading.RLock()
        self._state = LinkState.CLOSED
        self._info: DeviceInfo | None = None
        self._grid: Grid | None = None
        self._textures: dict[str, np.ndarray] = {}
        self._views: dict[str, dict[str, Sprite]] = {"default": {}}
        self._active_view = "default"
        self._current: np.ndarray | None = None  # the frame the host wants felt
        self._device_frame: np.ndarray | None = None  # what the device's active frame is known to be
        self._device_id = 0
        self._frame_id = 0
        self._gain = 1000
        self._blanked = False
        self._hb_counter = 0
        self._last_hb: float | None = None
        self._hb_rtt: float | None = None
        self._misses = 0
        self._next_reconnect = 0.0
        self._last_status: P.Status | None = None
        self._last_error: str | None = None
        self.reconnects = 0
        self.frames_committed = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- life cycle ----------------------------------------------------------------------------------------------
    def open(self) -> DeviceInfo:
        """Open the device and handshake; starts the heartbeat thread if `config.background`."""
        with self._io:
            self._connect()
        if self.config.background and self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="haptic-bridge-heartbeat", daemon=True)
            self._thread.start()
        return self.info

    def close(self) -> None:
        """Stop the heartbeat thread, blank the output (the safe state) if configured, release the device."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=max(2.0, 4 * self.config.heartbeat_interval_s))
            self._thread = None
        with self._io:
            if self._state is LinkState.UP and self.config.blank_on_close:
                try:
                    self._control(lambda s: P.Blank(s, 1))
                except BridgeError:
                    pass
            self.transport.close()
            self._state = LinkState.CLOSED

    def __enter__(self) -> "HapticDisplay":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def info(self) -> DeviceInfo:
        if self._info is None:
            raise LinkError("device info unknown: open() the display first")
        return self._info

    @property
    def link_state(self) -> LinkState:
        return self._state

    def _connect(self) -> None:
        """Open + handshake + restore state + re-send the current frame. Caller holds the lock."""
        self.transport.open()
        try:
            reply = self.session.request(lambda s: P.Hello(s, P.VERSION, P.VERSION, self.transport.report_size),
                                         timeout_s=self.config.handshake_timeout_s)
            if isinstance(reply, P.Nack) and reply.code == P.NackCode.BAD_VALUE:
                raise ProtocolError(f"bridge uses {reply.frame_id} B reports but report_size is "
                                    f"{self.transport.report_size}; set report_size: {reply.frame_id}")
            if isinstance(reply, P.Nack):
                raise ProtocolError(f"bridge refused protocol v{P.VERSION} (NACK {P.NackCode(reply.code).name}); "
                                    f"update the bridge firmware")
            info = DeviceInfo.from_info(reply, self.transport.name)
            if self._info is not None and (info.panel_w, info.panel_h) != (self._info.panel_w, self._info.panel_h):
                raise ProtocolError(f"bridge panel changed from {self._info.panel_w}x{self._info.panel_h} to "
                                    f"{info.panel_w}x{info.panel_h}; restart the kiosk")
            need = info.tile_w * info.tile_h + P.Tile.FMT.size
            if reply.max_payload < need:
                raise ProtocolError(f"bridge max_payload {reply.max_payload} B < one raw tile ({need} B)")
            self._info = info
            self._grid = Grid(info.panel_w, info.panel_h, info.tile_w, info.tile_h)
            status = self._heartbeat_exchange()
            self._frame_id = max(self._frame_id, status.active_id, status.pending_id)
            self._device_frame, self._device_id = None, status.active_id  # unknown contents: next upload is full
            self._state = LinkState.UP
            self._misses = 0
            if self._gain != status.gain:
                self._control(lambda s: P.SetGain(s, self._gain))
            if self._blanked != bool(status.flags & P.STATUS_BLANKED):
                self._control(lambda s: P.Blank(s, int(self._blanked)))
            if self._current is not None:
                self._upload(self._current)
        except BaseException:
            self.transport.close()
            self._state = LinkState.DOWN if self._info is not None else LinkState.CLOSED
            raise

    def _link_down(self, exc: BaseException) -> None:
        self._state = LinkState.DOWN
        self._last_error = str(exc)
        self._device_frame = None
        self._next_reconnect = self.clock.now()
        self.transport.close()

    def _guard(self, what: str):
        if self._state is LinkState.CLOSED:
            raise LinkError(f"cannot {what}: the display is not open")
        if self._state is LinkState.DOWN:
            raise LinkDownError(f"haptic bridge link down ({self._last_error}); {what} will be applied on reconnect")

    # -- heartbeat / reconnect -----------------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            self.poll()
            interval = self.config.heartbeat_interval_s if self._state is LinkState.UP \
                else min(self.config.heartbeat_interval_s, self.config.reconnect_interval_s)
            self._stop.wait(interval)

    def poll(self) -> LinkState:
        """One heartbeat-thread step: heartbeat when UP (detecting link loss), reconnect attempt when DOWN."""
        with self._io:
            if self._state is LinkState.UP:
                try:
                    status = self._heartbeat_exchange()
                except LinkTimeout as exc:
                    self._misses += 1
                    if self._misses >= self.config.link_loss_after:
                        self._link_down(exc)
                except LinkError as exc:
                    self._link_down(exc)
                else:
                    self._misses = 0
                    if self._device_frame is not None and (status.active_id != self._device_id or
                                                           status.active_crc != P.crc32(self._device_frame)):
                        self._device_frame = None  # the device lost our frame (reset?): re-send it in full
                        if self._current is not None:
                            try:
                                self._upload(self._current)
                            except LinkError as exc:
                                self._link_down(exc)
                            except CommitError as exc:
                                self._last_error = str(exc)
            elif self._state is LinkState.DOWN and self.clock.now() >= self._next_reconnect:
                self._next_reconnect = self.clock.now() + self.config.reconnect_interval_s
                try:
                    self._connect()
                    self.reconnects += 1
                except BridgeError as exc:
                    self._state = LinkState.DOWN
                    self._last_error = str(exc)
            return self._state

    def reconnect(self, timeout_s: float = 2.0) -> bool:
        """Try to bring a DOWN link UP within timeout_s (transport clock). True when UP."""
        deadline = self.clock.now() + timeout_s
        for _ in range(10_000):
            with self._io:
                if self._state is LinkState.UP:
                    return True
                self._next_reconnect = min(self._next_reconnect, self.clock.now())
            self.poll()
            if self._state is LinkState.UP:
                return True
            if self.clock.now() >= deadline:
                return False
            self.clock.sleep(self.config.reconnect_interval_s)
        return False

    def heartbeat(self) -> P.Status:
        """One heartbeat exchange now; returns the device's STATUS."""
        with self._io:
            self._guard("heartbeat")
            return self._heartbeat_exchange()

    def _heartbeat_exchange(self) -> P.Status:
        self._hb_counter = (self._hb_counter + 1) & P.U32
        t0 = self.clock.now()
        counter = self._hb_counter
        status = self.session.request(lambda s: P.Heartbeat(s, counter), timeout_s=self.config.heartbeat_timeout_s,
                                      retries=0)
        self._last_hb = self.clock.now()
        self._hb_rtt = self._last_hb - t0
        self._last_status = status
        return status

    def health(self) -> LinkHealth:
        with self._io:
            st = self._last_status
            age = None if self._last_hb is None else self.clock.now() - self._last_hb
            counters = dict(self.session.stats)
            counters["resyncs"] = getattr(self.transport, "resyncs", 0)
            return LinkHealth(self._state.value, age, self._hb_rtt, self._misses, self.reconnects,
                              self.frames_committed, st.active_id if st else None,
                              bool(st.flags & P.STATUS_BLANKED) if st else None,
                              bool(st.flags & P.STATUS_WATCHDOG) if st else None, self._last_error, counters)

    # -- control -------------------------------------------------------------------------------------------------
    def _control(self, build) -> None:
        reply = self.session.request(build)
        if isinstance(reply, P.Nack):
            raise CommitError(f"bridge refused {P.MsgType(reply.acked_type).name}: {P.NackCode(reply.code).name}")

    def _checked_control(self, what: str, build) -> None:
        with self._io:
            self._guard(what)
            try:
                self._control(build)
            except LinkError as exc:
                self._link_down(exc)
                raise LinkDownError(f"haptic bridge link lost during {what} ({exc}); applied on reconnect") from None

    def set_gain(self, gain: float) -> None:
        """Output gain in [0, 1] (felt friction = frame * gain), sent as permille."""
        if not 0.0 <= float(gain) <= 1.0:
            raise ValueError(f"gain must be in [0, 1], got {gain}")
        self._gain = int(round(float(gain) * 1000))
        self._checked_control("set_gain", lambda s: P.SetGain(s, self._gain))

    def blank(self) -> None:
        """All friction off now (the safe state); the frame is kept for `unblank()`."""
        self._blanked = True
        self._checked_control("blank", lambda s: P.Blank(s, 1))

    def unblank(self) -> None:
        self._blanked = False
        self._checked_control("unblank", lambda s: P.Blank(s, 0))

    def clear(self) -> None:
        """Make an all-zero frame active (atomically) and forget the sprites of the active view."""
        with self._io:
            self._views[self._active_view] = {}
            if self._grid is not None:
                self._current = np.zeros((self._grid.panel_h, self._grid.panel_w), np.uint8)
            self._guard("clear")
            self._frame_id += 1
            fid = self._frame_id
            try:
                self._control(lambda s: P.Clear(s, fid))
            except LinkError as exc:
                self._link_down(exc)
                raise LinkDownError(f"haptic bridge link lost during clear ({exc}); applied on reconnect") from None
            self._device_frame, self._device_id = self._current.copy(), fid
            self.frames_committed += 1

    # -- textures, sprites, views ---------------------------------------------------------------------------------
    def upload_texture(self, name: str, friction: np.ndarray) -> None:
        """Store texture `name`: uint8 (h, w) friction map, h <= max_texture_h, w <= max_texture_w (host side;
        it reaches the device as part of the composed frame at `commit()`)."""
        if not isinstance(friction, np.ndarray) or friction.dtype != np.uint8 or friction.ndim != 2:
            raise TypeError(f"texture {name!r} must be a uint8 numpy array of shape (h, w), got "
                            f"{getattr(friction, 'dtype', type(friction).__name__)} {getattr(friction, 'shape', '')}")
        if self._info is not None and (friction.shape[0] > self._info.max_texture_h
                                       or friction.shape[1] > self._info.max_texture_w):
            raise ValueError(f"texture {name!r} is {friction.shape[1]}x{friction.shape[0]}, larger than the device "
                             f"maximum {self._info.max_texture_w}x{self._info.max_texture_h}")
        if 0 in friction.shape:
            raise ValueError(f"texture {name!r} is empty: shape {friction.shape}")
        with self._io:
            self._textures[name] = friction.copy()

    def delete_texture(self, name: str) -> None:
        with self._io:
            users = [s.name for v in self._views.values() for s in v.values() if s.texture == name]
            if users:
                raise ValueError(f"texture {name!r} is used by sprites {users}; remove them first")
            self._textures.pop(name, None)

    def add_sprite(self, name: str, texture: str, x: int, y: int, *, width: int | None = None,
                   height: int | None = None, depth: int = 0, material: str = "1:1", view: str = "default") -> Sprite:
        """Place `texture` at the screen rectangle (x, y, width, height) (pixels, top-left origin) in `view`.
        width/height default to the texture's size; parts outside the panel are clipped."""
        with self._io:
            if texture not in self._textures:
                raise KeyError(f"no texture {texture!r}; upload_texture() it first (have {sorted(self._textures)})")
            if material not in MATERIALS:
                raise ValueError(f"material must be one of {MATERIALS}, got {material!r}")
            th, tw = self._textures[texture].shape
            sprite = Sprite(name, texture, int(x), int(y), int(width or tw), int(height or th), int(depth), material)
            if sprite.width <= 0 or sprite.height <= 0:
                raise ValueError(f"sprite {name!r} needs a positive size, got {sprite.width}x{sprite.height}")
            self._views.setdefault(view, {})[name] = sprite
            return sprite

    def remove_sprite(self, name: str, view: str = "default") -> None:
        with self._io:
            self._views.get(view, {}).pop(name, None)

    def show_view(self, name: str) -> None:
        """Switch the active view as a whole (felt after the next `commit()`)."""
        with self._io:
            if name not in self._views:
                raise KeyError(f"no view {name!r}; have {sorted(self._views)}")
            self._active_view = name

    def compose(self) -> np.ndarray:
        """The active view as a panel frame: uint8 (panel_h, panel_w), sprites in increasing depth order."""
        with self._io:
            g = self._require_grid()
            frame = np.zeros((g.panel_h, g.panel_w), np.uint8)
            for s in sorted(self._views[self._active_view].values(), key=lambda s: s.depth):
                _paste(frame, self._textures[s.texture], s)
            return frame

    def _require_grid(self) -> Grid:
        if self._grid is None:
            raise LinkError("panel size unknown: open() the display first")
        return self._grid

    # -- frames --------------------------------------------------------------------------------------------------
    def commit(self) -> CommitResult:
        """Compose the active view and make it felt atomically (see `present`)."""
        return self.present(self.compose())

    def present(self, frame: np.ndarray) -> CommitResult:
        """Make `frame` (uint8 (panel_h, panel_w)) the felt frame: delta tiles, compressed, committed atomically.

        Raises LinkDownError when the link is down (the frame is sent on reconnect), CommitError when the device
        keeps refusing it (the previous frame stays active).
        """
        with self._io:
            frame = self._require_grid().check_frame(frame)
            self._current = frame.copy()
            self._guard("the frame")
            try:
                return self._upload(self._current)
            except LinkError as exc:
                self._link_down(exc)
                raise LinkDownError(f"haptic bridge link lost during upload ({exc}); the frame is re-sent on "
                                    f"reconnect") from None

    def _upload(self, frame: np.ndarray) -> CommitResult:
        g, cfg = self._require_grid(), self.config
        t0 = self.clock.now()
        stats0 = self.session.stats["retransmits"]
        wire0 = self.transport.bytes_out
        frame_crc = P.crc32(frame.tobytes())
        payload = 0
        last_nack = "none"
        for attempt in range(1, cfg.frame_retries + 2):
            base = self._device_frame if cfg.delta else None
            todo = changed_tiles(g, frame, base)
            if base is not None and not todo:
                return CommitResult(self._device_id, 0, g.count, 0, 0, 0, attempt, False, True, 0.0)
            self._frame_id += 1
            fid = self._frame_id
            base_id = self._device_id if base is not None else P.FULL_BASE
            reply = self.session.request(lambda s: P.Begin(s, fid, base_id, len(todo)))
            if isinstance(reply, P.Nack):
                last_nack = P.NackCode(reply.code).name
                self._resync_device()
                continue
            builders, size = self._tile_builders(g, frame, fid, todo)
            payload += size
            try:
                self.session.send_tiles(builders)
            except Rejected as exc:
                last_nack = P.NackCode(exc.nack.code).name
                self._abort(fid)
                self._resync_device()
                continue
            reply = self.session.request(lambda s: P.Commit(s, fid, len(todo), frame_crc))
            if isinstance(reply, P.Nack):
                last_nack = P.NackCode(reply.code).name
                self._abort(fid)
                self._resync_device()
                continue
            self._device_frame, self._device_id = frame.copy(), fid
            self.frames_committed += 1
            return CommitResult(fid, len(todo), g.count, payload, self.transport.bytes_out - wire0,
                                self.session.stats["retransmits"] - stats0, attempt, base is None, False,
                                self.clock.now() - t0)
        raise CommitError(f"bridge refused the frame {cfg.frame_retries + 1} times (last NACK {last_nack}); "
                          f"the previous frame stays active")

    def _tile_builders(self, g: Grid, frame: np.ndarray, fid: int, todo):
        cfg = self.config
        builders, size = [], 0
        for tx, ty in todo:
            raw = g.tile_bytes(frame, tx, ty)
            codec, data = encode_tile(raw, cfg.compression, cfg.zlib_level)
            crc = P.crc32(raw)
            size += P.OVERHEAD + P.Tile.FMT.size + len(data)
            builders.append(lambda s, tx=tx, ty=ty, codec=codec, crc=crc, data=data:
                            P.Tile(s, fid, tx, ty, int(codec), crc, data))
        return builders, size

    def _abort(self, fid: int) -> None:
        try:
            self.session.request(lambda s: P.Abort(s, fid), retries=1)
        except LinkTimeout:
            pass  # the next BEGIN (newer frame id) drops the pending frame anyway

    def _resync_device(self) -> None:
        """After a NACK: forget the delta base and move our frame ids past the device's."""
        self._device_frame = None
        status = self._heartbeat_exchange()
        self._device_id = status.active_id
        self._frame_id = max(self._frame_id, status.active_id, status.pending_id)


def _paste(frame: np.ndarray, tex: np.ndarray, s: Sprite) -> None:
    """Draw texture `tex` into `frame` at sprite `s`'s rectangle with its material, clipped to the panel."""
    ph, pw = frame.shape
    y0, x0 = max(s.y, 0), max(s.x, 0)
    y1, x1 = min(s.y + s.height, ph), min(s.x + s.width, pw)
    if y0 >= y1 or x0 >= x1:
        return
    th, tw = tex.shape
    ys = np.arange(y0, y1) - s.y  # sprite-local rows/cols of the visible part
    xs = np.arange(x0, x1) - s.x
    if s.material == "zoom":
        rows, cols = ys * th // s.height, xs * tw // s.width
    elif s.material == "tile":
        rows, cols = ys % th, xs % tw
    else:  # 1:1: pixels beyond the texture stay untouched
        keep_y, keep_x = ys < th, xs < tw
        ys, xs = ys[keep_y], xs[keep_x]
        if ys.size == 0 or xs.size == 0:
            return
        y1, x1 = y0 + ys.size, x0 + xs.size
        rows, cols = ys, xs
    frame[y0:y1, x0:x1] = tex[np.ix_(rows, cols)]
