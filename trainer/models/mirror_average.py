"""A generator whose tactile output is averaged over mirrored views of its input (test-time mirroring).

Why: a 1 000-step model's relief away from the training touches is partly noise of its seed and of the crop's
orientation; the same sketch mirrored is another draw of it. Each view's relief is mirrored back (the height field's
derivatives follow the mirror, as in trainer/recipe/mirror.py: across the diagonal gx and gy trade places, left to
right gx changes sign) and the views are averaged. Averaging shrinks the relief where the views disagree, so it is
meant to be scored with a relief calibration after it (trainer/calibration.py, ReliefGain outside this wrapper).
The visual output is the plain view's: only the relief is averaged, so the photo and its scores do not change.

A `-low` mode averages only the views' coarse relief: the plain view's own relief plus the low-pass of how the views'
mean differs from it. Why: the generator's weave is not mirror-equivariant (each view draws it at another phase), so a
plain average cancels the weave's energy where the views disagree (KnitJacket, SatinShirt), while the error it removes
sits mostly at the scale of folds and seams. The cutoff is physical and set before any score: a Gaussian of
DETAIL_SIGMA_PX = 5 px (1.5 mm at the training grid's 0.3 mm/px), which keeps under 6 % of a 4 mm period (the widest
weave of the catalogue, corduroy's wales) and over 85 % of a 20 mm fold.

A `-lines` mode averages the views only within LINE_REACH_MM of the sketch's strokes (the evaluator's "by a line"
band, a disc dilation of the strokes computed in the graph) and keeps the plain view's relief in open cloth. Why: on
the full-schedule catalogue most of the average's angle gain sits by the strokes (seams, edges, folds drawn as lines),
where one view's ridge is misplaced; in open cloth it gains little, and on a weave the views disagree on (KnitJacket)
it costs. What each mode measured: docs/training.md, "Which views where".

An `-energy` mode averages everything, then scales the mean's fine relief (above the same DETAIL_SIGMA_PX cutoff)
back up to the energy the plain view's fine relief has over the mask, a gain between 1 and sqrt(views). Why: the
texture statistic compares how strong the weave is, not where it sits; averaging views that draw it at different
phases leaves the right places and the wrong strength, and one gain per canvas gives the strength back without
taking any view's phase. No data is fitted (the gain is the plain view's own energy), so it runs in the graph.

Other seeds (`others`: generators of the same garment and recipe) join as more views: each is run on the plain
sketch and on every mirror, and all views are averaged as above, the plain view still the first generator's. Why: a
seed is another draw of the off-touch relief, as a mirror is. Not adopted (what it measured: docs/training.md, "Seed
ensembles"); the exporter does not offer it.

It keeps the generator's forward(sketch, mask, kind) contract, so evaluation, the exporter's graphs and their
parity check run through it; an exported graph runs the generator once per view (its latency grows with them).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from kiosk.contract.graph import GRAPH_OUTPUTS
from trainer.data.synthetic import PITCH_MM as GRID_PITCH_MM
from trainer.models.mirror_modes import ENERGY, LINES, LOW, MODES
from trainer.physical import LINE_REACH_MM

# The px constants are set at the training grid's pitch (the synthetic garments' 0.3 mm; TouchClothing's is 0.31).
DETAIL_SIGMA_PX = 1.5 / GRID_PITCH_MM   # 5 px; why in the module docstring
ENERGY_EPS = 1e-6   # squared slope, summed over the mask: see detail_gain


def gaussian_taps(sigma: float, channels: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Depthwise weights of a separable Gaussian (3 sigma taps, summing to 1): constants, so an exported graph holds
    them as initialisers."""
    r = int(math.ceil(3 * sigma))
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=torch.float32) / sigma) ** 2)
    k = k / k.sum()
    return k.view(1, 1, 1, -1).repeat(channels, 1, 1, 1), k.view(1, 1, -1, 1).repeat(channels, 1, 1, 1)


def gaussian_lowpass(x: torch.Tensor, sigma: float | None = None,
                     taps: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
    """Separable Gaussian blur of each channel, edges replicated (so a constant passes unchanged)."""
    wx, wy = taps if taps is not None else gaussian_taps(sigma, x.shape[1])
    rx, ry = wx.shape[-1] // 2, wy.shape[-2] // 2
    x = F.conv2d(F.pad(x, (rx, rx, 0, 0), mode="replicate"), wx.to(x.dtype), groups=x.shape[1])
    return F.conv2d(F.pad(x, (0, 0, ry, ry), mode="replicate"), wy.to(x.dtype), groups=x.shape[1])


def disc_taps(radius: float) -> torch.Tensor:
    """(1, 1, k, k) weights: 1 within `radius` px of the centre, 0 outside."""
    r = int(math.floor(radius))
    d = torch.arange(-r, r + 1, dtype=torch.float32)
    return ((d.view(-1, 1) ** 2 + d.view(1, -1) ** 2) <= radius ** 2).float().view(1, 1, 2 * r + 1, 2 * r + 1)


def stroke_band(sketch: torch.Tensor, taps: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W) in {0, 1}: within the disc of a stroke (a sketch pixel darker than mid-grey; the sketch is in
    [-1, 1], strokes dark on white paper). The graph's input is the sketch times the mask, so silhouette ink just
    outside the mask (5-35 % of the ink on the six synthetic garments) is lost to it; but the outline is drawn on the
    mask's own boundary pixels too (the trainer's and the kiosk's masks alike), so every mask pixel within reach of
    the edge is still in the band (tests/trainer/test_mirror_average.py). A gap the kiosk's mask closes has no ink."""
    strokes = (sketch < 0).to(sketch.dtype)
    r = taps.shape[-1] // 2
    return (F.conv2d(strokes, taps.to(sketch.dtype), padding=r) > 0.5).to(sketch.dtype)


def detail_gain(plain_fine: torch.Tensor, mean_fine: torch.Tensor, mask: torch.Tensor, most: float) -> torch.Tensor:
    """(N, 1, 1, 1): the gain that gives the views' mean fine relief the plain view's energy over the mask, within
    [1, most]. `most` is sqrt(views), what n views that share nothing lose. The eps is tiny beside a garment's
    energy (~1e3: squared slopes summed over ~1e5 pixels) and makes a blank relief's 0/0 a gain of 1."""
    m = mask[:, :1]
    e_plain = (m * plain_fine * plain_fine).sum(dim=(1, 2, 3), keepdim=True)
    e_mean = (m * mean_fine * mean_fine).sum(dim=(1, 2, 3), keepdim=True)
    return torch.sqrt((e_plain + ENERGY_EPS) / (e_mean + ENERGY_EPS)).clamp(1.0, most)


def _mirror_in(x: torch.Tensor, op: str) -> torch.Tensor:
    return x.transpose(-1, -2) if op == "t" else torch.flip(x, dims=(-1,))


def _mirror_relief_back(tac: torch.Tensor, op: str) -> torch.Tensor:
    """Undo one mirror on a (gx, gy) relief: the image is mirrored back and the slope vector with it."""
    gx, gy = tac[:, 0:1], tac[:, 1:2]
    if op == "t":
        return torch.cat([gy.transpose(-1, -2), gx.transpose(-1, -2)], dim=1)
    return torch.cat([-torch.flip(gx, dims=(-1,)), torch.flip(gy, dims=(-1,))], dim=1)


def view_in(x: torch.Tensor, view: str) -> torch.Tensor:
    for op in view:
        x = _mirror_in(x, op)
    return x.contiguous()


def view_back(tac: torch.Tensor, view: str) -> torch.Tensor:
    for op in reversed(view):
        tac = _mirror_relief_back(tac, op)
    return tac


class MirrorAverage(nn.Module):
    def __init__(self, generator: nn.Module, mode: str, others: Sequence[nn.Module] = ()):
        super().__init__()
        if mode not in MODES or mode == "none":
            raise ValueError(f"mirror mode must be one of {', '.join(m for m in MODES if m != 'none')}; got {mode!r}")
        self.generator, self.mode, self.views = generator, mode, MODES[mode]
        self.others = nn.ModuleList(others)
        self.low, self.lines = mode.endswith(LOW), mode.endswith(LINES)
        self.energy = mode.endswith(ENERGY)
        wx, wy = gaussian_taps(DETAIL_SIGMA_PX, 2)   # the relief's two slope channels
        self.register_buffer("taps_x", wx, persistent=False)
        self.register_buffer("taps_y", wy, persistent=False)
        self.register_buffer("taps_disc", disc_taps(LINE_REACH_MM / GRID_PITCH_MM), persistent=False)

    def _views(self):
        """Every (generator, mirror) pair but the plain one: this generator's mirrors, then each other seed's plain
        view and mirrors ("" is no mirror)."""
        yield from ((self.generator, v) for v in self.views)
        for g in self.others:
            yield from ((g, v) for v in ("",) + tuple(self.views))

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor, kind: str = "full"):
        out = self.generator(sketch, mask, kind)
        names = GRAPH_OUTPUTS[kind]
        outs = list(out) if isinstance(out, tuple) else [out]
        if "tactile" in names:
            i = names.index("tactile")
            plain = total = outs[i]
            for g, view in self._views():
                if view:
                    o = g(view_in(sketch, view), view_in(mask, view), kind)
                    total = total + view_back(o[i] if isinstance(o, tuple) else o, view)
                else:
                    o = g(sketch, mask, kind)
                    total = total + (o[i] if isinstance(o, tuple) else o)
            n = (1 + len(self.views)) * (1 + len(self.others))
            mean = total / n
            if self.low:
                outs[i] = plain + gaussian_lowpass(mean - plain, taps=(self.taps_x, self.taps_y))
            elif self.energy:
                taps = (self.taps_x, self.taps_y)
                coarse = gaussian_lowpass(mean, taps=taps)
                fine = mean - coarse
                outs[i] = coarse + detail_gain(plain - gaussian_lowpass(plain, taps=taps), fine, mask,
                                               math.sqrt(n)) * fine
            elif self.lines:
                outs[i] = plain + stroke_band(sketch, self.taps_disc) * (mean - plain)
            else:
                outs[i] = mean
        return tuple(outs) if len(outs) > 1 else outs[0]
