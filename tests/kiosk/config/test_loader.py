"""The one typed config loader: types, unknown and missing keys, overrides, paths; errors are one line naming
the key (and the file); firmware_bridge's copy stays byte-identical."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kiosk.config import loader

ROOT = Path(__file__).resolve().parents[3]


class Bad(Exception):
    user_facing = True


class Foreign(Exception):
    user_facing = True


@dataclass(frozen=True)
class Inner:
    rate: float = 1.0
    mode: Literal["fast", "slow"] = "fast"

    def __post_init__(self) -> None:
        if self.rate <= 0:
            raise Bad("inner.rate must be > 0")


@dataclass(frozen=True)
class Other:
    level: int = 1

    def __post_init__(self) -> None:
        if self.level > 9:
            raise Foreign("level must be at most 9")


def _hex(value):
    if isinstance(value, str):
        return int(value, 16)
    return value


@dataclass(frozen=True)
class Doc:
    name: str
    count: int = 2
    on: bool = False
    pair: tuple[float, float] = (0.0, 1.0)
    sizes: tuple[int, ...] = ()
    where: Path | None = None
    extra: dict[str, int] = field(default_factory=dict)
    code: int = field(default=0, metadata={"parse": _hex})
    inner: Inner = field(default_factory=Inner)
    other: Other = field(default_factory=Other)
    digest: str = field(default="", metadata={"internal": True})


def test_a_full_document_builds_typed_frozen_values(tmp_path):
    doc = {"name": "x", "count": 3, "on": True, "pair": [1, 2.5], "sizes": [256, 512], "where": "sub/f.bin",
           "extra": {"a": 1}, "code": "ff", "inner": {"rate": "1e-3", "mode": "slow"}, "other": None}
    cfg = loader.build(Doc, doc, error=Bad, base_dir=tmp_path)
    assert cfg == Doc("x", 3, True, (1.0, 2.5), (256, 512), tmp_path / "sub/f.bin", {"a": 1}, 255,
                      Inner(1e-3, "slow"), Other())
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.count = 4  # type: ignore[misc]
    assert loader.build(Doc, loader.to_mapping(cfg), error=Bad) == cfg


@pytest.mark.parametrize("doc, message", [
    ({"name": "x", "colour": 1}, r"unknown key\(s\): colour \(valid: name, count"),
    ({"name": "x", "inner": {"speed": 1}}, r"unknown key\(s\) in inner: speed"),
    ({"count": 1}, r"missing key\(s\): name"),
    ({"name": "x", "count": "two"}, "count must be an integer, got str 'two'"),
    ({"name": "x", "count": True}, "count must be an integer, got a boolean"),
    ({"name": "x", "on": "yes"}, "on must be true or false"),
    ({"name": "x", "pair": [1]}, "pair must be a list of 2 values"),
    ({"name": "x", "sizes": 5}, "sizes must be a list"),
    ({"name": "x", "sizes": [1, "b"]}, r"sizes\[1\] must be an integer"),
    ({"name": "x", "inner": {"rate": float("nan")}}, "inner.rate must be a finite number"),
    ({"name": "x", "inner": {"rate": "inf"}}, "inner.rate must be a finite number"),
    ({"name": "x", "inner": {"rate": -1}}, "inner.rate must be > 0"),
    ({"name": "x", "inner": {"mode": "warp"}}, "inner.mode must be one of fast, slow"),
    ({"name": "x", "inner": 3}, "inner must be a mapping, got int 3"),
    ({"name": "x", "where": 3}, "where must be a path"),
    ({"name": ""}, "name must be a non-empty string"),
    ({"name": "x", "extra": {"a": "b"}}, "extra.a must be an integer"),
    ({"name": "x", "code": "zz"}, "code invalid literal"),
    ({"name": "x", "other": {"level": 10}}, "other: level must be at most 9"),
    ({"name": "x", "digest": "abc"}, r"unknown key\(s\): digest"),
    ({"name": "x", "odd\nkey": 1}, r"unknown key\(s\): 'odd\\nkey' \(valid"),       # quoted: still one line
    ({"name": "x", "extra": {"a\nb": "z"}}, r"extra\.'a\\nb' must be an integer"),
    ([1, 2], "the top level must be a mapping"),
])
def test_errors_name_the_key_in_one_line(doc, message):
    with pytest.raises(Bad, match=message) as info:
        loader.build(Doc, doc, error=Bad, where="conf.yaml")
    assert str(info.value).startswith("conf.yaml: ") and "\n" not in str(info.value)


def test_files_errors_name_the_file(tmp_path):
    with pytest.raises(Bad, match="cannot read thing config .*missing.yaml"):
        loader.load(Doc, tmp_path / "missing.yaml", error=Bad, what="thing config")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed")
    with pytest.raises(Bad, match="bad.yaml: not valid YAML"):
        loader.load(Doc, bad, error=Bad)
    bad.write_text("- a\n")
    with pytest.raises(Bad, match="bad.yaml: the top level must be a mapping"):
        loader.load(Doc, bad, error=Bad)
    bad.write_bytes(b"\xff\xfe")
    with pytest.raises(Bad, match="not UTF-8"):
        loader.load(Doc, bad, error=Bad)
    good = tmp_path / "good.yaml"
    good.write_text("name: g\nwhere: data/x\ninner: {rate: 2}\n")
    cfg = loader.load(Doc, good, error=Bad, overrides={"inner": {"mode": "slow"}})
    assert cfg.where == tmp_path / "data/x" and cfg.inner == Inner(2.0, "slow")
    with pytest.raises(Bad, match=f"{good}: count must be an integer"):
        loader.load(Doc, good, error=Bad, overrides={"count": "x"})


def test_overrides_are_parsed_into_the_fields_type():
    got = loader.parse_overrides(Doc, ["count=7", "pair=0.5,0.9", "sizes=[256, 512]", "name=007", "where=none",
                                       "inner.rate=1e-4", "on=true", "code=1f"], error=Bad)
    assert got == {"count": 7, "pair": (0.5, 0.9), "sizes": (256, 512), "name": "007", "where": None,
                   "inner": {"rate": 1e-4}, "on": True, "code": 0x1f}
    assert loader.build(Doc, got, error=Bad).code == 0x1f
    for item, message in [("count", "must be section.key=value"), ("inner.speed=1", r"unknown key\(s\) in inner"),
                          ("count=abc", "--set count=abc: count must be an integer"),
                          ("inner=3", "inner is a section"), ("count.x=1", "count is a setting")]:
        with pytest.raises(Bad, match=message):
            loader.parse_overrides(Doc, [item], error=Bad)


scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                    st.text(max_size=8))
keys = st.sampled_from(["name", "count", "on", "pair", "sizes", "where", "extra", "code", "inner", "rate", "mode",
                        "other", "level", "digest", "x"])
documents = st.recursive(scalars, lambda c: st.one_of(st.lists(c, max_size=3), st.dictionaries(keys, c, max_size=5)),
                         max_leaves=15)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents)
def test_any_document_gives_a_config_or_one_clear_line(doc):
    try:
        cfg = loader.build(Doc, doc, error=Bad, where="f.yaml")
    except Bad as exc:
        assert str(exc).startswith("f.yaml: ") and "\n" not in str(exc)
    else:
        assert isinstance(cfg, Doc)


def test_firmware_bridge_carries_an_identical_copy():
    """firmware_bridge imports nothing of ours, so it has its own copy; the two must not drift."""
    ours = (ROOT / "kiosk" / "config" / "loader.py").read_bytes()
    theirs = (ROOT / "firmware_bridge" / "config_loader.py").read_bytes()
    assert ours == theirs, "firmware_bridge/config_loader.py differs from kiosk/config/loader.py; copy it over"
