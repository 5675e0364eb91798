"""Exceptions of the exporter.

Every expected export or benchmark failure is an `ExportError`. Its `user_facing` flag is what the `vtkiosk`
dispatcher looks for to print one line instead of a traceback, so the exporter shares no base class with the kiosk.
"""
from __future__ import annotations


class ExportError(Exception):
    """An export that must not produce a bundle; the message says why and what to change."""

    user_facing = True
