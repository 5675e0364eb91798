"""Several kiosks, one study: the logs of several kiosks (or of remote web sessions) read as one.

Refused: logs of different studies, and logs whose sessions ran under different study configs (their SHA-256
differs), because pooling answers to different questions, bundles or schedules would be silently wrong. A trial
is counted once per (participant, session, trial): the first copy in the order the logs were given wins, later
copies are counted as duplicates (and as conflicts when their answer differs). Every counted response and session
says which kiosk it came from (the session record's `kiosk`, else the log file's name).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from kiosk.study.log import LogRead, LogState, SessionState, StudyLogError, load_state


class StudyMergeError(StudyLogError):
    """Logs that cannot be pooled; the message names them and why."""


@dataclass
class Merged:
    state: LogState
    reads: list[tuple[Path, LogRead]]
    duplicates: int = 0
    conflicts: list[dict] = field(default_factory=list)
    kiosks: dict[str, int] = field(default_factory=dict)   # kiosk -> counted responses


def _kiosk_of(session: SessionState, path: Path) -> str:
    return str(session.started.get("kiosk") or path.stem)


def merge_logs(paths: Sequence[str | Path]) -> Merged:
    """Read and pool study logs; raise StudyMergeError when they do not belong together."""
    if not paths:
        raise StudyMergeError("give at least one study log")
    loaded = [(Path(p), *load_state(p)) for p in paths]
    ids = {state.study_id for _, state, _ in loaded}
    if len(ids) > 1:
        raise StudyMergeError("the logs belong to different studies: " + ", ".join(
            f"{p.name}: {s.study_id}" for p, s, _ in loaded))
    if len(loaded) > 1:
        hashes = {p: sorted({s.started.get("config_sha256", "") for s in st.sessions.values()})
                  for p, st, _ in loaded}
        every = {h for hs in hashes.values() for h in hs}
        if len(every) > 1:
            raise StudyMergeError("the logs were written under different study configs (config SHA-256 "
                                  + "; ".join(f"{p.name}: {', '.join(h[:12] for h in hs) or 'none'}"
                                              for p, hs in hashes.items())
                                  + "); report each config's logs separately")
    first_path, first, _ = loaded[0]
    out = LogState(study_id=first.study_id, header=first.header)
    merged = Merged(out, [(p, r) for p, _, r in loaded])
    for path, state, _ in loaded:
        for key, s in state.sessions.items():
            kiosk = _kiosk_of(s, path)
            mine = out.sessions.get(key)
            if mine is None:
                mine = out.sessions[key] = SessionState(s.participant, s.session, {**s.started, "kiosk": kiosk},
                                                        ended=s.ended, consent=s.consent,
                                                        demographics=s.demographics,
                                                        familiarisation=list(s.familiarisation))
            else:
                mine.consent = mine.consent or s.consent
                mine.demographics = mine.demographics or s.demographics
            for trial, r in sorted(s.responses.items()):
                prior = mine.responses.get(trial)
                if prior is None:
                    mine.responses[trial] = {**r, "kiosk": kiosk, "log": path.name}
                    merged.kiosks[kiosk] = merged.kiosks.get(kiosk, 0) + 1
                    continue
                merged.duplicates += 1
                if (prior["choice"], prior["timeout"]) != (r["choice"], r["timeout"]):
                    merged.conflicts.append({"participant": key[0], "session": key[1], "trial": trial,
                                             "kept": {"kiosk": prior["kiosk"], "choice": prior["choice"]},
                                             "dropped": {"kiosk": kiosk, "choice": r["choice"]}})
            mine.duplicates.extend(s.duplicates)
        for who, rec in state.withdrawn.items():
            out.withdrawn.setdefault(who, rec)
        out.events.extend(state.events)
    return merged
