"""Sinusoidal positional encoding of pixel coordinates, as the published code defines it ("encoding dim 4").

Per axis, with p the 1-based pixel index within the crop and frequencies f_k = 10000^(-k / (d/2 - 1)):
[sin(f_0 p), ..., sin(f_{d/2-1} p), cos(f_0 p), ..., cos(f_{d/2-1} p)]. For d = 4 this is
[sin p, sin(1e-4 p), cos p, cos(1e-4 p)]. The x block (varies along columns) comes first, then the y block.
Built from `torch.arange` on the input's own shape so an ONNX export keeps H and W dynamic.
"""
from __future__ import annotations

import torch


def frequencies(dim: int, *, device=None, dtype=torch.float32) -> torch.Tensor:
    """(dim/2,) frequencies: 1 down to 1e-4, geometric."""
    assert dim >= 2 and dim % 2 == 0, f"encoding dim must be even and >= 2; got {dim}"
    half = dim // 2
    if half == 1:
        return torch.ones(1, device=device, dtype=dtype)
    k = torch.arange(half, device=device, dtype=dtype)
    return torch.pow(torch.tensor(1e-4, device=device, dtype=dtype), k / (half - 1))


def _axis_codes(like: torch.Tensor, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The x codes (dim, W) and y codes (dim, H) for an (N, C, H, W) tensor's grid: the encoding's one definition."""
    assert like.dim() == 4, f"expected (N, C, H, W); got shape {tuple(like.shape)}"
    # Index vectors from the input itself (not Python ints) so tracing keeps H and W symbolic.
    px = torch.cumsum(torch.ones_like(like[0, 0, 0, :]), 0)   # 1..W
    py = torch.cumsum(torch.ones_like(like[0, 0, :, 0]), 0)   # 1..H
    f = frequencies(dim, device=like.device, dtype=like.dtype)
    ax, ay = px[:, None] * f[None, :], py[:, None] * f[None, :]
    ex = torch.cat([torch.sin(ax), torch.cos(ax)], 1).t()      # (dim, W)
    ey = torch.cat([torch.sin(ay), torch.cos(ay)], 1).t()      # (dim, H)
    return ex, ey


def positional_encoding(like: torch.Tensor, dim: int = 4) -> torch.Tensor:
    """Encoding for an (N, C, H, W) tensor's grid.

    Shape: like (N, C, H, W) -> (N, 2*dim, H, W); channels [x block (dim), y block (dim)].
    Example: positional_encoding(torch.zeros(1, 1, 256, 256)).shape == (1, 8, 256, 256).
    """
    n = like.shape[0]
    ex, ey = _axis_codes(like, dim)
    ex = ex[:, None, :] * torch.ones_like(like[0, 0, :, :1])   # (dim, H, W)
    ey = ey[:, :, None] * torch.ones_like(like[0, 0, :1, :])   # (dim, H, W)
    return torch.cat([ex, ey], 0)[None].expand(n, -1, -1, -1)


def masked_input(sketch: torch.Tensor, mask: torch.Tensor, dim: int = 4) -> torch.Tensor:
    """The generator's first-layer input, cat(sketch, positional_encoding(sketch)) * mask, built in fewer passes
    over memory: each code block is one broadcast multiply of a row or column vector by the mask, then one concat
    (x * m is the same float as (x * 1) * m, so the values are exactly those of the expanded form).

    Shape: sketch, mask (N, 1, H, W) -> (N, 1 + 2*dim, H, W).
    """
    ex, ey = _axis_codes(sketch, dim)
    return torch.cat([sketch * mask, ex[None, :, None, :] * mask, ey[None, :, :, None] * mask], 1)
