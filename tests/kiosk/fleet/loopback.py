"""A real HTTP server on 127.0.0.1 serving a repository folder from a thread, with hooks that let a test play the
compromised mirror: answer one path with other bytes, endless bytes, or half the bytes and then vanish."""
from __future__ import annotations

import socket
import threading
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

ENDLESS_CAP = 64 << 20  # the endless stream stops here even if a broken client keeps reading


class _Handler(SimpleHTTPRequestHandler):
    server: "_Server"

    def log_message(self, *args) -> None:  # the test output stays readable
        pass

    def do_GET(self) -> None:
        self.server.requests.append(self.path)
        for match, hook in list(self.server.hooks):
            if match(self.path):
                hook(self)
                return
        super().do_GET()


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, addr, handler):
        super().__init__(addr, handler)
        self.hooks: list = []
        self.requests: list[str] = []


class RepoServer:
    """`with RepoServer(folder) as srv:` serves `folder` at `srv.url` until the block ends (or `stop()`)."""

    def __init__(self, root: Path, port: int = 0):
        self.root = Path(root)
        self._server = _Server(("127.0.0.1", port), partial(_Handler, directory=str(self.root)))
        self.port = self._server.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}/"
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="repo-server", daemon=True)
        self._thread.start()
        self.sent = 0  # bytes the attack hooks pushed

    @property
    def requests(self) -> list[str]:
        return self._server.requests

    def hook(self, suffix: str, action) -> None:
        """Answer every GET whose path ends with `suffix` with `action(handler)`."""
        self._server.hooks.append((lambda p: p.endswith(suffix), action))

    def stop(self) -> None:
        if self._thread.is_alive():
            self._server.shutdown()
            self._thread.join(timeout=5)
        self._server.server_close()

    def __enter__(self) -> "RepoServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- hostile answers ---------------------------------------------------------------------------------------
    def endless(self, handler) -> None:
        """200 with no length, then bytes until the client hangs up (or the cap)."""
        handler.send_response(200)
        handler.send_header("Content-Type", "application/octet-stream")
        handler.send_header("Connection", "close")
        handler.end_headers()
        chunk = b"\0" * 65536
        try:
            while self.sent < ENDLESS_CAP:
                handler.wfile.write(chunk)
                self.sent += len(chunk)
        except (BrokenPipeError, ConnectionResetError):
            pass
        handler.close_connection = True

    def vanish_midway(self, handler) -> None:
        """Promise the whole file, send half, then the whole server goes away."""
        data = (self.root / handler.path.lstrip("/")).read_bytes()
        handler.send_response(200)
        handler.send_header("Content-Length", str(len(data)))
        handler.end_headers()
        handler.wfile.write(data[: len(data) // 2])
        handler.wfile.flush()
        self.sent += len(data) // 2
        handler.connection.shutdown(socket.SHUT_RDWR)
        handler.close_connection = True
        threading.Thread(target=self.stop, daemon=True).start()
