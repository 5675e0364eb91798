"""Checkpoints the exporter can load without the trainer's training state.

`RUN/checkpoints/{latest,best}.pt` = {"generator": state_dict, "generator_class": "TwoBranchUNet" |
"ResnetGenerator" | "Pix2PixHDGenerator" | "SpadeGenerator", "model_config": {...}, "method": name, "step": n, "friction_scale": float, "info": {...
perceptual backbone / substitutes used ...}, "config": the run config as a dict, "machines": the CPU and kernel path
of each stretch it was trained in (trainer.provenance), "train_state": optimizers,
discriminators, history (for resume only)}. Written atomically (temp file + rename). A missing or unreadable
checkpoint is an error the operator sees - never silently random weights (the published code's defect).
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import torch
from torch import nn

from trainer.errors import TrainerError

log = logging.getLogger(__name__)


class CheckpointError(TrainerError):
    """A run without a usable checkpoint; the message names the file."""


def generator_classes() -> dict[str, type]:
    from trainer.models.generator import TwoBranchUNet
    from trainer.models.pix2pix_generator import ResnetGenerator
    from trainer.models.pix2pixhd_generator import Pix2PixHDGenerator
    from trainer.models.spade_generator import SpadeGenerator
    return {"TwoBranchUNet": TwoBranchUNet, "ResnetGenerator": ResnetGenerator,
            "Pix2PixHDGenerator": Pix2PixHDGenerator, "SpadeGenerator": SpadeGenerator}


def save_checkpoint(path: Path, payload: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)


def read_checkpoint(run_dir: Path, which: str = "best") -> dict:
    if which not in ("best", "latest"):
        raise CheckpointError(f"which must be 'best' or 'latest'; got {which!r}")
    path = Path(run_dir) / "checkpoints" / f"{which}.pt"
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint (train the run first, or pick --which latest)")
    try:
        ck = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the same operator-facing problem
        raise CheckpointError(f"{path}: unreadable checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(ck, dict) or "generator" not in ck or "model_config" not in ck:
        raise CheckpointError(f"{path}: not a vtkiosk checkpoint (no generator / model_config)")
    return ck


def bake_parametrizations(net: nn.Module) -> nn.Module:
    """Replace weight parametrizations (GauGAN's spectral norm) by the weights they compute, in place.

    A loaded generator is only run, never trained: in eval mode spectral norm still recomputes sigma on every call
    (an `aten::vdot` ONNX cannot export); baked weights give the same outputs.
    """
    from torch.nn.utils import parametrize

    for module in net.modules():
        if parametrize.is_parametrized(module):
            for name in list(module.parametrizations.keys()):
                parametrize.remove_parametrizations(module, name, leave_parametrized=True)
    return net


# SPADE's parameter-free norm once kept running statistics that evaluation used; training never did (it normalised
# with each batch's own), so a GauGAN generator trained then is the same network without those buffers.
_SPADE_RUNNING_STATS = (".norm.running_mean", ".norm.running_var", ".norm.num_batches_tracked")


def _drop_spade_running_stats(name: str, state: dict) -> dict:
    if name != "SpadeGenerator":
        return state
    kept = {k: v for k, v in state.items() if not k.endswith(_SPADE_RUNNING_STATS)}
    if len(kept) < len(state):
        log.info("checkpoint: SPADE running statistics dropped (%d buffers): evaluated with batch statistics, "
                 "as trained", len(state) - len(kept))
    return kept


WEIGHTS = ("average", "raw", "probe")


def generator_state(ck: dict, weights: str = "average") -> dict:
    """G's weights in a checkpoint: `average` = what is validated and exported (the EMA when the run kept one, else
    the raw weights); `raw` = the optimiser's own weights, kept for resuming, so the EMA can be measured as an
    ablation without another run; `probe` = the second average of a run trained with `train.ema_probe_ramp`."""
    if weights not in WEIGHTS:
        raise CheckpointError(f"weights must be one of {', '.join(WEIGHTS)}; got {weights!r}")
    if weights == "average":
        return ck["generator"]
    key = "generator" if weights == "raw" else "ema_probe"
    try:
        return ck["train_state"]["method"][key]
    except (KeyError, TypeError):
        if weights == "probe":
            raise CheckpointError("the checkpoint holds no probe average (trained without train.ema_probe_ramp, or "
                                  "an exported or compacted checkpoint); score its average instead") from None
        raise CheckpointError("the checkpoint holds no raw weights (no training state: an exported or compacted "
                              "checkpoint); score its average instead") from None


def load_generator(run_dir: Path, which: str = "best", weights: str = "average") -> tuple[nn.Module, dict]:
    """The trained generator in eval mode, and info: method, step, model_config, generator_class, friction_scale,
    info (perceptual backbone etc.), path, weights. Raises CheckpointError on anything missing or mismatched."""
    ck = read_checkpoint(run_dir, which)
    classes = generator_classes()
    name = ck.get("generator_class", "TwoBranchUNet")
    if name not in classes:
        raise CheckpointError(f"{run_dir}: unknown generator class {name!r}")
    try:
        state = generator_state(ck, weights)
    except CheckpointError as exc:
        raise CheckpointError(f"{run_dir}/checkpoints/{which}.pt: {exc}") from None
    try:
        net = classes[name].from_config(ck["model_config"])
        state = {k.removeprefix("module."): v for k, v in state.items()}
        net.load_state_dict(_drop_spade_running_stats(name, state), strict=True)
    except (RuntimeError, TypeError, KeyError) as exc:
        raise CheckpointError(f"{run_dir}/checkpoints/{which}.pt: weights do not fit the model ({exc})") from exc
    net.eval()
    bake_parametrizations(net)
    info = {k: ck.get(k) for k in ("method", "step", "model_config", "generator_class", "friction_scale", "info",
                                   "garment", "crop", "pixel_pitch_mm", "machines")}
    info["path"] = str(Path(run_dir) / "checkpoints" / f"{which}.pt")
    info["weights"] = weights
    return net, info
