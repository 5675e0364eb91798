"""`vtkiosk serve` stops cleanly on SIGTERM while renders are in flight (the main loop stops, not the handler)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.daemon_fixtures import BOX, http

ROOT = Path(__file__).resolve().parents[3]


def test_sigterm_during_renders_stops_serve_cleanly(tmp_path):
    path, trusted = make_bundle(tmp_path)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("NOTIFY_SOCKET", None)
    proc = subprocess.Popen([sys.executable, "-m", "vtkiosk", "serve", "--bundle", str(path), "--trusted-keys",
                             str(trusted), "--device", "emulated", "--port", "0"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    answered: list[int] = []
    done = threading.Event()

    def client(url: str, n: int) -> None:
        body = {"garment": "denim-shorts", "panel": {"x": 0, "y": 0, "w": 1280, "h": 800}, "screen": [1280, 800],
                "strokes": BOX, "base": False, "mode": "final", "client": f"c{n}"}
        k = 0
        while not done.is_set():
            k += 1
            body["strokes"] = [[[x + k % 7, y] for x, y in BOX[0]]]  # a new sketch each time: no cache hits
            try:
                answered.append(http(url + "api/render", body, timeout=10)[0])
            except OSError:
                return  # the server went away: expected once it stops

    try:
        line = proc.stdout.readline()
        assert "kiosk serving denim-shorts at http://127.0.0.1:" in line, proc.stderr.read()
        url = line.split(" at ")[1].strip()
        threads = [threading.Thread(target=client, args=(url, n), daemon=True) for n in range(2)]
        for t in threads:
            t.start()
        deadline = time.monotonic() + 60
        while len(answered) < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert 200 in answered, answered
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0, proc.stderr.read()[-2000:]
    finally:
        done.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
