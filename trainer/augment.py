"""Augmentation as in the paper: the images are stored padded; a random square crop is taken whose origin keeps
the whole object mask inside the crop (so the sketch's contour stays closed). For the published data (1800 px
padded, 1536 crops, object inside the 1280x960 frame) this is the published uniform origin in [0, 260].
"""
from __future__ import annotations

import numpy as np

from kiosk.contract.graph import GRID_MULTIPLE
from trainer.errors import TrainerError



class CropError(TrainerError):
    """The object cannot be kept inside a crop of the requested size."""


def object_bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1), exclusive end, of the True pixels."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        raise CropError("the object mask is empty")
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def resolve_crop(crop: int, mask: np.ndarray, *, fit: bool = True) -> int:
    """The crop side to use: `crop`, or (fit) the smallest multiple of 256 that holds the object, within the image."""
    p = mask.shape[0]
    x0, y0, x1, y1 = object_bbox(mask)
    need = max(x1 - x0, y1 - y0)
    side = crop
    if need > side:
        if not fit:
            raise CropError(f"the object ({x1 - x0}x{y1 - y0} px) does not fit a {crop} px crop; "
                            f"set data.fit_crop or a larger data.crop")
        side = -(-need // GRID_MULTIPLE) * GRID_MULTIPLE
    if side > p:
        raise CropError(f"a {side} px crop does not fit the {p} px padded image "
                        f"(object {x1 - x0}x{y1 - y0} px); use a smaller garment frame")
    return side


def origin_range(mask: np.ndarray, side: int) -> tuple[tuple[int, int], tuple[int, int]]:
    """((xmin, xmax), (ymin, ymax)) inclusive: crop origins inside the image that keep the object inside."""
    p = mask.shape[0]
    x0, y0, x1, y1 = object_bbox(mask)
    rx = (max(0, x1 - side), min(p - side, x0))
    ry = (max(0, y1 - side), min(p - side, y0))
    if rx[0] > rx[1] or ry[0] > ry[1]:
        raise CropError(f"no {side} px crop keeps the whole object inside the image")
    return rx, ry


def random_crop_origin(mask: np.ndarray, side: int, rng: np.random.Generator) -> tuple[int, int]:
    (xa, xb), (ya, yb) = origin_range(mask, side)
    return int(rng.integers(xa, xb + 1)), int(rng.integers(ya, yb + 1))


def eval_crop_origin(mask: np.ndarray, side: int) -> tuple[int, int]:
    """The published centre crop ((P - side) / 2) when it holds the object, else the nearest one that does."""
    p = mask.shape[0]
    (xa, xb), (ya, yb) = origin_range(mask, side)
    c = (p - side) // 2
    return int(np.clip(c, xa, xb)), int(np.clip(c, ya, yb))
