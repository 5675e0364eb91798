"""`vtkiosk study run|start|status|stop|export|report`: run and analyse A/B haptic user studies.

- run:    start the kiosk daemon in study mode (`--config study.yaml`); the page is served at /study.
- start:  the operator starts (or resumes) a participant's session on the running study (control socket).
- status: what the running study is doing; stop: end the current session early (its trials stay pending).
- export: one row per trial as CSV; report: the statistics (text, `--json`, `--plot`).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _parser(prog: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="action", required=True)

    run = sub.add_parser("run", help="serve the study: the kiosk daemon in study mode")
    run.add_argument("--config", type=Path, required=True, help="study YAML (see configs/study.example.yaml)")
    run.add_argument("--port", type=int, default=None, help="override the page's port (0 = any free port)")
    run.add_argument("--control-socket", type=Path, default=None, help="override the operator control socket")
    run.add_argument("--device", choices=("emulated",), default=None,
                     help="use the in-process emulated haptic device (no hardware)")

    def _target(p: argparse.ArgumentParser) -> None:
        g = p.add_mutually_exclusive_group(required=True)
        g.add_argument("--config", type=Path, help="the study YAML the running study was started with")
        g.add_argument("--socket", type=Path, help="the daemon's control socket")
        p.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for the daemon's answer")

    start = sub.add_parser("start", help="start or resume a participant's session (operator side)")
    start.add_argument("--participant", required=True, help="the participant's code (never a name)")
    start.add_argument("--new-session", action="store_true",
                       help="start another session for this participant (an unfinished last session is closed "
                            "as abandoned; its answers stay in the log)")
    _target(start)
    _target(sub.add_parser("status", help="the running study's state"))
    _target(sub.add_parser("stop", help="end the current session early (unanswered trials stay pending)"))

    export = sub.add_parser("export", help="one row per trial, PsychoPy-style wide CSV")
    export.add_argument("--log", type=Path, required=True)
    export.add_argument("--out", type=Path, required=True)

    report = sub.add_parser("report", help="preference rates, intervals, tests, breakdowns, plot")
    report.add_argument("--log", type=Path, required=True)
    report.add_argument("--json", type=Path, default=None, help="write the full report as JSON here")
    report.add_argument("--plot", type=Path, default=None, help="write the bar chart (PNG/PDF/SVG) here")
    report.add_argument("--bootstrap", type=int, default=10000, help="bootstrap resamples over participants")
    report.add_argument("--seed", type=int, default=0, help="bootstrap seed (the report is reproducible)")
    return parser


def _socket_of(args: argparse.Namespace) -> Path:
    if args.socket is not None:
        return args.socket
    from kiosk.study.config import load_study_config
    from kiosk.study.runtime import control_socket_of

    return control_socket_of(load_study_config(args.config))


def _control(args: argparse.Namespace, request: dict) -> int:
    from kiosk.ops.control import send_control

    reply = send_control(_socket_of(args), request, timeout_s=args.timeout)
    if not reply.get("ok"):
        print(f"error: {reply.get('error', 'the daemon refused the request')}", file=sys.stderr)
        return 2
    reply.pop("ok", None)
    print(json.dumps(reply, indent=2))
    return 0


def main(argv: list[str], prog: str = "vtkiosk study") -> int:
    args = _parser(prog).parse_args(argv)
    if args.action == "export":
        from kiosk.study.export import export_csv

        n = export_csv(args.log, args.out)
        print(f"wrote {n} trial row(s) to {args.out}")
        return 0
    if args.action == "report":
        from kiosk.study.report import format_text, plot, report_log, write_json

        rep = report_log(args.log, resamples=args.bootstrap, seed=args.seed)
        print(format_text(rep))
        if args.json:
            write_json(rep, args.json)
            print(f"\nwrote {args.json}")
        if args.plot:
            plot(rep, args.plot)
            print(f"wrote {args.plot}")
        return 0
    if args.action == "start":
        return _control(args, {"op": "study.start", "participant": args.participant,
                               "new_session": bool(args.new_session)})
    if args.action in ("status", "stop"):
        return _control(args, {"op": f"study.{args.action}"})
    from kiosk.study.runtime import run_study

    return run_study(args.config, port=args.port, control_socket=args.control_socket, device=args.device)
