"""A copy of a synthetic garment whose touches sit where they were pressed: the registration oracle.

The hard profile records each touch's rectangle off the pressed one by a registration error (synthetic.yaml's
`realism.registration_offsets_px`, recorded minus pressed corner, per touch in serial order), as marker tracking
does on a real capture. A model trained on the copy learns from touches that match the truth at their place, so the
difference it makes to the same recipe on the original is what perfect registration would be worth (docs/training.md,
"What registration is worth"). Everything but the touches' recorded corners is copied byte for byte.

    .venv/bin/python scripts/registered_copy.py data/hard640 DenimShorts data/registered
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer.data.synthetic import registration_offset  # noqa: E402
from trainer.data.touchclothing import DatasetError, find_garment  # noqa: E402

SPLITS = ("trainT", "valT", "testT")


def registered_copy(data: Path, name: str, out: Path) -> Path:
    try:
        src = find_garment(data, name)
    except DatasetError as exc:
        raise SystemExit(f"no garment {name} in {data}: {exc}") from exc
    meta_path = src / "synthetic.yaml"
    if not meta_path.is_file():
        raise SystemExit(f"{src.name}: not a synthetic garment (no synthetic.yaml): its registration is unknown")
    meta = yaml.safe_load(meta_path.read_text()) or {}
    offsets = (meta.get("realism") or {}).get("registration_offsets_px")
    if not isinstance(offsets, list):
        raise SystemExit(f"{src.name}: synthetic.yaml records no registration offsets (the easy profile has none)")
    return moved_copy(src, out, lambda stem: registration_offset(offsets, stem), SPLITS,
                      "moved back to where they were pressed")


def moved_copy(src: Path, out: Path, offset_of, splits=SPLITS, what: str = "moved") -> Path:
    """A copy of garment folder `src` under `out` whose touches of `splits` have their recorded corner moved by
    minus `offset_of(touch file stem)` (dx, dy), recorded minus pressed; everything else copied byte for byte."""
    dst = out / src.name
    if dst.resolve() == src.resolve():
        raise SystemExit(f"{dst}: the copy would overwrite its source")
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(src, dst)
    moved = 0
    for split in splits:
        for f in sorted((dst / split).glob("*_tactile.npz")):
            try:
                dx, dy = offset_of(f.stem)
            except ValueError as exc:
                raise SystemExit(str(exc)) from exc
            with np.load(f) as z:
                arrays = dict(z)
            arrays["vision_mask_x"] = np.asarray(int(arrays["vision_mask_x"]) - dx)
            arrays["vision_mask_y"] = np.asarray(int(arrays["vision_mask_y"]) - dy)
            np.savez_compressed(f, **arrays)
            moved += 1
    print(f"{dst}: {moved} touches {what}")
    return dst


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="dataset folder (e.g. data/hard640)")
    ap.add_argument("garment", help="garment name (e.g. DenimShorts)")
    ap.add_argument("out", type=Path, help="dataset folder to write the copy into")
    a = ap.parse_args(argv)
    registered_copy(a.data, a.garment, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
