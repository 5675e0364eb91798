"""DiffAugment (Zhao et al., NeurIPS 2020) on discriminator inputs: the same random, differentiable transform on the
real and the fake batch, so D cannot memorise the single garment it sees and G still gets a gradient through it.

The authors' `--use_diffaug` policy is colour (brightness, saturation, contrast), translation and cutout. Our D
inputs stack channels of different kinds (sketch, RGB, surface gradients, contact mask), so colour applies to the
RGB channels alone: brightening a gradient channel would change what "real" texture is, and the sketch and contact
channels are binary-ish masks. Translation and cutout move or blank every channel together, keeping them registered.

Shape: x (N, C, H, W); `rgb` the slice of the RGB channels (None: no colour transform).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

OPS = ("color", "translation", "cutout")


def parse_policy(policy: str) -> tuple[str, ...]:
    """'color,translation,cutout' -> ('color', 'translation', 'cutout'); '' -> () (off)."""
    ops = tuple(p.strip() for p in policy.split(",") if p.strip())
    bad = [p for p in ops if p not in OPS]
    if bad:
        raise ValueError(f"unknown DiffAugment op(s) {', '.join(bad)}; choose from {', '.join(OPS)}")
    return ops


def _color(x: torch.Tensor, rgb: slice, g: torch.Generator) -> torch.Tensor:
    n = x.shape[0]
    c = x[:, rgb]
    # drawn in float32 on the CPU whatever x is: the transform depends on the seed alone
    r = lambda: torch.rand(n, 1, 1, 1, generator=g).to(device=x.device, dtype=x.dtype)  # noqa: E731
    c = c + (r() - 0.5)                                          # brightness
    mean_ch = c.mean(dim=1, keepdim=True)
    c = (c - mean_ch) * (r() * 2) + mean_ch                      # saturation
    mean_all = c.mean(dim=(1, 2, 3), keepdim=True)
    c = (c - mean_all) * (r() + 0.5) + mean_all                  # contrast
    return torch.cat([x[:, :rgb.start], c, x[:, rgb.stop:]], 1)


def _translation(x: torch.Tensor, g: torch.Generator, ratio: float = 0.125) -> torch.Tensor:
    n, c, h, w = x.shape
    sh, sw = max(1, int(h * ratio + 0.5)), max(1, int(w * ratio + 0.5))
    ty = torch.randint(-sh, sh + 1, (n,), generator=g).to(x.device)
    tx = torch.randint(-sw, sw + 1, (n,), generator=g).to(x.device)
    padded = F.pad(x, (sw, sw, sh, sh))
    hp, wp = h + 2 * sh, w + 2 * sw
    rows = (torch.arange(h, device=x.device)[None, :] - ty[:, None] + sh).clamp(0, hp - 1)
    cols = (torch.arange(w, device=x.device)[None, :] - tx[:, None] + sw).clamp(0, wp - 1)
    # A gather over the flattened plane returns the standard layout. The earlier advanced indexing returned a
    # channels-last view, which CUDA's avg_pool2d differentiates wrongly under R1's double backward: the tactile D
    # diverged on every GPU run (docs/training.md, "On a GPU"; MultiScaleD now also makes its input contiguous).
    flat = (rows[:, :, None] * wp + cols[:, None, :]).reshape(n, 1, h * w)
    out = padded.reshape(n, c, hp * wp).gather(2, flat.expand(n, c, h * w).contiguous())
    return out.reshape(n, c, h, w)


def _cutout(x: torch.Tensor, g: torch.Generator, ratio: float = 0.5) -> torch.Tensor:
    n, _, h, w = x.shape
    ch, cw = max(1, int(h * ratio + 0.5)), max(1, int(w * ratio + 0.5))
    cy = torch.randint(0, h + (1 - ch % 2), (n,), generator=g).to(x.device)
    cx = torch.randint(0, w + (1 - cw % 2), (n,), generator=g).to(x.device)
    ys = torch.arange(h, device=x.device)[None, :, None]
    xs = torch.arange(w, device=x.device)[None, None, :]
    inside = ((ys - cy[:, None, None]).abs() <= ch // 2) & ((xs - cx[:, None, None]).abs() <= cw // 2)
    return x * (~inside)[:, None].to(x.dtype)


class DiffAugment:
    """`aug(real, fake)` gives batches of equal size the *same* transform (feature matching compares real and fake
    features position by position); successive calls draw new transforms from one seeded stream, reseeded per
    step, so a resumed run augments exactly as an uninterrupted one."""

    def __init__(self, policy: str, *, rgb: slice | None, seed: int = 0):
        self.ops = parse_policy(policy)
        self.rgb = rgb
        # a CPU stream whatever the device: the draws, and so a run, do not depend on where the step runs
        self.g = torch.Generator().manual_seed(seed)

    @property
    def active(self) -> bool:
        return bool(self.ops)

    def reseed(self, seed: int) -> None:
        self.g.manual_seed(seed)

    def __call__(self, *xs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        if len({len(x) for x in xs}) > 1:
            raise ValueError(f"DiffAugment: batches given together must have one size; got {[len(x) for x in xs]}")
        start = self.g.get_state()
        out = []
        for x in xs:
            self.g.set_state(start)
            out.append(self.one(x))
        return tuple(out)

    def one(self, x: torch.Tensor) -> torch.Tensor:
        if not self.ops or len(x) == 0:
            return x
        for op in self.ops:
            if op == "color" and self.rgb is not None:
                x = _color(x, self.rgb, self.g)
            elif op == "translation":
                x = _translation(x, self.g)
            elif op == "cutout":
                x = _cutout(x, self.g)
        return x
