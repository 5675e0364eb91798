"""Fabric surface textures as physically scaled height fields (mm) for the synthetic garment generator.

Every texture is evaluated on a pixel grid of known pitch (mm/px, 0.3 in the published capture) in the fabric's own
grain frame: u runs across the grain (weft), v along it (warp, e.g. down a trouser leg). Heights are in mm with zero
mean; slopes follow from them at the pixel pitch, so the same numbers drive the shading and the tactile ground truth.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

FABRICS: tuple[str, ...] = ("denim", "corduroy", "linen", "knit", "fleece", "satin")


@dataclass(frozen=True)
class FabricParams:
    """Per-garment fabric parameters (lengths in mm, heights in mm, albedo factors dimensionless).

    period_mm: dominant texture period (twill rib spacing, wale width, thread pitch, knit wale, noise scale).
    amplitude_mm: peak-to-valley height of the texture. thickness_mm: cloth height above the table (edge step).
    albedo_mod: how much the texture height modulates colour (denim twill shows white weft on the low side).
    specular: Blinn-Phong weight (satin is shiny, fleece is not).
    """

    name: str
    period_mm: float
    amplitude_mm: float
    thickness_mm: float
    albedo_mod: float
    specular: float
    course_mm: float = 0.0  # knit course (row) height; linen weft pitch


def sample_fabric(fabric: str, rng: np.random.Generator) -> FabricParams:
    """Draw one garment's fabric parameters within the documented physical ranges."""
    if fabric not in FABRICS:
        raise ValueError(f"unknown fabric {fabric!r}; expected one of {', '.join(FABRICS)}")
    u = rng.uniform
    if fabric == "denim":  # 3/1 twill: diagonal ribs ~1-1.5 mm apart, ~0.05-0.1 mm deep
        return FabricParams("denim", u(1.1, 1.4), u(0.06, 0.09), u(0.6, 0.8), 0.35, 0.02)
    if fabric == "corduroy":  # rounded wales 2-4 mm wide (8-wale to 14-wale cord), ~0.3 mm high
        return FabricParams("corduroy", u(2.3, 3.6), u(0.26, 0.34), u(0.9, 1.2), 0.22, 0.05)
    if fabric == "linen":  # plain weave, thread pitch ~0.8-1.1 mm, slubby threads
        p = u(0.85, 1.1)
        return FabricParams("linen", p, u(0.05, 0.07), u(0.3, 0.45), 0.18, 0.02, course_mm=p * u(0.9, 1.15))
    if fabric == "knit":  # jersey: V-stitch columns ~2.5-3.5 mm wide, courses ~2-2.6 mm
        return FabricParams("knit", u(2.6, 3.4), u(0.16, 0.22), u(0.9, 1.2), 0.2, 0.01, course_mm=u(2.0, 2.6))
    if fabric == "fleece":  # brushed pile: band-limited noise, features ~0.4-0.8 mm
        return FabricParams("fleece", u(0.4, 0.7), u(0.16, 0.22), u(1.2, 1.6), 0.12, 0.0)
    # satin: long floats give an almost flat, shiny face
    return FabricParams("satin", u(0.5, 0.7), u(0.006, 0.01), u(0.15, 0.25), 0.03, 0.35)


def grain_coords(shape: tuple[int, int], *, pitch_mm: float, angle_deg: float,
                 origin: tuple[int, int] = (0, 0)) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) in mm of each pixel of a (H, W) grid whose top-left pixel sits at frame (row, col) = origin.

    The grain direction v is rotated by angle_deg from the image's downward axis (positive = clockwise on screen).
    """
    h, w = shape
    y = (np.arange(h, dtype=np.float32) + origin[0])[:, None] * pitch_mm
    x = (np.arange(w, dtype=np.float32) + origin[1])[None, :] * pitch_mm
    a = np.deg2rad(angle_deg)
    c, s = np.float32(np.cos(a)), np.float32(np.sin(a))
    return x * c - y * s, x * s + y * c


def band_noise(rng: np.random.Generator, shape: tuple[int, int], sigma_px: float,
               sigma_px_y: float | None = None) -> np.ndarray:
    """Unit-std Gaussian noise low-passed at sigma_px (anisotropic when sigma_px_y is given), float32."""
    n = rng.standard_normal(shape, dtype=np.float32)
    n = cv2.GaussianBlur(n, (0, 0), sigmaX=max(sigma_px, 0.3), sigmaY=max(sigma_px_y or sigma_px, 0.3),
                         borderType=cv2.BORDER_REFLECT)
    return n / max(float(n.std()), 1e-6)


def texture(params: FabricParams, shape: tuple[int, int], *, pitch_mm: float, angle_deg: float,
            rng: np.random.Generator, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Zero-mean texture height (mm), float32 (H, W), of the fabric at the given pixel pitch and grain angle.

    Shape: (H, W) -> (H, W) float32 mm. The periodic part depends only on frame coordinates (origin), so two panels
    with the same grain angle join without a seam in the texture; the noise part comes from rng.
    """
    u, v = grain_coords(shape, pitch_mm=pitch_mm, angle_deg=angle_deg, origin=origin)
    p, a = params.period_mm, params.amplitude_mm
    two_pi = np.float32(2 * np.pi)
    name = params.name
    if name == "denim":
        # Ribs run diagonally (~45 deg to the grain); a second harmonic sharpens them like real twill lines.
        t = two_pi * (u + v) / (np.float32(np.sqrt(2.0)) * p)
        h = np.cos(t) + np.float32(0.25) * np.cos(2 * t + 0.6)
        h = h / np.float32(2.5) * a
        h += np.float32(0.08 * a) * band_noise(rng, shape, 6.0, 1.5)  # uneven yarn (slub streaks along v)
    elif name == "corduroy":
        # Rounded wales across u, narrow grooves between them: |sin|^0.75 profile, 0..a.
        h = np.abs(np.sin(np.float32(np.pi) * u / p)) ** np.float32(0.75) * a
        h += np.float32(0.04 * a) * band_noise(rng, shape, 0.8)  # pile
    elif name == "linen":
        # Plain weave: a thread goes over, then under, so the crossings form a checker of bumps with a period of
        # two threads; grooves between threads at the thread pitch; slubs thicken single threads over cm.
        q = params.course_mm
        check = np.sin(np.float32(np.pi) * u / p) * np.sin(np.float32(np.pi) * v / q)
        grooves = np.cos(two_pi * u / p) + np.cos(two_pi * v / q)
        h = (np.float32(0.7) * check + np.float32(0.15) * grooves) * np.float32(a / 1.7)
        h += np.float32(0.35 * a) * band_noise(rng, shape, 0.7, 12.0)  # slubs along the warp
    elif name == "knit":
        # Jersey: columns (wales) of V-shaped loops. Within a wale t in [-0.5, 0.5); the loop rows climb away from
        # the centre line, making chevrons; grooves at the wale centre and edges.
        q = params.course_mm
        t = u / p - np.floor(u / p) - np.float32(0.5)
        chev = np.float32(0.5) + np.float32(0.5) * np.cos(two_pi * (v / q + np.float32(0.9) * np.abs(t)))
        legs = np.float32(0.45) + np.float32(0.55) * np.abs(np.sin(two_pi * t))
        h = chev * legs * a
        h += np.float32(0.05 * a) * band_noise(rng, shape, 0.8)
    elif name == "fleece":
        # Brushed pile: isotropic band-limited noise (features ~period_mm), plus a few pills.
        s = p / pitch_mm
        h = band_noise(rng, shape, s) - np.float32(0.5) * band_noise(rng, shape, 4 * s)
        h = h * np.float32(a / 4.0)
        pills = (rng.random(shape, dtype=np.float32) > 0.9985).astype(np.float32)
        pills = cv2.GaussianBlur(pills, (0, 0), 1.6) * np.float32(16.0)
        h += np.minimum(pills, 1.0) * np.float32(0.35 * a)
    elif name == "satin":
        # Near flat: faint warp floats and a gentle drape undulation, both well under 0.01 mm.
        h = np.float32(0.25 * a) * np.cos(two_pi * u / np.float32(22.0)) * np.cos(two_pi * v / np.float32(31.0))
        h += np.float32(0.25 * a) * band_noise(rng, shape, 0.8, 3.0)
    else:
        raise ValueError(f"unknown fabric {name!r}; expected one of {', '.join(FABRICS)}")
    h = h.astype(np.float32, copy=False)
    return h - np.float32(h.mean())
