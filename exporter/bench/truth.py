"""Full-field ground truth for the benchmark: synthetic garments carry the true slopes over the whole garment
(`fullT/`), so the benchmark can put quantization error (int8 vs fp32) beside model error (fp32 vs truth).

Two ways to put a garment on a canvas of the benchmarked size, both at the training pixel pitch (what the model
learned; the kiosk's planner infers at that pitch too):
- `garment_truth`: the garment itself, cropped around the object like `trainer/evaluate.py` does when the canvas is
  smaller than the padded frame, padded with paper when larger. At the training crop size this is exactly the
  evaluation crop of `vtkiosk eval`; at larger sizes most of the canvas is blank paper the model never saw.
- `filled_truth`: the same garment (spec, seed, profile) synthesised again on a camera frame the size of the canvas,
  so the garment fills the canvas as a shopper's drawing fills a large panel: same cloth at the same pitch, a larger
  garment. This is what the kiosk computes at that grid size, and the canvas the benchmark's GT columns use.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

import yaml

from kiosk.contract.sketch import PAPER, NetworkInput, network_input


@dataclass(frozen=True)
class Truth:
    """Network input and true slopes on one canvas. Shape: gx, gy, mask (height, width)."""

    input: NetworkInput
    gx: np.ndarray
    gy: np.ndarray
    mask: np.ndarray


def _axis(bbox: tuple[int, int], padded: int, side: int) -> tuple[int, int, int] | None:
    """(source start, canvas start, length) along one axis; None when the object does not fit the canvas."""
    if side >= padded:
        return 0, (side - padded) // 2, padded
    lo, hi = max(0, bbox[1] - side), min(padded - side, bbox[0])
    if lo > hi:
        return None
    return int(np.clip((padded - side) // 2, lo, hi)), 0, side


def garment_truth(garment_dir: Path, size: tuple[int, int]) -> Truth | None:
    """The garment's ground truth on a `size` = (width, height) canvas, or None when it has no `fullT/` or the
    object does not fit. Needs the trainer's dataset reader."""
    from trainer.data.touchclothing import load_garment

    g = load_garment(Path(garment_dir))
    ft = g.full_tactile
    if ft is None:
        return None
    ys, xs = np.nonzero(g.mask)
    if len(xs) == 0:
        return None
    w, h = size
    ax = _axis((int(xs.min()), int(xs.max()) + 1), g.padded_size, w)
    ay = _axis((int(ys.min()), int(ys.max()) + 1), g.padded_size, h)
    if ax is None or ay is None:
        return None

    def place(a: np.ndarray, fill) -> np.ndarray:
        out = np.full((h, w), fill, a.dtype)
        (sx, dx, nx), (sy, dy, ny) = ax, ay
        out[dy:dy + ny, dx:dx + nx] = a[sy:sy + ny, sx:sx + nx]
        return out

    mask = place(g.mask, False)
    sketch = place(g.sketch, PAPER)
    return Truth(network_input(sketch, mask), place(ft.gx, np.float32(0)), place(ft.gy, np.float32(0)), mask)


def field_errors(tactile: np.ndarray, truth: Truth, friction_scale: float) -> dict[str, float]:
    """Full-field angular error (degrees) and friction-map MAE (levels) of a (1, 2, H, W) tactile output vs truth,
    over the object mask (`trainer.metrics.full_field_metrics`, the same numbers `vtkiosk eval` reports)."""
    from trainer.metrics import full_field_metrics

    return full_field_metrics(tactile[0, 0], tactile[0, 1], truth.gx, truth.gy, truth.mask, friction_scale)


def filled_truth(garment_dir: Path, size: tuple[int, int], workdir: Path) -> Truth | None:
    """Ground truth of the synthetic garment at `garment_dir`, re-synthesised on a `size` camera frame (written under
    `workdir`). None for a garment without `synthetic.yaml` or a frame the generator refuses (too tall)."""
    from trainer.data.synthetic import GarmentSpec, generate_garment

    desc_path = Path(garment_dir) / "synthetic.yaml"
    if not desc_path.is_file():
        return None
    desc = yaml.safe_load(desc_path.read_text())
    spec = GarmentSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in desc["spec"].items()})
    profile = desc.get("profile", "easy")  # the easy profile predates the key
    try:
        folder = generate_garment(Path(workdir) / f"{size[0]}x{size[1]}", spec, frame=size, profile=profile)
    except ValueError:
        return None
    return garment_truth(folder, size)
