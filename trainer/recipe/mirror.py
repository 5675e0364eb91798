"""Mirror a training crop (`data.transpose`: across its main diagonal; `data.flip`: left to right).

The tactile branch learns relief only where the garment was touched, so the few touches are all it has to learn how
a fold in the sketch becomes a ridge in the normal map. Mirroring a crop shows it each touch a second time. The
height field's derivatives follow the mirror: across the diagonal gx and gy trade places; left to right gx changes
sign. A mirror also mirrors the weave: the diagonal keeps a twill whose ribs run at 45 degrees and turns corduroy's
wales and a knit's courses by 90 degrees; left to right keeps wales and courses and turns the twill. Only the
diagonal keeps a photo lit from the upper left lit from there. Both are measured ablations, off by default
(docs/training.md, "Where the outside error sits").
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import torch

from trainer.data.touchclothing import PATCH

if TYPE_CHECKING:
    from trainer.sampling import Batch


def transpose_batch(b: "Batch") -> "Batch":
    """`b` mirrored across the crop's main diagonal: images and patches transposed, patch corners (x, y) -> (y, x),
    gx <-> gy. The crop's origin in the padded frame is kept (it says where the crop came from, not its layout)."""
    t = lambda x: x.transpose(-1, -2).contiguous()  # noqa: E731 - one line, used seven times
    return replace(b, sketch=t(b.sketch), mask=t(b.mask), visual=None if b.visual is None else t(b.visual),
                   coords=t(b.wave_coords()),
                   gx=t(b.gy), gy=t(b.gx), contact=t(b.contact),
                   origins=np.ascontiguousarray(b.origins[:, ::-1]),
                   unpaired=np.ascontiguousarray(b.unpaired[:, ::-1]), mirrored=True)


def flip_batch(b: "Batch") -> "Batch":
    """`b` mirrored left to right: images and patches flipped along x, patch corners x -> side - 32 - x, gx -> -gx.
    The crop's origin in the padded frame is kept, as for the diagonal."""
    f = lambda x: torch.flip(x, dims=(-1,))  # noqa: E731 - one line, used seven times
    side = b.sketch.shape[-1]

    def corners(o: np.ndarray) -> np.ndarray:
        o = o.copy()
        o[:, 0] = side - PATCH - o[:, 0]
        return o

    return replace(b, sketch=f(b.sketch), mask=f(b.mask), visual=None if b.visual is None else f(b.visual),
                   coords=f(b.wave_coords()), gx=-f(b.gx), gy=f(b.gy), contact=f(b.contact),
                   origins=corners(b.origins), unpaired=corners(b.unpaired), mirrored=True)
