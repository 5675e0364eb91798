"""Everything wrong with a garment folder's layout at once, each problem with the fix an operator can act on.

Loading (touchclothing.py) stops at the first problem; someone laying out downloaded TouchClothing data wants the
whole list in one pass: a misnamed folder, a missing or mis-cased sub-folder, a folder with no image or two, an image
at the unpadded camera size, touch files without the `_tactile.npz` suffix or with keys under other names. Only file
names, image headers and npz key lists are read, so this stays quick on the full 20-garment set.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from trainer.data.touchclothing import FOLDER_RE, IMAGE_EXTS, PUBLISHED_FRAME, SPLITS, TACTILE_KEYS

IMAGE_SUBS = {"S": "sketch (grayscale, ink dark on white)", "I": "visual image (RGB photo)",
              "M": "object mask (grayscale, garment white)"}
# Names seen in other tools' exports for the published keys; a hint, never accepted silently.
KEY_ALIASES = {"gx_raw": ("gx",), "gy_raw": ("gy",), "touch_thresh": ("contact", "touch_mask"),
               "touch_center_thresh": ("centres", "centers", "touch_center")}


@dataclass(frozen=True)
class Problem:
    """`where` (a path relative to the garment's parent), what is wrong, and what to do about it."""

    where: str
    what: str
    fix: str
    fatal: bool = True

    def __str__(self) -> str:
        return f"{self.where}: {self.what}; {self.fix}"


def _rel(root: Path, path: Path) -> str:
    return path.relative_to(root.parent).as_posix() + ("/" if path.is_dir() else "")


def name_problem(name: str, side: int | None = None) -> Problem | None:
    """Why `name` is not `singleskit_<Material>_padded_<P>_x1`, and the name it should have (`side`: the images'
    side in pixels, when known)."""
    m = FOLDER_RE.match(name)
    if m:
        if m["mult"] != "1":
            return Problem(name, f"tactile multiplier x{m['mult']} is not supported",
                           "only x1 (one tactile pixel per visual pixel) is published; use the x1 data")
        return None
    material = re.sub(r"^singleskit_", "", name)
    material = re.sub(r"_padded(_\d+)?(_x\d+)?$", "", material)
    material = re.sub(r"_x\d+$", "", material)
    material = "".join(part[:1].upper() + part[1:] for part in re.split(r"[\s_-]+", material) if part) or "Material"
    padded = re.search(r"padded_(\d+)", name)
    p = padded[1] if padded else (str(side) if side else "<P>")
    return Problem(name + "/", "not a garment folder name (expected singleskit_<Material>_padded_<P>_x1)",
                   f"rename it to singleskit_{material}_padded_{p}_x1" + ("" if padded or side else
                                                                         ", P = the images' side in pixels"))


def _images(folder: Path) -> tuple[list[Path], list[Path]]:
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    return [p for p in files if p.suffix.lower() in IMAGE_EXTS], [p for p in files if p.suffix.lower()
                                                                  not in IMAGE_EXTS]


def _missing_folder(root: Path, sub: str, what: str) -> Problem:
    twins = [p for p in root.iterdir() if p.is_dir() and p.name.lower() == sub.lower()]
    if twins:
        return Problem(_rel(root, twins[0]), f"misnamed: the loader looks for {sub}/ (case matters)",
                       f"rename it to {sub}/")
    return Problem(_rel(root, root) + sub + "/", "missing", f"create it and put the {what} there")


def _image_problems(root: Path, sub: str, side: int | None) -> list[Problem]:
    folder = root / sub
    images, others = _images(folder)
    where = _rel(root, folder)
    what = IMAGE_SUBS[sub[-1]]
    if not images:
        seen = f" (found {', '.join(p.name for p in others[:3])})" if others else ""
        return [Problem(where, f"must hold exactly one image; found none{seen}",
                        f"put the {what} there as PNG (extensions: {' '.join(IMAGE_EXTS)})")]
    if len(images) > 1:
        return [Problem(where, f"must hold exactly one image; found {len(images)} "
                               f"({', '.join(p.name for p in images[:4])})", "keep one, move the others out")]
    img = cv2.imread(str(images[0]), cv2.IMREAD_UNCHANGED)
    if img is None:
        return [Problem(_rel(root, images[0]), "not a readable image", "re-save it as PNG")]
    h, w = img.shape[:2]
    if side is None or (h, w) == (side, side):
        return []
    if (w, h) == PUBLISHED_FRAME:
        fix = (f"this is the unpadded {w}x{h} camera frame: pad it to {side}x{side} with the frame at "
               f"({(side - w) // 2}, {(side - h) // 2}) (docs/real-garments.md)")
    elif w == h:
        fix = f"the folder name says padded_{side}: resize the image to {side}x{side}, or rename the folder " \
              f"to ..._padded_{w}_x1 if every image is {w}x{w}"
    else:
        fix = f"images must be square, {side}x{side} (the padded size in the folder name)"
    return [Problem(_rel(root, images[0]), f"is {w}x{h} pixels, expected {side}x{side}", fix)]


def _touch_problems(root: Path, split: str) -> list[Problem]:
    folder = root / f"{split}T"
    where = _rel(root, folder)
    touches = sorted(folder.rglob("*_tactile.npz"))
    if not touches:
        npz = sorted(p for p in folder.rglob("*.npz"))
        fatal = split == "train"
        if npz:
            return [Problem(where, f"no *_tactile.npz touch files; found {len(npz)} other .npz "
                                   f"({', '.join(p.name for p in npz[:3])})",
                            f"touch files are named <material>_<serial>_tactile.npz: rename e.g. {npz[0].name} "
                            f"to {npz[0].stem}_tactile.npz", fatal)]
        return [Problem(where, "no touches (*_tactile.npz)",
                        "copy the garment's tactile files there" if fatal else
                        f"without {split} touches the {split} metrics are empty; copy them if you have them", fatal)]
    problems = []
    for path in touches:
        try:
            with np.load(path, allow_pickle=False) as z:
                keys = set(z.files)
        except (OSError, ValueError) as exc:
            problems.append(Problem(_rel(root, path), f"not a readable .npz ({exc})", "copy the file again"))
            continue
        missing = [k for k in TACTILE_KEYS if k not in keys]
        if missing:
            hints = [f"{a} -> {k}" for k in missing for a in KEY_ALIASES.get(k, ()) if a in keys]
            fix = f"rename keys {', '.join(hints)}" if hints else \
                "the published files hold gx_raw gy_raw vision_mask_{x,y,h,w} touch_thresh touch_center_thresh"
            problems.append(Problem(_rel(root, path), f"missing keys {', '.join(missing)}", fix))
    if len(problems) > 3:       # one broken export breaks them all: say it once, with the count
        problems = problems[:3] + [Problem(where, f"... and {len(problems) - 3} more touch files with problems",
                                           "the fix above applies to them too")]
    return problems


def layout_problems(root: Path) -> list[Problem]:
    """Every layout problem of one garment folder (fatal ones stop training; others are warnings)."""
    root = Path(root)
    m = FOLDER_RE.match(root.name)
    side = int(m["padded"]) if m else None
    problems: list[Problem] = []
    named = name_problem(root.name, side)
    edited = "edit" in root.name
    subs = [f"train{s}" for s in ("S",) if edited] or ["trainS", "trainI", "trainM"]
    present = []
    for sub in subs:
        if (root / sub).is_dir():
            present.append(sub)
        else:
            problems.append(_missing_folder(root, sub, IMAGE_SUBS[sub[-1]]))
    if named is not None and side is None:
        for sub in present:        # the images' side makes the fix's name concrete
            images, _ = _images(root / sub)
            img = cv2.imread(str(images[0]), cv2.IMREAD_UNCHANGED) if len(images) == 1 else None
            if img is not None and img.shape[0] == img.shape[1]:
                named = name_problem(root.name, img.shape[0])
                break
    if named is not None:
        problems.insert(0, named)
    for sub in present:
        problems += _image_problems(root, sub, side)
    test_subs = [s for s in ("testS", "testI", "testM") if (root / s).is_dir()]
    if test_subs and len(test_subs) < 3 and not edited:
        for s in sorted({"testS", "testI", "testM"} - set(test_subs)):
            problems.append(Problem(_rel(root, root) + s + "/", "missing while other test images exist",
                                    f"add the test {IMAGE_SUBS[s[-1]]}, or remove the test image folders", False))
    for sub in test_subs if len(test_subs) == 3 else []:
        problems += [Problem(p.where, p.what, p.fix, False) for p in _image_problems(root, sub, side)]
    if not edited:
        for split in SPLITS:
            if (root / f"{split}T").is_dir():
                problems += _touch_problems(root, split)
            else:
                problems.append(_missing_folder(root, f"{split}T", f"{split} touches (*_tactile.npz)"))
    return problems


def looks_like_garment(folder: Path) -> bool:
    """A folder someone meant as a garment: its name says so, or it holds the layout's sub-folders."""
    if "singleskit" in folder.name.lower() or "padded" in folder.name.lower():
        return True
    subs = {p.name.lower() for p in folder.iterdir() if p.is_dir()}
    return len(subs & {"trains", "traini", "trainm", "traint", "valt", "testt"}) >= 2
