"""The scene planner: graph per scene, region rounding, resolution caps, reuse, and agreement with the contract."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.bundle.archive import open_bundle
from kiosk.inference.engine import LoadedBundle
from kiosk.contract.errors import InputError
from kiosk.contract.graph import GRID_MULTIPLE
from kiosk.inference.scene import (MAX_ROUNDING_LOSS, Panel, Planner, Scene, SketchInput, Transform, choose_graph,
                         grid_for, place_region, reference_placement, render_sketch)
from kiosk.contract.sketch import rasterize
from tests.kiosk.bundle_factory import make_bundle

SCREEN = (1280, 800)
BOX = [[(300, 200), (800, 200), (800, 600), (300, 600), (300, 200)]]  # a closed 500 x 400 outline


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> LoadedBundle:
    tmp = tmp_path_factory.mktemp("scene")
    path, trusted = make_bundle(tmp)
    from kiosk.bundle.signature import load_trusted_keys

    lb = LoadedBundle(open_bundle(path, load_trusted_keys(trusted), workdir=tmp / "w"))
    yield lb
    lb.close()


def strokes(points=BOX) -> SketchInput:
    return SketchInput(tuple(np.asarray(s, np.float64) for s in points))


def main_panel(**kw) -> Panel:
    return Panel("main", (0, 0, *SCREEN), "denim-shorts", **kw)


def test_choose_graph_per_modalities():
    all3 = ("full", "tactile", "visual")
    assert choose_graph(("visual", "tactile"), all3) == "full"
    assert choose_graph(("tactile",), all3) == "tactile"
    assert choose_graph(("visual",), all3) == "visual"
    assert choose_graph((), all3) == "none"
    assert choose_graph(("tactile",), ("full",)) == "full"  # no single-branch graph: the full one does it
    with pytest.raises(InputError, match="no graph"):
        choose_graph(("visual", "tactile"), ("visual", "tactile"))


@settings(max_examples=400, deadline=None)
@given(bw=st.floats(1, 3000), bh=st.floats(1, 3000), cw=st.sampled_from([256, 512, 768, 1024]),
       ch=st.sampled_from([256, 512, 768]))
def test_grid_rounding_properties(bw, bh, cw, ch):
    (gw, gh), s = grid_for((bw, bh), (cw, ch))
    assert gw % GRID_MULTIPLE == 0 and gh % GRID_MULTIPLE == 0 and GRID_MULTIPLE <= gw <= cw and GRID_MULTIPLE <= gh <= ch
    assert 0 < s <= 1.0                              # never more than the panel's pixels
    assert gw / s >= bw - 1e-6 and gh / s >= bh - 1e-6  # the region covers the box
    s0 = min(1.0, cw / bw, ch / bh)
    assert s >= (1 - MAX_ROUNDING_LOSS) * s0 - 1e-9   # rounding costs at most 15 % of the affordable resolution


def test_grid_rounding_examples():
    assert grid_for((600, 300), (512, 512)) == ((512, 256), pytest.approx(512 / 600))
    assert grid_for((300, 300), (512, 512)) == ((256, 256), pytest.approx(256 / 300))  # down: loses 14.7 %
    assert grid_for((320, 320), (512, 512)) == ((512, 512), 1.0)  # down would lose 20 %: up, more background
    assert grid_for((100, 80), (512, 512)) == ((256, 256), 1.0)   # never upsampled
    assert grid_for((1280, 800), (512, 512))[0] == (512, 512)


def test_place_region_covers_the_object_and_stays_inside_the_panel_when_it_can():
    clip = (0, 0, 1280, 800)
    assert place_region((0, 0, 20, 20), (256, 256), clip) == (0, 0, 256, 256)
    assert place_region((1260, 780, 1280, 800), (256, 256), clip) == (1024, 544, 256, 256)
    assert place_region((100, 300, 1180, 500), (2000, 256), clip) == (-360, 272, 2000, 256)
    # An object partly outside the panel (a half-garment panel): covering it wins over staying inside.
    assert place_region((600, 100, 1400, 700), (1024, 768), clip) == (488, 16, 1024, 768)


def test_full_scene_plans_the_full_graph_over_the_object(bundle):
    scene = Scene((main_panel(),), SCREEN)
    plan = Planner(max_resolution=512).plan(scene, {"main": strokes()}, {"denim-shorts": bundle})
    p = plan.panels[0]
    assert p.graph == "full" and p.needs == ("visual", "tactile") and not p.reused
    x, y, w, h = p.region
    assert x <= 300 - 16 and y <= 200 - 16 and x + w >= 800 + 16 and y + h >= 600 + 16  # object + margin
    assert p.grid == (512, 512) and p.scale <= 1.0
    assert p.inputs.sketch.shape == (1, 1, 512, 512) and p.mask.any()
    assert p.computed_pixels == 512 * 512 < p.naive_pixels == 1280 * 1024
    assert "visual+tactile" in p.reason and plan.to_json()["panels"][0]["graph"] == "full"


def test_resolution_is_capped_by_the_bundle_and_the_config(bundle):
    scene = Scene((main_panel(visual="none"),), SCREEN)  # tactile only: the bundle declares 256x256 for it
    p = Planner(max_resolution=1024).plan(scene, {"main": strokes()}, {"denim-shorts": bundle}).panels[0]
    assert p.graph == "tactile" and p.grid == (256, 256) and p.scale < 0.5
    scene = Scene((main_panel(),), SCREEN)  # full: declared up to 512, config allows 256
    p = Planner(max_resolution=256, preview_max_resolution=256).plan(scene, {"main": strokes()},
                                                                     {"denim-shorts": bundle}).panels[0]
    assert p.graph == "full" and p.grid == (256, 256)


def test_preview_asks_only_for_the_visual_at_the_preview_cap(bundle):
    scene = Scene((main_panel(),), SCREEN)
    p = Planner(max_resolution=512, preview_max_resolution=256).plan(
        scene, {"main": strokes()}, {"denim-shorts": bundle}, preview=True).panels[0]
    assert p.graph == "visual" and p.needs == ("visual",) and p.grid == (256, 256)


def test_ab_study_scene_needs_no_visual_inference(bundle):
    """Two halves of the garment with its reference visual, each with model tactile: tactile graph only."""
    panels = tuple(Panel(side, (0 if side == "left" else 640, 0, 640, 800), "denim-shorts", visual="reference",
                         tactile="model", sketch="reference", half=side) for side in ("left", "right"))
    plan = Planner().plan(Scene(panels, SCREEN), {}, {"denim-shorts": bundle})
    assert [p.graph for p in plan.panels] == ["tactile", "tactile"]
    assert all(p.needs == ("tactile",) and "visual" not in p.outputs for p in plan.panels)
    assert all(p.placement is not None for p in plan.panels)
    left, right = plan.panels
    assert left.clip == (0, 0, 640, 800) and right.clip == (640, 0, 640, 800)
    # Each panel shows one half, cut at the garment's centre line, which sits on the panels' shared edge; the
    # friction region covers the whole garment and is clipped to the panel.
    bx, by, bw, bh = bundle.reference_bbox()
    for p in plan.panels:
        assert p.placement.x + (bx + bw / 2) * p.placement.scale == pytest.approx(640, abs=1e-6)
    assert left.region[0] < 640 < left.region[0] + left.region[2]


def test_nothing_from_the_model_and_nothing_drawn(bundle):
    scene = Scene((main_panel(visual="reference", tactile="none"),), SCREEN)
    p = Planner().plan(scene, {}, {"denim-shorts": bundle}).panels[0]
    assert p.graph == "none" and p.computed_pixels == 0
    open_stroke = SketchInput((np.array([[100.0, 100.0], [400.0, 120.0]]),))
    p = Planner().plan(Scene((main_panel(),), SCREEN), {"main": open_stroke}, {"denim-shorts": bundle}).panels[0]
    assert p.graph == "none" and p.region is None and "no closed outline" in p.reason
    with pytest.raises(InputError, match="no garment 'coat'"):
        Planner().plan(Scene((Panel("m", (0, 0, 10, 10), "coat"),), SCREEN), {}, {"denim-shorts": bundle})


def test_cached_modalities_are_not_recomputed(bundle):
    held = set()
    planner = Planner(cached=lambda key, mod: (key, mod) in held)
    scene = Scene((main_panel(),), SCREEN)
    first = planner.plan(scene, {"main": strokes()}, {"denim-shorts": bundle}).panels[0]
    held.add((first.cache_key, "visual"))
    second = planner.plan(scene, {"main": strokes()}, {"denim-shorts": bundle}).panels[0]
    assert second.cache_key == first.cache_key
    assert second.graph == "tactile" and second.reused == ("visual",)  # tactile-only: the visual is unchanged
    held.add((first.cache_key, "tactile"))
    third = planner.plan(scene, {"main": strokes()}, {"denim-shorts": bundle}).panels[0]
    assert third.graph == "none" and third.computed_pixels == 0 and third.reason == "all from cache"
    # The same drawing moved on screen (the page was laid out again): same network input, same key.
    moved = [[(x + 40, y + 24) for x, y in s] for s in BOX]
    fourth = planner.plan(scene, {"main": strokes(moved)}, {"denim-shorts": bundle}).panels[0]
    assert fourth.cache_key == first.cache_key and fourth.region[:2] == (first.region[0] + 40, first.region[1] + 24)
    edited = planner.plan(scene, {"main": strokes(BOX + [[(400, 300), (500, 400)]])},
                          {"denim-shorts": bundle}).panels[0]
    assert edited.cache_key != first.cache_key and edited.graph == "full"


def test_network_sketch_is_the_contract_rasterization():
    """At scale 1 the planner's raster of the strokes is exactly kiosk.contract.sketch.rasterize of the shifted strokes."""
    t = Transform(100.0, 50.0, 1.0, 1.0, (512, 512))
    got = render_sketch(strokes(), t, None, None)
    want = rasterize([[(x - 100, y - 50) for x, y in BOX[0]]], (512, 512))
    np.testing.assert_array_equal(got, want)


def test_reference_sketch_lands_where_the_placement_says(bundle):
    panel = main_panel(sketch="reference")
    sketch = bundle.reference_sketch()
    pl = reference_placement(panel, (sketch.shape[1], sketch.shape[0]), bundle.reference_bbox())
    t = Transform(0.0, 0.0, 1.0, 1.0, SCREEN)
    raster = render_sketch(SketchInput(base=True), t, sketch, pl)
    ys, xs = np.nonzero(raster < 128)
    ink = np.nonzero(sketch < 128)
    assert xs.min() == pytest.approx(ink[1].min() * pl.scale + pl.x, abs=math.ceil(pl.scale) + 1)
    assert ys.max() == pytest.approx(ink[0].max() * pl.scale + pl.y, abs=math.ceil(pl.scale) + 1)


def test_panel_and_scene_validation():
    with pytest.raises(InputError, match="visual must be one of"):
        Panel("a", (0, 0, 10, 10), "g", visual="photo")
    with pytest.raises(InputError, match="rect"):
        Panel("a", (0, 0, 0, 10), "g")
    with pytest.raises(InputError, match="unique"):
        Scene((Panel("a", (0, 0, 10, 10), "g"), Panel("a", (0, 0, 10, 10), "g")), SCREEN)


def test_large_outline_gaps_are_closed_by_the_coarse_mask(bundle):
    """A 30 px gap (a finger lifted early) closes on the coarse raster; at the grid only small gaps are closed
    (bounded cost), so the coarse mask is carried to the grid."""
    gap = [[(330, 200), (800, 200), (800, 600), (300, 600), (300, 200)]]  # 30 px open along the top
    p = Planner().plan(Scene((main_panel(),), SCREEN), {"main": strokes(gap)}, {"denim-shorts": bundle}).panels[0]
    assert p.graph == "full" and p.mask.any()
    x, y, w, h = p.region
    gx, gy = (550 - x) * p.grid[0] / w, (400 - y) * p.grid[1] / h  # the box's centre, in grid pixels
    assert p.mask[int(gy), int(gx)] and not p.mask[2, 2]
    from kiosk.inference.scene import FINE_MAX_GAP
    from kiosk.contract.sketch import object_mask

    fine = render_sketch(strokes(gap), Transform(x, y, p.grid[0] / w, p.grid[1] / h, p.grid), None, None)
    assert not object_mask(fine, max_gap_px=FINE_MAX_GAP).any()  # so the mask above is the coarse one, carried
