"""Evaluate one run, with the reference rows beside it (trainer.references: flat, mean-colour, oracle).

What is scored (docs/training.md, "Evaluation protocol"):
- visual PSNR / SSIM / L1 inside the object mask; LPIPS (VGG weights configured) on the object's bounding box;
- tactile MSE and angular error on every valid held-out patch centre (trainer.heldout);
- full-field angular error and friction MAE (synthetic ground truth), also inside / outside the training touch
  rectangles (outside = what the model had to generalise to);
- texture statistics (FB-SIFID always, SIFID with Inception weights) on *unseen* sketches (the other garments'
  sketches and edited ones in the same dataset folder) against this garment's photo and tactile truth; the same
  figures on the training sketch are reported with a `_seen` suffix;
- `gap_closed` per tactile metric: (flat - method) / (flat - oracle); None where flat and oracle tie.
"""
from __future__ import annotations

import hashlib
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from trainer.augment import CropError, eval_crop_origin, object_bbox, resolve_crop
from trainer.bootstrap import Units
from trainer.calibration import CalibrationError
from trainer.checkpoint import CheckpointError, load_generator, read_checkpoint
from trainer.config import config_from_dict
from trainer.data.touchclothing import DatasetError, Garment, extract_patches, find_garments, load_garment
from trainer.heldout import heldout_errors, touch_rect_mask
from trainer.metrics import full_field_scores, visual_scores
from trainer.models.mirror_average import MirrorAverage
from trainer.physical import LINE_REACH_MM
from trainer.relief import calibrate
from trainer.references import WEAVE_CUTOFF, object_colour, oracle, paint, weave_period_px, weave_split
from trainer.sampling import crop_tensors, cut, patches_to_tensors
from trainer.sheets import friction_tile, grid, label, normal_tile, save_png, to_uint8
from trainer.texture_distance import channel_banks, fb_sifid_banks, fb_sifid_channels

log = logging.getLogger(__name__)

HIGHER_IS_BETTER = {"visual_psnr", "visual_ssim"}
# lower is better for each; gap closed = (flat - method) / (flat - oracle)
GAP_METRICS = ("tactile_mse", "tactile_angle_deg", "full_angle_deg", "full_angle_deg_inside",
               "full_angle_deg_outside", "full_angle_deg_outside_lines", "full_angle_deg_outside_open",
               "full_friction_mae", "full_friction_mae_inside",
               "full_friction_mae_outside", "tactile_fbsifid_seen", "full_fbsifid_seen")
GAP_TIE = 1e-9   # |flat - oracle| at or below this (relative to |flat|) leaves no gap to close


@dataclass
class Unseen:
    """A sketch the model never trained on, cropped for the network. kind: 'other garment' or 'edited'."""

    name: str
    kind: str
    sketch: torch.Tensor
    mask: torch.Tensor


@dataclass
class Context:
    """A garment at an evaluation crop: everything needed to score any prediction of it (a run or a reference)."""

    g: Garment
    side: int
    origin: tuple[int, int]
    scale: float
    sketch: torch.Tensor = field(init=False)
    mask: torch.Tensor = field(init=False)
    visual: torch.Tensor = field(init=False)
    unseen: list[Unseen] = field(default_factory=list)

    def __post_init__(self):
        self.sketch, self.mask, self.visual = crop_tensors(self.g, self.origin, self.side)
        self.obj = self.crop(self.g.mask).astype(bool)
        self.inside = self.crop(touch_rect_mask(self.g, "train")) & self.obj
        self.near_lines = near_strokes(self.crop(self.g.sketch), self.g.pixel_pitch_mm)
        self.patches = extract_patches(self.g, "test", crop_origin=self.origin, crop_size=(self.side, self.side),
                                       mode="centre")
        self._oracle = None
        self._weave = None
        self._banks: dict[str, list[np.ndarray]] = {}

    def banks(self, which: str) -> list[np.ndarray]:
        """Filter-bank features of the photo ('visual') or the full-field truth ('tactile'), computed once: every
        prediction and reference is compared with them."""
        if which not in self._banks:
            self._banks[which] = channel_banks(self.visual[0].numpy() if which == "visual" else np.stack(self.truth()))
        return self._banks[which]

    def crop(self, a: np.ndarray) -> np.ndarray:
        x, y = self.origin
        return a[y:y + self.side, x:x + self.side]

    def truth(self) -> tuple[np.ndarray, np.ndarray] | None:
        ft = self.g.full_tactile
        return None if ft is None else (self.crop(ft.gx), self.crop(ft.gy))

    def oracle(self):
        if self._oracle is None:
            self._oracle = oracle(self.g) or False
        return self._oracle or None

    def weave_oracles(self):
        """(shape-oracle, texture-oracle) or None (no oracle, or no stated weave period)."""
        if self._weave is None:
            o = self.oracle()
            self._weave = (weave_split(self.g, o) if o is not None else None) or False
        return self._weave or None


def near_strokes(sketch: np.ndarray, pitch_mm: float | None) -> np.ndarray | None:
    """(H, W) bool: within LINE_REACH_MM of a stroke of the sketch (uint8, dark strokes on white paper), the
    silhouette included; None without a pixel pitch (the reach is physical: a seam's ridge is as wide in mm at any
    resolution)."""
    if pitch_mm is None or not (np.isfinite(pitch_mm) and pitch_mm > 0):
        return None
    strokes = (np.asarray(sketch) < 128).astype(np.uint8)
    if not strokes.any():
        return np.zeros(strokes.shape, bool)
    d = cv2.distanceTransform(1 - strokes, cv2.DIST_L2, 5)
    return d <= LINE_REACH_MM / pitch_mm


def find_unseen(g: Garment, side: int, source: Path | None = None) -> list[Unseen]:
    """Every other sketch in the garment's dataset folder (other garments, edited sketches) that fits `side`. With
    `source`, the sketches of that dataset folder instead, every garment there but one of this garment's name: more
    sketches than the garment's own dataset holds, so the texture statistic's interval rests on more units."""
    if source is not None:   # a missing or empty folder is the caller's error, so it raises
        others = [d for d in find_garments(source) if d.name != g.root.name]
    else:
        try:
            others = [d for d in find_garments(g.root.parent) if d.resolve() != g.root.resolve()]
        except Exception:  # noqa: BLE001 - a garment folder given directly has no siblings
            others = []
    out = []
    for d in others:
        try:
            o = load_garment(d, tactile=False)
        except DatasetError as exc:
            log.warning("eval: %s; not used as an unseen sketch", exc)
            continue
        try:
            s = resolve_crop(side, o.mask, fit=False)
        except CropError:
            log.info("eval: %s does not fit a %d px crop; not used as an unseen sketch", d.name, side)
            continue
        sk, mk, _ = crop_tensors(o, eval_crop_origin(o.mask, s), s, visual=np.zeros(o.mask.shape + (3,), np.uint8))
        out.append(Unseen(o.name, "edited" if o.edited else "other garment", sk, mk))
    return out


class Nets:
    """The pretrained networks the configuration names (LPIPS-VGG, InceptionV3 block 1), when their files exist."""

    def __init__(self, pre):
        self.lpips = self.inception = None
        if pre.vgg16 and Path(pre.vgg16).is_file():
            from trainer.losses.perceptual import Perceptual
            self.lpips = Perceptual(vgg16_path=pre.vgg16, lpips_lin_path=pre.lpips_lin)
        else:
            log.info("eval: no VGG16 weights configured; LPIPS not computed")
        if pre.inception and Path(pre.inception).is_file():
            from trainer.models.inception import InceptionBlock1
            self.inception = InceptionBlock1.from_file(pre.inception)
        else:
            log.info("eval: no InceptionV3 weights configured; SIFID not computed (FB-SIFID, weight-free, is "
                     "reported)")


def score(ctx: Context, nets: Nets, vis: torch.Tensor | None, tac: torch.Tensor | None,
          unseen: list[tuple[torch.Tensor | None, torch.Tensor | None]] | None = None) -> tuple[dict, dict]:
    """All metrics of one prediction on `ctx`: vis (1, 3, S, S), tac (1, 2, S, S) (either None to skip that
    modality), `unseen` = its outputs on ctx.unseen in order. Returns (metrics, units per additive metric)."""
    out: dict = {}
    units: dict[str, Units] = {}
    mask = ctx.obj
    if vis is not None:
        s, u = visual_scores(vis[0].numpy(), ctx.visual[0].numpy(), mask, ctx.origin)
        out.update(s)
        units.update(u)
        out["visual_fbsifid_seen"] = fb_sifid_banks(channel_banks(vis[0].numpy()), ctx.banks("visual"), mask)
        if nets.lpips is not None:
            x0, y0, x1, y1 = object_bbox(mask)
            with torch.no_grad():
                out["visual_lpips"] = float(nets.lpips(vis[..., y0:y1, x0:x1], ctx.visual[..., y0:y1, x0:x1]))
            out["lpips_backbone"] = nets.lpips.kind
        if nets.inception is not None:
            from trainer.models.inception import sifid
            out["visual_sifid_seen"] = sifid(nets.inception, vis, ctx.visual)
    if tac is not None:
        gx, gy = tac[0, 0].numpy(), tac[0, 1].numpy()
        ho = heldout_errors(ctx.g, "test", ctx.origin, ctx.side, gx, gy)
        out.update(ho.scores())
        units.update({k: v for k, v in ho.units().items() if len(v)})
        out.update(_seen_patch_texture(ctx, nets, tac))
        truth = ctx.truth()
        if truth is not None:
            s, u = full_field_scores(gx, gy, truth[0], truth[1], mask, ctx.inside, ctx.scale, ctx.origin,
                                     ctx.near_lines)
            out.update(s)
            units.update(u)
            out["full_fbsifid_seen"] = fb_sifid_banks(channel_banks(tac[0].numpy()), ctx.banks("tactile"), mask)
    if unseen:
        u_scores, u_units = _unseen_texture(ctx, nets, unseen)
        out.update(u_scores)
        units.update(u_units)
    return out, units


def _seen_patch_texture(ctx: Context, nets: Nets, tac: torch.Tensor) -> dict:
    """Texture statistics on the held-out patch nearest each test touch's middle (the published per-patch tactile
    SIFID / LPIPS; the sketch is the training one, hence `_seen`)."""
    ps = ctx.patches
    if not len(ps):
        return {}
    gx, gy, c = patches_to_tensors(ps, np.arange(len(ps)))
    fake, real = cut(tac, ps.origin), torch.cat([gx, gy], 1)
    out = {}
    cm = c[:, 0].numpy() > 0.5
    vals = [fb_sifid_channels(fake[k].numpy() * cm[k], real[k].numpy() * cm[k], cm[k]) for k in range(len(fake))]
    vals = [v for v in vals if np.isfinite(v)]
    if vals:
        out["tactile_fbsifid_seen"] = float(np.mean(vals))
    if nets.lpips is not None:
        from trainer.losses.perceptual import per_channel
        with torch.no_grad():
            out["tactile_lpips"] = float(per_channel(nets.lpips, fake * c, real * c, size=224))
    if nets.inception is not None:
        from trainer.models.inception import sifid_channels
        out["tactile_sifid_seen"] = sifid_channels(nets.inception, fake * c, real * c)
    return out


def sketch_key(name: str) -> int:
    """A stable int64 key per unseen sketch, so two methods' per-sketch scores pair up in the bootstrap."""
    return int.from_bytes(hashlib.blake2b(name.encode(), digest_size=7).digest(), "big")


def _unseen_texture(ctx: Context, nets: Nets, outputs) -> tuple[dict, dict[str, Units]]:
    """Mean over unseen sketches of the texture distance between the output (inside the new sketch's mask) and this
    garment's photo / full-field tactile truth (inside its own mask): does the model keep the fabric on a new shape?
    The FB-SIFID means come with one bootstrap unit per sketch (num = distance, den = 1)."""
    vals: dict[str, list[tuple[int, float]]] = {"visual_fbsifid_unseen": [], "visual_sifid_unseen": [],
                                               "full_fbsifid_unseen": []}
    truth = ctx.truth()
    for u, (vis, tac) in zip(ctx.unseen, outputs):
        um = u.mask[0, 0].numpy() > 0.5
        key = sketch_key(u.name)
        if vis is not None:
            vals["visual_fbsifid_unseen"].append(
                (key, fb_sifid_banks(channel_banks(vis[0].numpy()), ctx.banks("visual"), um, ctx.obj)))
            if nets.inception is not None:
                from trainer.models.inception import sifid
                vals["visual_sifid_unseen"].append((key, sifid(nets.inception, vis, ctx.visual)))
        if tac is not None and truth is not None:
            vals["full_fbsifid_unseen"].append(
                (key, fb_sifid_banks(channel_banks(tac[0].numpy()), ctx.banks("tactile"), um, ctx.obj)))
    out: dict = {}
    units: dict[str, Units] = {}
    for name, kv in vals.items():
        kv = [(k, v) for k, v in kv if np.isfinite(v)]
        if not kv:
            continue
        out[name] = float(np.mean([v for _, v in kv]))
        if "fbsifid" in name:
            units[name] = Units([k for k, _ in kv], [v for _, v in kv], np.ones(len(kv)))
    return out, units


def reference_predictions(ctx: Context) -> dict[str, tuple]:
    """name -> (vis, tac, unseen outputs, extra info) of each reference row this garment allows."""
    s = ctx.side
    flat = torch.zeros(1, 2, s, s)
    refs: dict[str, tuple] = {"flat": (None, flat, [(None, torch.zeros_like(u.mask.expand(-1, 2, -1, -1)))
                                                    for u in ctx.unseen], {})}
    colour = object_colour(ctx.visual[0].numpy(), ctx.obj)
    mc = torch.from_numpy(paint(colour, ctx.obj))[None]
    mc_unseen = [(torch.from_numpy(paint(colour, u.mask[0, 0].numpy() > 0.5))[None], None) for u in ctx.unseen]
    refs["mean-colour"] = (mc, None, mc_unseen, {})
    o = ctx.oracle()
    if o is not None:
        tac = torch.from_numpy(np.stack([ctx.crop(o.gx), ctx.crop(o.gy)]))[None]
        refs["oracle"] = (None, tac, None, {"sensor_blur_px": o.sigma_px, "sensor_fit_mse": o.fit_mse,
                                            "head_precision": o.precision})
    w = ctx.weave_oracles()
    if w is not None:
        period = weave_period_px(ctx.g)
        for name, wo in zip(("shape-oracle", "texture-oracle"), w):
            tac = torch.from_numpy(np.stack([ctx.crop(wo.gx), ctx.crop(wo.gy)]))[None]
            refs[name] = (None, tac, None, {"weave_period_px": period, "weave_cutoff_sigma_px": WEAVE_CUTOFF * period})
    return refs


def gap_closed(method: dict, flat: dict, oracle_row: dict) -> dict:
    """(flat - method) / (flat - oracle) per tactile metric the three rows share: 0 = no better than flat, 1 = as
    good as the oracle. None where flat and oracle tie (no gap to close)."""
    out = {}
    for k in GAP_METRICS:
        if k in method and k in flat and k in oracle_row:
            den = flat[k] - oracle_row[k]
            out[k] = float((flat[k] - method[k]) / den) if abs(den) > GAP_TIE * max(abs(flat[k]), 1.0) else None
    return out


class Prediction:
    """A run's outputs on its garment's evaluation crop (and on the unseen sketches), plus what scores them."""

    def __init__(self, run_dir: Path, which: str = "best", *, unseen: bool = True, weights: str = "average",
                 relief: str = "none", mirrors: str = "none", unseen_from: Path | None = None,
                 members: Sequence[Path] = ()):
        self.run = Path(run_dir)
        self.net, self.info = load_generator(self.run, which, weights)
        ck = read_checkpoint(self.run, which)
        self.cfg = config_from_dict(ck["config"])
        others = [self._member(Path(m), which, weights) for m in members]
        if others and mirrors == "none":
            raise CheckpointError("a seed ensemble is averaged by test-time mirroring: name a mirror mode too")
        if mirrors != "none":  # trainer/models/mirror_average.py: before the calibration, which fits what it returns
            self.net = MirrorAverage(self.net, mirrors, others).eval()
        garment_dir = Path(self.cfg.garment)
        if not garment_dir.is_dir():
            raise CheckpointError(f"{self.run}: its garment folder {garment_dir} is gone; cannot evaluate")
        g = load_garment(garment_dir)
        side = int(self.info["crop"])
        self.ctx = Context(g, side, eval_crop_origin(g.mask, side), float(self.info["friction_scale"]))
        self.relief = None
        if relief != "none":   # trainer/calibration.py: fitted on the training touches, applied to every output
            try:
                self.net, self.relief, _ = calibrate(self.net, g, side, relief)
            except CalibrationError as exc:
                log.warning("eval: %s: %s", self.run, exc)
                self.relief = {"rule": relief, "gain": None, "refused": str(exc)}
        if unseen:
            self.ctx.unseen = find_unseen(g, side, unseen_from)
        with torch.no_grad():
            self.vis, self.tac = self.net(self.ctx.sketch, self.ctx.mask)
            self.unseen = [self.net(u.sketch, u.mask) for u in self.ctx.unseen]

    def _member(self, run: Path, which: str, weights: str) -> torch.nn.Module:
        """Another seed's generator, for the ensemble: refused unless it is this run's garment and method."""
        net, info = load_generator(run, which, weights)
        cfg = config_from_dict(read_checkpoint(run, which)["config"])
        if (info["method"], Path(cfg.garment).name, info["crop"]) != (
                self.info["method"], Path(self.cfg.garment).name, self.info["crop"]):
            raise CheckpointError(f"{run}: an ensemble's runs must share the garment, method and crop of {self.run}")
        return net

    @property
    def g(self) -> Garment:
        return self.ctx.g

    @property
    def seed(self) -> int:
        return int(self.cfg.train.seed)


@dataclass
class Evaluation:
    """One run's JSON-able result, its per-unit sums, and its garment's reference rows with their units."""

    result: dict
    units: dict[str, Units]
    ref_units: dict[str, dict[str, Units]]


def evaluate(run_dir: Path, which: str = "best", *, swap: bool = True, unseen: bool = True,
             weights: str = "average", relief: str = "none", mirrors: str = "none",
             unseen_from: Path | None = None, members: Sequence[Path] = ()) -> Evaluation:
    """`members`: other seeds' runs averaged with this one (Prediction); never cached (trainer/eval_cache.py keys
    one run)."""
    p = Prediction(run_dir, which, unseen=unseen, weights=weights, relief=relief, mirrors=mirrors,
                   unseen_from=unseen_from, members=members)
    ctx = p.ctx
    nets = Nets(p.cfg.pretrained)
    out: dict = {"method": p.info["method"], "garment": p.g.name, "step": p.info["step"], "crop": ctx.side,
                 "seed": p.seed, "checkpoint": which, "weights": weights,
                 "perceptual": (p.info.get("info") or {}).get("perceptual"), "machines": p.info.get("machines"),
                 "unseen_sketches": [{"name": u.name, "kind": u.kind} for u in ctx.unseen]}
    if unseen_from is not None:   # the folder's name only: a table must not carry this machine's paths
        out["unseen_from"] = Path(unseen_from).name
    if mirrors != "none":
        out["mirrors"] = mirrors
    if members:   # folder names only, as for unseen_from
        out["members"] = [Path(m).name for m in members]
    if p.relief is not None:
        out["relief"] = p.relief
    metrics, units = score(ctx, nets, p.vis, p.tac, p.unseen)
    out.update(metrics)
    refs, ref_units = {}, {}
    for name, (vis, tac, uns, extra) in reference_predictions(ctx).items():
        refs[name], ref_units[name] = score(ctx, nets, vis, tac, uns)
        refs[name].update(extra)
    if "flat" in refs and "oracle" in refs:
        out["gap_closed"] = gap_closed(out, refs["flat"], refs["oracle"])
        for name in refs:
            refs[name]["gap_closed"] = gap_closed(refs[name], refs["flat"], refs["oracle"])
    out["references"] = refs
    if swap:
        path = swap_grid(p)
        if path is not None:
            out["swap_grid"] = str(path)
    return Evaluation(out, units, ref_units)


def evaluate_run(run_dir: Path, which: str = "best", *, swap: bool = True, weights: str = "average",
                 relief: str = "none", mirrors: str = "none", unseen_from: Path | None = None) -> dict:
    return evaluate(run_dir, which, swap=swap, weights=weights, relief=relief, mirrors=mirrors,
                    unseen_from=unseen_from).result


def swap_grid(p: Prediction) -> Path | None:
    """The paper's swap experiment: this garment's model on every other sketch in the same dataset."""
    rows = []
    for u, (vis, tac) in zip(p.ctx.unseen, p.unseen):
        gx, gy = tac[0, 0].numpy(), tac[0, 1].numpy()
        rows.append([label(to_uint8(u.sketch[0, 0].numpy()), f"{u.name.removeprefix('singleskit_')[:22]} (unseen)"),
                     label(to_uint8(vis[0].permute(1, 2, 0).numpy()), "visual"),
                     label(normal_tile(gx, gy), "normal map"),
                     label(friction_tile(gx, gy, p.ctx.scale), "friction map")])
    if not rows:
        return None
    path = p.run / "eval" / "swap.png"
    save_png(path, grid(rows))
    return path
