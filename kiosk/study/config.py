"""Typed study configuration: frozen dataclasses read from YAML by the project's one loader (`kiosk.config.loader`);
every error is one line naming the file and the key.

A study compares renderings: each *condition* (ours, pix2pix, an ablation, ...) is one bundle per garment. Every
trial pits the reference condition against one other condition on one garment. Two kinds share everything below:
`haptic` (the same ground-truth visual on both sides, two friction maps) and `visual` (two visual outputs side by
side, the haptic layer off; paper: "Which image do you think is more realistic?"). Example::

    id: haptic-ab-2026
    kind: haptic                       # or visual
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
    release: each_trial                # the operator releases every trial (or new_garment, none)
    consent: {version: "2026-01", text: "..."}       # or file: consent.txt; agreement is logged with its SHA-256
    demographics: {age_band: ["18-24", "25-34"], dominant_hand: [left, right]}   # optional, never names
    familiarisation:                   # haptic only: generated textures before the warm-up (never analysed)
      screen_mm: [217, 136]            # the haptic screen's physical size, so periods are millimetres
      textures: [{kind: uniform, level: 0.5}, {kind: grating, period_mm: 2}, {kind: bump, diameter_mm: 20}]

Relative paths are resolved against the config file's folder. The loader checks keys and types; each dataclass's
`__post_init__` checks what depends on other fields and fills the defaults that do (the question and release by
kind, the comparisons from the conditions, the instructions' time limit).
"""
from __future__ import annotations

import hashlib
import math
import re
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NoReturn

from kiosk.config import loader
from kiosk.contract.errors import KioskError

# A participant code is a code, never a name: short, no spaces, nothing that reads like personal data.
CODE_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}\Z")
_ID_RE = re.compile(r"[a-z0-9][a-z0-9._-]{0,63}\Z")
DEFAULT_QUESTION = "Which side do you feel better matches the real object material?"
VISUAL_QUESTION = "Which image do you think is more realistic?"
KINDS = ("haptic", "visual")
RELEASES = ("each_trial", "new_garment", "none")
DEFAULT_INSTRUCTIONS = {
    "haptic": ("Slide the index finger of your dominant hand over both sides of the screen and over the real "
               "garment on the table, as often as you like. Then tap the side that feels more like the real "
               "material. The first pair is practice; after that you have {limit} per pair."),
    "visual": ("You will see two images of the same garment side by side. Tap the one you think is more "
               "realistic. The first {practice} pairs are practice; after that you have {limit} per pair."),
}
TEXTURE_KINDS = ("uniform", "grating", "bump", "ridge")
_TEXTURE_SIZE = {"uniform": "level", "grating": "period_mm", "bump": "diameter_mm", "ridge": "width_mm"}


class StudyConfigError(KioskError):
    """A study config that cannot be used; the message names the key and what it must be."""


class ParticipantError(KioskError):
    """A participant code the study does not accept."""


def _fail(msg: str) -> NoReturn:
    raise StudyConfigError(msg)


def _set(obj: object, name: str, value: Any) -> None:
    """Fill a frozen field from `__post_init__` (a default that depends on other fields, a normalised value)."""
    object.__setattr__(obj, name, value)


def _name(value: Any, key: str) -> str:
    if not isinstance(value, str) or not _ID_RE.match(value):
        _fail(f"{key} {value!r} must be a lower-case id: a-z, 0-9, '.', '_', '-' (at most 64)")
    return value


def _seconds(value: Any) -> float:
    """`parse` for a time limit: a finite number of seconds (null, untimed, is handled by the loader)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"must be a number of seconds (or null: untimed), got {value!r:.40}")
    return float(value)


def _version(value: Any) -> str:
    """`parse` for the consent version: text, or a number YAML read as one (`version: 3`)."""
    if isinstance(value, bool) or not isinstance(value, (str, int, float)) or not str(value).strip():
        raise ValueError('must be the consent text\'s version, e.g. "2026-01"')
    return str(value).strip()


def _conditions(value: Any) -> dict[str, str | dict[str, str]]:
    """`parse` for `conditions`: condition -> a path template with {garment}, or a mapping garment -> path (paths
    are resolved by StudyConfig once the garments are known)."""
    if not isinstance(value, dict):
        raise ValueError(f"must be a mapping condition -> bundles, got {type(value).__name__}")
    out: dict[str, str | dict[str, str]] = {}
    for cond, spec in value.items():
        where = f"conditions.{_name(cond, 'conditions key')}"
        if isinstance(spec, str) and spec:
            out[cond] = spec
        elif isinstance(spec, dict):
            for g, p in spec.items():
                _name(g, f"{where} garment")
                if not isinstance(p, str) or not p or "\0" in p:
                    _fail(f"{where}.{g} must be a bundle path, got {type(p).__name__} {p!r:.40}")
            out[cond] = dict(spec)
        else:
            _fail(f"{where} must be a path template with {{garment}} or a mapping garment -> bundle path")
    return out


def _resolve(text: str, base: Path) -> Path:
    p = Path(text).expanduser()
    return p if p.is_absolute() else base / p


@dataclass(frozen=True)
class Participants:
    """Who may take part: an explicit allow-list of codes, or a regular expression a code must match fully."""

    codes: tuple[str, ...] = ()
    pattern: str | None = None

    def __post_init__(self) -> None:
        for c in self.codes:
            if not CODE_RE.match(c):
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


@dataclass(frozen=True)
class Consent:
    """The consent text participants agree to before trial 1; the log keeps its version and SHA-256. The text is
    inline (`text`) or in a file (`file`, read once here)."""

    version: str | None = field(default=None, metadata={"parse": _version})
    text: str | None = None
    file: Path | None = None

    def __post_init__(self) -> None:
        if self.version is None:
            _fail('consent.version must be the consent text\'s version, e.g. "2026-01"')
        if (self.text is None) == (self.file is None):
            _fail("consent needs exactly one of 'text' (inline) or 'file' (a text file)")
        text = self.text
        if self.file is not None:
            try:
                text = self.file.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                _fail(f"cannot read consent.file {self.file}: {getattr(exc, 'strerror', None) or exc}")
        assert text is not None
        if not text.strip() or len(text) > 20000:
            _fail("consent text must be non-empty and at most 20000 characters")
        _set(self, "version", _version(self.version))
        _set(self, "text", text.strip())
        _set(self, "file", None)  # read: the text is what the log's hash covers

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class Texture:
    """One familiarisation texture: a uniform friction level, a grating (period in mm), a bump or a ridge."""

    kind: Literal["uniform", "grating", "bump", "ridge"]
    level: float | None = None  # friction at the texture's peak, 0..1 of the device's range (0.8 unless uniform)
    period_mm: float | None = None
    diameter_mm: float | None = None
    width_mm: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in TEXTURE_KINDS:
            raise ValueError(f"kind must be one of {', '.join(TEXTURE_KINDS)}, got {self.kind!r}")
        need = _TEXTURE_SIZE[self.kind]
        extra = [n for n in ("period_mm", "diameter_mm", "width_mm") if n != need and getattr(self, n) is not None]
        if extra:
            raise ValueError(f"unknown key(s) for a {self.kind} texture: {', '.join(extra)} (valid: kind, level"
                             f"{'' if need == 'level' else ', ' + need})")
        if self.level is None and self.kind == "uniform":
            raise ValueError("level must be a number between 0 and 1 (a uniform texture's friction)")
        level = 0.8 if self.level is None else self.level
        if not 0.0 <= level <= 1.0:
            raise ValueError(f"level must be between 0 and 1, got {level:g}")
        _set(self, "level", float(level))
        if need != "level":
            size = getattr(self, need)
            if size is None or not 0.2 <= size <= 500.0:
                raise ValueError(f"{need} must be a number between 0.2 and 500 (millimetres), got {size}")

    @property
    def label(self) -> str:
        if self.kind == "uniform":
            return f"even friction, {round(100 * self.level)} %"
        if self.kind == "grating":
            return f"grating, {self.period_mm:g} mm period"
        if self.kind == "bump":
            return f"a bump, {self.diameter_mm:g} mm across"
        return f"a ridge, {self.width_mm:g} mm wide"


DEFAULT_TEXTURES = (Texture("uniform", level=0.2), Texture("uniform", level=0.8), Texture("grating", period_mm=8.0),
                    Texture("grating", period_mm=2.0), Texture("bump", diameter_mm=25.0),
                    Texture("ridge", width_mm=4.0))


@dataclass(frozen=True)
class Familiarisation:
    """Generated textures felt before the warm-up (haptic studies; never analysed). `screen_mm` is the haptic
    screen's physical size, so gratings and bumps have their stated size."""

    screen_mm: tuple[float, float] | None = None
    textures: tuple[Texture, ...] = DEFAULT_TEXTURES

    def __post_init__(self) -> None:
        mm = self.screen_mm
        if mm is None or not all(10 <= v <= 2000 for v in mm):
            raise ValueError("screen_mm must be the haptic screen's [width, height] in millimetres (10-2000), "
                             "so gratings and bumps have their stated physical size")
        if not 1 <= len(self.textures) <= 20:
            raise ValueError("textures must list 1 to 20 textures")


@dataclass(frozen=True)
class StudyConfig:
    id: str
    seed: int
    reference: str
    conditions: dict[str, dict[str, Path]] = field(metadata={"parse": _conditions})  # condition -> garment -> bundle
    garments: tuple[str, ...]
    warmup_garment: str
    participants: Participants
    log: Path
    comparisons: tuple[str, ...] | None = None   # conditions compared against the reference (default: all others)
    question: str | None = None                  # default: the paper's question for the kind
    test_garments: int = 5
    warmup_trials: int = 1
    time_limit_s: float | None = field(default=60.0, metadata={"parse": _seconds})  # None: test trials untimed too
    kind: Literal["haptic", "visual"] = "haptic"
    instructions: str | None = None              # {limit} and {practice} are filled in
    release: Literal["each_trial", "new_garment", "none"] | None = None   # default: each_trial (haptic), none
    timeout_notice_s: float = 3.0
    consent: Consent | None = None
    demographics: dict[str, tuple[str | int, ...]] | None = None
    familiarisation: Familiarisation | None = None
    kiosk_name: str | None = None                # default: the host name
    trusted_keys: Path | None = None
    allow_unsigned: bool = False
    kiosk: Path | dict[str, Any] | None = None   # the daemon config: a YAML path or an inline mapping
    source_sha256: str = field(default="", metadata={"internal": True, "empty_ok": True})  # of the file's bytes
    base_dir: Path = field(default=Path("."), metadata={"internal": True})  # relative paths start here

    def __post_init__(self) -> None:
        garments = tuple(_name(g, "garments entry") for g in self.garments)
        if len(set(garments)) != len(garments):
            _fail("garments lists a garment twice")
        if self.warmup_garment not in garments:
            _fail(f"warmup_garment {self.warmup_garment!r} is not in garments")
        _set(self, "conditions", self._resolved_conditions(garments))
        _name(self.reference, "reference")
        if self.reference not in self.conditions:
            _fail(f"reference {self.reference!r} is not one of the conditions ({', '.join(self.conditions)})")
        self._check_comparisons()
        pool = len(garments) - 1
        if not 1 <= self.test_garments <= pool:
            _fail(f"test_garments must be between 1 and {pool} (the garments other than the warm-up), "
                  f"got {self.test_garments}")
        if not 0 <= self.warmup_trials <= 20:
            _fail(f"warmup_trials must be between 0 and 20, got {self.warmup_trials}")
        if self.kind not in KINDS:
            _fail(f"kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.time_limit_s is not None and not 1.0 <= self.time_limit_s <= 3600.0:
            _fail(f"time_limit_s must be between 1 and 3600 seconds, got {self.time_limit_s:g}")
        question = self.question if self.question is not None else \
            DEFAULT_QUESTION if self.kind == "haptic" else VISUAL_QUESTION
        if not question.strip() or len(question) > 300:
            _fail("question must be non-empty text of at most 300 characters")
        _set(self, "question", question.strip())
        if self.trusted_keys is None and not self.allow_unsigned:
            _fail("give trusted_keys (a folder of *.pub keys) to check the bundles' signatures, "
                  "or allow_unsigned: true for development")
        release = self.release if self.release is not None else "each_trial" if self.kind == "haptic" else "none"
        if release not in RELEASES:
            _fail(f"release must be one of {', '.join(RELEASES)}, got {release!r}")
        _set(self, "release", release)
        if not 0.0 <= self.timeout_notice_s <= 30.0:
            _fail(f"timeout_notice_s must be between 0 and 30 seconds, got {self.timeout_notice_s:g}")
        _set(self, "instructions", self._filled_instructions())
        _set(self, "demographics", self._checked_demographics())
        if self.familiarisation is not None and self.kind != "haptic":
            _fail("familiarisation is for haptic studies (it renders textures on the haptic screen)")
        kiosk_name = self.kiosk_name if self.kiosk_name is not None else socket.gethostname()
        if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", kiosk_name):
            _fail(f"kiosk_name {kiosk_name!r} must be 1-64 letters, digits, '.', '_' or '-'")
        _set(self, "kiosk_name", kiosk_name)

    def _resolved_conditions(self, garments: tuple[str, ...]) -> dict[str, dict[str, Path]]:
        if len(self.conditions) < 2:
            _fail("conditions must name at least two conditions (the reference and one to compare)")
        out: dict[str, dict[str, Path]] = {}
        for cond, spec in self.conditions.items():
            _name(cond, "conditions key")
            where = f"conditions.{cond}"
            if isinstance(spec, str):
                if "{garment}" not in spec:
                    _fail(f"{where} is a path template and must contain '{{garment}}' (or give a mapping)")
                out[cond] = {g: _resolve(spec.replace("{garment}", g), self.base_dir) for g in garments}
                continue
            unknown = sorted(set(map(str, spec)) - set(garments))
            if unknown:
                _fail(f"{where} names garment(s) not in garments: {', '.join(unknown)}")
            missing = [g for g in garments if g not in spec]
            if missing:
                _fail(f"{where} has no bundle for garment(s): {', '.join(missing)}")
            out[cond] = {g: spec[g] if isinstance(spec[g], Path) else _resolve(spec[g], self.base_dir)
                         for g in garments}
        return out

    def _check_comparisons(self) -> None:
        comparisons = self.comparisons if self.comparisons is not None else \
            tuple(c for c in self.conditions if c != self.reference)
        for c in comparisons:
            _name(c, "comparisons entry")
            if c not in self.conditions:
                _fail(f"comparisons names {c!r}, which is not a condition")
            if c == self.reference:
                _fail(f"comparisons must not include the reference {self.reference!r} (it is in every trial)")
        if not comparisons or len(set(comparisons)) != len(comparisons):
            _fail("comparisons must list at least one condition, each once")
        _set(self, "comparisons", comparisons)

    def _filled_instructions(self) -> str:
        text = DEFAULT_INSTRUCTIONS[self.kind] if self.instructions is None else self.instructions
        if not text.strip() or len(text) > 2000:
            _fail("instructions must be non-empty text of at most 2000 characters")
        limit = self.time_limit_s
        return text.strip().replace("{limit}", "no time limit" if limit is None else f"{limit:g} seconds") \
            .replace("{practice}", str(self.warmup_trials))

    def _checked_demographics(self) -> dict[str, tuple[str, ...]] | None:
        if self.demographics is None:
            return None
        out: dict[str, tuple[str, ...]] = {}
        for name, choices in self.demographics.items():
            if not re.fullmatch(r"[a-z][a-z0-9_]{0,31}", name):
                _fail(f"demographics field {name!r} must be a lower-case name like age_band")
            if not 2 <= len(choices) <= 20 or len(set(map(str, choices))) != len(choices):
                _fail(f"demographics.{name} must list 2 to 20 distinct choices")
            for c in choices:
                if not 0 < len(str(c)) <= 40:
                    _fail(f"demographics.{name} choice {c!r} must be short text")
            out[name] = tuple(str(c) for c in choices)
        if not out:
            _fail("demographics must declare at least one field (or leave the key out)")
        return out

    @property
    def test_pool(self) -> tuple[str, ...]:
        """Garments a participant can be tested on (everything but the warm-up garment)."""
        return tuple(g for g in self.garments if g != self.warmup_garment)

    def bundle_path(self, condition: str, garment: str) -> Path:
        try:
            return self.conditions[condition][garment]
        except KeyError:
            raise StudyConfigError(f"no bundle for condition {condition!r} and garment {garment!r}") from None


def study_from_mapping(doc: Any, base: Path, *, source_sha256: str = "") -> StudyConfig:
    """Validate a parsed study document (paths relative to `base`); raise StudyConfigError naming the problem."""
    return loader.build(StudyConfig, doc, error=StudyConfigError, base_dir=base, where="study config",
                        internal={"source_sha256": source_sha256, "base_dir": base})


def load_study_config(path: str | Path) -> StudyConfig:
    """Read and validate a study YAML file; every failure is one line naming the file and the key."""
    path = Path(path)
    raw = loader.read_bytes(path, error=StudyConfigError, what="study config")
    doc = loader.parse_yaml(raw, path, error=StudyConfigError)
    base = path.resolve().parent
    return loader.build(StudyConfig, doc, error=StudyConfigError, base_dir=base, where=str(path),
                        internal={"source_sha256": hashlib.sha256(raw).hexdigest(), "base_dir": base})
