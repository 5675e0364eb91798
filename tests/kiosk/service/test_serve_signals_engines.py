"""`vtkiosk serve` with OpenVINO's native runtime loaded (engine `openvino`, and `auto`, which times it at
activation) stops cleanly on SIGTERM and SIGINT while renders run in OpenVINO's own worker threads: exit 0, within a
bounded time, no crash. A signal may land on any thread of the process, including the runtime's."""
from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.daemon_fixtures import BOX, http

ROOT = Path(__file__).resolve().parents[3]
STOP_WITHIN_S = 30

pytestmark = pytest.mark.skipif(importlib.util.find_spec("openvino") is None and os.environ.get("CI") != "true",
                                reason="OpenVINO (vtkiosk[openvino]) is not installed")


def _health(url: str) -> dict:
    return json.loads(http(url + "healthz", timeout=10)[1])


# each engine setting once, each stop signal once: every daemon start costs seconds
@pytest.mark.parametrize("engine,signum", [("openvino", signal.SIGTERM), ("auto", signal.SIGINT)],
                         ids=["openvino-SIGTERM", "auto-SIGINT"])
def test_stop_signal_with_openvino_loaded_exits_cleanly(tmp_path, engine, signum):
    path, trusted = make_bundle(tmp_path)
    cfg = tmp_path / "kiosk.yaml"
    cfg.write_text(yaml.safe_dump({"inference": {"engine": {"type": engine, "auto_runs": 1}}}))
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("NOTIFY_SOCKET", None)
    proc = subprocess.Popen([sys.executable, "-m", "vtkiosk", "serve", "--config", str(cfg), "--bundle", str(path),
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

    try:
        line = proc.stdout.readline()
        assert "kiosk serving denim-shorts at http://127.0.0.1:" in line, proc.stderr.read()
        url = line.split(" at ")[1].strip()
        health = _health(url)
        assert "openvino" in str(health.get("engines")), health  # the runtime is loaded, or auto timed it
        threads = [threading.Thread(target=client, args=(url, n), daemon=True) for n in range(2)]
        for t in threads:
            t.start()
        deadline = time.monotonic() + 60
        while len(answered) < 6 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert 200 in answered, answered
        t0 = time.monotonic()
        proc.send_signal(signum)
        rc = proc.wait(timeout=STOP_WITHIN_S)
        err = proc.stderr.read()
        assert rc == 0, f"exit {rc} after {time.monotonic() - t0:.1f} s: {err[-2000:]}"
        assert "Traceback" not in err and "Segmentation" not in err, err[-2000:]
    finally:
        done.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
