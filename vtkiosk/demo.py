"""`vtkiosk demo`: the README's main job.

Lives in the `vtkiosk` package, the composition root: it may use the trainer and exporter to build its demo
assets, which `kiosk/` itself must never import. Assets are cached in the work folder, so a second run starts in
seconds. Today it makes the synthetic garment set and its contact sheets; the kiosk issues extend it to train and
export a demo bundle and serve it with the emulated device.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from trainer.data.touchclothing import find_garments, load_garment


def build_parser(prog: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=Path("out/demo"),
                        help="where demo assets are built and cached (default out/demo)")
    parser.add_argument("--garments", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rebuild", action="store_true", help="ignore the cache and rebuild everything")
    return parser


def main(argv: list[str], prog: str = "vtkiosk demo") -> int:
    args = build_parser(prog).parse_args(argv)
    from trainer.data.contact_sheet import write_contact_sheet
    from trainer.data.synthetic import generate_dataset

    data = args.workdir / f"synthetic-seed{args.seed}-n{args.garments}"
    stamp = data / ".complete"
    t0 = time.perf_counter()
    if args.rebuild or not stamp.exists():
        print(f"demo: generating {args.garments} synthetic garments in {data}")
        generate_dataset(data, garments=args.garments, seed=args.seed)
        stamp.write_text("ok\n")
    else:
        print(f"demo: reusing synthetic garments in {data}")
    sheets = args.workdir / "sheets"
    for root in find_garments(data):
        out = sheets / f"{root.name}.png"
        if args.rebuild or not out.exists():
            write_contact_sheet(load_garment(root), out)
        print(f"demo: contact sheet {out}")
    print(f"demo: ready in {time.perf_counter() - t0:.1f} s")
    return 0
