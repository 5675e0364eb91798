"""One list of presets: the files in trainer/presets/ are what `vtkiosk train --help`, the README and
docs/training.md name, so adding or removing a preset file without the docs fails here."""
from __future__ import annotations

from pathlib import Path

from trainer.cli import build_parser
from trainer.config import PRESETS_DIR

ROOT = Path(__file__).resolve().parents[2]


def _presets() -> list[str]:
    names = sorted(f.stem for f in PRESETS_DIR.glob("*.yaml"))
    assert {"paper", "cpu", "demo", "tiny"} <= set(names), names
    return names


def test_help_names_every_preset_file():
    text = build_parser("vtkiosk train").format_help()
    assert all(p in text for p in _presets()), text


def test_readme_and_training_doc_name_every_preset_file():
    readme = next(line for line in (ROOT / "README.md").read_text().splitlines() if "`--preset` one of" in line)
    training = (ROOT / "docs" / "training.md").read_text().split("Presets (", 1)[1].split("\n\n", 1)[0]
    for p in _presets():
        assert f"`{p}`" in readme, (p, readme)
        assert f"- `{p}`:" in training, (p, training)
