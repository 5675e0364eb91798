"""`vtkiosk data synth|show|check`: make, look at and validate garment datasets (no torch needed)."""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from kiosk.contract.errors import InputError


def _frame(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"frame must look like 1280x960; got {text!r}") from exc
    return w, h


def build_parser(prog: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__)
    sub = parser.add_subparsers(dest="action", required=True)
    synth = sub.add_parser("synth", help="generate synthetic garments in the TouchClothing layout")
    synth.add_argument("--out", type=Path, required=True, help="dataset folder to write")
    synth.add_argument("--garments", type=int, default=6, help="number of garments (default 6: every fabric)")
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument("--frame", type=_frame, default=(1280, 960), help="camera frame WxH (default 1280x960)")
    synth.add_argument("--profile", choices=("hard", "easy"), default="hard",
                       help="hard (default): sparse touches (1/6 of the frame), prints, folds, lamp, camera model, "
                            "registration jitter; easy: the generator before profiles, bit for bit (docs/data.md)")
    synth.add_argument("--only", default=None, metavar="NAME[,NAME...]",
                       help="write only these garments of the set (material names, e.g. DenimShorts), exactly as "
                            "the whole set would have them: each garment has its own seed")
    synth.add_argument("--sheets", type=Path, default=None, help="also write one contact sheet per garment here")
    synth.add_argument("--no-progress", action="store_true")
    show = sub.add_parser("show", help="write a contact sheet of a garment (or of every garment in a dataset)")
    show.add_argument("--garment", type=Path, required=True, help="garment folder, or a dataset folder")
    show.add_argument("--out", type=Path, required=True,
                      help="PNG path for one garment; a folder when --garment is a dataset")
    show.add_argument("--tile-width", type=int, default=480)
    check = sub.add_parser("check", help="validate dataset folders and print a summary")
    check.add_argument("data", type=Path, help="garment folder or dataset folder")
    return parser


def _show(garment: Path, out: Path, tile_width: int) -> list[Path]:
    from trainer.data.contact_sheet import write_contact_sheet
    from trainer.data.touchclothing import FOLDER_RE, find_garments, load_garment

    roots = find_garments(garment)
    if FOLDER_RE.match(Path(garment).name):
        targets = [(roots[0], out if out.suffix else out / f"{roots[0].name}.png")]
    else:
        targets = [(r, out / f"{r.name}.png") for r in roots]
    return [write_contact_sheet(load_garment(r), o, tile_width=tile_width) for r, o in targets]


def main(argv: list[str], prog: str = "vtkiosk data") -> int:
    args = build_parser(prog).parse_args(argv)
    if args.action == "synth":
        from trainer.data.synthetic import generate_dataset

        if args.garments < 1:
            raise InputError(f"--garments must be at least 1; got {args.garments}")
        t0 = time.perf_counter()
        try:
            only = None if args.only is None else [n.strip() for n in args.only.split(",") if n.strip()]
            paths = generate_dataset(args.out, garments=args.garments, seed=args.seed, frame=args.frame,
                                     progress=not args.no_progress, profile=args.profile, only=only)
        except ValueError as exc:
            raise InputError(str(exc)) from exc
        print(f"wrote {len(paths)} garment(s) ({args.profile} profile) to {args.out} in "
              f"{time.perf_counter() - t0:.1f} s")
        if args.sheets is not None:
            for p in _show(args.out, args.sheets, 480):
                print(f"contact sheet: {p}")
        return 0
    if args.action == "show":
        for p in _show(args.garment, args.out, args.tile_width):
            print(f"contact sheet: {p}")
        return 0
    from trainer.data.check import check_dataset, format_reports

    reports = check_dataset(args.data)
    print(format_reports(reports))
    return 0 if all(r.ok for r in reports) else 1
