"""Shift-tolerant touch patches (`loss.tactile_shift`): the pick finds a known offset, keeps the recorded corner on
a tie, passes the gradient through the picked patch only, and a tiny run logs what it picked."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer.config import ConfigError, load_config
from trainer.data.synthetic import generate_dataset
from trainer.data.touchclothing import PATCH
from trainer.loop import Trainer
from trainer.recipe.registration import best_shift_patches, shifts
from trainer.sampling import cut

torch.set_num_threads(2)


def _relief(seed: int, side: int = 96) -> torch.Tensor:
    return torch.from_numpy(np.random.default_rng(seed).normal(size=(1, 2, side, side)).astype(np.float32))


@given(seed=st.integers(0, 10_000), k=st.integers(1, 3), data=st.data())
@settings(max_examples=60, deadline=None)
def test_the_pick_finds_each_patch_offset(seed, k, data):
    """Touches recorded `d` px from where they were pressed are matched at shift `d`, exactly, on a relief with no
    repeat (noise); patches reaching past the map's edge included."""
    x = _relief(seed)
    side = x.shape[-1]
    n = data.draw(st.integers(1, 6))
    origins = np.array([[data.draw(st.integers(0, side - PATCH)), data.draw(st.integers(0, side - PATCH))]
                        for _ in range(n)])
    d = np.array([[data.draw(st.integers(-k, k)), data.draw(st.integers(-k, k))] for _ in range(n)])
    pressed = np.clip(origins + d, 0, side - PATCH)
    target = cut(x, pressed)
    contact = torch.ones(n, 1, PATCH, PATCH)
    patches, picked = best_shift_patches(x, origins, target, contact, k)
    assert np.array_equal(picked, pressed - origins)
    assert torch.equal(patches, target)


def test_zero_radius_is_the_plain_cut_and_a_tie_or_no_contact_keeps_the_corner():
    x = _relief(1)
    origins = np.array([[3, 40], [50, 7]])
    patches, picked = best_shift_patches(x, origins, cut(x, origins) + 1.0, torch.ones(2, 1, PATCH, PATCH), 0)
    assert torch.equal(patches, cut(x, origins)) and not picked.any()
    flat = torch.zeros(1, 2, 96, 96)   # every shift ties
    _, picked = best_shift_patches(flat, origins, torch.ones(2, 2, PATCH, PATCH), torch.ones(2, 1, PATCH, PATCH), 2)
    assert not picked.any()
    target = cut(x, origins + 1)
    _, picked = best_shift_patches(x, origins, target, torch.zeros(2, 1, PATCH, PATCH), 2)
    assert not picked.any()
    assert shifts(1)[0] == (0, 0) and len(shifts(2)) == 25 and len(set(shifts(2))) == 25
    with pytest.raises(ValueError, match="shift radius"):
        best_shift_patches(x, origins, target, torch.ones(2, 1, PATCH, PATCH), -1)
    empty, none = best_shift_patches(x, np.zeros((0, 2), int), target[:0], torch.ones(0, 1, PATCH, PATCH), 2)
    assert empty.shape == (0, 2, PATCH, PATCH) and none.shape == (0, 2)


def test_the_gradient_reaches_the_picked_window_only():
    x = _relief(2).requires_grad_(True)
    origins = np.array([[30, 30]])
    target = cut(x.detach(), origins + np.array([[2, -1]]))
    patches, picked = best_shift_patches(x, origins, target, torch.ones(1, 1, PATCH, PATCH), 2)
    assert picked.tolist() == [[2, -1]]
    patches.sum().backward()
    grad = x.grad[0, 0]
    ys, xs = torch.nonzero(grad, as_tuple=True)
    assert (xs.min().item(), ys.min().item()) == (32, 29)
    assert (xs.max().item(), ys.max().item()) == (32 + PATCH - 1, 29 + PATCH - 1)


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    generate_dataset(root, garments=1, seed=0, frame=(192, 144), progress=False)
    return next(p for p in root.iterdir() if p.is_dir())


def test_a_run_with_shift_tolerant_touches_trains_and_logs_its_picks(synth, tmp_path):
    cfg = load_config("tiny", overrides=["train.steps=3", "train.deterministic=true", "train.threads=1",
                                         "loss.tactile_shift=2"])
    run = Trainer(cfg, synth, tmp_path / "run")
    run.run()
    last = run.history[-1]
    assert np.isfinite(last["g_total"]) and 0.0 <= last["t_shift_px"] <= 2 * 2 ** 0.5
    assert 0.0 <= last["t_shift_zero"] <= 1.0
    plain = Trainer(load_config("tiny", overrides=["train.steps=1", "train.threads=1"]), synth, tmp_path / "plain")
    plain.run()
    assert "t_shift_px" not in plain.history[-1]
    for bad in (-1, 9):
        with pytest.raises(ConfigError, match="tactile_shift"):
            load_config("tiny", overrides=[f"loss.tactile_shift={bad}"])
