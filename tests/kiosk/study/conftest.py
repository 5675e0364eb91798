"""Fixtures: signed study bundles (real tiny ONNX graphs) and a study runtime on the real daemon."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from .helpers import study_doc
from .study_bundles import make_study_bundles

CONDITIONS = ["ours", "pix2pix", "pix2pixhd"]
GARMENTS = ["g00", "g01", "g02", "g03"]


@pytest.fixture(scope="session")
def study_env(tmp_path_factory) -> tuple[Path, Path]:
    """(folder holding bundles/<condition>/<garment>.vtb, trusted-keys folder)."""
    root = tmp_path_factory.mktemp("study-env")
    trusted = make_study_bundles(root, CONDITIONS, GARMENTS)
    return root, trusted


def write_study(folder: Path, env: tuple[Path, Path], name: str = "study", **overrides) -> Path:
    root, trusted = env
    folder.mkdir(parents=True, exist_ok=True)
    doc = study_doc(garments=GARMENTS, test_garments=3,
                    conditions={c: str(root / "bundles" / c / "{garment}.vtb") for c in CONDITIONS},
                    trusted_keys=str(trusted), allow_unsigned=False, log=f"{name}.jsonl",
                    # a generous probe budget: these tests check behaviour, not speed, on a shared 2-core box
                    kiosk={"server": {"port": 0}, "inference": {"latency_budget_ms": 5000}},
                    # trials follow each other at once unless a test asks for the operator's release
                    release="none", timeout_notice_s=0)
    doc.update(overrides)
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path
