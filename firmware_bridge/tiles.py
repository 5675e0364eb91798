"""Tiling, delta detection and tile codecs for friction maps.

A frame is a uint8 array of shape (panel_h, panel_w) (row-major, 0 = natural friction, 255 = maximum). It is cut
into tiles of (tile_h, tile_w) pixels; edge tiles are clipped to the panel, so a 1280x800 panel with 64x64 tiles
has 20 x 13 = 260 tiles, the bottom row 64x32. Tile (tx, ty) covers rows [ty*tile_h, min(.., panel_h)) and columns
[tx*tile_w, min(.., panel_w)).

Codecs (protocol.Codec): RAW, ZLIB (level chosen by measurement, see docs/bridge-protocol.md) and FILL (a constant
tile is one byte). `encode_tile` picks the smallest; `decode_tile` is bounded: the output is exactly the tile's size
or a ProtocolError is raised, so a hostile zlib stream cannot make the device allocate more.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from .errors import ProtocolError
from .protocol import Codec


@dataclass(frozen=True)
class Grid:
    """Tile geometry of a panel. Units: pixels."""

    panel_w: int
    panel_h: int
    tile_w: int
    tile_h: int

    def __post_init__(self) -> None:
        for name in ("panel_w", "panel_h", "tile_w", "tile_h"):
            v = getattr(self, name)
            if not isinstance(v, int) or v <= 0:
                raise ValueError(f"Grid.{name} must be a positive int, got {v!r}")

    @property
    def nx(self) -> int:
        return -(-self.panel_w // self.tile_w)

    @property
    def ny(self) -> int:
        return -(-self.panel_h // self.tile_h)

    @property
    def count(self) -> int:
        return self.nx * self.ny

    def bounds(self, tx: int, ty: int) -> tuple[int, int, int, int]:
        """(y0, y1, x0, x1) pixel bounds of tile (tx, ty); raises IndexError if outside the grid."""
        if not (0 <= tx < self.nx and 0 <= ty < self.ny):
            raise IndexError(f"tile ({tx}, {ty}) outside a {self.nx}x{self.ny} grid")
        y0, x0 = ty * self.tile_h, tx * self.tile_w
        return y0, min(y0 + self.tile_h, self.panel_h), x0, min(x0 + self.tile_w, self.panel_w)

    def tile_len(self, tx: int, ty: int) -> int:
        y0, y1, x0, x1 = self.bounds(tx, ty)
        return (y1 - y0) * (x1 - x0)

    def all_tiles(self) -> list[tuple[int, int]]:
        return [(tx, ty) for ty in range(self.ny) for tx in range(self.nx)]

    def check_frame(self, frame: np.ndarray, name: str = "frame") -> np.ndarray:
        """Validate a friction frame: uint8, shape (panel_h, panel_w). Returns it C-contiguous."""
        if not isinstance(frame, np.ndarray):
            raise TypeError(f"{name} must be a numpy array, got {type(frame).__name__}")
        if frame.dtype != np.uint8:
            raise TypeError(f"{name} must be uint8 (0 = natural friction, 255 = maximum), got {frame.dtype}")
        if frame.shape != (self.panel_h, self.panel_w):
            raise ValueError(f"{name} must have shape (panel_h, panel_w) = ({self.panel_h}, {self.panel_w}), "
                             f"got {frame.shape}")
        return np.ascontiguousarray(frame)

    def tile_bytes(self, frame: np.ndarray, tx: int, ty: int) -> bytes:
        y0, y1, x0, x1 = self.bounds(tx, ty)
        return frame[y0:y1, x0:x1].tobytes()


def changed_tiles(grid: Grid, new: np.ndarray, old: np.ndarray | None) -> list[tuple[int, int]]:
    """Tiles whose pixels differ between `new` and `old` (all tiles if `old` is None), row-major order.

    Shape: new, old (panel_h, panel_w) uint8. Vectorised: pads to whole tiles and reduces per tile.
    """
    if old is None:
        return grid.all_tiles()
    diff = new != old
    ph, pw = grid.ny * grid.tile_h, grid.nx * grid.tile_w
    if diff.shape != (ph, pw):
        padded = np.zeros((ph, pw), dtype=bool)
        padded[: grid.panel_h, : grid.panel_w] = diff
        diff = padded
    per_tile = diff.reshape(grid.ny, grid.tile_h, grid.nx, grid.tile_w).any(axis=(1, 3))
    ty, tx = np.nonzero(per_tile)
    return [(int(x), int(y)) for y, x in zip(ty, tx)]


def encode_tile(raw: bytes, compression: str = "zlib", level: int = 1) -> tuple[int, bytes]:
    """Tile bytes -> (codec, data). compression "none": RAW always (the uncompressed baseline); "zlib": the
    smallest of FILL (constant tile, 1 byte), ZLIB at `level`, RAW."""
    if compression == "zlib":
        if raw and raw.count(raw[0]) == len(raw):
            return Codec.FILL, raw[:1]
        packed = zlib.compress(raw, level)
        if len(packed) < len(raw):
            return Codec.ZLIB, packed
    elif compression != "none":
        raise ValueError(f"compression must be 'none' or 'zlib', got {compression!r}")
    return Codec.RAW, raw


def decode_tile(codec: int, data: bytes, expected_len: int) -> bytes:
    """(codec, data) -> exactly `expected_len` bytes, or ProtocolError. Decompression is bounded."""
    if codec == Codec.RAW:
        if len(data) != expected_len:
            raise ProtocolError(f"RAW tile has {len(data)} B, expected {expected_len} B")
        return bytes(data)
    if codec == Codec.FILL:
        if len(data) != 1:
            raise ProtocolError(f"FILL tile has {len(data)} B, expected 1 B")
        return data * expected_len
    if codec == Codec.ZLIB:
        d = zlib.decompressobj()
        try:
            out = d.decompress(data, expected_len + 1)
        except zlib.error as exc:
            raise ProtocolError(f"ZLIB tile does not inflate ({exc})") from None
        if len(out) != expected_len or not d.eof or d.unconsumed_tail or d.unused_data:
            raise ProtocolError(f"ZLIB tile inflates to {len(out)}{'+' if not d.eof else ''} B, "
                                f"expected exactly {expected_len} B")
        return out
    raise ProtocolError(f"unknown tile codec {codec}")
