"""The training loop object (SPADE-style): data, method, validation, checkpoints, pictures, resume.

Determinism: torch is seeded once (network initialisation); every step's data is drawn from a generator seeded by
(seed, step, rank), and nothing else in a step is random, so a resumed run continues exactly as an uninterrupted
one (tests/trainer/test_loop.py checks this bit for bit under `torch.use_deterministic_algorithms`).
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from trainer.physical import dataset_pitch_mm
from trainer import provenance
from trainer.checkpoint import CheckpointError, read_checkpoint, save_checkpoint
from trainer.config import ConfigError, RunConfig
from trainer.recipe.identity import recipe_differences
from trainer.distributed import Dist, average_scalar
from trainer.errors import TrainerError
from trainer.methods import get_method
from trainer.progress import Progress
from trainer.recipe.schedule import apply_lr, lr_factor
from trainer.metrics import l1, psnr, tactile_patch_metrics
from trainer.models.weave_waves import weave_frequencies
from trainer.sampling import GarmentData, cut
from trainer.sheets import curves_png, grid, label, normal_tile, save_png, to_uint8, friction_tile

log = logging.getLogger("trainer")


def resolve_device(name: str, dist: Dist | None = None) -> torch.device:
    """`train.device` as a torch device. Under torchrun each rank takes its own GPU (its local rank)."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise TrainerError(f"train.device is {name!r} but this torch sees no GPU "
                               f"(torch {torch.__version__}); use cpu or auto")
        if dist is not None and name == "cuda":
            name = f"cuda:{dist.local_rank}"
        elif name == "cuda":
            name = "cuda:0"
    return torch.device(name)


def set_determinism(cfg: RunConfig, device: torch.device) -> None:
    torch.set_num_threads(cfg.train.threads)
    torch.manual_seed(cfg.train.seed)
    np.random.seed(cfg.train.seed)
    if device.type == "cuda":
        torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = cfg.train.tf32
    if cfg.train.deterministic:
        if device.type == "cuda":
            # cuBLAS is deterministic only with a fixed workspace, which must be set before it starts; some CUDA
            # kernels (e.g. transposed-conv backward) have no deterministic form, so they warn rather than stop.
            os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
            torch.use_deterministic_algorithms(True, warn_only=True)
        else:
            torch.use_deterministic_algorithms(True)


class Trainer:
    """Train one garment with one method into `out_dir` (the run directory)."""

    def __init__(self, cfg: RunConfig, garment_dir: Path, out_dir: Path, *, resume: bool = False,
                 dist: Dist | None = None):
        cfg = dataclasses.replace(cfg, garment=str(Path(garment_dir).resolve()))
        self.cfg = cfg
        self.out = Path(out_dir)
        self.dist = dist
        self.rank = dist.rank if dist else 0
        self.main = self.rank == 0
        self.device = resolve_device(cfg.train.device, dist)
        set_determinism(cfg, self.device)
        for key, tactile_only in (("transpose_visual=false", not cfg.data.transpose_visual),
                                  ("mirror_extra=true", cfg.data.mirror_extra)):
            if tactile_only and not get_method(cfg.method).separable_visual:
                raise ConfigError(f"data.{key} needs a two-branch method (ours and its ablations); "
                                  f"{cfg.method} has one loss over both outputs")
        self.data = GarmentData(Path(garment_dir), cfg.data, seed=cfg.train.seed)
        self.method = get_method(cfg.method)(cfg, side=self.data.side, dist=dist, device=str(self.device))
        if cfg.model.weave_waves:   # before the average copies G; a resumed run's checkpoint holds the same values
            self._set_waves(cfg.model.weave_waves)
        self.method.attach_ema(cfg.train.ema, cfg.train.ema_ramp, cfg.train.ema_probe_ramp)
        self.val = self.data.eval_set("val").to(self.device)
        self.step = 0
        self.history: list[dict] = []
        self.val_history: list[dict] = []
        self.best: float | None = None
        self.train_seconds = 0.0
        self.machines = [{"from_step": 0, "machine": provenance.this_machine(cfg.train.threads, self.device)}]
        if resume:
            self._resume()
        elif self.main and (self.out / "checkpoints" / "latest.pt").exists():
            raise CheckpointError(f"{self.out} already holds a run; pass --resume to continue it or pick a new --out")
        if self.main:
            self.out.mkdir(parents=True, exist_ok=True)
            cfg.dump(self.out / "config.yaml")

    # --- state ----------------------------------------------------------------------------------------------
    def _payload(self) -> dict:
        m = self.method
        weights = {k: v.detach().cpu() for k, v in m.eval_generator.state_dict().items()}  # loads on any machine
        return {"generator": weights, "generator_class": m.generator_class,
                "model_config": m.generator.model_config(), "method": m.name, "step": self.step,
                "friction_scale": self.data.friction_scale, "info": m.info, "garment": self.data.g.name,
                "data_profile": self.data.g.profile, "pixel_pitch_mm": dataset_pitch_mm(self.data.g)[0],
                "crop": self.data.side, "config": self.cfg.to_dict(), "machines": self.machines,
                "train_state": {"method": m.state_dict(), "history": self.history, "val": self.val_history,
                                "best": self.best, "train_seconds": self.train_seconds,
                                "torch_rng": torch.get_rng_state()}}

    def _set_waves(self, count: int) -> None:
        """The weave waves' frequencies, read off the training photo (trainer/models/weave_waves.py)."""
        g = self.method.generator
        if not hasattr(g, "set_waves"):
            raise ConfigError(f"model.weave_waves needs the two-branch generator (ours and its ablations); "
                              f"{self.cfg.method} has none")
        try:
            k = weave_frequencies(self.data.g.visual, self.data.g.mask, count)
        except ValueError as exc:
            raise ConfigError(f"{self.data.g.name}: {exc}") from None
        g.set_waves(k)
        periods = ", ".join(f"{2 * math.pi / max(math.hypot(*kk), 1e-12):.1f}" for kk in k.tolist())
        log.info("weave waves of %s: periods %s px", self.data.g.name, periods)

    def _resume(self) -> None:
        ck = read_checkpoint(self.out, "latest")
        if ck.get("method") != self.cfg.method:
            raise CheckpointError(f"{self.out}: holds method {ck.get('method')!r}, not {self.cfg.method!r}")
        if ck.get("garment") not in (None, self.data.g.name):
            raise CheckpointError(f"{self.out}: was trained on garment {ck['garment']!r}, not {self.data.g.name!r}")
        # The config comes from the command line, so a default changed since the run began would otherwise change
        # its recipe half-way without a word.
        changed, unknown = recipe_differences(ck.get("config", {}), self.cfg.to_dict())
        if changed:
            raise CheckpointError(
                f"{self.out}: the command's config differs from the run's recipe ({'; '.join(changed)}); pass "
                f"--set key=<the run's value> for each to continue it as it was trained, or start a new --out")
        if unknown:
            log.warning("%s: the run predates config keys %s; resuming with their current values", self.out,
                        ", ".join(unknown))
        ts = ck["train_state"]
        self.method.load_state_dict(ts["method"])
        self.history, self.val_history = ts["history"], ts["val"]
        self.best, self.train_seconds = ts["best"], ts.get("train_seconds", 0.0)
        torch.set_rng_state(ts["torch_rng"])
        self.step = int(ck["step"])
        here = provenance.this_machine(self.cfg.train.threads, self.device)
        self.machines, changed = provenance.continue_record(ck.get("machines"), self.step, here)
        if changed:
            log.warning("%s: %s", self.out, changed)
        log.info("resumed %s at step %d", self.out, self.step)

    def save(self, which: str = "latest") -> None:
        if self.main:
            save_checkpoint(self.out / "checkpoints" / f"{which}.pt", self._payload())

    # --- validation and pictures ----------------------------------------------------------------------------
    @torch.no_grad()
    def predict(self, batch) -> tuple[torch.Tensor, torch.Tensor]:
        g = self.method.eval_generator
        was = g.training
        g.eval()
        out = g(batch.sketch, batch.mask)
        g.train(was)
        return out

    def validate(self) -> dict:
        v = self.val
        vis, tac = self.predict(v)
        out = {"step": self.step, "val_visual_l1": l1(vis, v.visual), "val_visual_psnr": psnr(vis, v.visual)}
        if len(v.origins):
            tm = tactile_patch_metrics(cut(tac, v.origins), v.gx, v.gy, v.contact)
            out.update({f"val_{k}": x for k, x in tm.items()})
        return out

    def sample_sheet(self, path: Path) -> None:
        v = self.val
        vis, tac = self.predict(v)
        vis, tac, sketch, real = (t.cpu() for t in (vis, tac, v.sketch, v.visual))
        gx, gy = tac[0, 0].numpy(), tac[0, 1].numpy()
        tiles = [label(to_uint8(sketch[0, 0].numpy()), "sketch"),
                 label(to_uint8(real[0].permute(1, 2, 0).numpy()), "real visual"),
                 label(to_uint8(vis[0].permute(1, 2, 0).numpy()), f"step {self.step}: visual"),
                 label(normal_tile(gx, gy), "normal map"),
                 label(friction_tile(gx, gy, self.data.friction_scale), "friction map")]
        ft = self.data.g.full_tactile
        if ft is not None:
            x, y = v.origin
            s = self.data.side
            tiles.append(label(normal_tile(ft.gx[y:y + s, x:x + s], ft.gy[y:y + s, x:x + s]), "true normal"))
        save_png(path, grid([tiles]))

    # --- the loop -------------------------------------------------------------------------------------------
    def run(self, until: int | None = None, should_stop: Callable[[], bool] | None = None) -> dict:
        """Train to `until` (default: the schedule's end). `should_stop()` is asked after every step (a signal
        flag); when it says yes, the run saves its latest checkpoint at once so `--resume` continues from there."""
        t = self.cfg.train
        end = min(until if until is not None else t.steps, t.steps)
        bar = None
        if self.main and t.progress:
            bar = Progress(total=end, initial=self.step, desc=f"{self.cfg.method}:{self.data.g.material}")
        self.method.train()
        t0 = time.perf_counter()
        first = self.step
        # the steady step time: the second half's steps, without the first half's warm-up or the end's checkpoint
        mid, at_mid, at_last = first + (end - first) // 2, None, None
        self.stopped = False
        while self.step < end:
            if self.step == mid:
                at_mid = self.train_seconds + time.perf_counter() - t0
            if should_stop is not None and self._agree_to_stop(should_stop()):
                self.stopped = True
                self.train_seconds += time.perf_counter() - t0
                t0 = time.perf_counter()
                self.save("latest")
                log.info("stopped at step %d on request; --resume continues from there", self.step)
                break
            batch = self.data.batch(self.step, self.rank).to(self.device)
            o = self.cfg.optim
            factor = lr_factor(o.lr_policy, self.step, t.steps, o.decay_from)
            apply_lr(self.method.opts, factor)
            logs = self.method.step(batch, self.step)
            self.method.after_step(self.step)
            logs["lr_factor"] = factor
            self.step += 1
            if self.step == end:
                at_last = self.train_seconds + time.perf_counter() - t0
            if self.step % t.log_every == 0 or self.step == end:
                if self.dist is not None:
                    logs = {k: average_scalar(x, self.dist.world) for k, x in logs.items()}
                self.history.append({"step": self.step, **logs})
                if bar is not None:
                    bar.losses_seen(logs)
            if bar is not None:
                bar.update(1)
            if self.step % t.val_every == 0 or self.step == end:
                self._validate_and_keep_best()
            if self.main and (self.step % t.sample_every == 0 or self.step == end):
                self.sample_sheet(self.out / "samples" / f"step_{self.step:05d}.png")
            if self.step % t.ckpt_every == 0 or self.step == end:
                self.train_seconds += time.perf_counter() - t0
                t0 = time.perf_counter()
                self.save("latest")
                if self.main:
                    curves_png(self.out / "curves.png", self.history, self.val_history)
        if bar is not None:
            bar.close()
        self.train_seconds += time.perf_counter() - t0
        done = self.step - first
        if at_mid is not None and self.step > mid:
            steady = ((at_last if at_last is not None else self.train_seconds) - at_mid) / (self.step - mid)
        else:
            steady = None
        summary = {"method": self.cfg.method, "garment": self.data.g.name, "data_profile": self.data.g.profile,
                   "pixel_pitch_mm": dataset_pitch_mm(self.data.g)[0], "step": self.step,
                   "crop": self.data.side, "friction_scale": self.data.friction_scale, **self.method.info,
                   "train_seconds": round(self.train_seconds, 1), "steps_this_session": done,
                   "seconds_per_step": round(self.train_seconds / max(self.step, 1), 4),
                   "seconds_per_step_steady": None if steady is None else round(steady, 4),
                   "val": self.val_history[-1] if self.val_history else None, "best_val_score": self.best,
                   "stopped_early": self.stopped, "machines": self.machines}
        if self.main:
            (self.out / "metrics.json").write_text(json.dumps({"train": summary}, indent=2))
        return summary

    def _agree_to_stop(self, mine: bool) -> bool:
        """Under torchrun every rank must stop at the same step, or the others wait forever in a collective."""
        if self.dist is None:
            return mine
        return average_scalar(float(mine), self.dist.world) > 0

    def _validate_and_keep_best(self) -> None:
        if not self.main:
            return
        v = self.validate()
        self.val_history.append(v)
        # Best = lowest validation tactile angular error (the headline metric) plus visual L1 in degrees-ish
        # units (x10), so a run that stops learning the image is not kept for its tactile alone.
        score = v.get("val_tactile_angle_deg", 0.0) + 10.0 * v["val_visual_l1"]
        if self.best is None or score < self.best:
            self.best = score
            save_checkpoint(self.out / "checkpoints" / "best.pt", self._payload())
