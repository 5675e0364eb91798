"""Known haptic panels: physical size and pixels, so the planner can render texture at true scale.

Each entry says where its figures come from. The vendor's public datasheets were searched for and not found
(docs/haptics.md, "Panel sizes"), so no entry here is a datasheet figure: the one known panel is the 10.1-inch
1280x800 TanvasTouch screen the paper's published friction maps target (authors' rendering scripts resize to
1280x800), with its active area derived from the 10.1-inch diagonal at 16:10 and square pixels. An operator whose
unit's datasheet says otherwise states `panel.width_mm` / `panel.height_mm` in the kiosk config, which win.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class KnownPanel:
    model: str
    width_px: int
    height_px: int
    width_mm: float
    height_mm: float
    source: str
    from_datasheet: bool

    @property
    def pitch_mm(self) -> float:
        return self.width_mm / self.width_px


def _from_diagonal(inches: float, w_px: int, h_px: int) -> tuple[float, float]:
    d = inches * 25.4 / math.hypot(w_px, h_px)
    return round(w_px * d, 1), round(h_px * d, 1)


_W, _H = _from_diagonal(10.1, 1280, 800)
KNOWN_PANELS: dict[str, KnownPanel] = {
    "tanvastouch-10.1": KnownPanel(
        "tanvastouch-10.1", 1280, 800, _W, _H,
        source="10.1-inch 1280x800 TanvasTouch screen targeted by the paper's friction maps (Gao et al. 2023, "
               "authors' scripts); active area derived from the diagonal, not read from a vendor datasheet",
        from_datasheet=False),
}
DEFAULT_PANEL = "tanvastouch-10.1"
