"""The payloads of the study log's records, built in one place so the service, the tests and the readers agree.

A `response` record holds everything an analysis or an audit of one trial needs, in one line: study id, participant code, session, trial
index, garment (and the half shown), the two conditions and their sides, the choice, the response time, the timeout
flag, both bundles' versions and manifest hashes, the software version, and monotonic + wall timestamps (with the
boot id that makes the monotonic clock comparable).
"""
from __future__ import annotations

from kiosk.study.config import StudyConfig
from kiosk.study.schedule import Schedule, Trial


def session_payload(config: StudyConfig, schedule: Schedule, bundles: dict[str, dict[str, dict]], *,
                    software: str, stamp: dict) -> dict:
    """Session start: the full schedule, the config's hash, the study kind, the kiosk it runs on and every bundle's
    identity."""
    return {"study_id": config.id, "participant": schedule.participant, "session": schedule.session,
            "schedule": schedule.to_json(), "config_sha256": config.source_sha256, "question": config.question,
            "time_limit_s": config.time_limit_s, "bundles": bundles, "software": software, "kind": config.kind,
            "kiosk": config.kiosk_name, "consent_version": config.consent.version if config.consent else None,
            **stamp}


def response_payload(schedule: Schedule, trial: Trial, *, choice: str | None, timeout: bool, rt_s: float | None,
                     time_limit_s: float | None, bundles: dict[str, dict[str, dict]], software: str,
                     shown: dict, stamp: dict) -> dict:
    """A trial's outcome: `choice` is 'left'/'right', or None with timeout=True."""
    if timeout != (choice is None):
        raise ValueError("a response is either a choice or a timeout")
    chosen = trial.condition_on(choice) if choice else None
    ref = schedule.reference
    return {
        "study_id": schedule.study_id, "participant": schedule.participant, "session": schedule.session,
        "trial": trial.index, "block": trial.block, "garment": trial.garment, "half": trial.half,
        "reference": ref, "comparison": trial.comparison, "left": trial.left, "right": trial.right,
        "reference_side": trial.side_of(ref), "choice": choice, "chosen": chosen,
        "chose_reference": None if chosen is None else chosen == ref, "timeout": timeout, "rt_s": rt_s,
        "time_limit_s": time_limit_s,
        "bundles": {side: {"condition": cond, **bundles[cond][trial.garment]}
                    for side, cond in (("left", trial.left), ("right", trial.right))},
        "software": software, "shown_wall": shown.get("wall"), "shown_mono": shown.get("mono"), **stamp,
    }
