"""Drive a running study like its page and its operator: real HTTP on 127.0.0.1 and the real control socket."""
from __future__ import annotations

import json
import urllib.error
import urllib.request
from pathlib import Path

from kiosk.ops.control import send_control


class StudyPage:
    """What study.js does, as plain HTTP calls."""

    def __init__(self, base_url: str, timeout_s: float = 30.0) -> None:
        self.base = base_url.rstrip("/")
        self.timeout_s = timeout_s

    def _call(self, method: str, path: str, body: object | None = None) -> tuple[int, dict]:
        data = None if body is None else (body if isinstance(body, bytes) else json.dumps(body).encode())
        req = urllib.request.Request(self.base + path, data=data, method=method,
                                     headers={"Content-Type": "application/json"} if data is not None else {})
        try:
            with urllib.request.urlopen(req, timeout=self.timeout_s) as resp:
                return resp.status, json.loads(resp.read() or b"{}")
        except urllib.error.HTTPError as exc:
            return exc.code, json.loads(exc.read() or b"{}")

    def state(self) -> dict:
        status, doc = self._call("GET", "/api/study/trial")
        assert status == 200, doc
        return doc

    def shown(self, token: str) -> dict:
        return self._call("POST", "/api/study/shown", {"token": token})[1]

    def choose(self, token: str, side: str) -> dict:
        status, doc = self._call("POST", "/api/study/choice", {"token": token, "side": side})
        assert status == 200, doc
        return doc

    def raw(self, method: str, path: str, body: object | None = None) -> tuple[int, dict]:
        return self._call(method, path, body)

    def get_bytes(self, path: str) -> tuple[int, bytes]:
        try:
            with urllib.request.urlopen(self.base + path, timeout=self.timeout_s) as resp:
                return resp.status, resp.read()
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read()


def operator(socket_path: Path, op: str, **fields) -> dict:
    """One control request (`study.start`, `study.status`, `study.stop`)."""
    return send_control(socket_path, {"op": op, **fields}, timeout_s=30.0)
