"""The kiosk's HTTP server: the page, its API, /healthz and /metrics, on loopback only.

Standard library only (`ThreadingHTTPServer`, HTTP/1.1 keep-alive so a drawing page reuses its connection).
Routes are (method, path prefix) -> handler(Request) -> Response; the longest matching prefix wins, so the study
mounts `server.route("POST", "/api/study/", handler)` beside the daemon's own routes. Static files come from
`kiosk/static/` (`/` is `index.html`, `/NAME` is `NAME.html` when it exists, e.g. `/study`).

A handler's `KioskError` (user_facing) is a 400 with `{"error": message}`; anything else is a 500 with a generic
message and a logged traceback. Bodies are bounded (`max_body_bytes`); non-loopback binds are refused unless
explicitly allowed, because the page has no login.
"""
from __future__ import annotations

import json
import logging
import mimetypes
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
            return json.loads(self.body.decode("utf-8"), parse_constant=_refuse_constant)
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


class KioskServer:
    def __init__(self, host: str = "127.0.0.1", port: int = 8765, *, allow_non_loopback: bool = False,
                 static_dir: Path = STATIC_DIR, max_body_bytes: int = MAX_BODY_BYTES, timeout_s: float = 10.0):
        if not allow_non_loopback and not is_loopback(host):
            raise ConfigError(f"refusing to serve on {host!r}: the kiosk page has no login, so it listens on "
                              "loopback only (allow_non_loopback to override)")
        self.host, self.port = host, port
        self.static_dir = Path(static_dir)
        self.max_body_bytes = max_body_bytes
        self.timeout_s = timeout_s
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

    def dispatch(self, req: Request) -> tuple[Response, str]:
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
                # Small answers on a keep-alive connection must not wait for the peer's delayed ACK (Nagle):
                # that alone costs 40 ms per frame.
                self.connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

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
                elif self.headers.get("Transfer-Encoding"):
                    self._send(Response.error(411, "send a Content-Length (chunked bodies are not accepted)"),
                               close=True)
                    return
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
            self._httpd = _HTTPServer((self.host, self.port), _Handler)
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
