"""Synthetic garments (easy profile): the published TouchClothing layout, physically consistent tactile truth, fabric
character. The hard profile's own properties: test_synthetic_hard.py."""
from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from kiosk.contract.haptics import height_from_gradients
from trainer.data import synthetic as syn
from trainer.data.synth_fabrics import FABRICS, sample_fabric, texture

FRAME = (320, 240)
P, OX, OY = 450, 65, 105
KEYS = {"gx_raw", "gy_raw", "vision_mask_x", "vision_mask_y", "vision_mask_h", "vision_mask_w", "touch_thresh",
        "touch_center_thresh"}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    out = tmp_path_factory.mktemp("synth")
    return syn.generate_dataset(out, garments=2, seed=3, frame=FRAME, progress=False, profile="easy")


def _one(folder: Path, sub: str) -> Path:
    files = sorted((folder / sub).iterdir())
    assert len(files) == 1, f"{folder.name}/{sub} must hold exactly one file, has {[f.name for f in files]}"
    return files[0]


def _touches(folder: Path) -> list[tuple[str, Path]]:
    return [(sub, f) for sub in ("trainT", "valT", "testT") for f in sorted((folder / sub).glob("*.npz"))]


def _full(folder: Path) -> dict[str, np.ndarray]:
    with np.load(next((folder / "fullT").glob("*_full_tactile.npz"))) as z:
        return {k: z[k] for k in z.files}


def test_padded_geometry_matches_published_and_scales() -> None:
    assert syn.padded_geometry((1280, 960)) == (1800, 260, 420)
    assert syn.padded_geometry(FRAME) == (P, OX, OY)
    assert syn.sensor_rect_size((1280, 960)) == (104, 78)
    assert syn.touch_target((1280, 960)) == 250


def test_folder_layout_names_and_images(dataset: list[Path]) -> None:
    assert [d.name for d in dataset] == ["singleskit_DenimShorts_padded_450_x1",
                                         "singleskit_CorduroyTrousers_padded_450_x1"]
    for d in dataset:
        material = d.name.split("_")[1].lower()
        assert {c.name for c in d.iterdir()} == set(syn.SUBFOLDERS) | {"fullT", "synthetic.yaml"}
        sketch = cv2.imread(str(_one(d, "trainS")), cv2.IMREAD_UNCHANGED)
        bgr = cv2.imread(str(_one(d, "trainI")), cv2.IMREAD_UNCHANGED)
        mask = cv2.imread(str(_one(d, "trainM")), cv2.IMREAD_UNCHANGED)
        assert sketch.shape == (P, P) and sketch.dtype == np.uint8
        assert bgr.shape == (P, P, 3) and mask.shape == (P, P)
        assert set(np.unique(mask)) == {0, 255}
        assert mask[:OY].max() == 0 and mask[:, :OX].max() == 0          # padding: no object
        assert sketch[:OY].min() == 255 and sketch[:, :OX].min() == 255  # padding: paper
        assert (sketch[mask > 0] == 0).any()                              # ink on the garment
        meta = yaml.safe_load((d / "synthetic.yaml").read_text())
        table = np.round(np.asarray(meta["colours"]["table"]) * 255).astype(int)
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        assert (rgb[0, 0] == table).all(), "padding of I must be the table colour in RGB order"
        for k in "SIM":
            assert _one(d, f"test{k}").read_bytes() == _one(d, f"train{k}").read_bytes()
        assert meta["frame"] == list(FRAME) and meta["offsets"] == [OX, OY] and meta["padded_size"] == P
        assert meta["pixel_pitch_mm"] == pytest.approx(0.3)
        touches = _touches(d)
        assert len(touches) == meta["touches"] == syn.touch_target(FRAME)
        serials = []
        for _, f in touches:
            m = re.fullmatch(rf"{material}_(\d{{4}})_tactile\.npz", f.name)
            assert m, f.name
            serials.append(int(m.group(1)))
            with np.load(f) as z:
                assert set(z.files) == KEYS
                assert z["gx_raw"].dtype == np.float32 and z["gy_raw"].dtype == np.float32
                assert z["touch_thresh"].dtype == np.uint8 and z["touch_thresh"].shape == z["gx_raw"].shape
                assert z["touch_center_thresh"].shape == z["gx_raw"].shape
                assert z["gx_raw"].shape == (int(z["vision_mask_h"]), int(z["vision_mask_w"]))
        assert sorted(serials) == list(range(1, len(touches) + 1))
        full = _full(d)
        assert set(full) == {"gx", "gy", "height_mm", "pixel_pitch_mm"}
        assert full["gx"].shape == full["height_mm"].shape == (P, P) and full["gx"].dtype == np.float32
        assert float(full["pixel_pitch_mm"]) == pytest.approx(0.3)
        assert not full["gx"][mask == 0].any() and not full["height_mm"][mask == 0].any()


def test_rectangles_inside_frame_with_centre_on_garment(dataset: list[Path]) -> None:
    for d in dataset:
        mask = cv2.imread(str(_one(d, "trainM")), cv2.IMREAD_GRAYSCALE)[OY:OY + FRAME[1], OX:OX + FRAME[0]]
        for _, f in _touches(d):
            with np.load(f) as z:
                x, y, h, w = (int(z[k]) for k in ("vision_mask_x", "vision_mask_y", "vision_mask_h", "vision_mask_w"))
            assert (h, w) == syn.sensor_rect_size(FRAME)
            assert 0 <= x and x + w <= FRAME[0] and 0 <= y and y + h <= FRAME[1]
            assert mask[y + h // 2, x + w // 2] == 255


def test_gx_raw_is_full_field_plus_sensor_noise(dataset: list[Path]) -> None:
    for d in dataset:
        full = _full(d)
        res = []
        for _, f in _touches(d):
            with np.load(f) as z:
                x, y, h, w = (int(z[k]) for k in ("vision_mask_x", "vision_mask_y", "vision_mask_h", "vision_mask_w"))
                res.append(z["gx_raw"] - full["gx"][OY + y:OY + y + h, OX + x:OX + x + w])
                res.append(z["gy_raw"] - full["gy"][OY + y:OY + y + h, OX + x:OX + x + w])
        r = np.concatenate([a.ravel() for a in res])
        assert abs(r.mean()) < 0.1 * syn.SENSOR_NOISE
        assert 0.9 * syn.SENSOR_NOISE < r.std() < 1.1 * syn.SENSOR_NOISE
        assert np.abs(r).max() < 7 * syn.SENSOR_NOISE


def test_gradients_are_those_of_the_height_field(dataset: list[Path]) -> None:
    for d in dataset:
        full = _full(d)
        hmm, p = full["height_mm"], float(full["pixel_pitch_mm"])
        mask = hmm > 0
        inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        cx = (hmm[1:-1, 2:] - hmm[1:-1, :-2]) / (2 * p)
        cy = (hmm[2:, 1:-1] - hmm[:-2, 1:-1]) / (2 * p)
        np.testing.assert_allclose(full["gx"][1:-1, 1:-1][inner[1:-1, 1:-1]], cx[inner[1:-1, 1:-1]], atol=1e-5)
        np.testing.assert_allclose(full["gy"][1:-1, 1:-1][inner[1:-1, 1:-1]], cy[inner[1:-1, 1:-1]], atol=1e-5)
        rec = height_from_gradients(full["gx"], full["gy"], pixel_pitch=p)
        core = cv2.erode(mask.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
        err = (rec - hmm)[core]
        assert (err - err.mean()).std() < 0.1 * hmm[core].std()
        a = np.abs(np.concatenate([full["gx"][mask], full["gy"][mask]]))
        # At 320x240 hems and seams cover a large share of a small garment, so "mostly" is the median here; at
        # 1280x960 about 90 % of slopes stay under 0.3.
        assert np.percentile(a, 50) < 0.2, "fabric slopes must stay mostly within +-0.3 like the real data"
        assert np.percentile(a, 99.5) > 0.3, "seams, edges and buttons must give larger local slopes"


def test_contact_mask_follows_the_75th_percentile_rule(dataset: list[Path]) -> None:
    for d in dataset:
        full = _full(d)
        fracs = []
        for _, f in _touches(d):
            with np.load(f) as z:
                x, y, h, w = (int(z[k]) for k in ("vision_mask_x", "vision_mask_y", "vision_mask_h", "vision_mask_w"))
                thresh, centre = z["touch_thresh"], z["touch_center_thresh"]
            hr = full["height_mm"][OY + y:OY + y + h, OX + x:OX + x + w]
            hi = hr > np.percentile(hr, 75)
            fracs.append(hi.mean())
            assert set(np.unique(thresh)) <= {0, 255} and set(np.unique(centre)) <= {0, 255}
            assert (thresh[hi] == 255).all(), "dilation must keep every contact pixel"
            assert (thresh == 255).mean() > hi.mean()
            assert centre.any() and (thresh[centre > 0] == 255).all()
            assert not centre[:16].any() and not centre[:, :16].any()
            assert not centre[h - 15:].any() and not centre[:, w - 15:].any()
        assert 0.2 < np.mean(fracs) <= 0.25


def test_split_is_six_two_two(dataset: list[Path]) -> None:
    for d in dataset:
        n = {s: len(list((d / s).glob("*_tactile.npz"))) for s in ("trainT", "valT", "testT")}
        total = sum(n.values())
        assert n["trainT"] == round(0.6 * total) and n["valT"] == round(0.2 * total)
        assert n["testT"] == total - n["trainT"] - n["valT"]


def _arrays(folder: Path) -> dict[str, np.ndarray]:
    out = {}
    for sub in ("trainS", "trainI", "trainM"):
        out[sub] = cv2.imread(str(_one(folder, sub)), cv2.IMREAD_UNCHANGED)
    for sub, f in _touches(folder):
        with np.load(f) as z:
            for k in z.files:
                out[f"{sub}/{f.name}/{k}"] = z[k]
    for k, v in _full(folder).items():
        out[f"fullT/{k}"] = v
    return out


def test_deterministic_for_a_seed(tmp_path: Path, dataset: list[Path]) -> None:
    spec = syn.default_specs(2, 3)[0]
    again = _arrays(syn.generate_garment(tmp_path / "a", spec, frame=FRAME, profile="easy"))
    first = _arrays(dataset[0])
    assert again.keys() == first.keys()
    for k in first:
        assert first[k].tobytes() == again[k].tobytes(), k
    other = _arrays(syn.generate_garment(tmp_path / "b", replace(spec, seed=spec.seed + 1), frame=FRAME,
                                         profile="easy"))
    assert other["trainI"].tobytes() != first["trainI"].tobytes()
    assert other["fullT/height_mm"].tobytes() != first["fullT/height_mm"].tobytes()
    assert syn.default_specs(3, 1) != syn.default_specs(3, 2)


def test_prints_change_albedo_not_height(tmp_path: Path) -> None:
    spec = syn.GarmentSpec(name="KnitSkirt", shape="skirt", fabric="knit", seed=11, flowers=0, text="")
    plain = _arrays(syn.generate_garment(tmp_path / "plain", spec, frame=FRAME, profile="easy"))
    printed = _arrays(syn.generate_garment(tmp_path / "print", replace(spec, text="VT"), frame=FRAME, profile="easy"))
    assert plain["fullT/height_mm"].tobytes() == printed["fullT/height_mm"].tobytes()
    assert np.abs(plain["trainI"].astype(int) - printed["trainI"].astype(int)).max() > 100


def _peak_period_mm(profile_power: np.ndarray, n: int, pitch: float) -> float:
    freqs = np.fft.rfftfreq(n, d=pitch)
    k = 1 + int(np.argmax(profile_power[1:]))
    return 1.0 / freqs[k]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fabric_height_fields_have_their_documented_character(seed: int) -> None:
    n, pitch = 512, 0.3
    hs = {}
    for f in FABRICS:
        rng = np.random.default_rng(seed)
        params = sample_fabric(f, rng)
        hs[f] = (params, texture(params, (n, n), pitch_mm=pitch, angle_deg=0.0, rng=rng))
    # corduroy: wales across x, 2-4 mm wide, ~0.3 mm high
    prm, h = hs["corduroy"]
    period = _peak_period_mm((np.abs(np.fft.rfft(h, axis=1)) ** 2).mean(0), n, pitch)
    assert 2.0 <= period <= 4.0 and period == pytest.approx(prm.period_mm, rel=0.1)
    assert 0.2 < np.percentile(h, 99) - np.percentile(h, 1) < 0.4
    # denim: diagonal twill ribs 1-1.5 mm apart
    _, h = hs["denim"]
    spec = np.abs(np.fft.fft2(h)) ** 2
    spec[0, 0] = 0
    ky, kx = np.unravel_index(np.argmax(spec), spec.shape)
    fy, fx = np.fft.fftfreq(n, pitch)[ky], np.fft.fftfreq(n, pitch)[kx]
    assert abs(abs(fx) - abs(fy)) < 0.1 * abs(fx) and fx != 0
    assert 1.0 <= 1.0 / np.hypot(fx, fy) <= 1.5
    # knit: courses (V rows) 2-2.6 mm apart along the grain
    prm, h = hs["knit"]
    period = _peak_period_mm((np.abs(np.fft.rfft(h, axis=0)) ** 2).mean(1), n, pitch)
    assert period == pytest.approx(prm.course_mm, rel=0.1)
    # linen: plain weave checker, two threads per period on both axes
    prm, h = hs["linen"]
    px = _peak_period_mm((np.abs(np.fft.rfft(h, axis=1)) ** 2).mean(0), n, pitch)
    py = _peak_period_mm((np.abs(np.fft.rfft(h, axis=0)) ** 2).mean(1), n, pitch)
    assert px == pytest.approx(2 * prm.period_mm, rel=0.1) and py == pytest.approx(2 * prm.course_mm, rel=0.1)
    # fleece: isotropic noise without a dominant period
    _, h = hs["fleece"]
    pxw = (np.abs(np.fft.rfft(h, axis=1)) ** 2).mean(0)[1:]
    pyw = (np.abs(np.fft.rfft(h, axis=0)) ** 2).mean(1)[1:]
    assert 0.7 < pxw.sum() / pyw.sum() < 1.4
    assert pxw.max() / np.median(pxw[:100]) < 20
    cord = (np.abs(np.fft.rfft(hs["corduroy"][1], axis=1)) ** 2).mean(0)[1:]
    assert cord.max() / np.median(cord[:100]) > 100
    # satin: near flat
    assert hs["satin"][1].std() < 0.05 * hs["corduroy"][1].std()
    assert np.percentile(hs["satin"][1], 99) - np.percentile(hs["satin"][1], 1) < 0.02


def test_default_specs_cover_all_fabrics_and_shapes() -> None:
    first = syn.default_specs(6, 0)
    assert {s.fabric for s in first} == set(syn.FABRICS)
    assert {s.shape for s in first} == set(syn.SHAPES)
    many = syn.default_specs(20, 5)
    assert len({s.name for s in many}) == 20
    assert all(re.fullmatch(r"[A-Z][A-Za-z0-9]*", s.name) for s in many)


@pytest.mark.parametrize("kwargs", [{"garments": 0}, {"garments": -2}, {"frame": (100, 80)},
                                    {"frame": (200, 400)}, {"frame": "320x240"}])
def test_bad_arguments_raise_value_error(tmp_path: Path, kwargs: dict) -> None:
    with pytest.raises(ValueError):
        syn.generate_dataset(tmp_path, progress=False, **{"frame": FRAME, **kwargs})


@pytest.mark.parametrize("field,value", [("fabric", "tweed"), ("shape", "hat"), ("name", "denim shorts")])
def test_bad_spec_raises_value_error(tmp_path: Path, field: str, value: str) -> None:
    spec = replace(syn.GarmentSpec(name="DenimShorts", shape="shorts", fabric="denim", seed=0), **{field: value})
    with pytest.raises(ValueError, match=field if field != "name" else "CamelCase"):
        syn.generate_garment(tmp_path, spec, frame=FRAME)
    assert not any(tmp_path.iterdir())
