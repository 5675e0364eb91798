"""Garment ids: every name a user meets maps to one id; ids are stable and safe as folder names."""
from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kiosk.contract.errors import InputError
from kiosk.contract.garment import garment_id, same_garment


@pytest.mark.parametrize("name", ["DenimShorts", "singleskit_DenimShorts_padded_900_x1", "denim-shorts",
                                  "singleskit_DenimShorts_padded_1800_x1", " denim-shorts "])
def test_three_names_one_id(name):
    assert garment_id(name) == "denim-shorts"


def test_other_examples():
    assert garment_id("CorduroyTrousers") == "corduroy-trousers"
    assert garment_id("KnitJacket") == "knit-jacket"
    assert garment_id("T_Shirt 2") == "t-shirt-2"
    assert same_garment("KnitJacket", "singleskit_KnitJacket_padded_270_x1")
    assert not same_garment("KnitJacket", "DenimShorts") and not same_garment("", "x")


@pytest.mark.parametrize("bad", ["", "   ", None, 7, "___", "..", ".", "-."])
def test_refuses_what_names_nothing(bad):
    with pytest.raises(InputError):
        garment_id(bad)


@given(st.text(min_size=1, max_size=80))
def test_ids_are_idempotent_and_folder_safe(name):
    try:
        gid = garment_id(name)
    except InputError:
        return
    assert garment_id(gid) == gid
    assert 0 < len(gid) <= 64 and "/" not in gid and gid not in (".", "..") and gid == gid.lower()
