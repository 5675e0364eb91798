"""`vtkiosk serve` with OpenVINO's native runtime loaded (engine `openvino`, and `auto`, which times it at
activation) stops cleanly on SIGTERM and SIGINT while renders run in OpenVINO's own worker threads: exit 0, within a
bounded time, no crash. A signal may land on any thread of the process, including the runtime's."""
from __future__ import annotations

import importlib.util
import json
import os
import signal
import time

import pytest
import yaml

from tests.kiosk.daemon_fixtures import http

from .serve_under_load import serving

STOP_WITHIN_S = 30

pytestmark = pytest.mark.skipif(importlib.util.find_spec("openvino") is None and os.environ.get("CI") != "true",
                                reason="OpenVINO (vtkiosk[openvino]) is not installed")


def _health(url: str) -> dict:
    return json.loads(http(url + "healthz", timeout=10)[1])


# each engine setting once, each stop signal once: every daemon start costs seconds
@pytest.mark.parametrize("engine,signum", [("openvino", signal.SIGTERM), ("auto", signal.SIGINT)],
                         ids=["openvino-SIGTERM", "auto-SIGINT"])
def test_stop_signal_with_openvino_loaded_exits_cleanly(tmp_path, engine, signum):
    cfg = tmp_path / "kiosk.yaml"
    cfg.write_text(yaml.safe_dump({"inference": {"engine": {"type": engine, "auto_runs": 1}}}))
    with serving(tmp_path, "--config", str(cfg)) as (proc, url, answered, start_clients):
        health = _health(url)
        assert "openvino" in str(health.get("engines")), health  # the runtime is loaded, or auto timed it
        start_clients(url, at_least=6)
        assert 200 in answered, answered
        t0 = time.monotonic()
        proc.send_signal(signum)
        rc = proc.wait(timeout=STOP_WITHIN_S)
        err = proc.stderr.read()
        assert rc == 0, f"exit {rc} after {time.monotonic() - t0:.1f} s: {err[-2000:]}"
        assert "Traceback" not in err and "Segmentation" not in err, err[-2000:]
