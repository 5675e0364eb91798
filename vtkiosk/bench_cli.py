"""`vtkiosk bench infer|e2e|e2e-compare|haptics|threads`: route to the benchmark that owns each measurement.

`infer` measures bundles (and PyTorch eager beside them, when torch is installed), so it lives on the exporter side;
`e2e` drives a running kiosk daemon and must never import torch, so it lives in `kiosk/`. Imported lazily for that
reason, as is `e2e-compare` (two e2e runs' JSON side by side). `haptics` uses the synthetic fabrics' truth
(trainer), so it lives on the exporter side too. `threads` times bundles in worker processes as `infer` does, so it
sits beside it (it imports no torch).
"""
from __future__ import annotations

import importlib

SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "infer": ("exporter.bench.infer", "latency, memory and error of a bundle's graphs per size x precision"),
    "e2e": ("kiosk.bench.e2e", "stroke end -> friction frame committed / visual shown, against a live daemon"),
    "e2e-compare": ("kiosk.bench.e2e_ratio", "two `bench e2e` settings side by side: latency ratios, 95 % intervals"),
    "haptics": ("exporter.bench.haptics", "felt texture period, contrast and fabric distinguishability at true scale"),
    "threads": ("exporter.bench.threads", "engine session settings and preview/refine thread splits on this CPU"),
}


def main(argv: list[str], prog: str = "vtkiosk bench") -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: {prog} {{{','.join(SUBCOMMANDS)}}} [options]\n")
        for name, (_, summary) in SUBCOMMANDS.items():
            print(f"  {name:11s} {summary}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in SUBCOMMANDS:
        print(f"{prog}: unknown benchmark {name!r} (choose from {', '.join(SUBCOMMANDS)})")
        return 2
    module = importlib.import_module(SUBCOMMANDS[name][0])
    return int(module.main(rest, prog=f"{prog} {name}") or 0)
