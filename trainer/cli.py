"""`vtkiosk train`: train one garment (or a catalogue, one garment after the other) with one method.

Light at import time (argparse only); torch is imported inside `main`. Multi-GPU for one garment: run the same
command under `torchrun --nproc_per_node=N -m trainer.cli ...`. A catalogue on a cluster: one job per garment
(Slurm job array; see docs/training.md).
"""
from __future__ import annotations

import argparse
import logging
import shlex
import sys
from pathlib import Path


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description="Train a visual-tactile garment model.")
    p.add_argument("--data", required=True, type=Path, help="dataset folder (or one garment folder)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--garment", help="garment name (material, e.g. DenimShorts) or folder name")
    which.add_argument("--all", action="store_true", help="every garment in --data, one after the other")
    which.add_argument("--index", type=int, help="the N-th garment in --data (0-based; for Slurm job arrays)")
    from trainer.config import PRESETS_DIR
    from trainer.methods import METHODS
    p.add_argument("--method", default="ours", help=", ".join(METHODS))
    presets = ", ".join(sorted(f.stem for f in PRESETS_DIR.glob("*.yaml")))
    p.add_argument("--preset", default="cpu", help=f"{presets}, or a path to a YAML preset")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one config value (repeatable), e.g. --set train.steps=100")
    p.add_argument("--out", required=True, type=Path,
                   help="run folder (with --all/--index: a parent folder; runs go to OUT/<garment>/<method>)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its latest checkpoint")
    p.add_argument("--steps", type=int, help="shorthand for --set train.steps=N")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="also log what is set up (substitute losses, resume point); default: progress and problems")
    return p


def pick_garments(args) -> list[Path]:
    from trainer.data.touchclothing import DatasetError, find_garment, find_garments
    found = find_garments(args.data)
    if args.all:
        return found
    if args.index is not None:
        if not 0 <= args.index < len(found):
            raise DatasetError(f"--index {args.index} out of range: {args.data} holds {len(found)} garments")
        return [found[args.index]]
    if args.garment is None:
        if len(found) == 1:
            return found
        raise DatasetError(f"{args.data} holds {len(found)} garments; name one with --garment or pass --all")
    return [find_garment(args.data, args.garment)]


def main(argv: list[str], prog: str = "vtkiosk train") -> int:
    args = build_parser(prog).parse_args(argv)
    args.argv = list(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    from trainer.config import load_config
    overrides = list(args.overrides) + ([f"train.steps={args.steps}"] if args.steps else [])
    cfg0 = load_config(args.preset, overrides=overrides, method=args.method)
    from trainer.methods import get_method
    get_method(cfg0.method)  # unknown names fail before any data is read
    garments = pick_garments(args)
    from kiosk.ops.signals import on_signals
    from trainer.distributed import cleanup, init_from_env
    dist = init_from_env()
    with on_signals() as signals:
        try:
            return _train_all(args, garments, overrides, dist, signals)
        finally:
            cleanup()


def _train_all(args, garments, overrides, dist, signals) -> int:
    """Train each garment in turn; a stop signal ends the current run at its next step, with a checkpoint."""
    from trainer.config import load_config
    from trainer.data.touchclothing import parse_folder_name
    from trainer.loop import Trainer
    for g in garments:
        cfg = load_config(args.preset, overrides=overrides, method=args.method)
        out = args.out if len(garments) == 1 and not args.all else \
            args.out / parse_folder_name(g.name)[0] / cfg.method
        if len(garments) == 1 and args.index is not None:
            out = args.out / parse_folder_name(g.name)[0] / cfg.method
        trainer = Trainer(cfg, g, out, resume=args.resume, dist=dist)
        if (dist is None or dist.main) and not args.resume:
            # how this run was made, as typed (the demo catalogue records it beside the packed model)
            (out / "command.txt").write_text(shlex.join(["vtkiosk", "train", *args.argv]) + "\n")
        summary = trainer.run(should_stop=lambda: signals.stop)
        if dist is None or dist.main:
            val = summary.get("val") or {}
            print(f"{g.name} [{cfg.method}] step {summary['step']}: "
                  + ", ".join(f"{k}={v:.4g}" for k, v in val.items() if k != "step")
                  + f" ({summary['seconds_per_step']} s/step) -> {out}")
        if summary["stopped_early"]:
            print(f"stopped by signal at step {summary['step']}; continue with --resume --out {out}",
                  file=sys.stderr)
            return 128 + (signals.stop_signal or 15)  # unfinished: a scheduler may requeue the job
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:], prog="python -m trainer.cli"))
