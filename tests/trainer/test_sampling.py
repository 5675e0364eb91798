"""Patch sampler and augmentation on a folder in the published layout (known gradient field)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from tests.conftest import field_gx
from trainer.augment import eval_crop_origin, object_bbox, origin_range, random_crop_origin
from trainer.config import DataConfig
from trainer.data.synthetic import generate_dataset
from trainer.recipe.mirror import flip_batch
from trainer.sampling import GarmentData, cut, laplacian_weights, window_variance


@pytest.fixture(scope="module")
def data(real_layout_dir):
    return GarmentData(real_layout_dir / "singleskit_DenimToy_padded_1800_x1",
                       DataConfig(crop=256, patches=16, unpaired=8), seed=3)


def test_crop_grows_to_hold_the_object_and_keeps_it_inside(data):
    assert data.side == 768   # the 680x560 object needs 3 x 256
    x0, y0, x1, y1 = object_bbox(data.g.mask)
    for step in range(20):
        b = data.batch(step)
        ox, oy = b.origin
        assert ox <= x0 and oy <= y0 and x1 <= ox + data.side and y1 <= oy + data.side
        assert int(b.mask.sum()) == int(data.g.mask.sum())   # the whole object is in every crop


def test_paired_patches_land_where_the_tactile_files_say(data):
    gx_full, gy_full = field_gx((1800, 1800))
    b = data.batch(5)
    ox, oy = b.origin
    assert b.gx.shape == (16, 1, 32, 32)
    for k, (px, py) in enumerate(b.origins.tolist()):
        want_x = gx_full[oy + py:oy + py + 32, ox + px:ox + px + 32]
        want_y = gy_full[oy + py:oy + py + 32, ox + px:ox + px + 32]
        np.testing.assert_allclose(b.gx[k, 0].numpy(), want_x, atol=1e-6)
        np.testing.assert_allclose(b.gy[k, 0].numpy(), want_y, atol=1e-6)
    # and the sketch patch at that origin is the garment's sketch there (the same coordinates for every modality)
    sk = cut(b.sketch, b.origins[:1])[0, 0].numpy()
    px, py = b.origins[0]
    raw = data.g.sketch[oy + py:oy + py + 32, ox + px:ox + px + 32].astype(np.float32) / 127.5 - 1
    np.testing.assert_allclose(sk, raw * data.g.mask[oy + py:oy + py + 32, ox + px:ox + px + 32], atol=1e-6)


@pytest.mark.parametrize("how", ["uniform", "laplacian"])
def test_unpaired_patches_are_centred_on_the_object(real_layout_dir, how):
    data = GarmentData(real_layout_dir / "singleskit_DenimToy_padded_1800_x1",
                       DataConfig(crop=256, patches=16, unpaired=8, unpaired_sampling=how), seed=3)
    b = data.batch(2)
    assert len(b.unpaired) == 8
    m = b.mask[0, 0].numpy()
    for x, y in b.unpaired.tolist():
        assert m[y + 16, x + 16] == 1 and x + 32 <= data.side and y + 32 <= data.side


def _sketch_activity(data, b, corners) -> float:
    """How busy the sketch is (mean var(Laplacian) over 32x32 windows) under `corners`, relative to under the
    batch's paired patches."""
    ox, oy = b.origin
    crop = data.g.sketch[oy:oy + data.side, ox:ox + data.side]
    # weights are normalised over the windows given: score both sets in one call to compare them
    ref = laplacian_weights(crop, np.concatenate([np.asarray(corners), b.origins]), floor=0.0)
    return float(ref[:len(corners)].mean() / max(ref[len(corners):].mean(), 1e-12))


def test_laplacian_unpaired_patches_sit_where_paired_ones_do(tmp_path_factory):
    """Paired patches favour busy sketch; uniform unpaired ones land mostly on plain cloth, which the tactile D
    learns as a 'fake' cue. Laplacian-weighted ones land on sketch as busy as the paired ones'."""
    garment = generate_dataset(tmp_path_factory.mktemp("synth"), garments=1, seed=0, frame=(640, 480),
                               progress=False, profile="easy")[0]
    ratio = {}
    for how in ("uniform", "laplacian"):
        data = GarmentData(garment, DataConfig(crop=512, patches=32, unpaired=64, unpaired_sampling=how), seed=3)
        rs = [_sketch_activity(data, b, b.unpaired) for b in (data.batch(s) for s in range(8))]
        ratio[how] = float(np.mean(rs))
    assert ratio["uniform"] < 0.6 * ratio["laplacian"]
    assert 0.5 < ratio["laplacian"] < 2.0


def test_batches_are_a_pure_function_of_seed_and_step(data):
    a, b, c = data.batch(7), data.batch(7), data.batch(8)
    assert a.origin == b.origin and np.array_equal(a.origins, b.origins) and torch.equal(a.gx, b.gx)
    assert a.origin != c.origin or not np.array_equal(a.origins, c.origins)


def test_laplacian_weights_prefer_sketch_lines():
    sketch = np.full((128, 128), 255, np.uint8)
    sketch[60:62, :] = 0
    w = laplacian_weights(sketch, np.array([[10, 45], [10, 2], [50, 90]]), floor=0.1)
    assert w.sum() == pytest.approx(1.0) and w[0] > 5 * w[1] and w[1] == pytest.approx(w[2])


def test_window_variance_is_the_laplacian_variance_of_each_window():
    rng = np.random.default_rng(0)
    sketch = np.where(rng.random((96, 80)) < 0.05, 0, 255).astype(np.uint8)
    var = window_variance(sketch)
    assert var.shape == (96 - 32 + 1, 80 - 32 + 1)
    lap = cv2.Laplacian(sketch.astype(np.float32) / 255.0, cv2.CV_32F, ksize=3).astype(np.float64)
    for y, x in [(0, 0), (64, 48), (17, 5), (40, 33)]:
        assert var[y, x] == pytest.approx(lap[y:y + 32, x:x + 32].var(), rel=1e-6, abs=1e-9)


def test_fixed_validation_set_is_the_centre_crop(data):
    v1, v2 = data.eval_set("val"), data.eval_set("val")
    assert v1.origin == v2.origin == eval_crop_origin(data.g.mask, data.side)
    assert torch.equal(v1.gx, v2.gx) and len(v1.origins) == 2   # one patch per val touch


def test_origin_range_matches_published_for_full_frame_object():
    """An object filling the 1280x960 frame: x origins [4, 260] (1540 - 1536 .. 260), y [0, 264]."""
    m = np.zeros((1800, 1800), bool)
    m[420:1380, 260:1540] = True
    (xa, xb), (ya, yb) = origin_range(m, 1536)
    assert (xa, xb) == (4, 260) and (ya, yb) == (0, 264)
    rng = np.random.default_rng(0)
    xs = [random_crop_origin(m, 1536, rng)[0] for _ in range(200)]
    assert min(xs) >= 4 and max(xs) <= 260 and len(set(xs)) > 50


def _mirrored(real_layout_dir, p: float, flip: float = 0.0) -> GarmentData:
    return GarmentData(real_layout_dir / "singleskit_DenimToy_padded_1800_x1",
                       DataConfig(crop=256, patches=16, unpaired=8, transpose=p, flip=flip), seed=3)


def test_a_mirrored_crop_is_the_garment_transposed_with_gx_and_gy_traded(real_layout_dir):
    """data.transpose=1: every crop is the garment mirrored across the crop's diagonal, read at the same place."""
    data = _mirrored(real_layout_dir, 1.0)
    gx_full, gy_full = field_gx((1800, 1800))
    b = data.batch(5)
    ox, oy = b.origin
    s = data.side
    raw = data.g.sketch[oy:oy + s, ox:ox + s].astype(np.float32) / 127.5 - 1
    np.testing.assert_allclose(b.sketch[0, 0].numpy(), (raw * data.g.mask[oy:oy + s, ox:ox + s]).T, atol=1e-6)
    np.testing.assert_allclose(b.visual[0].numpy(), np.transpose(
        (data.g.visual[oy:oy + s, ox:ox + s].astype(np.float32) / 127.5 - 1) * data.g.mask[oy:oy + s, ox:ox + s, None],
        (2, 1, 0)), atol=1e-6)
    for k, (px, py) in enumerate(b.origins.tolist()):
        # the patch at (px, py) of the mirrored crop is the patch at (py, px) of the garment's crop, mirrored
        src = (slice(oy + px, oy + px + 32), slice(ox + py, ox + py + 32))
        np.testing.assert_allclose(b.gx[k, 0].numpy(), gy_full[src].T, atol=1e-6)
        np.testing.assert_allclose(b.gy[k, 0].numpy(), gx_full[src].T, atol=1e-6)
    m = b.mask[0, 0].numpy()
    for x, y in b.unpaired.tolist():
        assert m[y + 16, x + 16] == 1   # unpaired corners still land on the (mirrored) object


def test_a_flipped_crop_is_the_garment_mirrored_left_to_right_with_gx_negated(real_layout_dir):
    """data.flip=1: every crop is the garment mirrored left to right, read at the same place; the x slope changes
    sign (h'(x) = h(W - 1 - x) gives dh'/dx = -dh/dx mirrored) and the y slope does not."""
    data = _mirrored(real_layout_dir, 0.0, flip=1.0)
    gx_full, gy_full = field_gx((1800, 1800))
    b = data.batch(5)
    ox, oy = b.origin
    s = data.side
    m_crop = data.g.mask[oy:oy + s, ox:ox + s]
    raw = data.g.sketch[oy:oy + s, ox:ox + s].astype(np.float32) / 127.5 - 1
    np.testing.assert_allclose(b.sketch[0, 0].numpy(), (raw * m_crop)[:, ::-1], atol=1e-6)
    np.testing.assert_allclose(b.visual[0].numpy(), np.transpose(
        (data.g.visual[oy:oy + s, ox:ox + s].astype(np.float32) / 127.5 - 1) * m_crop[..., None],
        (2, 0, 1))[:, :, ::-1], atol=1e-6)
    assert b.mirrored
    for k, (px, py) in enumerate(b.origins.tolist()):
        # the patch at (px, py) of the flipped crop is the patch at (s - 32 - px, py) of the garment's crop, flipped
        src = (slice(oy + py, oy + py + 32), slice(ox + s - 32 - px, ox + s - px))
        np.testing.assert_allclose(b.gx[k, 0].numpy(), -gx_full[src][:, ::-1], atol=1e-6)
        np.testing.assert_allclose(b.gy[k, 0].numpy(), gy_full[src][:, ::-1], atol=1e-6)
    m = b.mask[0, 0].numpy()
    for x, y in b.unpaired.tolist():
        assert m[y + 16, x + 16] == 1


def test_mirror_extra_keeps_the_crop_as_photographed_and_carries_the_mirror_as_its_twin(real_layout_dir, data):
    """data.mirror_extra: a mirrored step trains the crop as photographed (the same draw as with mirrors off) and
    the same crop mirrored beside it; an unmirrored step has no twin."""
    extra = GarmentData(real_layout_dir / "singleskit_DenimToy_padded_1800_x1",
                        DataConfig(crop=256, patches=16, unpaired=8, flip=0.5, mirror_extra=True), seed=3)
    twins = 0
    for step in range(12):
        a, b = data.batch(step), extra.batch(step)
        assert not b.mirrored and torch.equal(a.sketch, b.sketch) and torch.equal(a.gx, b.gx)
        assert np.array_equal(a.origins, b.origins) and np.array_equal(a.unpaired, b.unpaired)
        if b.twin is not None:
            twins += 1
            want = flip_batch(a)
            assert b.twin.mirrored and b.twin.twin is None
            for k in ("sketch", "mask", "visual", "gx", "gy", "contact"):
                assert torch.equal(getattr(b.twin, k), getattr(want, k)), k
            assert np.array_equal(b.twin.origins, want.origins)
    assert 0 < twins < 12


def test_the_flip_negates_a_height_fields_x_slope():
    rng = np.random.default_rng(1)
    h = cv2.GaussianBlur(rng.normal(size=(64, 64)).astype(np.float32), (0, 0), 3)
    gy, gx = np.gradient(h)
    gy_f, gx_f = np.gradient(h[:, ::-1])
    np.testing.assert_allclose(gx_f, -gx[:, ::-1], atol=1e-6)
    np.testing.assert_allclose(gy_f, gy[:, ::-1], atol=1e-6)


def test_the_mirror_turns_a_height_fields_x_slope_into_its_y_slope():
    """Why gx and gy trade places: mirroring a surface h across the diagonal, h'(x, y) = h(y, x), gives
    dh'/dx = (dh/dy) mirrored, and the contact sensor's gx, gy are those slopes."""
    rng = np.random.default_rng(0)
    h = cv2.GaussianBlur(rng.normal(size=(64, 64)).astype(np.float32), (0, 0), 3)
    gy, gx = np.gradient(h)
    gy_t, gx_t = np.gradient(h.T)
    np.testing.assert_allclose(gx_t, gy.T, atol=1e-6)
    np.testing.assert_allclose(gy_t, gx.T, atol=1e-6)


def test_mirroring_off_keeps_the_stream_and_half_mirrors_about_half(real_layout_dir, data):
    off = _mirrored(real_layout_dir, 0.0)
    half = _mirrored(real_layout_dir, 0.5)
    flips = 0
    for step in range(40):
        a, b, h = data.batch(step), off.batch(step), half.batch(step)
        assert torch.equal(a.sketch, b.sketch) and torch.equal(a.gx, b.gx) and np.array_equal(a.origins, b.origins)
        assert torch.equal(h.gx, half.batch(step).gx)     # a step draws the same mirror every time (resume)
        same = torch.equal(h.sketch, a.sketch)
        assert same or torch.equal(h.sketch, a.sketch.transpose(-1, -2))
        flips += not same
    assert 8 <= flips <= 32   # Binomial(40, 0.5): outside this with probability < 1e-4


@pytest.mark.parametrize("key", ["transpose", "flip"])
@pytest.mark.parametrize("value, says", [("1.5", "is a probability"), ("-0.1", "is a probability"),
                                         ("nan", "must be a finite number")])
def test_a_mirror_probability_outside_0_1_is_refused(key, value, says):
    from trainer.config import ConfigError, load_config
    with pytest.raises(ConfigError, match=f"data.{key} {says}"):
        load_config("tiny", overrides=[f"data.{key}={value}"])
