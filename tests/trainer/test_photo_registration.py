"""scripts/photo_registration.py: touches whose slopes are a centred filter of the photo, read off by planted
offsets, are placed back exactly; the CLI scores the estimates against the recorded offsets, writes a copy whose
training touches alone are moved, and refuses what it cannot register."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from tests.scripts_module import load_script
from trainer.data.touchclothing import load_garment
from trainer.models.shading_relief import filter_bank


@pytest.fixture(scope="module")
def pr():
    return load_script("photo_registration")


@pytest.fixture(scope="module")
def garment(hard_one):
    return load_garment(next(hard_one.glob("singleskit_*")))


def planted(pr, g, offsets: dict[str, tuple[int, int]]):
    """A copy of `g` whose training touches measured a fixed mix of the shading bank on the photo, pressed at the
    recorded corner minus `offsets` (nothing but the photo and the offsets decides them)."""
    bank = filter_bank(11).astype(np.float64)
    rng = np.random.default_rng(0)
    w = rng.normal(size=(2, bank.shape[0]))
    kernels = np.stack([np.tensordot(w[c], bank[:, c], axes=1) for c in (0, 1)])
    rx, ry = pr.convolve(pr.photo_luminance(g), kernels)
    touches = []
    for t in g.touches["train"]:
        dx, dy = offsets.get(t.name, (0, 0))
        r = t.rect
        win = np.s_[r.y - dy:r.y - dy + r.h, r.x - dx:r.x - dx + r.w]
        touches.append(dataclasses.replace(t, gx=rx[win].astype(np.float32), gy=ry[win].astype(np.float32)))
    return dataclasses.replace(g, touches={**g.touches, "train": touches})


def test_planted_offsets_are_found(pr, garment):
    names = [t.name for t in pr.training_touches(garment, 2)]
    assert len(names) >= pr.MIN_TOUCHES
    rng = np.random.default_rng(1)
    # about as far as the hard profile records them (1 px a side)
    # about as far as the hard profile records them (1 px a side); from 2 px a side the first filter, fitted at the
    # recorded corners, is too far off to start from on this small frame's twill
    picks = np.clip(np.round(rng.normal(0, 1, (len(names), 2))), -2, 2).astype(int)
    want = {n: (int(dx), int(dy)) for n, (dx, dy) in zip(names, picks)}
    assert sum(v != (0, 0) for v in want.values()) >= len(want) // 2, "most touches should be planted off"
    got, rounds = pr.estimate(planted(pr, garment, want), radius=2)
    assert got == want and rounds >= 2
    # at the recorded corners (no offsets planted) nothing moves and one round says so
    got0, rounds0 = pr.estimate(planted(pr, garment, {}), radius=2)
    assert set(got0.values()) == {(0, 0)} and rounds0 == 1


def test_cli_scores_against_the_record_and_writes_a_moved_copy(pr, hard_one, garment, tmp_path, capsys):
    name = garment.name.split("_")[1]
    out = tmp_path / "reg.json"
    assert pr.main([str(hard_one), name, "--radius", "2", "--write", str(tmp_path / "copy"),
                    "--json", str(out)]) == 0
    row = json.loads(out.read_text())["garments"][0]
    assert row["touches"] == len(row["offsets"]) >= pr.MIN_TOUCHES
    assert 0 <= row["score"]["hits"] <= row["touches"] and row["score"]["mean_px_recorded"] > 0
    assert name in capsys.readouterr().out
    moved = load_garment(tmp_path / "copy" / garment.name)
    for split, touches in garment.touches.items():
        for t0, t1 in zip(touches, moved.touches[split]):
            dx, dy = row["offsets"].get(t0.name, (0, 0)) if split == "train" else (0, 0)
            assert (t1.rect.x, t1.rect.y) == (t0.rect.x - dx, t0.rect.y - dy)
            assert np.array_equal(t0.gx, t1.gx)


def test_what_cannot_be_registered_is_refused(pr, hard_one, garment, tmp_path, capsys):
    assert pr.main([str(hard_one), "Nothing"]) == 2
    assert "no garment Nothing" in capsys.readouterr().err
    for bad in (["--width", "4"], ["--radius", "0"], ["--rounds", "0"]):
        with pytest.raises(SystemExit) as e:
            pr.main([str(hard_one), "x", *bad])
        assert e.value.code == 2
    few = dataclasses.replace(garment, touches={**garment.touches, "train": garment.touches["train"][:2]})
    with pytest.raises(SystemExit, match="at least 4 are needed"):
        pr.estimate(few)
    dark = dataclasses.replace(garment, visual=None)
    with pytest.raises(SystemExit, match="no photo"):
        pr.estimate(dark)


def test_the_free_basis_reads_each_window_less_its_mean(pr):
    lum = np.random.default_rng(2).normal(size=(9, 11))
    maps = pr.convolve(lum, pr.basis_kernels(3, "free"))
    win = np.lib.stride_tricks.sliding_window_view(np.pad(lum, 1, mode="edge"), (3, 3)).reshape(9, 11, 9)
    assert np.allclose(maps.transpose(1, 2, 0), win - win.mean(-1, keepdims=True))
    assert pr.basis_kernels(11, "bank").shape == (16, 11, 11)
