"""A report-size mismatch between host and an emulated bridge fails the handshake with the fix in the message,
instead of opening a link whose tiles are never acknowledged."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from firmware_bridge.config import BridgeConfig
from firmware_bridge.display import HapticDisplay
from firmware_bridge.errors import LinkError, ProtocolError


@pytest.mark.timeout(60)
def test_a_report_size_mismatch_over_the_emulator_socket_is_refused_at_handshake(tmp_path):
    sock = str(tmp_path / "bridge.sock")
    proc = subprocess.Popen([sys.executable, "-m", "firmware_bridge.cli", "emulate", "--socket", sock,
                             "--panel", "256x128", "--tile", "32", "--report-size", "64", "--duration", "40"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for _ in range(600):
            if os.path.exists(sock):
                break
            time.sleep(0.05)
        assert os.path.exists(sock), proc.stderr.read() if proc.poll() is not None else "no socket"
        cfg = BridgeConfig(type="emulated", socket=sock, report_size=1024, background=False)
        with pytest.raises(ProtocolError, match=r"bridge uses 64 B reports but report_size is 1024; "
                                                r"set report_size: 64"):
            HapticDisplay(cfg).open()
        # the other way round the device's replies do not fit the host's reports: no answer, a clear error
        cfg = BridgeConfig(type="emulated", socket=sock, report_size=32, background=False)
        with pytest.raises(LinkError):
            HapticDisplay(cfg).open()
        # the matching size opens and a full frame is acknowledged
        cfg = BridgeConfig(type="emulated", socket=sock, report_size=64, background=False)
        with HapticDisplay(cfg) as disp:
            import numpy as np

            r = disp.present(np.full((128, 256), 7, np.uint8))
            assert r.tiles_sent == 32
    finally:
        proc.terminate()
        proc.communicate(timeout=10)
