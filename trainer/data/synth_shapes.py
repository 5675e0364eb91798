"""Garment geometry in a normalised frame: silhouette panels, extra fabric layers, seams, stitching and buttons.

Coordinates are (x, y) with y down, in units of the garment height (the garment box is `aspect` wide and 1 high).
`fit_to_frame` maps a layout to camera pixels; the renderer turns it into height (mm) and albedo. Each builder
jitters its proportions with the rng so two shirts differ.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SHAPES: tuple[str, ...] = ("shirt", "trousers", "shorts", "jacket", "skirt")

Pts = list[tuple[float, float]]


@dataclass
class Layout:
    """One garment's geometry. panels: (polygon, grain angle deg); union of panels = silhouette.

    layers: polygons of extra fabric on top (pockets, waistbands, collars, plackets, cuffs), raised by one cloth
    thickness with hemmed edges. seams: raised ridges (open polylines). stitches: recessed top-stitching (open
    polylines, drawn dashed). buttons: (x, y, radius). decor_boxes: (x0, y0, x1, y1) free areas for appliques/prints.
    """

    aspect: float
    panels: list[tuple[Pts, float]] = field(default_factory=list)
    layers: list[Pts] = field(default_factory=list)
    seams: list[Pts] = field(default_factory=list)
    stitches: list[Pts] = field(default_factory=list)
    buttons: list[tuple[float, float, float]] = field(default_factory=list)
    decor_boxes: list[tuple[float, float, float, float]] = field(default_factory=list)

    def transformed(self, scale: float, dx: float, dy: float) -> "Layout":
        """The same layout in pixels: p_px = p * scale + (dx, dy); radii scale too."""
        def t(pts: Pts) -> Pts:
            return [(x * scale + dx, y * scale + dy) for x, y in pts]
        return Layout(
            aspect=self.aspect,
            panels=[(t(p), a) for p, a in self.panels],
            layers=[t(p) for p in self.layers],
            seams=[t(p) for p in self.seams],
            stitches=[t(p) for p in self.stitches],
            buttons=[(x * scale + dx, y * scale + dy, r * scale) for x, y, r in self.buttons],
            decor_boxes=[(x0 * scale + dx, y0 * scale + dy, x1 * scale + dx, y1 * scale + dy)
                         for x0, y0, x1, y1 in self.decor_boxes],
        )


def _rect(x0: float, y0: float, x1: float, y1: float) -> Pts:
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


def _inset(poly: Pts, d: float) -> Pts:
    """Polygon shrunk towards its centroid by about d (for a stitch line just inside a hemmed edge)."""
    c = np.mean(np.asarray(poly), axis=0)
    out = []
    for x, y in poly:
        v = np.array([x, y]) - c
        n = float(np.linalg.norm(v)) or 1.0
        out.append(tuple((c + v * max(n - d, 0.0) / n).tolist()))
    return out


def _closed(poly: Pts) -> Pts:
    return list(poly) + [poly[0]]


def _arc(cx: float, cy: float, rx: float, ry: float, a0: float, a1: float, n: int = 16) -> Pts:
    t = np.deg2rad(np.linspace(a0, a1, n))
    return [(cx + rx * np.cos(a), cy + ry * np.sin(a)) for a in t]


def _angle(p: tuple[float, float], q: tuple[float, float]) -> float:
    """Grain angle (deg) that makes the fabric's v axis run from p to q."""
    return float(np.rad2deg(np.arctan2(-(q[0] - p[0]), q[1] - p[1])))


def _pocket(lay: Layout, x0: float, y0: float, x1: float, y1: float, pointed: bool) -> None:
    """Patch pocket: a layer with a hemmed top and a top-stitched outline."""
    cx = (x0 + x1) / 2
    poly = [(x0, y0), (x1, y0), (x1, y1 - (0.02 if pointed else 0)), (cx, y1), (x0, y1 - (0.02 if pointed else 0))]
    lay.layers.append(poly)
    lay.stitches.append(_closed(_inset(poly, 0.008)))
    lay.seams.append([(x0, y0 + 0.015), (x1, y0 + 0.015)])


def shirt(rng: np.random.Generator) -> Layout:
    """Short-sleeved button-front shirt with collar, placket, chest pocket and sleeve seams."""
    j = lambda v, s=0.015: v + rng.uniform(-s, s)  # noqa: E731 - small jitter of one proportion
    cx, bw, sl = 0.56, j(0.29), j(0.24, 0.03)
    lay = Layout(aspect=1.12)
    shoulder_l, shoulder_r = (cx - bw, 0.07), (cx + bw, 0.07)
    arm_l, arm_r = (cx - bw + 0.01, 0.30), (cx + bw - 0.01, 0.30)
    body = [(cx - 0.09, 0.02), shoulder_l, arm_l, (cx - bw - 0.01, 0.98), (cx + bw + 0.01, 0.98), arm_r, shoulder_r,
            (cx + 0.09, 0.02), (cx, 0.08)]
    lay.panels.append((body, 0.0))
    for side in (-1, 1):
        sh, ar = (shoulder_l, arm_l) if side < 0 else (shoulder_r, arm_r)
        out_top = (sh[0] + side * sl, sh[1] + 0.20)
        out_bot = (ar[0] + side * (sl - 0.06), ar[1] + 0.12)
        sleeve = [sh, out_top, out_bot, ar]
        lay.panels.append((sleeve, _angle(sh, out_top) * 0.5))
        lay.seams.append([sh, ar])  # armhole
        hem = [(out_top[0] * 0.93 + sh[0] * 0.07, out_top[1] * 0.93 + sh[1] * 0.07),
               (out_bot[0] * 0.93 + ar[0] * 0.07, out_bot[1] * 0.93 + ar[1] * 0.07)]
        lay.stitches.append(hem)
    lay.stitches.append([(cx - bw + 0.005, 0.95), (cx + bw - 0.005, 0.95)])  # hem stitching
    placket = _rect(cx - 0.025, 0.08, cx + 0.025, 0.98)
    lay.layers.append(placket)
    lay.stitches += [[(cx - 0.018, 0.09), (cx - 0.018, 0.975)], [(cx + 0.018, 0.09), (cx + 0.018, 0.975)]]
    for side in (-1, 1):
        collar = [(cx + side * 0.10, 0.0), (cx + side * 0.005, 0.085), (cx + side * 0.05, 0.17),
                  (cx + side * 0.17, 0.07)]
        lay.layers.append(collar)
        lay.stitches.append(_inset(collar, 0.01)[1:])
    n_btn = int(rng.integers(5, 7))
    for y in np.linspace(0.15, 0.9, n_btn):
        lay.buttons.append((cx, float(y), 0.017))
    px0 = cx - bw + 0.06
    _pocket(lay, px0, 0.24, px0 + 0.13, 0.40, pointed=bool(rng.integers(2)))
    lay.decor_boxes.append((cx + 0.06, 0.42, cx + bw - 0.05, 0.86))
    return lay


def jacket(rng: np.random.Generator) -> Layout:
    """Long-sleeved jacket: lapels, button front, flap pockets, cuffs, hem band, armhole and yoke seams."""
    j = lambda v, s=0.015: v + rng.uniform(-s, s)  # noqa: E731
    cx, bw = 0.60, j(0.27)
    lay = Layout(aspect=1.2)
    sh_l, sh_r = (cx - bw, 0.06), (cx + bw, 0.06)
    arm_l, arm_r = (cx - bw + 0.01, 0.30), (cx + bw - 0.01, 0.30)
    body = [(cx - 0.08, 0.0), sh_l, arm_l, (cx - bw - 0.02, 0.97), (cx + bw + 0.02, 0.97), arm_r, sh_r,
            (cx + 0.08, 0.0), (cx, 0.05)]
    lay.panels.append((body, 0.0))
    reach = j(0.28, 0.02)
    for side in (-1, 1):
        sh, ar = (sh_l, arm_l) if side < 0 else (sh_r, arm_r)
        cuff_out = (sh[0] + side * reach, 0.86)
        cuff_in = (ar[0] + side * (reach - 0.12), 0.90)
        lay.panels.append(([sh, cuff_out, cuff_in, ar], _angle(sh, cuff_out)))
        lay.seams.append([sh, ar])
        k = 0.86
        c0 = (sh[0] + (cuff_out[0] - sh[0]) * k, sh[1] + (cuff_out[1] - sh[1]) * k)
        c1 = (ar[0] + (cuff_in[0] - ar[0]) * k, ar[1] + (cuff_in[1] - ar[1]) * k)
        lay.layers.append([c0, cuff_out, cuff_in, c1])  # cuff
        lay.seams.append([(cx + side * 0.09, 0.16), (cx + side * (bw - 0.01), 0.20)])  # yoke
        lapel = [(cx + side * 0.08, 0.0), (cx + side * 0.005, 0.06), (cx + side * 0.02, 0.38),
                 (cx + side * 0.13, 0.16), (cx + side * 0.11, 0.05)]
        lay.layers.append(lapel)
        lay.stitches.append(_closed(_inset(lapel, 0.01)))
        px = cx + side * 0.15
        lay.layers.append(_rect(px - 0.08, 0.60, px + 0.08, 0.78))  # pocket bag
        flap = [(px - 0.085, 0.58), (px + 0.085, 0.58), (px + 0.085, 0.64), (px, 0.66), (px - 0.085, 0.64)]
        lay.layers.append(flap)
        lay.stitches.append(_inset(flap, 0.008))
        lay.buttons.append((px, 0.635, 0.012))
    lay.layers.append(_rect(cx - bw - 0.02, 0.90, cx + bw + 0.02, 0.97))  # hem band
    lay.stitches.append([(cx - bw - 0.01, 0.905), (cx + bw + 0.01, 0.905)])
    lay.layers.append(_rect(cx - 0.03, 0.05, cx + 0.03, 0.90))  # button stand
    lay.seams.append([(cx, 0.05), (cx, 0.97)])
    for y in np.linspace(0.42, 0.84, int(rng.integers(3, 5))):
        lay.buttons.append((cx, float(y), 0.022))
    lay.decor_boxes.append((cx - bw + 0.04, 0.24, cx - 0.06, 0.54))
    return lay


def _bottoms(rng: np.random.Generator, leg: float) -> Layout:
    """Trousers/shorts: waistband, belt loops, fly, slant pockets, crotch seam, legs with cuffs and creases.

    Built in units of the rise (waist to crotch = 1), leg = leg length below the crotch in those units, then
    normalised to total height 1.
    """
    j = lambda v, s=0.03: v + rng.uniform(-s, s)  # noqa: E731
    wb, hw = 0.14, j(0.66)
    hip = hw + 0.05
    flare = j(0.04, 0.02) if leg > 1.2 else j(0.14, 0.03)
    y_hip, y_crotch, y_hem = 0.5, 1.0, 1.0 + leg
    cx = hip + flare + 0.02
    lay = Layout(aspect=2 * cx)
    seat = [(cx - hw, 0.0), (cx + hw, 0.0), (cx + hip, y_hip), (cx + hip, y_crotch), (cx, y_crotch),
            (cx - hip, y_crotch), (cx - hip, y_hip)]
    lay.panels.append((seat, 0.0))
    for side in (-1, 1):
        top_out, top_in = (cx + side * hip, y_hip), (cx + side * 0.005, y_crotch - 0.04)
        hem_out, hem_in = (cx + side * (hip + flare), y_hem), (cx + side * 0.07, y_hem)
        lay.panels.append(([top_out, hem_out, hem_in, top_in, (cx, y_crotch)],
                           _angle(((top_out[0] + top_in[0]) / 2, y_crotch), ((hem_out[0] + hem_in[0]) / 2, y_hem))))
        lay.seams.append([((top_out[0] + top_in[0]) / 2, y_crotch + 0.05),
                          ((hem_out[0] + hem_in[0]) / 2, y_hem - 0.12)])  # pressed crease
        cuff = 0.1
        t = cuff / (y_hem - y_hip)
        cuff_out = (hem_out[0] - (hem_out[0] - top_out[0]) * t, y_hem - cuff)
        lay.layers.append([cuff_out, hem_out, hem_in, (hem_in[0], y_hem - cuff)])
        lay.stitches.append([(cuff_out[0] - side * 0.02, y_hem - cuff + 0.02), (hem_in[0] + side * 0.02,
                                                                                 y_hem - cuff + 0.02)])
        # slant pocket: a facing layer between the waistband, the side seam and a curved opening
        x_open = cx + side * (hw - 0.26)
        curve = [(x_open + side * (hip - (x_open - cx) * side) * s ** 1.6, wb + s * 0.42)
                 for s in np.linspace(0.0, 1.0, 9)]
        lay.layers.append(curve + [(cx + side * hip, y_hip), (cx + side * hw, wb)])
        lay.stitches.append([(x + side * 0.025, y - 0.01) for x, y in curve[:-1]])
        for xl in (cx + side * (hw - 0.05), cx + side * 0.25):
            lay.layers.append(_rect(xl - 0.025, -0.004, xl + 0.025, wb + 0.05))  # belt loop
    lay.layers.append(_rect(cx - hw, 0.0, cx + hw, wb))  # waistband
    lay.stitches.append([(cx - hw + 0.02, wb - 0.02), (cx + hw - 0.02, wb - 0.02)])
    lay.seams.append([(cx, wb), (cx, y_crotch)])
    lay.stitches.append([(cx - 0.11, wb + 0.02), (cx - 0.11, y_crotch - 0.25)]
                        + _arc(cx, y_crotch - 0.25, 0.11, 0.14, 180, 95, 6))  # fly (J-stitch)
    lay.buttons.append((cx - 0.03, wb / 2, 0.035))
    lay.decor_boxes.append((cx - hip + 0.06, y_crotch + 0.05, cx - 0.13,
                            min(y_crotch + 0.9, y_hem - 0.2)))
    out = lay.transformed(1.0 / y_hem, 0.0, 0.0)
    out.aspect = lay.aspect / y_hem
    return out


def trousers(rng: np.random.Generator) -> Layout:
    """Long trousers: legs about twice the rise, grain along each leg."""
    return _bottoms(rng, leg=1.9)


def shorts(rng: np.random.Generator) -> Layout:
    """Shorts: legs shorter than the rise, wider box."""
    return _bottoms(rng, leg=0.55)


def skirt(rng: np.random.Generator) -> Layout:
    """A-line skirt: waistband, gore seams (grain along each gore), patch pocket, optional button front."""
    hw, hem = 0.22 + rng.uniform(-0.02, 0.02), 0.44 + rng.uniform(-0.03, 0.03)
    cx, wb = 0.5, 0.08
    lay = Layout(aspect=1.0)
    hem_curve = _arc(cx, 0.93, hem, 0.07, 0, 180, 21)  # right to left, sagging in the middle
    bounds = np.linspace(-1, 1, 4)
    for i in range(3):
        a, b = bounds[i], bounds[i + 1]
        top_a, top_b = (cx + a * hw, 0.0), (cx + b * hw, 0.0)
        bot_a = (cx + a * hem, 0.93 + 0.07 * np.sqrt(max(0.0, 1 - a * a)))
        bot_b = (cx + b * hem, 0.93 + 0.07 * np.sqrt(max(0.0, 1 - b * b)))
        seg = [p for p in hem_curve if (bot_a[0] - 1e-9) <= p[0] <= (bot_b[0] + 1e-9)]
        poly = [top_a, top_b, bot_b] + sorted(seg, key=lambda p: -p[0]) + [bot_a]
        mid = (a + b) / 2
        lay.panels.append((poly, _angle((cx + mid * hw, 0.0), (cx + mid * hem, 1.0))))
        if i > 0:
            lay.seams.append([top_a, bot_a])
    lay.layers.append(_rect(cx - hw - 0.005, 0.0, cx + hw + 0.005, wb))
    lay.stitches.append([(cx - hw + 0.01, wb - 0.01), (cx + hw - 0.01, wb - 0.01)])
    lay.stitches.append([(x, y - 0.03) for x, y in hem_curve[2:-2]])
    lay.buttons.append((cx + hw - 0.04, wb / 2, 0.016))
    if rng.integers(2):
        lay.layers.append(_rect(cx - 0.025, wb, cx + 0.025, 0.96))
        for y in np.linspace(0.18, 0.85, 5):
            lay.buttons.append((cx, float(y), 0.016))
    _pocket(lay, cx + 0.12, 0.22, cx + 0.27, 0.38, pointed=False)
    lay.decor_boxes.append((cx - 0.34, 0.40, cx - 0.07, 0.80))
    return lay


BUILDERS = {"shirt": shirt, "trousers": trousers, "shorts": shorts, "jacket": jacket, "skirt": skirt}


def build(shape: str, rng: np.random.Generator) -> Layout:
    """Layout of one garment shape (normalised units); ValueError for an unknown shape."""
    if shape not in BUILDERS:
        raise ValueError(f"unknown garment shape {shape!r}; expected one of {', '.join(SHAPES)}")
    return BUILDERS[shape](rng)


def fit_to_frame(layout: Layout, frame: tuple[int, int], rng: np.random.Generator) -> tuple[Layout, float]:
    """Scale the layout to fill 62-78 % of the frame (the limiting side), centre it with a little jitter.

    Returns the pixel layout and the garment height in px.
    """
    w, h = frame
    fill = rng.uniform(0.66, 0.76)
    scale = fill * min(h, w / layout.aspect)
    gw, gh = layout.aspect * scale, scale
    dx = (w - gw) / 2 + rng.uniform(-0.03, 0.03) * w
    dy = (h - gh) / 2 + rng.uniform(-0.03, 0.03) * h
    return layout.transformed(scale, dx, dy), scale
