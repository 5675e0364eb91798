"""Method registry (pix2pix-style `--model X`): a method name -> the class in its own file, imported lazily."""
from __future__ import annotations

import importlib

from trainer.errors import TrainerError

METHODS: dict[str, str] = {
    "ours": "trainer.methods.ours:Ours",
    "pix2pix": "trainer.methods.pix2pix:Pix2Pix",
    "pix2pixhd": "trainer.methods.pix2pixhd:Pix2PixHD",
    "gaugan": "trainer.methods.gaugan:GauGAN",
    "pix2pix-joint-d": "trainer.methods.pix2pix_joint_d:Pix2PixJointD",
    "ours-no-gan": "trainer.methods.ours_no_gan:OursNoGAN",
    "ours-no-rec": "trainer.methods.ours_no_rec:OursNoRec",
    "no-visual-gan": "trainer.methods.no_visual_gan:NoVisualGAN",
    "no-tactile-gan": "trainer.methods.no_tactile_gan:NoTactileGAN",
    "no-visual-rec": "trainer.methods.no_visual_rec:NoVisualRec",
    "no-tactile-rec": "trainer.methods.no_tactile_rec:NoTactileRec",
}


class UnknownMethod(TrainerError):
    pass


def get_method(name: str):
    if name not in METHODS:
        raise UnknownMethod(f"unknown method {name!r}; choose one of {', '.join(METHODS)}")
    module, cls = METHODS[name].split(":")
    return getattr(importlib.import_module(module), cls)
