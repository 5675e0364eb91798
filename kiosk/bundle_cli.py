"""`vtkiosk bundle inspect|verify FILE`: look into a bundle; check it the way a kiosk does before use."""
from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path


def _summary(bundle) -> str:
    m = bundle.manifest
    lines = [f"bundle      {m.garment_id} ({m.display_name}) model {m.model_version}, method {m.method}",
             f"created     {m.created_at} by exporter {m.exporter_version}",
             f"friction    scale {m.friction_scale:g} ({m.friction_normalization}), pitch {m.pixel_pitch_mm} mm/px",
             f"panel       {m.panel_size[0]}x{m.panel_size[1]}",
             f"signed by   {bundle.key_id or 'NOT CHECKED'}"]
    for kind, g in m.graphs.items():
        sizes = ", ".join(f"{w}x{h}" for w, h in g.sizes)
        lines.append(f"graph       {kind:8} {g.precision:5} {g.file}  sizes {sizes}")
    for prec, errs in m.errors.items():
        against = "PyTorch" if prec == "fp32" else "fp32"
        lines.append(f"error       {prec:5} vs {against}: " + ", ".join(f"{k} {v:.4g}" for k, v in errs.items()))
    for k, v in m.metrics.items():
        lines.append(f"metric      {k} {v:.4g}")
    return "\n".join(lines)


def main(argv: list[str], prog: str = "vtkiosk bundle") -> int:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__)
    sub = parser.add_subparsers(dest="action", required=True)
    for name, text in (("inspect", "print the manifest summary (schema-checked, signature not required)"),
                       ("verify", "check signature, hashes, schema, and probe every graph in ONNX Runtime")):
        p = sub.add_parser(name, help=text)
        p.add_argument("file", type=Path)
        p.add_argument("--trusted-keys", type=Path, default=None, help="folder of trusted *.pub keys")
        p.add_argument("--allow-unsigned", action="store_true", help="development only: skip the signature")
        p.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    from kiosk.bundle import open_bundle
    from kiosk.signature import load_trusted_keys

    trusted = load_trusted_keys(args.trusted_keys) if args.trusted_keys else None
    allow_unsigned = args.allow_unsigned or (args.action == "inspect" and trusted is None)
    workdir = Path(tempfile.mkdtemp(prefix="vtkiosk-bundle-"))
    try:
        bundle = open_bundle(args.file, trusted, workdir=workdir, allow_unsigned=allow_unsigned)
        print(_summary(bundle))
        if args.action == "verify":
            from kiosk.probe import probe_bundle

            for r in probe_bundle(bundle, threads=args.threads):
                print(f"probe       {r.graph:8} {r.size[0]}x{r.size[1]} {r.precision}: loads in {r.load_ms:.0f} ms, "
                      f"runs in {r.run_ms:.0f} ms, outputs finite")
            print("verified    ok")
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return 0
