"""What a visual head that drew the real photo exactly would give the shading relief: a run's relief (under a mirror
mode) with the shading relief read from its own photo and from the garment's real training photo, each fitted on the
training touches as `--relief shade` / `shade-lift` fit it, scored on the full-field truth's outside angle.

Why: the shading relief can only read back the weave the visual head places. The real photo in its place bounds what
placing the weave in the photo (weave waves, trainer/models/weave_waves.py) can give the relief, before any is
trained; the scores are the evaluator's own (trainer/evaluate.py), on the training sketch only.

`--linear K` adds a wider bound: the best any linear reading of a photo could do. Beside the model's relief, a free
K x K filter of the photo's log-luminance (each window's mean out) is fitted per slope channel, on the recorded
touches as the rules fit, then on the truth at the same pixels (registration perfect) and on the truth over the whole
object (an oracle fit: no linear reading of that photo, however found, comes closer to the truth there in squares).

    .venv/bin/python scripts/photo_shading_bound.py runs/b3/KnitJacket/ours-txr-s12 --mirrors flip+transpose-energy
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from trainer.calibration import CalibrationError, touch_pixels  # noqa: E402
from trainer.checkpoint import CheckpointError  # noqa: E402
from trainer.evaluate import Nets, Prediction, gap_closed, reference_predictions, score  # noqa: E402
from trainer.models.mirror_modes import MODES  # noqa: E402
from trainer.models.shading_relief import dog_bands, log_luminance  # noqa: E402
from trainer.shading_fit import fit_shading, solve  # noqa: E402

METRIC = "full_angle_deg_outside"
LINEAR_RIDGE = 0.01   # per sample, on columns scaled to unit RMS (shading_fit.solve); 121 taps need more than its 8
FITS = ("recorded touches", "truth at touches", "truth everywhere")


class RealPhoto(torch.nn.Module):
    """The run's relief beside the real photo of its training crop in place of its visual output."""

    def __init__(self, net: torch.nn.Module, photo: torch.Tensor):
        super().__init__()
        self.net, self.photo = net, photo

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor, kind: str = "full"):
        assert sketch.shape[-2:] == self.photo.shape[-2:], "the real photo is the training crop's only"
        return self.photo * mask, self.net(sketch, mask, "tactile")


def bound(run: Path, which: str = "latest", mirrors: str = "none", linear: tuple[int, ...] = ()) -> dict:
    p = Prediction(run, which, unseen=False, mirrors=mirrors)
    ctx, nets = p.ctx, Nets(p.cfg.pretrained)
    refs = {k: score(ctx, nets, None, t)[0] for k, (_, t, _, _) in reference_predictions(ctx).items()
            if k in ("flat", "oracle", "shape-oracle")}
    if "flat" not in refs or "oracle" not in refs:
        raise SystemExit(f"{run}: its garment has no full-field truth (a synthetic garment is needed)")

    def row(tac: torch.Tensor, **extra) -> dict:
        s = score(ctx, nets, None, tac)[0]
        return {METRIC: s[METRIC], "gap_closed": gap_closed(s, refs["flat"], refs["oracle"])[METRIC], **extra}

    rows = {"as given": row(p.tac)}
    for photo, net in (("own photo", p.net), ("real photo", RealPhoto(p.net, ctx.visual))):
        for rule, floor in (("shade", None), ("shade-lift", 1.0)):
            try:
                fit = fit_shading(net, ctx.g, ctx.side, floor=floor)
            except CalibrationError as exc:
                rows[f"{rule}, {photo}"] = {"refused": str(exc)}
                continue
            with torch.no_grad():
                _, tac = fit.wrap(net)(ctx.sketch, ctx.mask)
            rows[f"{rule}, {photo}"] = row(tac, model_weight=fit.model_weight)
    for k in linear:
        for photo, vis in (("own photo", p.vis), ("real photo", ctx.visual)):
            try:
                reliefs = linear_reliefs(ctx, p.tac, vis, k)
            except CalibrationError as exc:
                rows[f"linear {k}, {photo}"] = {"refused": str(exc)}
                continue
            for where, tac in reliefs.items():
                rows[f"linear {k}, {photo}, fit on {where}"] = row(tac)
    for name in ("shape-oracle", "flat", "oracle"):
        if name in refs:
            rows[name] = {METRIC: refs[name][METRIC],
                          "gap_closed": gap_closed(refs[name], refs["flat"], refs["oracle"])[METRIC]}
    return {"run": run.name, "garment": p.g.name, "mirrors": mirrors, "checkpoint": which, "rows": rows,
            "photo_band_correlation": band_correlation(p.vis, ctx)}


def windows(img: np.ndarray, k: int) -> np.ndarray:
    """(H, W, k * k) view: every pixel's k x k window of (H, W), edges replicated."""
    r = k // 2
    v = np.lib.stride_tricks.sliding_window_view(np.pad(img, r, mode="edge"), (k, k))
    return v.reshape(*img.shape, k * k)


def linear_reliefs(ctx, tac: torch.Tensor, vis: torch.Tensor, k: int) -> dict[str, torch.Tensor]:
    """Per fit of FITS, (1, 2, H, W): the model's relief weighted plus a free k x k filter of the photo's
    log-luminance, one pair (weight, filter) per slope channel, fitted on that fit's pixels, applied over the object."""
    if k < 1 or k % 2 == 0:
        raise ValueError(f"a linear filter needs an odd width of at least 1; got {k}")
    win = windows(log_luminance(vis.float(), ctx.mask)[0, 0].double().numpy(), k)
    model = tac[0].double().numpy()
    truth = ctx.truth()
    found = touch_pixels(ctx.g, ctx.origin, ctx.side)
    if not found:
        raise CalibrationError(f"{ctx.g.name}: no training touch inside the evaluation crop to fit a filter on")
    ty, tx = (np.concatenate([f[i] for f in found]) for i in (0, 1))
    ey, ex = np.nonzero(ctx.obj)
    sets = {FITS[0]: (ty, tx, [np.concatenate([f[i] for f in found]) for i in (2, 3)]),
            FITS[1]: (ty, tx, [t[ty, tx] for t in truth]),
            FITS[2]: (ey, ex, [t[ey, ex] for t in truth])}

    def feats(yy, xx):
        f = win[yy, xx]
        return f - f.mean(1, keepdims=True)   # a window's uniform brightness is no slope

    every = feats(ey, ex)
    out = {}
    for where, (yy, xx, target) in sets.items():
        f = feats(yy, xx)
        pred = np.zeros_like(model)
        for c in (0, 1):
            w = solve(np.concatenate([model[c, yy, xx][:, None], f], 1), np.asarray(target[c], np.float64),
                      LINEAR_RIDGE)
            pred[c, ey, ex] = w[0] * model[c, ey, ex] + every @ w[1:]
        out[where] = torch.from_numpy(pred.astype(np.float32))[None]
    return out


def band_correlation(vis: torch.Tensor, ctx) -> list[float]:
    """Per fine band, the correlation of the model's photo with the real one on the object off the training touches'
    rectangles: how well the visual head places what the shading relief reads (1 = in place, 0 = unrelated)."""
    own = dog_bands(log_luminance(vis, ctx.mask))[0, 0].numpy()
    real = dog_bands(log_luminance(ctx.visual, ctx.mask))[0, 0].numpy()
    off = ctx.obj & ~ctx.inside
    out = []
    for a, b in zip(own, real):
        x, y = a[off].astype(np.float64), b[off].astype(np.float64)
        x, y = x - x.mean(), y - y.mean()
        den = float(np.sqrt((x * x).sum() * (y * y).sum()))
        out.append(float((x * y).sum() / den) if den > 0 else 0.0)   # a flat photo is unrelated, not 0/0
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run folders of a two-branch method on synthetic garments")
    ap.add_argument("--which", default="latest", choices=("latest", "best"))
    ap.add_argument("--mirrors", default="none", choices=sorted(MODES))
    ap.add_argument("--linear", type=int, nargs="*", default=[], metavar="K",
                    help="add the rows of a free K x K linear filter of each photo (odd K; 11 and 21 measured)")
    ap.add_argument("--json", type=Path, help="write the rows here")
    a = ap.parse_args(argv)
    if any(k < 1 or k % 2 == 0 for k in a.linear):
        ap.error(f"--linear takes odd widths of at least 1; got {a.linear}")
    torch.set_num_threads(1)
    out = []
    for run in a.runs:
        try:
            b = bound(run, a.which, a.mirrors, tuple(a.linear))
        except CheckpointError as exc:
            print(f"{run}: {exc}", file=sys.stderr)
            return 2
        out.append(b)
        print(f"{run} ({b['garment']}, mirrors {a.mirrors}): outside angle (deg) / gap closed")
        for name, r in b["rows"].items():
            if "refused" in r:
                print(f"  {name:48} refused: {r['refused']}")
                continue
            w = f"  (model weight {r['model_weight']:.2f})" if "model_weight" in r else ""
            print(f"  {name:48} {r[METRIC]:7.3f}  {100 * r['gap_closed']:5.1f} %{w}")
        print("  photo's fine bands against the real photo's off the touches, correlation: "
              + " / ".join(f"{c:.3f}" for c in b["photo_band_correlation"]))
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
