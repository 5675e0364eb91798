"""Ordering of bundle model versions (`model.version` in the manifest), so "older" means one thing everywhere.

The store refuses to install or activate a version older than a garment's newest installed one, and fleet sync
needs the same notion of "newer"; both ask this module.

A version string is 1 to 64 characters: letters, digits and '.', '_', '+', '-', starting with a letter or digit
(it also names the version's folder in the store). Ordering:

1. one leading 'v' or 'V' before a digit is ignored ("v2" is "2");
2. the rest is read as a sequence of tokens: runs of digits (numbers) and runs of letters (words); the
   separators '.', '_', '+', '-' only end a token;
3. tokens are compared left to right: numbers by value ("10" > "9", "007" == "7"), words by their lowercase
   spelling, and a number ranks above a word in the same place ("2.1" > "2.beta");
4. when one sequence is a prefix of the other, the longer is newer ("1.2.1" > "1.2");
5. strings with the same tokens (e.g. "v2" and "2", "1.0" and "1-0") are equal in rank; `Version` objects still
   sort deterministically among themselves by the raw string, but `compare` says 0.

There is no pre-release notion: "1.0-rc1" ranks above "1.0". The exporter's default, "YYYYMMDD-step", and dotted
dates such as "2026.11.21-1" both order by time; a garment should keep to one scheme, because across schemes the
first number decides (20261121 > 2026).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

from kiosk.contract.errors import KioskError

VERSION_RE = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9._+-]{0,63}\Z")
_TOKEN_RE = re.compile(r"[0-9]+|[A-Za-z]+")


class VersionError(KioskError):
    """A version string outside the grammar above."""


@dataclass(frozen=True, order=True)
class Version:
    """A parsed model version; compares by the documented ordering (ties broken by the raw string)."""

    key: tuple[tuple[int, int, str], ...] = field(repr=False)
    raw: str


def parse_version(text: object) -> Version:
    """Parse a manifest version string; raise VersionError (one line) when it is not one."""
    if not isinstance(text, str) or not VERSION_RE.match(text):
        shown = repr(text) if not isinstance(text, str) or len(text) <= 70 else repr(text[:67] + "...")
        raise VersionError(f"version {shown} is not a bundle version (1 to 64 letters, digits, '.', '_', '+', '-', "
                           "starting with a letter or digit)")
    body = text[1:] if text[0] in "vV" and text[1:2].isdigit() else text
    # A number ranks above a word in the same place: (1, value, "") > (0, 0, word).
    key = tuple((1, int(t), "") if t.isdigit() else (0, 0, t.lower()) for t in _TOKEN_RE.findall(body))
    return Version(key, text)


def compare(a: str, b: str) -> int:
    """-1, 0 or 1 as version `a` is older than, level with, or newer than version `b`."""
    ka, kb = parse_version(a).key, parse_version(b).key
    return (ka > kb) - (ka < kb)


def is_older(a: str, b: str) -> bool:
    """True when version `a` ranks strictly below version `b`."""
    return compare(a, b) < 0


def newest(versions) -> str | None:
    """The highest-ranked of some version strings (None for none); among equal ranks the greatest raw string."""
    parsed = [parse_version(v) for v in versions]
    return max(parsed).raw if parsed else None
