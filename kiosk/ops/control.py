"""The operator's control socket: JSON lines over a unix stream socket, one request -> one reply.

`vtkiosk bundle activate|rollback` tells the running daemon to reload through it ({"op": "reload"}); the study
adds "study.*" ops through the daemon. Requests are objects with a string "op"; replies are objects with "ok"
(bool) and, on failure, "error" (one line an operator can act on).

Access is restricted two ways: the socket file is created with `mode` (0660) and `group` (the operator group)
before it becomes visible under its final name (bound under a temporary name, then renamed, so there is no
window with looser permissions), and every connection's peer credentials (SO_PEERCRED) are checked: root, the
daemon's own user, or a member of `group`.
"""
from __future__ import annotations

import errno
import grp
import json
import logging
import os
import pwd
import socket
import stat
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path

from kiosk.contract.errors import KioskError

log = logging.getLogger(__name__)

SO_PEERGROUPS = getattr(socket, "SO_PEERGROUPS", 59)  # Linux asm-generic value; Python does not name it
MAX_LINE = 64 << 10  # bytes per request line; a control request is tiny
Handler = Callable[[dict], dict]


class ControlError(KioskError):
    """The control socket cannot be set up, reached, or answered."""


class NoDaemonError(ControlError):
    """Nothing listens on the control socket: the daemon is not running."""


def _decode_request(line: bytes) -> dict:
    try:
        req = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ControlError(f"request is not a JSON line ({exc})") from exc
    if not isinstance(req, dict):
        raise ControlError("request must be a JSON object")
    if not isinstance(req.get("op"), str) or not req["op"]:
        raise ControlError('request needs a string "op"')
    return req


def _encode(reply: dict) -> bytes:
    return json.dumps(reply, separators=(",", ":"), default=str).encode("utf-8") + b"\n"


def _group_members(gid: int) -> set[str]:
    try:
        return set(grp.getgrgid(gid).gr_mem)
    except KeyError:
        return set()


def _peer_groups(conn: socket.socket) -> set[int]:
    """The peer process's supplementary groups as the kernel knows them (SO_PEERGROUPS, Linux >= 4.13)."""
    try:
        data = conn.getsockopt(socket.SOL_SOCKET, SO_PEERGROUPS, 1024)  # room for 256 groups
    except OSError:
        return set()
    return set(struct.unpack(f"{len(data) // 4}I", data[: len(data) // 4 * 4]))


class ControlServer:
    """Serves `handler` on the unix socket `path` from a background thread (a thread per connection)."""

    def __init__(self, path: Path, handler: Handler, *, group: str | None = None, mode: int = 0o660,
                 timeout_s: float = 30.0):
        self.path = Path(path)
        self.handler = handler
        self.group = group
        self.mode = mode
        self.timeout_s = timeout_s
        self._gid: int | None = None
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def _clear_stale(self) -> None:
        try:
            st = self.path.lstat()
        except FileNotFoundError:
            return
        if not stat.S_ISSOCK(st.st_mode):
            raise ControlError(f"{self.path} exists and is not a socket; refusing to replace it")
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        try:
            probe.connect(str(self.path))
        except OSError as exc:
            if exc.errno in (errno.ECONNREFUSED, errno.ENOENT):
                self.path.unlink(missing_ok=True)  # left over from a daemon that died
                return
            raise ControlError(f"cannot check the existing control socket {self.path}: {exc}") from exc
        else:
            raise ControlError(f"another daemon already listens on {self.path}")
        finally:
            probe.close()

    def start(self) -> None:
        if self._sock is not None:
            return
        if self.group is not None:
            try:
                self._gid = grp.getgrnam(self.group).gr_gid
            except KeyError as exc:
                raise ControlError(f"control socket group {self.group!r} does not exist "
                                   "(install systemd/vtkiosk.sysusers.conf)") from exc
        if not self.path.parent.is_dir():
            raise ControlError(f"control socket folder {self.path.parent} does not exist")
        if len(os.fsencode(self.path)) > 107:
            raise ControlError(f"control socket path {self.path} is longer than a unix socket allows (107 bytes)")
        self._clear_stale()
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        tmp.unlink(missing_ok=True)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        try:
            sock.bind(str(tmp))
            os.chmod(tmp, self.mode)
            if self._gid is not None and tmp.stat().st_gid != self._gid:
                # Under vtkiosk.service the folder is setgid vtkiosk-ops, so the socket already has the group and
                # no chown is needed (the unit's syscall filter refuses chown).
                os.chown(tmp, -1, self._gid)
            sock.listen(64)
            os.rename(tmp, self.path)
        except OSError as exc:
            sock.close()
            tmp.unlink(missing_ok=True)
            raise ControlError(f"cannot create the control socket {self.path}: {exc}") from exc
        sock.settimeout(0.2)
        self._sock = sock
        self._stop.clear()
        self._thread = threading.Thread(target=self._accept_loop, name="vtkiosk-control", daemon=True)
        self._thread.start()
        log.info("control socket listening on %s", self.path)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            try:
                self.path.unlink()
            except FileNotFoundError:
                pass
        with self._lock:
            for c in list(self._conns):
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def __enter__(self) -> ControlServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- serving -----------------------------------------------------------------------------------------------
    def _accept_loop(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue
            threading.Thread(target=self._serve, args=(conn,), name="vtkiosk-control-conn", daemon=True).start()

    def _peer_allowed(self, conn: socket.socket) -> tuple[bool, str]:
        creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
        pid, uid, gid = struct.unpack("3i", creds)
        if uid in (0, os.geteuid()) or self._gid is None or gid == self._gid:
            return True, ""
        if self._gid in _peer_groups(conn):
            return True, ""
        try:
            name = pwd.getpwuid(uid).pw_name
        except KeyError:
            name = None
        if name is not None and (name in _group_members(self._gid) or self._gid in os.getgrouplist(name, gid)):
            return True, ""
        return False, f"uid {uid} (pid {pid}) is not in group {self.group}"

    def _serve(self, conn: socket.socket) -> None:
        with self._lock:
            self._conns.add(conn)
        try:
            conn.settimeout(self.timeout_s)
            allowed, why = self._peer_allowed(conn)
            if not allowed:
                log.warning("control socket: refused %s", why)
                conn.sendall(_encode({"ok": False, "error": f"permission denied: {why}"}))
                return
            buf = b""
            while not self._stop.is_set():
                nl = buf.find(b"\n")
                if nl < 0:
                    if len(buf) > MAX_LINE:
                        conn.sendall(_encode({"ok": False, "error": f"request longer than {MAX_LINE} bytes"}))
                        return
                    chunk = conn.recv(8192)
                    if not chunk:
                        return
                    buf += chunk
                    continue
                line, buf = buf[:nl], buf[nl + 1:]
                if line.strip():
                    conn.sendall(_encode(self._answer(line)))
        except (OSError, TimeoutError):
            return
        finally:
            with self._lock:
                self._conns.discard(conn)
            conn.close()

    def _answer(self, line: bytes) -> dict:
        try:
            req = _decode_request(line)
        except ControlError as exc:
            return {"ok": False, "error": str(exc)}
        try:
            reply = self.handler(req)
        except Exception as exc:  # noqa: BLE001 - one failed op must not take the socket down
            if getattr(exc, "user_facing", False):
                return {"ok": False, "error": str(exc)}
            log.exception("control op %r failed", req.get("op"))
            return {"ok": False, "error": f"internal error in {req['op']}: {type(exc).__name__}: {exc}"}
        if not isinstance(reply, dict):
            return {"ok": False, "error": f"op {req['op']} returned {type(reply).__name__}, not an object"}
        return {"ok": True, **reply} if "ok" not in reply else reply


def send_control(path: Path, request: dict, timeout_s: float = 10.0) -> dict:
    """Send one request and wait for its reply. NoDaemonError when nobody listens; ControlError otherwise."""
    path = Path(path)
    if not isinstance(request, dict) or not isinstance(request.get("op"), str):
        raise ControlError('a control request is an object with a string "op"')
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
    sock.settimeout(timeout_s)
    try:
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                try:
                    sock.connect(str(path))
                    break
                except BlockingIOError:
                    # EAGAIN: the listen backlog is full (many operators or a busy daemon); wait our turn.
                    if time.monotonic() >= deadline:
                        raise
                    time.sleep(0.01)
        except (FileNotFoundError, ConnectionRefusedError) as exc:
            raise NoDaemonError(f"no kiosk daemon is listening on {path}") from exc
        except PermissionError as exc:
            raise ControlError(f"no permission to use the control socket {path} "
                               "(run as root or as a member of the operator group vtkiosk-ops)") from exc
        except OSError as exc:
            raise ControlError(f"cannot reach the control socket {path}: {exc}") from exc
        try:
            try:
                sock.sendall(_encode(request))
            except (BrokenPipeError, ConnectionResetError):
                # The daemon answered and closed before reading (a refusal by peer credentials): its answer is
                # already in our receive buffer, so read it rather than report the pipe.
                pass
            buf = b""
            while b"\n" not in buf:
                chunk = sock.recv(65536)
                if not chunk:
                    raise ControlError(f"the daemon closed the control connection without answering {request['op']}")
                buf += chunk
                if len(buf) > 16 * MAX_LINE:
                    raise ControlError("the daemon's reply is too long")
        except TimeoutError as exc:
            raise ControlError(f"the daemon did not answer {request['op']} within {timeout_s:g} s") from exc
        except OSError as exc:
            raise ControlError(f"control connection failed: {exc}") from exc
    finally:
        sock.close()
    try:
        reply = json.loads(buf[: buf.index(b"\n")].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ControlError(f"the daemon's reply is not JSON ({exc})") from exc
    if not isinstance(reply, dict):
        raise ControlError("the daemon's reply is not a JSON object")
    return reply
