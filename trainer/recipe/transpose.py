"""Mirror a training crop across its main diagonal (`data.transpose`).

The tactile branch learns relief only where the garment was touched, so the few touches are all it has to learn how
a fold in the sketch becomes a ridge in the normal map. Mirroring a crop shows it each touch at a second orientation.
Of the mirrors, the diagonal is the one that keeps the photo's light where it was: a lamp at the upper left (the
synthetic renderer's, and the usual studio set-up) stays at the upper left, so the visual branch is not taught
shading from two sides. The height field's x derivative becomes its y derivative, so gx and gy trade places.
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from trainer.sampling import Batch


def transpose_batch(b: "Batch") -> "Batch":
    """`b` mirrored across the crop's main diagonal: images and patches transposed, patch corners (x, y) -> (y, x),
    gx <-> gy. The crop's origin in the padded frame is kept (it says where the crop came from, not its layout)."""
    t = lambda x: x.transpose(-1, -2).contiguous()  # noqa: E731 - one line, used six times
    return replace(b, sketch=t(b.sketch), mask=t(b.mask), visual=None if b.visual is None else t(b.visual),
                   gx=t(b.gy), gy=t(b.gx), contact=t(b.contact),
                   origins=np.ascontiguousarray(b.origins[:, ::-1]),
                   unpaired=np.ascontiguousarray(b.unpaired[:, ::-1]), mirrored=True)
