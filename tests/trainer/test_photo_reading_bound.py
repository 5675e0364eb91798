"""scripts/photo_reading_bound.py: each half of the object is read by a reader taught on the other half's truth, the
rows are scored beside the references, and bad arguments or a folder that is no run are clear errors."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tests.scripts_module import load_script


@pytest.fixture(scope="module")
def rb():
    return load_script("photo_reading_bound")


@pytest.fixture(scope="module")
def run(hard_tiny_run):
    return hard_tiny_run


@settings(max_examples=50, deadline=None)
@given(arrays(bool, st.tuples(st.integers(1, 12), st.integers(1, 12))))
def test_halves_split_the_object(rb, obj):
    a, b = rb.halves(obj)
    assert not (a & b).any() and np.array_equal(a | b, obj)


def test_both_photos_read_and_scored_beside_the_references(rb, run, tmp_path, capsys):
    out = tmp_path / "reading.json"
    assert rb.main([str(run), "--steps", "3", "--channels", "4", "--width", "3", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())[0]["rows"]
    want = {f"{r}, {p}" for r in ("linear 3", "network 4") for p in ("own photo", "real photo")}
    assert want | {"as given", "flat", "oracle"} <= set(rows)
    assert all(math.isfinite(rows[k]["full_angle_deg_outside"]) for k in want)
    assert rows["flat"]["gap_closed"] == pytest.approx(0) and rows["oracle"]["gap_closed"] == pytest.approx(1)
    assert "linear 3, real photo" in capsys.readouterr().out


def test_each_half_is_read_by_the_other_halfs_reader(rb, run):
    """Truth planted as one known 3 x 3 filter of the real photo's log-luminance on the left half and another on the
    right: each half is read with the other half's filter (up to the ridge), so no half is scored by a reader taught
    on it. The network's output is finite, and both leave the background at 0."""
    import torch

    from trainer.evaluate import Prediction
    from trainer.models.shading_relief import log_luminance
    p = Prediction(run, "latest", unseen=False)
    ctx = p.ctx
    obj = ctx.obj
    win = rb.windows(log_luminance(ctx.visual, ctx.mask)[0, 0].double().numpy(), 3)
    win = win - win.mean(-1, keepdims=True)
    left, right = rb.halves(obj)
    a, b = np.random.default_rng(0).normal(size=(2, 2, 9))
    planted = tuple(np.where(left, win @ a[c], np.where(right, win @ b[c], 0.0)).astype(np.float32) for c in (0, 1))
    crossed = np.stack([np.where(left, win @ b[c], np.where(right, win @ a[c], 0.0)) for c in (0, 1)])
    ctx.truth = lambda: planted
    lin, net = rb.read(ctx, torch.zeros_like(p.tac), ctx.visual, 3, 4, 2)
    assert lin.shape == net.shape == p.tac.shape

    def err(want):
        return np.abs(lin[0].numpy() - want)[:, obj].mean() / np.abs(want[:, obj]).mean()

    assert err(crossed) < 0.1 < err(np.stack(planted))
    assert float(lin[0][:, ~obj].abs().max()) == 0.0 and float(net[0][:, ~obj].abs().max()) == 0.0
    assert np.isfinite(net.numpy()).all()


@pytest.mark.parametrize("bad", [["--width", "4"], ["--channels", "0"], ["--steps", "0"]])
def test_bad_arguments_are_refused(rb, run, bad, capsys):
    with pytest.raises(SystemExit) as e:
        rb.main([str(run), *bad])
    assert e.value.code == 2 and "must be odd" in capsys.readouterr().err


def test_a_folder_that_is_no_run_is_refused(rb, tmp_path, capsys):
    assert rb.main([str(tmp_path)]) == 2
    assert str(tmp_path) in capsys.readouterr().err
