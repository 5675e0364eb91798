"""Test helpers for the operations side: a socket that receives sd_notify datagrams the way systemd does, and the
real `vtkiosk serve` running as a child process (optionally with systemd-python hidden, or under a sandbox)."""
from __future__ import annotations

import os
import queue
import re
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
SERVING = re.compile(r"kiosk serving .* at (http://[^\s/]+/)")

# Runs `python -m vtkiosk ...` with the systemd package made unimportable: the pure-Python sd_notify path.
HIDE_SYSTEMD = textwrap.dedent("""
    import importlib.abc, runpy, sys
    class _NoSystemd(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "systemd" or name.startswith("systemd."):
                raise ImportError("systemd-python hidden by the test")
            return None
    sys.meta_path.insert(0, _NoSystemd())
    sys.argv = ["vtkiosk", *sys.argv[1:]]
    runpy.run_module("vtkiosk", run_name="__main__")
""")


class NotifySocket:
    """What systemd does: a unix datagram socket that collects sd_notify messages (path, or '@name')."""

    def __init__(self, address: str):
        self.address = address
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind("\0" + address[1:] if address.startswith("@") else address)
        self.sock.settimeout(0.05)
        self.messages: list[str] = []

    def drain(self, wait_s: float = 0.0) -> list[str]:
        deadline = time.monotonic() + wait_s
        while True:
            try:
                self.messages.append(self.sock.recv(4096).decode())
            except TimeoutError:
                if time.monotonic() >= deadline:
                    return self.messages
            else:
                if wait_s and time.monotonic() >= deadline:
                    return self.messages

    def close(self) -> None:
        self.sock.close()


class TimedNotifySocket(NotifySocket):
    """Also records when each message arrived (monotonic seconds), from a background reader."""

    def __init__(self, address: str):
        super().__init__(address)
        self.timed: list[tuple[float, str]] = []
        self._q: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.sock.recv(4096).decode()
            except TimeoutError:
                continue
            except OSError:
                return
            self.timed.append((time.monotonic(), msg))
            self.messages.append(msg)

    def wait_for(self, pred, timeout: float, after: float = 0.0) -> tuple[float, str] | None:
        """The first message arriving at or after `after` (monotonic) that satisfies pred."""
        end = time.monotonic() + timeout
        while True:
            for t, m in list(self.timed):
                if t >= after and pred(m):
                    return t, m
            if time.monotonic() >= end:
                return None
            time.sleep(0.02)

    def between(self, t0: float, t1: float) -> list[str]:
        return [m for t, m in list(self.timed) if t0 <= t < t1]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        super().close()


class ServeProcess:
    """`vtkiosk serve --config <written config>` as a child process; `url` once it printed that it serves."""

    def __init__(self, config: dict, workdir: Path, *, env: dict | None = None, hide_systemd: bool = False,
                 preexec_fn=None, timeout_s: float = 120.0):
        self.config_path = workdir / "kiosk.yaml"
        self.config_path.write_text(yaml.safe_dump(config))
        self.env = {**os.environ, **(env or {})}
        self.env.pop("JOURNAL_STREAM", None)
        self.hide_systemd = hide_systemd
        self.preexec_fn = preexec_fn
        self.timeout_s = timeout_s
        self.proc: subprocess.Popen | None = None
        self.url: str | None = None
        self.output: list[str] = []

    def start(self) -> ServeProcess:
        args = ["serve", "--config", str(self.config_path)]
        cmd = [sys.executable, "-c", HIDE_SYSTEMD, *args] if self.hide_systemd else \
            [sys.executable, "-m", "vtkiosk", *args]
        self.proc = subprocess.Popen(cmd, cwd=ROOT, env=self.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, preexec_fn=self.preexec_fn)
        got: queue.Queue = queue.Queue()

        def pump() -> None:
            assert self.proc is not None and self.proc.stdout is not None
            for line in self.proc.stdout:
                self.output.append(line)
                found = SERVING.search(line)
                if found:
                    got.put(found.group(1))
            got.put(None)

        threading.Thread(target=pump, daemon=True).start()
        try:
            self.url = got.get(timeout=self.timeout_s)
        except queue.Empty:
            self.url = None
        if self.url is None:
            self.stop()
            raise AssertionError("vtkiosk serve did not start:\n" + "".join(self.output))
        return self

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 30.0) -> int:
        if self.proc is None:
            return 0
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def __enter__(self) -> ServeProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
