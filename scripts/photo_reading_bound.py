"""How much of the relief off the touches a photo carries, read by a filter or a small network that is taught by the
full-field truth over one half of the garment and scored on the other half.

Why: the relief rules (`--relief shade`) and scripts/photo_shading_bound.py read a photo with a filter fitted on the
training touches, whose few pixels sit a pixel or two off where they were pressed. Here the teacher is the truth
itself, registered and over half the object (tens of thousands of pixels), so what is left is what the photo does
not carry, or carries in a way the reader cannot take. The object is split at its median column; each half is
predicted by a reader taught on the other, and the whole is scored by the evaluator (trainer/evaluate.py) on the
training sketch beside the reference rows. Readers: a free K x K linear filter of the photo's log-luminance beside
the model's relief (as `--linear`), and a five-layer convolutional network (about 31 px of reach) on the photo, its
log-luminance, the mask and the model's relief. Each reads the run's own photo and the garment's real one.

    .venv/bin/python scripts/photo_reading_bound.py runs/b3/KnitJacket/ours-txr-s12 --mirrors flip+transpose-energy
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
from torch import nn

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from photo_shading_bound import LINEAR_RIDGE, METRIC, windows  # noqa: E402

from trainer.checkpoint import CheckpointError  # noqa: E402
from trainer.evaluate import Nets, Prediction, gap_closed, reference_predictions, score  # noqa: E402
from trainer.models.mirror_modes import MODES  # noqa: E402
from trainer.models.shading_relief import log_luminance  # noqa: E402
from trainer.shading_fit import solve  # noqa: E402

LR, LR_LATE, LATE = 2e-3, 5e-4, 0.7   # Adam; the rate drops for the last 30 % of the steps


def halves(obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The object split at its median column: two disjoint masks whose union is the object."""
    cols = np.nonzero(obj)[1]
    mid = np.median(cols) if len(cols) else 0.0
    left = np.arange(obj.shape[1])[None] < mid
    return obj & left, obj & ~left


def reader(channels: int) -> nn.Module:
    """Photo (3), log-luminance, mask and the model's relief (2) in; slopes (2) out. Dilations 1, 2, 4: about 31 px
    of reach, a few weave periods and the width of a fold's flank."""
    c = channels
    return nn.Sequential(nn.Conv2d(7, c, 5, padding=2), nn.ReLU(), nn.Conv2d(c, c, 5, padding=4, dilation=2),
                         nn.ReLU(), nn.Conv2d(c, c, 5, padding=8, dilation=4), nn.ReLU(),
                         nn.Conv2d(c, c, 3, padding=1), nn.ReLU(), nn.Conv2d(c, 2, 3, padding=1))


def read(ctx, tac: torch.Tensor, photo: torch.Tensor, width: int, channels: int, steps: int
         ) -> tuple[torch.Tensor, torch.Tensor]:
    """(linear, network) reliefs (1, 2, H, W): each half of the object read by a reader taught on the other half."""
    truth = np.stack(ctx.truth())
    obj = ctx.obj
    lum = log_luminance(photo.float(), ctx.mask)
    centred = lum - lum[0, 0][torch.from_numpy(obj)].mean()   # the lamp's level is no slope
    x = torch.cat([photo.float(), centred, ctx.mask.float(), tac.float()], 1)
    target = torch.from_numpy(truth).float()[None]
    win = windows(lum[0, 0].double().numpy(), width)
    model = tac[0].double().numpy()
    linear, net_out = np.zeros_like(model), torch.zeros_like(target)
    split = halves(obj)
    for taught, scored in (split, split[::-1]):
        ty, tx = np.nonzero(taught)
        sy, sx = np.nonzero(scored)
        f_t, f_s = win[ty, tx], win[sy, sx]
        f_t, f_s = f_t - f_t.mean(1, keepdims=True), f_s - f_s.mean(1, keepdims=True)
        for c in (0, 1):
            w = solve(np.concatenate([model[c, ty, tx][:, None], f_t], 1), truth[c, ty, tx].astype(np.float64),
                      LINEAR_RIDGE)
            linear[c, sy, sx] = w[0] * model[c, sy, sx] + f_s @ w[1:]
        torch.manual_seed(0)
        net = reader(channels)
        opt = torch.optim.Adam(net.parameters(), LR)
        m = torch.from_numpy(taught)[None, None].float()
        for step in range(steps):
            if step == int(LATE * steps):
                for group in opt.param_groups:
                    group["lr"] = LR_LATE
            loss = (((net(x) - target) ** 2) * m).sum() / (2 * m.sum())
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            s = torch.from_numpy(scored)
            net_out[0][:, s] = net(x)[0][:, s]
    return torch.from_numpy(linear.astype(np.float32))[None], net_out


def bound(run: Path, which: str = "latest", mirrors: str = "none", width: int = 11, channels: int = 16,
          steps: int = 150) -> dict:
    p = Prediction(run, which, unseen=False, mirrors=mirrors)
    ctx, nets = p.ctx, Nets(p.cfg.pretrained)
    refs = {k: score(ctx, nets, None, t)[0] for k, (_, t, _, _) in reference_predictions(ctx).items()
            if k in ("flat", "oracle", "shape-oracle")}
    if "flat" not in refs or "oracle" not in refs:
        raise SystemExit(f"{run}: its garment has no full-field truth (a synthetic garment is needed)")

    def row(s: dict) -> dict:
        return {METRIC: s[METRIC], "gap_closed": gap_closed(s, refs["flat"], refs["oracle"])[METRIC]}

    rows = {"as given": row(score(ctx, nets, None, p.tac)[0])}
    for photo, vis in (("own photo", p.vis), ("real photo", ctx.visual)):
        lin, net = read(ctx, p.tac, vis, width, channels, steps)
        rows[f"linear {width}, {photo}"] = row(score(ctx, nets, None, lin * ctx.mask)[0])
        rows[f"network {channels}, {photo}"] = row(score(ctx, nets, None, net * ctx.mask)[0])
    for name in ("shape-oracle", "flat", "oracle"):
        if name in refs:
            rows[name] = row(refs[name])
    return {"run": run.name, "garment": p.g.name, "mirrors": mirrors, "checkpoint": which, "width": width,
            "channels": channels, "steps": steps, "rows": rows}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run folders of a two-branch method on synthetic garments")
    ap.add_argument("--which", default="latest", choices=("latest", "best"))
    ap.add_argument("--mirrors", default="none", choices=sorted(MODES))
    ap.add_argument("--width", type=int, default=11, help="the linear filter's width, odd (11)")
    ap.add_argument("--channels", type=int, default=16, help="the network's width (16)")
    ap.add_argument("--steps", type=int, default=150, help="the network's Adam steps per half (150)")
    ap.add_argument("--json", type=Path, help="write the rows here")
    a = ap.parse_args(argv)
    if a.width < 1 or a.width % 2 == 0 or a.channels < 1 or a.steps < 1:
        ap.error(f"--width must be odd, --channels and --steps at least 1; got {a.width}, {a.channels}, {a.steps}")
    torch.set_num_threads(1)
    out = []
    for run in a.runs:
        try:
            b = bound(run, a.which, a.mirrors, a.width, a.channels, a.steps)
        except CheckpointError as exc:
            print(f"{run}: {exc}", file=sys.stderr)
            return 2
        out.append(b)
        print(f"{run} ({b['garment']}, mirrors {a.mirrors}): outside angle (deg) / gap closed, each half read by "
              "a reader taught on the other half's truth")
        for name, r in b["rows"].items():
            print(f"  {name:24} {r[METRIC]:7.3f}  {100 * r['gap_closed']:5.1f} %")
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
