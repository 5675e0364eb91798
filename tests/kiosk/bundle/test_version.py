"""Version ordering: the documented examples, and the properties a total order must have (hypothesis)."""
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.bundle.version import Version, VersionError, compare, is_older, newest, parse_version

versions = st.from_regex(r"\A[A-Za-z0-9][A-Za-z0-9._+-]{0,20}\Z")


@pytest.mark.parametrize("older,newer", [
    ("1", "2"), ("9", "10"), ("1.2", "1.2.1"), ("2.beta", "2.1"), ("v1", "v2"), ("v9", "10"),
    ("2026.11.21-1", "2026.11.21-2"), ("2026.11.21-9", "2026.11.22-1"), ("20261121-99", "20261122-1"),
    ("1.0", "1.0-rc1"), ("alpha", "beta"), ("Alpha", "beta"), ("2026.1-a", "2026.1-b"),
])
def test_documented_examples(older, newer):
    assert compare(older, newer) == -1 and compare(newer, older) == 1
    assert is_older(older, newer) and not is_older(newer, older)
    assert newest([newer, older]) == newest([older, newer]) == newer


@pytest.mark.parametrize("a,b", [("v2", "2"), ("007", "7"), ("1.0", "1-0"), ("1+2", "1_2"), ("RC", "rc")])
def test_equal_rank(a, b):
    assert compare(a, b) == 0 and not is_older(a, b) and not is_older(b, a)


@pytest.mark.parametrize("bad", ["", "-1", ".1", "a/b", "../x", "x" * 65, "1 2", "é", None, 3, "v2\n"])
def test_refuses_what_is_not_a_version(bad):
    with pytest.raises(VersionError, match="is not a bundle version") as e:
        parse_version(bad)
    assert "\n" not in str(e.value)


def test_newest_of_nothing():
    assert newest([]) is None


@settings(max_examples=300, deadline=None)
@given(versions, versions, versions)
def test_total_order(a, b, c):
    assert compare(a, b) == -compare(b, a)
    assert compare(a, a) == 0
    if compare(a, b) <= 0 and compare(b, c) <= 0:
        assert compare(a, c) <= 0
    pa, pb = parse_version(a), parse_version(b)
    assert (pa < pb) or (pb < pa) or a == b  # Version objects sort deterministically
    if compare(a, b) < 0:
        assert pa < pb


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 10**6), min_size=1, max_size=4), st.lists(st.integers(0, 10**6), min_size=1,
                                                                         max_size=4))
def test_dotted_numbers_order_like_integer_tuples(x, y):
    a, b = ".".join(map(str, x)), ".".join(map(str, y))
    assert compare(a, b) == (x > y) - (x < y)


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=80))
def test_any_text_parses_or_gives_one_line(text):
    try:
        v = parse_version(text)
    except VersionError as e:
        assert "\n" not in str(e)
    else:
        assert isinstance(v, Version) and v.raw == text
