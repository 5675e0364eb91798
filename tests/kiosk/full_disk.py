"""A real file system that runs out of space on demand, for full-disk tests.

Preferred: a small tmpfs mounted on a test folder (needs mount rights, e.g. root). `fill()` writes a ballast file
until the kernel answers ENOSPC; `free()` deletes it. Where mounting is not permitted the same scenario runs under
RLIMIT_FSIZE instead: `fill(slack)` caps the size any file of this process may reach at the largest file now in the
folder plus `slack` bytes, so the next write fails half-way with EFBIG (SIGXFSZ is ignored meanwhile), and `free()`
lifts the cap. Either way the writes fail in the kernel, as they would on a full disk; nothing is simulated.
"""
from __future__ import annotations

import contextlib
import errno
import os
import resource
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path


class FullDisk:
    def __init__(self, folder: Path, mode: str) -> None:
        self.folder = folder
        self.mode = mode              # "tmpfs" or "rlimit"
        self._ballast = folder / ".ballast"
        self._saved: tuple[int, int] | None = None
        self._old_handler = None

    def fill(self, slack: int = 0) -> None:
        if self.mode == "tmpfs":
            fd = os.open(self._ballast, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
            try:
                chunk = b"\0" * 4096
                while True:
                    try:
                        os.write(fd, chunk)
                    except OSError as exc:
                        if exc.errno != errno.ENOSPC:
                            raise
                        if len(chunk) == 1:
                            break
                        chunk = chunk[: len(chunk) // 2]
            finally:
                os.close(fd)
            return
        largest = max((p.stat().st_size for p in self.folder.rglob("*") if p.is_file()), default=0)
        if self._saved is None:
            self._saved = resource.getrlimit(resource.RLIMIT_FSIZE)
            self._old_handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (largest + slack, self._saved[1]))

    def free(self) -> None:
        if self.mode == "tmpfs":
            self._ballast.unlink(missing_ok=True)
        elif self._saved is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, self._saved)
            signal.signal(signal.SIGXFSZ, self._old_handler)
            self._saved = None


@contextlib.contextmanager
def small_disk(folder: Path, size_kib: int = 1024) -> Iterator[FullDisk]:
    """A folder on a real file system of `size_kib` that `fill()` fills and `free()` frees (see the module doc)."""
    folder.mkdir(parents=True, exist_ok=True)
    mounted = False
    if os.geteuid() == 0:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kib}k,mode=0755", "tmpfs", str(folder)],
                           capture_output=True, text=True, check=False)
        mounted = r.returncode == 0
    disk = FullDisk(folder, "tmpfs" if mounted else "rlimit")
    try:
        yield disk
    finally:
        disk.free()
        if mounted:
            subprocess.run(["umount", "-l", str(folder)], capture_output=True, check=False)
