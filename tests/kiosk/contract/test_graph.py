"""The graph interface is defined once: grid arithmetic, input names, outputs and channels."""
from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kiosk.bundle import manifest
from kiosk.contract.errors import InputError
from kiosk.contract.graph import (GRAPH_KINDS, GRAPH_OUTPUTS, GRID_MULTIPLE, INPUT_NAMES, OUTPUT_CHANNELS,
                                  check_grid, feeds, grid_ceil, grid_floor, is_grid, unpack)


@given(st.integers(min_value=-10_000, max_value=100_000))
def test_grid_floor_and_ceil_bracket_n_on_the_grid(n):
    lo, hi = grid_floor(n), grid_ceil(n)
    assert is_grid(lo) and is_grid(hi)
    assert lo <= max(n, GRID_MULTIPLE) <= hi
    assert hi - lo <= GRID_MULTIPLE
    if is_grid(n):
        assert lo == hi == n


@given(st.integers(min_value=1, max_value=8192), st.integers(min_value=1, max_value=8192))
def test_check_grid_accepts_exactly_the_grid(w, h):
    if is_grid(w) and is_grid(h):
        assert check_grid(w, h) == (w, h)
    else:
        with pytest.raises(InputError, match=f"multiples of {GRID_MULTIPLE}"):
            check_grid(w, h)


def test_feeds_round_trip_and_cover_the_input_names():
    f = feeds("s", "m")
    assert tuple(f) == INPUT_NAMES and unpack(f) == ("s", "m")


def test_every_graph_kind_has_outputs_with_known_channels_and_the_manifest_reads_the_same_table():
    assert set(GRAPH_OUTPUTS) == set(GRAPH_KINDS)
    assert all(o in OUTPUT_CHANNELS for outs in GRAPH_OUTPUTS.values() for o in outs)
    assert manifest.GRAPH_OUTPUTS is GRAPH_OUTPUTS and manifest.GRAPH_KINDS is GRAPH_KINDS
