"""The kiosk config: typed, strict, with errors an operator can act on (and nothing else escapes the parser)."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kiosk.service.config import ConfigError, KioskConfig, config_from_mapping, load_config

EXAMPLE = Path(__file__).resolve().parents[3] / "configs" / "kiosk.example.yaml"


def _write(tmp_path: Path, doc) -> Path:
    p = tmp_path / "kiosk.yaml"
    p.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc))
    return p


def test_example_config_loads_and_resolves_paths():
    cfg = load_config(EXAMPLE)
    assert isinstance(cfg, KioskConfig)
    assert cfg.server.host == "127.0.0.1"
    assert cfg.device.type == "emulated"
    assert cfg.store.root is not None and cfg.store.root.is_absolute()


def test_defaults_need_something_to_serve(tmp_path):
    with pytest.raises(ConfigError, match="no bundles to serve"):
        load_config(_write(tmp_path, {}))
    cfg = load_config(_write(tmp_path, {"bundles": ["a.vtb"]}))
    assert cfg.bundles == (tmp_path / "a.vtb",)  # relative to the config file's folder
    assert cfg.inference.threads == 2 and cfg.server.port == 8765 and not cfg.store.allow_unsigned


@pytest.mark.parametrize("doc, message", [
    ({"bundles": ["a"], "servr": {}}, "unknown key.*servr"),
    ({"bundles": ["a"], "server": {"prot": 1}}, "unknown key.*server.*prot"),
    ({"bundles": ["a"], "inference": {"threads": "two"}}, "inference.threads must be an integer"),
    ({"bundles": ["a"], "inference": {"threads": 0}}, "inference.threads must be an integer from 1"),
    ({"bundles": ["a"], "inference": {"max_resolution": 500}}, "multiple of 256"),
    ({"bundles": ["a"], "inference": {"preview_max_resolution": 1024, "max_resolution": 512}}, "must not exceed"),
    ({"bundles": ["a"], "inference": {"precisions": ["int4"]}}, "precisions"),
    ({"bundles": ["a"], "inference": {"provider": "tpu"}}, "provider"),
    ({"bundles": ["a"], "inference": {"quick_tactile": "never"}}, "inference.quick_tactile must be one of at-scale"),
    ({"bundles": ["a"], "inference": {"quick_tactile": 1}}, "inference.quick_tactile"),
    ({"bundles": ["a"], "inference": {"latency_budget_ms": float("nan")}}, "finite number"),
    ({"bundles": ["a"], "server": {"host": "0.0.0.0"}}, "not a loopback address"),
    ({"bundles": ["a"], "server": {"port": 70000}}, "server.port"),
    ({"bundles": ["a"], "server": {"allow_non_loopback": "yes"}}, "true or false"),
    ({"bundles": ["a"], "device": {"type": "serial"}}, "device: type must be one of"),
    ({"bundles": ["a"], "device": {"bogus": 1}}, r"unknown key\(s\) in device: bogus"),
    ({"bundles": ["a"], "device": []}, "device must be a mapping"),
    ({"bundles": "a.vtb"}, "bundles must be a list"),
    ({"bundles": [3]}, r"bundles\[0\] must be a path"),
    ({"bundles": ["a"], "health": {"stale_after_s": -1}}, "health.stale_after_s"),
    ({"bundles": ["a"], "log_level": "LOUD"}, "log_level"),
    ({"bundles": ["a"], "inference": None, "server": 5}, "server must be a mapping"),
    ({"bundles": ["a"], "page": {"idle_timeout_s": 0}}, "page.idle_timeout_s must be from 0.5"),
    ({"bundles": ["a"], "page": {"idle_timeout_s": float("inf")}}, "page.idle_timeout_s must be a finite number"),
    ({"bundles": ["a"], "page": {"attract_garment_s": 1}}, "page.attract_garment_s"),
    ({"bundles": ["a"], "page": {"tap_max_px": -1}}, "page.tap_max_px"),
    ({"bundles": ["a"], "page": {"auto_feel": "yes"}}, "page.auto_feel must be true or false"),
    ({"bundles": ["a"], "page": {"texts": {"titel": "Hi"}}}, "unknown key.*page.texts.*titel"),
    ({"bundles": ["a"], "page": {"texts": {"title": ""}}}, "page.texts.title must be a non-empty string"),
    ({"bundles": ["a"], "page": {"texts": {"title": "a\nb"}}}, "page.texts.title must be one line"),
    ({"bundles": ["a"], "page": {"texts": {"hint_feel": "x" * 201}}}, "page.texts.hint_feel must be one line of at"),
])
def test_bad_configs_name_the_key(tmp_path, doc, message):
    with pytest.raises(ConfigError, match=message) as info:
        load_config(_write(tmp_path, doc))
    assert str(tmp_path / "kiosk.yaml") in str(info.value)  # the operator learns which file
    assert info.value.user_facing


def test_non_loopback_only_when_allowed(tmp_path):
    cfg = load_config(_write(tmp_path, {"bundles": ["a"], "server": {"host": "0.0.0.0", "allow_non_loopback": True}}))
    assert cfg.server.host == "0.0.0.0"
    for host in ("127.0.0.1", "127.3.4.5", "::1", "localhost"):
        assert load_config(_write(tmp_path, {"bundles": ["a"], "server": {"host": host}})).server.host == host


def test_unreadable_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.yaml")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(_write(tmp_path, "server: [unclosed"))
    with pytest.raises(ConfigError, match="must be a mapping of sections"):
        load_config(_write(tmp_path, "- a\n- b\n"))
    p = tmp_path / "bin.yaml"
    p.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="not UTF-8"):
        load_config(p)


def test_page_section_defaults_and_overrides(tmp_path):
    cfg = load_config(_write(tmp_path, {"bundles": ["a"]}))
    assert cfg.page.idle_timeout_s == 90.0 and cfg.page.auto_feel and cfg.page.texts.draw == "Draw"
    cfg = load_config(_write(tmp_path, {"bundles": ["a"], "page": {"idle_timeout_s": 30, "texts": {
        "feel": "Fühlen", "title": "Zeichnen. Sehen. Fühlen."}}}))
    assert cfg.page.idle_timeout_s == 30.0 and cfg.page.texts.feel == "Fühlen"
    assert cfg.page.texts.draw == "Draw"  # the texts not given keep their defaults
    doc = cfg.page.to_json()
    assert doc["texts"]["title"] == "Zeichnen. Sehen. Fühlen." and doc["idle_timeout_s"] == 30.0


def test_command_line_overrides_merge_by_section(tmp_path):
    path = _write(tmp_path, {"bundles": ["a"], "server": {"port": 9000}, "device": {"type": "hid", "vid": 4617}})
    cfg = load_config(path, {"server": {"host": "::1"}, "device": {"type": "emulated"}, "bundles": ["/b.vtb"]})
    assert cfg.server.port == 9000 and cfg.server.host == "::1"
    assert cfg.device.type == "emulated" and cfg.device.vid == 4617
    assert cfg.bundles == (Path("/b.vtb"),)
    assert load_config(None, {"bundles": ["/x.vtb"]}).bundles == (Path("/x.vtb"),)


# -- property: whatever the YAML says, the parser answers with a config or a ConfigError ------------------------------
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                    st.text(max_size=12))
keys = st.sampled_from(["server", "store", "bundles", "device", "inference", "health", "control", "debug", "page",
                        "texts", "idle_timeout_s", "title",
                        "state_dir", "log_level", "host", "port", "threads", "type", "root", "precisions",
                        "max_resolution", "allow_non_loopback", "emulator", "faults", "x"])
documents = st.recursive(scalars, lambda children: st.one_of(st.lists(children, max_size=4),
                                                             st.dictionaries(keys, children, max_size=5)),
                         max_leaves=20)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents)
def test_any_document_gives_a_config_or_a_clear_error(doc):
    try:
        cfg = config_from_mapping(doc)
    except ConfigError as exc:
        assert str(exc) and "\n" not in str(exc)
    else:
        assert isinstance(cfg, KioskConfig)


@settings(max_examples=200, deadline=None)
@given(section=st.sampled_from(["server", "inference", "health", "store", "debug", "page"]),
       key=st.sampled_from(["port", "threads", "host", "stale_after_s", "allow_unsigned", "max_resolution",
                            "fault_injection", "latency_budget_ms", "cache_mb", "margin_px", "idle_timeout_s",
                            "tap_max_px", "texts", "auto_feel", "quick_tactile"]),
       value=scalars)
def test_mutated_valid_config_gives_a_config_or_a_clear_error(section, key, value):
    doc = {"bundles": ["/a.vtb"], section: {key: value}}
    try:
        config_from_mapping(doc)
    except ConfigError as exc:
        assert str(exc)


def test_panel_defaults_to_the_known_tanvastouch_panel():
    cfg = config_from_mapping({"bundles": ["g.vtb"]})
    assert cfg.panel.model == "tanvastouch-10.1"
    assert cfg.panel.pitch_mm == pytest.approx(0.1696, abs=5e-4)  # 10.1-inch 16:10 diagonal over 1280 px
    assert "not read from a vendor datasheet" in cfg.panel.describe()["source"]


def test_panel_stated_in_mm_overrides_the_table():
    cfg = config_from_mapping({"bundles": ["g.vtb"], "panel": {"model": None, "width_mm": 320.0,
                                                               "height_mm": 200.0, "width_px": 1280,
                                                               "height_px": 800}})
    assert cfg.panel.pitch_mm == pytest.approx(0.25) and cfg.panel.describe()["source"] == "kiosk config"


@pytest.mark.parametrize("panel, message", [
    ({"model": "tanvas-99"}, "not a known panel"),
    ({"model": None, "width_mm": 300.0}, "panel.height_mm is needed"),
    ({"width_mm": 300.0}, "not square"),
    ({"model": None, "width_mm": 2.0, "height_mm": 1.0, "width_px": 100, "height_px": 50}, "from 10 to 5000"),
    ({"width_mm": "wide"}, "panel.width_mm must be a finite number"),
])
def test_bad_panels_name_the_key(panel, message):
    with pytest.raises(ConfigError, match=message):
        config_from_mapping({"bundles": ["g.vtb"], "panel": panel})


def test_inference_engine_type_is_checked():
    assert config_from_mapping({"inference": {"engine": {"type": "auto"}}, "bundles": ["x.vtb"]}).inference.engine \
        .type == "auto"
    assert KioskConfig(bundles=(Path("x.vtb"),)).inference.engine.type == "onnxruntime"
    with pytest.raises(ConfigError, match="inference.engine.type"):
        config_from_mapping({"inference": {"engine": {"type": "tensorrt"}}, "bundles": ["x.vtb"]})
    with pytest.raises(ConfigError, match="inference.engine.auto_runs"):
        config_from_mapping({"inference": {"engine": {"type": "auto", "auto_runs": 0}}, "bundles": ["x.vtb"]})
