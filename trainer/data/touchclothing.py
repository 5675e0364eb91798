"""Loader for the published TouchClothing layout (and our synthetic garments, which use the same layout).

One folder per garment, `singleskit_<Material>_padded_<P>_x<k>/`, with `trainS trainI trainM trainT valT testS testI
testM testT`. Images are stored padded to P x P with the camera frame centred; tactile touches are `*_tactile.npz`
files whose sensor rectangle is given in unpadded camera pixels. The layout is the published dataset's; this
module is the only place that knows it.

Synthetic garments add `synthetic.yaml` (frame size and offsets when the frame is not the published 1280x960) and
`fullT/*_full_tactile.npz` (gradients over the whole garment), which the real data lacks.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from trainer.errors import TrainerError
from kiosk.config import loader
from kiosk.contract.garment import same_garment
from kiosk.contract.haptics import calibrate_scale

PUBLISHED_FRAME = (1280, 960)  # camera frame (width, height)
PUBLISHED_PADDED = 1800
PATCH = 32
SPLITS = ("train", "val", "test")
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
TACTILE_KEYS = ("gx_raw", "gy_raw", "vision_mask_x", "vision_mask_y", "vision_mask_h", "vision_mask_w",
                "touch_thresh", "touch_center_thresh")
FOLDER_RE = re.compile(r"^singleskit_(?P<material>.+?)_padded_(?P<padded>\d+)_x(?P<mult>\d+)$")


class DatasetError(TrainerError):
    """A garment folder that does not follow the layout; the message names the folder and what is missing."""


@dataclass(frozen=True)
class Rect:
    """A rectangle in padded-frame pixels: x = column, y = row of the top-left corner."""

    x: int
    y: int
    w: int
    h: int


@dataclass
class TactileTouch:
    """One press of the tactile sensor: gradients over its rectangle and where 32x32 patches may be centred.

    Shape: gx, gy (h, w) float32 slopes; contact, centres (h, w) bool; rect in padded-frame pixels, (h, w) = its size.
    """

    name: str
    split: str
    gx: np.ndarray
    gy: np.ndarray
    contact: np.ndarray
    centres: np.ndarray
    rect: Rect


@dataclass
class FullTactile:
    """Ground-truth gradients over the whole padded frame (synthetic garments only). Shape: (P, P) float32."""

    gx: np.ndarray
    gy: np.ndarray
    height_mm: np.ndarray | None
    pixel_pitch_mm: float


@dataclass
class Garment:
    """Everything one garment folder holds, in padded-frame coordinates (P x P)."""

    root: Path
    material: str
    padded_size: int
    multiplier: int
    frame: tuple[int, int]       # camera frame (width, height)
    offset: tuple[int, int]      # camera frame's top-left in the padded image (x, y)
    edited: bool                 # an edited sketch: no ground truth
    sketch: np.ndarray           # (P, P) uint8, ink 0 on paper 255
    mask: np.ndarray             # (P, P) bool
    visual: np.ndarray | None    # (P, P, 3) uint8 RGB
    test_sketch: np.ndarray | None = None
    test_mask: np.ndarray | None = None
    test_visual: np.ndarray | None = None
    touches: dict[str, list[TactileTouch]] = field(default_factory=dict)
    full_tactile: FullTactile | None = None
    meta: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.root.name

    @property
    def profile(self) -> str:
        """Which data this is: "real" (no synthetic.yaml), or the synthetic profile ("easy" when the file names none:
        the generator before profiles)."""
        if not (self.root / "synthetic.yaml").is_file():
            return "real"
        return str(self.meta.get("profile", "easy"))

    @property
    def pixel_pitch_mm(self) -> float | None:
        """mm per padded-frame pixel, when the garment states it (synthetic.yaml); None for real data."""
        v = self.meta.get("pixel_pitch_mm")
        return float(v) if v is not None else None

    def touch_count(self) -> dict[str, int]:
        return {s: len(self.touches.get(s, [])) for s in SPLITS}


@dataclass
class PatchSet:
    """32x32 tactile patches cut from touches, placed in a crop of the padded frame.

    Shape: gx, gy, contact (N, 32, 32) float32 (contact = sensor contact mask x object mask, in {0, 1});
    origin (N, 2) int (x, y) of each patch's top-left corner in crop pixels; touch (N,) int index into the split.
    """

    gx: np.ndarray
    gy: np.ndarray
    contact: np.ndarray
    origin: np.ndarray
    touch: np.ndarray

    def __len__(self) -> int:
        return int(self.gx.shape[0])


def parse_folder_name(name: str) -> tuple[str, int, int]:
    """`singleskit_<Material>_padded_<P>_x<k>` -> (material, P, k)."""
    m = FOLDER_RE.match(name)
    if not m:
        raise DatasetError(f"{name}: not a garment folder (expected singleskit_<Material>_padded_<P>_x<k>)")
    return m["material"], int(m["padded"]), int(m["mult"])


def find_garments(data_dir: Path) -> list[Path]:
    """Garment folders directly inside `data_dir`, or `data_dir` itself when it is one; sorted by name."""
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise DatasetError(f"{data_dir}: no such dataset folder")
    if FOLDER_RE.match(data_dir.name):
        return [data_dir]
    found = sorted(p for p in data_dir.iterdir() if p.is_dir() and FOLDER_RE.match(p.name))
    if not found:
        raise DatasetError(f"{data_dir}: no garment folders (singleskit_<Material>_padded_<P>_x<k>) inside")
    return found


def find_garment(data_dir: Path, name: str) -> Path:
    """The garment folder in `data_dir` that `name` denotes: DenimShorts, denim-shorts or the folder name."""
    found = find_garments(data_dir)
    for g in found:
        if same_garment(name, g.name):
            return g
    names = ", ".join(parse_folder_name(g.name)[0] for g in found)
    raise DatasetError(f"no garment {name!r} in {data_dir} (have: {names})")


def _single_image(root: Path, sub: str, required: bool) -> Path | None:
    folder = root / sub
    if not folder.is_dir():
        if required:
            raise DatasetError(f"{root.name}: missing sub-folder {sub}/")
        return None
    images = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_EXTS)
    if len(images) != 1:
        if not images and not required:
            return None
        raise DatasetError(f"{root.name}: {sub}/ must hold exactly one image; found {len(images)}")
    return images[0]


def _read_image(path: Path, color: bool, size: int) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR if color else cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise DatasetError(f"{path}: not a readable image")
    if img.shape[:2] != (size, size):
        raise DatasetError(f"{path}: expected {size}x{size} pixels (the padded size in the folder name); "
                           f"got {img.shape[1]}x{img.shape[0]}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if color else img


def _read_meta(root: Path) -> dict:
    path = root / "synthetic.yaml"
    if not path.is_file():
        return {}
    # A dataset's self-description, not a configuration: open-ended keys, of which this loader reads a few and
    # checks those where it reads them; the one loader's reader makes a broken file one line naming it.
    return loader.load_yaml(path, error=DatasetError, what="garment description")


def _frame_and_offset(meta: dict, padded: int, root: Path) -> tuple[tuple[int, int], tuple[int, int]]:
    frame = meta.get("frame", PUBLISHED_FRAME)
    try:
        fw, fh = (int(v) for v in frame)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{root.name}: synthetic.yaml 'frame' must be [width, height]; got {frame!r}") from exc
    default = ((padded - fw) // 2, (padded - fh) // 2)
    offset = meta.get("offset", meta.get("offsets", default))
    try:
        ox, oy = (int(v) for v in offset)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{root.name}: synthetic.yaml 'offset' must be [x, y]; got {offset!r}") from exc
    if not (0 <= ox and 0 <= oy and ox + fw <= padded and oy + fh <= padded):
        raise DatasetError(f"{root.name}: a {fw}x{fh} frame at offset ({ox}, {oy}) does not fit in {padded} px")
    return (fw, fh), (ox, oy)


def _as_mask01(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32)
    if a.size and a.max() > 1:
        a = a / 255.0
    return a > 0.5


def load_touch(path: Path, split: str, offset: tuple[int, int]) -> TactileTouch:
    """One `*_tactile.npz`; the rectangle is moved from camera pixels to the padded frame."""
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in TACTILE_KEYS if k not in z.files]
            if missing:
                raise DatasetError(f"{path}: missing keys {', '.join(missing)}")
            data = {k: z[k] for k in TACTILE_KEYS}
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a readable tactile file ({exc})") from exc
    gx = np.asarray(data["gx_raw"], dtype=np.float32)
    gy = np.asarray(data["gy_raw"], dtype=np.float32)
    if gx.ndim != 2 or gx.shape != gy.shape:
        raise DatasetError(f"{path}: gx_raw and gy_raw must be equal 2-D arrays; got {gx.shape}, {gy.shape}")
    contact, centres = _as_mask01(data["touch_thresh"]), _as_mask01(data["touch_center_thresh"])
    if contact.shape != gx.shape or centres.shape != gx.shape:
        raise DatasetError(f"{path}: touch_thresh/touch_center_thresh must match gx_raw's shape {gx.shape}")
    if not (np.isfinite(gx).all() and np.isfinite(gy).all()):
        raise DatasetError(f"{path}: gradients contain NaN or Inf")
    x, y, h, w = (int(np.asarray(data[k]).reshape(-1)[0]) for k in
                  ("vision_mask_x", "vision_mask_y", "vision_mask_h", "vision_mask_w"))
    return TactileTouch(path.stem, split, gx, gy, contact, centres, Rect(x + offset[0], y + offset[1], w, h))


def load_garment(root: Path, *, tactile: bool = True) -> Garment:
    """Read one garment folder. Raises DatasetError naming what is missing or malformed."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such garment folder")
    material, padded, mult = parse_folder_name(root.name)
    if mult != 1:
        raise DatasetError(f"{root.name}: tactile multiplier x{mult} is not supported (only x1 is published)")
    edited = "edit" in root.name
    meta = _read_meta(root)
    frame, offset = _frame_and_offset(meta, padded, root)
    sketch = _read_image(_single_image(root, "trainS", True), False, padded)  # type: ignore[arg-type]
    mask_path = _single_image(root, "trainM", not edited)
    visual_path = _single_image(root, "trainI", not edited)
    if mask_path is not None:
        mask = _read_image(mask_path, False, padded) > 127
    else:
        from kiosk.contract.sketch import object_mask
        mask = object_mask(sketch)
    visual = _read_image(visual_path, True, padded) if visual_path is not None else None
    g = Garment(root=root, material=material, padded_size=padded, multiplier=mult, frame=frame, offset=offset,
                edited=edited, sketch=sketch, mask=mask, visual=visual, meta=meta)
    if edited:
        return g
    test = [_single_image(root, s, False) for s in ("testS", "testM", "testI")]
    if all(p is not None for p in test):
        g.test_sketch = _read_image(test[0], False, padded)  # type: ignore[arg-type]
        g.test_mask = _read_image(test[1], False, padded) > 127  # type: ignore[arg-type]
        g.test_visual = _read_image(test[2], True, padded)  # type: ignore[arg-type]
    if tactile:
        for split in SPLITS:
            folder = root / f"{split}T"
            if not folder.is_dir():
                raise DatasetError(f"{root.name}: missing sub-folder {split}T/")
            g.touches[split] = [load_touch(p, split, offset) for p in sorted(folder.rglob("*_tactile.npz"))]
        if not g.touches["train"]:
            raise DatasetError(f"{root.name}: trainT/ holds no *_tactile.npz files")
        g.full_tactile = _load_full_tactile(root, padded)
    return g


def _load_full_tactile(root: Path, padded: int) -> FullTactile | None:
    files = sorted((root / "fullT").glob("*_full_tactile.npz")) if (root / "fullT").is_dir() else []
    if not files:
        return None
    with np.load(files[0], allow_pickle=False) as z:
        if "gx" not in z.files or "gy" not in z.files:
            raise DatasetError(f"{files[0]}: full tactile file needs keys gx and gy")
        gx, gy = z["gx"].astype(np.float32), z["gy"].astype(np.float32)
        height = z["height_mm"].astype(np.float32) if "height_mm" in z.files else None
        pitch = float(z["pixel_pitch_mm"]) if "pixel_pitch_mm" in z.files else 0.3
    if gx.shape != (padded, padded) or gy.shape != (padded, padded):
        raise DatasetError(f"{files[0]}: gx/gy must be {padded}x{padded}; got {gx.shape}")
    return FullTactile(gx, gy, height, pitch)


def valid_centres(touch: TactileTouch, patch: int = PATCH) -> np.ndarray:
    """(K, 2) int (row, col) of allowed patch centres whose patch lies inside the touch's own arrays."""
    half = patch // 2
    rows, cols = np.nonzero(touch.centres)
    h, w = touch.gx.shape
    ok = (rows - half >= 0) & (rows + half <= h) & (cols - half >= 0) & (cols + half <= w)
    return np.stack([rows[ok], cols[ok]], axis=1)


def extract_patches(g: Garment, split: str, *, crop_origin: tuple[int, int] = (0, 0),
                    crop_size: tuple[int, int] | None = None, per_touch: int = 1, mode: str = "random",
                    rng: np.random.Generator | None = None, mask: np.ndarray | None = None,
                    patch: int = PATCH) -> PatchSet:
    """Cut 32x32 patches from a split's touches, following the published rules.

    A patch is centred on an allowed centre (touch_center_thresh); its mask is contact mask x object mask; patches
    not fully inside the crop, or with no object pixel, are dropped. Tactile pixel (r, c) of a touch maps to visual
    pixel (rect.y + r, rect.x + c) (multiplier 1). `mode` "random" draws `per_touch` centres per touch with `rng`;
    "centre" takes the allowed centre nearest the middle of each touch (deterministic: for evaluation).
    `crop_origin` (x, y) and `crop_size` (width, height) are in padded-frame pixels; `mask` overrides the garment's
    object mask (e.g. an augmented one) and must then be given in crop coordinates.
    """
    if split not in g.touches:
        raise DatasetError(f"{g.name}: no tactile split {split!r} loaded")
    if mode not in ("random", "centre"):
        raise ValueError(f"mode must be 'random' or 'centre'; got {mode!r}")
    if mode == "random" and rng is None:
        raise ValueError("mode 'random' needs an rng (numpy Generator) for reproducibility")
    cx0, cy0 = crop_origin
    cw, ch = crop_size if crop_size is not None else (g.padded_size - cx0, g.padded_size - cy0)
    obj = mask if mask is not None else g.mask[cy0:cy0 + ch, cx0:cx0 + cw]
    if obj.shape != (ch, cw):
        raise ValueError(f"mask must have the crop's shape {(ch, cw)}; got {obj.shape}")
    half = patch // 2
    out_gx, out_gy, out_c, out_o, out_t = [], [], [], [], []
    for ti, touch in enumerate(g.touches[split]):
        centres = valid_centres(touch, patch)
        if len(centres) == 0:
            continue
        # Crop-frame top-left corner of each candidate patch.
        ox = touch.rect.x + centres[:, 1] - half - cx0
        oy = touch.rect.y + centres[:, 0] - half - cy0
        inside = (ox >= 0) & (oy >= 0) & (ox + patch <= cw) & (oy + patch <= ch)
        centres, ox, oy = centres[inside], ox[inside], oy[inside]
        if len(centres) == 0:
            continue
        if mode == "centre":
            mid = np.array([touch.gx.shape[0] / 2, touch.gx.shape[1] / 2])
            order = np.argsort(((centres - mid) ** 2).sum(axis=1), kind="stable")
        else:
            order = rng.permutation(len(centres))  # type: ignore[union-attr]
        taken = 0
        for k in order:
            r, c = centres[k]
            m = obj[oy[k]:oy[k] + patch, ox[k]:ox[k] + patch]
            contact = touch.contact[r - half:r + half, c - half:c + half] & m
            if not m.any():
                continue
            out_gx.append(touch.gx[r - half:r + half, c - half:c + half])
            out_gy.append(touch.gy[r - half:r + half, c - half:c + half])
            out_c.append(contact.astype(np.float32))
            out_o.append((int(ox[k]), int(oy[k])))
            out_t.append(ti)
            taken += 1
            if taken >= (1 if mode == "centre" else per_touch):
                break
    if not out_gx:
        empty = np.zeros((0, patch, patch), np.float32)
        return PatchSet(empty, empty.copy(), empty.copy(), np.zeros((0, 2), int), np.zeros(0, int))
    return PatchSet(np.stack(out_gx).astype(np.float32), np.stack(out_gy).astype(np.float32),
                    np.stack(out_c), np.array(out_o, dtype=int), np.array(out_t, dtype=int))


def friction_scale(g: Garment, split: str = "train", quantile: float = 0.98) -> float:
    """The garment's calibrated friction scale from its measured contact pixels (what the exporter stores)."""
    touches = g.touches.get(split, [])
    if not touches:
        raise DatasetError(f"{g.name}: no {split} touches to calibrate the friction scale from")
    gx = np.concatenate([t.gx[t.contact] for t in touches])[None, :]
    gy = np.concatenate([t.gy[t.contact] for t in touches])[None, :]
    return calibrate_scale(gx, gy, quantile=quantile)
