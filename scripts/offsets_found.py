"""Does a trained model say where each training touch was pressed? Its relief matched with every touch at each
shift within a radius, against the offsets the synthetic garment recorded.

The hard profile records each touch a pixel or two from where it was pressed (synthetic.yaml's
`realism.registration_offsets_px`, recorded minus pressed corner). A model whose relief is the consensus of its
touches should match each touch best where it was pressed: at shift = -offset. This scores that, per touch, for
each run given, beside two references: `truth` (the full-field truth in place of a model: what the touch itself
allows, under its sensor's blur and noise) and `recorded` (shift 0 for every touch: right only where the offset is
0). `--split val` or `test` asks the same of touches the model never trained on: whether its relief off the
training touches is sharp enough to place a touch. docs/training.md, "Registration-tolerant touches".

    .venv/bin/python scripts/offsets_found.py data/hard640 SatinShirt runs/s69/SatinShirt/ours-txs-s8 \
        --radius 2 --json docs/compare_1k/offsets_found/SatinShirt.json
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer.augment import eval_crop_origin  # noqa: E402
from trainer.data.synthetic import registration_offset  # noqa: E402
from trainer.data.touchclothing import DatasetError, Garment, find_garment, load_garment  # noqa: E402
from trainer.recipe.registration import shifts  # noqa: E402


def recorded_offsets(g: Garment) -> list[tuple[int, int]]:
    meta = g.root / "synthetic.yaml"
    realism = ((yaml.safe_load(meta.read_text()) if meta.is_file() else None) or {}).get("realism") or {}
    offsets = realism.get("registration_offsets_px")
    if not isinstance(offsets, list):
        raise SystemExit(f"{g.name}: no recorded registration offsets (not a hard-profile synthetic garment)")
    return [(int(dx), int(dy)) for dx, dy in offsets]


def best_shifts(relief: tuple[np.ndarray, np.ndarray], origin: tuple[int, int], g: Garment, radius: int,
                split: str = "train") -> dict[str, tuple[int, int]]:
    """Per touch of `split` whose rectangle, moved by up to `radius`, lies inside `relief` (gx, gy over a crop at
    `origin` of the padded frame): the (dx, dy) at which |relief - touch| over its contact pixels is lowest."""
    gx, gy = relief
    side_y, side_x = gx.shape
    tried = shifts(radius)
    out = {}
    for t in g.touches.get(split, []):
        r = t.rect
        x, y = r.x - origin[0], r.y - origin[1]
        if x - radius < 0 or y - radius < 0 or x + r.w + radius > side_x or y + r.h + radius > side_y:
            continue
        if not t.contact.any():
            continue
        cost = []
        for dx, dy in tried:
            win = np.s_[y + dy:y + dy + r.h, x + dx:x + dx + r.w]
            cost.append(np.abs(gx[win] - t.gx)[t.contact].mean() + np.abs(gy[win] - t.gy)[t.contact].mean())
        out[t.name] = tried[int(np.argmin(cost))]
    return out


def score(found: dict[str, tuple[int, int]], offsets: list[tuple[int, int]]) -> dict:
    """Hits (the shift is exactly -offset), the mean distance left between where the touch is then placed and where
    it was pressed, and the same distance for the recorded corner."""
    if not found:
        raise SystemExit("no touch of the split lies inside the crop with room for the shifts")
    left, before, hits = [], [], 0
    for name, (dx, dy) in found.items():
        try:
            ox, oy = registration_offset(offsets, name)
        except ValueError as exc:
            raise SystemExit(str(exc)) from exc
        hits += (dx, dy) == (-ox, -oy)
        left.append(np.hypot(dx + ox, dy + oy))
        before.append(np.hypot(ox, oy))
    return {"touches": len(found), "hits": hits, "hit_rate": round(hits / len(found), 3),
            "mean_px_left": round(float(np.mean(left)), 3), "mean_px_recorded": round(float(np.mean(before)), 3)}


def model_relief(run: Path, which: str, g: Garment) -> tuple[tuple[np.ndarray, np.ndarray], tuple[int, int]]:
    """A run's relief (gx, gy) on its evaluation crop of `g`, and the crop's corner in the padded frame."""
    import torch

    from trainer.checkpoint import load_generator, read_checkpoint
    from trainer.config import config_from_dict
    from trainer.sampling import crop_tensors
    trained_on = Path(config_from_dict(read_checkpoint(run, which)["config"]).garment).name
    if trained_on != g.name:
        raise SystemExit(f"{run}: trained on {trained_on}, not {g.name}")
    net, info = load_generator(run, which)
    side = int(info["crop"])
    origin = eval_crop_origin(g.mask, side)
    sk, mk, _ = crop_tensors(g, origin, side)
    with torch.no_grad():
        _, tac = net(sk, mk)
    t = tac[0].numpy()
    return (t[0], t[1]), origin


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="dataset folder (e.g. data/hard640)")
    ap.add_argument("garment", help="garment name (e.g. SatinShirt)")
    ap.add_argument("runs", nargs="*", type=Path, help="run folders trained on this garment")
    ap.add_argument("--radius", type=int, default=2, help="largest shift tried per axis, px (2)")
    ap.add_argument("--which", default="latest", help="checkpoint: latest or best (latest)")
    ap.add_argument("--split", choices=("train", "val", "test"), default="train",
                    help="whose touches to place (train: those the model learnt from)")
    ap.add_argument("--json", type=Path, help="write the rows here")
    a = ap.parse_args(argv)
    if not 1 <= a.radius <= 8:
        raise SystemExit(f"--radius is 1..8 px; got {a.radius}")
    try:
        g = load_garment(find_garment(a.data, a.garment))
    except DatasetError as exc:
        raise SystemExit(f"no garment {a.garment} in {a.data}: {exc}") from exc
    if g.full_tactile is None:
        raise SystemExit(f"{g.name}: no full-field truth to place the touches against")
    offsets = recorded_offsets(g)
    found_truth = best_shifts((g.full_tactile.gx, g.full_tactile.gy), (0, 0), g, a.radius, a.split)   # whole frame
    rows = {"recorded": score({k: (0, 0) for k in found_truth}, offsets), "truth": score(found_truth, offsets)}
    for run in a.runs:
        relief, run_origin = model_relief(run, a.which, g)
        rows[f"{run.parent.name}/{run.name}"] = score(best_shifts(relief, run_origin, g, a.radius, a.split), offsets)
    print(f"{g.name}: {a.split} touches placed by the best shift within {a.radius} px")
    print(f"{'row':<34} {'touches':>7} {'hits':>5} {'px left':>8} {'px recorded':>11}")
    for name, r in rows.items():
        print(f"{name:<34} {r['touches']:>7} {r['hits']:>5} {r['mean_px_left']:>8.3f} {r['mean_px_recorded']:>11.3f}")
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"garment": g.name, "split": a.split, "radius": a.radius, "which": a.which,
                                      "rows": rows},
                                     indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
