"""Shift-tolerant touch patches (`loss.tactile_shift`): each touch is compared with the generated relief at the
best of the small shifts around where it was recorded.

A capture records each touch a pixel or two from where it was pressed (marker tracking; the hard profile's
`realism.registration_offsets_px`), so a loss taken at the recorded corner teaches a ridge smeared over the jitter.
Moving the touches back to where they were pressed is worth 5-15 points of the full-field gap (docs/training.md,
"What registration is worth"), but the offsets are unknown on a real capture. Here they are latent: for every
paired patch the generated map is cut at each shift within +-k px and the patch whose masked L1 to the touch is
lowest is the one every tactile term (L1, perceptual, texture, the tactile D's paired fake) then sees. Once the
generator renders the consensus of the touches, the best shift of each is its offset. The choice is not
differentiated (a hard pick, as in a min over alignments); the gradient flows through the picked patch.

Measured and dropped, so off by default (docs/training.md, "Registration-tolerant touches"): the touches barely
overlap, so nothing ties one touch's place to another's, the picks scatter over the window, and the relief comes out
worse than when every touch is taken where it was recorded.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from trainer.data.touchclothing import PATCH


def shifts(k: int) -> list[tuple[int, int]]:
    """The (dx, dy) tried, zero first so a tie keeps the recorded corner."""
    grid = [(dx, dy) for dy in range(-k, k + 1) for dx in range(-k, k + 1) if (dx, dy) != (0, 0)]
    return [(0, 0)] + sorted(grid, key=lambda s: (s[0] ** 2 + s[1] ** 2, s))


def best_shift_patches(x: torch.Tensor, origins: np.ndarray, target: torch.Tensor, contact: torch.Tensor,
                       k: int) -> tuple[torch.Tensor, np.ndarray]:
    """Patches of `x` (1, C, H, W) at `origins` (K, 2) (x, y) corners moved by the best shift within +-k px, and the
    shifts (K, 2) (dx, dy) picked.

    "Best" is the lowest mean |patch - target| over the contact pixels (a patch with no contact keeps (0, 0)).
    Corners moved off the map read the edge pixels repeated (replicate padding), so a patch at the crop's border is
    compared like any other. k = 0 is the plain cut.
    """
    assert x.dim() == 4 and x.shape[0] == 1, f"expected (1, C, H, W); got {tuple(x.shape)}"
    if k < 0:
        raise ValueError(f"k is a shift radius in px, >= 0; got {k}")
    n = len(origins)
    if n == 0:
        return x.new_zeros((0, x.shape[1], PATCH, PATCH)), np.zeros((0, 2), int)
    size = PATCH + 2 * k
    padded = F.pad(x, (k, k, k, k), mode="replicate") if k else x
    # the window of each patch with every shift inside it: corner (x, y) of the map is (x, y) of the padded map - k
    windows = torch.cat([padded[:, :, y:y + size, xx:xx + size] for xx, y in np.asarray(origins).tolist()], 0)
    tried = shifts(k)
    with torch.no_grad():
        w = contact.sum((1, 2, 3)).clamp_min(1.0) * x.shape[1]
        cost = torch.stack([((windows[:, :, k + dy:k + dy + PATCH, k + dx:k + dx + PATCH] - target).abs() * contact)
                            .sum((1, 2, 3)) / w for dx, dy in tried], 0)          # (S, K)
        pick = cost.argmin(0)                                                      # first minimum: (0, 0) on a tie
    picked = np.asarray(tried, int)[pick.cpu().numpy()]
    patches = torch.stack([windows[i, :, k + dy:k + dy + PATCH, k + dx:k + dx + PATCH]
                           for i, (dx, dy) in enumerate(picked.tolist())], 0)
    return patches, picked
