"""Photometric tactile loss (`loss.tactile_shading`): the relief asked to explain the real photo's fine shading.

Why: the tactile terms see the relief only where a touch was recorded, and the touches are registered to the photo
only to within a few pixels, so off the touches nothing says where the weave's ridges sit. The training photo does,
everywhere on the object and in the frame the full-field truth shares: under a lamp, a fine band of the
log-luminance is, to first order, the height's derivative along the light (linear shape from shading), so it is a
fixed linear mix of the same band of the two slopes. Per crop and band the mix (the lamp's direction and strength,
never given; a mirrored crop has its own) is the least-squares fit, and the loss is the share of the photo's band
the fit leaves unexplained (1 - R^2, in [0, 1]). It is blind to the relief's scale, which the touches set, and its
gradient enters the generator through the tactile output only (the photo is the data's; the shared encoder still
moves, so the generated photo can too).
"""
from __future__ import annotations

import torch

from trainer.models.shading_relief import dog_bands, log_luminance

RIDGE = 1e-3      # relative ridge on the 2 x 2 normal equations: a flat relief explains nothing, stably
# The photo band's energy floor per object pixel (a band of 0.1 % contrast): a photo with no shading, or no object,
# gives 0, not 0 / 0 nor float noise over float noise.
FLOOR = 1e-6


def unexplained(slopes: torch.Tensor, photo: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(N, len(BANDS)): the share of each photo band's energy on the object that no mix of the slopes' bands
    explains (1 = none of it, 0 = all of it)."""
    m = (mask > 0.5).to(slopes.dtype)
    g = dog_bands(slopes * m)                           # (N, 2, B, H, W)
    b = dog_bands(log_luminance(photo, mask))[:, 0]     # (N, B, H, W); background filled: no silhouette cliff
    gx, gy = g[:, 0], g[:, 1]

    def dot(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return (u * v * m).sum((-2, -1))

    sxx, sxy, syy = dot(gx, gx), dot(gx, gy), dot(gy, gy)
    sxb, syb, sbb = dot(gx, b), dot(gy, b), dot(b, b)
    lam = RIDGE * (sxx + syy) / 2 + 1e-12            # + a constant: a flat relief's system stays invertible
    a, d = sxx + lam, syy + lam
    det = a * d - sxy * sxy                             # > 0: a, d > |sxy| by Cauchy-Schwarz plus the ridge
    explained = (d * sxb * sxb - 2 * sxy * sxb * syb + a * syb * syb) / det
    floor = FLOOR * m.sum((-2, -1)).clamp_min(1.0)
    return ((sbb - explained) / torch.maximum(sbb, floor)).clamp(0.0, 1.0)


def shading_loss(slopes: torch.Tensor, photo: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean unexplained share over the crops and bands: 0 when the relief's bands account for the photo's."""
    return unexplained(slopes, photo, mask).mean()
