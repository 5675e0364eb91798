"""The tactile D's R1 on a GPU before and after the channels-last fix, as one picture.

    python scripts/plot_gpu_r1.py [docs/compare_gpu/r1-diagnosis]

Reads the probe rows of the diverging run (`probe_before_fix.jsonl`, written by scripts/gpu_r1_probe.py) and the
fixed runs' logged R1 (`r1_history_after_fix.json`) and writes `r1_curves.png` beside them.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main() -> int:
    d = Path(sys.argv[1] if len(sys.argv) > 1 else "docs/compare_gpu/r1-diagnosis")
    probe = [json.loads(line) for line in (d / "probe_before_fix.jsonl").read_text().splitlines() if line.strip()]
    after = json.loads((d / "r1_history_after_fix.json").read_text())
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    steps = [r["step"] for r in probe]
    a.semilogy(steps, [r["r1_run"] for r in probe], "o-", label="R1 as the GPU run computed it")
    a.semilogy(steps, [r["r1_cpu64"] for r in probe], "s--", label="R1 of the same D and patches, CPU float64")
    a.set_title("before: SatinShirt 512 px, H100, channels-last D input")
    a.set_xlabel("step")
    a.set_ylabel("tactile D's R1 penalty")
    a.legend(fontsize=8)
    for garment, rows in sorted(after.items()):
        rows = [r for r in rows if r.get("d_tactile_r1") is not None]
        b.semilogy([r["step"] for r in rows], [r["d_tactile_r1"] for r in rows], label=garment)
    b.set_title("after: four garments, 768 px, H100, standard layout")
    b.set_xlabel("step")
    b.legend(fontsize=8)
    for ax in (a, b):
        ax.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    out = d / "r1_curves.png"
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
