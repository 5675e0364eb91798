"""The target's picture: which runs it places where, the corner `ours` must reach, and a real PNG."""
from __future__ import annotations

import math

import cv2
import pytest
from hypothesis import given, strategies as st

from trainer import target_plot
from trainer.target_plot import X, Y


def run(garment, method, x, y, refs=None):
    return {"garment": garment, "method": method, X: x, Y: y, "references": refs or {}}


REFS = {"flat": {X: 16.9, Y: 0.25}, "oracle": {X: 5.5, Y: None}, "shape-oracle": {X: 15.6},
        "mean-colour": {X: None, Y: None}}


def test_points_keep_runs_with_both_figures_only():
    results = [run("KnitJacket", "ours", 14.5, 0.05), run("KnitJacket", "ours", 14.9, 0.06),
               run("KnitJacket", "gaugan", float("nan"), 0.07), run("KnitJacket", "pix2pix", 19.0, None),
               run("KnitJacket", "pix2pixhd", True, 0.08), run("KnitJacket", "ours-no-gan", 18.0, float("inf")),
               run("DenimShorts", "ours", 7.0, 0.006)]
    pts = target_plot.points(results)
    assert pts == {"KnitJacket": {"ours": [(14.5, 0.05), (14.9, 0.06)]}, "DenimShorts": {"ours": [(7.0, 0.006)]}}


def test_references_keep_angle_only_rows_and_drop_rows_with_neither():
    refs = target_plot.reference_points([run("KnitJacket", "ours", 14.5, 0.05, REFS),
                                         run("KnitJacket", "gaugan", 24.0, 0.07, {"flat": {X: 1.0, Y: 1.0}})])
    assert refs == {"KnitJacket": {"flat": (16.9, 0.25), "oracle": (5.5, None), "shape-oracle": (15.6, None)}}


def test_corner_is_the_best_other_mean_on_each_figure():
    methods = {"ours": [(1.0, 0.001)], "a": [(10.0, 0.2), (12.0, 0.4)], "b": [(16.0, 0.05)]}
    assert target_plot.corner(methods, "ours") == (11.0, 0.05)
    assert target_plot.corner({"ours": [(1.0, 0.1)]}, "ours") is None


@given(st.lists(st.tuples(st.sampled_from("abc"), st.floats(0, 90), st.floats(0, 1)), min_size=1, max_size=12))
def test_corner_is_never_beaten_by_another_methods_mean(rows):
    methods: dict[str, list] = {}
    for m, x, y in rows:
        methods.setdefault(m, []).append((x, y))
    c = target_plot.corner(methods, "a")
    others = [m for m in methods if m != "a"]
    if not others:
        assert c is None
        return
    for m in others:
        mx = sum(x for x, _ in methods[m]) / len(methods[m])
        my = sum(y for _, y in methods[m]) / len(methods[m])
        assert c[0] <= mx + 1e-9 and c[1] <= my + 1e-9


def test_short_names():
    assert target_plot._short("singleskit_KnitJacket_padded_900_x1") == "KnitJacket"
    assert target_plot._short("my garment") == "my garment"


def test_plot_writes_one_panel_per_garment(tmp_path):
    results = [run(g, m, x, y, REFS) for g in ("singleskit_KnitJacket_padded_900_x1", "singleskit_A_x", "B", "C")
               for m, x, y in (("ours", 14.5, 0.05), ("ours", 14.9, 0.06), ("gaugan", 24.3, 0.07))]
    target = {"garments": [{"garment": "B", "won": True, "settled": True}]}
    out = target_plot.plot(results, tmp_path / "t" / "target.png", "ours", target)
    img = cv2.imread(str(out))
    assert img is not None and math.isclose(img.shape[1] / img.shape[0], 1.1, rel_tol=0.15)   # 2 x 2 panels


def test_plot_writes_nothing_without_both_figures(tmp_path):
    assert target_plot.plot([run("B", "ours", 1.0, None)], tmp_path / "target.png", "ours") is None
    assert not (tmp_path / "target.png").exists()


@pytest.mark.parametrize("n", [1, 3])
def test_plot_with_only_ours_draws_no_corner(tmp_path, n):
    results = [run(f"G{i}", "ours", 3.0 + i, 0.01) for i in range(n)]
    assert target_plot.plot(results, tmp_path / "target.png", "ours").is_file()
