"""Seed ensembles: several seeds of one garment and recipe averaged at test time, scored beside each seed alone.

A seed's relief away from the training touches is one draw of it, as a mirrored view of the sketch is; test-time
mirroring (trainer/models/mirror_average.py) averages the views of one seed, and this averages them over seeds too
(`others`), the `-energy` mode giving the mean's fine relief back the plain view's strength. The runs are taken in
the order given and cut into disjoint groups of each `--sizes` (4 runs, sizes 2 4: the first two, the last two,
all four); every run is also scored alone, through the evaluation cache, so the singles are the tables' own rows.
The largest size is `ours` of the intervals (`ens-N - X`). A group costs its size times the views in generator
passes a frame (said under the table); an ensemble's rows are never cached. `--beside` adds other methods' runs
(`[LABEL=]RUN[@...]`, as `vtkiosk eval --compare` takes them; cached), so the target check reads the ensemble
against them too.

    .venv/bin/python scripts/seed_ensemble_study.py --sizes 2 4 --relief lift --mirrors flip+transpose-energy \
        --unseen-from data/hard640x24 --out docs/compare_1k/mirrors/ensemble_kn \
        runs/s68/KnitJacket/ours-txr-s8 runs/s68/KnitJacket/ours-txr-s9 \
        runs/s70/KnitJacket/ours-txr-s10 runs/s70/KnitJacket/ours-txr-s11
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer import eval_cache  # noqa: E402
from trainer.compare import parse_labelled, report  # noqa: E402
from trainer.evaluate import evaluate  # noqa: E402
from trainer.models.mirror_modes import MODES  # noqa: E402
from trainer.relief_rules import RULES  # noqa: E402


def groups(runs: list[Path], size: int) -> list[list[Path]]:
    """Disjoint consecutive groups of `size` runs; refused unless `size` divides the count."""
    if size < 2 or len(runs) % size:
        raise ValueError(f"an ensemble size must be 2 or more and divide the {len(runs)} runs; got {size}")
    return [runs[i:i + size] for i in range(0, len(runs), size)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="seeds of one garment and recipe, in the order to group them")
    ap.add_argument("--sizes", nargs="+", type=int, default=[2])
    ap.add_argument("--relief", default="lift", choices=RULES)
    ap.add_argument("--mirrors", default="flip+transpose-energy", choices=[m for m in MODES if m != "none"])
    ap.add_argument("--unseen-from", type=Path)
    ap.add_argument("--beside", nargs="+", default=[], metavar="[LABEL=]RUN[@...]",
                    help="other methods' runs to score beside, as `eval --compare` names them (as trained unless "
                         "an @ says otherwise)")
    ap.add_argument("--which", default="latest")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    if len(set(a.runs)) != len(a.runs):
        ap.error("a run is named twice")
    try:
        plan = {n: groups(a.runs, n) for n in sorted(set(a.sizes))}
    except ValueError as exc:
        ap.error(str(exc))
    try:
        beside, labels = parse_labelled(a.beside) if a.beside else ([], {})
    except ValueError as exc:
        ap.error(str(exc))
    torch.set_num_threads(1)
    evals = []
    for spec in beside:
        print(f"beside: {spec}", flush=True)
        e = eval_cache.scored(spec.path, a.which, spec.weights, relief=spec.relief, mirrors=spec.mirrors,
                              unseen_from=a.unseen_from)
        name = labels.get(spec, e.result["method"] + "".join(f"-{t}" for t in spec.tags))   # as eval --compare
        if name != e.result["method"]:
            e.result["trained_method"], e.result["method"] = e.result["method"], name
        evals.append(e)
    for run in a.runs:
        print(f"single: {run}", flush=True)
        e = eval_cache.scored(run, a.which, relief=a.relief, mirrors=a.mirrors, unseen_from=a.unseen_from)
        e.result["trained_method"], e.result["method"] = e.result["method"], "single"
        evals.append(e)
    for n, gs in plan.items():
        for g in gs:
            print(f"ens-{n}: {' + '.join(map(str, g))}", flush=True)
            e = evaluate(g[0], a.which, swap=False, relief=a.relief, mirrors=a.mirrors, unseen_from=a.unseen_from,
                         members=g[1:])
            e.result["trained_method"], e.result["method"] = e.result["method"], f"ens-{n}"
            evals.append(e)
    ours = f"ens-{max(plan)}"
    md, data = report(evals, ours)
    views = 1 + len(MODES[a.mirrors])
    md += (f"\n\nGenerator passes a frame: single {views}, " + ", ".join(f"ens-{n} {n * views}" for n in plan)
           + f" (mirrors {a.mirrors}, relief {a.relief}).\n")
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "compare.md").write_text(md)
    (a.out / "compare.json").write_text(json.dumps({**data, "study_runs": [str(r) for r in a.runs],
                                                     "sizes": sorted(plan), "passes_per_view_set": views},
                                                    indent=2))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
