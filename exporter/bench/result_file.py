"""Every bench writes its result one way: indented JSON with a final newline, its folder made, a line saying where."""
from __future__ import annotations

import json
from pathlib import Path


def write_result(path: Path | None, result: dict) -> None:
    """Nothing when `path` is None (no --json given)."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {path}")
