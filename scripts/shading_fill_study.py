"""How far the shading relief's background fill must reach: the runs scored with each fill, side by side.

The shading relief (trainer/models/shading_relief.py) fills the photo's background with the object's own
log-luminance nearby before its 11 x 11 filters, so the silhouette does not read as a cliff. Its fill, two normalised
Gaussian blurs of sigma FILL_SIGMA (8 px: 49 taps a pass), is most of the rule's cost in an exported graph, although
the filters reach only 5 px past the object. This scores each run under each fill: a Gaussian sigma in px, or `mean`
(the object's mean log-luminance, one number an image), the fit redone for each (it reads the same slopes), and writes
the tables and the `FIRST - X` intervals (the first fill named is the reference) with trainer.compare.report, plus the
torch time of the slopes alone at 512 px beside each fill. The run at the module's own FILL_SIGMA is scored through
the evaluation cache (stored for `vtkiosk eval --compare` to reuse); the others never touch it.

    .venv/bin/python scripts/shading_fill_study.py --fills 8 3 mean --relief shade-lift \
        --mirrors flip+transpose-energy --unseen-from data/hard640x24 --out docs/compare_1k/mirrors/shade_fill \
        runs/s68/KnitJacket/ours-txr-s8 runs/s68/KnitJacket/ours-txr-s9 ...
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from trainer import eval_cache  # noqa: E402
from trainer.compare import report  # noqa: E402
from trainer.evaluate import evaluate  # noqa: E402
from trainer.models import shading_relief as sr  # noqa: E402

OWN_SIGMA = sr.FILL_SIGMA   # the module's own fill, before any is swapped in


def mean_fill(visual: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The object's mean log-luminance in the background (0 for an image with no object)."""
    lum = sr.log_luma(visual)
    m = (mask > 0.5).to(visual.dtype)
    mean = (lum * m).sum((2, 3), keepdim=True) / m.sum((2, 3), keepdim=True).clamp_min(1.0)
    return lum * m + mean * (1 - m)


@contextmanager
def fill(name: str):
    """The shading relief with this fill for the duration (the module reads both names at call time)."""
    saved = sr.FILL_SIGMA, sr.log_luminance
    try:
        if name == "mean":
            sr.log_luminance = mean_fill
        else:
            sr.FILL_SIGMA = float(name)
        yield
    finally:
        sr.FILL_SIGMA, sr.log_luminance = saved


def slopes_ms(repeats: int = 20) -> float:
    """Median torch time (ms) of the slopes at 512 px: fill, log and the eight-filter bank's two outputs mixed."""
    g = torch.Generator().manual_seed(0)
    visual = torch.rand(1, 3, 512, 512, generator=g) * 2 - 1
    mask = torch.zeros(1, 1, 512, 512)
    mask[..., 64:448, 96:416] = 1
    kernel = torch.randn(2, 1, sr.KERNEL, sr.KERNEL, generator=g)
    times = []
    with torch.no_grad():
        for i in range(repeats + 3):
            t = time.perf_counter()
            sr.shading_slopes(visual, mask, kernel)
            if i >= 3:
                times.append(1e3 * (time.perf_counter() - t))
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--fills", nargs="+", default=["8", "3", "mean"],
                    help="Gaussian sigmas in px or `mean`; the first is the reference of the intervals")
    ap.add_argument("--relief", default="shade-lift", choices=("shade", "shade-lift"))
    ap.add_argument("--mirrors", default="none")
    ap.add_argument("--unseen-from", type=Path)
    ap.add_argument("--which", default="latest")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    for f in a.fills:
        if f != "mean" and not (f.replace(".", "", 1).isdigit() and float(f) > 0):
            ap.error(f"a fill is a positive sigma in px or `mean`; got {f!r}")
    torch.set_num_threads(1)
    evals, timing = [], {}
    for f in a.fills:
        label = f"fill-{f}"
        with fill(f):
            timing[label] = slopes_ms()
            for run in a.runs:
                print(f"{label}: {run}", flush=True)
                if f != "mean" and float(f) == OWN_SIGMA:   # the module's own: through the cache
                    e = eval_cache.scored(run, a.which, relief=a.relief, mirrors=a.mirrors, unseen_from=a.unseen_from)
                else:
                    e = evaluate(run, a.which, swap=False, relief=a.relief, mirrors=a.mirrors,
                                 unseen_from=a.unseen_from)
                e.result["trained_method"], e.result["method"] = e.result["method"], label
                evals.append(e)
    md, data = report(evals, f"fill-{a.fills[0]}")
    load = os.getloadavg()[0]   # the times are noise on a loaded machine: said beside them
    md += "\n\ntorch time of the slopes alone at 512 px (1 thread, median of 20, ms): " + ", ".join(
        f"{k} {v:.1f}" for k, v in timing.items()) + f" (1-min load average {load:.2f} on {os.cpu_count()} CPUs)\n"
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "compare.md").write_text(md)
    (a.out / "compare.json").write_text(json.dumps({**data, "slopes_ms": timing, "load_average": load,
                                                     "study_runs": [str(r) for r in a.runs]}, indent=2))
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
