"""Sketches of the runtime contract: touch strokes -> sketch raster, object mask, network input.

The trainer builds its inputs with these same functions, so a sketch drawn with a finger on the kiosk and a sketch
extracted from a training photo reach the network in the same form.

Conventions
-----------
- A sketch is (H, W) uint8 with ink 0 (a drawn line) on paper 255, lines about `LINE_PX` pixels wide.
- A mask is (H, W) bool, True on the garment.
- Strokes are in panel pixels: x = column from the left, y = row from the top.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import NamedTuple

import cv2
import numpy as np

from kiosk.contract.errors import InputError
from kiosk.contract.validate import check_size

INK = 0
PAPER = 255
# Width of sketch lines at the camera frame's resolution; training sketches and finger strokes use the same.
LINE_PX = 2
# Refuse stroke sets larger than this (a stuck touch controller), instead of drawing for seconds.
MAX_POINTS = 200_000


class NetworkInput(NamedTuple):
    """What an exported graph takes. Positional encoding is computed inside the graph, not here.

    Shape: sketch (1, 1, H, W) float32 in [-1, 1], 0 outside the mask; mask (1, 1, H, W) float32 in {0, 1}.
    """

    sketch: np.ndarray
    mask: np.ndarray


def _check_sketch(sketch: object) -> np.ndarray:
    arr = np.asarray(sketch)
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(f"sketch must be a 2-D (H, W) array; got shape {arr.shape}")
    if arr.dtype != np.uint8:
        raise InputError(f"sketch must be uint8 (ink 0 on paper 255); got dtype {arr.dtype}")
    return np.ascontiguousarray(arr)


def _stroke_points(stroke: object, index: int) -> np.ndarray:
    """One stroke as an (N, 2) float64 array of (x, y); pressure/time columns are accepted and ignored."""
    try:
        pts = np.asarray(stroke, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"stroke {index} must be a list of (x, y[, pressure[, time]]) numbers") from exc
    if pts.size == 0:
        return np.zeros((0, 2))
    if pts.ndim == 1 and pts.shape[0] in (2, 3, 4):
        pts = pts[None, :]
    if pts.ndim != 2 or pts.shape[1] not in (2, 3, 4):
        raise InputError(f"stroke {index} must be a list of (x, y[, pressure[, time]]) points; "
                         f"got an array of shape {pts.shape}")
    return pts[:, :2]


def rasterize(strokes: Iterable[Sequence[Sequence[float]]], size: tuple[int, int], *,
              width_px: int = LINE_PX, base: np.ndarray | None = None) -> np.ndarray:
    """Draw touch strokes as a thin-contour sketch like the training sketches.

    Points with non-finite coordinates split a stroke (the touch controller lost the finger); coordinates off the
    canvas are clamped to its edge; a single-point stroke is a dot. Pressure does not change the line width: the
    training sketches are thinned, uniform lines, and the network has only seen those. `base` (an existing sketch of
    the same size) is drawn over, for incremental edits.

    Shape: strokes: any number of strokes, each (N, 2..4) as (x, y[, pressure[, time]]); size: (width, height)
    -> (height, width) uint8, ink 0 on paper 255.
    Raises InputError for malformed strokes, a bad size or width, or more than MAX_POINTS points in all.

    Example:
        >>> s = rasterize([[(1, 1), (6, 1)]], (8, 4))
        >>> int((s == 0).sum()) > 0
        True
    """
    w, h = check_size(size)
    if isinstance(width_px, bool) or not isinstance(width_px, (int, np.integer)) or not 1 <= width_px <= 64:
        raise InputError(f"width_px must be an integer from 1 to 64; got {width_px!r}")
    if base is None:
        canvas = np.full((h, w), PAPER, dtype=np.uint8)
    else:
        canvas = _check_sketch(base).copy()
        if canvas.shape != (h, w):
            raise InputError(f"base sketch has shape {canvas.shape}, expected {(h, w)}")
    if strokes is None or isinstance(strokes, (str, bytes)):
        raise InputError("strokes must be a list of strokes, each a list of (x, y) points")
    total = 0
    polylines: list[np.ndarray] = []
    for i, stroke in enumerate(strokes):
        pts = _stroke_points(stroke, i)
        total += len(pts)
        if total > MAX_POINTS:
            raise InputError(f"too many stroke points (more than {MAX_POINTS}); clear the canvas and draw again")
        finite = np.isfinite(pts).all(axis=1)
        # Split the stroke at every run of non-finite points.
        breaks = np.flatnonzero(np.diff(np.concatenate([[0], finite.astype(np.int8), [0]])))
        for start, stop in zip(breaks[::2], breaks[1::2]):
            seg = pts[start:stop].copy()
            seg[:, 0] = np.clip(seg[:, 0], 0, w - 1)
            seg[:, 1] = np.clip(seg[:, 1], 0, h - 1)
            if len(seg) == 1:
                seg = np.repeat(seg, 2, axis=0)  # a tap: a zero-length line is a dot
            polylines.append(np.rint(seg).astype(np.int32).reshape(-1, 1, 2))
    # One-pixel lines widened by a width_px square, exactly as `sketch_from_image` widens its thinned edges
    # (cv2's own thick lines come out one pixel wider for even widths).
    ink = np.zeros((h, w), dtype=np.uint8)
    if polylines:
        cv2.polylines(ink, polylines, False, 1, 1, cv2.LINE_8)
        if width_px > 1:
            ink = cv2.dilate(ink, np.ones((width_px, width_px), np.uint8))
        canvas[ink > 0] = INK
    return canvas


def _fill_from_border(closed_ink: np.ndarray) -> np.ndarray:
    """Everything not reachable from the image border without crossing ink: the filled outline(s)."""
    h, w = closed_ink.shape
    free = np.where(closed_ink, 0, 255).astype(np.uint8)
    padded = cv2.copyMakeBorder(free, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=255)
    flood_mask = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(padded, flood_mask, (0, 0), 128)
    return padded[1:-1, 1:-1] != 128


def _largest_component(mask: np.ndarray) -> np.ndarray:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros_like(mask, dtype=bool)
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    return labels == best


def object_mask(sketch: object, *, max_gap_px: int | None = None) -> np.ndarray:
    """The garment's mask: the filled outer contour of the sketch.

    Hand-drawn outlines leave gaps, so the ink is closed morphologically with growing kernels (3 px up to
    `max_gap_px`, default 8 % of the shorter side, at least 11 px; a kernel of k px bridges gaps of about k - 4 px) until the outline encloses an area clearly larger than its own
    ink; then the region not reachable from the border is filled and only the largest component is kept.
    A sketch without ink, or one that no closing can close, gives an all-False mask (nothing to synthesise).

    Shape: (H, W) uint8 sketch (ink 0 on paper 255) -> (H, W) bool.
    """
    arr = _check_sketch(sketch)
    ink = arr < 128
    if not ink.any():
        return np.zeros(arr.shape, dtype=bool)
    if max_gap_px is None:
        max_gap_px = max(11, int(0.08 * min(arr.shape)))
    k = 3
    while True:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
        closed = cv2.morphologyEx(ink.astype(np.uint8), cv2.MORPH_CLOSE, kernel, borderType=cv2.BORDER_CONSTANT,
                                  borderValue=0) > 0
        filled = _fill_from_border(closed) | ink
        region = _largest_component(filled)
        if _encloses(region, ink) or k >= max_gap_px:
            break
        k = min(2 * k + 1, max(max_gap_px, 3))
    if not _encloses(region, ink):
        # The outline never closed: what we have is only lines, not an object.
        return np.zeros(arr.shape, dtype=bool)
    return region


_RIM = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))


def _encloses(region: np.ndarray, ink: np.ndarray) -> bool:
    """Whether `region` is an enclosed area rather than lines: clearly larger than the ink on its rim.

    Only the rim's ink (a 3 px band inside the region's edge) counts, so a garment whose sketch is dense with
    interior detail (a knit's loops, quilting) still reads as enclosed when the sketch is downsampled, where its
    lines grow relative to its area; an open stroke is all rim and never passes."""
    area = int(region.sum())
    if area == 0:
        return False
    inner = cv2.erode(region.astype(np.uint8), _RIM, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    return area > 2 * int((ink & region & ~inner).sum())


def network_input(sketch: object, mask: object) -> NetworkInput:
    """The graph inputs, exactly as the trainer feeds the network: sketch / 127.5 - 1, times the mask.

    Shape: sketch (H, W) uint8, mask (H, W) bool or {0, 1} -> NetworkInput of two (1, 1, H, W) float32 arrays.
    """
    s = _check_sketch(sketch)
    m = np.asarray(mask)
    if m.shape != s.shape:
        raise InputError(f"mask shape {m.shape} must equal sketch shape {s.shape}")
    if m.dtype != bool:
        if not (np.issubdtype(m.dtype, np.number) and np.isin(m, (0, 1)).all()):
            raise InputError("mask must be boolean or contain only 0 and 1")
        m = m.astype(bool)
    mf = m.astype(np.float32)
    x = (s.astype(np.float32) * np.float32(1.0 / 127.5) - np.float32(1.0)) * mf
    return NetworkInput(x[None, None], mf[None, None])


def sketch_from_image(rgb: object, mask: object, *, blur_sigma: float | None = None,
                      min_length_px: int | None = None) -> np.ndarray:
    """The training-time sketch extractor: edges of a garment photo, thinned, like a drawn contour.

    Stands in for the paper's DexiNed + thinning with OpenCV: Gaussian blur at a scale that suppresses fabric texture
    (`blur_sigma`, default 0.25 % of the shorter side), Canny with thresholds from the image's own gradient
    distribution, edges kept inside the slightly dilated mask, the mask's outline added (the silhouette is always
    part of a garment sketch), thinning (Zhang-Suen, `cv2.ximgproc.thinning`), removal of short fragments
    (`min_length_px`, default 1 % of the shorter side: the paper removes small edges by hand), and lines drawn at
    LINE_PX.

    Shape: rgb (H, W, 3) uint8, mask (H, W) bool -> (H, W) uint8 sketch, ink 0 on paper 255.
    """
    img = np.asarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or img.shape[0] < 2 or img.shape[1] < 2:
        raise InputError(f"rgb must be an (H, W, 3) uint8 image; got shape {img.shape} dtype {img.dtype}")
    m = np.asarray(mask).astype(bool)
    if m.shape != img.shape[:2]:
        raise InputError(f"mask shape {m.shape} must equal the image's {img.shape[:2]}")
    short = min(img.shape[:2])
    sigma = 0.0025 * short if blur_sigma is None else float(blur_sigma)
    min_len = max(4, int(0.01 * short)) if min_length_px is None else int(min_length_px)
    gray = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
    if sigma > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), sigmaX=sigma)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.hypot(gx, gy)
    inside = mag[m]
    # Thresholds from the garment's own gradient distribution: only its strongest structure becomes lines.
    hi = float(np.quantile(inside, 0.95)) if inside.size else 0.0
    hi = max(hi, 8.0)
    edges = cv2.Canny(gray, 0.5 * hi, hi, L2gradient=True) > 0
    m8 = m.astype(np.uint8)
    near = cv2.dilate(m8, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))) > 0
    edges &= near
    outline = np.zeros_like(m8)
    contours, _ = cv2.findContours(m8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(outline, contours, -1, 1, 1)
    lines = (edges | (outline > 0)).astype(np.uint8) * 255
    thin = cv2.ximgproc.thinning(lines, thinningType=cv2.ximgproc.THINNING_ZHANGSUEN) > 0
    n, labels, stats, _ = cv2.connectedComponentsWithStats(thin.astype(np.uint8), connectivity=8)
    span = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT])
    keep = span >= min_len
    keep[0] = False
    thin = keep[labels]
    if LINE_PX > 1:
        thin = cv2.dilate(thin.astype(np.uint8), np.ones((LINE_PX, LINE_PX), np.uint8)) > 0
    return np.where(thin, INK, PAPER).astype(np.uint8)


def letterbox(sketch: object, size: tuple[int, int]) -> tuple[np.ndarray, tuple[float, int, int]]:
    """Fit a sketch into `size` = (width, height) keeping its aspect ratio, centred on paper.

    Lines are resampled by area and re-binarised, so they stay ink/paper and do not thin out to grey.
    Returns the fitted sketch and (scale, x offset, y offset): source pixel (x, y) lands at
    (x * scale + x offset, y * scale + y offset).

    Shape: (H, W) uint8 -> (height, width) uint8.
    """
    s = _check_sketch(sketch)
    w, h = check_size(size)
    scale = min(w / s.shape[1], h / s.shape[0])
    nw, nh = max(1, round(s.shape[1] * scale)), max(1, round(s.shape[0] * scale))
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_NEAREST
    small = cv2.resize(s, (nw, nh), interpolation=interp)
    small = np.where(small < 224, INK, PAPER).astype(np.uint8)  # a partly covered pixel keeps its line
    out = np.full((h, w), PAPER, np.uint8)
    ox, oy = (w - nw) // 2, (h - nh) // 2
    out[oy:oy + nh, ox:ox + nw] = small
    return out, (scale, ox, oy)
