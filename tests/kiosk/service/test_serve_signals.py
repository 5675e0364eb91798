"""`vtkiosk serve` stops cleanly on SIGTERM while renders are in flight (the main loop stops, not the handler)."""
from __future__ import annotations

import signal

from .serve_under_load import serving


def test_sigterm_during_renders_stops_serve_cleanly(tmp_path):
    with serving(tmp_path) as (proc, url, answered, start_clients):
        start_clients(url, at_least=3)
        assert 200 in answered, answered
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0, proc.stderr.read()[-2000:]
