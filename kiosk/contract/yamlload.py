"""YAML documents from outside the kiosk (configs, study files), read with bounded nesting.

PyYAML composes nested collections recursively, so a few kilobytes of `[[[[...` raise RecursionError (or worse,
exhaust the stack) instead of a YAMLError, and an integer of thousands of digits raises ValueError. Both surface
here as `yaml.YAMLError` subclasses with one-line messages, so every loader's existing `except yaml.YAMLError`
turns them into its own clear error.
"""
from __future__ import annotations

from typing import Any

import yaml

MAX_DEPTH = 32   # configs nest 3 or 4 levels deep


class YAMLLimitError(yaml.YAMLError):
    """A document that is well-formed YAML but no sane config: nested too deeply, or a value too large."""


class BoundedLoader(yaml.SafeLoader):
    """SafeLoader that refuses documents nested deeper than `max_depth` collections."""

    max_depth = MAX_DEPTH

    def compose_node(self, parent, index):  # type: ignore[override]
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > self.max_depth:
                line = self.peek_event().start_mark.line + 1
                raise YAMLLimitError(f"nested deeper than {self.max_depth} levels (line {line})")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def safe_load(text: str | bytes) -> Any:
    """`yaml.safe_load` with bounded nesting; every failure is a `yaml.YAMLError` with a one-line message."""
    try:
        return yaml.load(text, Loader=BoundedLoader)  # noqa: S506 - BoundedLoader is a SafeLoader
    except RecursionError:
        raise YAMLLimitError("nested too deeply") from None
    except ValueError as exc:   # int() of more than 4300 digits, and the like
        raise YAMLLimitError(f"holds a value that cannot be read ({one_line(str(exc), 100)})") from None


def one_line(text: str, limit: int = 200) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
