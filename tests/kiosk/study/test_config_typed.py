"""The study config on the project's one loader: errors name the file and the key on one line, whatever the
document holds; the program's own fields (digest, folder) cannot be set by a file; a loaded config is frozen."""
from __future__ import annotations

import dataclasses

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kiosk.study.config import StudyConfigError, load_study_config

from .helpers import study_doc, write_config

SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                    st.text(max_size=12))
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                       st.dictionaries(st.text(max_size=8), inner, max_size=3)),
                      max_leaves=8)
KEYS = st.sampled_from(sorted(study_doc()) + ["comparisons", "question", "kind", "release", "consent",
                                                "demographics", "familiarisation", "kiosk_name", "kiosk",
                                                "time_limit_s", "timeout_notice_s", "instructions"])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=KEYS, value=VALUES)
def test_any_value_under_any_key_loads_or_is_one_line_naming_file_and_key(tmp_path, key, value):
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump({**study_doc(), key: value}))
    try:
        cfg = load_study_config(path)
    except StudyConfigError as exc:
        msg = str(exc)
        assert msg.startswith(f"{path}: ") and "\n" not in msg.strip() and len(msg) < 1200, msg
        assert exc.user_facing
        return
    assert cfg.conditions["ours"]["g01"].is_absolute() and cfg.release in ("each_trial", "new_garment", "none")
    assert cfg.time_limit_s is None or 1.0 <= cfg.time_limit_s <= 3600.0


@pytest.mark.parametrize("key", ["source_sha256", "base_dir"])
def test_the_programs_own_fields_cannot_come_from_a_file(tmp_path, key):
    with pytest.raises(StudyConfigError, match=f"unknown key\\(s\\): {key}"):
        load_study_config(write_config(tmp_path, **{key: "x"}))


def test_errors_name_the_file_and_the_nested_key(tmp_path):
    path = write_config(tmp_path, familiarisation={"screen_mm": [200, 100], "textures": [{"kind": "bump"}]})
    with pytest.raises(StudyConfigError) as err:
        load_study_config(path)
    assert str(err.value).startswith(f"{path}: familiarisation.textures[0]: diameter_mm must be a number")


def test_a_loaded_config_is_frozen_and_its_defaults_follow_its_kind(tmp_path):
    cfg = load_study_config(write_config(tmp_path, kind="visual"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.seed = 8  # type: ignore[misc]
    assert (cfg.release, cfg.comparisons) == ("none", ("pix2pix", "pix2pixhd"))
    assert dataclasses.replace(cfg, seed=8).conditions == cfg.conditions   # normalising twice changes nothing
