"""`vtkiosk eval --run RUN [--json OUT]`, `vtkiosk eval --compare RUN... --out DIR` and `vtkiosk eval --pool
TABLE.json... --out DIR`. Light imports; torch is imported inside `main` (and by --pool's table code)."""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from trainer.models.mirror_modes import HELP as MIRROR_HELP, MODES as MIRROR_MODES
from trainer.relief_rules import HELP as RELIEF_HELP, RULES


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description="Evaluate trained runs; compare methods.")
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--run", metavar="RUN[@raw|@probe]",
                      help="a run folder (from vtkiosk train --out); RUN@raw scores G's raw weights instead of their "
                           "moving average (train.ema), the EMA's ablation without another run; RUN@probe the second "
                           "average of a run trained with train.ema_probe_ramp")
    mode.add_argument("--compare", nargs="+", metavar="[LABEL=]RUN[@raw|@probe]",
                      help="several runs: table + sheets; LABEL=RUN names a run's row LABEL instead of its method "
                           "(a recipe variant beside the method it varies, e.g. ours-r1-10=runs/g/r1_10); RUN@raw "
                           "scores the run's raw weights, in rows named <method>-raw (RUN@probe: its probe average, "
                           "<method>-probe)")
    mode.add_argument("--pool", nargs="+", type=Path, metavar="TABLE.json",
                      help="one comparison from stored tables (compare.json of --compare), for runs whose weights "
                           "are gone: each run counts by its score, so intervals resample garments and seeds only")
    p.add_argument("--only", nargs="+", metavar="LABEL",
                   help="--pool: keep only these rows (method labels; --ours among them), e.g. one treatment of a "
                        "method and the methods it is checked against")
    p.add_argument("--garments", nargs="+", metavar="GARMENT",
                   help="--pool: read only these garments' runs (any name of one: SatinShirt, satin-shirt, its "
                        "folder), so a part of a check can come from one table and be pooled with the rest after")
    p.add_argument("--which", choices=("best", "latest"), default="best", help="checkpoint to evaluate")
    p.add_argument("--relief", choices=RULES, default="none",
                   help=f"before scoring, {RELIEF_HELP}; default none: as trained; with --compare, RUN@rms "
                        "calibrates one run only")
    p.add_argument("--mirrors", choices=tuple(MIRROR_MODES), default="none",
                   help=f"{MIRROR_HELP}; default none; with --compare, RUN@flip mirrors one run only")
    p.add_argument("--json", type=Path, help="also write the metrics here")
    p.add_argument("--out", type=Path, default=Path("compare"), help="output folder of --compare")
    p.add_argument("--no-swap", action="store_true", help="skip the unseen-sketch swap grid")
    p.add_argument("--unseen-from", type=Path, metavar="DATA",
                   help="take the unseen sketches (FB-SIFID unseen) from this dataset folder, every garment there "
                        "but one of the run's name, instead of the run's own dataset: more sketches, a narrower "
                        "interval (e.g. a larger set made by `vtkiosk data synth --garments 24` with the same seed "
                        "and frame); scored and stored apart from the plain scores")
    p.add_argument("--rescore", action="store_true",
                   help="--compare: score every run again instead of reusing the scores stored beside it "
                        "(RUN/eval/compare-<which>.*; reused only when checkpoint, data and scoring code are unchanged)")
    p.add_argument("--ours", default="ours", metavar="METHOD",
                   help="--compare: the method the 'METHOD - X' intervals are taken for (default ours; the first "
                        "run's method when no run has it)")
    p.add_argument("--bootstrap", type=int, default=2000, metavar="N",
                   help="--compare: bootstrap resamples of each interval (default 2000)")
    return p


def main(argv: list[str], prog: str = "vtkiosk eval") -> int:
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    if args.bootstrap < 100:
        parser.error(f"--bootstrap must be at least 100 for a 95 % interval; got {args.bootstrap}")
    if args.only is not None and args.pool is None:
        parser.error("--only keeps rows of a pooled table; it goes with --pool (with --compare, name the runs)")
    if args.garments is not None and args.pool is None:
        parser.error("--garments keeps garments of a pooled table; it goes with --pool "
                     "(with --compare, name the runs)")
    if args.unseen_from is not None:
        if args.pool is not None:
            parser.error("--unseen-from scores runs; a pooled table has its runs' scores already "
                         "(score each table with it, then pool)")
        from trainer.data.touchclothing import DatasetError, find_garments
        try:
            find_garments(args.unseen_from)
        except DatasetError as exc:
            parser.error(f"--unseen-from: {exc}")
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if args.pool is not None:
        from trainer.pool import PoolError, pool
        try:
            md, data = pool(args.pool, args.out, ours=args.ours, n_boot=args.bootstrap, only=args.only,
                            garments=args.garments)
        except PoolError as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            return 2
        if args.json is not None:
            args.json.write_text(json.dumps(data, indent=2))
        print(md)
        plot = f"; target plot: {data['target_plot']}" if data.get("target_plot") else ""
        print(f"table: {args.out / 'compare.md'}, {args.out / 'compare.json'}{plot}")
        return 0
    import torch
    torch.set_num_threads(min(torch.get_num_threads(), 4))
    if args.run is not None:
        from trainer.compare import parse_run, write_eval
        from trainer.evaluate import evaluate_run
        try:
            spec = parse_run(args.run, args.relief, args.mirrors)
        except ValueError as exc:
            parser.error(str(exc))
        result = evaluate_run(spec.path, args.which, swap=not args.no_swap, weights=spec.weights,
                              relief=spec.relief, mirrors=spec.mirrors, unseen_from=args.unseen_from)
        write_eval(spec.path, result, args.json)
        print(json.dumps(result, indent=2))
        return 0
    from trainer.compare import compare, parse_labelled
    try:
        runs, labels = parse_labelled(args.compare, args.relief, args.mirrors)
    except ValueError as exc:
        parser.error(str(exc))
    md, data = compare(runs, args.out, args.which, ours=args.ours, n_boot=args.bootstrap, cache=not args.rescore,
                       labels=labels, unseen_from=args.unseen_from)
    if args.json is not None:
        args.json.write_text(json.dumps(data, indent=2))
    print(md)
    plot = f"; target plot: {data['target_plot']}" if data.get("target_plot") else ""
    print(f"table: {args.out / 'compare.md'}, {args.out / 'compare.json'}{plot}; sheets: {', '.join(data['sheets'])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:], prog="python -m trainer.eval_cli"))
