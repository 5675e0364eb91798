"""The exported graph's interface: what the trainer trains, the exporter writes and the kiosk runs must agree on.

Defined once here (numpy-free, torch-free) and imported by all three sides, so a renamed input or a new output
channel is one edit, and a bundle written by one version of the exporter is read by the kiosk with the same names.

- Inputs: `sketch` (1, 1, H, W) float32 in [-1, 1] and `mask` (1, 1, H, W) float32 in {0, 1}; H and W are
  multiples of `GRID_MULTIPLE` (the generator halves the grid eight times, and the innermost level must be 1x1 or
  more). Positional encoding is computed inside the graph, so the runtime feeds only these two.
- Outputs: `visual` (3 channels, RGB in [-1, 1]) and `tactile` (2 channels, gx and gy); a graph kind computes the
  outputs `GRAPH_OUTPUTS[kind]` in that order.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from kiosk.contract.errors import InputError

GRID_MULTIPLE = 256
SKETCH_INPUT = "sketch"
MASK_INPUT = "mask"
INPUT_NAMES = (SKETCH_INPUT, MASK_INPUT)
OUTPUT_CHANNELS = {"visual": 3, "tactile": 2}
GRAPH_KINDS = ("full", "tactile", "visual")
GRAPH_OUTPUTS = {"full": ["visual", "tactile"], "tactile": ["tactile"], "visual": ["visual"]}


def feeds(sketch: Any, mask: Any) -> dict[str, Any]:
    """The input mapping a graph session takes (ONNX Runtime feeds), from the sketch and mask arrays."""
    return {SKETCH_INPUT: sketch, MASK_INPUT: mask}


def unpack(feed: Mapping[str, Any]) -> tuple[Any, Any]:
    """(sketch, mask) from a feed mapping written by `feeds`."""
    return feed[SKETCH_INPUT], feed[MASK_INPUT]


def is_grid(n: int) -> bool:
    """True for a side length a graph accepts: a positive multiple of `GRID_MULTIPLE`."""
    return n >= GRID_MULTIPLE and n % GRID_MULTIPLE == 0


def grid_floor(n: int) -> int:
    """The largest grid side <= n, and never below one `GRID_MULTIPLE`."""
    return max(GRID_MULTIPLE, int(n) // GRID_MULTIPLE * GRID_MULTIPLE)


def grid_ceil(n: float) -> int:
    """The smallest grid side >= n (one `GRID_MULTIPLE` at least)."""
    return max(GRID_MULTIPLE, math.ceil(n / GRID_MULTIPLE) * GRID_MULTIPLE)


def check_grid(width: int, height: int) -> tuple[int, int]:
    """(width, height) if both are grid sides, else InputError saying why a graph cannot take them."""
    if not (is_grid(width) and is_grid(height)):
        raise InputError(f"sizes must be multiples of {GRID_MULTIPLE} (the generator halves the grid eight times); "
                         f"got {width}x{height}")
    return width, height
