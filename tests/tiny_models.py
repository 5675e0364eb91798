"""Real bundles of real methods at tiny size, made in-process: the synthetic set, the trainer's own runs, the
exporter's fp32 graphs at the contract's 256 grid, signed. In-process because a `vtkiosk train` child per run pays
Python's and torch's start-up again each time; training and export are the same code either way.

A run is either trained (`steps` >= 1, the trainer's loop) or the generator as the trainer builds and checkpoints it
before its first step (`steps=0`): same method, architecture, data, friction calibration and reference assets, so
its bundle exercises everything the exporter and the kiosk do with that method; only the weights are untrained.
"""
from __future__ import annotations

from pathlib import Path

SYNTH_FRAME = (320, 240)


def synthetic_set(out: Path, garments: int) -> list[Path]:
    """The default synthetic set's first `garments` garments (every fabric from six on), at a 320x240 frame."""
    from trainer.data.synthetic import generate_dataset
    return generate_dataset(out, garments=garments, seed=0, frame=SYNTH_FRAME, progress=False)


def tiny_run(garment_dir: Path, method: str, out: Path, *, steps: int) -> Path:
    """A `tiny`-preset run of `method` on one garment folder, single-threaded; `steps=0`: checkpoint the initialised
    generator as `best` and `latest` without training."""
    from trainer.config import load_config
    from trainer.loop import Trainer
    cfg = load_config("tiny", method=method, overrides=[f"train.steps={max(steps, 1)}", "train.threads=1"])
    trainer = Trainer(cfg, garment_dir, out)
    if steps:
        trainer.run()
    else:
        trainer.save("latest")
        trainer.save("best")
    return out


def keypair(folder: Path) -> tuple[Path, Path]:
    """(signing key, trusted-keys folder holding its public half)."""
    from exporter.keys import generate_keypair
    keys, trusted = folder / "keys", folder / "trusted"
    generate_keypair(keys, "op")
    trusted.mkdir(parents=True, exist_ok=True)
    (trusted / "op.pub").write_bytes((keys / "op.pub").read_bytes())
    return keys / "op.key", trusted


def tiny_bundle(run: Path, out: Path, signing_key: Path):
    """Export `run` to a signed fp32 bundle at 256x256; returns the exporter's report."""
    from exporter.export import ExportConfig, export_run
    from exporter.keys import load_private_key
    return export_run(run, out, ExportConfig(precision="fp32", sizes=[(256, 256)], which="latest"),
                      signing_key=load_private_key(signing_key), progress=lambda *_: None)
