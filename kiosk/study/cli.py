"""`vtkiosk study ...`: plan, run and analyse A/B user studies (haptic and visual).

- plan:     participants needed for a given power, by simulating the clustered design the report analyses.
- run:      start the kiosk daemon in study mode (`--config study.yaml`); the page is served at /study.
- start:    the operator starts (or resumes) a participant's session on the running study (control socket).
- next:     release the waiting trial; skip: skip the familiarisation stage; withdraw: a participant withdraws.
- status:   what the running study is doing (`--watch`: the researcher's live view); stop: end the session early.
- export:   one row per trial as CSV; report: the statistics (text, `--json`, `--plot`); figure: studies side
            by side; export-page: a visual study as a self-contained web page for remote participants.
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
    status = sub.add_parser("status", help="the running study's state (--watch: the researcher's live view)")
    _target(status)
    status.add_argument("--watch", action="store_true", help="redraw every --interval seconds until Ctrl-C")
    status.add_argument("--interval", type=float, default=1.0)
    status.add_argument("--counts", action="store_true",
                        help="show the running preference counts (hidden by default, to avoid peeking)")
    _target(sub.add_parser("stop", help="end the current session early (unanswered trials stay pending)"))
    _target(sub.add_parser("next", help="release the waiting trial (its clock starts once it is on screen)"))
    _target(sub.add_parser("skip", help="skip the familiarisation stage (only the operator can)"))
    withdraw = sub.add_parser("withdraw", help="mark a participant withdrawn: left out of the report, nothing "
                                               "deleted (through the running study, or --log when none runs)")
    withdraw.add_argument("--participant", required=True)
    g = withdraw.add_mutually_exclusive_group(required=True)
    g.add_argument("--config", type=Path, help="the running study's YAML")
    g.add_argument("--socket", type=Path, help="the daemon's control socket")
    g.add_argument("--log", type=Path, help="the study log, when no study is running")
    withdraw.add_argument("--timeout", type=float, default=30.0)

    export = sub.add_parser("export", help="one row per trial, PsychoPy-style wide CSV")
    export.add_argument("--log", type=Path, required=True, action="append",
                        help="a study log; repeat for several kiosks of one study")
    export.add_argument("--out", type=Path, required=True)

    report = sub.add_parser("report", help="preference rates, intervals, tests, breakdowns, plot")
    report.add_argument("--log", type=Path, required=True, action="append",
                        help="a study log; repeat for several kiosks of one study")
    report.add_argument("--json", type=Path, default=None, help="write the full report as JSON here")
    report.add_argument("--plot", type=Path, default=None, help="write the bar chart (PNG/PDF/SVG) here")
    report.add_argument("--bootstrap", type=int, default=10000, help="bootstrap resamples over participants")
    report.add_argument("--seed", type=int, default=0, help="bootstrap seed (the report is reproducible)")

    figure = sub.add_parser("figure", help="several studies' bars side by side (the paper's layout)")
    figure.add_argument("--report", type=Path, required=True, action="append",
                        help="a report JSON (study report --json); repeat: visual study first, then haptic")
    figure.add_argument("--out", type=Path, required=True)

    page = sub.add_parser("export-page", help="a visual study as one self-contained HTML file for remote runs")
    page.add_argument("--config", type=Path, required=True, help="the visual study's YAML")
    page.add_argument("--out", type=Path, required=True, help="the HTML file to write")
    page.add_argument("--participant", action="append", default=None,
                      help="a participant code the page accepts (repeat); default: the config's codes list")
    page.add_argument("--post-url", default=None,
                      help="also POST every record (one JSON line) to this URL as it is written")

    pl = sub.add_parser("plan", help="participants needed: power by simulating the clustered design")
    pl.add_argument("--rate", action="append", required=True, metavar="COMPARISON=RATE",
                    help="expected preference for the reference in one comparison, e.g. pix2pixhd=0.767 (repeat)")
    pl.add_argument("--garments", type=int, default=5, help="test garments per participant (default 5)")
    pl.add_argument("--spread", type=float, default=0.1,
                    help="SD of the participants' own preference rates around the expected rate (default 0.1)")
    pl.add_argument("--power", type=float, default=0.8, help="target power for every comparison (default 0.8)")
    pl.add_argument("--participants", default="4-40:2", help="counts to try: 'A-B:STEP' or 'N,N,...'")
    pl.add_argument("--sims", type=int, default=4000, help="simulated studies per count (default 4000)")
    pl.add_argument("--seed", type=int, default=0)
    pl.add_argument("--json", type=Path, default=None)
    return parser


def _counts(text: str) -> list[int]:
    from kiosk.contract.errors import InputError

    try:
        if "-" in text:
            span, _, step = text.partition(":")
            a, b = (int(v) for v in span.split("-", 1))
            out = list(range(a, b + 1, int(step or 1)))
        else:
            out = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"--participants must be 'A-B:STEP' or 'N,N,...', got {text!r}") from None
    if not out or min(out) < 1 or len(out) > 200:
        raise InputError("--participants must give 1 to 200 counts, each at least 1")
    return out


def _rates(items: list[str]) -> dict[str, float]:
    from kiosk.contract.errors import InputError

    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            rate = float(value)
        except ValueError:
            rate = float("nan")
        if not sep or not name.strip() or not 0.0 < rate < 1.0:
            raise InputError(f"--rate must be COMPARISON=RATE with 0 < RATE < 1, e.g. pix2pixhd=0.767; got {item!r}")
        out[name.strip()] = rate
    return out


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


def _watch(args: argparse.Namespace) -> int:
    import time

    from kiosk.ops.control import send_control
    from kiosk.study.watch import format_status

    sock = _socket_of(args)
    tty = sys.stdout.isatty()
    try:
        while True:
            reply = send_control(sock, {"op": "study.status", "counts": bool(args.counts)}, timeout_s=args.timeout)
            if not reply.get("ok"):
                print(f"error: {reply.get('error', 'the daemon refused the request')}", file=sys.stderr)
                return 2
            text = format_status(reply)
            print(("\x1b[H\x1b[2J" if tty else "") + text + ("" if tty else "\n"), flush=True)
            if not args.watch:
                return 0
            time.sleep(max(0.2, args.interval))
    except KeyboardInterrupt:
        return 0


def main(argv: list[str], prog: str = "vtkiosk study") -> int:
    args = _parser(prog).parse_args(argv)
    if args.action == "plan":
        from kiosk.study.plan import format_plan, plan

        result = plan(_rates(args.rate), garments=args.garments, spread=args.spread, target=args.power,
                      participants=_counts(args.participants), sims=args.sims, seed=args.seed)
        print(format_plan(result))
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(result, indent=2) + "\n")
        return 0
    if args.action == "figure":
        from kiosk.study.report import StudyReportError, plot_studies

        reps = []
        for path in args.report:
            try:
                reps.append(json.loads(path.read_text()))
            except (OSError, ValueError) as exc:
                raise StudyReportError(f"cannot read report {path}: {getattr(exc, 'strerror', None) or exc}") \
                    from None
        plot_studies(reps, args.out)
        print(f"wrote {args.out}")
        return 0
    if args.action == "export-page":
        from kiosk.study.webpage import export_page

        n = export_page(args.config, args.out, participants=args.participant, post_url=args.post_url)
        print(f"wrote {args.out} ({n} participant code(s))")
        return 0
    if args.action == "withdraw" and args.log is not None:
        from kiosk.study.log import StudyLog, read_log

        study_id = read_log(args.log).records[0]["study_id"]
        with StudyLog.open(args.log, study_id) as lg:
            if args.participant not in {p for p, _ in lg.state.sessions}:
                print(f"error: participant {args.participant} has no session in {args.log}", file=sys.stderr)
                return 2
            already = args.participant in lg.state.withdrawn
            if not already:
                lg.append("withdraw", participant=args.participant, reason="operator", **lg.stamp())
        print(json.dumps({"withdrawn": args.participant, "already": already}, indent=2))
        return 0
    if args.action == "withdraw":
        return _control(args, {"op": "study.withdraw", "participant": args.participant})
    if args.action in ("next", "skip"):
        return _control(args, {"op": f"study.{args.action}"})
    if args.action == "status" and (args.watch or args.counts):
        return _watch(args)
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
