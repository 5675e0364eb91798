"""scripts/registered_copy.py: touches moved back to where they were pressed match the truth there; inputs
without a recorded registration are refused."""
from __future__ import annotations


import numpy as np
import pytest
import yaml

from tests.scripts_module import load_script
from trainer.data.synthetic import generate_dataset, registration_offset
from trainer.data.touchclothing import load_garment


@pytest.fixture(scope="module")
def rc():
    return load_script("registered_copy")


def _touch_error(g) -> float:
    """Mean |recorded gx - truth gx| over every touch's contact pixels."""
    ft, errs = g.full_tactile, []
    for touches in g.touches.values():
        for t in touches:
            r = t.rect
            errs.append(np.abs(t.gx[t.contact] - ft.gx[r.y:r.y + r.h, r.x:r.x + r.w][t.contact]))
    return float(np.concatenate(errs).mean())


def test_registered_copy_moves_every_touch_back(rc, hard_one, tmp_path):
    src = next(hard_one.glob("singleskit_*"))
    name = src.name.split("_")[1]
    offsets = yaml.safe_load((src / "synthetic.yaml").read_text())["realism"]["registration_offsets_px"]
    assert any(o != [0, 0] for o in offsets), "the fixture should have some registration error to undo"
    dst = rc.registered_copy(hard_one, name, tmp_path)
    before, after = load_garment(src), load_garment(dst)
    for split, touches in before.touches.items():
        for t0, t1 in zip(touches, after.touches[split]):
            dx, dy = registration_offset(offsets, t0.name)
            assert (t1.rect.x, t1.rect.y) == (t0.rect.x - dx, t0.rect.y - dy)
            assert np.array_equal(t0.gx, t1.gx) and np.array_equal(t0.contact, t1.contact)
    # the recorded slopes now sit on the truth they were measured from (only the sensor noise is left)
    assert _touch_error(after) < 0.5 * _touch_error(before)
    assert np.array_equal(before.sketch, after.sketch) and np.array_equal(before.full_tactile.gx,
                                                                          after.full_tactile.gx)


def test_registered_copy_refuses_what_it_cannot_register(rc, hard_one, tmp_path):
    with pytest.raises(SystemExit, match="no garment Nothing"):
        rc.registered_copy(hard_one, "Nothing", tmp_path)
    src = next(hard_one.glob("singleskit_*"))
    name = src.name.split("_")[1]
    with pytest.raises(SystemExit, match="overwrite its source"):
        rc.registered_copy(hard_one, name, hard_one)
    easy = tmp_path / "easy"
    generate_dataset(easy, garments=1, seed=3, frame=(192, 144), progress=False, profile="easy")
    with pytest.raises(SystemExit, match="no registration offsets"):
        rc.registered_copy(easy, next(easy.glob("singleskit_*")).name.split("_")[1], tmp_path / "out")


def test_a_touch_s_offset_is_read_by_its_serial_and_unknown_serials_are_refused():
    offsets = [[1, -2], [0, 3]]
    assert registration_offset(offsets, "denimshorts_0002_tactile") == (0, 3)
    for bad in ("denimshorts_0003_tactile", "denimshorts_0000_tactile", "denimshorts_full_tactile", "tactile"):
        with pytest.raises(ValueError, match="no registration offset for this touch"):
            registration_offset(offsets, bad)
