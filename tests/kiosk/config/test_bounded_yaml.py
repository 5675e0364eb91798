"""Bounded YAML loading: any text gives a document or a one-line yaml.YAMLError, never RecursionError."""
from __future__ import annotations

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.config.loader import MAX_DEPTH, YAMLLimitError, safe_load


@pytest.mark.parametrize("text", ["[" * 2000 + "]" * 2000, "{a: " * 2000 + "1" + "}" * 2000,
                                  "".join(" " * i + "-\n" for i in range(700)) + " " * 700 + "1\n",
                                  "port: " + "9" * 5000])
def test_hostile_documents_are_a_one_line_yaml_error(text):
    with pytest.raises(YAMLLimitError) as e:
        safe_load(text)
    assert "\n" not in str(e.value) and len(str(e.value)) < 200


def test_normal_nesting_loads():
    doc = "a:\n" + "".join("  " * (i + 1) + f"k{i}:\n" for i in range(MAX_DEPTH - 3)) + "  " * (MAX_DEPTH - 1) + "x"
    assert safe_load(doc)["a"]["k0"]["k1"] is not None
    assert safe_load("[" * (MAX_DEPTH - 1) + "]" * (MAX_DEPTH - 1)) is not None
    with pytest.raises(YAMLLimitError):
        safe_load("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1))


@settings(max_examples=100, deadline=None)
@given(st.one_of(st.text(max_size=200), st.integers(1, 1500).map(lambda n: "[" * n + "]" * n),
                 st.integers(1, 6000).map(lambda n: "x: " + "7" * n)))
def test_any_text_gives_a_document_or_a_yaml_error(text):
    try:
        safe_load(text)
    except yaml.YAMLError:
        pass
