"""Exceptions of the kiosk runtime.

Every error an operator or a caller can act on derives from `KioskError`; its `user_facing` flag tells the
command line to print the message as one line instead of a traceback.
"""
from __future__ import annotations


class KioskError(Exception):
    """An expected failure with a message that says what to do."""

    user_facing = True


class InputError(KioskError, ValueError):
    """Malformed input to the runtime contract (arrays, strokes, sizes, parameters)."""
