"""The evaluation protocol: every held-out patch centre, inside/outside masks, masked visual metrics, the reference
rows (flat, mean-colour, oracle), gap closed, and `vtkiosk eval --compare` end to end on tiny runs."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from trainer.augment import eval_crop_origin
from trainer.config import load_config
from trainer.data.synthetic import generate_dataset
from trainer.data.touchclothing import extract_patches, load_garment
from trainer.evaluate import Context, Nets, find_unseen, gap_closed, near_strokes, reference_predictions, score
from trainer.heldout import heldout_errors, touch_rect_mask
from trainer.loop import Trainer
from trainer.metrics import full_field_scores, tactile_patch_metrics, visual_scores
from trainer.references import Oracle, exported_head, fit_sensor_blur, oracle, weave_period_px, weave_split
from trainer.sampling import patches_to_tensors
from vtkiosk.cli import main as vtkiosk

FULL = ("full_angle_deg", "full_angle_deg_inside", "full_angle_deg_outside", "full_friction_mae",
        "full_friction_mae_inside", "full_friction_mae_outside")


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth_eval")
    # the easy profile: touches are the truth plus white noise, so the oracle's fitted sensor blur must be 0
    generate_dataset(root, garments=2, seed=0, frame=(192, 144), progress=False, profile="easy")
    return root


@pytest.fixture(scope="module")
def garment(synth):
    return load_garment(synth / "singleskit_DenimShorts_padded_270_x1")


def _ctx(g, side=256):
    return Context(g, side, eval_crop_origin(g.mask, side), 0.05)


def _pooled(g, ctx, gx, gy, per_touch):
    """Brute force: cut every patch (extract_patches) and pool their contact pixels."""
    ps = extract_patches(g, "test", crop_origin=ctx.origin, crop_size=(ctx.side, ctx.side),
                         per_touch=per_touch, mode="random", rng=np.random.default_rng(0))
    tgx, tgy, c = patches_to_tensors(ps, np.arange(len(ps)))
    fake = torch.stack([torch.stack([torch.from_numpy(gx[y:y + 32, x:x + 32]),
                                     torch.from_numpy(gy[y:y + 32, x:x + 32])]) for x, y in ps.origin.tolist()])
    return tactile_patch_metrics(fake, tgx, tgy, c), len(ps)


def test_every_held_out_centre_is_scored_exactly_as_cutting_every_patch(garment):
    ctx = _ctx(garment)
    rng = np.random.default_rng(1)
    gx, gy = (rng.normal(0, 0.1, (ctx.side, ctx.side)).astype(np.float32) for _ in range(2))
    allc = heldout_errors(garment, "test", ctx.origin, ctx.side, gx, gy)
    want, n = _pooled(garment, ctx, gx, gy, per_touch=10 ** 6)
    s = allc.scores()
    assert s["test_patches"] == n > 10 * s["test_touches"]
    assert s["tactile_angle_deg"] == pytest.approx(want["tactile_angle_deg"], rel=1e-6)
    assert s["tactile_mse"] == pytest.approx(want["tactile_mse"], rel=1e-5)
    # "middle" reproduces the old one-patch-per-touch protocol
    mid = heldout_errors(garment, "test", ctx.origin, ctx.side, gx, gy, centres="middle").scores()
    ps = ctx.patches
    tgx, tgy, c = patches_to_tensors(ps, np.arange(len(ps)))
    fake = torch.stack([torch.stack([torch.from_numpy(gx[y:y + 32, x:x + 32]),
                                     torch.from_numpy(gy[y:y + 32, x:x + 32])]) for x, y in ps.origin.tolist()])
    old = tactile_patch_metrics(fake, tgx, tgy, c)
    assert mid["test_patches"] == len(ps)
    assert mid["tactile_angle_deg"] == pytest.approx(old["tactile_angle_deg"], rel=1e-6)
    assert mid["tactile_mse"] == pytest.approx(old["tactile_mse"], rel=1e-5)
    with pytest.raises(ValueError, match="centres"):
        heldout_errors(garment, "test", ctx.origin, ctx.side, gx, gy, centres="some")


def test_inside_and_outside_masks_split_the_object_at_the_training_rectangles(garment):
    rects = touch_rect_mask(garment, "train")
    for t in garment.touches["train"]:
        r = t.rect
        assert rects[r.y:r.y + r.h, r.x:r.x + r.w].all()
    built = np.zeros_like(rects)
    for t in garment.touches["train"]:
        built[t.rect.y:t.rect.y + t.rect.h, t.rect.x:t.rect.x + t.rect.w] = True
    assert np.array_equal(rects, built) and not rects[~built].any()
    ctx = _ctx(garment)
    assert np.array_equal(ctx.inside, ctx.crop(rects) & ctx.obj)
    assert 0 < ctx.inside.sum() < ctx.obj.sum()
    # a prediction that is exact inside the rectangles and flat outside: zero error inside, flat's error outside
    tx, ty = ctx.truth()
    gx, gy = np.where(ctx.inside, tx, 0), np.where(ctx.inside, ty, 0)
    s, u = full_field_scores(gx, gy, tx, ty, ctx.obj, ctx.inside, 0.05, ctx.origin)
    flat, _ = full_field_scores(0 * tx, 0 * ty, tx, ty, ctx.obj, ctx.inside, 0.05, ctx.origin)
    assert s["full_angle_deg_inside"] == pytest.approx(0, abs=1e-5) and s["full_friction_mae_inside"] == 0
    assert s["full_angle_deg_outside"] == pytest.approx(flat["full_angle_deg_outside"])
    f = s["full_inside_fraction"]
    assert s["full_angle_deg"] == pytest.approx((1 - f) * s["full_angle_deg_outside"], abs=1e-5)
    assert u["full_angle_deg"].den.sum() == ctx.obj.sum()


def test_the_outside_angle_splits_into_the_sketchs_lines_and_open_cloth(garment):
    """Exact where the sketch draws (outside the touches), flat in open cloth: zero error by the lines, flat's error
    in open cloth, and the two parts pixel-weight back to the outside angle."""
    ctx = _ctx(garment)
    lines = ctx.near_lines
    out = ctx.obj & ~ctx.inside
    assert lines is not None and 0 < (out & lines).sum() < out.sum()
    tx, ty = ctx.truth()
    gx, gy = np.where(lines, tx, 0), np.where(lines, ty, 0)
    s, u = full_field_scores(gx, gy, tx, ty, ctx.obj, ctx.inside, 0.05, ctx.origin, lines)
    flat, _ = full_field_scores(0 * tx, 0 * ty, tx, ty, ctx.obj, ctx.inside, 0.05, ctx.origin, lines)
    assert s["full_angle_deg_outside_lines"] == pytest.approx(0, abs=1e-5)
    assert s["full_angle_deg_outside_open"] == pytest.approx(flat["full_angle_deg_outside_open"])
    assert flat["full_angle_deg_outside_open"] > 0
    share = (out & lines).sum() / out.sum()
    for r in (s, flat):
        assert r["full_angle_deg_outside"] == pytest.approx(
            share * r["full_angle_deg_outside_lines"] + (1 - share) * r["full_angle_deg_outside_open"], rel=1e-5)
    assert u["full_angle_deg_outside_lines"].den.sum() + u["full_angle_deg_outside_open"].den.sum() == out.sum()
    # without the mask (no pixel pitch) there is no split, and nothing else changes
    plain, _ = full_field_scores(gx, gy, tx, ty, ctx.obj, ctx.inside, 0.05, ctx.origin)
    assert "full_angle_deg_outside_lines" not in plain
    assert plain["full_angle_deg_outside"] == pytest.approx(s["full_angle_deg_outside"])


@pytest.mark.parametrize("pitch, near, far", [(0.3, 4, 5), (0.6, 2, 3), (0.1, 12, 13)])
def test_a_line_reaches_the_same_millimetres_at_any_pixel_pitch(pitch, near, far):
    sketch = np.full((40, 40), 255, np.uint8)
    sketch[:, 20] = 0                       # one vertical stroke
    m = near_strokes(sketch, pitch)
    assert m[:, 20].all() and m[:, 20 + near].all() and m[:, 20 - near].all()
    assert not m[:, 20 + far].any() and not m[:, 20 - far].any()


def test_no_lines_without_a_pixel_pitch_and_none_on_blank_paper():
    blank = np.full((16, 16), 255, np.uint8)
    assert near_strokes(blank, None) is None and near_strokes(blank, float("nan")) is None
    assert near_strokes(blank, 0.0) is None
    assert not near_strokes(blank, 0.3).any()


def test_visual_metrics_look_inside_the_object_mask_only():
    rng = np.random.default_rng(0)
    real = rng.uniform(-1, 1, (3, 64, 64))
    mask = np.zeros((64, 64), bool)
    mask[16:48, 20:50] = True
    fake = real.copy()
    fake[:, ~mask] = -real[:, ~mask]            # wrong everywhere off the object
    s, u = visual_scores(fake, real, mask, (0, 0))
    assert s["visual_psnr"] == pytest.approx(120.0) and s["visual_l1"] == 0.0
    fake[:, mask] += 0.1                         # 0.05 on [0, 1]: MSE 0.0025, PSNR 26.02 dB
    s, _ = visual_scores(np.clip(fake, -2, 2), real, mask, (0, 0))
    assert s["visual_psnr"] == pytest.approx(10 * np.log10(1 / 0.0025)) and s["visual_l1"] == pytest.approx(0.1)
    assert visual_scores(real, real, mask, (0, 0))[0]["visual_ssim"] == pytest.approx(1.0)


def test_oracle_is_the_truth_through_the_measured_sensor_blur_and_the_exported_head(garment):
    o = oracle(garment)
    assert o.sigma_px == 0.0 and o.precision == "float32"   # these touches are truth + white noise: no blur
    ft = garment.full_tactile
    assert np.array_equal(o.gx, exported_head(ft.gx, garment.mask))
    assert np.abs(o.gx).max() <= 1.0 and not o.gx[~garment.mask].any()
    # touches recorded through a 1.5 px gel blur: the fit finds it
    blurred = load_garment(garment.root)
    bx = cv2.GaussianBlur(ft.gx, (0, 0), 1.5, borderType=cv2.BORDER_REFLECT)
    by = cv2.GaussianBlur(ft.gy, (0, 0), 1.5, borderType=cv2.BORDER_REFLECT)
    for t in blurred.touches["train"]:
        r = t.rect
        t.gx, t.gy = bx[r.y:r.y + r.h, r.x:r.x + r.w], by[r.y:r.y + r.h, r.x:r.x + r.w]
    assert fit_sensor_blur(blurred)[0] == pytest.approx(1.5)
    half = exported_head(np.array([[0.1 + 1e-4, 3.0]]), np.ones((1, 2)), "fp16")
    assert half[0, 0] == np.float16(0.1 + 1e-4) and half[0, 1] == 1.0
    with pytest.raises(ValueError, match="precision"):
        exported_head(ft.gx, garment.mask, "int4")


def test_oracle_scores_at_least_as_well_as_any_prediction_on_the_full_field(garment):
    ctx = _ctx(garment)
    nets = Nets(load_config("tiny").pretrained)
    refs = reference_predictions(ctx)
    assert set(refs) == {"flat", "mean-colour", "oracle", "shape-oracle", "texture-oracle"}
    o, _ = score(ctx, nets, None, refs["oracle"][1])
    tx, ty = ctx.truth()
    rng = np.random.default_rng(0)
    t = torch.from_numpy(np.stack([tx, ty]))[None]
    m = torch.from_numpy(ctx.obj.astype(np.float32))
    candidates = {"flat": refs["flat"][1], "noisy": t + 0.05 * torch.from_numpy(rng.normal(size=t.shape)).float(),
                  "too strong": 1.3 * t, "blurred": torch.from_numpy(np.stack(
                      [cv2.GaussianBlur(a, (0, 0), 2.0) for a in (tx, ty)]))[None]}
    for name, c in candidates.items():
        c = (c.clamp(-1, 1) * m)[0].numpy()      # what a generator's head can emit: tanh range, 0 off the object
        s, _ = full_field_scores(c[0], c[1], tx, ty, ctx.obj, ctx.inside, ctx.scale, ctx.origin)
        for k in FULL:
            assert o[k] <= s[k] + 1e-9, (name, k, o[k], s[k])


def _band_power(a: np.ndarray, period: float) -> float:
    """Power of `a` in the ring of spatial frequencies within 25 % of 1/period."""
    f = np.abs(np.fft.fft2(a)) ** 2
    fy, fx = np.meshgrid(np.fft.fftfreq(a.shape[0]), np.fft.fftfreq(a.shape[1]), indexing="ij")
    r = np.hypot(fx, fy)
    return float(f[(r > 0.75 / period) & (r < 1.25 / period)].sum())


def test_weave_oracles_split_the_oracle_into_its_shape_and_an_unplaced_weave(garment):
    """A fold (smooth) plus a weave (6 px period): the shape-oracle keeps the fold and drops the weave; the
    texture-oracle keeps the weave's spectrum but not its place, so it scores worse than the shape-oracle."""
    g = load_garment(garment.root)
    period = 6.0
    g.meta = dict(g.meta, pixel_pitch_mm=0.5, fabric={"period_mm": period * 0.5})
    assert weave_period_px(g) == pytest.approx(period)
    n = g.mask.shape[0]
    xx = np.mgrid[0:n, 0:n][1].astype(np.float32)
    fold = 0.3 * np.sin(2 * np.pi * xx / 90.0)
    # a weave of many components (a ring of frequencies around 1/period), so "not placed" means uncorrelated
    f = np.fft.fft2(np.random.default_rng(3).normal(size=(n, n)))
    fy, fx = np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(n), indexing="ij")
    ring = np.abs(np.hypot(fx, fy) - 1.0 / period) < 0.1 / period
    weave = np.real(np.fft.ifft2(f * ring)).astype(np.float32)
    weave *= 0.1 / weave.std()
    m = g.mask
    o = Oracle(exported_head(fold + weave, m), exported_head(0 * fold, m), 0.0, 0.0, "float32")
    shape, texture = weave_split(g, o)
    inner = cv2.erode(m.astype(np.uint8), np.ones((25, 25), np.uint8)).astype(bool)   # away from the mask's edge
    assert np.abs(shape.gx - fold)[inner].max() < 0.03                         # the fold survives
    assert _band_power((shape.gx - fold) * inner, period) < 0.01 * _band_power((o.gx - fold) * inner, period)  # nor weave
    ratio = _band_power(texture.gx - shape.gx, period) / _band_power((o.gx - shape.gx) * m, period)
    assert 0.7 < ratio < 1.3                                                    # the weave's spectrum is kept
    assert abs(np.corrcoef((texture.gx - shape.gx)[inner], (o.gx - shape.gx)[inner])[0, 1]) < 0.2   # its place not
    for a in (shape.gx, shape.gy, texture.gx, texture.gy):
        assert np.isfinite(a).all() and np.abs(a).max() <= 1.0 and not a[~m].any()
    assert np.array_equal(weave_split(g, o)[1].gx, texture.gx)                  # fixed phases: reproducible


@pytest.mark.parametrize("fabric, pitch", [(None, 0.3), ({}, 0.3), ({"period_mm": 0.0}, 0.3),
                                           ({"period_mm": float("nan")}, 0.3), ({"period_mm": "wide"}, 0.3),
                                           ({"period_mm": 1.2}, None), ({"period_mm": 1.2}, 0.0), ("denim", 0.3)])
def test_no_weave_oracles_without_a_usable_weave_period(garment, fabric, pitch):
    g = load_garment(garment.root)
    g.meta = {k: v for k, v in g.meta.items() if k not in ("fabric", "pixel_pitch_mm")}
    if fabric is not None:
        g.meta["fabric"] = fabric
    if pitch is not None:
        g.meta["pixel_pitch_mm"] = pitch
    assert weave_period_px(g) is None and weave_split(g, oracle(g)) is None
    assert set(reference_predictions(_ctx(g))) == {"flat", "mean-colour", "oracle"}


def test_unseen_sketches_are_the_other_garments_and_the_edited_ones(synth, tmp_path):
    import shutil
    for d in synth.iterdir():
        shutil.copytree(d, tmp_path / d.name)
    src = tmp_path / "singleskit_DenimShorts_padded_270_x1"
    edit = tmp_path / "singleskit_DenimShortsedit1_padded_270_x1" / "trainS"
    edit.mkdir(parents=True)
    sketch = cv2.imread(str(next((src / "trainS").glob("*.png"))), cv2.IMREAD_GRAYSCALE)
    cv2.line(sketch, (60, 100), (200, 110), 0, 2)       # an edit: one more stroke
    cv2.imwrite(str(edit / "denimshortsedit1_sketch.png"), sketch)
    shutil.copyfile(src / "synthetic.yaml", edit.parent / "synthetic.yaml")
    (tmp_path / "singleskit_Broken_padded_270_x1").mkdir()     # unreadable: skipped, not fatal
    g = load_garment(src)
    found = {u.name: u.kind for u in find_unseen(g, 256)}
    assert found == {"singleskit_CorduroyTrousers_padded_270_x1": "other garment",
                     "singleskit_DenimShortsedit1_padded_270_x1": "edited"}
    assert find_unseen(load_garment(synth / "singleskit_CorduroyTrousers_padded_270_x1"), 256)[0].kind == \
        "other garment"


def test_gap_closed_is_guarded_where_flat_and_oracle_tie():
    flat, orc = {"tactile_angle_deg": 20.0, "tactile_mse": 0.1}, {"tactile_angle_deg": 4.0, "tactile_mse": 0.1}
    g = gap_closed({"tactile_angle_deg": 8.0, "tactile_mse": 0.05, "visual_psnr": 30.0}, flat, orc)
    assert g == {"tactile_angle_deg": pytest.approx(0.75), "tactile_mse": None}
    assert gap_closed(flat, flat, orc)["tactile_angle_deg"] == 0.0
    assert gap_closed(orc, flat, orc)["tactile_angle_deg"] == 1.0


@pytest.mark.slow
def test_compare_on_tiny_runs_has_reference_rows_gaps_and_intervals(synth, tmp_path, capsys, monkeypatch):
    runs = []
    for garment_name in ("DenimShorts", "CorduroyTrousers"):
        for method in ("ours", "pix2pix"):
            cfg = load_config("tiny", method=method, overrides=["train.steps=1", "train.threads=1"])
            out = tmp_path / garment_name / method
            Trainer(cfg, synth / f"singleskit_{garment_name}_padded_270_x1", out).run()
            runs.append(out)
    cmp_dir = tmp_path / "cmp"
    assert vtkiosk(["eval", "--compare", *map(str, runs), "--out", str(cmp_dir), "--bootstrap", "200"]) == 0
    md = (cmp_dir / "compare.md").read_text()
    for row in ("| ours |", "| pix2pix |", "| *flat* (reference) |", "| *mean-colour* (reference) |",
                "| *oracle* (reference) |", "paired bootstrap 95 % interval", "| *flat* | – |", "outside° ↓"):
        assert row in md, row
    assert md.count("gap") >= 6
    data = json.loads((cmp_dir / "compare.json").read_text())
    assert set(data["references"]) == {"flat", "mean-colour", "oracle", "shape-oracle", "texture-oracle"}
    assert data["reference_gap_closed"]["oracle"]["full_angle_deg"] == 1.0
    assert {"tactile_angle_deg", "full_angle_deg_outside"} <= set(data["gap_closed"]["pix2pix"])
    d = data["differences"]["rows"]["pix2pix"]["full_angle_deg"]
    assert d["lo"] <= d["diff"] <= d["hi"] and d["garments"] == 2
    n_unseen = sum(len(r["unseen_sketches"]) for r in data["runs"] if r["method"] == "ours")
    u = data["differences"]["rows"]["pix2pix"]["full_fbsifid_unseen"]   # one unit per unseen sketch
    assert u["garments"] == 2 and u["units"] == n_unseen and u["lo"] <= u["diff"] <= u["hi"]
    target = data["target"]
    assert target["competitors"] == ["pix2pix"] and len(target["garments"]) == 2 and target["met"] is False
    assert "### Target check" in md and "Not met" in md
    for r in data["runs"]:   # the oracle beats every trained run on the full field, garment by garment
        assert all(r["references"]["oracle"][k] <= r[k] for k in FULL)
        assert r["test_patches"] > r["test_touches"] and r["unseen_sketches"][0]["kind"] == "other garment"
        assert "visual_fbsifid_unseen" in r and "visual_fbsifid_seen" in r and "full_fbsifid_unseen" in r
    assert (cmp_dir / "sheet_DenimShorts.png").is_file() and (cmp_dir / "sheet_CorduroyTrousers.png").is_file()
    sheet = cv2.imread(str(cmp_dir / "sheet_DenimShorts.png"))
    assert sheet.shape[0] == 256 * 6   # sketch row, truth, flat + mean-colour, oracle, ours, pix2pix
    assert "target_plot" not in data and "sheets" not in data   # no machine's paths in the committed JSON
    plot = cv2.imread(str(cmp_dir / "target.png"))
    assert plot is not None and plot.shape[1] > plot.shape[0]   # two garments side by side
    # scores are stored beside each run; a second compare reuses them while nothing changed
    assert (runs[0] / "eval" / "compare-best.json").is_file() and (runs[0] / "eval" / "compare-best.npz").is_file()
    # RUN@raw: the raw weights in rows of their own, stored apart (no EMA here, so they score as the average does)
    assert vtkiosk(["eval", "--compare", str(runs[0]), f"{runs[0]}@raw", "--out", str(cmp_dir / "raw"),
                    "--bootstrap", "200"]) == 0
    raw = json.loads((cmp_dir / "raw" / "compare.json").read_text())
    assert [(r["method"], r["weights"]) for r in raw["runs"]] == [("ours", "average"), ("ours-raw", "raw")]
    assert raw["runs"][1]["full_angle_deg"] == pytest.approx(raw["runs"][0]["full_angle_deg"])
    assert (runs[0] / "eval" / "compare-best-raw.json").is_file()
    # RUN@rms: the relief calibrated on the training touches (trainer/calibration.py), in rows and files of its own
    assert vtkiosk(["eval", "--compare", str(runs[0]), f"{runs[0]}@rms", "--out", str(cmp_dir / "rms"),
                    "--bootstrap", "200"]) == 0
    cal = json.loads((cmp_dir / "rms" / "compare.json").read_text())
    assert [r["method"] for r in cal["runs"]] == ["ours", "ours-rms"] and "relief" not in cal["runs"][0]
    fit = cal["runs"][1]["relief"]
    assert fit["rule"] == "rms" and 0.25 <= fit["gain"] <= 4.0 and fit["pixels"] >= 256
    plain, scaled = cal["runs"][0], cal["runs"][1]
    assert scaled["full_fbsifid_seen"] != pytest.approx(plain["full_fbsifid_seen"])
    assert scaled["visual_psnr"] == pytest.approx(plain["visual_psnr"])   # the visual output is untouched
    assert (runs[0] / "eval" / "compare-best-rms.json").is_file()
    # RUN@flip@ls: the relief averaged over mirrored views, then calibrated (trainer/models/mirror_average.py)
    assert vtkiosk(["eval", "--compare", str(runs[0]), f"{runs[0]}@flip@ls", "--out", str(cmp_dir / "flip"),
                    "--bootstrap", "200"]) == 0
    mir = json.loads((cmp_dir / "flip" / "compare.json").read_text())
    assert [r["method"] for r in mir["runs"]] == ["ours", "ours-flip-ls"] and "mirrors" not in mir["runs"][0]
    assert mir["runs"][1]["mirrors"] == "flip" and mir["runs"][1]["relief"]["rule"] == "ls"
    assert mir["runs"][1]["full_angle_deg"] != pytest.approx(mir["runs"][0]["full_angle_deg"])
    assert mir["runs"][1]["visual_psnr"] == pytest.approx(mir["runs"][0]["visual_psnr"])
    assert (runs[0] / "eval" / "compare-best-flip-ls.json").is_file()
    # RUN@shade-lift: the relief mixed with the run's own visual shading (trainer/shading_fit.py), weight >= 1
    assert vtkiosk(["eval", "--compare", str(runs[0]), f"{runs[0]}@shade-lift", "--out", str(cmp_dir / "shade"),
                    "--bootstrap", "200"]) == 0
    sh = json.loads((cmp_dir / "shade" / "compare.json").read_text())
    assert [r["method"] for r in sh["runs"]] == ["ours", "ours-shade-lift"]
    sfit = sh["runs"][1]["relief"]
    assert sfit["rule"] == "shade-lift" and sfit["model_weight"] >= 1.0 and len(sfit["filter_weights"]) == 8
    assert sh["runs"][1]["full_angle_deg"] != pytest.approx(sh["runs"][0]["full_angle_deg"])
    assert sh["runs"][1]["visual_psnr"] == pytest.approx(sh["runs"][0]["visual_psnr"])
    assert (runs[0] / "eval" / "compare-best-shade-lift.json").is_file()
    assert vtkiosk(["eval", "--run", str(runs[0]), "--relief", "rms", "--no-swap"]) == 0
    merged = json.loads((runs[0] / "metrics.json").read_text())
    assert merged["eval_rms"]["relief"]["gain"] == pytest.approx(fit["gain"]) and "eval" not in merged
    assert (runs[0] / "eval" / "metrics-rms.json").is_file() and not (runs[0] / "eval" / "metrics.json").exists()
    import trainer.eval_cache as cache_mod

    def refuse(*a, **k):
        raise AssertionError("re-scored a run whose stored scores were current")
    monkeypatch.setattr(cache_mod, "evaluate", refuse)
    assert vtkiosk(["eval", "--compare", *map(str, runs[:3]), f"pix2pix-b={runs[3]}", "--out", str(cmp_dir / "again"),
                    "--bootstrap", "200"]) == 0   # and a labelled run gets its own rows
    again = json.loads((cmp_dir / "again" / "compare.json").read_text())
    assert again["mean"]["ours"] == data["mean"]["ours"]
    assert again["differences"]["rows"]["flat"] == data["differences"]["rows"]["flat"]
    assert again["garments"]["pix2pix-b"] == ["singleskit_CorduroyTrousers_padded_270_x1"]
    assert "| pix2pix-b |" in (cmp_dir / "again" / "compare.md").read_text()
    assert [r.get("trained_method") for r in again["runs"]][3] == "pix2pix"
    with pytest.raises(AssertionError, match="re-scored"):   # --rescore, or a changed checkpoint, scores again
        vtkiosk(["eval", "--compare", *map(str, runs), "--out", str(cmp_dir / "r"), "--bootstrap", "200", "--rescore"])
    ck = runs[1] / "checkpoints" / "best.pt"
    ck.write_bytes(ck.read_bytes() + b"\0")
    with pytest.raises(AssertionError, match="re-scored"):
        vtkiosk(["eval", "--compare", *map(str, runs), "--out", str(cmp_dir / "c"), "--bootstrap", "200"])
    capsys.readouterr()
    with pytest.raises(SystemExit):
        vtkiosk(["eval", "--compare", str(runs[0]), "--bootstrap", "10"])
    assert "--bootstrap must be at least 100" in capsys.readouterr().err


def test_unseen_sketches_from_a_larger_dataset_folder(synth, tmp_path, capsys, monkeypatch):
    """`eval --unseen-from`: the texture statistic on another folder's sketches (every garment there but the run's
    own), one unit each, scored and stored apart from the plain scores, refused when the folder has no garments."""
    big = tmp_path / "big4"   # the same seed and frame: its first two garments are the fixture's own
    generate_dataset(big, garments=4, seed=0, frame=(192, 144), progress=False, profile="easy")
    g = load_garment(synth / "singleskit_DenimShorts_padded_270_x1")
    names = [u.name for u in find_unseen(g, 256, big)]
    assert len(names) == 3 and g.name not in names and "singleskit_CorduroyTrousers_padded_270_x1" in names
    cfg = load_config("tiny", method="ours", overrides=["train.steps=1", "train.threads=1"])
    run = tmp_path / "run"
    Trainer(cfg, g.root, run).run()
    out = tmp_path / "cmp"
    assert vtkiosk(["eval", "--compare", str(run), "--out", str(out), "--bootstrap", "200",
                    "--unseen-from", str(big)]) == 0
    data = json.loads((out / "compare.json").read_text())
    r = data["runs"][0]
    assert r["unseen_from"] == "big4" and sorted(u["name"] for u in r["unseen_sketches"]) == sorted(names)
    assert data["differences"]["rows"]["flat"]["full_fbsifid_unseen"]["units"] == 3
    assert "Unseen sketches (FB-SIFID unseen): 3 per run, from the dataset folder `big4`" in \
        (out / "compare.md").read_text()
    assert str(tmp_path) not in (out / "compare.json").read_text().replace(str(run), "")
    assert (run / "eval" / "compare-best-unseen_big4.json").is_file()
    assert not (run / "eval" / "compare-best.json").exists()   # the plain scores are not these
    assert vtkiosk(["eval", "--compare", str(run), "--out", str(tmp_path / "plain"), "--bootstrap", "200"]) == 0
    plain = json.loads((tmp_path / "plain" / "compare.json").read_text())["runs"][0]
    assert len(plain["unseen_sketches"]) == 1 and "unseen_from" not in plain
    assert plain["full_fbsifid_unseen"] != pytest.approx(r["full_fbsifid_unseen"])
    assert vtkiosk(["eval", "--run", str(run), "--no-swap", "--unseen-from", str(big)]) == 0
    assert (run / "eval" / "metrics-unseen_big4.json").is_file()
    assert "eval_unseen_big4" in json.loads((run / "metrics.json").read_text())
    import trainer.eval_cache as cache_mod

    def refuse(*a, **k):
        raise AssertionError("re-scored")
    monkeypatch.setattr(cache_mod, "evaluate", refuse)
    args = ["eval", "--compare", str(run), "--out", str(tmp_path / "again"), "--bootstrap", "200",
            "--unseen-from", str(big)]
    assert vtkiosk(args) == 0                       # stored scores reused while the folder is unchanged
    sk = next(p for p in sorted(big.rglob("*.png")) if g.root.name not in p.parts)
    sk.write_bytes(sk.read_bytes() + b"\0")        # a changed unseen sketch scores again
    with pytest.raises(AssertionError, match="re-scored"):
        vtkiosk(args)
    capsys.readouterr()
    for bad, msg in (([str(tmp_path / "nowhere")], "no such dataset folder"),
                     ([str(tmp_path / "run")], "no garment folders")):
        with pytest.raises(SystemExit):
            vtkiosk(["eval", "--compare", str(run), "--unseen-from", *bad])
        err = capsys.readouterr().err
        assert "--unseen-from" in err and msg in err
    with pytest.raises(SystemExit):
        vtkiosk(["eval", "--pool", str(out / "compare.json"), "--unseen-from", str(big)])
    assert "a pooled table has its runs' scores already" in capsys.readouterr().err


def test_labelled_runs_parse():
    from trainer.compare import RunSpec, parse_labelled
    runs, labels = parse_labelled(["runs/a/ours", "ours-r1-10=runs/b/r1", "x=y=z", "runs/a/ours@raw", "e=runs/c@raw"])
    assert runs == [RunSpec(Path("runs/a/ours")), RunSpec(Path("runs/b/r1")), RunSpec(Path("y=z")),
                    RunSpec(Path("runs/a/ours"), "raw"), RunSpec(Path("runs/c"), "raw")]
    assert labels == {RunSpec(Path("runs/b/r1")): "ours-r1-10", RunSpec(Path("y=z")): "x",
                      RunSpec(Path("runs/c"), "raw"): "e"}
    assert str(runs[3]) == "runs/a/ours@raw" and str(runs[0]) == "runs/a/ours"
    assert parse_labelled(["runs/a=b/c"]) == ([RunSpec(Path("runs/a=b/c"))], {})   # a path with '=' is a path
    assert parse_labelled(["runs/me@home/a"]) == ([RunSpec(Path("runs/me@home/a"))], {})   # and one with '@'
    for bad in ("=runs/a", "label="):
        with pytest.raises(ValueError, match="LABEL=RUN"):
            parse_labelled([bad])
    with pytest.raises(ValueError, match=r"takes average, raw, probe \(weights\), rms"):
        parse_labelled(["runs/a@ema"])
    with pytest.raises(ValueError, match="given twice"):
        parse_labelled(["runs/a", "x=runs/a"])
