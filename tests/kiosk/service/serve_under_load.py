"""A real `vtkiosk serve` on loopback with two clients rendering new sketches non-stop: the stop-signal tests'
common setup (the tests keep their own assertions)."""
from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Iterator

from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.daemon_fixtures import BOX, http

ROOT = Path(__file__).resolve().parents[3]


@contextlib.contextmanager
def serving(tmp_path: Path, *extra: str) -> Iterator[tuple[subprocess.Popen, str, list[int], callable]]:
    """Yields (process, base URL, HTTP statuses answered so far, start_clients()); kills the process on the way out
    if it is still running."""
    path, trusted = make_bundle(tmp_path)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("NOTIFY_SOCKET", None)
    proc = subprocess.Popen([sys.executable, "-m", "vtkiosk", "serve", *extra, "--bundle", str(path),
                             "--trusted-keys", str(trusted), "--device", "emulated", "--port", "0"], cwd=ROOT,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    answered: list[int] = []
    done = threading.Event()

    def client(url: str, n: int) -> None:
        body = {"garment": "denim-shorts", "panel": {"x": 0, "y": 0, "w": 1280, "h": 800}, "screen": [1280, 800],
                "strokes": BOX, "base": False, "mode": "final", "client": f"c{n}"}
        k = 0
        while not done.is_set():
            k += 1
            body["strokes"] = [[[x + k % 7, y + n] for x, y in BOX[0]]]  # a new sketch each time: no cache hits
            try:
                answered.append(http(url + "api/render", body, timeout=10)[0])
            except OSError:
                return  # the server went away: expected once it stops

    def start_clients(url: str, at_least: int) -> None:
        """Two rendering clients; returns once `at_least` answers came back (or after 60 s)."""
        for n in range(2):
            threading.Thread(target=client, args=(url, n), daemon=True).start()
        deadline = time.monotonic() + 60
        while len(answered) < at_least and time.monotonic() < deadline:
            time.sleep(0.02)

    try:
        line = proc.stdout.readline()
        assert "kiosk serving denim-shorts at http://127.0.0.1:" in line, proc.stderr.read()
        yield proc, line.split(" at ")[1].strip(), answered, start_clients
    finally:
        done.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
