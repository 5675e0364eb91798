"""The study log: durable appends, torn and corrupt records detected and never counted, resume, one writer."""
from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kiosk.study.log import (DuplicateResponse, StudyLog, StudyLogError, encode_record, load_state, parse_log_bytes,
                             read_log)

from ..full_disk import small_disk
from .helpers import run_session, study_config


def _log_with_answers(tmp_path, n_answers=6):
    cfg = study_config(tmp_path)
    log = StudyLog.open(cfg.log, cfg.id)
    run_session(log, cfg, "P01", lambda s, i: "left" if i % 3 else "right", stop_after=n_answers)
    log.close()
    return cfg


def test_round_trip_and_line_format(tmp_path):
    cfg = _log_with_answers(tmp_path)
    lines = cfg.log.read_bytes().splitlines()
    assert len(lines) == 1 + 1 + 6                      # header, session, six responses
    for n, line in enumerate(lines, 1):
        rec = json.loads(line)
        assert rec["seq"] == n and len(rec["sum"]) == 16
    state, read = load_state(cfg.log)
    assert not read.problems and not read.torn_tail
    s = state.sessions[("P01", 1)]
    assert sorted(s.responses) == list(range(6)) and s.next_trial() == 6
    r = s.responses[1]
    for key in ("study_id", "participant", "session", "trial", "garment", "left", "right", "choice", "rt_s",
                "timeout", "bundles", "software", "mono", "wall", "boot_id", "reference_side", "half"):
        assert key in r, key
    assert r["bundles"]["left"]["condition"] == r["left"] and "manifest_sha256" in r["bundles"]["right"]


def test_resume_continues_at_first_unanswered_trial(tmp_path):
    cfg = _log_with_answers(tmp_path, n_answers=4)
    with StudyLog.open(cfg.log, cfg.id) as log:
        assert log.state.sessions[("P01", 1)].next_trial() == 4
        run_session(log, cfg, "P01", lambda s, i: "right")
        assert log.state.sessions[("P01", 1)].next_trial() is None
    state, _ = load_state(cfg.log)
    s = state.sessions[("P01", 1)]
    assert len(s.responses) == s.n_trials and not s.duplicates
    assert [s.responses[i]["choice"] for i in range(4, s.n_trials)] == ["right"] * (s.n_trials - 4)


def test_duplicate_response_is_refused_and_never_counted(tmp_path):
    cfg = _log_with_answers(tmp_path, n_answers=2)
    with StudyLog.open(cfg.log, cfg.id) as log:
        first = log.state.sessions[("P01", 1)].responses[1]
        payload = {k: v for k, v in first.items() if k not in ("seq", "type")}
        size = cfg.log.stat().st_size
        with pytest.raises(DuplicateResponse):
            log.record_response(**payload)
        assert cfg.log.stat().st_size == size           # nothing written
        log.append("response", **dict(payload, choice="right"))   # bypass the guard: a reader still counts one
    state, _ = load_state(cfg.log)
    s = state.sessions[("P01", 1)]
    assert s.responses[1]["seq"] == first["seq"] and len(s.duplicates) == 1
    assert len(state.responses()) == 2


def test_one_writer_at_a_time_and_wrong_logs(tmp_path):
    cfg = _log_with_answers(tmp_path, n_answers=1)
    with StudyLog.open(cfg.log, cfg.id):
        with pytest.raises(StudyLogError, match="in use by another process"):
            StudyLog.open(cfg.log, cfg.id)
    with pytest.raises(StudyLogError, match="belongs to study 'haptic-ab-test'"):
        StudyLog.open(cfg.log, "other-study")
    other = tmp_path / "notes.txt"
    other.write_text("hello\nworld\n")
    with pytest.raises(StudyLogError, match="not a vtkiosk study log"):
        StudyLog.open(other, cfg.id)
    with pytest.raises(StudyLogError, match="not a vtkiosk study log"):
        read_log(other)
    with pytest.raises(StudyLogError, match="no study log"):
        read_log(tmp_path / "missing.jsonl")
    assert other.read_text() == "hello\nworld\n"        # never touched


def test_torn_header_is_set_aside(tmp_path):
    path = tmp_path / "log.jsonl"
    line = encode_record({"seq": 1, "type": "log", "format": "vtkiosk-study-log", "version": 1, "study_id": "s"})
    path.write_bytes(line[:20])
    with StudyLog.open(path, "s") as log:
        assert log.state.study_id == "s"
    assert (tmp_path / "log.jsonl.torn-0").read_bytes() == line[:20]
    assert not read_log(path).problems


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("log")
    cfg = _log_with_answers(tmp, n_answers=8)
    data = cfg.log.read_bytes()
    return cfg, data, parse_log_bytes(data).records


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 10**6))
def test_truncated_tail_keeps_exactly_the_complete_records(written, cut):
    _, data, originals = written
    cut %= len(data) + 1
    read = parse_log_bytes(data[:cut])
    complete = data[:cut].count(b"\n")
    assert read.records == originals[:complete]
    assert read.torn_tail == (cut > 0 and data[cut - 1:cut] != b"\n")
    assert read.valid_end == (data[:cut].rfind(b"\n") + 1)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pos=st.integers(0, 10**6), flip=st.integers(1, 255))
def test_a_corrupt_byte_loses_only_its_own_records(written, pos, flip):
    _, data, originals = written
    pos %= len(data)
    bad = bytearray(data)
    bad[pos] ^= flip
    read = parse_log_bytes(bytes(bad))
    line_of = data[:pos].count(b"\n")                       # record index holding the byte
    touched = {line_of} | ({line_of + 1} if data[pos:pos + 1] == b"\n" else set())
    for rec in read.records:
        assert rec in originals                             # nothing invented, nothing altered
    kept = {originals.index(r) for r in read.records}
    assert set(range(len(originals))) - kept <= touched
    if set(range(len(originals))) - kept:
        assert read.problems                                # a lost record is always reported


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 10**6), garbage=st.binary(max_size=40))
def test_writer_recovers_from_a_torn_tail(tmp_path_factory, written, cut, garbage):
    cfg, data, originals = written
    tmp = tmp_path_factory.mktemp("torn")
    path = tmp / "study.jsonl"
    header_end = data.index(b"\n") + 1
    cut = header_end + cut % (len(data) - header_end + 1)
    torn = data[:cut] + garbage.replace(b"\n", b"")
    path.write_bytes(torn)
    complete = data[:cut].count(b"\n")
    with StudyLog.open(path, cfg.id) as log:
        assert log.read_at_open.records == originals[:complete]
        log.append("event", kind="test", detail="after recovery", **log.stamp())
    read = read_log(path)
    assert not read.problems and not read.torn_tail
    assert read.records[:-1] == originals[:complete] and read.records[-1]["seq"] == complete + 1
    aside = list(tmp.glob("study.jsonl.torn-*"))
    if len(torn) > data[:cut].rfind(b"\n") + 1:
        assert len(aside) == 1 and aside[0].read_bytes() == torn[data[:cut].rfind(b"\n") + 1:]
    else:
        assert not aside


def test_a_full_disk_leaves_the_log_as_it_was_and_writing_resumes_when_space_returns(tmp_path):
    """Fill a real file system under the log, keep appending, free it, append again: every acknowledged record
    reads back, no failed append leaves a byte behind, and the first record after the outage is not glued to one."""
    with small_disk(tmp_path / "disk", size_kib=256) as disk:
        cfg = study_config(disk.folder)
        log = StudyLog.open(cfg.log, cfg.id)
        acked, failures = [], 0
        pad = "x" * 300   # records cross page boundaries, so a write can fail half-way

        def append(n):
            nonlocal failures
            before = cfg.log.read_bytes()
            try:
                acked.append(log.append("event", kind="tap", n=n, pad=pad)["seq"])
            except (OSError, StudyLogError) as exc:
                failures += 1
                assert cfg.log.read_bytes() == before, "a failed append changed the log"
                assert "\n" not in str(exc) and "study log" in str(exc)
                assert log.write_error is not None

        for n in range(5):
            append(n)
        disk.fill(slack=100)
        for n in range(5, 40):
            append(n)
        assert failures >= 20, "the disk never filled"
        disk.free()
        for n in range(40, 45):
            append(n)
        assert log.write_error is None
        log.close()
        read = read_log(cfg.log)
        assert not read.problems and not read.torn_tail
        assert [r["seq"] for r in read.records[1:]] == acked == list(range(2, len(acked) + 2))
        assert [r["n"] for r in read.records[-5:]] == list(range(40, 45))
