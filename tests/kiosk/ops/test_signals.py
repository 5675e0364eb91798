"""The one signal helper: the handler only records the signal, the main loop stops; every long-running command
installs its handlers through it (and firmware_bridge's copy stays byte-identical)."""
from __future__ import annotations

import ast
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from kiosk.ops.signals import Signals, on_signals

ROOT = Path(__file__).resolve().parents[3]
HELPERS = {Path("kiosk/ops/signals.py"), Path("firmware_bridge/signals.py")}


SELF_SIGNAL = """
import signal, threading
from kiosk.ops.signals import on_signals
before, before_hup = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGHUP)
with on_signals(signal.SIGHUP) as signals:
    assert not signals.stop and signals.stop_signal is None
    signal.pthread_kill(threading.main_thread().ident, signal.SIGHUP)
    signals.wait(2.0)
    assert signals.take(signal.SIGHUP) and not signals.take(signal.SIGHUP) and not signals.stop
    signal.pthread_kill(threading.main_thread().ident, signal.SIGTERM)
    signals.wait(2.0)
    assert signals.stop and signals.stop_signal == signal.SIGTERM
assert signal.getsignal(signal.SIGTERM) is before and signal.getsignal(signal.SIGHUP) is before_hup
print("ok")
"""


def test_a_signal_is_recorded_and_the_previous_handler_comes_back():
    # in a fresh interpreter: this process may hold native libraries (OpenVINO, loaded by the engine tests) whose
    # own handling of a signal sent to the whole test process is not what is under test here
    proc = subprocess.run([sys.executable, "-c", SELF_SIGNAL], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr


def test_wait_returns_when_a_signal_arrives_and_otherwise_after_the_timeout():
    s = Signals()
    threading.Timer(0.1, s.handler, (signal.SIGINT, None)).start()
    t0 = time.monotonic()
    s.wait(30.0)
    assert s.stop and time.monotonic() - t0 < 20.0
    t0 = time.monotonic()
    Signals().wait(0.05)
    assert time.monotonic() - t0 >= 0.05


def test_the_handler_touches_no_lock():
    """What the handler runs is one list append: nothing that can wait on a lock the main thread holds."""
    tree = ast.parse((ROOT / "kiosk/ops/signals.py").read_text())
    handler = next(n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and n.name == "handler")
    calls = [n for n in ast.walk(handler) if isinstance(n, ast.Call)]
    assert len(calls) == 1 and ast.unparse(calls[0].func) == "self.received.append"


def test_only_the_helper_installs_signal_handlers():
    offenders = []
    for pkg in ("kiosk", "firmware_bridge", "trainer", "exporter", "vtkiosk"):
        for path in (ROOT / pkg).rglob("*.py"):
            rel = path.relative_to(ROOT)
            if rel in HELPERS:
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Call) and ast.unparse(node.func) in ("signal.signal", "signal"):
                    offenders.append(f"{rel}:{node.lineno}")
    assert not offenders, f"install handlers through kiosk.ops.signals.on_signals, not directly: {offenders}"


def test_firmware_bridge_carries_an_identical_copy():
    ours = (ROOT / "kiosk/ops/signals.py").read_bytes()
    assert ours == (ROOT / "firmware_bridge/signals.py").read_bytes(), \
        "firmware_bridge/signals.py differs from kiosk/ops/signals.py; copy it over"
