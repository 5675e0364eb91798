"""Test-time mirroring (trainer/models/mirror_average.py): each view's relief mirrored back with its slope vector,
the visual output untouched, RUN@flip parsed and stored apart."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from torch import nn
from torch.nn import functional as F

from kiosk.contract.sketch import network_input, object_mask
from trainer.compare import RunSpec, parse_labelled, parse_run
from trainer.data.synthetic import generate_dataset
from trainer.data.touchclothing import load_garment
from trainer.eval_cache import _paths
from trainer.evaluate import near_strokes
from trainer.models.mirror_average import (DETAIL_SIGMA_PX, GRID_PITCH_MM, MODES, MirrorAverage, detail_gain,
                                           disc_taps, gaussian_lowpass, stroke_band, view_back, view_in)
from trainer.models.mirror_modes import ENERGY, LINES, LOW, VIEWS
from trainer.physical import LINE_REACH_MM

MIRRORED = [m for m in MODES if m != "none"]


class SlopeNet(nn.Module):
    """The relief of a height field equal to the sketch: central differences with zero padding, which mirror
    exactly as slopes do. Any correct averaging returns it unchanged."""

    def __init__(self):
        super().__init__()
        self.calls = 0

    def forward(self, sketch, mask, kind="full"):
        self.calls += 1
        p = F.pad(sketch, (1, 1, 1, 1))
        gx = (p[..., 1:-1, 2:] - p[..., 1:-1, :-2]) / 2
        gy = (p[..., 2:, 1:-1] - p[..., :-2, 1:-1]) / 2
        vis = sketch.repeat(1, 3, 1, 1) * mask
        tac = torch.cat([gx, gy], 1)
        return {"full": (vis, tac), "tactile": tac, "visual": vis}[kind]


class AnyNet(nn.Module):
    """A generator with no symmetry at all (a random convolution and a constant slope)."""

    def __init__(self):
        super().__init__()
        torch.manual_seed(0)
        self.conv = nn.Conv2d(2, 5, 3, padding=1)

    def forward(self, sketch, mask, kind="full"):
        h = self.conv(torch.cat([sketch, mask], 1))
        vis, tac = torch.tanh(h[:, :3]), torch.tanh(h[:, 3:]) + torch.tensor([0.3, -0.2]).view(1, 2, 1, 1)
        return {"full": (vis, tac), "tactile": tac, "visual": vis}[kind]


def inputs(h: int, w: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, 1, h, w, generator=g), (torch.rand(1, 1, h, w, generator=g) > 0.2).float()


@settings(max_examples=25, deadline=None)
@given(h=st.integers(3, 12), w=st.integers(3, 12), seed=st.integers(0, 2**16), mode=st.sampled_from(MIRRORED))
def test_a_relief_that_mirrors_as_slopes_do_is_returned_unchanged(h, w, seed, mode):
    s, m = inputs(h, w, seed)   # non-square crops too: a transposed view is w x h
    net = SlopeNet()
    vis, tac = MirrorAverage(net, mode)(s, m)
    ref_vis, ref_tac = net(s, m)
    assert torch.allclose(tac, ref_tac, atol=1e-6) and torch.equal(vis, ref_vis)


@settings(max_examples=25, deadline=None)
@given(h=st.integers(2, 10), w=st.integers(2, 10), seed=st.integers(0, 2**16))
def test_each_view_is_undone_by_its_way_back(h, w, seed):
    """The slopes of a mirrored sketch, mirrored back (image and vector), are the sketch's own slopes."""
    s, _ = inputs(h, w, seed)
    net = SlopeNet()
    slopes = net(s, s, "tactile")
    for view in ("f", "t", "tf"):
        mirrored = view_in(s, view)
        assert mirrored.shape[-2:] == ((w, h) if "t" in view else (h, w))
        assert torch.allclose(view_back(net(mirrored, mirrored, "tactile"), view), slopes, atol=1e-6)


@pytest.mark.parametrize("mode", ["flip", "transpose"])
def test_a_two_view_average_is_exactly_symmetric_for_any_generator(mode):
    """{plain, mirror} is a group: the averaged model is mirror-equivariant whatever the generator learned."""
    s, m = inputs(8, 8, 3)
    net = MirrorAverage(AnyNet(), mode)
    view = MODES[mode][0]
    with torch.no_grad():
        _, tac = net(s, m)
        _, tac_m = net(view_in(s, view), view_in(m, view))
        assert torch.allclose(view_back(tac_m, view), tac, atol=1e-6)
        if mode == "flip":   # a constant x-slope is not left-right symmetric, so the average removes it
            assert abs(float(tac[:, 0].mean()) - float(AnyNet()(s, m)[1][:, 0].mean())) > 0.05


class WeaveNet(SlopeNet):
    """SlopeNet plus a fixed fine 'weave' drawn in the output's own frame (so each view draws it at another place)
    and a constant slope (coarse, and not left-right symmetric)."""

    def __init__(self, h: int, w: int):
        super().__init__()
        g = torch.Generator().manual_seed(7)
        self.weave = {(h, w): torch.randn(1, 2, h, w, generator=g), (w, h): torch.randn(1, 2, w, h, generator=g)}

    def forward(self, sketch, mask, kind="full"):
        vis, tac = SlopeNet.forward(self, sketch, mask, "full")
        tac = tac + 0.5 * self.weave[tuple(sketch.shape[-2:])] + torch.tensor([0.3, -0.2]).view(1, 2, 1, 1)
        return {"full": (vis, tac), "tactile": tac, "visual": vis}[kind]


@pytest.mark.parametrize("mode", [m for m in VIEWS if m != "none"])
def test_a_low_mode_keeps_the_detail_and_averages_the_coarse_relief(mode):
    """The plain average cancels a weave the views draw at different places; the -low mode keeps the plain view's
    weave and still removes what the views disagree on at coarse scale (here a constant slope)."""
    s, m = inputs(64, 48, 5)
    net = WeaveNet(64, 48)
    with torch.no_grad():
        plain = net(s, m, "tactile")
        full = MirrorAverage(net, mode)(s, m, "tactile")
        low = MirrorAverage(net, mode + LOW)(s, m, "tactile")
    weave = 0.5 * net.weave[(64, 48)]
    kept = lambda out: float(((out - gaussian_lowpass(out, DETAIL_SIGMA_PX)) * weave).mean() / (weave ** 2).mean())
    assert kept(full) < 0.6 < 0.85 < kept(low)   # the share of the plain view's weave left in the output
    coarse = lambda out: gaussian_lowpass(out, 3 * DETAIL_SIGMA_PX)[..., 20:44, 12:36].mean(dim=(-1, -2))
    assert torch.allclose(coarse(low), coarse(full), atol=0.03)
    assert not torch.allclose(coarse(plain), coarse(full), atol=0.1)


def test_an_energy_mode_keeps_the_means_coarse_relief_and_the_plain_views_fine_energy():
    s, m = inputs(64, 48, 5)
    m[..., :4, :] = 0   # a mask that is not the whole canvas: the energies are taken over it
    net = WeaveNet(64, 48)
    with torch.no_grad():
        plain = net(s, m, "tactile")
        mean = MirrorAverage(net, "flip+transpose")(s, m, "tactile")
        out = MirrorAverage(net, "flip+transpose" + ENERGY)(s, m, "tactile")
    fine = lambda x: x - gaussian_lowpass(x, DETAIL_SIGMA_PX)
    energy = lambda x: float((m * x * x).sum())
    added = out - gaussian_lowpass(mean, DETAIL_SIGMA_PX)   # what the mode puts on the mean's coarse relief
    gain = float((added * fine(mean)).sum() / (fine(mean) ** 2).sum())
    assert 1.2 < gain < 2 and torch.allclose(added, gain * fine(mean), atol=1e-5)   # the mean's pattern, one gain
    assert energy(fine(mean)) < 0.6 * energy(fine(plain))   # the weave the views disagree on is averaged away
    assert energy(added) == pytest.approx(energy(fine(plain)), rel=1e-4)   # and its strength given back


class ShiftedNet(AnyNet):
    """Another seed: the same kind of generator, drawn from another initialisation."""

    def __init__(self, seed: int):
        super().__init__()
        torch.manual_seed(seed)
        self.conv = nn.Conv2d(2, 5, 3, padding=1)


@pytest.mark.parametrize("mode", [m for m in VIEWS if m != "none"])
def test_other_seeds_join_as_more_views_and_the_photo_stays_the_first_seeds(mode):
    """Averaging two seeds' views is the mean of each seed's own mirror average (every view counts once), and the
    visual output is the first seed's plain one."""
    s, m = inputs(10, 7, 2)
    a, b = AnyNet(), ShiftedNet(5)
    with torch.no_grad():
        vis, tac = MirrorAverage(a, mode, [b])(s, m)
        alone = [MirrorAverage(n, mode)(s, m)[1] for n in (a, b)]
    assert torch.allclose(tac, (alone[0] + alone[1]) / 2, atol=1e-6) and torch.equal(vis, a(s, m)[0])
    assert not torch.allclose(alone[0], alone[1], atol=1e-3)   # the two seeds differ


def test_an_energy_ensemble_may_give_back_up_to_all_its_views():
    """The -energy gain's bound is sqrt(every view), seeds included: two seeds of four views may lose up to
    sqrt(8) of a weave they share nothing of."""
    s, m = inputs(64, 48, 5)
    a, b = WeaveNet(64, 48), WeaveNet(64, 48)
    g = torch.Generator().manual_seed(11)
    b.weave = {k: torch.randn(v.shape, generator=g) for k, v in a.weave.items()}   # another seed's weave
    fine = lambda x: x - gaussian_lowpass(x, DETAIL_SIGMA_PX)
    energy = lambda x: float((m * x * x).sum())
    with torch.no_grad():
        plain = a(s, m, "tactile")
        mean = MirrorAverage(a, "flip+transpose", [b])(s, m, "tactile")
        out = MirrorAverage(a, "flip+transpose" + ENERGY, [b])(s, m, "tactile")
    added = out - gaussian_lowpass(mean, DETAIL_SIGMA_PX)
    gain = float((added * fine(mean)).sum() / (fine(mean) ** 2).sum())
    assert 2 < gain <= 8 ** 0.5 + 1e-6   # past one seed's bound, sqrt(4)
    assert energy(added) == pytest.approx(energy(fine(plain)), rel=1e-4)


def test_an_ensemble_is_refused_across_garments_methods_or_without_mirrors(tmp_path):
    from trainer.checkpoint import CheckpointError
    from trainer.config import load_config
    from trainer.evaluate import Prediction
    from trainer.loop import Trainer

    garments = generate_dataset(tmp_path / "data", garments=2, seed=0, frame=(192, 144), progress=False,
                                profile="easy")
    runs = {}
    for name, method, garment in (("one", "ours", 0), ("two", "ours", 0), ("pix", "pix2pix", 0), ("far", "ours", 1)):
        cfg = load_config("tiny", method=method, overrides=["train.steps=1", "train.threads=1",
                                                            f"train.seed={len(runs)}"])
        runs[name] = tmp_path / name
        Trainer(cfg, garments[garment], runs[name]).run()
    with pytest.raises(CheckpointError, match="mirror mode"):
        Prediction(runs["one"], "latest", unseen=False, members=[runs["two"]])
    for other in ("pix", "far"):
        with pytest.raises(CheckpointError, match="share the garment, method and crop"):
            Prediction(runs["one"], "latest", unseen=False, mirrors="flip", members=[runs[other]])
    p = Prediction(runs["one"], "latest", unseen=False, mirrors="flip", members=[runs["two"]])
    assert len(p.net.others) == 1 and torch.isfinite(p.tac).all()


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**16), a=st.floats(0, 1e3), b=st.floats(0, 1e3), masked=st.floats(0, 1))
def test_the_detail_gain_is_finite_and_bounded(seed, a, b, masked):
    """Between 1 and the bound whatever the reliefs, 1 where both are blank or the mask is empty: nothing a canvas
    holds makes it divide by zero."""
    g = torch.Generator().manual_seed(seed)
    p, q = a * torch.randn(2, 2, 9, 7, generator=g), b * torch.randn(2, 2, 9, 7, generator=g)
    m = (torch.rand(2, 1, 9, 7, generator=g) >= masked).float()
    k = detail_gain(p, q, m, 2.0)
    assert k.shape == (2, 1, 1, 1) and torch.isfinite(k).all() and ((k >= 1) & (k <= 2)).all()
    assert torch.equal(detail_gain(torch.zeros_like(p), torch.zeros_like(q), m, 2.0), torch.ones(2, 1, 1, 1))
    assert torch.equal(detail_gain(p, q, torch.zeros_like(m), 2.0), torch.ones(2, 1, 1, 1))


def stroked_sketch(h: int, w: int, seed: int) -> np.ndarray:
    """uint8 paper (255) with a few dark strokes at random places and angles."""
    import cv2
    rng = np.random.default_rng(seed)
    s = np.full((h, w), 255, np.uint8)
    for _ in range(int(rng.integers(1, 5))):
        p, q = rng.integers(0, (w, h), 2), rng.integers(0, (w, h), 2)
        cv2.line(s, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), 0, int(rng.integers(1, 3)))
    return s


@settings(max_examples=20, deadline=None)
@given(h=st.integers(8, 64), w=st.integers(8, 64), seed=st.integers(0, 2**16))
def test_the_stroke_band_is_the_evaluators_by_a_line_region(h, w, seed):
    """The -lines band (a disc dilation in the graph) and the evaluator's "by a line" pixels (a distance transform)
    are the same reach from the same strokes; they may differ only where OpenCV's 5x5 distance is approximate."""
    s = stroked_sketch(h, w, seed)
    band = stroke_band(torch.from_numpy(s.astype(np.float32) / 127.5 - 1)[None, None],
                       disc_taps(LINE_REACH_MM / GRID_PITCH_MM))[0, 0].numpy().astype(bool)
    near = near_strokes(s, GRID_PITCH_MM)
    assert (band == near).mean() > 0.99
    assert band[s < 128].all() and not band[~near_strokes(s, GRID_PITCH_MM / 2)].any()   # nothing past twice the reach


def test_a_lines_mode_averages_by_the_strokes_and_keeps_open_cloth():
    s = stroked_sketch(64, 48, 11)
    x = torch.from_numpy(s.astype(np.float32) / 127.5 - 1)[None, None]
    m = torch.ones_like(x)
    net = WeaveNet(64, 48)
    band = torch.from_numpy(near_strokes(s, GRID_PITCH_MM))
    with torch.no_grad():
        plain = net(x, m, "tactile")
        mean = MirrorAverage(net, "flip+transpose")(x, m, "tactile")
        lines = MirrorAverage(net, "flip+transpose" + LINES)(x, m, "tactile")
    assert 0.05 < float(band.float().mean()) < 0.8
    agree = (stroke_band(x, disc_taps(LINE_REACH_MM / GRID_PITCH_MM))[0, 0] > 0) == band
    inside, outside = band & agree, ~band & agree
    assert torch.equal(lines[..., outside], plain[..., outside])   # open cloth: the plain view's weave, untouched
    assert torch.allclose(lines[..., inside], mean[..., inside], atol=1e-6)
    blank = torch.ones(1, 1, 64, 48)   # no strokes: nothing to average
    with torch.no_grad():
        assert torch.equal(MirrorAverage(net, "flip" + LINES)(blank, m, "tactile"), net(blank, m, "tactile"))


def silhouette_edge(mask: np.ndarray) -> np.ndarray:
    """Mask pixels within the lines' reach of a pixel outside the mask."""
    taps = disc_taps(LINE_REACH_MM / GRID_PITCH_MM)
    out = torch.from_numpy((~mask).astype(np.float32))[None, None]
    return (F.conv2d(out, taps, padding=taps.shape[-1] // 2)[0, 0] > 0.5).numpy() & mask


def lines_band(sketch: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The -lines band as an exported graph computes it: from the graph's input, the sketch times the mask."""
    x = network_input(sketch, mask).sketch
    return stroke_band(torch.from_numpy(x), disc_taps(LINE_REACH_MM / GRID_PITCH_MM))[0, 0].numpy() > 0.5


def test_the_band_holds_the_silhouettes_inner_edge_on_generated_garments(tmp_path):
    """Part of the silhouette's ink lies outside the mask (the graph never sees it), but the outline is drawn on the
    mask's own boundary pixels too, so the band still covers every mask pixel near the edge: adding the mask's edge
    to the band (tried) changes no pixel."""
    for path in generate_dataset(tmp_path, garments=6, seed=0, frame=(640, 480), progress=False):
        g = load_garment(path, tactile=False)
        m = g.mask.astype(bool)
        assert ((g.sketch < 128) & ~m).any()   # the case in question: ink outside the mask
        edge = silhouette_edge(m)
        assert edge.any() and lines_band(g.sketch, m)[edge].all(), path.name


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), thickness=st.integers(1, 3))
def test_the_band_holds_the_silhouettes_inner_edge_on_a_kiosk_mask(seed, thickness):
    """The kiosk's mask is the region the closed outline encloses, its ink included: the same holds there."""
    import cv2
    rng = np.random.default_rng(seed)
    pts = rng.integers(8, 88, (8, 2)).astype(np.int32)
    hull = cv2.convexHull(pts)
    s = np.full((96, 96), 255, np.uint8)
    cv2.polylines(s, [hull], True, 0, thickness)
    m = object_mask(s)
    assume(m.any())   # a degenerate hull (points on a line) encloses nothing
    edge = silhouette_edge(m)
    assert lines_band(s, m)[edge].all()


def test_the_lowpass_keeps_a_constant_and_the_mean():
    x = torch.full((1, 2, 9, 4), 0.7)
    assert torch.allclose(gaussian_lowpass(x, DETAIL_SIGMA_PX), x)
    y = torch.randn(1, 2, 40, 40, generator=torch.Generator().manual_seed(1))
    assert abs(float(gaussian_lowpass(y, DETAIL_SIGMA_PX).mean() - y.mean())) < 0.02
    assert float(gaussian_lowpass(y, DETAIL_SIGMA_PX).std()) < 0.2 * float(y.std())   # white noise mostly removed


def test_only_the_relief_is_averaged_and_only_where_a_graph_has_one():
    s, m = inputs(8, 6, 1)
    base = AnyNet()
    for mode in MIRRORED:
        net = MirrorAverage(SlopeNet(), mode)
        net(s, m, "visual")
        assert net.generator.calls == 1   # a visual-only graph runs the generator once
        net(s, m, "tactile")
        assert net.generator.calls == 2 + len(MODES[mode])
        wrapped = MirrorAverage(base, mode)
        with torch.no_grad():
            assert torch.equal(wrapped(s, m)[0], base(s, m)[0])
            assert torch.allclose(wrapped(s, m, "tactile"), wrapped(s, m)[1])
            assert torch.isfinite(wrapped(s, m)[1]).all()
    for bad in ("none", "rotate", ""):
        with pytest.raises(ValueError, match="mirror mode"):
            MirrorAverage(base, bad)


def test_run_arguments_name_the_mirrors():
    assert parse_run("runs/a@flip") == RunSpec(Path("runs/a"), mirrors="flip")
    assert parse_run("runs/a@flip+transpose@ls") == parse_run("runs/a@ls@flip+transpose") \
        == RunSpec(Path("runs/a"), relief="ls", mirrors="flip+transpose")
    assert parse_run("runs/a", mirrors="transpose").mirrors == "transpose"
    assert parse_run("runs/a@flip+transpose-low@ls") == RunSpec(Path("runs/a"), relief="ls",
                                                                mirrors="flip+transpose-low")
    assert parse_run("runs/a@flip", mirrors="transpose").mirrors == "flip"   # a run's own suffix wins
    spec = RunSpec(Path("runs/a"), "raw", "ls", "flip")
    assert str(spec) == "runs/a@raw@flip@ls" and parse_run(str(spec)) == spec
    for bad in ("runs/a@flip@flip", "runs/a@flip@transpose", "runs/a@rotate", "@flip"):
        with pytest.raises(ValueError):
            parse_run(bad)
    runs, labels = parse_labelled(["x=runs/a@flip", "runs/a"], mirrors="none")
    assert runs == [RunSpec(Path("runs/a"), mirrors="flip"), RunSpec(Path("runs/a"))]
    assert labels == {RunSpec(Path("runs/a"), mirrors="flip"): "x"}


def test_mirrored_scores_are_stored_apart(tmp_path):
    names = {_paths(tmp_path, "latest", "average", r, m)[0].name for r in ("none", "ls") for m in MODES}
    assert len(names) == 2 * len(MODES) and "compare-latest-flip-ls.json" in names


def test_the_command_line_offers_exactly_the_modes():
    """The CLIs keep torch out of --help, so they spell the modes out; this holds them to MODES."""
    from exporter.cli import build_parser as export_parser
    from trainer.eval_cli import build_parser as eval_parser
    for parser in (eval_parser("eval"), export_parser("export")):
        action = next(a for a in parser._actions if "--mirrors" in a.option_strings)
        assert tuple(action.choices) == tuple(MODES) and action.default == "none"
