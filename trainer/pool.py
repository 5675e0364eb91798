"""`vtkiosk eval --pool TABLE.json...`: one comparison from stored tables, for runs whose weights are gone.

A run's scores outlive its weights: `compare.json` keeps every run's figures, but not the per-unit sums the paired
hierarchical bootstrap resamples, and a weights folder does not survive a fresh machine. Pooling gives each stored
run one unit holding its score (trainer.bootstrap.single_unit), so the point estimates are the ones `--compare`
would print and the intervals resample garments and each method's seeds, not the touches and blocks within a run.
Where seeds vary more than places on the garment (the Fidelity II tables) that is the larger part of the spread;
docs/training.md compares the two intervals on the same runs.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from kiosk.contract.garment import same_garment
from trainer import target_plot
from trainer.bootstrap import single_unit
from trainer.compare import DIFF_METRICS, report
from trainer.evaluate import Evaluation

POOL_RESAMPLED = ("garments, then each method's seeds; one score per run (pooled from stored tables, which keep "
                  "no per-unit sums), so the places within a run are not resampled")
IDENTITY = ("method", "garment", "seed", "step", "crop", "weights", "checkpoint")


class PoolError(ValueError):
    """A stored table that cannot be pooled; the message names the file and what is wrong."""


def _scores(d: dict) -> dict[str, float]:
    return {k: float(d[k]) for k in DIFF_METRICS if target_plot.is_score(d.get(k))}


def load_runs(paths: list[Path], garments: list[str] | None = None) -> list[dict]:
    """Every run of the tables (on `garments`, when given), each once: a run in two tables (the same method,
    garment, seed, step, crop, weights and checkpoint) with the same scores is kept once; with other scores it is an
    error, since two runs would then be counted as one. The same seed trained again on another machine is such a
    pair; a check that takes one garment's runs from one table and another's from a second pools each part on its
    garments (`garments` leaves the others unread), then pools the parts."""
    seen: dict[tuple, tuple[dict, Path]] = {}
    out: list[dict] = []
    held: set[str] = set()
    for path in paths:
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise PoolError(f"{path}: cannot read a comparison table ({exc})") from exc
        runs = data.get("runs") if isinstance(data, dict) else None
        if not isinstance(runs, list) or not runs:
            raise PoolError(f"{path}: no 'runs' list; expected the compare.json of `vtkiosk eval --compare`")
        for i, r in enumerate(runs):
            if not isinstance(r, dict) or not all(isinstance(r.get(k), str) for k in ("method", "garment")):
                raise PoolError(f"{path}: run {i} has no method and garment")
            if not _scores(r):
                raise PoolError(f"{path}: run {i} ({r['method']} on {r['garment']}) has no finite score")
            held.add(r["garment"])
            if garments is not None and not any(same_garment(r["garment"], g) for g in garments):
                continue
            key = tuple(json.dumps(r.get(k)) for k in IDENTITY)
            if key in seen:
                first, where = seen[key]
                a, b = _scores(first), _scores(r)
                if a.keys() != b.keys() or any(not math.isclose(a[k], b[k], rel_tol=1e-9, abs_tol=1e-12) for k in a):
                    raise PoolError(f"{path}: run {i} ({r['method']} on {r['garment']}, seed {r.get('seed')}) is "
                                    f"also in {where} with other scores: two runs under one name; label one "
                                    f"(LABEL=RUN) when tabling it, or pool one of the tables")
                continue
            seen[key] = (r, Path(path))
            out.append(dict(r) | {"pooled_from": str(path)})
    missing = [g for g in dict.fromkeys(garments or ()) if not any(same_garment(h, g) for h in held)]
    if missing:
        raise PoolError(f"--garments names garment(s) no table holds: {', '.join(missing)} "
                        f"(garments: {', '.join(sorted(held))})")
    return out


def evaluation(r: dict) -> Evaluation:
    """A stored run as an Evaluation whose every metric (and reference row) is one unit."""
    refs = r.get("references") if isinstance(r.get("references"), dict) else {}
    return Evaluation(result=r, units={k: single_unit(k, v) for k, v in _scores(r).items()},
                      ref_units={n: {k: single_unit(k, v) for k, v in _scores(ref).items()}
                                 for n, ref in refs.items() if isinstance(ref, dict)})


def keep_rows(runs: list[dict], only: list[str] | None, ours: str) -> list[dict]:
    """The runs of the rows named in `only` (all when None). A table often holds treatments of one method beside
    each other (txr-ftl, txr-energy); the target check counts every other row as a competitor, so a check of one
    treatment against the other methods names its rows. A name no table holds is an error, not an empty row."""
    if only is None:
        return runs
    held = {r["method"] for r in runs}
    missing = [m for m in dict.fromkeys(only) if m not in held]
    if missing:
        raise PoolError(f"--only names row(s) no table holds: {', '.join(missing)} (rows: {', '.join(sorted(held))})")
    if ours not in only:
        raise PoolError(f"--only leaves out --ours {ours!r}: the intervals are taken for it")
    return [r for r in runs if r["method"] in only]


def pool(paths: list[Path], out_dir: Path, *, ours: str = "ours", n_boot: int = 2000,
         only: list[str] | None = None, garments: list[str] | None = None) -> tuple[str, dict]:
    """The table, intervals and target check of all runs in `paths` (of the rows in `only` and the garments in
    `garments`, when given); writes compare.md, compare.json and the target's picture (trainer.target_plot)."""
    runs = keep_rows(load_runs(paths, garments), only, ours)
    evals = [evaluation(r) for r in runs]
    md, data = report(evals, ours, n_boot=n_boot, resampled=POOL_RESAMPLED)
    names = ", ".join(str(p) for p in paths)
    rows = f" Rows kept: {', '.join(only)}." if only is not None else ""
    rows += f" Garments kept: {', '.join(garments)}." if garments is not None else ""
    md = (f"Pooled from {len(paths)} stored table(s) ({names}): {len(evals)} runs.{rows} Intervals resample "
          f"{POOL_RESAMPLED}.\n\n") + md
    data["pooled_from"] = [str(p) for p in paths]
    data["rows_kept"] = list(only) if only is not None else None
    data["garments_kept"] = list(garments) if garments is not None else None
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "compare.md").write_text(md)
    (out_dir / "compare.json").write_text(json.dumps(data, indent=2))
    drawn = target_plot.beside_table([e.result for e in evals], data, out_dir, ours)
    data["target_plot"] = str(drawn) if drawn else None
    return md, data
