"""kiosk.ops.logsetup.say_line: the serving line reaches a shared, unbuffered pipe whole."""
from __future__ import annotations

import io

from kiosk.ops.logsetup import say_line


class RecordingStream(io.StringIO):
    """Keeps each write() apart: what an unbuffered pipe would receive as separate os.write calls."""

    def __init__(self) -> None:
        super().__init__()
        self.writes: list[str] = []

    def write(self, s: str) -> int:
        self.writes.append(s)
        return super().write(s)


def test_say_line_is_one_write_with_its_newline(monkeypatch):
    # CI ran with PYTHONUNBUFFERED: print() sent text and newline apart and a log line from the watchdog thread
    # landed between them, so the test reading the URL got "http://127.0.0.1:N/2026-11-21 ... INFO kiosk.ops.notify..."
    stream = RecordingStream()
    monkeypatch.setattr("sys.stdout", stream)
    say_line("kiosk serving denim-shorts at http://127.0.0.1:8000/")
    say_line("second")
    assert stream.writes == ["kiosk serving denim-shorts at http://127.0.0.1:8000/\n", "second\n"]
