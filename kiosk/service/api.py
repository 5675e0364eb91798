"""The page's render request: JSON -> (Scene, sketches, mode), with a clear InputError for anything malformed.

The page sends strokes, never rasters: the daemon rasterizes them with `kiosk.contract.sketch.rasterize` (the contract), so
what the network sees is defined in one place. Coordinates are screen pixels (x right, y down).

Single-panel form (the drawing page)::

    {"garment": "denim-shorts", "panel": {"x": 0, "y": 0, "w": 1280, "h": 800}, "screen": [1280, 800],
     "strokes": [[[x, y], [x, y, pressure, t_ms], ...], ...], "base": false, "mode": "final", "client": "tab-1"}

Scene form (several panels, e.g. the A/B study)::

    {"scene": {"screen": [1280, 800], "panels": [{"id": "a", "rect": [0, 0, 640, 800], "bundle": "denim-shorts",
     "visual": "reference", "tactile": "model", "sketch": "reference", "half": "left"}, ...]},
     "sketches": {"a": {"strokes": [...], "base": true}}, "mode": "final"}
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from kiosk.contract.errors import InputError
from kiosk.inference.scene import Panel, Scene, SketchInput
from kiosk.contract.sketch import MAX_POINTS

MAX_STROKES = 2000
MAX_COORD = 1e6
MODES = ("preview", "final", "refine")


@dataclass(frozen=True)
class RenderRequest:
    """mode: `preview` (while drawing: visual only, preview resolution), `final` (stroke end: everything; at the
    preview resolution first when the daemon refines, answering `refine: true`), `refine` (everything at full
    resolution), `full` (everything at full resolution in one step: the study's show())."""

    scene: Scene
    sketches: dict[str, SketchInput]
    mode: str
    client: str

    @property
    def preview(self) -> bool:
        return self.mode == "preview"


def _int(v: Any, what: str, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or not lo <= v <= hi:
        raise InputError(f"{what} must be a number from {lo} to {hi}; got {v!r:.40}")
    if isinstance(v, float) and not v.is_integer():
        v = round(v)
    return int(v)


def _str(v: Any, what: str, limit: int = 64) -> str:
    if not isinstance(v, str) or not v or len(v) > limit:
        raise InputError(f"{what} must be a non-empty string of at most {limit} characters")
    return v


def parse_strokes(doc: Any, what: str = "strokes") -> tuple[np.ndarray, ...]:
    """A JSON list of strokes, each a list of [x, y] / [x, y, pressure] / [x, y, pressure, t] points."""
    if doc is None:
        return ()
    if not isinstance(doc, list):
        raise InputError(f"{what} must be a list of strokes")
    if len(doc) > MAX_STROKES:
        raise InputError(f"{what}: more than {MAX_STROKES} strokes; clear the canvas and draw again")
    total = 0
    out = []
    for i, stroke in enumerate(doc):
        if not isinstance(stroke, list):
            raise InputError(f"{what}[{i}] must be a list of points")
        total += len(stroke)
        if total > MAX_POINTS:
            raise InputError(f"{what}: more than {MAX_POINTS} points in all; clear the canvas and draw again")
        if not stroke:
            continue
        pts = np.empty((len(stroke), 2), np.float64)
        for j, p in enumerate(stroke):
            if not isinstance(p, list) or not 2 <= len(p) <= 4:
                raise InputError(f"{what}[{i}][{j}] must be [x, y] or [x, y, pressure[, time]]")
            for k, v in enumerate(p):
                if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or abs(v) > MAX_COORD:
                    raise InputError(f"{what}[{i}][{j}][{k}] must be a finite number within +-{MAX_COORD:g}")
            pts[j] = p[0], p[1]
        out.append(pts)
    return tuple(out)


def _rect(v: Any, what: str) -> tuple[int, int, int, int]:
    if isinstance(v, dict):
        keys = ("x", "y", "w", "h")
        if set(v) != set(keys):
            raise InputError(f"{what} must be {{x, y, w, h}} in screen pixels")
        v = [v[k] for k in keys]
    if not isinstance(v, list) or len(v) != 4:
        raise InputError(f"{what} must be [x, y, w, h] in screen pixels")
    x, y = (_int(c, f"{what} x/y", -16384, 16384) for c in v[:2])
    w, h = (_int(c, f"{what} width/height", 1, 16384) for c in v[2:])
    return (x, y, w, h)


def _screen(v: Any) -> tuple[int, int]:
    if not isinstance(v, list) or len(v) != 2:
        raise InputError("screen must be [width, height] in pixels")
    return (_int(v[0], "screen width", 1, 16384), _int(v[1], "screen height", 1, 16384))


def _sketch(v: Any, what: str) -> SketchInput:
    if not isinstance(v, dict) or not set(v) <= {"strokes", "base"}:
        raise InputError(f"{what} must be an object with 'strokes' and optionally 'base'")
    base = v.get("base", False)
    if not isinstance(base, bool):
        raise InputError(f"{what}.base must be true or false")
    return SketchInput(parse_strokes(v.get("strokes"), f"{what}.strokes"), base)


def _only(doc: dict, allowed: set[str], what: str) -> None:
    extra = sorted(str(k) for k in doc if k not in allowed)
    if extra:
        raise InputError(f"unknown field(s) in {what}: {', '.join(extra)}")


def parse_render_request(doc: Any) -> RenderRequest:
    """Validate a render request (either form); InputError names the first problem."""
    if not isinstance(doc, dict):
        raise InputError("the render request must be a JSON object")
    mode = doc.get("mode", "final")
    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}")
    client = _str(doc.get("client", "default"), "client")
    if "scene" in doc:
        _only(doc, {"scene", "sketches", "mode", "client"}, "the render request")
        sc = doc["scene"]
        if not isinstance(sc, dict) or not isinstance(sc.get("panels"), list):
            raise InputError("scene must be an object with 'screen' and a list of 'panels'")
        _only(sc, {"screen", "panels"}, "scene")
        panels = []
        for i, p in enumerate(sc["panels"]):
            if not isinstance(p, dict):
                raise InputError(f"scene.panels[{i}] must be an object")
            _only(p, {"id", "rect", "bundle", "visual", "tactile", "sketch", "half"}, f"scene.panels[{i}]")
            opts = {k: _str(p[k], f"scene.panels[{i}].{k}", 16) for k in ("visual", "tactile", "sketch", "half")
                    if k in p}
            where = f"scene.panels[{i}]"
            panels.append(Panel(_str(p.get("id"), f"{where}.id"), _rect(p.get("rect"), f"{where}.rect"),
                                _str(p.get("bundle"), f"{where}.bundle"), **opts))
        scene = Scene(tuple(panels), _screen(sc.get("screen")))
        sk = doc.get("sketches", {})
        if not isinstance(sk, dict):
            raise InputError("sketches must map panel ids to {strokes, base}")
        ids = {p.id for p in panels}
        unknown = sorted(set(sk) - ids)
        if unknown:
            raise InputError(f"sketches for unknown panel(s): {', '.join(map(str, unknown))}")
        sketches = {k: _sketch(v, f"sketches.{k}") for k, v in sk.items()}
        return RenderRequest(scene, sketches, mode, client)
    _only(doc, {"garment", "panel", "screen", "strokes", "base", "mode", "client"}, "the render request")
    garment = _str(doc.get("garment"), "garment")
    rect = _rect(doc.get("panel"), "panel")
    screen = _screen(doc.get("screen", [rect[0] + rect[2], rect[1] + rect[3]]))
    sketch = _sketch({k: doc[k] for k in ("strokes", "base") if k in doc}, "the request")
    panel = Panel("main", rect, garment)
    return RenderRequest(Scene((panel,), screen), {"main": sketch}, mode, client)
