"""Typed configs from YAML presets; errors name the key."""
from __future__ import annotations

import pytest
import yaml

from trainer.config import ConfigError, config_from_dict, load_config


@pytest.mark.parametrize("preset", ["paper", "cpu", "tiny"])
def test_presets_load_and_round_trip(preset, tmp_path):
    cfg = load_config(preset)
    assert cfg.preset == preset and cfg.data.crop % 256 == 0
    cfg.dump(tmp_path / "c.yaml")
    again = config_from_dict(yaml.safe_load((tmp_path / "c.yaml").read_text()))
    assert again == cfg


def test_paper_preset_is_the_published_schedule():
    cfg = load_config("paper")
    assert (cfg.data.crop, cfg.train.steps, cfg.data.patches, cfg.data.unpaired) == (1536, 81000, 64, 32)
    assert (cfg.optim.lr, cfg.optim.betas, cfg.optim.lr_tactile_d) == (1e-3, (0.0, 0.99), 5e-4)
    assert (cfg.loss.visual_l1, cfg.loss.tactile_gan, cfg.loss.tactile_l1) == (100, 5, 10)


def test_overrides_are_typed_and_unknown_keys_fail():
    cfg = load_config("cpu", overrides=["train.steps=7", "optim.betas=[0.5, 0.9]", "pretrained.vgg16=/x.pth"])
    assert cfg.train.steps == 7 and cfg.optim.betas == (0.5, 0.9) and cfg.pretrained.vgg16 == "/x.pth"
    with pytest.raises(ConfigError, match="train.stepz"):
        load_config("cpu", overrides=["train.stepz=7"])
    with pytest.raises(ConfigError, match="train.steps"):
        load_config("cpu", overrides=["train.steps=abc"])
    with pytest.raises(ConfigError, match="multiple of 256"):
        load_config("cpu", overrides=["data.crop=300"])
    with pytest.raises(ConfigError, match="no preset"):
        load_config("gpu-fast")
    with pytest.raises(ConfigError, match="model.tactile_mult must be >= 1"):
        load_config("cpu", overrides=["model.tactile_mult=0"])


def test_config_is_frozen_and_overrides_take_the_fields_type():
    import dataclasses

    cfg = load_config("tiny", overrides=["optim.betas=0.5,0.9", "train.deterministic=true", "model.d_norm=instance",
                                         "pretrained.vgg16=none", "optim.lr=2e-4"])
    assert cfg.optim.betas == (0.5, 0.9) and cfg.train.deterministic is True and cfg.model.d_norm == "instance"
    assert cfg.pretrained.vgg16 is None and cfg.optim.lr == 2e-4
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.train.steps = 3
    with pytest.raises(ConfigError, match="train.deterministic must be true or false"):
        load_config("tiny", overrides=["train.deterministic=maybe"])
    with pytest.raises(ConfigError, match="optim.betas must be a list"):
        load_config("tiny", overrides=["optim.betas=0.5"])


def test_recipe_differences_ignore_execution_keys_and_report_unknown_ones_apart():
    from trainer.recipe.identity import recipe_differences
    old = load_config("cpu").to_dict()
    new = load_config("cpu", overrides=["train.threads=1", "train.progress=false", "optim.lr=0.002"]).to_dict()
    new["garment"] = "/elsewhere/DenimShorts"
    assert recipe_differences(old, new) == (["optim.lr: 0.001 -> 0.002"], [])
    del old["loss"]["diffaug"]
    old["model"]["retired"] = 3
    changed, unknown = recipe_differences(old, new)
    assert unknown == ["loss.diffaug"] and "model.retired: 3 -> (no such key)" in changed
