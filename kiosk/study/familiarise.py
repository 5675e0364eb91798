"""Familiarisation textures: friction maps made from a description in millimetres, not from a model.

The paper lets participants feel homogeneous textures before the warm-up so they learn what the device can render.
These are the kiosk's own: a uniform friction level, a grating (raised-cosine stripes of a stated period), a bump
(a raised-cosine dome of a stated diameter) and a ridge (one raised-cosine stripe of a stated width), laid out at
the haptic screen's physical pitch so a 2 mm grating is 2 mm under the finger on any screen.

Shape: `texture_pixels(texture, (w, h), screen, screen_mm)` -> (h, w) uint8, 0 = natural friction, 255 = maximum.

Example:
    >>> from kiosk.study.config import Texture
    >>> texture_pixels(Texture("uniform", level=0.5), (4, 2), (100, 50), (200.0, 100.0)).tolist()
    [[128, 128, 128, 128], [128, 128, 128, 128]]
"""
from __future__ import annotations

import numpy as np

from kiosk.contract.errors import InputError
from kiosk.study.config import Texture


def pitch_mm(screen: tuple[int, int], screen_mm: tuple[float, float]) -> tuple[float, float]:
    """Millimetres per screen pixel along x and y."""
    if min(screen) < 1 or min(screen_mm) <= 0:
        raise InputError(f"screen {screen} px / {screen_mm} mm cannot give a pixel pitch")
    return screen_mm[0] / screen[0], screen_mm[1] / screen[1]


def _raised_cosine(d_mm: np.ndarray, half_width_mm: float) -> np.ndarray:
    """1 at distance 0, falling smoothly to 0 at `half_width_mm` and beyond."""
    x = np.clip(np.abs(d_mm) / half_width_mm, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * x))


def texture_pixels(texture: Texture, size: tuple[int, int], screen: tuple[int, int],
                   screen_mm: tuple[float, float]) -> np.ndarray:
    """The friction map of `texture` over a region of `size` = (w, h) screen pixels."""
    w, h = size
    if w < 1 or h < 1:
        raise InputError(f"a familiarisation texture needs a region of at least 1 x 1 px, got {size}")
    px, py = pitch_mm(screen, screen_mm)
    x_mm = (np.arange(w, dtype=np.float64) + 0.5 - w / 2) * px
    y_mm = (np.arange(h, dtype=np.float64) + 0.5 - h / 2) * py
    if texture.kind == "uniform":
        z = np.ones((h, w))
    elif texture.kind == "grating":
        period = float(texture.period_mm or 0)
        if period < 2 * px:
            raise InputError(f"a {period:g} mm grating is finer than this screen can render "
                             f"({px:.3f} mm per pixel: at least {2 * px:.2f} mm)")
        z = np.broadcast_to(0.5 * (1.0 + np.cos(2 * np.pi * x_mm / period)), (h, w))
    elif texture.kind == "bump":
        r = np.hypot(x_mm[None, :], y_mm[:, None])
        z = _raised_cosine(r, float(texture.diameter_mm or 0) / 2)
    elif texture.kind == "ridge":
        z = np.broadcast_to(_raised_cosine(x_mm, float(texture.width_mm or 0) / 2), (h, w))
    else:
        raise InputError(f"unknown familiarisation texture kind {texture.kind!r}")
    return np.ascontiguousarray(np.rint(255.0 * texture.level * z).astype(np.uint8))
