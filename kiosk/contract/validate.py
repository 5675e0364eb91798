"""Input checks shared by the runtime contract's functions."""
from __future__ import annotations

from kiosk.contract.errors import InputError

MAX_SIDE = 16384


def check_size(size: object, unit: str = "pixels") -> tuple[int, int]:
    """(width, height) as two ints from 1 to MAX_SIDE, or InputError naming what was given."""
    try:
        w, h = (int(v) for v in size)  # type: ignore[union-attr]
    except (TypeError, ValueError) as exc:
        raise InputError(f"size must be (width, height) in {unit}; got {size!r}") from exc
    if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
        raise InputError(f"size must be between 1x1 and {MAX_SIDE}x{MAX_SIDE} {unit}; got {w}x{h}")
    return w, h
