"""Exceptions of the trainer.

Every expected training failure (a bad preset, an unknown method, a dataset that does not follow the layout, a run
without a checkpoint) is a `TrainerError`. Its `user_facing` flag is what the `vtkiosk` dispatcher looks for to print
one line instead of a traceback, so the trainer needs no common base class with the kiosk.
"""
from __future__ import annotations


class TrainerError(Exception):
    """An expected training failure with a message that says what to change."""

    user_facing = True
