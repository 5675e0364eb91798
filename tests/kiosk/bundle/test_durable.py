"""Files replaced whole (the fleet's metadata and state, the store's history): a failed write keeps the old file
and leaves no temporary beside it."""
from __future__ import annotations

import stat

import pytest

from kiosk.bundle.durable import atomic_write


def test_a_write_replaces_the_file_whole_and_readable_by_the_server(tmp_path):
    path = tmp_path / "deep" / "timestamp.json"
    atomic_write(path, b"one")
    atomic_write(path, b"two")
    assert path.read_bytes() == b"two" and sorted(p.name for p in path.parent.iterdir()) == ["timestamp.json"]
    assert stat.S_IMODE(path.stat().st_mode) == 0o644   # a static server's user reads it


def test_a_failed_write_keeps_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "state.json"
    atomic_write(path, b"old")
    with pytest.raises(TypeError):
        atomic_write(path, "not bytes")   # fails inside the write, after the temporary exists
    assert path.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["state.json"]
