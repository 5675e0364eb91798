"""`vtkiosk <command> ...`: dispatch to the subsystem that owns the command, importing only that one.

Lazy on purpose: `vtkiosk serve` must never import torch, so the table below names modules as strings and
only the invoked command's module is imported. Each module offers `main(argv: list[str], prog: str) -> int`.
Expected failures (exceptions with a true `user_facing` attribute, or OS errors such as a missing file) become
one line on stderr and exit status 2; anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import importlib
import sys

# command -> (module, one-line summary)
COMMANDS: dict[str, tuple[str, str]] = {
    "data": ("trainer.data.cli", "synthesise, show and check garment datasets (TouchClothing layout)"),
    "train": ("trainer.cli", "train a garment model (ours, baselines, ablations)"),
    "eval": ("trainer.eval_cli", "evaluate runs and compare methods"),
    "export": ("exporter.cli", "export a trained run as a signed ONNX bundle"),
    "keys": ("exporter.keys_cli", "generate an operator signing key pair"),
    "bundle": ("kiosk.bundle.cli", "inspect, verify, install, activate and roll back bundles"),
    "bench": ("vtkiosk.bench_cli", "speed-against-error benchmarks (infer, e2e, e2e-compare, haptics, threads)"),
    "serve": ("kiosk.service.cli", "run the kiosk daemon"),
    "fleet": ("kiosk.fleet.cli", "publish bundles to a TUF update repository; sync a kiosk from it"),
    "device": ("firmware_bridge.cli", "probe, emulate and benchmark the haptic bridge"),
    "study": ("kiosk.study.cli", "plan, run and analyse haptic and visual A/B user studies"),
    "demo": ("vtkiosk.demo", "the main job: the kiosk on the trained demo catalogue with the emulated device"),
    "catalogue": ("vtkiosk.catalogue", "pack trained runs into the demo catalogue, check the committed one"),
}


def _usage() -> str:
    width = max(len(c) for c in COMMANDS)
    lines = ["usage: vtkiosk <command> [options]", "", "commands:"]
    lines += [f"  {c.ljust(width)}  {summary}" for c, (_, summary) in COMMANDS.items()]
    lines += ["", "`vtkiosk <command> --help` for a command's options."]
    return "\n".join(lines)


def is_user_facing(exc: BaseException) -> bool:
    """Errors an operator can act on: our own flagged errors and OS-level failures (missing file, no permission)."""
    return bool(getattr(exc, "user_facing", False)) or isinstance(exc, OSError)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        print(f"vtkiosk: unknown command {command!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, _ = COMMANDS[command]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        print(f"vtkiosk {command}: not available in this installation ({exc})", file=sys.stderr)
        return 2
    try:
        return int(module.main(rest, prog=f"vtkiosk {command}") or 0)
    except KeyboardInterrupt:
        print(f"vtkiosk {command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the one place that turns expected errors into one line
        if is_user_facing(exc):
            print(f"vtkiosk {command}: error: {exc}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    raise SystemExit(main())
