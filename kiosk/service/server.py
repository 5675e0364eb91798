"""The kiosk's HTTP server: the page, its API, /healthz and /metrics, on loopback only.

Standard library only (`ThreadingHTTPServer`, HTTP/1.1 keep-alive so a drawing page reuses its connection).
Routes are (method, path prefix) -> handler(Request) -> Response; the longest matching prefix wins, so the study
mounts `server.route("POST", "/api/study/", handler)` beside the daemon's own routes. Static files come from
`kiosk/static/` (`/` is `index.html`, `/NAME` is `NAME.html` when it exists, e.g. `/study`).

A handler's `KioskError` (user_facing) is a 400 with `{"error": message}`; anything else is a 500 with a generic
message and a logged traceback. Bodies are bounded (`max_body_bytes`); non-loopback binds are refused unless
explicitly allowed, because the page has no login.

Loopback alone does not keep other web pages out: any page the kiosk's browser (or a visitor's) opens can send
requests to 127.0.0.1, and a page that rebinds its own DNS name to 127.0.0.1 even reads the answers. So before any
route runs: the Host header must name this server (its listen address, `localhost` on loopback, or one of
`server_names`) with its port (421 otherwise); an Origin, when sent, must be this server's own (403), as must
Sec-Fetch-Site (same-origin, or none for a typed address); and every POST (and any request with a body) must say
`application/json` (415), which a cross-origin form or a "simple" fetch cannot send without a preflight that this
server never grants.

Slow clients cannot hold the server: a request's line, headers and body must all arrive within `header_timeout_s`
of its first wait (else the connection is closed), and at most `max_connections` connections are served at once;
the next one gets a 503 and is closed at once.
"""
from __future__ import annotations

import io
import json
import logging
import math
import mimetypes
import re
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from kiosk.service.config import ConfigError, is_loopback
from kiosk.contract.errors import InputError, KioskError

log = logging.getLogger(__name__)
STATIC_DIR = Path(__file__).resolve().parents[1] / "static"
MAX_BODY_BYTES = 8 << 20
MAX_INT_DIGITS = 30          # a JSON integer longer than this is no count, size or coordinate the kiosk takes
_HOST_RE = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+)(?::([0-9]{1,5}))?$")


@dataclass
class Request:
    method: str
    path: str
    query: dict[str, list[str]]
    headers: dict[str, str]
    body: bytes
    client: str
    received_at: float = field(default_factory=time.monotonic)

    def json(self) -> object:
        """The body as JSON; InputError (-> 400) when it is not. NaN/Infinity literals are refused."""
        if not self.body:
            raise InputError("the request needs a JSON body")
        try:
            return json.loads(self.body.decode("utf-8"), parse_constant=_refuse_constant, parse_int=_bounded_int,
                              parse_float=_finite_float)
        except UnicodeDecodeError:
            raise InputError("the request body is not UTF-8") from None
        except json.JSONDecodeError as exc:
            raise InputError(f"the request body is not valid JSON ({exc.msg} at line {exc.lineno} column "
                             f"{exc.colno})") from None
        except RecursionError:
            raise InputError("the request body is nested too deeply") from None

    def arg(self, name: str, default: str | None = None) -> str | None:
        values = self.query.get(name)
        return values[-1] if values else default


def _refuse_constant(name: str) -> object:
    raise InputError(f"the request body contains {name}, which is not a number the kiosk accepts")


def _bounded_int(text: str) -> int:
    # int() of thousands of digits is slow (quadratic) and Python refuses it past 4300 digits with a ValueError.
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise InputError(f"the request body holds an integer of {len(text.lstrip('-'))} digits; at most "
                         f"{MAX_INT_DIGITS} are accepted")
    return int(text)


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise InputError(f"the request body holds a number too large for the kiosk ({text[:20]}...)")
    return value


def split_host(value: str) -> tuple[str, int | None] | None:
    """A Host header (or an Origin's host part) as (lowercase name, port or None); None when malformed."""
    m = _HOST_RE.match(value.strip())
    if not m:
        return None
    port = int(m.group(2)) if m.group(2) else None
    if port is not None and not 0 < port <= 65535:
        return None
    return m.group(1).lower(), port


@dataclass
class Response:
    status: int = 200
    body: bytes = b""
    content_type: str = "application/octet-stream"
    headers: dict[str, str] = field(default_factory=dict)

    @classmethod
    def json(cls, obj: object, status: int = 200) -> "Response":
        data = json.dumps(obj, separators=(",", ":"), allow_nan=False, default=_json_default).encode("utf-8")
        return cls(status, data, "application/json")

    @classmethod
    def text(cls, text: str, content_type: str = "text/plain; charset=utf-8", status: int = 200) -> "Response":
        return cls(status, text.encode("utf-8"), content_type)

    @classmethod
    def error(cls, status: int, message: str) -> "Response":
        return cls.json({"error": message}, status)


def _json_default(obj: object) -> object:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


Handler = Callable[[Request], Response]


class _HTTPServer(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 64

    def __init__(self, address, handler, max_connections: int) -> None:
        self._slots = threading.BoundedSemaphore(max_connections)
        super().__init__(address, handler)

    def process_request(self, request, client_address):  # type: ignore[override]
        if not self._slots.acquire(blocking=False):
            # Over the cap: answer at once and close, without a thread (a flood of idle sockets costs nothing).
            try:
                request.settimeout(0.5)
                body = b'{"error":"the kiosk is serving too many connections; try again"}'
                request.sendall(b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\n"
                                b"Content-Length: %d\r\nConnection: close\r\nRetry-After: 1\r\n\r\n%s"
                                % (len(body), body))
            except OSError:
                pass
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._slots.release()
            raise

    def process_request_thread(self, request, client_address):  # type: ignore[override]
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()


class _DeadlineReader(socket.SocketIO):
    """The socket's read side, bounded by the handler's deadline for the whole request (not per recv), so a
    client that trickles one byte at a time cannot keep a connection for ever."""

    def __init__(self, sock: socket.socket, handler: "BaseHTTPRequestHandler", idle_timeout_s: float) -> None:
        super().__init__(sock, "rb")
        self._handler = handler
        self._idle = idle_timeout_s

    def readinto(self, b):  # type: ignore[override]
        deadline = getattr(self._handler, "deadline", None)
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("the request did not arrive in time")
            self._sock.settimeout(min(left, self._idle))
        return super().readinto(b)


class KioskServer:
    def __init__(self, host: str = "127.0.0.1", port: int = 8765, *, allow_non_loopback: bool = False,
                 static_dir: Path = STATIC_DIR, max_body_bytes: int = MAX_BODY_BYTES, timeout_s: float = 10.0,
                 header_timeout_s: float = 10.0, max_connections: int = 64, server_names: tuple[str, ...] = ()):
        if not allow_non_loopback and not is_loopback(host):
            raise ConfigError(f"refusing to serve on {host!r}: the kiosk page has no login, so it listens on "
                              "loopback only (allow_non_loopback to override)")
        if header_timeout_s <= 0 or max_connections < 1:
            raise ConfigError("the server needs header_timeout_s > 0 and max_connections >= 1")
        self.host, self.port = host, port
        self.static_dir = Path(static_dir)
        self.max_body_bytes = max_body_bytes
        self.timeout_s = timeout_s
        self.header_timeout_s = header_timeout_s
        self.max_connections = max_connections
        names = {host.lower().strip("[]"), *(n.lower() for n in server_names)}
        if is_loopback(host):
            names |= {"localhost", "127.0.0.1", "::1"}
        self.host_names = frozenset(names)
        self._routes: list[tuple[str, str, Handler]] = []
        self._lock = threading.Lock()
        self._httpd: _HTTPServer | None = None
        self._thread: threading.Thread | None = None
        self.requests = 0
        self.on_request: Callable[[str, str, int, float], None] | None = None  # (method, route, status, seconds)

    # -- routing -------------------------------------------------------------------------------------------------
    def route(self, method: str, path_prefix: str, handler: Handler) -> None:
        """Serve `method` requests whose path starts with `path_prefix` (longest prefix wins; an exact path such
        as "/healthz" matches only itself and its sub-paths)."""
        if method not in ("GET", "POST", "PUT", "DELETE"):
            raise ValueError(f"unsupported method {method!r}")
        if not path_prefix.startswith("/"):
            raise ValueError(f"route prefix must start with '/'; got {path_prefix!r}")
        with self._lock:
            self._routes = [r for r in self._routes if (r[0], r[1]) != (method, path_prefix)]
            self._routes.append((method, path_prefix, handler))
            self._routes.sort(key=lambda r: -len(r[1]))

    def _match(self, method: str, path: str) -> tuple[Handler | None, str, bool]:
        """(handler, matched prefix, path known for another method)."""
        other = False
        with self._lock:
            routes = list(self._routes)
        for m, prefix, handler in routes:
            if path == prefix or (path.startswith(prefix) and (prefix.endswith("/") or path[len(prefix)] == "/")):
                if m == method:
                    return handler, prefix, False
                other = True
        return None, "", other

    def _static(self, path: str) -> Response | None:
        name = "index.html" if path in ("", "/") else path.lstrip("/")
        if name.startswith("static/"):
            name = name[len("static/"):]
        if "/" in name or name.startswith(".") or not name:
            return None
        candidates = [name] if "." in name else [name + ".html"]
        for cand in candidates:
            p = self.static_dir / cand
            if p.is_file():
                ctype = mimetypes.guess_type(cand)[0] or "application/octet-stream"
                if ctype.startswith("text/") or ctype in ("application/javascript",):
                    ctype += "; charset=utf-8"
                return Response(200, p.read_bytes(), ctype, {"Cache-Control": "no-cache"})
        return None

    def _is_mine(self, host_text: str, default_port: int | None) -> bool:
        parsed = split_host(host_text)
        if parsed is None:
            return False
        name, port = parsed
        return name.strip("[]") in self.host_names and (port if port is not None else default_port) == self.port

    def screen(self, req: Request) -> Response | None:
        """Refuse a request that another web page could have sent (see the module doc); None lets it through."""
        host = req.headers.get("host")
        if host is None or not self._is_mine(host, 80):
            return Response.error(421, f"this kiosk does not serve the host {(host or '(none)')[:80]!r}; use "
                                       f"{self.url}")
        origin = req.headers.get("origin")
        if origin is not None:
            parts = urlsplit(origin)
            if parts.scheme != "http" or parts.path not in ("", "/") or not self._is_mine(parts.netloc, 80):
                return Response.error(403, f"requests from the web page at {origin[:80]!r} are not allowed")
        fetch_site = req.headers.get("sec-fetch-site")
        if fetch_site is not None and fetch_site not in ("same-origin", "none"):
            return Response.error(403, f"requests from another site ({fetch_site[:20]}) are not allowed")
        if req.method == "POST" or req.body:
            ctype = req.headers.get("content-type", "").split(";")[0].strip().lower()
            if ctype != "application/json":
                return Response.error(415, f"a {req.method} must send Content-Type: application/json (got "
                                           f"{ctype[:60] or 'none'!r})")
        return None

    def dispatch(self, req: Request) -> tuple[Response, str]:
        refused = self.screen(req)
        if refused is not None:
            return refused, str(refused.status)
        handler, prefix, other = self._match(req.method, req.path)
        if handler is None:
            if req.method == "GET":
                static = self._static(req.path)
                if static is not None:
                    return static, "static"
            if other:
                return Response.error(405, f"{req.method} is not allowed on {req.path}"), "405"
            return Response.error(404, f"nothing at {req.path}"), "404"
        try:
            resp = handler(req)
        except KioskError as exc:
            if getattr(exc, "user_facing", False):
                return Response.error(400, str(exc)), prefix
            log.exception("handler for %s %s failed", req.method, req.path)
            return Response.error(500, "internal error (see the kiosk log)"), prefix
        except Exception:  # noqa: BLE001 - a request must never take the server down
            log.exception("handler for %s %s failed", req.method, req.path)
            return Response.error(500, "internal error (see the kiosk log)"), prefix
        if not isinstance(resp, Response):
            log.error("handler for %s %s returned %r", req.method, req.path, type(resp))
            return Response.error(500, "internal error (see the kiosk log)"), prefix
        return resp, prefix

    # -- life cycle ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        server = self

        class _Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"
            timeout = server.timeout_s

            def setup(self):
                super().setup()
                # Small answers on a keep-alive connection must not wait for the peer's delayed ACK (Nagle): the
                # delayed-ACK timer (40 ms minimum on Linux) would be added to every frame.
                self.connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.deadline: float | None = None
                self.rfile = io.BufferedReader(_DeadlineReader(self.connection, self, server.timeout_s))

            def handle_one_request(self):
                # The whole request (line, headers, body) must arrive within header_timeout_s; an idle keep-alive
                # connection is closed after the same time.
                self.deadline = time.monotonic() + server.header_timeout_s
                super().handle_one_request()

            def log_message(self, fmt, *args):  # noqa: N802 - the base class's name
                log.debug("%s %s", self.address_string(), fmt % args)

            def _handle(self, method: str) -> None:
                t0 = time.perf_counter()
                parts = urlsplit(self.path)
                length_text = self.headers.get("Content-Length")
                body = b""
                if length_text is not None:
                    try:
                        length = int(length_text)
                    except ValueError:
                        length = -1
                    if length < 0:
                        self._send(Response.error(400, "bad Content-Length"), close=True)
                        return
                    if length > server.max_body_bytes:
                        self._send(Response.error(413, f"request body over {server.max_body_bytes} bytes"),
                                   close=True)
                        return
                    body = self.rfile.read(length)
                    if len(body) < length:   # the client closed, or the deadline cut the body short
                        self.close_connection = True
                        return
                elif self.headers.get("Transfer-Encoding"):
                    self._send(Response.error(411, "send a Content-Length (chunked bodies are not accepted)"),
                               close=True)
                    return
                self.deadline = None
                headers = {k.lower(): v for k, v in self.headers.items()}
                req = Request(method, parts.path, parse_qs(parts.query), headers, body, self.client_address[0])
                resp, route = server.dispatch(req)
                self._send(resp)
                server.requests += 1
                if server.on_request is not None:
                    try:
                        server.on_request(method, route, resp.status, time.perf_counter() - t0)
                    except Exception:  # noqa: BLE001 - metrics must not break serving
                        log.exception("request hook failed")

            def _send(self, resp: Response, close: bool = False) -> None:
                phrase = HTTPStatus(resp.status).phrase if resp.status in HTTPStatus._value2member_map_ else ""
                lines = [f"HTTP/1.1 {resp.status} {phrase}", f"Date: {self.date_time_string()}",
                         f"Content-Type: {resp.content_type}", f"Content-Length: {len(resp.body)}",
                         "X-Content-Type-Options: nosniff"]
                lines += [f"{k}: {v}" for k, v in resp.headers.items()]
                if close:
                    lines.append("Connection: close")
                    self.close_connection = True
                head = ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")
                try:
                    # One write: a small answer is one segment (no Nagle wait for the peer's delayed ACK).
                    self.wfile.write(head + resp.body if self.command != "HEAD" else head)
                except (BrokenPipeError, ConnectionResetError):
                    self.close_connection = True
                self.log_request(resp.status, len(resp.body))

            def do_GET(self):  # noqa: N802
                self._handle("GET")

            def do_POST(self):  # noqa: N802
                self._handle("POST")

            def do_PUT(self):  # noqa: N802
                self._handle("PUT")

            def do_DELETE(self):  # noqa: N802
                self._handle("DELETE")

        try:
            self._httpd = _HTTPServer((self.host, self.port), _Handler, self.max_connections)
        except OSError as exc:
            raise ConfigError(f"cannot listen on {self.host}:{self.port} ({exc.strerror or exc}); is another "
                              "kiosk running? Choose another port (--port, or server.port in the config)") from None
        self.port = self._httpd.server_address[1]
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="vtkiosk-http", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._httpd = None
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"
