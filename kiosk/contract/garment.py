"""One name for a garment: its id, `denim-shorts` (lower-case, hyphenated), used by bundles, the store, the page,
studies and run folders' reports.

People meet the same garment as a material name (`DenimShorts`, from the dataset) and as a dataset folder
(`singleskit_DenimShorts_padded_900_x1`); wherever a user types a garment, all three are accepted and mean the id.
"""
from __future__ import annotations

import re

from kiosk.contract.errors import InputError

_FOLDER = re.compile(r"^singleskit_(?P<material>.+?)_padded_\d+_x\d+$")
_ID = re.compile(r"^[a-z0-9][a-z0-9._-]{0,63}$")


def garment_id(name: str) -> str:
    """`DenimShorts`, `singleskit_DenimShorts_padded_900_x1` or `denim-shorts` -> `denim-shorts`."""
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"a garment name must be a non-empty string; got {name!r}")
    name = name.strip()
    m = _FOLDER.match(name)
    material = m["material"] if m else name
    if _ID.match(material):
        return material
    out = "".join(("-" + c.lower()) if c.isupper() and i and material[i - 1] not in "-_ " else c.lower()
                  for i, c in enumerate(material))
    out = re.sub(r"[\s_]+", "-", out)
    out = re.sub(r"-{2,}", "-", "".join(c for c in out if c.isalnum() or c in "-."))[:64].strip("-")
    if not _ID.match(out):
        raise InputError(f"{name!r} has no letters or digits to make a garment id from")
    return out


def same_garment(a: str, b: str) -> bool:
    """Whether two names people use denote the same garment."""
    try:
        return garment_id(a) == garment_id(b)
    except InputError:
        return False
