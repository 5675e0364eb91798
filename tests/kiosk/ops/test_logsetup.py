"""kiosk.ops.logsetup: structured fields on stderr, and through libsystemd's native journal protocol to a journal
socket (journald's own when it runs here, else one the test binds at the journal's path)."""
from __future__ import annotations

import os
import socket
import struct
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from kiosk.ops.logsetup import configure_logging, stderr_is_journal

ROOT = Path(__file__).resolve().parents[3]
JOURNAL_SOCKET = Path("/run/systemd/journal/socket")

LOG_SNIPPET = """
import logging, sys
from kiosk.ops.logsetup import configure_logging
kind = configure_logging(level="DEBUG", journal={journal})
print(kind, flush=True)
logging.getLogger("kiosk.service.daemon").info("frame committed in %d ms", 41,
    extra={{"BUNDLE_ID": "denim-shorts@{tag}", "STAGE_MS": {{"infer": 30.5, "upload": 4}}, "lower": "dropped"}})
"""


def _run(journal: str, tag: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", LOG_SNIPPET.format(journal=journal, tag=tag)], cwd=ROOT,
                          capture_output=True, text=True, timeout=60, env=env)


def test_stderr_lines_carry_the_structured_fields():
    proc = _run("False", "1")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "stderr"
    line = proc.stderr.strip().splitlines()[-1]
    assert "INFO kiosk.service.daemon: frame committed in 41 ms" in line
    assert "BUNDLE_ID=denim-shorts@1" in line and "STAGE_MS=\"{'infer': 30.5, 'upload': 4}\"" in line
    assert "lower" not in line


def test_auto_picks_stderr_outside_systemd_and_journal_when_stderr_is_the_journal_stream(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    proc = _run("None", "2", env)
    assert proc.stdout.strip() == "stderr"
    with open(tmp_path / "stream", "w") as f:
        st = os.fstat(f.fileno())
        stream = f"{st.st_dev}:{st.st_ino}"
    assert not stderr_is_journal({"JOURNAL_STREAM": stream})  # names another file than our stderr
    assert not stderr_is_journal({"JOURNAL_STREAM": "garbage"})
    st = os.fstat(2)
    assert stderr_is_journal({"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"})


def test_bad_level_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown log level"):
        configure_logging(level="LOUD", journal=False)


def _parse_native(datagram: bytes) -> dict[str, str]:
    """journald's native protocol: KEY=value lines, or KEY\\n<le64 length><bytes>\\n for values with newlines."""
    fields, i = {}, 0
    while i < len(datagram):
        nl = datagram.index(b"\n", i)
        line = datagram[i:nl]
        if b"=" in line:
            k, v = line.split(b"=", 1)
            i = nl + 1
        else:
            k = line
            (n,) = struct.unpack("<Q", datagram[nl + 1: nl + 9])
            v = datagram[nl + 9: nl + 9 + n]
            i = nl + 9 + n + 1
        fields[k.decode()] = v.decode()
    return fields


def test_journal_handler_sends_structured_fields():
    pytest.importorskip("systemd.journal")
    tag = uuid.uuid4().hex
    if JOURNAL_SOCKET.exists():  # journald runs here: read the entry back with journalctl
        proc = _run("True", tag)
        assert proc.returncode == 0 and proc.stdout.strip() == "journal", proc.stderr
        out = subprocess.run(["journalctl", "-o", "json", f"BUNDLE_ID=denim-shorts@{tag}"], capture_output=True,
                             text=True, timeout=30)
        if out.returncode != 0 or not out.stdout.strip():
            pytest.skip(f"journald runs but this user cannot read it back: {out.stderr.strip()}")
        import json
        fields = json.loads(out.stdout.splitlines()[-1])
    else:
        if os.geteuid() != 0:
            pytest.skip("no journald here, and binding its socket path needs root")
        made_dir = not JOURNAL_SOCKET.parent.exists()
        JOURNAL_SOCKET.parent.mkdir(parents=True, exist_ok=True)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            sock.bind(str(JOURNAL_SOCKET))
            sock.settimeout(10)
            proc = _run("True", tag)
            assert proc.returncode == 0 and proc.stdout.strip() == "journal", proc.stderr
            fields = _parse_native(sock.recv(1 << 20))
        finally:
            sock.close()
            JOURNAL_SOCKET.unlink(missing_ok=True)
            if made_dir:
                JOURNAL_SOCKET.parent.rmdir()
    assert fields["MESSAGE"] == "frame committed in 41 ms"
    assert fields["BUNDLE_ID"] == f"denim-shorts@{tag}"
    assert fields["STAGE_MS"] == '{"infer":30.5,"upload":4}'
    assert fields["PRIORITY"] == "6" and fields["SYSLOG_IDENTIFIER"] == "vtkiosk" and fields["LOGGER"] == "kiosk.service.daemon"
    assert not any(k.islower() for k in fields if not k.startswith("_"))  # no LogRecord noise
