"""The thread and session keys of the kiosk config: defaults, one-line errors for bad values, and what reaches
the engines."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.inference.sessions import SessionSettings
from kiosk.service.config import ConfigError, KioskConfig, config_from_mapping


def _cfg(inference: dict) -> KioskConfig:
    return config_from_mapping({"bundles": ["g.vtb"], "inference": inference})


def test_defaults_are_the_measured_ones():
    inf = _cfg({}).inference
    assert inf.threads == 2 and inf.preview_threads == 1
    assert inf.session_settings() == SessionSettings(threads=2)  # arena and memory pattern on, sequential, 1 stream


def test_keys_reach_the_session_settings():
    inf = _cfg({"threads": 1, "preview_threads": 0,
                "engine": {"onnxruntime": {"mem_arena": False, "mem_pattern": False, "execution_mode": "parallel"},
                           "openvino": {"streams": 2, "hint": "throughput"}}}).inference
    assert inf.preview_threads == 0
    assert inf.session_settings() == SessionSettings(threads=1, mem_arena=False, mem_pattern=False,
                                                     execution_mode="parallel", streams=2, hint="throughput")


@pytest.mark.parametrize("inference, message", [
    ({"preview_threads": -1}, "inference.preview_threads must be an integer from 0"),
    ({"preview_threads": 65}, "inference.preview_threads must be an integer from 0"),
    ({"preview_threads": "one"}, "inference.preview_threads must be an integer"),
    ({"preview_threads": True}, "inference.preview_threads must be an integer"),
    ({"engine": {"onnxruntime": {"execution_mode": "fast"}}}, "inference.engine.onnxruntime.execution_mode"),
    ({"engine": {"onnxruntime": {"mem_arena": "yes"}}}, "true or false"),
    ({"engine": {"onnxruntime": {"arena": True}}}, "unknown key.*arena"),
    ({"engine": {"openvino": {"streams": 0}}}, "inference.engine.openvino.streams must be an integer from 1"),
    ({"engine": {"openvino": {"streams": 17}}}, "inference.engine.openvino.streams"),
    ({"engine": {"openvino": {"hint": "speed"}}}, "inference.engine.openvino.hint must be one of"),
])
def test_bad_values_give_one_line(inference, message):
    with pytest.raises(ConfigError, match=message) as err:
        _cfg(inference)
    assert "\n" not in str(err.value)


def test_a_bad_value_in_a_file_names_the_file(tmp_path):
    from kiosk.service.config import load_config

    p = tmp_path / "kiosk.yaml"
    p.write_text("bundles: [g.vtb]\ninference:\n  engine:\n    openvino: {hint: fastest}\n")
    with pytest.raises(ConfigError, match="kiosk.yaml.*inference.engine.openvino.hint") as err:
        load_config(p)
    assert "\n" not in str(err.value)


values = st.one_of(st.none(), st.booleans(), st.integers(-5, 100), st.floats(allow_nan=True),
                   st.text(max_size=12), st.sampled_from(["sequential", "parallel", "latency", "throughput"]),
                   st.lists(st.integers(), max_size=2), st.dictionaries(st.text(max_size=5), st.integers(), max_size=2))


@settings(max_examples=300, deadline=None)
@given(where=st.sampled_from([("preview_threads",), ("threads",), ("engine", "onnxruntime", "mem_arena"),
                              ("engine", "onnxruntime", "mem_pattern"), ("engine", "onnxruntime", "execution_mode"),
                              ("engine", "openvino", "streams"), ("engine", "openvino", "hint"),
                              ("engine", "onnxruntime"), ("engine", "openvino")]),
       value=values)
def test_any_value_gives_settings_or_a_one_line_error(where, value):
    doc: dict = {}
    node = doc
    for key in where[:-1]:
        node = node.setdefault(key, {})
    node[where[-1]] = value
    try:
        inf = _cfg(doc).inference
    except ConfigError as exc:
        assert str(exc) and "\n" not in str(exc)
    else:
        s = inf.session_settings()  # a config that loads always gives valid engine settings
        assert 0 <= inf.preview_threads <= 64 and 1 <= s.threads <= 64 and 1 <= s.streams <= 16
