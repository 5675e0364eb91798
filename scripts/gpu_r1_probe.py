"""Does the tactile D's step compute the same thing on the GPU as on the CPU, *while* `ours` trains there?

    python scripts/gpu_r1_probe.py --data data/hard640 --garment SatinShirt --out runs/probe [--every 25]
        [--steps 600] [--set section.key=value ...]

Why: on a GPU every `ours` run's R1 term grew from ~1e-1 to ~1e5 within a few hundred steps, while the same recipe
on the CPU keeps it near 1e-2 (docs/training.md, "On a GPU"). `scripts/gpu_r1_check.py` compares the penalty for a
fresh D and a random batch; this one compares it for the D the run has grown, on the very patches and DiffAugment
draw of its D step. Every `--every` steps it copies DT as the step is about to use it and recomputes the step's D
loss, R1 and their gradients with respect to D's weights on the CPU in float64 (the reference), the CPU in float32
(float32's own rounding at that state), CUDA in float32 (as the run computes it) with cuDNN on and off, and CUDA in
float64. A CUDA row far from the reference while the CPU float32 row is close points at the backend; all rows close
while R1 still grows means the GPU run reaches a state the CPU run does not, by a route this check does not see.
Training itself is untouched (the copies are taken before the step and thrown away): the run is an ordinary
`vtkiosk train` run directory with the probe's rows beside it in `r1_probe.jsonl`.
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer.config import load_config  # noqa: E402
from trainer.losses.gan import d_loss, d_loss_fake, r1_penalty  # noqa: E402
from trainer.recipe.diffaug import DiffAugment  # noqa: E402

VARIANTS = (("cpu", torch.float32, True), ("cuda", torch.float32, True), ("cuda", torch.float32, False),
            ("cuda", torch.float64, True))


def d_step_terms(dt: torch.nn.Module, real, fake, unpaired, aug: DiffAugment, gamma: float):
    """The D step of `Ours.step` on copies: (D loss, R1, grad of the total, grad of R1 alone) w.r.t. DT's weights."""
    real = real.detach().clone().requires_grad_(True)
    ra, fa = aug(real, fake)
    (ua,) = aug(unpaired)
    real_o, fake_o = dt(ra), dt(fa)
    loss = d_loss(real_o, fake_o)
    if len(unpaired):
        loss = loss + d_loss_fake(dt(ua))
    r1 = r1_penalty(real_o, real)
    params = [p for p in dt.parameters()]
    # a last layer's bias moves no input gradient, so R1 does not reach it: zeros there
    g_r1 = torch.autograd.grad(r1, params, retain_graph=True, allow_unused=True)
    g_all = torch.autograd.grad(loss + gamma / 2 * r1, params, allow_unused=True)
    flat = lambda gs: torch.cat([(torch.zeros_like(p) if g is None else g).flatten()  # noqa: E731
                                 for g, p in zip(gs, params)]).double().cpu()
    return float(loss.detach()), float(r1.detach()), flat(g_all), flat(g_r1)


def rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / max(float(b.norm()), 1e-300))


class Probe:
    """Wraps `method.tactile_d`: on probe steps, the D step's call (the one whose real patches need a gradient)
    is recomputed on every variant before it runs."""

    def __init__(self, method, every: int, out: Path):
        self.m, self.every, self.out = method, every, out
        self.step = 0
        self.pending: dict | None = None
        self.inner = method.tactile_d
        method.tactile_d = self

    def __call__(self, real, fake, unpaired):
        if real.requires_grad and self.step % self.every == 0:
            self.compare(real, fake, unpaired)
        return self.inner(real, fake, unpaired)

    def compare(self, real, fake, unpaired) -> None:
        m = self.m
        state = m.aug_tactile.g.get_state()
        gamma = m.cfg.loss.tactile_r1
        dt0 = copy.deepcopy(m.nets["DT"]).cpu()
        rows = {}
        for dev, dtype, cudnn in (("cpu", torch.float64, True),) + VARIANTS:
            if dev == "cuda" and not torch.cuda.is_available():
                continue
            aug = DiffAugment(m.cfg.loss.diffaug, rgb=m.aug_tactile.rgb)
            aug.g.set_state(state)
            dt = copy.deepcopy(dt0).to(device=dev, dtype=dtype)
            on = lambda x: x.detach().to(device=dev, dtype=dtype)  # noqa: E731
            before = torch.backends.cudnn.enabled
            torch.backends.cudnn.enabled = cudnn
            try:
                rows[(dev, str(dtype).removeprefix("torch."), cudnn)] = d_step_terms(
                    dt, on(real), on(fake), on(unpaired), aug, gamma)
            finally:
                torch.backends.cudnn.enabled = before
        ref = rows.pop(("cpu", "float64", True))
        rec = {"step": self.step, "d_loss_cpu64": ref[0], "r1_cpu64": ref[1],
               "grad_norm_cpu64": float(ref[2].norm()), "r1_grad_norm_cpu64": float(ref[3].norm()), "variants": []}
        for (dev, dt_name, cudnn), (loss, r1, g_all, g_r1) in rows.items():
            rec["variants"].append({"device": dev, "dtype": dt_name, "cudnn": cudnn, "d_loss": loss, "r1": r1,
                                    "r1_rel": abs(r1 - ref[1]) / max(abs(ref[1]), 1e-300),
                                    "grad_rel": rel(g_all, ref[2]), "r1_grad_rel": rel(g_r1, ref[3])})
        self.pending = rec

    def record(self, logs: dict) -> None:
        """Writes the probe's row with the value the run itself logged (it must equal the float32 row)."""
        rec, self.pending = self.pending, None
        if rec is None:
            return
        rec["r1_run"] = logs.get("d_tactile_r1")
        with (self.out / "r1_probe.jsonl").open("a") as f:
            f.write(json.dumps(rec) + "\n")
        worst = max((v["r1_grad_rel"] for v in rec["variants"] if v["device"] == "cuda"), default=float("nan"))
        print(f"[probe] step {self.step:5d}  R1 {rec['r1_cpu64']:.4g} (run: {rec['r1_run']:.4g})  "
              f"|grad R1| {rec['r1_grad_norm_cpu64']:.4g}  worst CUDA grad-of-R1 rel diff {worst:.3g}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--garment", required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--every", type=int, default=25)
    ap.add_argument("--preset", default="cpu")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    a = ap.parse_args()
    from trainer.cli import pick_garments
    from trainer.loop import Trainer
    recipe = ["loss.tactile_r1=10", "loss.diffaug=color,translation,cutout", "train.ema=0.999",
              "train.threads=1", "train.progress=false", f"train.steps={a.steps}"]
    cfg = load_config(a.preset, overrides=recipe + a.overrides, method="ours")
    (g,) = pick_garments(argparse.Namespace(data=a.data, all=False, index=None, garment=a.garment))
    trainer = Trainer(cfg, g, a.out)
    probe = Probe(trainer.method, a.every, a.out)
    step_fn = trainer.method.step

    def counted(batch, step):
        probe.step = step
        logs = step_fn(batch, step)
        probe.record(logs)
        return logs

    trainer.method.step = counted
    t0 = time.perf_counter()
    from kiosk.ops.signals import on_signals
    with on_signals() as signals:   # a TERM ends the run at its next step, with a checkpoint, as `vtkiosk train`
        summary = trainer.run(should_stop=lambda: signals.stop)
    print(f"done: step {summary['step']}, {time.perf_counter() - t0:.0f} s, val {summary.get('val')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
