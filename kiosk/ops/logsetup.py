"""Logging for the kiosk: to the systemd journal with structured fields when running under systemd, else stderr.

Structured fields travel as `extra` with journal-style names (upper case, digits, underscores), e.g.
    log.info("frame committed", extra={"BUNDLE_ID": "denim-shorts@2026.11.21-1", "STAGE_MS": 41.7})
and become journal fields (`journalctl -u vtkiosk BUNDLE_ID=denim-shorts@2026.11.21-1 -o verbose`); on stderr they
are appended as `KEY=value`.

`journal=None` decides like systemd recommends: the journal when stderr *is* the journal stream (JOURNAL_STREAM
names stderr's device:inode) and systemd-python is installed; stderr otherwise (a terminal, a test, a container).
"""
from __future__ import annotations

import json
import logging
import os
import re
import sys

FIELD_RE = re.compile(r"^[A-Z0-9][A-Z0-9_]*$")
_OURS = "_vtkiosk_handler"
FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def structured_fields(record: logging.LogRecord) -> dict[str, object]:
    """The journal-style fields a caller passed in `extra` (upper-case names)."""
    return {k: v for k, v in record.__dict__.items() if FIELD_RE.match(k)}


class FieldsFormatter(logging.Formatter):
    """The usual line, then the structured fields as KEY=value (values with blanks quoted)."""

    def format(self, record: logging.LogRecord) -> str:
        line = super().format(record)
        fields = structured_fields(record)
        if fields:
            parts = []
            for k, v in fields.items():
                text = " ".join(str(v).split())
                parts.append(f'{k}="{text}"' if (" " in text or not text) else f"{k}={text}")
            line += " " + " ".join(parts)
        return line


def stderr_is_journal(environ=None) -> bool:
    """True when systemd connected our stderr to the journal (JOURNAL_STREAM=<dev>:<ino> of fd 2)."""
    env = os.environ if environ is None else environ
    value = env.get("JOURNAL_STREAM", "")
    try:
        dev, ino = (int(x) for x in value.split(":"))
        st = os.fstat(2)
    except (ValueError, OSError):
        return False
    return (st.st_dev, st.st_ino) == (dev, ino)


def _journal_value(v: object) -> object:
    return json.dumps(v, default=str, separators=(",", ":")) if isinstance(v, (dict, list, tuple)) else v


def _journal_handler() -> logging.Handler | None:
    try:
        from systemd import journal  # type: ignore[import-not-found]
    except ImportError:
        return None

    def send(message: str, /, **fields: object) -> None:
        # JournalHandler passes every LogRecord attribute; keep only valid journal field names (the rest is noise
        # journald would drop) and write containers as JSON.
        journal.send(message, **{k: _journal_value(v) for k, v in fields.items() if FIELD_RE.match(k)})

    return journal.JournalHandler(sender_function=send, SYSLOG_IDENTIFIER="vtkiosk")


def configure_logging(*, level: str | int = "INFO", journal: bool | None = None) -> str:
    """Install one handler on the root logger (replacing one we installed before); returns "journal" or "stderr".

    journal=True asks for the journal; without systemd-python it falls back to stderr and says so.
    """
    if isinstance(level, str):
        numeric = logging.getLevelName(level.upper())
        if not isinstance(numeric, int):
            raise ValueError(f"unknown log level {level!r} (DEBUG, INFO, WARNING, ERROR)")
        level = numeric
    root = logging.getLogger()
    for h in [h for h in root.handlers if getattr(h, _OURS, False)]:
        root.removeHandler(h)
        h.close()
    want_journal = stderr_is_journal() if journal is None else journal
    handler = _journal_handler() if want_journal else None
    kind = "journal"
    if handler is None:
        kind = "stderr"
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(FieldsFormatter(FORMAT))
    else:
        handler.setFormatter(logging.Formatter("%(message)s"))
    setattr(handler, _OURS, True)
    root.addHandler(handler)
    root.setLevel(level)
    if want_journal and kind == "stderr":
        logging.getLogger(__name__).warning("systemd-python is not installed: logging to stderr, not the journal")
    return kind


def say_line(text: str) -> None:
    """One line to stdout in a single write.

    print() writes the text and the newline separately; unbuffered (PYTHONUNBUFFERED, as under CI) a log line from
    another thread on the same pipe can land between them, and whoever reads the serving URL off it gets garbage.
    """
    sys.stdout.write(text + "\n")
    sys.stdout.flush()
