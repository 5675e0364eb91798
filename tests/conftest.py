"""Shared fixtures: small datasets the project generates itself (nothing is downloaded)."""
from __future__ import annotations

import os
from pathlib import Path

# The suite runs in two processes (pyproject's `-n auto --dist loadfile`) on a two-core machine; OpenMP's default
# spin-wait makes each process's torch threads burn the core the other needs (a 6 s test took 44 s). Passive waiting
# changes no number, only how idle threads wait; set before torch loads libgomp, and inherited by the workers.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import cv2
import numpy as np
import pytest

from tests.ci_skips import pytest_make_collect_report, pytest_runtest_makereport  # noqa: F401 - hooks

REAL_OFFSET = (260, 420)  # published: 1280x960 frame centred in 1800x1800


def field_gx(shape):
    """A known gradient field over the padded frame, so tests can check where patches were cut from."""
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
    return 0.1 * np.sin(x / 7.0) + 0.001 * y / 18.0, 0.1 * np.cos(y / 5.0) + 0.001 * x / 18.0


def write_real_layout(root: Path, material: str = "DenimToy", touches=(6, 2, 2), seed: int = 0) -> Path:
    """A tiny garment folder with the published names, sizes and npz keys (1800 px padded, 1280x960 frame)."""
    rng = np.random.default_rng(seed)
    g = root / f"singleskit_{material}_padded_1800_x1"
    p = 1800
    ox, oy = REAL_OFFSET
    mask = np.zeros((p, p), np.uint8)
    cv2.rectangle(mask, (ox + 300, oy + 200), (ox + 980, oy + 760), 255, -1)
    sketch = np.full((p, p), 255, np.uint8)
    cv2.rectangle(sketch, (ox + 300, oy + 200), (ox + 980, oy + 760), 0, 2)
    visual = np.full((p, p, 3), 200, np.uint8)
    visual[mask > 0] = (40, 60, 150)
    for prefix in ("train", "test"):
        for sub, img in (("S", sketch), ("M", mask), ("I", visual)):
            (g / f"{prefix}{sub}" / "nested").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(g / f"{prefix}{sub}" / "nested" / f"{material}.png"), img)
    gx_full, gy_full = field_gx((p, p))
    serial = 0
    for split, n in zip(("train", "val", "test"), touches):
        (g / f"{split}T").mkdir(parents=True, exist_ok=True)
        for _ in range(n):
            h, w = 104, 78
            x = int(rng.integers(300, 980 - w))  # unpadded camera pixels
            y = int(rng.integers(200, 760 - h))
            gx = gx_full[oy + y:oy + y + h, ox + x:ox + x + w]
            gy = gy_full[oy + y:oy + y + h, ox + x:ox + x + w]
            contact = np.zeros((h, w), np.uint8)
            contact[10:-10, 8:-8] = 255
            centres = np.zeros((h, w), np.uint8)
            centres[30:-30, 24:-24] = 255
            np.savez(g / f"{split}T" / f"{material.lower()}_{serial:04d}_tactile.npz",
                     gx_raw=gx.astype(np.float64), gy_raw=gy.astype(np.float64), vision_mask_x=x, vision_mask_y=y,
                     vision_mask_h=h, vision_mask_w=w, touch_thresh=contact, touch_center_thresh=centres)
            serial += 1
    return g


@pytest.fixture(scope="session")
def real_layout_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("touchclothing")
    write_real_layout(root)
    return root


@pytest.fixture(scope="session")
def hard_one(tmp_path_factory) -> Path:
    """A dataset folder with one hard-profile synthetic garment (320x240 frame): touches recorded off where they were
    pressed, full-field truth. Tests write their outputs elsewhere, so it is shared."""
    from trainer.data.synthetic import generate_dataset
    root = tmp_path_factory.mktemp("hard_one")
    generate_dataset(root, garments=1, seed=3, frame=(320, 240), progress=False, profile="hard")
    return root


@pytest.fixture(scope="session")
def hard_tiny_run(hard_one, tmp_path_factory) -> Path:
    """A 30-step tiny-preset run on the hard garment: what the photo-reading scripts' tests read. Shared, not
    written to."""
    from trainer.config import load_config
    from trainer.loop import Trainer
    out = tmp_path_factory.mktemp("hard_tiny") / "run"
    Trainer(load_config("tiny", overrides=["train.steps=30", "train.threads=1"]), next(
        p for p in hard_one.iterdir() if p.is_dir()), out).run()
    return out


@pytest.fixture(scope="session")
def easy_garment(tmp_path_factory):
    """One easy-profile synthetic garment (192x144 frame), loaded: its photo is Lambert shading of its touch field.
    The relief calibrations' tests read it and never write, so it is shared."""
    from trainer.data.synthetic import generate_dataset
    from trainer.data.touchclothing import load_garment
    root = tmp_path_factory.mktemp("easy_garment")
    generate_dataset(root, garments=1, seed=0, frame=(192, 144), progress=False, profile="easy")
    return load_garment(next(p for p in root.iterdir() if p.is_dir()))
