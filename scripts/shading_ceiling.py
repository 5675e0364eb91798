"""How much of a garment's photo the photometric tactile loss could ever explain: its `unexplained` share (per fine
band, trainer/recipe/shading.py) for the full-field true relief, for the truth without its weave (the shape-oracle's
low-pass), and for no relief, on the whole frame.

Why: the loss pulls the relief toward whatever linear mix of slopes best accounts for the photo's fine bands; the
part of those bands that even the true relief leaves unexplained (the weave's colour, prints, dye, the sheen) is a
floor no model can go under, and what a run's logged `t_shade` reaches reads against it.

    .venv/bin/python scripts/shading_ceiling.py data/hard640 KnitJacket SatinShirt CorduroyTrousers DenimShorts
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from trainer.data.touchclothing import load_garment  # noqa: E402
from trainer.models.shading_relief import BANDS, blur  # noqa: E402
from trainer.recipe.shading import unexplained  # noqa: E402
from trainer.references import WEAVE_CUTOFF, weave_period_px  # noqa: E402


def ceiling(folder: Path) -> dict[str, list[float]]:
    g = load_garment(folder)
    if g.visual is None or g.full_tactile is None:
        raise SystemExit(f"{folder.name}: needs a photo and full-field tactile truth (a synthetic garment)")
    vis = torch.from_numpy(np.asarray(g.visual, np.float32) / 127.5 - 1).permute(2, 0, 1)[None]
    m = torch.from_numpy(g.mask.astype(np.float32))[None, None]
    truth = torch.from_numpy(np.stack([g.full_tactile.gx, g.full_tactile.gy]).astype(np.float32))[None]
    period = weave_period_px(g)
    if period is None:
        raise SystemExit(f"{folder.name}: states no weave period, so there is no shape-oracle to compare")
    s = WEAVE_CUTOFF * period
    shape = torch.cat([blur(truth[:, i:i + 1], s) for i in range(2)], 1)
    return {name: [round(x, 3) for x in unexplained(rel, vis, m)[0].tolist()]
            for name, rel in (("truth", truth), ("truth without weave", shape), ("flat", torch.zeros_like(truth)))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="a synthetic dataset folder (vtkiosk data synth)")
    ap.add_argument("garments", nargs="+", help="garment names (the CamelCase material of the folder)")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    bands = ", ".join(f"{b[0]}-{b[1]} px" for b in BANDS)
    print(f"unexplained share of the photo's fine bands ({bands}); 0 = all explained, 1 = none")
    for name in a.garments:
        found = sorted(a.data.glob(f"*_{name}_*"))
        if not found:
            print(f"{name}: no garment folder under {a.data}", file=sys.stderr)
            return 2
        for row, vals in ceiling(found[0]).items():
            print(f"{name:18} {row:20} " + "  ".join(f"{v:.3f}" for v in vals))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
