"""The hard synthetic profile: sparse touches at the paper's density, a photo that is not a function of the touch
field, folds that shade without touching the tactile truth, registration jitter, determinism; and the easy profile
reproducing the generator before profiles bit for bit."""
from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from trainer.data import synthetic as syn
from trainer.data.cli import main as data_cli
from trainer.data.touchclothing import load_garment

FRAME = (320, 240)


def folder_digest(folder: Path) -> str:
    """SHA-256 over a garment folder's contents: decoded pixels, npz arrays, text (zip timestamps left out)."""
    h = hashlib.sha256()
    for f in sorted(p for p in Path(folder).rglob("*") if p.is_file()):
        h.update(str(f.relative_to(folder)).encode())
        if f.suffix == ".png":
            h.update(cv2.imread(str(f), cv2.IMREAD_UNCHANGED).tobytes())
        elif f.suffix == ".npz":
            with np.load(f) as z:
                for k in sorted(z.files):
                    h.update(k.encode())
                    h.update(np.ascontiguousarray(z[k]).tobytes())
        else:
            h.update(f.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The same garment spec in both profiles."""
    out = tmp_path_factory.mktemp("profiles")
    spec = syn.default_specs(1, 3)[0]
    return {p: syn.generate_garment(out / p, spec, frame=FRAME, profile=p) for p in ("easy", "hard")}


def _meta(folder: Path) -> dict:
    return yaml.safe_load((folder / "synthetic.yaml").read_text())


def _rects(folder: Path) -> list[tuple[str, dict]]:
    out = []
    for sub in ("trainT", "valT", "testT"):
        for f in sorted((folder / sub).glob("*.npz")):
            with np.load(f) as z:
                out.append((sub, {k: z[k] for k in z.files} | {"serial": int(f.name.split("_")[1])}))
    return out


def test_easy_profile_is_the_generator_before_profiles_bit_for_bit(tmp_path: Path) -> None:
    # digest of the generator as it was before profiles existed (same spec, frame and seed)
    spec = syn.default_specs(1, 5)[0]
    folder = syn.generate_garment(tmp_path, spec, frame=(256, 192), profile="easy")
    assert folder_digest(folder) == "d331ee751033e7744979c8fd9a96733c7737fcd5b0b53dc0cd6740358f1be62e"
    assert "profile" not in _meta(folder) and load_garment(folder).profile == "easy"


def test_hard_is_the_default_and_metadata_records_profile_and_pitch(pair: dict[str, Path], tmp_path: Path) -> None:
    assert syn.DEFAULT_PROFILE == "hard"
    meta = _meta(pair["hard"])
    assert meta["profile"] == "hard" and meta["pixel_pitch_mm"] == pytest.approx(0.3)
    g = load_garment(pair["hard"])
    assert g.profile == "hard" and g.pixel_pitch_mm == pytest.approx(0.3)
    assert _meta(pair["easy"])["pixel_pitch_mm"] == pytest.approx(0.3)
    assert meta["colours"]["thread"] == meta["colours"]["garment"]  # seams and stitching in matching thread
    assert data_cli(["synth", "--out", str(tmp_path), "--garments", "1", "--frame", "192x144", "--no-progress"]) == 0
    assert _meta(next(tmp_path.glob("singleskit_*")))["profile"] == "hard"


@pytest.mark.parametrize("frame", [(320, 240), (640, 480)])
def test_touch_rectangles_cover_a_sixth_of_the_frame_at_most_and_split_six_two_two(tmp_path: Path, frame) -> None:
    spec = syn.default_specs(1, 0)[0]  # denim shorts fill ~40 % of the frame: the 1/6 target applies
    folder = syn.generate_garment(tmp_path, spec, frame=frame, profile="hard")
    meta, g = _meta(folder), load_garment(folder)
    w, h = frame
    rects = _rects(folder)
    rh, rw = syn.sensor_rect_size(frame)
    cover = np.zeros((h, w), bool)
    for _, z in rects:
        x, y = int(z["vision_mask_x"]), int(z["vision_mask_y"])
        cover[y:y + rh, x:x + rw] = True
    target = meta["touch_coverage_target"]
    frame_mask = g.mask[g.offset[1]:g.offset[1] + h, g.offset[0]:g.offset[0] + w]
    assert target == pytest.approx(min(1 / 6, syn.GARMENT_COVERAGE_CAP * frame_mask.mean()), abs=1e-3)
    assert target == pytest.approx(1 / 6, abs=0.01)
    # recorded (jittered) rectangles: within one rectangle of the target
    assert abs(cover.mean() - target) <= rh * rw / (w * h) + 1e-9, (cover.mean(), target)
    # most of the garment stays untouched, to generalise to
    assert (cover & frame_mask).sum() / frame_mask.sum() < 0.5
    n = len(rects)
    counts = {s: sum(1 for sub, _ in rects if sub == s) for s in ("trainT", "valT", "testT")}
    assert counts == {"trainT": round(0.6 * n), "valT": round(0.2 * n), "testT": n - round(0.6 * n) - round(0.2 * n)}
    if frame[0] >= 640:  # at smaller frames the sensor rectangle's 48 x 40 px floor leaves room for fewer touches
        assert counts["testT"] >= 4
    # every test touch offers patch centres, many in all (the per-centre evaluation scores each)
    centres = [int(z["touch_center_thresh"].astype(bool).sum()) for sub, z in rects if sub == "testT"]
    assert min(centres) > 0 and sum(centres) >= 50, centres


def test_slim_garment_keeps_most_of_itself_untouched(tmp_path: Path) -> None:
    spec = syn.default_specs(2, 0)[1]  # corduroy trousers fill ~20 % of the frame
    folder = syn.generate_garment(tmp_path, spec, frame=FRAME, profile="hard")
    meta = _meta(folder)
    assert meta["touch_coverage_target"] < 1 / 6
    assert meta["touch_coverage_of_garment"] < 0.6


def _slope_r2(folder: Path) -> float:
    """Share of the photo's luminance variance on the garment explained by the tactile slope (gx, gy) alone."""
    g = load_garment(folder)
    m = g.mask
    lum = cv2.cvtColor(g.visual, cv2.COLOR_RGB2GRAY).astype(np.float64)[m]
    q = [np.clip(np.round(a[m] / 0.02), -30, 30).astype(int) for a in (g.full_tactile.gx, g.full_tactile.gy)]
    _, inv, cnt = np.unique(q[0] * 100 + q[1], return_inverse=True, return_counts=True)
    means = np.bincount(inv, lum) / cnt
    return float(1 - ((lum - means[inv]) ** 2).mean() / lum.var())


def test_visual_is_not_a_function_of_the_slope_alone(pair: dict[str, Path]) -> None:
    easy, hard = _slope_r2(pair["easy"]), _slope_r2(pair["hard"])
    assert easy > 0.8, easy  # easy: the photo nearly encodes the slope
    assert hard < 0.6, hard


def test_folds_shade_the_photo_but_leave_the_tactile_truth(tmp_path: Path, monkeypatch) -> None:
    spec = syn.default_specs(1, 3)[0]
    folded = syn.generate_garment(tmp_path / "folded", spec, frame=FRAME, profile="hard")
    meta = _meta(folded)
    assert len(meta["realism"]["folds"]) >= 2
    lo, hi = meta["realism"]["fold_height_range_mm"]
    assert hi - lo > 2.0
    original = syn.sample_realism
    monkeypatch.setattr(syn, "sample_realism",
                        lambda *a, **k: replace(original(*a, **k), folds=(), wrinkle_mm=0.0))
    flat = syn.generate_garment(tmp_path / "flat", spec, frame=FRAME, profile="hard")
    a, b = load_garment(folded), load_garment(flat)
    for k in ("gx", "gy", "height_mm"):
        assert np.array_equal(getattr(a.full_tactile, k), getattr(b.full_tactile, k)), k
    assert np.array_equal(a.sketch, b.sketch)
    diff = a.visual.astype(np.float32) - b.visual.astype(np.float32)
    low = cv2.GaussianBlur(np.abs(diff).mean(-1), (0, 0), 8.0)
    assert low[a.mask].mean() > 2.0  # a broad change of shading, in grey levels
    # the weave survives: the folded photo's fine detail still follows the unfolded one's
    hp = [(v.astype(np.float32) - cv2.GaussianBlur(v.astype(np.float32), (0, 0), 2.0)).mean(-1)[a.mask]
          for v in (a.visual, b.visual)]
    assert np.corrcoef(hp[0], hp[1])[0, 1] > 0.5


def test_touches_are_registered_with_a_small_jitter(pair: dict[str, Path]) -> None:
    folder = pair["hard"]
    meta, g = _meta(folder), load_garment(folder)
    offsets = np.asarray(meta["realism"]["registration_offsets_px"])
    assert offsets.shape == (meta["touches"], 2) and np.abs(offsets).max() <= 6 and np.abs(offsets).sum() > 0
    ox, oy = g.offset
    for _, z in _rects(folder):
        dx, dy = offsets[z["serial"] - 1]
        x, y = int(z["vision_mask_x"]) - dx + ox, int(z["vision_mask_y"]) - dy + oy
        h, w = z["gx_raw"].shape
        resid = z["gx_raw"] - g.full_tactile.gx[y:y + h, x:x + w]
        assert resid.std() == pytest.approx(syn.SENSOR_NOISE, rel=0.3)  # pressed place = recorded - offset


def test_hard_profile_is_deterministic_per_seed(tmp_path: Path, pair: dict[str, Path]) -> None:
    spec = syn.default_specs(1, 3)[0]
    again = syn.generate_garment(tmp_path / "again", spec, frame=FRAME, profile="hard")
    assert folder_digest(again) == folder_digest(pair["hard"])
    other = syn.generate_garment(tmp_path / "other", replace(spec, seed=spec.seed + 1), frame=FRAME, profile="hard")
    assert folder_digest(other) != folder_digest(pair["hard"])


def test_unknown_profile_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown data profile 'medium'"):
        syn.generate_garment(tmp_path, syn.default_specs(1, 0)[0], frame=FRAME, profile="medium")
    with pytest.raises(ValueError, match="unknown data profile"):
        syn.generate_dataset(tmp_path, garments=1, frame=FRAME, progress=False, profile="")
