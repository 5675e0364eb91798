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

Relative paths are resolved against the config file's folder. The project's one loader (`kiosk.config.loader`) reads
the file and checks the types; the dataclasses below check what the values mean.
"""
from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from kiosk.config import loader
from kiosk.contract.errors import KioskError

# A participant code is a code, never a name: short, no spaces, nothing that reads like personal data.
CODE_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}\Z")
_ID_RE = re.compile(r"[a-z0-9][a-z0-9._-]{0,63}\Z")
DEFAULT_QUESTION = "Which side do you feel better matches the real object material?"


class StudyConfigError(KioskError):
    """A study config that cannot be used; the message names the key and what it must be."""


class ParticipantError(KioskError):
    """A participant code the study does not accept."""


@dataclass(frozen=True)
class Participants:
    """Who may take part: an explicit allow-list of codes, or a regular expression a code must match fully."""

    codes: tuple[str, ...] = ()
    pattern: str | None = None

    def __post_init__(self) -> None:
        for c in self.codes:
            if not isinstance(c, str) or not CODE_RE.match(c):
                _fail(f"participants.codes entry {c!r} is not a code (1-32 letters, digits, '-' or '_')")
        if len(set(self.codes)) != len(self.codes):
            _fail("participants.codes lists a code twice")
        if self.pattern is not None:
            try:
                re.compile(self.pattern)
            except re.error as exc:
                _fail(f"participants.pattern is not a valid regular expression ({exc})")
        if not self.codes and self.pattern is None:
            _fail("participants needs 'codes' (an allow-list) or 'pattern' (a regular expression)")

    def check(self, code: str) -> str:
        """Return `code` if accepted; raise ParticipantError otherwise (the message never echoes odd input raw)."""
        if not isinstance(code, str) or not CODE_RE.match(code):
            raise ParticipantError("participant code must be 1-32 letters, digits, '-' or '_' (a code, not a name)")
        if self.codes and code not in self.codes:
            raise ParticipantError(f"participant code {code} is not on this study's list")
        if self.pattern is not None and not re.fullmatch(self.pattern, code):
            raise ParticipantError(f"participant code {code} does not match the study's pattern {self.pattern}")
        return code


_INTERNAL = {"internal": True}


@dataclass(frozen=True)
class StudyConfig:
    id: str
    seed: int
    reference: str
    # condition -> garment -> bundle path; the file may give a path template with {garment} instead of a mapping
    conditions: dict[str, Any]
    garments: tuple[str, ...]
    warmup_garment: str
    participants: Participants
    log: Path
    comparisons: tuple[str, ...] | None = None  # compared against the reference (None: every other condition)
    question: str = DEFAULT_QUESTION
    test_garments: int = 5
    warmup_trials: int = 1
    time_limit_s: float = 60.0
    trusted_keys: Path | None = None
    allow_unsigned: bool = False
    kiosk: Path | dict | None = None         # the daemon config: a YAML path or an inline mapping
    source_sha256: str = field(default="", metadata=_INTERNAL)     # of the config file's bytes, written into the log
    base_dir: Path = field(default=Path("."), metadata=_INTERNAL)  # the config file's folder (relative paths start there)

    def __post_init__(self) -> None:
        _name(self.id, "id")
        for g in self.garments:
            _name(g, "garments entry")
        if len(set(self.garments)) != len(self.garments):
            _fail("garments lists a garment twice")
        _name(self.warmup_garment, "warmup_garment")
        if self.warmup_garment not in self.garments:
            _fail(f"warmup_garment {self.warmup_garment!r} is not in garments")
        conditions = _conditions(self.conditions, self.garments, self.base_dir)
        object.__setattr__(self, "conditions", conditions)
        _name(self.reference, "reference")
        if self.reference not in conditions:
            _fail(f"reference {self.reference!r} is not one of the conditions ({', '.join(conditions)})")
        comparisons = tuple(c for c in conditions if c != self.reference) if self.comparisons is None \
            else tuple(self.comparisons)
        for c in comparisons:
            _name(c, "comparisons entry")
            if c not in conditions:
                _fail(f"comparisons names {c!r}, which is not a condition")
            if c == self.reference:
                _fail(f"comparisons must not include the reference {self.reference!r} (it is in every trial)")
        if not comparisons or len(set(comparisons)) != len(comparisons):
            _fail("comparisons must list at least one condition, each once")
        object.__setattr__(self, "comparisons", comparisons)
        pool = len(self.garments) - 1
        if not 1 <= self.test_garments <= pool:
            _fail(f"test_garments must be between 1 and {pool} (the garments other than the warm-up), "
                  f"got {self.test_garments}")
        if not 0 <= self.warmup_trials <= 20:
            _fail(f"warmup_trials must be between 0 and 20, got {self.warmup_trials}")
        if not 1.0 <= float(self.time_limit_s) <= 3600.0:
            _fail(f"time_limit_s must be between 1 and 3600 seconds, got {self.time_limit_s}")
        if not self.question.strip() or len(self.question) > 300:
            _fail("question must be non-empty text of at most 300 characters")
        object.__setattr__(self, "question", self.question.strip())
        if self.trusted_keys is None and not self.allow_unsigned:
            _fail("give trusted_keys (a folder of *.pub keys) to check the bundles' signatures, "
                  "or allow_unsigned: true for development")

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
    raise StudyConfigError(msg)


def _name(value: Any, key: str) -> str:
    if not isinstance(value, str) or not _ID_RE.match(value):
        _fail(f"{key} {value!r} must be a lower-case id: a-z, 0-9, '.', '_', '-' (at most 64)")
    return value


def _path(value: Any, key: str, base: Path) -> Path:
    if not isinstance(value, (str, Path)) or not str(value):
        _fail(f"{key} must be a path, got {type(value).__name__} {value!r}")
    p = Path(value).expanduser()
    return p if p.is_absolute() else base / p


def _conditions(doc: dict, garments: tuple[str, ...], base: Path) -> dict[str, dict[str, Path]]:
    """condition -> garment -> bundle path, from templates (`bundles/ours/{garment}.vtb`) or explicit mappings."""
    if len(doc) < 2:
        _fail("conditions must name at least two conditions (the reference and one to compare)")
    out: dict[str, dict[str, Path]] = {}
    for cond, spec in doc.items():
        _name(cond, "conditions key")
        where = f"conditions.{cond}"
        if isinstance(spec, (str, Path)):
            if "{garment}" not in str(spec):
                _fail(f"{where} is a path template and must contain '{{garment}}' (or give a mapping)")
            out[cond] = {g: _path(str(spec).replace("{garment}", g), where, base) for g in garments}
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


def study_from_mapping(doc: Any, base: Path, *, source_sha256: str = "",
                       where: str = "study config") -> StudyConfig:
    """Validate a parsed study document; raise StudyConfigError naming the first problem."""
    return loader.build(StudyConfig, doc, error=StudyConfigError, base_dir=base, where=where,
                        internal={"source_sha256": source_sha256, "base_dir": base})


def load_study_config(path: str | Path) -> StudyConfig:
    """Read and validate a study YAML file."""
    path = Path(path)
    raw = loader.read_bytes(path, error=StudyConfigError, what="study config")
    doc = loader.parse_yaml(raw, path, error=StudyConfigError)
    return study_from_mapping(doc, path.resolve().parent, source_sha256=hashlib.sha256(raw).hexdigest(),
                              where=str(path))
