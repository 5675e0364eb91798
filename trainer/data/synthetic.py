"""Procedural synthetic garments written in the published TouchClothing layout, plus full-field tactile truth.

Each garment is one height field (mm, at 0.3 mm/px) from which everything follows: the camera image (albedo x
shading from its normals), the simulated GelSight touches (slopes over a 32 x 24 mm rectangle, contact mask by the
paper's 75th-percentile rule), and `fullT/` with the dense slopes the real capture never had. One loader reads
real and synthetic sets; `synthetic.yaml` makes each garment self-describing.

Frames other than 1280x960 keep the 0.3 mm pitch (a smaller garment, same cloth), scale the padded square
P = round(1800 W / 1280) (even) and the sensor rectangle with the frame (at least 48 x 40 px so 32x32 patches fit).

Two profiles. `hard` (the default) is closer to the paper's capture: the touch rectangles cover about 1/6 of the
frame at every frame size, and the photo is partly independent of the touch field (prints, dye mottling, seams in
matching thread, folds, a fixed lamp, a camera model, registration jitter between photo and touches;
`synth_realism.py`). `easy` is the generator as it was before profiles, bit for bit: Lambert shading of the touch
field itself, and max(20, round(250 x frame area / (1280 x 960))) touches covering most of the garment.
"""
from __future__ import annotations

import os
import shutil
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, replace
from multiprocessing import get_context
from pathlib import Path

import cv2
import numpy as np
import yaml

from trainer.data.synth_fabrics import FABRICS, FabricParams, sample_fabric
from trainer.data.synth_realism import Realism, sample_realism
from trainer.data.synth_render import Decor, Rendered, render
from trainer.data.synth_shapes import SHAPES, build, fit_to_frame

__all__ = ["FABRICS", "PROFILES", "SHAPES", "GarmentSpec", "default_specs", "generate_dataset", "generate_garment",
           "padded_geometry", "sensor_rect_size", "touch_coverage_target", "touch_target"]

GENERATOR_VERSION = "1.0"
PITCH_MM = 0.3  # mm per camera pixel, as in the published capture
DEFAULT_FRAME = (1280, 960)
SENSOR_MM = (32.0, 24.0)  # GelSight R1.5 sensing area, H x W
SENSOR_NOISE = 0.01  # std of the sensor's slope noise (mm/mm) added to gx_raw, gy_raw
PATCH = 32  # tactile patch side (px); patch centres keep PATCH // 2 px from the rectangle border
CONTACT_PERCENTILE = 75.0
CONTACT_DILATION_PX = 1  # 3x3 dilation of the contact mask (the paper's guard against false negatives)
MIN_FRAME = 128
PROFILES = ("hard", "easy")
DEFAULT_PROFILE = "hard"
TOUCH_COVERAGE = 1 / 6  # hard: fraction of the camera frame under the union of touch rectangles (paper, supp.)
# hard: ... but at most this fraction of the garment, so a slim garment (trousers fill ~20 % of the frame) still
# leaves most of itself untouched to generalise to
GARMENT_COVERAGE_CAP = 0.4
REGISTRATION_JITTER_PX = 2.0  # hard: std of the photo-to-touch registration error at 1280x960, scaled with the frame
SUBFOLDERS = ("trainS", "trainI", "trainM", "trainT", "valT", "testS", "testI", "testM", "testT")

_PALETTES: dict[str, list[tuple[float, float, float]]] = {
    "denim": [(0.16, 0.24, 0.42), (0.33, 0.46, 0.64), (0.17, 0.17, 0.21)],
    "corduroy": [(0.62, 0.45, 0.28), (0.40, 0.42, 0.22), (0.46, 0.16, 0.19)],
    "linen": [(0.80, 0.74, 0.62), (0.86, 0.84, 0.80), (0.60, 0.67, 0.54)],
    "knit": [(0.55, 0.55, 0.57), (0.18, 0.22, 0.36), (0.80, 0.62, 0.22)],
    "fleece": [(0.70, 0.16, 0.16), (0.18, 0.38, 0.26), (0.84, 0.81, 0.73)],
    "satin": [(0.84, 0.74, 0.55), (0.06, 0.44, 0.31), (0.16, 0.26, 0.64), (0.78, 0.44, 0.54)],
}
_ACCENTS = [(0.95, 0.85, 0.25), (0.92, 0.92, 0.90), (0.85, 0.30, 0.45), (0.35, 0.60, 0.90), (0.95, 0.55, 0.20),
            (0.55, 0.35, 0.75)]
_WORDS = ("VT", "KIOSK", "TOUCH", "SOFT", "HELLO", "SUMMER", "CMU")
# first six garments: every fabric and every shape, with a spread of decorations
_DEFAULTS = (("denim", "shorts", 2, "", False), ("corduroy", "trousers", 1, "", False),
             ("linen", "shirt", 0, "", True), ("knit", "jacket", 0, "KIOSK", False),
             ("fleece", "skirt", 3, "", False), ("satin", "shirt", 1, "VT", False))


@dataclass(frozen=True)
class GarmentSpec:
    """What to generate. name: CamelCase material (folder/file stem, unique in a set); seed drives all randomness.

    colour: garment RGB in 0..1, or None for a fabric-typical colour drawn from the seed. flowers: number of applique
    flowers; text: printed word ("" for none); stripes: printed stripes along the grain.
    """

    name: str
    shape: str
    fabric: str
    seed: int
    colour: tuple[float, float, float] | None = None
    flowers: int = 1
    text: str = ""
    stripes: bool = False

    def validate(self) -> None:
        if self.fabric not in FABRICS:
            raise ValueError(f"unknown fabric {self.fabric!r}; expected one of {', '.join(FABRICS)}")
        if self.shape not in SHAPES:
            raise ValueError(f"unknown garment shape {self.shape!r}; expected one of {', '.join(SHAPES)}")
        if not self.name or not self.name.isalnum() or not self.name[0].isupper():
            raise ValueError(f"garment name must be CamelCase letters/digits (e.g. 'DenimShorts'); got {self.name!r}")
        if not 0 <= self.flowers <= 6:
            raise ValueError(f"flowers must be 0..6; got {self.flowers}")


def _check_frame(frame: object) -> tuple[int, int]:
    if (not isinstance(frame, (tuple, list)) or len(frame) != 2
            or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in frame)):
        raise ValueError(f"frame must be (width, height) in px, e.g. (1280, 960); got {frame!r}")
    w, h = int(frame[0]), int(frame[1])
    if min(w, h) < MIN_FRAME:
        raise ValueError(f"frame {w}x{h} is too small; both sides must be at least {MIN_FRAME} px")
    if padded_geometry((w, h))[0] < h:
        raise ValueError(f"frame {w}x{h} is too tall for the padded square round(1800*W/1280); use W >= 0.71 H")
    return w, h


def padded_geometry(frame: tuple[int, int]) -> tuple[int, int, int]:
    """(P, x offset, y offset): the padded square side and where the camera frame sits in it (1800, 260, 420)."""
    w, h = frame
    p = 1800 if (w, h) == DEFAULT_FRAME else int(round(1800 * w / 1280))
    p += p % 2
    return p, (p - w) // 2, (p - h) // 2


def sensor_rect_size(frame: tuple[int, int]) -> tuple[int, int]:
    """(h, w) px of the GelSight rectangle: 32 x 24 mm downsampled to 104 x 78 px (paper, Sec. 3) at 1280x960,
    scaled with the frame width, at least 48 x 40 so 32x32 patches with centres 16 px inside still exist."""
    s = frame[0] / DEFAULT_FRAME[0]
    return max(int(round(104 * s)), PATCH + 16), max(int(round(78 * s)), PATCH + 8)


def touch_target(frame: tuple[int, int]) -> int:
    """Number of touches per garment: 250 at 1280x960 (the paper's ~200-300), fewer in proportion, at least 20."""
    return int(min(300, max(20, round(250 * frame[0] * frame[1] / (DEFAULT_FRAME[0] * DEFAULT_FRAME[1])))))


def default_specs(n: int, seed: int) -> list[GarmentSpec]:
    """n garment specs; the first six cover all six fabrics and all five shapes, later ones are drawn at random."""
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
        raise ValueError(f"garments must be a positive integer; got {n!r}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7919]))
    specs: list[GarmentSpec] = []
    seen: dict[str, int] = {}
    for i in range(int(n)):
        if i < len(_DEFAULTS):
            fabric, shape, flowers, text, stripes = _DEFAULTS[i]
        else:
            fabric, shape = str(rng.choice(FABRICS)), str(rng.choice(SHAPES))
            flowers = int(rng.integers(0, 4))
            text = str(rng.choice(_WORDS)) if rng.random() < 0.4 else ""
            stripes = bool(rng.random() < 0.25) and shape in ("shirt", "skirt")
        base = fabric.capitalize() + shape.capitalize()
        seen[base] = seen.get(base, 0) + 1
        name = base if seen[base] == 1 else f"{base}{seen[base]}"
        gseed = int(np.random.SeedSequence([int(seed), i]).generate_state(1)[0])
        specs.append(GarmentSpec(name=name, shape=shape, fabric=fabric, seed=gseed, flowers=flowers, text=text,
                                 stripes=stripes))
    return specs


def _colours(spec: GarmentSpec, rng: np.random.Generator) -> tuple[tuple[float, float, float], Decor,
                                                                    tuple[float, float, float]]:
    """Garment colour, decoration colours and a table colour that contrasts with the garment."""
    pal = _PALETTES[spec.fabric]
    base = spec.colour if spec.colour is not None else pal[int(rng.integers(len(pal)))]
    base = tuple(float(np.clip(c * rng.uniform(0.93, 1.07), 0, 1)) for c in base)
    acc = [_ACCENTS[i] for i in rng.permutation(len(_ACCENTS))]
    lum = 0.3 * base[0] + 0.59 * base[1] + 0.11 * base[2]
    dark = lum < 0.45
    decor = Decor(flowers=spec.flowers, petal_rgb=acc[0], centre_rgb=acc[1], text=spec.text,
                  print_rgb=(0.95, 0.95, 0.93) if dark else (0.12, 0.12, 0.14), stripes=spec.stripes,
                  stripe_rgb=acc[2] if dark else tuple(c * 0.45 for c in base),
                  button_rgb=(0.85, 0.82, 0.75) if dark else (0.25, 0.18, 0.12),
                  thread_rgb=(0.85, 0.60, 0.25) if spec.fabric == "denim" else tuple(c * 0.75 for c in base))
    table = (0.80, 0.79, 0.76) if lum < 0.62 else (0.42, 0.40, 0.38)
    return base, decor, tuple(float(c) for c in table)


def _pad(img: np.ndarray, p: int, ox: int, oy: int, fill: float | tuple) -> np.ndarray:
    h, w = img.shape[:2]
    out = np.empty((p, p) + img.shape[2:], img.dtype)
    out[...] = fill
    out[oy:oy + h, ox:ox + w] = img
    return out


def _touches(mask: np.ndarray, height_mm: np.ndarray, rect_hw: tuple[int, int], n: int,
             rng: np.random.Generator) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """Sensor touches (x, y, contact mask, centre mask) on a jittered grid, like pressing a GelSight in rows.

    A touch counts when its rectangle lies inside the frame, its centre on the garment and it leaves at least one
    allowed patch centre. The grid spacing starts at sqrt(mask area / n) and shrinks until n touches count; the
    surplus is dropped at random, keeping grid order. Fewer than n only when the garment cannot hold n.
    """
    h, w = mask.shape
    rh, rw = rect_hw
    spacing = max(np.sqrt(float(mask.sum()) / n), 2.0)
    cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    found: list[tuple[int, int]] = []
    for _ in range(40):
        ys = np.arange(spacing / 2, h, spacing)
        xs = np.arange(spacing / 2, w, spacing)
        gy, gx = np.meshgrid(ys, xs, indexing="ij")
        jit = rng.uniform(-0.3, 0.3, (2,) + gy.shape) * spacing
        x0 = np.clip(np.round(gx + jit[1] - rw / 2), 0, w - rw).astype(int).ravel()
        y0 = np.clip(np.round(gy + jit[0] - rh / 2), 0, h - rh).astype(int).ravel()
        ok = mask[y0 + rh // 2, x0 + rw // 2]
        found = []
        for x, y in zip(x0[ok].tolist(), y0[ok].tolist()):
            if (x, y) not in cache:
                cache[(x, y)] = _contact(height_mm[y:y + rh, x:x + rw], CONTACT_DILATION_PX)
            if cache[(x, y)][1].any():
                found.append((x, y))
        if len(found) >= n:
            break
        spacing *= 0.93
    if len(found) > n:
        found = [found[i] for i in np.sort(rng.choice(len(found), n, replace=False))]
    return [(x, y) + cache[(x, y)] for x, y in found]


def _coverage(touches: list, rect_hw: tuple[int, int], shape: tuple[int, int]) -> float:
    """Fraction of the frame under the union of the touches' rectangles."""
    cov = np.zeros(shape, bool)
    for x, y, *_ in touches:
        cov[y:y + rect_hw[0], x:x + rect_hw[1]] = True
    return float(cov.mean())


def touch_coverage_target(mask: np.ndarray) -> float:
    """Hard profile: the fraction of the frame the touch rectangles should cover, min(1/6, 0.4 x garment share)."""
    return float(min(TOUCH_COVERAGE, GARMENT_COVERAGE_CAP * mask.mean()))


def _touches_by_coverage(mask: np.ndarray, height_mm: np.ndarray, rect_hw: tuple[int, int],
                         rng: np.random.Generator) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """Hard profile: as many touches as it takes for their rectangles to cover `touch_coverage_target` (within
    half a rectangle), placed like `_touches`. Each count is tried with the same stream, so the result is seeded."""
    state = rng.bit_generator.state
    target = touch_coverage_target(mask) * mask.size
    n = max(5, int(np.ceil(target / (rect_hw[0] * rect_hw[1]))))
    best: list = []
    for _ in range(12):
        rng.bit_generator.state = state
        found = _touches(mask, height_mm, rect_hw, n, rng)
        cov = _coverage(found, rect_hw, mask.shape) * mask.size
        best = found
        if cov >= target - 0.5 * rect_hw[0] * rect_hw[1] or len(found) < n:
            break
        n += max(1, int(round((target - cov) / (rect_hw[0] * rect_hw[1]))))
    return best


def _contact(height: np.ndarray, dilate_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Paper's contact rule: height above its 75th percentile, dilated; patch centres >= 16 px inside, eroded."""
    hi = height > np.percentile(height, CONTACT_PERCENTILE)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilate_px + 1, 2 * dilate_px + 1))
    thresh = cv2.dilate(hi.astype(np.uint8) * 255, k)
    inner = np.zeros_like(thresh)
    half = PATCH // 2
    inner[half:thresh.shape[0] - half + 1, half:thresh.shape[1] - half + 1] = 255
    allowed = cv2.bitwise_and(thresh, inner)
    centre = cv2.erode(allowed, np.ones((3, 3), np.uint8))
    if not centre.any():
        centre = allowed
    return thresh, centre


def _write_png(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")


def _check_profile(profile: object) -> str:
    if profile not in PROFILES:
        raise ValueError(f"unknown data profile {profile!r}; expected one of {', '.join(PROFILES)}")
    return str(profile)


def generate_garment(out_dir: Path, spec: GarmentSpec, *, frame: tuple[int, int] = DEFAULT_FRAME,
                     profile: str = DEFAULT_PROFILE) -> Path:
    """Render one garment and write `singleskit_<Name>_padded_<P>_x1/` under out_dir; returns that folder.

    An existing folder of the same name is replaced (written to a temporary sibling, then renamed).
    """
    from kiosk.contract.sketch import sketch_from_image  # the kiosk's own sketch rule, so synthetic sketches match it

    spec.validate()
    hard = _check_profile(profile) == "hard"
    w, h = _check_frame(frame)
    p, ox, oy = padded_geometry((w, h))
    ss = np.random.SeedSequence(int(spec.seed))
    r_shape, r_fabric, r_colour, r_render, r_touch = (np.random.default_rng(s) for s in ss.spawn(5))
    # the hard profile's extra draws come from a stream of their own, so the easy profile's streams are untouched
    r_hard = np.random.default_rng(np.random.SeedSequence([int(spec.seed), 1]))

    layout, garment_px = fit_to_frame(build(spec.shape, r_shape), (w, h), r_shape)
    fabric: FabricParams = sample_fabric(spec.fabric, r_fabric)
    base, decor, table = _colours(spec, r_colour)
    realism: Realism | None = None
    if hard:
        decor = replace(decor, thread_rgb=base)  # seams and stitching in matching thread
        pts = np.concatenate([np.asarray(poly, np.float64) for poly, _ in layout.panels])
        realism = sample_realism(r_hard, frame=(w, h), pitch_mm=PITCH_MM, bbox=(*pts.min(0), *pts.max(0)),
                                 base_rgb=base)
    ren: Rendered = render(layout, garment_px, fabric, base, decor, table, (w, h), PITCH_MM, r_render,
                           realism=realism)
    sketch_src = ren.sketch_rgb if ren.sketch_rgb is not None else ren.rgb
    sketch = np.asarray(sketch_from_image(sketch_src, ren.mask), dtype=np.uint8)
    if sketch.shape != (h, w):
        raise ValueError(f"sketch_from_image returned shape {sketch.shape}, expected {(h, w)}")

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    final = out_dir / f"singleskit_{spec.name}_padded_{p}_x1"
    tmp = out_dir / f".{final.name}.tmp{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    for sub in SUBFOLDERS + ("fullT",):
        (tmp / sub).mkdir(parents=True)
    stem = spec.name.lower()

    images = {
        "S": _pad(sketch, p, ox, oy, 255),
        "I": cv2.cvtColor(_pad(ren.rgb, p, ox, oy, tuple(int(round(c * 255)) for c in table)), cv2.COLOR_RGB2BGR),
        "M": _pad(ren.mask.astype(np.uint8) * 255, p, ox, oy, 0),
    }
    names = {"S": "sketch", "I": "image", "M": "mask"}
    for key, img in images.items():
        _write_png(tmp / f"train{key}" / f"{stem}_{names[key]}.png", img)
        fname = f"{stem}_{names[key]}.png"
        shutil.copyfile(tmp / f"train{key}" / fname, tmp / f"test{key}" / fname)

    rh, rw = sensor_rect_size((w, h))
    if hard:
        touches = _touches_by_coverage(ren.mask, ren.height_mm, (rh, rw), r_touch)
    else:
        touches = _touches(ren.mask, ren.height_mm, (rh, rw), touch_target((w, h)), r_touch)
    order = r_touch.permutation(len(touches))
    n_train, n_val = int(round(0.6 * len(touches))), int(round(0.2 * len(touches)))
    split = {}
    for rank, i in enumerate(order):
        split[int(i)] = "trainT" if rank < n_train else ("valT" if rank < n_train + n_val else "testT")
    jitter_px = REGISTRATION_JITTER_PX * w / DEFAULT_FRAME[0]
    jitters = []
    for i, (x0, y0, thresh, centre) in enumerate(touches):
        noise = r_touch.normal(0.0, SENSOR_NOISE, (2, rh, rw)).astype(np.float32)
        # hard: the recorded rectangle (marker tracking) is off the pressed one by a small registration error
        rx, ry = x0, y0
        if hard:
            dx, dy = np.round(r_hard.normal(0.0, jitter_px, 2)).astype(int)
            rx, ry = int(np.clip(x0 + dx, 0, w - rw)), int(np.clip(y0 + dy, 0, h - rh))
            jitters.append([rx - x0, ry - y0])
        np.savez_compressed(
            tmp / split[i] / f"{stem}_{i + 1:04d}_tactile.npz",
            gx_raw=ren.gx[y0:y0 + rh, x0:x0 + rw] + noise[0], gy_raw=ren.gy[y0:y0 + rh, x0:x0 + rw] + noise[1],
            vision_mask_x=np.int64(rx), vision_mask_y=np.int64(ry), vision_mask_h=np.int64(rh),
            vision_mask_w=np.int64(rw), touch_thresh=thresh, touch_center_thresh=centre)

    np.savez_compressed(tmp / "fullT" / f"{stem}_full_tactile.npz",
                        gx=_pad(ren.gx, p, ox, oy, 0.0), gy=_pad(ren.gy, p, ox, oy, 0.0),
                        height_mm=_pad(ren.height_mm, p, ox, oy, 0.0), pixel_pitch_mm=np.float64(PITCH_MM))
    counts = {k: sum(1 for v in split.values() if v == k) for k in ("trainT", "valT", "testT")}
    meta = {
        "generator": "vtkiosk.trainer.data.synthetic", "generator_version": GENERATOR_VERSION,
        "spec": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(spec).items()},
        "shape": spec.shape, "fabric": asdict(fabric),
        "decorations": {"flowers": decor.flowers, "text": decor.text, "stripes": decor.stripes,
                        "buttons": len(layout.buttons), "pockets_layers": len(layout.layers),
                        "seams": len(layout.seams), "stitch_lines": len(layout.stitches)},
        "colours": {"garment": list(base), "table": list(table), "petal": list(decor.petal_rgb),
                    "flower_centre": list(decor.centre_rgb), "print": list(decor.print_rgb),
                    "stripe": list(decor.stripe_rgb), "button": list(decor.button_rgb),
                    "thread": list(decor.thread_rgb)},
        "frame": [w, h], "padded_size": p, "offsets": [ox, oy], "pixel_pitch_mm": PITCH_MM,
        "sensor_rect_hw_px": [rh, rw], "sensor_noise_slope": SENSOR_NOISE, "patch": PATCH,
        "contact_percentile": CONTACT_PERCENTILE, "contact_dilation_px": CONTACT_DILATION_PX,
        "touches": len(touches), "split": counts,
        "slope_percentiles_on_mask": {str(q): float(np.percentile(np.abs(ren.gx[ren.mask]), q)) for q in (50, 95, 99)},
    }
    if hard:  # easy keeps its metadata byte-identical (an absent `profile` reads as easy)
        meta = {"profile": "hard", **meta}
        meta["touch_coverage_target"] = round(touch_coverage_target(ren.mask), 4)
        meta["touch_coverage_of_frame"] = round(_coverage(touches, (rh, rw), (h, w)), 4)
        meta["touch_coverage_of_garment"] = round(
            _coverage(touches, (rh, rw), (h, w)) * h * w / max(int(ren.mask.sum()), 1), 4)
        meta["realism"] = {
            "folds": [[round(v, 3) for v in f] for f in realism.folds], "wrinkle_mm": realism.wrinkle_mm,
            "fold_height_range_mm": [float(ren.fold_mm.min()), float(ren.fold_mm.max())],
            "print": realism.print_kind, "print_period_mm": realism.print_period_mm,
            "print_rgb": list(realism.print_rgb), "mottle": realism.mottle, "thread": "matching",
            "lamp_xy_mm": list(realism.lamp_xy_mm), "lamp_height_mm": realism.lamp_height_mm,
            "blur_px": realism.blur_px, "read_noise": realism.read_noise, "shot_gain": realism.shot_gain,
            "registration_jitter_std_px": round(jitter_px, 3),
            "registration_offsets_px": jitters,  # recorded minus pressed rectangle corner, per touch in serial order
        }
    (tmp / "synthetic.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    shutil.rmtree(final, ignore_errors=True)
    os.replace(tmp, final)
    return final


def registration_offset(offsets: Sequence, touch: str) -> tuple[int, int]:
    """The recorded-minus-pressed corner (dx, dy) of the touch named `touch` (<material>_<serial>_tactile), from
    synthetic.yaml's `realism.registration_offsets_px`, which `generate_garment` writes in serial order."""
    parts = touch.split("_")
    serial = parts[-2] if len(parts) >= 3 else ""
    if not serial.isdigit() or not 1 <= int(serial) <= len(offsets):
        raise ValueError(f"{touch}: no registration offset for this touch ({len(offsets)} recorded)")
    dx, dy = offsets[int(serial) - 1]
    return int(dx), int(dy)


def _worker_init() -> None:
    cv2.setNumThreads(1)


def _one(args: tuple[Path, GarmentSpec, tuple[int, int], str]) -> Path:
    out_dir, spec, frame, profile = args
    return generate_garment(out_dir, spec, frame=frame, profile=profile)


def generate_dataset(out_dir: Path, *, garments: int = 6, seed: int = 0, frame: tuple[int, int] = DEFAULT_FRAME,
                     progress: bool = True, profile: str = DEFAULT_PROFILE,
                     only: Sequence[str] | None = None) -> list[Path]:
    """Generate `garments` garments (default_specs(garments, seed)) under out_dir; returns their folders in order.
    `only`: just the named ones (spec names such as "DenimShorts"), identical to the whole set's (per-garment seeds).

    Uses two worker processes when there is more than one garment; the output does not depend on scheduling.
    """
    frame = _check_frame(frame)
    profile = _check_profile(profile)
    specs = default_specs(garments, seed)
    if only is not None:
        names = [s.name for s in specs]
        unknown = [n for n in only if n not in names]
        if unknown or not only:
            raise ValueError(f"--only: no garment {', '.join(unknown) or '(none given)'} in this set; it has "
                             f"{', '.join(names)}")
        specs = [s for s in specs if s.name in set(only)]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs = [(out_dir, s, frame, profile) for s in specs]
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(jobs), desc="synthetic garments", unit="garment")
    t0 = time.perf_counter()
    results: dict[int, Path] = {}
    try:
        if len(jobs) == 1:
            results[0] = _one(jobs[0])
            if bar:
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=2, mp_context=get_context("spawn"),
                                     initializer=_worker_init) as pool:
                futs = {pool.submit(_one, j): i for i, j in enumerate(jobs)}
                for fut in as_completed(futs):
                    results[futs[fut]] = fut.result()
                    if bar:
                        bar.update()
                        bar.set_postfix_str(f"{time.perf_counter() - t0:.1f}s")
    finally:
        if bar:
            bar.close()
    return [results[i] for i in range(len(jobs))]

