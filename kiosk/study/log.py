"""The study log: an fsync'd, append-only JSON-lines file with a checksum on every record.

Why this and not SQLite (WAL, synchronous=FULL), which would be just as durable:
- The log is a study's primary data and is archived with the paper. A text file with one self-checking record per
  line can be read, checked and diffed in twenty years with nothing but a JSON parser and SHA-256.
- Every record carries its own checksum, so bit rot or a torn write anywhere is *detected*; SQLite keeps no
  checksum on table pages (only on WAL frames), so a flipped byte in a stored choice would be read back silently.
- One file: a researcher who copies `study.db` without its `-wal` file while a session runs silently loses the
  latest choices; an append-only file copied at any moment is a valid log up to a possibly torn last line.
- Append-only means a written choice is never rewritten, so a crash can only ever damage the record in flight.
What it costs: the recovery rules below are ours, so they are tested (property-based truncation/corruption tests and
a SIGKILL test over hundreds of trials), and one writer at a time is enforced with an exclusive `flock`.

Durability: a record is one `write()` on an O_APPEND descriptor followed by `fsync()` (and an fsync of the folder when
the file is created); `append` returns only after both, and the service acknowledges a choice to the page only after
`append` returned. So every acknowledged choice survives a crash or power loss.

Format: each line is canonical JSON (sorted keys, no spaces, ASCII, no NaN) of a record with fields `seq` (1, 2, 3,
... with no gaps), `type` and the payload, plus `sum` = the first 16 hex digits of SHA-256 over the canonical JSON of
the record without `sum`. A reader counts a record only when its line is complete (ends with a newline), parses, and
its checksum matches; anything else is reported as a problem and never counted. On opening for writing, bytes after
the last valid record (a torn tail from a crash) are moved aside to `<log>.torn-<offset>` and cut off, so new
records never follow garbage. While the writer runs, an append the file system refuses half-way (a full disk) is cut
back to the last valid record before the error is raised, so the log stays exactly as it was and the next append,
once there is space again, starts on a clean line.
"""
from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from kiosk.bundle.durable import fsync_dir
from kiosk.contract.errors import KioskError

FORMAT = "vtkiosk-study-log"
FORMAT_VERSION = 1
RECORD_TYPES = ("log", "session", "resume", "shown", "response", "event", "end", "consent", "demographics",
                "familiarisation", "release", "withdraw")
MAX_LINE = 1 << 20


class StudyLogError(KioskError):
    """A study log that cannot be opened or written; the message says what to do."""


class StudyLogWriteError(StudyLogError):
    """An append that the file system refused (full disk, I/O error); the log is exactly as before it."""


class DuplicateResponse(KioskError):
    """A trial that already has a durable response; the new one is not written."""


def canonical(obj: Any) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode()


def checksum(record_without_sum: dict) -> str:
    return hashlib.sha256(canonical(record_without_sum)).hexdigest()[:16]


def encode_record(record: dict) -> bytes:
    """One log line (with its newline) for a record that has no `sum` yet."""
    if "sum" in record:
        raise ValueError("record already has a checksum")
    body = dict(record)
    body["sum"] = checksum(record)
    line = canonical(body) + b"\n"
    if len(line) > MAX_LINE:
        raise StudyLogError(f"study log record of {len(line)} bytes is over the {MAX_LINE}-byte limit")
    return line


def decode_line(line: bytes) -> dict:
    """Parse and check one complete line (without its newline); raise ValueError saying why it is not valid."""
    try:
        rec = json.loads(line.decode("ascii"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not a JSON record ({type(exc).__name__})") from None
    if not isinstance(rec, dict):
        raise ValueError("not a JSON object")
    stored = rec.pop("sum", None)
    if not isinstance(stored, str):
        raise ValueError("no checksum")
    try:
        expect = checksum(rec)
    except ValueError:
        raise ValueError("holds a non-finite number") from None
    if stored != expect:
        raise ValueError("checksum mismatch (corrupt or half-written)")
    if not isinstance(rec.get("seq"), int) or isinstance(rec.get("seq"), bool) or rec.get("type") not in RECORD_TYPES:
        raise ValueError("no valid seq/type")
    return rec


@dataclass(frozen=True)
class Problem:
    line: int     # 1-based line number
    offset: int   # byte offset of the line's start
    reason: str


@dataclass
class LogRead:
    records: list[dict]
    problems: list[Problem]
    valid_end: int          # byte offset just after the last valid record
    size: int               # bytes in the file when read

    @property
    def torn_tail(self) -> bool:
        return self.valid_end < self.size


def parse_log_bytes(data: bytes) -> LogRead:
    """Split a log's bytes into valid records and problems (pure: the same bytes give the same answer)."""
    records: list[dict] = []
    problems: list[Problem] = []
    offset, valid_end, line_no = 0, 0, 0
    last_seq = 0
    while offset < len(data):
        line_no += 1
        nl = data.find(b"\n", offset)
        if nl < 0:
            problems.append(Problem(line_no, offset, f"incomplete last line ({len(data) - offset} bytes, no newline)"))
            break
        line = data[offset:nl]
        try:
            rec = decode_line(line)
        except ValueError as exc:
            problems.append(Problem(line_no, offset, str(exc)))
        else:
            if rec["seq"] <= last_seq:
                problems.append(Problem(line_no, offset, f"seq {rec['seq']} repeats or goes back (after {last_seq})"))
            else:
                if rec["seq"] != last_seq + 1:
                    problems.append(Problem(line_no, offset, f"seq jumps from {last_seq} to {rec['seq']} "
                                                             "(records missing)"))
                records.append(rec)
                last_seq = rec["seq"]
                valid_end = nl + 1
        offset = nl + 1
    return LogRead(records=records, problems=problems, valid_end=valid_end, size=len(data))


def read_log(path: str | Path) -> LogRead:
    """Read a log without locking it (a running study may be appending; its in-flight line counts as torn)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise StudyLogError(f"no study log at {path}") from None
    read = parse_log_bytes(data)
    if not read.records or read.records[0].get("type") != "log" or read.records[0].get("format") != FORMAT:
        raise StudyLogError(f"{path} is not a vtkiosk study log (no valid header record)")
    if read.records[0].get("version") != FORMAT_VERSION:
        raise StudyLogError(f"{path} is study log format version {read.records[0].get('version')}; this software "
                            f"reads version {FORMAT_VERSION}")
    return read


# --- the state a log describes --------------------------------------------------------------------------------


@dataclass
class SessionState:
    participant: str
    session: int
    started: dict                                   # the 'session' record (holds the full schedule)
    responses: dict[int, dict] = field(default_factory=dict)   # trial index -> first 'response' record
    duplicates: list[dict] = field(default_factory=list)       # later responses for an answered trial (never counted)
    ended: bool = False                             # an 'end' record (complete or stopped) not followed by 'resume'
    consent: dict | None = None                     # the latest 'consent' record of this session
    demographics: dict | None = None                # the 'demographics' record (declined fields are null)
    familiarisation: list[dict] = field(default_factory=list)   # shown / skipped / complete steps (never analysed)

    @property
    def consented(self) -> bool:
        return bool(self.consent and self.consent.get("agreed") is True)

    @property
    def familiarised(self) -> bool:
        """The familiarisation stage is over: completed, or skipped by the operator."""
        return any(r.get("action") in ("complete", "skipped") for r in self.familiarisation)

    def familiarisation_step(self) -> int:
        """The first texture not yet shown to the end (0 when the stage has not started)."""
        done = [r["step"] for r in self.familiarisation if r.get("action") == "done"]
        return max(done) + 1 if done else 0

    @property
    def n_trials(self) -> int:
        return len(self.started["schedule"]["trials"])

    def next_trial(self) -> int | None:
        """The first unanswered trial (None when all are answered)."""
        for i in range(self.n_trials):
            if i not in self.responses:
                return i
        return None


@dataclass
class LogState:
    study_id: str
    header: dict
    sessions: dict[tuple[str, int], SessionState] = field(default_factory=dict)
    events: list[dict] = field(default_factory=list)
    withdrawn: dict[str, dict] = field(default_factory=dict)    # participant -> their 'withdraw' record

    def fold(self, rec: dict) -> None:
        """Take one valid record into the state (the one rule for replaying a log and for appending to it)."""
        kind, key = rec["type"], (rec.get("participant"), rec.get("session"))
        s = self.sessions.get(key)
        if kind == "session":
            if s is None:
                self.sessions[key] = SessionState(participant=key[0], session=key[1], started=rec)
        elif kind == "response":
            if s is None:
                self.events.append({"kind": "orphan_response", "seq": rec["seq"]})
            elif rec["trial"] in s.responses:
                s.duplicates.append(rec)
            else:
                s.responses[rec["trial"]] = rec
        elif kind in ("end", "resume"):
            if s is not None:
                s.ended = kind == "end"
        elif kind == "consent" and s is not None:
            s.consent = rec
        elif kind == "demographics" and s is not None:
            s.demographics = rec
        elif kind == "familiarisation" and s is not None:
            s.familiarisation.append(rec)
        elif kind == "withdraw":
            self.withdrawn.setdefault(rec["participant"], rec)
        elif kind == "event":
            self.events.append(rec)

    def responses(self) -> list[dict]:
        """Every counted response, in log order."""
        out = [r for s in self.sessions.values() for r in s.responses.values()]
        return sorted(out, key=lambda r: r["seq"])

    def latest_session(self, participant: str) -> SessionState | None:
        mine = [s for (p, _), s in self.sessions.items() if p == participant]
        return max(mine, key=lambda s: s.session) if mine else None


def replay(records: Iterable[dict]) -> LogState:
    """Fold valid records into sessions and responses; a response is counted once, the first time it appears."""
    it = iter(records)
    header = next(it)
    state = LogState(study_id=header["study_id"], header=header)
    for rec in it:
        state.fold(rec)
    return state


def load_state(path: str | Path) -> tuple[LogState, LogRead]:
    read = read_log(path)
    return replay(read.records), read


# --- writing ----------------------------------------------------------------------------------------------------


def wall_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="microseconds")


def boot_id() -> str:
    """Monotonic timestamps only compare within one boot; this names the boot."""
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return "unknown"


def software_version() -> str:
    try:
        from importlib.metadata import version

        return f"vtkiosk {version('vtkiosk')}"
    except Exception:  # noqa: BLE001 - not installed as a distribution (e.g. run from a checkout)
        return "vtkiosk unknown"


class StudyLog:
    """The one writer of a study log: exclusive lock, torn-tail recovery, durable appends, live state."""

    def __init__(self, path: Path, fd: int, read: LogRead, state: LogState) -> None:
        self.path = path
        self._fd = fd
        self.read_at_open = read
        self.state = state
        self._seq = read.records[-1]["seq"]
        self._end = read.valid_end    # bytes of valid records: the file's size between appends
        self.write_error: str | None = None   # why the last append failed; None once one succeeds again
        self.boot_id = boot_id()
        self.software = software_version()

    @classmethod
    def open(cls, path: str | Path, study_id: str) -> "StudyLog":
        """Open (or create) the log of `study_id` for appending. Raises StudyLogError."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        created = not path.exists()
        try:
            fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o640)
        except OSError as exc:
            raise StudyLogError(f"cannot open study log {path}: {exc.strerror}") from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                    raise StudyLogError(f"study log {path} is in use by another process (one study writer at a "
                                        "time)") from None
                raise
            data = _read_all(fd)
            if data and b"\n" not in data:  # a crash while the header was written: nothing else can be in it
                _set_aside_tail(path, fd, data, 0)
                data = b""
            if not data:
                header = {"seq": 1, "type": "log", "format": FORMAT, "version": FORMAT_VERSION, "study_id": study_id,
                          "created": wall_now(), "software": software_version()}
                try:
                    _write_durably(fd, encode_record(header))
                except OSError:
                    _cut_back(fd, 0)
                    raise
                if created:
                    fsync_dir(path.parent)
                data = _read_all(fd)
            read = parse_log_bytes(data)
            if not read.records or read.records[0].get("type") != "log" or read.records[0].get("format") != FORMAT:
                raise StudyLogError(f"{path} is not a vtkiosk study log; refusing to append to it")
            if read.records[0].get("study_id") != study_id:
                raise StudyLogError(f"{path} belongs to study {read.records[0].get('study_id')!r}, not {study_id!r}; "
                                    "give each study its own log")
            if read.torn_tail:
                _set_aside_tail(path, fd, data, read.valid_end)
            return cls(path, fd, read, replay(read.records))
        except OSError as exc:
            os.close(fd)
            raise StudyLogWriteError(f"cannot prepare the study log {path}: {exc.strerror or exc}; nothing in it "
                                     "was changed") from None
        except BaseException:
            os.close(fd)
            raise

    def append(self, type_: str, **payload: Any) -> dict:
        """Write one record durably and fold it into the state; return it (with seq)."""
        if type_ not in RECORD_TYPES or type_ == "log":
            raise ValueError(f"unknown record type {type_!r}")
        rec = {"seq": self._seq + 1, "type": type_, **payload}
        line = encode_record(rec)
        self._append_line(line)
        self._seq += 1
        self._fold(rec)
        return rec

    def _append_line(self, line: bytes) -> None:
        """Write one line durably, or leave the file exactly as it was and raise StudyLogWriteError.

        A write that fails half-way (ENOSPC) leaves its first bytes in the file; the next record would be glued to
        them and read back as garbage although it was fsync'd and acknowledged. So a failed append is cut back to
        the last valid record at once, and every append first checks that nothing follows that record (a cut that
        itself failed is retried there)."""
        try:
            if os.fstat(self._fd).st_size != self._end:
                _cut_back(self._fd, self._end)
            _write_durably(self._fd, line)
        except OSError as exc:
            try:
                _cut_back(self._fd, self._end)
            except OSError:
                pass  # the next append retries the cut before it writes
            self.write_error = (f"cannot write to the study log {self.path}: {exc.strerror or exc}"
                                f"{' (the disk is full)' if exc.errno in (errno.ENOSPC, errno.EDQUOT) else ''}")
            raise StudyLogWriteError(f"{self.write_error}; nothing was recorded, everything before is safe") \
                from None
        self._end += len(line)
        self.write_error = None

    def record_response(self, **payload: Any) -> dict:
        """Append a trial's response unless it already has one (then raise DuplicateResponse, nothing written)."""
        s = self.state.sessions.get((payload["participant"], payload["session"]))
        if s is None:
            raise StudyLogError(f"no session {payload['session']} of {payload['participant']} in the log")
        if payload["trial"] in s.responses:
            raise DuplicateResponse(f"trial {payload['trial']} of {payload['participant']} already has a response")
        return self.append("response", **payload)

    def stamp(self) -> dict:
        """Wall and monotonic time of now, with the boot they belong to."""
        return {"wall": wall_now(), "mono": time.monotonic(), "boot_id": self.boot_id}

    def _fold(self, rec: dict) -> None:
        self.state.fold(rec)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)  # releases the flock
            self._fd = -1

    def __enter__(self) -> "StudyLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _read_all(fd: int) -> bytes:
    os.lseek(fd, 0, os.SEEK_SET)
    chunks = []
    while True:
        b = os.read(fd, 1 << 20)
        if not b:
            return b"".join(chunks)
        chunks.append(b)


def _write_durably(fd: int, line: bytes) -> None:
    view = memoryview(line)
    while view:
        n = os.write(fd, view)
        view = view[n:]
    os.fsync(fd)


def _cut_back(fd: int, size: int) -> None:
    """Drop whatever follows the last valid record (the bytes of a failed append), durably."""
    os.ftruncate(fd, size)
    os.fsync(fd)


def _set_aside_tail(path: Path, fd: int, data: bytes, valid_end: int) -> None:
    """Keep the torn bytes for forensics in a side file, then cut them off the log (both durably)."""
    aside = path.with_name(f"{path.name}.torn-{valid_end}")
    with open(aside, "wb") as f:
        f.write(data[valid_end:])
        f.flush()
        os.fsync(f.fileno())
    os.ftruncate(fd, valid_end)
    os.fsync(fd)
    fsync_dir(path.parent)
