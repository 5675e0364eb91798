"""Is the tactile discriminator's R1 penalty, and its gradient, the same on a GPU as on the CPU?

    python scripts/gpu_r1_check.py [--out r1_check.json] [--devices cpu cuda]

Why: on an H200 every `ours` run's R1 term grew from ~1e-1 to ~1e5 within a few hundred steps, with TF32 on or off,
while the same recipe on the CPU keeps it near 1e-2 (docs/training.md, "On a GPU"). R1 needs the second derivative
through the discriminator (its BatchNorm, convolutions and DiffAugment's indexing); a backend that drops or
mis-states a second-order term would let the discriminator sharpen unchecked. This builds the tactile D of `ours`
(7-channel 32 px patches, the cpu preset's widths), draws one seeded batch, and compares on each device and precision
the penalty and its gradient with respect to D's weights against the CPU in float64. A row far above float32's
rounding (relative difference ~1e-6) points at the backend.

A second table checks the D's own operations one by one on a channels-last-strided input (what DiffAugment's
translation returned before it was rewritten): the output, the R1-style input gradient and its gradient, on the GPU
against the CPU in float64. On an H100 with torch 2.11.0+cu130 `avg_pool2d(count_include_pad=False)` failed it (R1 off
by 8 %, its gradient unrelated) while convolution, BatchNorm and LeakyReLU passed (docs/training.md, "On a GPU"); a
later torch that passes it makes the workarounds in DiffAugment and MultiScaleD unnecessary, not wrong.
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer.losses.gan import r1_penalty  # noqa: E402
from trainer.models.discriminators import MultiScaleD  # noqa: E402
from trainer.recipe.diffaug import DiffAugment  # noqa: E402
from trainer.sampling import PATCH  # noqa: E402

# off, each DiffAugment op alone (to name the one that differs), and the recipe's policy
POLICIES = ("", "color", "translation", "cutout", "color,translation,cutout")


def penalty_and_grads(d: MultiScaleD, x: torch.Tensor, *, diffaug: str, seed: int):
    d.zero_grad(set_to_none=True)
    x = x.clone().requires_grad_(True)
    aug = DiffAugment(diffaug, rgb=slice(3, 6), seed=seed)
    (xa,) = aug(x)
    r1 = r1_penalty(d(xa), x)
    r1.backward()
    grads = torch.cat([p.grad.flatten() for p in d.parameters() if p.grad is not None])
    return float(r1.detach()), grads.double().cpu()


def _op_terms(op, x0: torch.Tensor, dev: str, channels_last: bool, cudnn: bool):
    """(sum of squared outputs, squared norm of its input gradient, gradient of that w.r.t. input and weights)."""
    torch.backends.cudnn.enabled = cudnn
    x = x0.to(dev).requires_grad_(True)
    xin = x.to(memory_format=torch.channels_last) if channels_last else x * 1
    op = copy.deepcopy(op).to(dev) if isinstance(op, nn.Module) else op   # the caller's stays on the CPU
    out = op(xin).pow(2).sum()
    (g,) = torch.autograd.grad(out, x, create_graph=True)
    r1 = g.pow(2).sum()
    wrt = [x] + (list(op.parameters()) if isinstance(op, nn.Module) else [])
    grads = torch.autograd.grad(r1, wrt, allow_unused=True)
    flat = torch.cat([(torch.zeros_like(w) if gr is None else gr).flatten() for gr, w in zip(grads, wrt)])
    return float(out.detach()), float(r1.detach()), flat.detach().double().cpu()


def op_rows(devices: list[str], seed: int) -> list[dict]:
    """The tactile D's operations on a channels-last input, each device against the CPU's standard layout."""
    torch.manual_seed(seed)
    x0 = torch.rand(96, 7, 32, 32, dtype=torch.float64) * 2 - 1
    ops = {"conv2d": nn.Conv2d(7, 8, 4, 2, 2).double(), "batch_norm": nn.BatchNorm2d(7).double(),
           "leaky_relu": nn.LeakyReLU(0.2),
           "avg_pool2d": lambda t: F.avg_pool2d(t, 3, stride=2, padding=1, count_include_pad=False)}
    rows = []
    for name, op in ops.items():
        ref = _op_terms(op, x0, "cpu", False, True)
        for dev in devices:
            if dev == "cuda" and not torch.cuda.is_available():
                continue
            for cudnn in ((True, False) if dev == "cuda" else (True,)):
                out, r1, g = _op_terms(op, x0, dev, True, cudnn)
                rows.append({"op": name, "device": dev, "cudnn": cudnn, "layout": "channels_last",
                             "out_rel_diff": abs(out - ref[0]) / abs(ref[0]),
                             "r1_rel_diff": abs(r1 - ref[1]) / abs(ref[1]),
                             "grad_rel_diff": float((g - ref[2]).norm() / ref[2].norm())})
    torch.backends.cudnn.enabled = True
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path)
    ap.add_argument("--devices", nargs="+", default=["cpu", "cuda"])
    ap.add_argument("--patches", type=int, default=96)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    torch.manual_seed(a.seed)
    ref_d = MultiScaleD(in_ch=7, ndf=8, n_layers=3, num_D=3, norm="batch", min_input=PATCH).double()
    x = torch.rand(a.patches, 7, PATCH, PATCH, dtype=torch.float64) * 2 - 1
    cases = []
    for dev in a.devices:
        if dev == "cuda" and not torch.cuda.is_available():
            print("no GPU here: cuda rows skipped", file=sys.stderr)
            continue
        for dtype in (torch.float64, torch.float32):
            for cudnn in ((True, False) if dev == "cuda" else (True,)):
                for diffaug in POLICIES:
                    cases.append((dev, dtype, cudnn, diffaug))
    rows = []
    ref: dict[str, tuple[float, torch.Tensor]] = {}
    for diffaug in POLICIES:
        ref[diffaug] = penalty_and_grads(ref_d, x, diffaug=diffaug, seed=a.seed)
    for dev, dtype, cudnn, diffaug in cases:
        torch.backends.cudnn.enabled = cudnn
        torch.backends.cudnn.allow_tf32 = False
        d = MultiScaleD(in_ch=7, ndf=8, n_layers=3, num_D=3, norm="batch", min_input=PATCH)
        d.load_state_dict(ref_d.state_dict())
        d = d.to(device=dev, dtype=dtype)
        r1, g = penalty_and_grads(d, x.to(device=dev, dtype=dtype), diffaug=diffaug, seed=a.seed)
        r1_ref, g_ref = ref[diffaug]
        rows.append({"device": dev, "dtype": str(dtype).removeprefix("torch."), "cudnn": cudnn,
                     "diffaug": diffaug or "off", "r1": r1, "r1_cpu_float64": r1_ref,
                     "r1_rel_diff": abs(r1 - r1_ref) / max(abs(r1_ref), 1e-30),
                     "grad_rel_diff": float((g - g_ref).norm() / max(float(g_ref.norm()), 1e-30))})
    torch.backends.cudnn.enabled = True
    print(f"{'device':7} {'dtype':8} {'cudnn':6} {'diffaug':25} {'R1':>12} {'R1 rel diff':>12} {'grad rel diff':>14}")
    for r in rows:
        print(f"{r['device']:7} {r['dtype']:8} {str(r['cudnn']):6} {r['diffaug']:25} {r['r1']:12.5g} "
              f"{r['r1_rel_diff']:12.3g} {r['grad_rel_diff']:14.3g}")
    ops = op_rows(a.devices, a.seed)
    print(f"\n{'op':11} {'device':7} {'cudnn':6} {'out rel diff':>12} {'R1 rel diff':>12} {'grad rel diff':>14}"
          "   (channels-last input, against the CPU's standard layout in float64)")
    for r in ops:
        print(f"{r['op']:11} {r['device']:7} {str(r['cudnn']):6} {r['out_rel_diff']:12.3g} {r['r1_rel_diff']:12.3g} "
              f"{r['grad_rel_diff']:14.3g}")
    if a.out:
        gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
        a.out.write_text(json.dumps({"torch": torch.__version__, "gpu": gpu, "patches": a.patches, "rows": rows,
                                     "channels_last_ops": ops}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
