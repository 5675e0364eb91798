"""From model outputs to what is shown and felt, in screen pixels.

The visual goes to the page at the network grid as RGBA (alpha = object mask); the page scales it into the
planned region. The friction map is made from the tactile output with the bundle's calibration
(`kiosk.contract.haptics.friction_map`), resampled to the same region's screen pixels and cropped to what is visible of the
panel, so it is a texture that lands exactly under the visual: texture pixel (i, j) is screen pixel (x + j, y + i).
"""
from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from kiosk.contract.haptics import SUPERSAMPLE, NonFiniteCounter, friction_map

Rect = tuple[int, int, int, int]


@dataclass(frozen=True)
class Texture:
    """A friction texture at screen position (x, y): uint8 (h, w), 0 = natural friction, 255 = maximum."""

    panel: str
    pixels: np.ndarray
    x: int
    y: int

    @property
    def rect(self) -> Rect:
        return (self.x, self.y, int(self.pixels.shape[1]), int(self.pixels.shape[0]))


def intersect(a: Rect, b: Rect) -> Rect | None:
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[0] + a[2], b[0] + b[2]), min(a[1] + a[3], b[1] + b[3])
    if x0 >= x1 or y0 >= y1:
        return None
    return (x0, y0, x1 - x0, y1 - y0)


def friction_texture(panel: str, tactile: np.ndarray, region: Rect, clip: Rect, *, scale: float,
                     normalization: str = "calibrated", constants: Mapping[str, float] | None = None,
                     counter: NonFiniteCounter | None = None, supersample: int = SUPERSAMPLE) -> Texture | None:
    """The friction texture of one panel: tactile (1, 2, H, W) at the grid -> the region's screen pixels, cropped to
    `clip` (the visible panel). None when nothing of the region is visible."""
    visible = intersect(region, clip)
    if visible is None:
        return None
    rx, ry, rw, rh = region
    fm = friction_map(tactile[0, 0], tactile[0, 1], scale, size=(rw, rh), normalization=normalization,
                      constants=constants, counter=counter, supersample=supersample)
    vx, vy, vw, vh = visible
    crop = np.ascontiguousarray(fm[vy - ry:vy - ry + vh, vx - rx:vx - rx + vw])
    return Texture(panel, crop, vx, vy)


class FrictionSource:
    """A panel's friction texture, made on first use (by the haptic output thread, so the visual's response never
    waits for it). Its screen rectangle is known before: the visible part of the region."""

    def __init__(self, panel: str, tactile: np.ndarray, region: Rect, clip: Rect, *, scale: float,
                 normalization: str = "calibrated", constants: Mapping[str, float] | None = None):
        self.panel, self.tactile, self.region, self.clip = panel, tactile, region, clip
        self.scale, self.normalization, self.constants = scale, normalization, constants
        self.rect = intersect(region, clip)
        self.nonfinite = 0
        self.ms = 0.0
        self._texture: Texture | None = None
        self._made = False
        self._lock = threading.Lock()

    def texture(self) -> Texture | None:
        with self._lock:
            if self._made:
                return self._texture
            t0 = time.perf_counter()
            counter = NonFiniteCounter()
            self._texture = friction_texture(self.panel, self.tactile, self.region, self.clip, scale=self.scale,
                                             normalization=self.normalization, constants=self.constants,
                                             counter=counter)
            self.nonfinite = counter.count
            self.ms = 1e3 * (time.perf_counter() - t0)
            self._made = True
            return self._texture


def compose(textures: list[Texture], size: tuple[int, int]) -> np.ndarray:
    """The panel frame the device should hold: textures pasted at their screen positions, later ones on top,
    clipped to the device panel `size` = (width, height). What the haptics bench measures the felt period on."""
    w, h = size
    frame = np.zeros((h, w), np.uint8)
    for t in textures:
        vis = intersect(t.rect, (0, 0, w, h))
        if vis is None:
            continue
        x, y, vw, vh = vis
        frame[y:y + vh, x:x + vw] = t.pixels[y - t.y:y - t.y + vh, x - t.x:x - t.x + vw]
    return frame
