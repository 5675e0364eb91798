"""Register a garment's training touches to its photo: where was each touch pressed, read from the photo alone?

The hard profile records each touch a pixel or two off where it was pressed (synthetic.yaml's
`realism.registration_offsets_px`, recorded minus pressed corner), as marker tracking does on a real capture, and
the touches moved back are worth 5-15 points of the gap (docs/training.md, "What registration is worth"). The photo
is in the frame the truth is in, so a touch whose slopes match the photo's shading best a pixel away was pressed
there. Alternating, a mix of the shading relief's filter bank (trainer/models/shading_relief.py) applied to the
photo's log-luminance is fitted to the training touches' slopes where they are placed now, and each touch is moved
to the offset within `--radius` where that relief matches it best (least squares after a gain of its own), until no
touch moves. The bank's filters are centred, so the mix cannot absorb a shift common to every touch. `--basis free`
fits every tap of a K x K window instead; that filter can absorb a common shift, so the offsets' rounded mean is
taken out each round (recording errors average to nothing, but not on ten touches: docs/training.md, "How far a
reading of the photo reaches"). Only the photo and the training touches are read: a real capture can be registered
the same way.

On a synthetic garment the estimates are scored against the recorded offsets (`hits`: exactly right; mean distance
left against the recorded corners'). `--write OUT` writes a copy of the garment whose training touches are moved by
the estimates (scripts/registered_copy.py's copy; the validation and test touches stay as recorded).

    .venv/bin/python scripts/photo_registration.py data/hard640 KnitJacket --write data/photo_registered
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from offsets_found import score  # noqa: E402
from registered_copy import moved_copy  # noqa: E402

from trainer.data.synthetic import registration_offset  # noqa: E402
from trainer.data.touchclothing import DatasetError, Garment, find_garment, load_garment  # noqa: E402
from trainer.models.shading_relief import filter_bank, log_luminance  # noqa: E402
from trainer.recipe.registration import shifts  # noqa: E402

RIDGE = 1e-3       # per sample, on columns scaled to unit SD: the touches' pixels far outnumber the taps
BASES = ("bank", "free")
MIN_TOUCHES = 4    # fewer cannot pin the common shift, nor fit a filter worth moving a touch for


class Touch(NamedTuple):
    name: str
    y: np.ndarray     # contact pixels, padded frame, where recorded
    x: np.ndarray
    gx: np.ndarray
    gy: np.ndarray


def photo_luminance(g: Garment) -> np.ndarray:
    """(P, P) float64: the photo's log-luminance over the object, the background filled from it."""
    if g.visual is None:
        raise SystemExit(f"{g.name}: no photo to register the touches to")
    vis = torch.from_numpy(g.visual.astype(np.float32) / 127.5 - 1.0).permute(2, 0, 1)[None]
    mask = torch.from_numpy(g.mask.astype(np.float32))[None, None]
    return log_luminance(vis, mask)[0, 0].double().numpy()


def training_touches(g: Garment, radius: int) -> list[Touch]:
    """The training touches with contact, whose rectangle moved by up to `radius` stays inside the frame."""
    side_y, side_x = g.mask.shape
    out = []
    for t in g.touches.get("train", []):
        r = t.rect
        if r.x - radius < 0 or r.y - radius < 0 or r.x + r.w + radius > side_x or r.y + r.h + radius > side_y:
            continue
        rr, cc = np.nonzero(t.contact)
        if len(rr):
            out.append(Touch(t.name, rr + r.y, cc + r.x, t.gx[rr, cc].astype(np.float64),
                             t.gy[rr, cc].astype(np.float64)))
    return out


def basis_kernels(width: int, basis: str) -> np.ndarray:
    """(F, width, width) float64: the filters a fit mixes. `bank`: the shading relief's bank, every filter centred,
    so the mix cannot absorb a shift shared by every touch. `free`: every tap of the window, the window's mean out
    (a uniform brightness is no slope)."""
    if basis == "bank":
        return filter_bank(width).reshape(-1, width, width).astype(np.float64)
    taps = width * width
    return (np.eye(taps) - 1.0 / taps).reshape(taps, width, width)


def convolve(lum: np.ndarray, kernels: np.ndarray) -> np.ndarray:
    """(n, P, P): each of `kernels` (n, K, K) applied to `lum` (P, P), edges replicated."""
    r = kernels.shape[-1] // 2
    x = torch.from_numpy(np.pad(lum, r, mode="edge"))[None, None]
    return F.conv2d(x, torch.from_numpy(np.ascontiguousarray(kernels))[:, None])[0].numpy()


def fit_filters(lum: np.ndarray, touches: list[Touch], placed: dict[str, tuple[int, int]], width: int,
                basis: str = "bank") -> np.ndarray:
    """(2, width, width): the gx and gy kernels, ridge fits of the touches' slopes on the basis' responses, each
    touch read at its pressed place (recorded minus its offset in `placed`)."""
    kernels = basis_kernels(width, basis)
    maps = convolve(lum, kernels)
    a = np.concatenate([maps[:, t.y - placed[t.name][1], t.x - placed[t.name][0]].T for t in touches])
    sd = a.std(0)
    sd = np.where(sd > 0, sd, 1.0)   # a response constant over every touch carries nothing: weight 0, no 0 division
    an = a / sd
    lhs = an.T @ an + RIDGE * len(a) * np.eye(a.shape[1])
    return np.stack([np.tensordot(np.linalg.solve(lhs, an.T @ np.concatenate(target)) / sd, kernels, axes=1)
                     for target in ([t.gx for t in touches], [t.gy for t in touches])])


def best_offset(t: Touch, rx: np.ndarray, ry: np.ndarray, tried: list[tuple[int, int]]) -> tuple[int, int]:
    """The offset (recorded minus pressed) whose pressed place matches the touch best after its own gain; the zero
    offset first, so a tie (a flat photo) keeps the recorded corner."""
    best, pick = np.inf, (0, 0)
    energy = float((t.gx * t.gx + t.gy * t.gy).sum())
    for dx, dy in tried:
        px, py = rx[t.y - dy, t.x - dx], ry[t.y - dy, t.x - dx]
        cross, power = float((px * t.gx + py * t.gy).sum()), float((px * px + py * py).sum())
        left = energy - (cross * cross / power if power > 0 else 0.0)
        if left < best - 1e-12 * max(energy, 1e-30):
            best, pick = left, (dx, dy)
    return pick


def estimate(g: Garment, width: int = 11, radius: int = 3, rounds: int = 8, basis: str = "bank") -> tuple[dict[str, tuple[int, int]], int]:
    """Per training touch, its estimated offset (dx, dy), recorded minus pressed; and the rounds it took (it stops
    when no touch moves)."""
    touches = training_touches(g, radius)
    if len(touches) < MIN_TOUCHES:
        raise SystemExit(f"{g.name}: {len(touches)} training touches with room for the shifts (at least "
                         f"{MIN_TOUCHES} are needed to register them to the photo)")
    lum = photo_luminance(g)
    tried = shifts(radius)
    placed = {t.name: (0, 0) for t in touches}
    for n in range(1, rounds + 1):
        rx, ry = convolve(lum, fit_filters(lum, touches, placed, width, basis))
        found = {t.name: best_offset(t, rx, ry, tried) for t in touches}
        common = np.round(np.mean(list(found.values()), 0)).astype(int) * int(basis == "free")
        found = {k: (dx - int(common[0]), dy - int(common[1])) for k, (dx, dy) in found.items()}
        if found == placed:
            return placed, n
        placed = found
    return placed, rounds


def recorded(g: Garment) -> list | None:
    realism = (g.meta.get("realism") or {}) if isinstance(g.meta, dict) else {}
    offsets = realism.get("registration_offsets_px")
    return offsets if isinstance(offsets, list) else None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="dataset folder (e.g. data/hard640)")
    ap.add_argument("garments", nargs="+", help="garment names (e.g. KnitJacket)")
    ap.add_argument("--width", type=int, default=11, help="filter width, px, odd (11)")
    ap.add_argument("--radius", type=int, default=3, help="largest offset tried per axis, px (3)")
    ap.add_argument("--rounds", type=int, default=8, help="most fit-and-move rounds (8)")
    ap.add_argument("--basis", choices=BASES, default="bank",
                    help="the filter: the shading relief's centred bank, mixed (bank), or free taps (free)")
    ap.add_argument("--write", type=Path, help="write copies with the training touches moved here")
    ap.add_argument("--json", type=Path, help="write the estimates and scores here")
    a = ap.parse_args(argv)
    if a.width < 1 or a.width % 2 == 0:
        ap.error(f"--width must be odd and at least 1; got {a.width}")
    if not 1 <= a.radius <= 8 or a.rounds < 1:
        ap.error(f"--radius is 1..8 px and --rounds at least 1; got {a.radius} and {a.rounds}")
    torch.set_num_threads(1)
    out = []
    print(f"{'garment':<20} {'touches':>7} {'rounds':>6} {'hits':>5} {'zero hits':>9} {'px left':>8} "
          f"{'px recorded':>11}")
    for name in a.garments:
        try:
            src = find_garment(a.data, name)
            g = load_garment(src)
        except DatasetError as exc:
            print(f"no garment {name} in {a.data}: {exc}", file=sys.stderr)
            return 2
        est, rounds = estimate(g, a.width, a.radius, a.rounds, a.basis)
        row = {"garment": g.name, "touches": len(est), "rounds": rounds,
               "offsets": {k: list(v) for k, v in sorted(est.items())}}
        offsets = recorded(g)
        if offsets is not None:
            # offsets_found.score counts a move of -offset as a hit
            row["score"] = score({k: (-dx, -dy) for k, (dx, dy) in est.items()}, offsets)
            row["zero_hits"] = sum(registration_offset(offsets, k) == (0, 0) for k in est)
            s = row["score"]
            print(f"{name:<20} {len(est):>7} {rounds:>6} {s['hits']:>5} {row['zero_hits']:>9} "
                  f"{s['mean_px_left']:>8.3f} {s['mean_px_recorded']:>11.3f}")
        else:
            print(f"{name:<20} {len(est):>7} {rounds:>6}  (no recorded offsets to score against)")
        if a.write:
            moved_copy(src, a.write, lambda stem, est=est: tuple(est.get(stem, (0, 0))), ("trainT",),
                       "moved by the photo's registration")
        out.append(row)
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"width": a.width, "radius": a.radius, "basis": a.basis, "garments": out}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
