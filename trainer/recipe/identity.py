"""What makes two runs the same recipe: a saved run config less how the run was executed.

Used by `--resume` (which refuses a changed recipe) and by the demo catalogue's recipe hash, which the serving
process computes: so this module imports nothing heavier than `json` (no torch).
"""
from __future__ import annotations

import json

# Run-config keys that say how a run is executed, not what it learns: a resume may change them, and the catalogue's
# recipe hash leaves them out. Everything else (train.steps too: it sets the learning-rate decay) is the recipe.
EXECUTION_KEYS = frozenset({("garment",), ("train", "threads"), ("train", "progress"), ("train", "log_every"),
                            ("train", "sample_every"), ("train", "ckpt_every"), ("train", "deterministic"),
                            ("train", "device"), ("train", "tf32")})


def recipe_view(cfg: dict) -> dict:
    """A saved config less its execution keys: what two runs must share to be the same recipe."""
    out = json.loads(json.dumps(cfg))
    for path in EXECUTION_KEYS:
        cur = out
        for k in path[:-1]:
            cur = cur.get(k, {})
        cur.pop(path[-1], None)
    return out


def recipe_differences(recorded: dict, current: dict) -> tuple[list[str], list[str]]:
    """(`key: recorded -> current` for every recipe key whose value differs, keys the recorded config lacks).

    A key absent from `recorded` was added to the trainer after that run started, so its value then is unknown and
    is reported apart rather than as a change."""
    changed: list[str] = []
    unknown: list[str] = []

    def walk(a: dict, b: dict, prefix: str) -> None:
        for k in sorted(set(a) | set(b)):
            name = f"{prefix}{k}"
            if k not in a:
                unknown.append(name)
            elif k not in b:
                changed.append(f"{name}: {a[k]!r} -> (no such key)")
            elif isinstance(a[k], dict) and isinstance(b[k], dict):
                walk(a[k], b[k], name + ".")
            elif a[k] != b[k]:
                changed.append(f"{name}: {a[k]!r} -> {b[k]!r}")

    walk(recipe_view(recorded), recipe_view(current), "")
    return changed, unknown
