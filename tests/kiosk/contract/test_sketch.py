"""Sketch preprocessing of the runtime contract: strokes, masks, network input, the training-time extractor."""
import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.contract.errors import InputError
from kiosk.contract.sketch import (INK, LINE_PX, MAX_POINTS, PAPER, network_input, object_mask, rasterize,
                          sketch_from_image)

RECT = [(20, 20), (100, 20), (100, 80), (20, 80), (20, 20)]


def test_rasterize_draws_ink_on_paper():
    s = rasterize([RECT], (128, 96))
    assert s.shape == (96, 128) and s.dtype == np.uint8
    assert set(np.unique(s)) == {INK, PAPER}
    assert s[20, 60] == INK and s[50, 60] == PAPER
    # Line width is LINE_PX across a horizontal segment.
    assert (s[:, 60] == INK).sum() == 2 * LINE_PX


def test_rasterize_empty_and_single_point():
    assert (rasterize([], (5, 3)) == PAPER).all()
    assert (rasterize([[]], (5, 3)) == PAPER).all()
    dot = rasterize([[(2, 1)]], (5, 3))
    assert dot[1, 2] == INK and (dot == INK).sum() <= 9
    assert rasterize([(2.0, 1.0, 0.5)], (5, 3))[1, 2] == INK  # one bare point with pressure


def test_rasterize_nan_splits_and_out_of_range_clamps():
    s = rasterize([[(np.nan, 1), (0, 1), (4, 1), (np.inf, 0), (4, 2), (400, 2)]], (10, 4), width_px=1)
    assert s[1, 0:5].tolist() == [INK] * 5
    assert s[2, 4:10].tolist() == [INK] * 6  # clamped to the right edge
    assert s[1, 6] == PAPER


def test_rasterize_many_points_and_limit():
    rng = np.random.default_rng(1)
    s = rasterize([rng.random((100_000, 2)) * 1000], (1280, 800))
    assert (s == INK).any()
    with pytest.raises(InputError, match="too many"):
        rasterize([np.zeros((MAX_POINTS + 1, 2))], (10, 10))


def test_rasterize_draws_over_a_base():
    base = rasterize([[(0, 0), (9, 0)]], (10, 5), width_px=1)
    both = rasterize([[(0, 4), (9, 4)]], (10, 5), width_px=1, base=base)
    assert both[0].tolist() == [INK] * 10 and both[4].tolist() == [INK] * 10
    assert base[4].tolist() == [PAPER] * 10
    with pytest.raises(InputError, match="base"):
        rasterize([], (11, 5), base=base)


@pytest.mark.parametrize("strokes, size, match", [
    ([[(1, 2, 3, 4, 5)]], (5, 5), "points"),
    ([[("a", "b")]], (5, 5), "numbers"),
    ("abc", (5, 5), "list of strokes"),
    (None, (5, 5), "list of strokes"),
    ([], (0, 5), "size"),
    ([], (5,), "size"),
    ([], (99999, 5), "size"),
])
def test_rasterize_rejects_malformed(strokes, size, match):
    with pytest.raises(InputError, match=match):
        rasterize(strokes, size)


def test_rasterize_rejects_bad_width():
    for width in (0, 65, 2.5, True):
        with pytest.raises(InputError, match="width_px"):
            rasterize([], (5, 5), width_px=width)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.tuples(st.floats(allow_nan=True, allow_infinity=True),
                                   st.floats(allow_nan=True, allow_infinity=True)), max_size=20), max_size=5),
       st.integers(1, 40), st.integers(1, 40))
def test_rasterize_never_crashes(strokes, w, h):
    s = rasterize(strokes, (w, h))
    assert s.shape == (h, w) and s.dtype == np.uint8


def test_object_mask_closed_outline():
    m = object_mask(rasterize([RECT], (128, 96)))
    assert m.dtype == bool
    assert m[50, 60] and not m[5, 5] and not m[90, 120]
    assert abs(int(m.sum()) - 82 * 62) < 200


def test_object_mask_closes_a_small_gap():
    gap = [(20, 20), (100, 20), (100, 80), (20, 80), (20, 27)]
    m = object_mask(rasterize([gap], (128, 96)))
    assert m[50, 60] and m.sum() > 4500


def test_object_mask_keeps_largest_component_and_fills_holes():
    big = [(10, 10), (70, 10), (70, 70), (10, 70), (10, 10)]
    small = [(90, 10), (100, 10), (100, 20), (90, 20), (90, 10)]
    pocket = [(30, 30), (50, 30), (50, 50), (30, 50), (30, 30)]
    m = object_mask(rasterize([big, small, pocket], (128, 96)))
    assert m[40, 40] and m[20, 20] and not m[15, 95]


def _textured_garment(side: int = 400) -> np.ndarray:
    """A closed outline filled with short marks, like a knit's or a quilt's sketch: more ink inside than on the rim."""
    a, b = side // 5, 4 * side // 5
    marks = [[(x, y), (x + 4, y + 1)] for y in range(a + 4, b - 4, 3) for x in range(a + 4, b - 8, 6)]
    return rasterize([[(a, a), (b, a), (b, b), (a, b), (a, a)], *marks], (side, side), width_px=1)


@pytest.mark.parametrize("scale", [1.0, 0.9, 0.75, 0.5, 0.3])
def test_object_mask_of_a_textured_garment_survives_downsampling(scale):
    """The planner downsamples a garment's reference sketch by area and re-binarises it; interior detail then
    outweighs the outline's ink, which must not make a closed garment read as 'only lines'."""
    sketch = _textured_garment()
    n = round(sketch.shape[0] * scale)
    small = np.where(cv2.resize(sketch, (n, n), interpolation=cv2.INTER_AREA) < 224, INK, PAPER).astype(np.uint8)
    m = object_mask(small, max_gap_px=3)
    if scale < 1:  # the case: the garment's area is less than twice its ink (the old 'only lines' rule)
        assert m.sum() < 2 * (small == INK).sum()
    assert m.sum() == pytest.approx((0.6 * n) ** 2, rel=0.1)


def test_an_open_stroke_with_texture_is_still_not_an_object():
    sketch = _textured_garment()
    sketch[:, :] = PAPER
    marks = [[(x, 200), (x + 5, 202)] for x in range(80, 320, 9)]
    line = rasterize([[(80, 80), (320, 80), (320, 320)], *marks], sketch.shape[::-1], width_px=1)
    assert not object_mask(line, max_gap_px=3).any()


def test_object_mask_no_object():
    assert not object_mask(np.full((20, 30), PAPER, np.uint8)).any()
    assert not object_mask(rasterize([[(5, 5), (25, 5)]], (30, 20))).any()  # a line encloses nothing
    with pytest.raises(InputError, match="uint8"):
        object_mask(np.zeros((4, 4), np.float32))


def test_network_input_matches_reference_normalisation():
    s = rasterize([RECT], (128, 96))
    m = object_mask(s)
    x = network_input(s, m)
    assert x.sketch.shape == (1, 1, 96, 128) and x.sketch.dtype == np.float32
    assert x.mask.shape == (1, 1, 96, 128) and set(np.unique(x.mask)) == {0.0, 1.0}
    expect = (s.astype(np.float32) / 127.5 - 1.0) * m
    np.testing.assert_allclose(x.sketch[0, 0], expect, atol=1e-6)
    assert (x.sketch[0, 0][~m] == 0).all() and x.sketch.min() == -1.0 and x.sketch.max() == 1.0
    with pytest.raises(InputError, match="shape"):
        network_input(s, m[:-1])
    with pytest.raises(InputError, match="0 and 1"):
        network_input(s, m.astype(np.float32) * 0.5)


def _toy_garment():
    img = np.full((240, 320, 3), 210, np.uint8)
    mask = np.zeros((240, 320), np.uint8)
    pts = np.array([[80, 40], [240, 40], [260, 200], [60, 200]], np.int32)
    cv2.fillPoly(mask, [pts], 1)
    rng = np.random.default_rng(0)
    texture = (rng.standard_normal((240, 320)) * 6).astype(np.int16)
    body = np.clip(np.array([60, 80, 150])[None, None, :] + texture[..., None], 0, 255).astype(np.uint8)
    img = np.where(mask[..., None] > 0, body, img)
    cv2.line(img, (160, 40), (160, 200), (20, 30, 70), 2)  # a seam
    return img, mask.astype(bool)


def test_sketch_from_image_finds_outline_and_seam_not_texture():
    img, mask = _toy_garment()
    s = sketch_from_image(img, mask)
    assert s.shape == mask.shape and s.dtype == np.uint8
    ink = s == INK
    assert ink[120, 155:166].any()                 # the seam
    assert ink[40, 100:200].any()                  # the top of the outline
    inside = mask & ~cv2.dilate(ink.astype(np.uint8), np.ones((9, 9))).astype(bool)
    assert inside.sum() > 0.8 * (mask.sum() - ink.sum() * 5)
    # The mask recovered from the extracted sketch matches the true silhouette.
    rec = object_mask(s)
    iou = (rec & mask).sum() / (rec | mask).sum()
    assert iou > 0.95


def test_sketch_from_image_rejects_bad_input():
    with pytest.raises(InputError, match="uint8"):
        sketch_from_image(np.zeros((5, 5, 3), np.float32), np.ones((5, 5), bool))
    with pytest.raises(InputError, match="mask"):
        sketch_from_image(np.zeros((5, 5, 3), np.uint8), np.ones((4, 5), bool))
