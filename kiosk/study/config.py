"""Typed study configuration, loaded from YAML with errors that name the key.

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

Relative paths are resolved against the config file's folder.
"""
from __future__ import annotations

import hashlib
import re
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

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
DEFAULT_TEXTURES = ({"kind": "uniform", "level": 0.2}, {"kind": "uniform", "level": 0.8},
                    {"kind": "grating", "period_mm": 8.0}, {"kind": "grating", "period_mm": 2.0},
                    {"kind": "bump", "diameter_mm": 25.0}, {"kind": "ridge", "width_mm": 4.0})

_KEYS = {"id", "question", "seed", "reference", "conditions", "comparisons", "garments", "warmup_garment",
         "warmup_trials", "test_garments", "time_limit_s", "participants", "log", "trusted_keys", "allow_unsigned",
         "kiosk", "kind", "instructions", "release", "timeout_notice_s", "consent", "demographics",
         "familiarisation", "kiosk_name"}
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
class Consent:
    """The consent text participants agree to before trial 1; the log keeps its version and SHA-256."""

    version: str
    text: str

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class Texture:
    """One familiarisation texture: a uniform friction level, a grating (period in mm), a bump or a ridge."""

    kind: str
    level: float = 0.8          # friction at the texture's peak, 0..1 of the device's range
    period_mm: float | None = None
    diameter_mm: float | None = None
    width_mm: float | None = None

    @property
    def label(self) -> str:
        if self.kind == "uniform":
            return f"even friction, {round(100 * self.level)} %"
        if self.kind == "grating":
            return f"grating, {self.period_mm:g} mm period"
        if self.kind == "bump":
            return f"a bump, {self.diameter_mm:g} mm across"
        return f"a ridge, {self.width_mm:g} mm wide"


@dataclass(frozen=True)
class Familiarisation:
    screen_mm: tuple[float, float]
    textures: tuple[Texture, ...]


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
    time_limit_s: float | None = 60.0       # None: test trials are untimed too
    kind: str = "haptic"
    instructions: str = ""
    release: str = "each_trial"
    timeout_notice_s: float = 3.0
    consent: Consent | None = None
    demographics: dict[str, tuple[str, ...]] | None = None
    familiarisation: Familiarisation | None = None
    kiosk_name: str = ""
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


def _instructions(doc: Any, kind: str, limit: float | None, practice: int) -> str:
    if doc is None:
        doc = DEFAULT_INSTRUCTIONS[kind]
    _type(doc, str, "instructions", "text shown to the participant before the first trial")
    if not doc.strip() or len(doc) > 2000:
        _fail("instructions must be non-empty text of at most 2000 characters")
    return doc.strip().replace("{limit}", "no time limit" if limit is None else f"{limit:g} seconds") \
        .replace("{practice}", str(practice))


def _consent(doc: Any, base: Path) -> Consent | None:
    if doc is None:
        return None
    _type(doc, dict, "consent", "a mapping with 'version' and 'text' (or 'file')")
    unknown = sorted(set(map(str, doc)) - {"version", "text", "file"})
    if unknown:
        _fail(f"unknown key(s) in consent: {', '.join(unknown)} (valid: version, text, file)")
    version = doc.get("version")
    if not isinstance(version, (str, int, float)) or isinstance(version, bool) or not str(version).strip():
        _fail("consent.version must be the consent text's version, e.g. \"2026-01\"")
    if ("text" in doc) == ("file" in doc):
        _fail("consent needs exactly one of 'text' (inline) or 'file' (a text file)")
    if "file" in doc:
        path = _path(doc["file"], "consent.file", base)
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            _fail(f"cannot read consent.file {path}: {getattr(exc, 'strerror', None) or exc}")
    else:
        text = _type(doc["text"], str, "consent.text", "text")
    if not text.strip() or len(text) > 20000:
        _fail("consent text must be non-empty and at most 20000 characters")
    return Consent(version=str(version).strip(), text=text.strip())


def _demographics(doc: Any) -> dict[str, tuple[str, ...]] | None:
    if doc is None:
        return None
    _type(doc, dict, "demographics", "a mapping field -> list of choices (e.g. age_band, dominant_hand)")
    out: dict[str, tuple[str, ...]] = {}
    for name, choices in doc.items():
        if not isinstance(name, str) or not re.fullmatch(r"[a-z][a-z0-9_]{0,31}", name):
            _fail(f"demographics field {name!r} must be a lower-case name like age_band")
        _type(choices, list, f"demographics.{name}", "a list of choices")
        if not 2 <= len(choices) <= 20 or len(set(map(str, choices))) != len(choices):
            _fail(f"demographics.{name} must list 2 to 20 distinct choices")
        for c in choices:
            if not isinstance(c, (str, int)) or isinstance(c, bool) or not 0 < len(str(c)) <= 40:
                _fail(f"demographics.{name} choice {c!r} must be short text")
        out[name] = tuple(str(c) for c in choices)
    if not out:
        _fail("demographics must declare at least one field (or leave the key out)")
    return out


def _positive(spec: dict, key: str, where: str, lo: float, hi: float) -> float:
    v = _type(spec.get(key), (int, float), f"{where}.{key}", "a number")
    if not lo <= float(v) <= hi:
        _fail(f"{where}.{key} must be between {lo:g} and {hi:g}, got {v}")
    return float(v)


def _familiarisation(doc: Any, kind: str) -> Familiarisation | None:
    if doc is None:
        return None
    if kind != "haptic":
        _fail("familiarisation is for haptic studies (it renders textures on the haptic screen)")
    _type(doc, dict, "familiarisation", "a mapping with screen_mm and textures")
    unknown = sorted(set(map(str, doc)) - {"screen_mm", "textures"})
    if unknown:
        _fail(f"unknown key(s) in familiarisation: {', '.join(unknown)} (valid: screen_mm, textures)")
    mm = doc.get("screen_mm")
    if not (isinstance(mm, list) and len(mm) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                          and 10 <= v <= 2000 for v in mm)):
        _fail("familiarisation.screen_mm must be the haptic screen's [width, height] in millimetres (10-2000), "
              "so gratings and bumps have their stated physical size")
    specs = doc.get("textures", list(DEFAULT_TEXTURES))
    _type(specs, list, "familiarisation.textures", "a list of textures")
    if not 1 <= len(specs) <= 20:
        _fail("familiarisation.textures must list 1 to 20 textures")
    textures = []
    for i, spec in enumerate(specs):
        where = f"familiarisation.textures[{i}]"
        _type(spec, dict, where, "a mapping with 'kind'")
        k = spec.get("kind")
        if k not in TEXTURE_KINDS:
            _fail(f"{where}.kind must be one of {', '.join(TEXTURE_KINDS)}, got {k!r}")
        need = {"uniform": "level", "grating": "period_mm", "bump": "diameter_mm", "ridge": "width_mm"}[k]
        unknown = sorted(set(map(str, spec)) - {"kind", "level", need})
        if unknown:
            _fail(f"unknown key(s) in {where} ({k}): {', '.join(unknown)} (valid: kind, level, {need})")
        level = _positive(spec, "level", where, 0.0, 1.0) if "level" in spec or k == "uniform" else 0.8
        size = {} if k == "uniform" else {need: _positive(spec, need, where, 0.2, 500.0)}
        textures.append(Texture(kind=k, level=level, **size))
    return Familiarisation(screen_mm=(float(mm[0]), float(mm[1])), textures=tuple(textures))


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
    kind = doc.get("kind", "haptic")
    if kind not in KINDS:
        _fail(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    limit = doc.get("time_limit_s", 60.0)
    if limit is not None:
        _type(limit, (int, float), "time_limit_s", "a number of seconds (or null: untimed)")
        if not 1.0 <= float(limit) <= 3600.0:
            _fail(f"time_limit_s must be between 1 and 3600 seconds, got {limit}")
        limit = float(limit)
    question = _type(doc.get("question", DEFAULT_QUESTION if kind == "haptic" else VISUAL_QUESTION), str,
                     "question", "text")
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
    release = doc.get("release", "each_trial" if kind == "haptic" else "none")
    if release not in RELEASES:
        _fail(f"release must be one of {', '.join(RELEASES)}, got {release!r}")
    notice = _type(doc.get("timeout_notice_s", 3.0), (int, float), "timeout_notice_s", "a number of seconds")
    if not 0.0 <= float(notice) <= 30.0:
        _fail(f"timeout_notice_s must be between 0 and 30 seconds, got {notice}")
    instructions = _instructions(doc.get("instructions"), kind, limit, warmup_trials)
    familiarisation = _familiarisation(doc.get("familiarisation"), kind)
    kiosk_name = _type(doc.get("kiosk_name", socket.gethostname()), str, "kiosk_name", "a name")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", kiosk_name):
        _fail(f"kiosk_name {kiosk_name!r} must be 1-64 letters, digits, '.', '_' or '-'")
    return StudyConfig(
        id=study_id, seed=seed, reference=reference, conditions=conditions, garments=garments, warmup_garment=warmup,
        participants=_participants(doc["participants"]), log=_path(doc["log"], "log", base), comparisons=comparisons,
        question=question.strip(), test_garments=n_test, warmup_trials=warmup_trials, time_limit_s=limit,
        kind=kind, instructions=instructions, release=release, timeout_notice_s=float(notice),
        consent=_consent(doc.get("consent"), base), demographics=_demographics(doc.get("demographics")),
        familiarisation=familiarisation, kiosk_name=kiosk_name, trusted_keys=trusted, allow_unsigned=allow_unsigned, kiosk=kiosk, source_sha256=source_sha256, base_dir=base)


def load_study_config(path: str | Path) -> StudyConfig:
    """Read and validate a study YAML file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise StudyConfigError(f"cannot read study config {path}: {exc.strerror or exc}") from None
    try:
        doc = loader.safe_load(raw)
    except yaml.YAMLError as exc:
        raise StudyConfigError(f"{path}: not valid YAML ({loader.one_line(str(exc))})") from None
    return study_from_mapping(doc, path.resolve().parent, source_sha256=hashlib.sha256(raw).hexdigest())
