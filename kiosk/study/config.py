"""Typed study configuration, loaded from YAML with errors that name the key.

A study compares haptic renderings: each *condition* (ours, pix2pix, an ablation, ...) is one bundle per garment.
Every trial pits the reference condition against one other condition on one garment. Example::

    id: haptic-ab-2026
    question: "Which side do you feel better matches the real object material?"
    seed: 2023
    reference: ours
    conditions:                        # condition -> bundle per garment
      ours: bundles/ours/{garment}.vtb       # a template ({garment} is replaced) ...
      pix2pix:                               # ... or an explicit mapping garment -> bundle
        denim-shorts: bundles/p2p/denim-shorts.vtb
        wool-coat: bundles/p2p/wool-coat.vtb
    garments: [denim-shorts, wool-coat, ...]
    warmup_garment: denim-shorts       # not analysed, untimed
    test_garments: 5                   # per participant, drawn from the garments other than the warm-up
    time_limit_s: 60
    participants: {pattern: "P[0-9]{2}"}   # or {codes: [P01, P02]}
    log: study-log.jsonl
    trusted_keys: keys/                # or allow_unsigned: true (development only)
    kiosk: kiosk.yaml                  # the daemon's config (a path or an inline mapping)

Relative paths are resolved against the config file's folder.
"""
from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from kiosk.contract import yamlload
from kiosk.contract.errors import KioskError

# A participant code is a code, never a name: short, no spaces, nothing that reads like personal data.
CODE_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}\Z")
_ID_RE = re.compile(r"[a-z0-9][a-z0-9._-]{0,63}\Z")
DEFAULT_QUESTION = "Which side do you feel better matches the real object material?"

_KEYS = {"id", "question", "seed", "reference", "conditions", "comparisons", "garments", "warmup_garment",
         "warmup_trials", "test_garments", "time_limit_s", "participants", "log", "trusted_keys", "allow_unsigned",
         "kiosk"}
_REQUIRED = {"id", "seed", "reference", "conditions", "garments", "warmup_garment", "participants", "log"}


class StudyConfigError(KioskError):
    """A study config that cannot be used; the message names the key and what it must be."""


class ParticipantError(KioskError):
    """A participant code the study does not accept."""


@dataclass(frozen=True)
class Participants:
    """Who may take part: an explicit allow-list of codes, or a regular expression a code must match fully."""

    codes: tuple[str, ...] = ()
    pattern: str | None = None

    def check(self, code: str) -> str:
        """Return `code` if accepted; raise ParticipantError otherwise (the message never echoes odd input raw)."""
        if not isinstance(code, str) or not CODE_RE.match(code):
            raise ParticipantError("participant code must be 1-32 letters, digits, '-' or '_' (a code, not a name)")
        if self.codes and code not in self.codes:
            raise ParticipantError(f"participant code {code} is not on this study's list")
        if self.pattern is not None and not re.fullmatch(self.pattern, code):
            raise ParticipantError(f"participant code {code} does not match the study's pattern {self.pattern}")
        return code


@dataclass(frozen=True)
class StudyConfig:
    id: str
    seed: int
    reference: str
    conditions: dict[str, dict[str, Path]]   # condition -> garment -> bundle path
    garments: tuple[str, ...]
    warmup_garment: str
    participants: Participants
    log: Path
    comparisons: tuple[str, ...] = ()        # conditions compared against the reference (default: all others)
    question: str = DEFAULT_QUESTION
    test_garments: int = 5
    warmup_trials: int = 1
    time_limit_s: float = 60.0
    trusted_keys: Path | None = None
    allow_unsigned: bool = False
    kiosk: Path | dict | None = None         # the daemon config: a YAML path or an inline mapping
    source_sha256: str = ""                  # of the config file's bytes, written into the log
    base_dir: Path = Path(".")               # the config file's folder (relative paths start there)

    @property
    def test_pool(self) -> tuple[str, ...]:
        """Garments a participant can be tested on (everything but the warm-up garment)."""
        return tuple(g for g in self.garments if g != self.warmup_garment)

    def bundle_path(self, condition: str, garment: str) -> Path:
        try:
            return self.conditions[condition][garment]
        except KeyError:
            raise StudyConfigError(f"no bundle for condition {condition!r} and garment {garment!r}") from None


def _fail(msg: str) -> None:
    raise StudyConfigError(f"study config: {msg}")


def _type(value: Any, kind: type | tuple, key: str, what: str) -> Any:
    if isinstance(value, bool) and bool not in (kind if isinstance(kind, tuple) else (kind,)):
        _fail(f"{key} must be {what}, got a boolean")
    if not isinstance(value, kind):
        _fail(f"{key} must be {what}, got {type(value).__name__} {value!r}")
    return value


def _name(value: Any, key: str) -> str:
    _type(value, str, key, "a lower-case id like 'denim-shorts'")
    if not _ID_RE.match(value):
        _fail(f"{key} {value!r} must be a lower-case id: a-z, 0-9, '.', '_', '-' (at most 64)")
    return value


def _path(value: Any, key: str, base: Path) -> Path:
    _type(value, str, key, "a path")
    p = Path(value).expanduser()
    return p if p.is_absolute() else base / p


def _conditions(doc: Any, garments: tuple[str, ...], base: Path) -> dict[str, dict[str, Path]]:
    _type(doc, dict, "conditions", "a mapping condition -> bundles")
    if len(doc) < 2:
        _fail("conditions must name at least two conditions (the reference and one to compare)")
    out: dict[str, dict[str, Path]] = {}
    for cond, spec in doc.items():
        _name(cond, "conditions key")
        where = f"conditions.{cond}"
        if isinstance(spec, str):
            if "{garment}" not in spec:
                _fail(f"{where} is a path template and must contain '{{garment}}' (or give a mapping)")
            out[cond] = {g: _path(spec.replace("{garment}", g), where, base) for g in garments}
        elif isinstance(spec, dict):
            unknown = sorted(set(map(str, spec)) - set(garments))
            if unknown:
                _fail(f"{where} names garment(s) not in garments: {', '.join(unknown)}")
            missing = [g for g in garments if g not in spec]
            if missing:
                _fail(f"{where} has no bundle for garment(s): {', '.join(missing)}")
            out[cond] = {g: _path(spec[g], f"{where}.{g}", base) for g in garments}
        else:
            _fail(f"{where} must be a path template with {{garment}} or a mapping garment -> bundle path")
    return out


def _participants(doc: Any) -> Participants:
    _type(doc, dict, "participants", "a mapping with 'codes' (a list) and/or 'pattern' (a regular expression)")
    unknown = sorted(set(map(str, doc)) - {"codes", "pattern"})
    if unknown:
        _fail(f"unknown key(s) in participants: {', '.join(unknown)} (valid: codes, pattern)")
    codes = doc.get("codes", [])
    _type(codes, list, "participants.codes", "a list of codes")
    for c in codes:
        if not isinstance(c, str) or not CODE_RE.match(c):
            _fail(f"participants.codes entry {c!r} is not a code (1-32 letters, digits, '-' or '_')")
    if len(set(codes)) != len(codes):
        _fail("participants.codes lists a code twice")
    pattern = doc.get("pattern")
    if pattern is not None:
        _type(pattern, str, "participants.pattern", "a regular expression")
        try:
            re.compile(pattern)
        except re.error as exc:
            _fail(f"participants.pattern is not a valid regular expression ({exc})")
    if not codes and pattern is None:
        _fail("participants needs 'codes' (an allow-list) or 'pattern' (a regular expression)")
    return Participants(codes=tuple(codes), pattern=pattern)


def study_from_mapping(doc: Any, base: Path, *, source_sha256: str = "") -> StudyConfig:
    """Validate a parsed study document; raise StudyConfigError naming the first problem."""
    _type(doc, dict, "the top level", "a mapping")
    unknown = sorted(set(map(str, doc)) - _KEYS)
    if unknown:
        _fail(f"unknown key(s): {', '.join(unknown)} (valid: {', '.join(sorted(_KEYS))})")
    missing = sorted(_REQUIRED - set(doc))
    if missing:
        _fail(f"missing key(s): {', '.join(missing)}")
    study_id = _name(doc["id"], "id")
    seed = _type(doc["seed"], int, "seed", "an integer")
    garments_doc = _type(doc["garments"], list, "garments", "a list of garment ids")
    garments = tuple(_name(g, "garments entry") for g in garments_doc)
    if len(set(garments)) != len(garments):
        _fail("garments lists a garment twice")
    warmup = _name(doc["warmup_garment"], "warmup_garment")
    if warmup not in garments:
        _fail(f"warmup_garment {warmup!r} is not in garments")
    conditions = _conditions(doc["conditions"], garments, base)
    reference = _name(doc["reference"], "reference")
    if reference not in conditions:
        _fail(f"reference {reference!r} is not one of the conditions ({', '.join(conditions)})")
    comps_doc = doc.get("comparisons", [c for c in conditions if c != reference])
    _type(comps_doc, list, "comparisons", "a list of condition names")
    comparisons = tuple(_name(c, "comparisons entry") for c in comps_doc)
    for c in comparisons:
        if c not in conditions:
            _fail(f"comparisons names {c!r}, which is not a condition")
        if c == reference:
            _fail(f"comparisons must not include the reference {reference!r} (it is in every trial)")
    if not comparisons or len(set(comparisons)) != len(comparisons):
        _fail("comparisons must list at least one condition, each once")
    n_test = _type(doc.get("test_garments", 5), int, "test_garments", "an integer")
    pool = len(garments) - 1
    if not 1 <= n_test <= pool:
        _fail(f"test_garments must be between 1 and {pool} (the garments other than the warm-up), got {n_test}")
    warmup_trials = _type(doc.get("warmup_trials", 1), int, "warmup_trials", "an integer")
    if not 0 <= warmup_trials <= 20:
        _fail(f"warmup_trials must be between 0 and 20, got {warmup_trials}")
    limit = _type(doc.get("time_limit_s", 60.0), (int, float), "time_limit_s", "a number of seconds")
    if not 1.0 <= float(limit) <= 3600.0:
        _fail(f"time_limit_s must be between 1 and 3600 seconds, got {limit}")
    question = _type(doc.get("question", DEFAULT_QUESTION), str, "question", "text")
    if not question.strip() or len(question) > 300:
        _fail("question must be non-empty text of at most 300 characters")
    allow_unsigned = _type(doc.get("allow_unsigned", False), bool, "allow_unsigned", "true or false")
    trusted = _path(doc["trusted_keys"], "trusted_keys", base) if doc.get("trusted_keys") is not None else None
    if trusted is None and not allow_unsigned:
        _fail("give trusted_keys (a folder of *.pub keys) to check the bundles' signatures, "
              "or allow_unsigned: true for development")
    kiosk = doc.get("kiosk")
    if kiosk is not None and not isinstance(kiosk, dict):
        kiosk = _path(kiosk, "kiosk", base)
    return StudyConfig(
        id=study_id, seed=seed, reference=reference, conditions=conditions, garments=garments, warmup_garment=warmup,
        participants=_participants(doc["participants"]), log=_path(doc["log"], "log", base), comparisons=comparisons,
        question=question.strip(), test_garments=n_test, warmup_trials=warmup_trials, time_limit_s=float(limit),
        trusted_keys=trusted, allow_unsigned=allow_unsigned, kiosk=kiosk, source_sha256=source_sha256, base_dir=base)


def load_study_config(path: str | Path) -> StudyConfig:
    """Read and validate a study YAML file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise StudyConfigError(f"cannot read study config {path}: {exc.strerror or exc}") from None
    try:
        doc = yamlload.safe_load(raw)
    except yaml.YAMLError as exc:
        raise StudyConfigError(f"{path}: not valid YAML ({yamlload.one_line(str(exc))})") from None
    return study_from_mapping(doc, path.resolve().parent, source_sha256=hashlib.sha256(raw).hexdigest())
