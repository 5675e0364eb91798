"""Shared builders for the study tests: a config document and logs written through the real log writer."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import yaml

from kiosk.study.config import StudyConfig, study_from_mapping
from kiosk.study.log import StudyLog
from kiosk.study.records import response_payload, session_payload
from kiosk.study.schedule import Schedule, make_schedule


def study_doc(**overrides) -> dict:
    doc = {
        "id": "haptic-ab-test", "seed": 7, "reference": "ours",
        "conditions": {"ours": "bundles/ours/{garment}.vtb", "pix2pix": "bundles/pix2pix/{garment}.vtb",
                       "pix2pixhd": "bundles/pix2pixhd/{garment}.vtb"},
        "garments": ["g00", "g01", "g02", "g03", "g04", "g05", "g06"], "warmup_garment": "g00",
        "test_garments": 5, "time_limit_s": 60, "participants": {"pattern": "P[0-9]{2}"},
        "log": "study.jsonl", "allow_unsigned": True,
    }
    doc.update(overrides)
    return doc


def study_config(tmp: Path, **overrides) -> StudyConfig:
    return study_from_mapping(study_doc(**overrides), tmp, source_sha256="0" * 64)


def write_config(tmp: Path, **overrides) -> Path:
    p = tmp / "study.yaml"
    p.write_text(yaml.safe_dump(study_doc(**overrides), sort_keys=False))
    return p


def fake_bundle_ids(config: StudyConfig) -> dict[str, dict[str, dict]]:
    """Bundle identities as the service records them (version, manifest hash) for logs written without bundles."""
    return {c: {g: {"model_version": f"{c}-1", "manifest_sha256": f"{i:02d}{j:02d}".ljust(64, "0"),
                    "method": c, "garment_id": g, "key_id": None}
                for j, g in enumerate(config.garments)} for i, c in enumerate(config.conditions)}


def run_session(log: StudyLog, config: StudyConfig, participant: str,
                choose: Callable[[Schedule, int], str | None], *, session: int = 1, stop_after: int | None = None,
                rt: float = 1.5) -> Schedule:
    """Start (or continue) a session and answer trials with `choose(schedule, trial_index)` -> side or None."""
    schedule = make_schedule(config, participant, session)
    bundles = fake_bundle_ids(config)
    key = (participant, session)
    if key not in log.state.sessions:
        log.append("session", **session_payload(config, schedule, bundles, software=log.software,
                                                stamp=log.stamp()))
    done = 0
    while (i := log.state.sessions[key].next_trial()) is not None:
        if stop_after is not None and done >= stop_after:
            break
        trial = schedule.trials[i]
        shown = log.stamp()
        side = choose(schedule, i)
        log.record_response(**response_payload(
            schedule, trial, choice=side, timeout=side is None, rt_s=None if side is None else rt,
            time_limit_s=config.time_limit_s if trial.timed else None, bundles=bundles, software=log.software,
            shown=shown, stamp=log.stamp()))
        done += 1
    return schedule
