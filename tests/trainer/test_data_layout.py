"""`vtkiosk data check` on a wrong TouchClothing layout: every problem at once, each with a fix an operator can act
on (trainer/data/layout.py), through the function and the real command line."""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.conftest import write_real_layout
from trainer.data.check import check_dataset, format_reports
from trainer.data.layout import layout_problems, name_problem
from trainer.data.touchclothing import FOLDER_RE, DatasetError, parse_folder_name

LAYOUT_SUBS = ("trainS", "trainI", "trainM", "trainT", "valT", "testT")


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    return write_real_layout(tmp_path_factory.mktemp("pristine"), touches=(2, 1, 1))


@pytest.fixture
def garment(pristine, tmp_path) -> Path:
    out = tmp_path / "data" / pristine.name
    shutil.copytree(pristine, out)
    return out


def _one(folder: Path) -> Path:
    return next(p for p in folder.rglob("*") if p.is_file())


def _rename_keys(g: Path) -> None:
    for f in (g / "trainT").glob("*.npz"):
        data = dict(np.load(f))
        data["gx"] = data.pop("gx_raw")
        np.savez(f, **data)


BREAKAGES = {
    "misnamed folder": (lambda g: g.rename(g.parent / "DenimToy"), "DenimToy/",
                        "rename it to singleskit_DenimToy_padded_1800_x1"),
    "no multiplier": (lambda g: g.rename(g.parent / "singleskit_DenimToy_padded_1800"),
                      "singleskit_DenimToy_padded_1800/", "rename it to singleskit_DenimToy_padded_1800_x1"),
    "mis-cased sub-folder": (lambda g: (g / "trainM").rename(g / "trainm"), "trainm/", "rename it to trainM/"),
    "missing sub-folder": (lambda g: shutil.rmtree(g / "trainI"), "trainI/: missing",
                           "create it and put the visual image"),
    "unpadded image": (lambda g: cv2.imwrite(str(_one(g / "trainI")), np.zeros((960, 1280, 3), np.uint8)),
                       "is 1280x960 pixels, expected 1800x1800", "pad it to 1800x1800 with the frame at (260, 420)"),
    "wrong square size": (lambda g: cv2.imwrite(str(_one(g / "trainM")), np.zeros((900, 900), np.uint8)),
                          "is 900x900 pixels", "resize the image to 1800x1800, or rename the folder"),
    "two images": (lambda g: shutil.copy(_one(g / "trainS"), _one(g / "trainS").parent / "copy.png"),
                   "found 2 (", "keep one"),
    "unsupported image format": (lambda g: _one(g / "trainS").rename(g / "trainS" / "sketch.gif"),
                                 "found none (found sketch.gif)", "as PNG"),
    "touches misnamed": (lambda g: [f.rename(f.with_name(f.name.replace("_tactile", ""))) for f in
                                    (g / "trainT").glob("*.npz")], "no *_tactile.npz touch files; found 2 other",
                         "_tactile.npz"),
    "no touches at all": (lambda g: [f.unlink() for f in (g / "trainT").glob("*.npz")], "trainT/: no touches",
                          "copy the garment's tactile files there"),
    "keys under other names": (_rename_keys, "missing keys gx_raw", "rename keys gx -> gx_raw"),
}


@pytest.mark.parametrize("name", sorted(BREAKAGES))
def test_each_wrong_layout_is_named_with_its_fix(garment, name):
    breakage, what, fix = BREAKAGES[name]
    breakage(garment)
    reports = check_dataset(garment.parent)
    (r,) = reports
    text = format_reports(reports)
    assert not r.ok and "FAIL" in text, text
    assert any(what in p and fix in p for p in r.problems), r.problems


def test_all_problems_are_listed_at_once(garment):
    for name in ("mis-cased sub-folder", "unpadded image", "keys under other names"):
        BREAKAGES[name][0](garment)
    (r,) = check_dataset(garment.parent)
    for name in ("mis-cased sub-folder", "unpadded image", "keys under other names"):
        assert any(BREAKAGES[name][1] in p for p in r.problems), (name, r.problems)
    assert len(r.problems) == 4, r.problems          # both train touch files lack gx_raw


def test_missing_val_touches_is_a_warning_with_a_reason(garment):
    for f in (garment / "valT").glob("*.npz"):
        f.unlink()
    (r,) = check_dataset(garment.parent)
    assert r.ok and any("valT/: no touches" in w and "val metrics are empty" in w for w in r.warnings), r.warnings


def test_a_dataset_with_no_garment_folder_says_where_the_layout_is(tmp_path):
    (tmp_path / "notes").mkdir()
    with pytest.raises(DatasetError, match="no garment folders .* docs/real-garments.md"):
        check_dataset(tmp_path)


def test_the_command_line_prints_each_problem_and_exits_1(garment):
    BREAKAGES["mis-cased sub-folder"][0](garment)
    BREAKAGES["unpadded image"][0](garment)
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "data", "check", str(garment.parent)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    problems = [line for line in proc.stdout.splitlines() if line.strip().startswith("problem:")]
    assert len(problems) == 2 and "rename it to trainM/" in proc.stdout and "Traceback" not in proc.stderr


# --- properties ------------------------------------------------------------------------------------------------
materials = st.lists(st.sampled_from(["Denim", "Shorts", "Wool", "Coat", "Silk", "Knit", "Jacket", "Satin"]),
                     min_size=1, max_size=3).map("".join)


@given(material=materials, padded=st.integers(64, 4000),
       mangle=st.sampled_from(["drop_x", "drop_prefix", "drop_padded", "snake", "x2"]))
@settings(max_examples=60, deadline=None)
def test_a_mangled_folder_name_gets_a_name_that_loads(material, padded, mangle):
    good = f"singleskit_{material}_padded_{padded}_x1"
    assert name_problem(good) is None
    bad = {"drop_x": good[:-3], "drop_prefix": good.removeprefix("singleskit_"),
           "drop_padded": f"singleskit_{material}", "snake": f"{material.lower()}_padded_{padded}",
           "x2": good[:-1] + "2"}[mangle]
    problem = name_problem(bad, side=padded)
    assert problem is not None and bad in problem.where
    if mangle == "x2":
        assert "only x1" in problem.fix
        return
    suggested = problem.fix.rsplit("rename it to ", 1)[1].split(",")[0]
    assert FOLDER_RE.match(suggested), suggested
    got_material, got_padded, mult = parse_folder_name(suggested)
    assert got_padded == padded and mult == 1
    assert got_material.lower() == material.lower()


@given(removed=st.sets(st.sampled_from(LAYOUT_SUBS)))
@settings(max_examples=40, deadline=None)
def test_exactly_the_missing_sub_folders_are_named(removed):
    with tempfile.TemporaryDirectory() as tmp:
        g = Path(tmp) / "singleskit_Denim_padded_64_x1"
        for sub in LAYOUT_SUBS:
            if sub not in removed:
                (g / sub).mkdir(parents=True)
        g.mkdir(exist_ok=True)
        named = {p.where.rstrip("/").rsplit("/", 1)[1] for p in layout_problems(g) if p.what == "missing"}
        assert named == set(removed)
