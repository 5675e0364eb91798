"""Scripted participants for end-to-end studies: a real `vtkiosk study run` process, driven over real HTTP and the
real control socket, with a known preference for the reference condition. Each participant goes through the whole
protocol the config asks for (consent, optional questions, familiarisation, the operator's release between trials).

    .venv/bin/python -m tests.kiosk.study.simulate --out docs/study    # regenerates docs/study (both studies)

Each participant prefers the reference over baseline b with a rate drawn from Beta(k * r_b, k * (1 - r_b)) (mean
r_b, participants differ), and then chooses trial by trial with that rate; the side it taps is wherever the
schedule put the chosen condition, so a side bias in the schedule could not fake a preference.
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

from .driver import StudyPage, operator

ROOT = Path(__file__).resolve().parents[3]


class StudyProcess:
    """`vtkiosk study run --config CONFIG --device emulated` as a child process; stdout/stderr go to files."""

    def __init__(self, config: Path, workdir: Path, *, ready_timeout_s: float = 120.0) -> None:
        self.config, self.workdir = config, workdir
        workdir.mkdir(parents=True, exist_ok=True)
        self.launches = 0
        self.proc: subprocess.Popen | None = None
        self.page: StudyPage | None = None
        self.socket: Path | None = None
        self.ready_timeout_s = ready_timeout_s

    def start(self) -> None:
        self.launches += 1
        out = self.workdir / f"run-{self.launches}.out"
        err = self.workdir / f"run-{self.launches}.err"
        with open(out, "wb") as fo, open(err, "wb") as fe:
            self.proc = subprocess.Popen([sys.executable, "-m", "vtkiosk.cli", "study", "run", "--config",
                                          str(self.config), "--device", "emulated", "--port", "0"],
                                         cwd=ROOT, stdout=fo, stderr=fe, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        deadline = time.monotonic() + self.ready_timeout_s
        url = sock = None
        while time.monotonic() < deadline:
            text = out.read_text()
            for line in text.splitlines():
                if ": page " in line:
                    url = line.split(": page ", 1)[1].strip().removesuffix("study")
                if ": control socket " in line:
                    sock = Path(line.split(": control socket ", 1)[1].strip())
            if url and sock:
                self.page, self.socket = StudyPage(url), sock
                return
            if self.proc.poll() is not None:
                raise RuntimeError(f"study run exited with {self.proc.returncode}:\n{err.read_text()[-3000:]}")
            time.sleep(0.05)
        self.kill()
        raise RuntimeError(f"study run did not become ready:\n{err.read_text()[-3000:]}")

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=30)

    def stop(self) -> int:
        if self.proc is None:
            return 0
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.kill()
        return self.proc.returncode


class Participant:
    def __init__(self, code: str, rates: dict[str, float], rng: random.Random, *, concentration: float = 20.0):
        self.code = code
        self.rng = rng
        self.rates = {b: rng.betavariate(concentration * r, concentration * (1 - r)) for b, r in rates.items()}

    def side(self, trial: dict, schedule_trial) -> str:
        """Tap the side of the reference with this participant's rate for the trial's comparison."""
        t = schedule_trial
        ref_side = "left" if t.left != t.comparison else "right"
        other = "right" if ref_side == "left" else "left"
        return ref_side if self.rng.random() < self.rates[t.comparison] else other


def run_participants(proc: StudyProcess, config, codes: list[str], rates: dict[str, float], seed: int) -> int:
    """Run every participant's whole session through the page API (and the operator's release where the study
    waits for it); return the number of acknowledged choices."""
    from kiosk.study.schedule import make_schedule

    rng = random.Random(seed)
    acked = 0
    for code in codes:
        who = Participant(code, rates, rng)
        reply = operator(proc.socket, "study.start", participant=code)
        assert reply["ok"], reply
        schedule = make_schedule(config, code, reply["session"])
        while True:
            st = proc.page.state()
            state = st["state"]
            if state == "done":
                break
            if state == "consent":
                proc.page.raw("POST", "/api/study/consent", {"token": st["token"], "agreed": True,
                                                             "version": st["consent"]["version"]})
            elif state == "demographics":
                answers = {k: rng.choice([*v, None]) for k, v in st["fields"].items()}
                proc.page.raw("POST", "/api/study/demographics", {"token": st["token"], "answers": answers})
            elif state == "familiarisation":
                proc.page.raw("POST", "/api/study/familiarised", {"token": st["token"]})
            elif state == "wait":
                assert operator(proc.socket, "study.next")["ok"]
            elif state == "trial":
                tr = st["trial"]
                proc.page.raw("POST", "/api/study/shown", {"token": tr["token"], "page": f"sim-{code}"})
                res = proc.page.choose(tr["token"], who.side(tr, schedule.trials[tr["index"]]))
                assert res["recorded"], res
                acked += 1
            else:
                raise AssertionError(f"unexpected page state {st}")
    return acked


HAPTIC_RATES = {"pix2pix": 0.796, "pix2pixhd": 0.767, "gaugan": 0.842}     # the paper's haptic results
VISUAL_RATES = {"pix2pix": 0.85, "pix2pixhd": 0.75, "gaugan": 0.70, "ours-no-gan": 0.60, "ours-no-rec": 0.65}


def simulate_study(work: Path, kind: str, rates: dict[str, float], n: int, seed: int, **extra) -> dict:
    """Build bundles, run a `vtkiosk study run` process, drive `n` participants, return the report."""
    import yaml

    from kiosk.study.config import load_study_config
    from kiosk.study.report import report_log

    from .helpers import study_doc
    from .study_bundles import make_study_bundles

    garments = [f"g{i:02d}" for i in range(8)]
    if (work / f"{kind}.jsonl").exists():          # --keep: a finished run is reported again, not repeated
        rep = report_log(work / f"{kind}.jsonl")
        rep["log"] = f"{kind}.jsonl"
        return rep
    trusted = make_study_bundles(work, ["ours", *rates], garments)
    doc = study_doc(id=f"{kind}-ab-simulated", kind=kind, garments=garments, seed=2023,
                    conditions={c: f"bundles/{c}/{{garment}}.vtb" for c in ["ours", *rates]},
                    trusted_keys=str(trusted), allow_unsigned=False, log=f"{kind}.jsonl", kiosk_name="sim-kiosk",
                    kiosk={"server": {"port": 0}, "inference": {"latency_budget_ms": 5000}}, **extra)
    (work / "study.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    config = load_study_config(work / "study.yaml")
    proc = StudyProcess(work / "study.yaml", work / "proc", ready_timeout_s=900.0)   # dozens of bundles to verify
    proc.start()
    try:
        run_participants(proc, config, [f"P{i:02d}" for i in range(1, n + 1)], rates, seed=seed)
    finally:
        proc.stop()
    rep = report_log(config.log)
    rep["log"] = f"{kind}.jsonl"
    return rep


def main(argv: list[str] | None = None) -> int:
    import shutil

    from kiosk.study.report import format_text, plot, plot_studies, write_json

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("docs/study"))
    ap.add_argument("--work", type=Path, default=Path("out/study-sim"))
    ap.add_argument("--participants", type=int, default=20)
    ap.add_argument("--keep", action="store_true", help="report a study whose log is already in --work again")
    args = ap.parse_args(argv)
    work = args.work.resolve()
    if work.exists() and not args.keep:
        shutil.rmtree(work)
    reps = {
        "haptic": simulate_study(
            work / "haptic", "haptic", HAPTIC_RATES, args.participants, seed=7, test_garments=5,
            release="each_trial", consent={"version": "sim-1", "text": "Simulated consent."},
            demographics={"age_band": ["18-24", "25-34", "35+"], "dominant_hand": ["left", "right"]},
            familiarisation={"screen_mm": [217, 136], "textures": [{"kind": "uniform", "level": 0.5},
                                                                   {"kind": "grating", "period_mm": 4}]}),
        "visual": simulate_study(work / "visual", "visual", VISUAL_RATES, args.participants, seed=8,
                                 test_garments=6, warmup_trials=5, time_limit_s=None,
                                 demographics={"age_band": ["18-24", "25-34", "35+"]}),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    for kind, rates in (("haptic", HAPTIC_RATES), ("visual", VISUAL_RATES)):
        rep = reps[kind]
        plot(rep, args.out / f"{kind}-preference.png",
             title=f"Simulated {kind} study: {rep['participants']} participants, true rates "
                   + ", ".join(f"{b} {100 * r:.0f}%" for b, r in rates.items()))
        write_json(rep, args.out / f"{kind}-report.json")
        (args.out / f"{kind}-report.txt").write_text(format_text(rep) + "\n")
        print(format_text(rep), "\n")
    plot_studies([reps["visual"], reps["haptic"]], args.out / "both-studies.png")
    print(f"wrote {args.out}/{{haptic,visual}}-preference.png, -report.json/.txt and both-studies.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
