"""The planner at physical scale: one model pixel covers the bundle's pitch on the panel, whatever the drawing
size; rounding to the graph sizes never changes the scale; one clear warning when the bundle's sizes cannot serve."""
from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.bundle.archive import open_bundle
from kiosk.bundle.signature import load_trusted_keys
from kiosk.contract.errors import InputError
from kiosk.inference.engine import LoadedBundle
from kiosk.contract.graph import GRID_MULTIPLE as MULTIPLE
from kiosk.inference.scene import Panel, Planner, Scene, SketchInput, physical_grid
from tests.kiosk.bundle_factory import make_bundle

SCREEN = (1280, 800)


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> LoadedBundle:
    tmp = tmp_path_factory.mktemp("physical")
    path, trusted = make_bundle(tmp)  # pixel_pitch_mm 0.3, full graph sizes up to 512x512
    lb = LoadedBundle(open_bundle(path, load_trusted_keys(trusted), workdir=tmp / "w"))
    yield lb
    lb.close()


def box(w: float, h: float) -> SketchInput:
    x0, y0 = 640 - w / 2, 400 - h / 2
    pts = [(x0, y0), (x0 + w, y0), (x0 + w, y0 + h), (x0, y0 + h), (x0, y0)]
    return SketchInput((np.asarray(pts, np.float64),))


def plan(bundle, sketch, **kw):
    scene = Scene((Panel("main", (0, 0, *SCREEN), "denim-shorts"),), SCREEN)
    return Planner(max_resolution=512, **kw).plan(scene, {"main": sketch}, {"denim-shorts": bundle}).panels[0]


@pytest.mark.parametrize("panel_mm", [0.17, 0.25, 0.3])
@pytest.mark.parametrize("size", [120, 250, 380])
def test_one_model_pixel_covers_the_bundle_pitch(bundle, panel_mm, size):
    p = plan(bundle, box(size, size * 0.8), panel_pitch_mm=panel_mm)
    target = panel_mm / 0.3
    assert p.target_scale == pytest.approx(target) and p.scale == pytest.approx(target)
    assert p.felt_ratio == pytest.approx(1.0)
    rx, ry, rw, rh = p.region
    # grid px per screen px in each axis is the target, up to the region's rounding to whole screen pixels
    assert p.grid[0] / rw == pytest.approx(target, rel=2e-3) and p.grid[1] / rh == pytest.approx(target, rel=3e-3)
    assert p.grid[0] % MULTIPLE == 0 and p.grid[1] % MULTIPLE == 0


def test_fewer_pixels_than_the_screen_on_a_fine_panel(bundle):
    legacy = plan(bundle, box(400, 300))
    physical = plan(bundle, box(400, 300), panel_pitch_mm=0.17)
    assert legacy.scale == 1.0 and physical.scale == pytest.approx(0.17 / 0.3)
    assert physical.computed_pixels < legacy.computed_pixels


@settings(max_examples=300, deadline=None)
@given(bw=st.floats(1, 3000), bh=st.floats(1, 3000), target=st.floats(0.2, 3.0),
       cw=st.sampled_from([256, 512, 768]), ch=st.sampled_from([256, 512, 768]))
def test_physical_grid_properties(bw, bh, target, cw, ch):
    (gw, gh), s = physical_grid((bw, bh), target, (cw, ch))
    assert gw % MULTIPLE == 0 and gh % MULTIPLE == 0 and MULTIPLE <= gw <= cw and MULTIPLE <= gh <= ch
    assert 0 < s <= target
    assert gw / s >= bw * (1 - 1e-9) and gh / s >= bh * (1 - 1e-9)  # the region covers the box
    if bw * target <= cw and bh * target <= ch:
        assert s == target  # when the bundle's sizes can serve, the scale is exactly physical


def test_physical_grid_rejects_bad_scale():
    with pytest.raises(InputError, match="physical scale"):
        physical_grid((100, 100), float("nan"), (512, 512))
    with pytest.raises(InputError, match="panel pitch"):
        Planner(panel_pitch_mm=-0.2)


def test_mismatch_is_warned_once_in_one_line(bundle, caplog):
    # A 3 mm/px panel would need 10 model px per screen px: a 380 px garment needs a 3840 px grid, the bundle
    # stops at 512. The planner serves what fits, says so once, and records how much coarser it is felt.
    planner = Planner(max_resolution=512, panel_pitch_mm=3.0)
    scene = Scene((Panel("main", (0, 0, *SCREEN), "denim-shorts"),), SCREEN)
    with caplog.at_level(logging.WARNING, logger="kiosk.inference.scene"):
        for _ in range(3):
            p = planner.plan(scene, {"main": box(380, 300)}, {"denim-shorts": bundle}).panels[0]
    msgs = [r.getMessage() for r in caplog.records if r.name == "kiosk.inference.scene"]
    assert len(msgs) == 1 and "\n" not in msgs[0]
    assert "denim-shorts" in msgs[0] and "3.000 mm/px" in msgs[0] and "0.300 mm/px" in msgs[0]
    assert "coarser" in msgs[0]
    assert p.target_scale == pytest.approx(10.0) and p.felt_ratio == pytest.approx(10.0 / p.scale)
    assert p.felt_ratio > 5


def test_quick_answer_may_drop_the_scale_silently_and_refines_to_physical(bundle, caplog):
    scene = Scene((Panel("main", (0, 0, *SCREEN), "denim-shorts"),), SCREEN)
    planner = Planner(max_resolution=512, preview_max_resolution=256, panel_pitch_mm=0.17)
    with caplog.at_level(logging.WARNING, logger="kiosk.inference.scene"):
        quick = planner.plan(scene, {"main": box(800, 500)}, {"denim-shorts": bundle}, quick=True).panels[0]
    assert quick.grid == (256, 256) and quick.refine_grid == (512, 512) and quick.felt_ratio > 1
    assert not [r for r in caplog.records if r.name == "kiosk.inference.scene"]


def _quick(bundle, sketch, *, needs=None, **kw):
    panel = Panel("main", (0, 0, *SCREEN), "denim-shorts")
    if needs == "tactile":  # a panel that shows no model visual (as the study's, whose visual is a reference)
        panel = Panel("main", (0, 0, *SCREEN), "denim-shorts", visual="none")
    planner = Planner(**{"max_resolution": 512, "preview_max_resolution": 256, "panel_pitch_mm": 0.17, **kw})
    return planner.plan(Scene((panel,), SCREEN), {"main": sketch}, {"denim-shorts": bundle}, quick=True).panels[0]


def test_quick_answer_leaves_friction_felt_too_coarse_to_the_refinement(bundle):
    far = _quick(bundle, box(800, 500))  # needs 512x512 at physical scale; 256 would feel it ~1.6x coarser
    assert far.deferred == ("tactile",) and far.needs == ("visual",) and far.graph == "visual"
    assert far.felt_ratio > 1.1 and far.refine_grid == (512, 512) and far.to_json()["deferred"] == ["tactile"]
    near = _quick(bundle, box(400, 300))  # fits the 256 px quick grid at physical scale: nothing to wait for
    assert near.deferred == () and near.felt_ratio == pytest.approx(1.0) and near.graph == "full"
    always = _quick(bundle, box(800, 500), quick_tactile="always")
    assert always.deferred == () and always.graph == "full" and always.felt_ratio == pytest.approx(far.felt_ratio)
    # no refinement would come closer (the full cap is the quick one): the quick answer is final, friction and all
    capped = _quick(bundle, box(800, 500), max_resolution=256)
    assert capped.deferred == () and capped.refine_grid == capped.grid and capped.graph == "full"


@settings(max_examples=60, deadline=None)
@given(w=st.floats(60, 1200), h=st.floats(60, 760))
def test_deferral_happens_exactly_when_the_quick_grid_feels_too_coarse_and_a_refinement_follows(bundle, w, h):
    p = _quick(bundle, box(w, h))
    always = _quick(bundle, box(w, h), quick_tactile="always")
    too_coarse = always.felt_ratio > 1.1 and always.refine_grid != always.grid
    assert (p.deferred == ("tactile",)) == too_coarse
    assert ("tactile" in p.needs) != too_coarse and "visual" in p.needs


def test_a_tactile_only_panel_keeps_its_quick_friction_and_a_bad_setting_is_refused(bundle):
    alone = _quick(bundle, box(800, 500), needs="tactile")
    assert alone.deferred == () and alone.needs == ("tactile",) and alone.felt_ratio > 1.1
    with pytest.raises(InputError, match="quick_tactile must be one of at-scale, always"):
        Planner(quick_tactile="sometimes")
