"""Deterministic drawing sessions for `vtkiosk bench e2e`: what a shopper's finger does, as timed stroke points.

Each session draws a garment outline on a 1280x800 panel (in one or two strokes, so the outline closes only at the
end, like a real drawing), adds detail strokes (a pocket, a seam), undoes the last one, and clears. Points are
sampled every 8 px at 700 px/s with +-1 px jitter (seeded), i.e. about 90 touch events a second.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SPEED_PX_S = 700.0
STEP_PX = 8.0


@dataclass(frozen=True)
class Action:
    """draw: add `stroke` ((N, 3) x, y, t_ms from the stroke's start); undo: drop the last stroke; clear: all."""

    kind: str
    stroke: np.ndarray | None = None
    label: str = ""


@dataclass(frozen=True)
class Session:
    name: str
    actions: tuple[Action, ...]


def _polyline(points, rng: np.random.Generator) -> np.ndarray:
    pts = np.asarray(points, np.float64)
    out = [pts[0]]
    for a, b in zip(pts[:-1], pts[1:]):
        n = max(1, int(np.ceil(np.hypot(*(b - a)) / STEP_PX)))
        for t in np.arange(1, n + 1) / n:
            out.append(a + (b - a) * t)
    xy = np.asarray(out) + rng.uniform(-1, 1, (len(out), 2))
    dist = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    return np.column_stack([np.round(xy, 1), np.round(1e3 * dist / SPEED_PX_S, 1)])


def _shift(points, dx, dy):
    return [(x + dx, y + dy) for x, y in points]


SHIRT = [(470, 180), (420, 200), (330, 260), (370, 330), (430, 300), (430, 620), (850, 620), (850, 300), (910, 330),
         (950, 260), (860, 200), (810, 180), (760, 210), (520, 210), (470, 180)]
SHORTS = [(420, 220), (860, 220), (900, 600), (690, 600), (640, 380), (590, 600), (380, 600), (420, 220)]
SKIRT = [(500, 200), (780, 200), (900, 620), (380, 620), (500, 200)]


def sessions(seed: int = 0) -> list[Session]:
    rng = np.random.default_rng(seed)

    def draw(points, label):
        return Action("draw", _polyline(points, rng), label)

    shirt = Session("shirt", (
        draw(SHIRT[:8], "outline, left half (open)"),
        draw(SHIRT[7:], "outline, right half (closes it)"),
        draw([(700, 360), (780, 360), (780, 440), (700, 440), (700, 360)], "pocket"),
        draw([(640, 215), (640, 610)], "placket seam"),
        Action("undo", label="undo the seam"),
        Action("clear", label="clear")))
    shorts = Session("shorts", (
        draw(SHORTS, "outline (one stroke)"),
        draw([(430, 260), (850, 260)], "waistband"),
        draw([(470, 300), (540, 300), (540, 360)], "pocket"),
        Action("undo", label="undo the pocket"),
        Action("clear", label="clear")))
    skirt = Session("skirt", (
        draw(_shift(SKIRT, -60, 0), "outline (one stroke)"),
        draw([(500, 300), (720, 300)], "hem line"),
        draw([(560, 400), (600, 560)], "pleat"),
        draw([(660, 400), (700, 560)], "pleat"),
        Action("undo", label="undo a pleat"),
        Action("clear", label="clear")))
    return [shirt, shorts, skirt]
