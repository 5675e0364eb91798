"""`vtkiosk export --run RUN --out garment.vtb [--precision int8|fp16|fp32] [--sign-key KEY]`."""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from exporter.quiet import chatter_to
from trainer.models.mirror_modes import HELP as MIRROR_HELP, MODES as MIRROR_MODES
from trainer.relief_rules import HELP as RELIEF_HELP, RULES as RELIEF_RULES


def _sizes(text: str) -> list[tuple[int, int]]:
    out = []
    for item in text.split(","):
        item = item.strip().lower()
        try:
            w, h = (int(v) for v in item.split("x")) if "x" in item else (int(item), int(item))
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"sizes look like 512,768 or 1024x768; got {item!r}") from exc
        out.append((w, h))
    return out


def _levels(text: str) -> float:
    """An error bound in friction levels: finite and not negative (NaN would silently disable the check)."""
    try:
        v = float(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"a bound in friction levels, e.g. 2.0; got {text!r}") from exc
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"a bound in friction levels must be finite and >= 0; got {text!r}")
    return v


def _islands(text: str) -> tuple[str, ...]:
    from exporter.quantize import FP32_ISLANDS
    parts = tuple(t.strip() for t in text.split(",") if t.strip() and t.strip() != "none")
    bad = [t for t in parts if t not in FP32_ISLANDS]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown part(s) {', '.join(bad)}; choose from {', '.join(FP32_ISLANDS)}")
    return parts


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__)
    p.add_argument("--run", type=Path, required=True, help="a training run folder (vtkiosk train --out)")
    p.add_argument("--out", type=Path, required=True, help="bundle file to write (.vtb)")
    p.add_argument("--log", type=Path, default=None,
                   help="where the libraries' own output goes (default: OUT.log beside the bundle)")
    p.add_argument("--precision", choices=("int8", "fp16", "fp32"), default="int8")
    p.add_argument("--sizes", type=_sizes, default=[(512, 512), (768, 768)],
                   help="input sizes the kiosk may run, multiples of 256 (default 512,768); int8 is calibrated "
                        "at exactly these")
    p.add_argument("--sign-key", type=Path, default=None, help="Ed25519 private key (vtkiosk keys generate)")
    p.add_argument("--which", choices=("best", "latest"), default="best")
    p.add_argument("--calibration", choices=("minmax", "percentile", "entropy"), default="percentile",
                   help="int8 activation ranges: percentile (99.999th, default: measured best), minmax, entropy")
    p.add_argument("--int8-fp32", type=_islands, default=None, metavar="PARTS",
                   help="int8 only: graph parts kept in fp32, comma-separated from "
                        "pe,first-conv,heads,tactile-branch, or 'none' (default pe,first-conv,heads)")
    p.add_argument("--max-friction-mae", type=_levels, default=1.0,
                   help="refuse an int8 graph whose friction-map error exceeds this many levels (default 1)")
    p.add_argument("--max-friction-mae-garment", type=_levels, default=None, metavar="LEVELS",
                   help="also refuse an int8 graph whose friction-map error over the garment alone exceeds this "
                        "(the canvas figure counts the blank paper around the garment, where the error is 0; "
                        "default: no such bound)")
    p.add_argument("--force", action="store_true",
                   help="write the bundle even above --max-friction-mae / --max-friction-mae-garment")
    p.add_argument("--model-version", default=None,
                   help="the bundle's version (ordered as kiosk.bundle.version says; default YYYYMMDD-step)")
    p.add_argument("--display-name", default=None)
    p.add_argument("--relief", choices=RELIEF_RULES, default="none",
                   help=f"{RELIEF_HELP}; a shade rule is one more convolution in every graph, and auto's choice is "
                        "in the provenance; default none: as trained")
    p.add_argument("--mirrors", choices=tuple(MIRROR_MODES), default="none",
                   help=f"{MIRROR_HELP}; inside every graph, so the tactile latency grows with the passes; "
                        "default none")
    p.add_argument("--normalization", choices=("perceptual", "calibrated", "quantile"), default="perceptual",
                   help="friction mapping the bundle uses (docs/haptics.md); its constants are calibrated and stored")
    p.add_argument("--runs-root", type=Path, default=None,
                   help="record the run in the manifest relative to this folder (default: the working directory; "
                        "a run outside it is recorded as a hash of its path)")
    p.add_argument("--embed-weights", action="store_true",
                   help="each graph embeds its own tensors (the layout kiosks before exporter 0.3 read; about "
                        "twice the bytes) instead of sharing one weights file")
    return p


def main(argv: list[str], prog: str = "vtkiosk export") -> int:
    args = build_parser(prog).parse_args(argv)
    from exporter.export import ExportConfig, export_run
    from exporter.keys import load_private_key

    key = load_private_key(args.sign_key) if args.sign_key else None
    cfg = ExportConfig(precision=args.precision, sizes=args.sizes, which=args.which,
                       calibration_method=args.calibration, max_friction_mae=args.max_friction_mae,
                       max_friction_mae_garment=args.max_friction_mae_garment,
                       force=args.force, model_version=args.model_version, display_name=args.display_name,
                       normalization=args.normalization, runs_root=args.runs_root,
                       share_weights=not args.embed_weights, relief=args.relief,
                       mirrors=args.mirrors)
    if args.int8_fp32 is not None:
        cfg.fp32_islands = args.int8_fp32
    log_path = args.log or Path(str(args.out) + ".log")
    with chatter_to(log_path) as say:
        try:
            report = export_run(args.run, args.out, cfg, signing_key=key, progress=say)
        except Exception as exc:
            if getattr(exc, "user_facing", False):
                exc.args = (f"{exc} (library output: {log_path})",)
            raise
    m = report.manifest
    print(f"wrote {report.out}: {m.garment_id} {m.model_version}, {len(m.graphs)} graphs at {args.precision}, "
          f"{'signed' if key else 'UNSIGNED (kiosks refuse it without --allow-unsigned)'}")
    return 0
