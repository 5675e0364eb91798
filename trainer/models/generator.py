"""The two-branch U-Net generator of the paper (published variant): one encoder, a shared decoder trunk, then a
visual head (RGB) and a tactile head (gx, gy) that take the same skips.

Channel plan (base 10): 9 -> 10 -> 20 -> 40 -> 80 -> 80 -> 80 -> 80 -> 80, eight 4x4 stride-2 convolutions.
Down: LeakyReLU(0.2) -> conv -> InstanceNorm (affine off); the outermost down has no activation/norm and the
innermost no norm (pix2pix convention) - which is also what keeps a 256 px input valid: the 8th down reaches 1x1,
where an InstanceNorm would zero everything, and it has none. Up: ReLU -> transposed conv -> InstanceNorm.
Decoder up7..up4 are shared; up3..up0 exist once per branch. Every up layer except the innermost (up7) and the
outermost (up0) takes the encoder skip of its level, concatenated (as in the authors' code: the outermost takes no skip).
Outputs: tanh, multiplied by the mask. About 1.47 M parameters.

`tactile_reads_visual` (not in the paper; docs/training.md, "The tactile head reads the visual head") feeds each
visual head layer's output into the next tactile head layer as well (up3 -> up2, up2 -> up1, up1 -> up0): the
visual head is trained densely on whole images and learns the shading of folds, while the tactile head sees only
touch patches, so reading the visual features is how the tactile head could get at the garment's shape.

Input: the masked sketch (N, 1, H, W) in [-1, 1] and the mask (N, 1, H, W) in {0, 1}, exactly the two tensors of
`kiosk.contract.sketch.network_input`; the positional encoding is computed inside, so exported graphs take only these.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from kiosk.contract.graph import GRAPH_OUTPUTS, GRID_MULTIPLE
from trainer.models.posenc import masked_input
from trainer.models.weave_waves import object_coords, wave_mix


WAVE_HEADS = ("both", "visual")   # the tactile head's own waves are measured apart (docs/training.md, "Weave waves")


@dataclass
class GeneratorConfig:
    """What `TwoBranchUNet` needs to be rebuilt from a checkpoint (stored as `model_config`)."""

    base: int = 10
    pe_dim: int = 4
    out_visual: int = 3
    out_tactile: int = 2
    max_mult: int = 8
    outer_skip: bool = False
    tactile_mult: int = 1   # width multiplier of the tactile head's own layers (up3..up0); 1 = the paper's
    tactile_reads_visual: bool = False   # the tactile head's up2..up0 also take the visual head's features
    weave_waves: int = 0   # plane waves each head mixes into its output (trainer/models/weave_waves.py); 0 = off
    weave_waves_heads: str = "both"   # which heads mix them: "both" or "visual"


def _down(cin: int, cout: int, *, outermost: bool = False, innermost: bool = False) -> nn.Sequential:
    conv = nn.Conv2d(cin, cout, 4, 2, 1)
    if outermost:
        return nn.Sequential(conv)
    layers: list[nn.Module] = [nn.LeakyReLU(0.2), conv]
    if not innermost:
        layers.append(nn.InstanceNorm2d(cout, affine=False))
    return nn.Sequential(*layers)


def _up(cin: int, cout: int, *, outermost: bool = False, tanh: bool = True) -> nn.Sequential:
    conv = nn.ConvTranspose2d(cin, cout, 4, 2, 1)
    if outermost:
        return nn.Sequential(nn.ReLU(), conv, nn.Tanh()) if tanh else nn.Sequential(nn.ReLU(), conv)
    return nn.Sequential(nn.ReLU(), conv, nn.InstanceNorm2d(cout, affine=False))


class Branch(nn.Module):
    """up3..up0 of one modality: skips from levels 3..1, no skip into the outermost layer (unless outer_skip).

    `mult` widens the head's own layers (not the skips it takes), so a head can gain capacity without touching the
    shared encoder and trunk."""

    def __init__(self, *, widths: list[int], out: int, outer_skip: bool, mult: int = 1,
                 reads: list[int] | None = None, waves: int = 0):
        super().__init__()
        self.out, self.waves = out, waves
        # widths[i] = channels of encoder level i output (down_i), i = 0..7; `reads` = the channels of another
        # head's up3, up2, up1 outputs, taken as extra inputs of this head's up2, up1, up0
        self.outer_skip = outer_skip
        own = [c * mult for c in widths[:3]]
        extra = list(reads) if reads else [0, 0, 0]
        self.up3 = _up(2 * widths[4], own[2])
        self.up2 = _up(widths[2] + own[2] + extra[0], own[1])
        self.up1 = _up(widths[1] + own[1] + extra[1], own[0])
        # with waves, up0 also gives each output channel a sin and a cos weight per wave; tanh after the mix
        self.up0 = _up((widths[0] if outer_skip else 0) + own[0] + extra[2], out * (1 + 2 * waves), outermost=True,
                       tanh=not waves)

    @property
    def widths_out(self) -> list[int]:
        """Channels of up3, up2, up1 outputs: what another head reading this one takes."""
        return [self.up3[1].out_channels, self.up2[1].out_channels, self.up1[1].out_channels]

    def forward(self, trunk: torch.Tensor, skips: list[torch.Tensor],
                read: list[torch.Tensor] | None = None, waves: tuple | None = None) -> torch.Tensor:
        return self.last(self.features(trunk, skips, read), skips, read, waves)

    def features(self, trunk: torch.Tensor, skips: list[torch.Tensor],
                 read: list[torch.Tensor] | None = None) -> list[torch.Tensor]:
        """[up3, up2, up1] outputs; `read` = another head's three, concatenated into up2, up1 (and up0, `last`)."""
        extra = _extra(read)
        y3 = self.up3(torch.cat([skips[3], trunk], 1))
        y2 = self.up2(torch.cat([skips[2], y3, *extra[0]], 1))
        y1 = self.up1(torch.cat([skips[1], y2, *extra[1]], 1))
        return [y3, y2, y1]

    def last(self, features: list[torch.Tensor], skips: list[torch.Tensor],
             read: list[torch.Tensor] | None = None, waves: tuple | None = None) -> torch.Tensor:
        """up0, the output layer, on top of `features`; `waves` = (coords, k) when the head mixes weave waves."""
        inputs = ([skips[0]] if self.outer_skip else []) + [features[-1], *_extra(read)[2]]
        y = self.up0(torch.cat(inputs, 1))
        if not self.waves:
            return y
        coords, k = waves
        return torch.tanh(y[:, :self.out] + wave_mix(y[:, self.out:], coords, k, self.out))


def _extra(read: list[torch.Tensor] | None) -> list[list[torch.Tensor]]:
    """What each of up2, up1, up0 concatenates from another head: one tensor each, or nothing."""
    return [[t] for t in read] if read is not None else [[], [], []]


class TwoBranchUNet(nn.Module):
    """Sketch (+ mask) -> (visual RGB, tactile gx gy), both tanh x mask.

    `forward(sketch, mask, kind)` is the one way to pick branches: `kind` is a graph kind of the runtime contract
    (`kiosk.contract.graph.GRAPH_OUTPUTS`): "full" (default, training) -> (visual, tactile); "visual" or "tactile"
    -> that single tensor, and the other branch is not computed. The exporter wraps the same call (`GraphModule`).

    Shape: sketch, mask (N, 1, H, W), H and W multiples of 256 -> visual (N, 3, H, W), tactile (N, 2, H, W).
    """

    def __init__(self, *, base: int = 10, pe_dim: int = 4, out_visual: int = 3, out_tactile: int = 2,
                 max_mult: int = 8, outer_skip: bool = False, tactile_mult: int = 1,
                 tactile_reads_visual: bool = False, weave_waves: int = 0, weave_waves_heads: str = "both"):
        super().__init__()
        if tactile_mult < 1:
            raise ValueError(f"tactile_mult must be >= 1; got {tactile_mult}")
        if weave_waves < 0:
            raise ValueError(f"weave_waves must be >= 0; got {weave_waves}")
        if weave_waves_heads not in WAVE_HEADS:
            raise ValueError(f"weave_waves_heads must be one of {', '.join(WAVE_HEADS)}; got {weave_waves_heads!r}")
        self.config = GeneratorConfig(base, pe_dim, out_visual, out_tactile, max_mult, outer_skip, tactile_mult,
                                      bool(tactile_reads_visual), int(weave_waves), weave_waves_heads)
        self.pe_dim = pe_dim
        w = [min(base * 2 ** i, base * max_mult) for i in range(8)]   # 10 20 40 80 80 80 80 80
        cin = 1 + 2 * pe_dim
        self.downs = nn.ModuleList([_down(cin, w[0], outermost=True)] +
                                   [_down(w[i - 1], w[i], innermost=(i == 7)) for i in range(1, 8)])
        self.up7 = _up(w[7], w[6])
        self.up6 = _up(2 * w[6], w[5])
        self.up5 = _up(2 * w[5], w[4])
        self.up4 = _up(2 * w[4], w[3])
        self.visual = Branch(widths=w, out=out_visual, outer_skip=outer_skip, waves=weave_waves)
        self.tactile = Branch(widths=w, out=out_tactile, outer_skip=outer_skip, mult=tactile_mult,
                              reads=self.visual.widths_out if tactile_reads_visual else None,
                              waves=weave_waves if weave_waves_heads == "both" else 0)
        if weave_waves:   # set from the training photo before training (set_waves); a checkpoint restores it
            self.register_buffer("wave_k", torch.zeros(weave_waves, 2))

    def set_waves(self, k) -> None:
        """The waves' frequencies (K, 2) rad/px, read off the training photo (weave_waves.weave_frequencies)."""
        k = torch.as_tensor(k, dtype=torch.float32)
        assert self.config.weave_waves and k.shape == self.wave_k.shape and bool(torch.isfinite(k).all()), \
            f"expected {self.config.weave_waves} finite (kx, ky) pairs; got {tuple(k.shape)}"
        self.wave_k.copy_(k)

    @classmethod
    def from_config(cls, cfg: dict | GeneratorConfig) -> "TwoBranchUNet":
        d = asdict(cfg) if isinstance(cfg, GeneratorConfig) else dict(cfg)
        return cls(**d)

    def model_config(self) -> dict:
        return asdict(self.config)

    def _check(self, sketch: torch.Tensor, mask: torch.Tensor) -> None:
        assert sketch.dim() == 4 and sketch.shape[1] == 1, \
            f"sketch must be (N, 1, H, W); got {tuple(sketch.shape)}"
        assert mask.shape == sketch.shape, f"mask must match sketch {tuple(sketch.shape)}; got {tuple(mask.shape)}"
        if not torch.jit.is_tracing() and not torch.onnx.is_in_onnx_export():
            h, w = sketch.shape[-2:]
            assert h % GRID_MULTIPLE == 0 and w % GRID_MULTIPLE == 0, \
                f"input H and W must be multiples of {GRID_MULTIPLE} (8 stride-2 levels); got {h}x{w}"

    def encode(self, sketch: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """Shared part: masked (sketch, PE) -> encoder skips and the trunk after up4."""
        self._check(sketch, mask)
        x = masked_input(sketch, mask, self.pe_dim)
        skips = []
        for down in self.downs:
            x = down(x)
            skips.append(x)
        y = self.up7(skips[7])
        y = self.up6(torch.cat([skips[6], y], 1))
        y = self.up5(torch.cat([skips[5], y], 1))
        y = self.up4(torch.cat([skips[4], y], 1))
        return y, skips

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor, kind: str = "full",
                coords: torch.Tensor | None = None):
        """`coords`: the weave waves' (u, v) per pixel (N, 2, H, W), given only in training, where a mirrored crop
        carries its pixels' own; otherwise computed from the mask (weave_waves.object_coords)."""
        assert kind in GRAPH_OUTPUTS, f"kind must be one of {', '.join(GRAPH_OUTPUTS)}; got {kind!r}"
        trunk, skips = self.encode(sketch, mask)
        waves = None
        if self.config.weave_waves:
            waves = (object_coords(mask) if coords is None else coords, self.wave_k)
        heads: dict[str, torch.Tensor] = {}
        if self.config.tactile_reads_visual and "tactile" in GRAPH_OUTPUTS[kind]:
            # the visual head's last layer is skipped when only the tactile output is asked for
            seen = self.visual.features(trunk, skips)
            if "visual" in GRAPH_OUTPUTS[kind]:
                heads["visual"] = self.visual.last(seen, skips, waves=waves)
            heads["tactile"] = self.tactile(trunk, skips, seen, waves)
        outs = tuple((heads[name] if name in heads else getattr(self, name)(trunk, skips, waves=waves)) * mask
                     for name in GRAPH_OUTPUTS[kind])
        return outs if len(outs) > 1 else outs[0]


class GraphModule(nn.Module):
    """`generator(sketch, mask, kind)` as a module of (sketch, mask) only: what is exported as the `kind` graph and
    what PyTorch eager runs for it, so the trained module and the exported graph share one code path."""

    def __init__(self, generator: nn.Module, kind: str):
        super().__init__()
        assert kind in GRAPH_OUTPUTS, f"kind must be one of {', '.join(GRAPH_OUTPUTS)}; got {kind!r}"
        self.generator, self.kind = generator, kind

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor):
        return self.generator(sketch, mask, self.kind)
