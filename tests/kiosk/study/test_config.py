"""Study config: every field typed and checked, errors name the key; participant codes are codes."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from kiosk.study.config import ParticipantError, Participants, StudyConfigError, load_study_config

from .helpers import study_doc, write_config


def test_loads_and_resolves_paths(tmp_path):
    cfg = load_study_config(write_config(tmp_path))
    assert cfg.id == "haptic-ab-test" and cfg.reference == "ours"
    assert cfg.comparisons == ("pix2pix", "pix2pixhd")           # default: every other condition, config order
    assert cfg.bundle_path("pix2pix", "g03") == tmp_path / "bundles/pix2pix/g03.vtb"
    assert cfg.log == tmp_path / "study.jsonl"
    assert cfg.test_pool == ("g01", "g02", "g03", "g04", "g05", "g06")
    assert cfg.time_limit_s == 60.0 and cfg.warmup_trials == 1
    assert len(cfg.source_sha256) == 64


def test_explicit_mapping_and_comparisons(tmp_path):
    doc = study_doc(conditions={"ours": "o/{garment}.vtb", "abl": {f"g0{i}": f"/abs/a{i}.vtb" for i in range(7)},
                                "p2p": "p/{garment}.vtb"}, comparisons=["abl"])
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(doc))
    cfg = load_study_config(path)
    assert cfg.comparisons == ("abl",)
    assert cfg.bundle_path("abl", "g02") == Path("/abs/a2.vtb")


@pytest.mark.parametrize("change, message", [
    ({"colour": "red"}, "unknown key(s): colour"),
    ({"seed": "7"}, "seed must be an integer"),
    ({"seed": True}, "seed must be an integer, got a boolean"),
    ({"reference": "theirs"}, "reference 'theirs' is not one of the conditions"),
    ({"warmup_garment": "g99"}, "warmup_garment 'g99' is not in garments"),
    ({"garments": ["g00", "g00"]}, "garments lists a garment twice"),
    ({"garments": ["G 00"]}, "must be a lower-case id"),
    ({"test_garments": 7}, "test_garments must be between 1 and 6"),
    ({"test_garments": 0}, "test_garments must be between 1 and 6"),
    ({"time_limit_s": 0}, "time_limit_s must be between 1 and 3600"),
    ({"time_limit_s": "60s"}, "time_limit_s must be a finite number"),
    ({"question": " "}, "question must be non-empty"),
    ({"conditions": {"ours": "a/{garment}.vtb"}}, "at least two conditions"),
    ({"conditions": {"ours": "a/x.vtb", "p2p": "b/{garment}.vtb"}}, "must contain '{garment}'"),
    ({"conditions": {"ours": "a/{garment}.vtb", "p2p": {"g00": "x.vtb"}}}, "conditions.p2p has no bundle for"),
    ({"conditions": {"ours": "a/{garment}.vtb", "p2p": 3}}, "conditions.p2p must be a path template"),
    ({"comparisons": ["ours"]}, "must not include the reference"),
    ({"comparisons": ["nope"]}, "comparisons names 'nope'"),
    ({"comparisons": []}, "comparisons must list at least one"),
    ({"participants": {}}, "participants needs 'codes'"),
    ({"participants": {"pattern": "P[0-9"}}, "participants.pattern is not a valid regular expression"),
    ({"participants": {"codes": ["Jane Doe"]}}, "is not a code"),
    ({"participants": {"codes": ["P01"], "names": []}}, "unknown key(s) in participants: names"),
    ({"allow_unsigned": False}, "give trusted_keys"),
    ({"warmup_trials": -1}, "warmup_trials must be between 0 and 20"),
])
def test_bad_configs_name_the_problem(tmp_path, change, message):
    path = write_config(tmp_path, **change)
    with pytest.raises(StudyConfigError) as err:
        load_study_config(path)
    assert message in str(err.value)
    assert err.value.user_facing


def test_missing_keys_and_not_yaml(tmp_path):
    doc = study_doc()
    del doc["log"], doc["seed"]
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(StudyConfigError, match="missing key\\(s\\): log, seed"):
        load_study_config(tmp_path / "a.yaml")
    (tmp_path / "b.yaml").write_text("id: [unclosed")
    with pytest.raises(StudyConfigError, match="not valid YAML"):
        load_study_config(tmp_path / "b.yaml")
    (tmp_path / "c.yaml").write_text("- a list\n")
    with pytest.raises(StudyConfigError, match="top level must be a mapping"):
        load_study_config(tmp_path / "c.yaml")
    with pytest.raises(StudyConfigError, match="cannot read study config"):
        load_study_config(tmp_path / "missing.yaml")


def test_participant_codes():
    by_list = Participants(codes=("P01", "P02"))
    assert by_list.check("P01") == "P01"
    with pytest.raises(ParticipantError, match="not on this study's list"):
        by_list.check("P03")
    by_pattern = Participants(pattern="P[0-9]{2}")
    assert by_pattern.check("P42") == "P42"
    for bad in ("P4", "P420", "p42"):
        with pytest.raises(ParticipantError, match="does not match"):
            by_pattern.check(bad)
    for bad in ("", "Jane Doe", "a" * 33, "../x", "P01\n", None, 7):
        with pytest.raises(ParticipantError, match="a code, not a name"):
            by_pattern.check(bad)


def test_the_example_config_is_valid():
    from kiosk.service.config import config_from_mapping

    root = Path(__file__).resolve().parents[3]
    cfg = load_study_config(root / "configs" / "study.example.yaml")
    assert cfg.reference == "ours" and cfg.comparisons == ("pix2pix", "pix2pixhd", "gaugan")
    assert cfg.test_garments == 5 and cfg.time_limit_s == 60.0
    kiosk = config_from_mapping({**cfg.kiosk, "bundles": ["x.vtb"]})
    assert kiosk.control.group == "vtkiosk-ops"
