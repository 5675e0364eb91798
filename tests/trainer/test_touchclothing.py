"""The TouchClothing loader on a tiny folder in the published layout."""
import shutil

import numpy as np
import pytest

from tests.conftest import REAL_OFFSET, field_gx, write_real_layout
from trainer.data.check import check_dataset, format_reports
from trainer.data.touchclothing import (PATCH, DatasetError, extract_patches, find_garments, friction_scale,
                                        load_garment, parse_folder_name)


def test_folder_name():
    assert parse_folder_name("singleskit_Denim_Shorts_padded_1800_x1") == ("Denim_Shorts", 1800, 1)
    with pytest.raises(DatasetError, match="not a garment folder"):
        parse_folder_name("denim")


def test_load_published_layout(real_layout_dir):
    (root,) = find_garments(real_layout_dir)
    g = load_garment(root)
    assert g.material == "DenimToy" and g.padded_size == 1800 and g.offset == REAL_OFFSET
    assert g.frame == (1280, 960) and not g.edited and g.full_tactile is None
    assert g.sketch.shape == (1800, 1800) and g.visual.shape == (1800, 1800, 3) and g.mask.dtype == bool
    assert g.touch_count() == {"train": 6, "val": 2, "test": 2}
    t = g.touches["train"][0]
    assert t.gx.dtype == np.float32 and t.contact.dtype == bool
    # 0/255 masks were divided by 255
    assert t.contact.mean() < 1 and t.centres.any()


def test_patches_land_where_the_tactile_file_says(real_layout_dir):
    g = load_garment(find_garments(real_layout_dir)[0])
    gx_full, gy_full = field_gx((1800, 1800))
    crop = (120, 97)
    ps = extract_patches(g, "train", crop_origin=crop, crop_size=(1536, 1536), per_touch=3,
                         rng=np.random.default_rng(0))
    assert len(ps) == 18 and ps.gx.shape == (18, PATCH, PATCH)
    for i in range(len(ps)):
        x, y = ps.origin[i]
        px, py = crop[0] + x, crop[1] + y
        np.testing.assert_allclose(ps.gx[i], gx_full[py:py + PATCH, px:px + PATCH], atol=1e-6)
        np.testing.assert_allclose(ps.gy[i], gy_full[py:py + PATCH, px:px + PATCH], atol=1e-6)
        assert 0 <= x and x + PATCH <= 1536 and 0 <= y and y + PATCH <= 1536
        assert set(np.unique(ps.contact[i])) <= {0.0, 1.0}


def test_patches_outside_crop_or_object_are_dropped(real_layout_dir):
    g = load_garment(find_garments(real_layout_dir)[0])
    # A crop that holds none of the touches.
    ps = extract_patches(g, "val", crop_origin=(0, 0), crop_size=(200, 200), mode="centre")
    assert len(ps) == 0
    # An empty object mask drops every patch.
    ps = extract_patches(g, "val", mode="centre", mask=np.zeros((1800, 1800), bool))
    assert len(ps) == 0
    ps = extract_patches(g, "val", mode="centre")
    assert len(ps) == 2
    assert np.array_equal(ps.origin, extract_patches(g, "val", mode="centre").origin)  # deterministic
    with pytest.raises(ValueError, match="rng"):
        extract_patches(g, "val")


def test_friction_scale_positive(real_layout_dir):
    g = load_garment(find_garments(real_layout_dir)[0])
    s = friction_scale(g)
    assert 0.001 < s < 0.1


def test_check_summary(real_layout_dir):
    reports = check_dataset(real_layout_dir)
    assert len(reports) == 1 and reports[0].ok
    text = format_reports(reports)
    assert "DenimToy" in text and "6/  2/  2" in text and "0 failed" in text


@pytest.mark.parametrize("breakage, match", [
    (lambda g: shutil.rmtree(g / "trainM"), "missing sub-folder trainM"),
    (lambda g: shutil.rmtree(g / "valT"), "missing sub-folder valT"),
    (lambda g: shutil.copy(next((g / "trainS").rglob("*.png")), g / "trainS" / "second.png"), "exactly one image"),
    (lambda g: (next((g / "trainI").rglob("*.png"))).write_bytes(b"not an image"), "not a readable image"),
    (lambda g: [p.unlink() for p in (g / "trainT").glob("*.npz")], "no \\*_tactile.npz"),
])
def test_bad_folders_name_what_is_missing(tmp_path, breakage, match):
    g = write_real_layout(tmp_path, touches=(2, 1, 1))
    breakage(g)
    with pytest.raises(DatasetError, match=match):
        load_garment(g)
    reports = check_dataset(tmp_path)
    assert not reports[0].ok and "FAIL" in format_reports(reports)


def test_bad_tactile_files(tmp_path):
    g = write_real_layout(tmp_path, touches=(2, 1, 1))
    f = next((g / "trainT").glob("*.npz"))
    data = dict(np.load(f))
    del data["touch_center_thresh"]
    np.savez(f, **data)
    with pytest.raises(DatasetError, match="missing keys touch_center_thresh"):
        load_garment(g)
    data["touch_center_thresh"] = np.zeros((3, 3))
    np.savez(f, **data)
    with pytest.raises(DatasetError, match="must match"):
        load_garment(g)
    f.write_bytes(b"garbage")
    with pytest.raises(DatasetError, match="not a readable tactile file"):
        load_garment(g)


def test_wrong_image_size(tmp_path):
    g = write_real_layout(tmp_path, touches=(1, 1, 1))
    renamed = g.parent / g.name.replace("1800", "1700")
    g.rename(renamed)
    with pytest.raises(DatasetError, match="expected 1700x1700"):
        load_garment(renamed)


def test_edited_sketch_folder_needs_only_a_sketch(tmp_path):
    g = write_real_layout(tmp_path, material="DenimToy_edit1", touches=(1, 1, 1))
    for sub in ("trainI", "trainM", "trainT", "valT", "testS", "testI", "testM", "testT"):
        shutil.rmtree(g / sub)
    loaded = load_garment(g)
    assert loaded.edited and loaded.visual is None and loaded.mask.any()


@pytest.mark.parametrize("text, match", [
    ("frame: [unclosed\n", "not valid YAML"),
    ("[" * 500 + "]" * 500, "not valid YAML"),
    ("- a list\n", "top level must be a mapping"),
    ("frame: [12, x]\n", "'frame' must be \\[width, height\\]"),
])
def test_a_broken_garment_description_is_one_line_naming_the_file(tmp_path, text, match):
    g = write_real_layout(tmp_path, touches=(1, 1, 1))
    (g / "synthetic.yaml").write_text(text)
    with pytest.raises(DatasetError, match=match) as err:
        load_garment(g)
    assert "\n" not in str(err.value) and "synthetic.yaml" in str(err.value)
