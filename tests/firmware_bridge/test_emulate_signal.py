"""`vtkiosk device emulate` stops cleanly on SIGTERM while a host is uploading frames to it."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from firmware_bridge.config import BridgeConfig
from firmware_bridge.display import HapticDisplay
from firmware_bridge.errors import BridgeError

ROOT = Path(__file__).resolve().parents[2]


def test_sigterm_during_uploads_stops_the_emulator_cleanly(tmp_path):
    sock = tmp_path / "emu.sock"
    proc = subprocess.Popen([sys.executable, "-m", "vtkiosk", "device", "emulate", "--socket", str(sock),
                             "--report-size", "1024"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    committed = []
    done = threading.Event()

    def host() -> None:
        cfg = BridgeConfig(type="emulated", socket=str(sock), report_size=1024, background=False)
        try:
            with HapticDisplay(cfg) as d:
                shape = (d.info.panel_h, d.info.panel_w)
                while not done.is_set():
                    d.present(np.full(shape, len(committed) % 256, np.uint8))
                    committed.append(1)
        except (BridgeError, OSError):
            pass  # the emulator went away mid-upload: expected once it stops

    try:
        assert "listening on" in proc.stdout.readline()
        t = threading.Thread(target=host, daemon=True)
        t.start()
        deadline = time.monotonic() + 60
        while not committed and time.monotonic() < deadline and t.is_alive():
            time.sleep(0.02)
        assert committed, "the host never committed a frame"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0, proc.stderr.read()
        assert "emulated bridge stopped" in proc.stdout.read()
        assert not sock.exists()
    finally:
        done.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
