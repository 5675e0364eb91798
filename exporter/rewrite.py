"""Exact graph rewrites that make the generator run faster in ONNX Runtime on CPU.

ONNX Runtime has no int8 ConvTranspose kernel on CPU, so a quantized U-Net would keep its whole decoder in fp32.
A 4x4 stride-2 padding-1 transposed convolution equals a 3x3 convolution (padding 1) to 4x the channels followed
by a 2x2 pixel shuffle (ONNX DepthToSpace, CRD mode): each output parity (a, b) is a 2x2 correlation over the input,
placed inside a 3x3 kernel. The rewrite is exact in exact arithmetic (tests: max difference ~1e-6 in float32), and
the 3x3 convolution quantizes like any other.
"""
from __future__ import annotations

import copy

import torch
from torch import nn

# For output parity a (0 = even, 1 = odd): which 3x3 kernel index takes which 4x4 transposed-kernel index.
# Derived from o = 2i + k - 1: even outputs use k=1 at offset 0 and k=3 at offset -1; odd outputs use k=0 at
# offset +1 and k=2 at offset 0; offset d sits at 3x3 index d + 1.
_TAPS = {0: ((1, 1), (0, 3)), 1: ((1, 2), (2, 0))}


class ConvTransposeAsConv(nn.Module):
    """Drop-in replacement for ConvTranspose2d(kernel 4, stride 2, padding 1): Conv 3x3 -> PixelShuffle(2)."""

    def __init__(self, convt: nn.ConvTranspose2d):
        super().__init__()
        if not is_rewritable(convt):
            raise ValueError(f"only ConvTranspose2d(kernel 4, stride 2, padding 1, groups 1, dilation 1) can be "
                             f"rewritten; got {convt}")
        cin, cout = convt.in_channels, convt.out_channels
        w = convt.weight.detach()  # (cin, cout, 4, 4)
        k3 = torch.zeros(cout, 2, 2, cin, 3, 3, dtype=w.dtype)
        for a in (0, 1):
            for b in (0, 1):
                for iy, ky in _TAPS[a]:
                    for ix, kx in _TAPS[b]:
                        k3[:, a, b, :, iy, ix] = w[:, :, ky, kx].t()
        self.conv = nn.Conv2d(cin, cout * 4, 3, padding=1, bias=convt.bias is not None)
        with torch.no_grad():
            self.conv.weight.copy_(k3.reshape(cout * 4, cin, 3, 3))
            if convt.bias is not None:
                self.conv.bias.copy_(convt.bias.detach().repeat_interleave(4))
        self.shuffle = nn.PixelShuffle(2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.shuffle(self.conv(x))


def is_rewritable(m: nn.Module) -> bool:
    return (isinstance(m, nn.ConvTranspose2d) and m.kernel_size == (4, 4) and m.stride == (2, 2)
            and m.padding == (1, 1) and m.output_padding == (0, 0) and m.groups == 1 and m.dilation == (1, 1))


def rewrite_conv_transpose(model: nn.Module) -> tuple[nn.Module, int]:
    """A copy of `model` with every rewritable ConvTranspose2d replaced; returns (copy, number replaced)."""
    model = copy.deepcopy(model)
    count = 0
    for name, child in list(model.named_modules()):
        for attr, sub in list(child.named_children()):
            if is_rewritable(sub):
                setattr(child, attr, ConvTransposeAsConv(sub))
                count += 1
    return model, count
