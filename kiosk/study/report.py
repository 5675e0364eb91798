"""`vtkiosk study report`: what a researcher publishes from a study log.

Per comparison (reference vs each other condition, test trials only; warm-up is never analysed and timeouts are
counted but are not choices): the preference rate for the reference with a Wilson 95 % interval, the exact two-sided
binomial test against 50 %, n; breakdowns per garment and per participant; a participant-clustered interval
(CR1 sandwich) and a percentile bootstrap over participants (fixed seed), because one participant answers many
trials; Bradley-Terry strengths when more than two conditions were compared; and a bar chart like the paper's
user-study figures (preference for the reference against each baseline, intervals, the 50 % chance line), for a
haptic or a visual study, or both side by side (`plot_studies`).

Withdrawn participants are left out of every number (the log keeps their records). Several kiosks' logs are pooled
by `kiosk.study.merge` and the report says how many trials came from each kiosk. When the study collected
demographics, the report gives the paper's summary line (how many people, and the answers per field).
"""
from __future__ import annotations

import json
import math
import textwrap
from collections import defaultdict
from pathlib import Path
from typing import Iterable

from kiosk.contract.errors import KioskError
from kiosk.study.log import LogRead, LogState
from kiosk.study.merge import Merged, merge_logs
from kiosk.study.stats import (binom_test_two_sided, bootstrap_interval, bradley_terry, cluster_robust_interval,
                               wilson_interval)


class StudyReportError(KioskError):
    """A report that cannot be produced (no data, plotting unavailable)."""


def _counts(rows: Iterable[dict]) -> dict:
    rows = list(rows)
    answered = [r for r in rows if not r["timeout"]]
    n = len(answered)
    k = sum(1 for r in answered if r["chose_reference"])
    lo, hi = wilson_interval(k, n)
    return {"n": n, "wins": k, "rate": (k / n) if n else None, "wilson95": [lo, hi],
            "p_value": binom_test_two_sided(k, n), "timeouts": len(rows) - n}


def _by(rows: list[dict], key: str) -> list[dict]:
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[str(r[key])].append(r)
    return [{key: name, **_counts(g)} for name, g in sorted(groups.items())]


def _clustered(rows: list[dict], *, resamples: int, seed: int) -> tuple[dict, dict]:
    per: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for r in rows:
        if not r["timeout"]:
            per[r["participant"]][0] += int(bool(r["chose_reference"]))
            per[r["participant"]][1] += 1
    names = sorted(per)
    wins, counts = [per[p][0] for p in names], [per[p][1] for p in names]
    cr = cluster_robust_interval(wins, counts)
    cr["method"] = "ratio estimator with CR1 cluster-robust variance over participants"
    return cr, bootstrap_interval(wins, counts, resamples=resamples, seed=seed)


def demographics_summary(state: LogState, participants: set[str]) -> dict | None:
    """Per declared field, how many participants gave each answer (their latest session's answers)."""
    latest: dict[str, dict] = {}
    for (p, n), s in sorted(state.sessions.items()):
        if p in participants and s.demographics is not None:
            latest[p] = s.demographics.get("answers", {})
    if not latest:
        return None
    fields: dict[str, dict[str, int]] = {}
    for answers in latest.values():
        for name, value in answers.items():
            bucket = fields.setdefault(name, {})
            key = "not answered" if value is None else str(value)
            bucket[key] = bucket.get(key, 0) + 1
    missing = len(participants - set(latest))
    parts = []
    for name, counts in fields.items():
        shown = ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: (kv[0] == "not answered",
                                                                                          -kv[1], kv[0])))
        parts.append(f"{name.replace('_', ' ')}: {shown}")
    line = f"{_people(len(participants))}; " + "; ".join(parts)
    if missing:
        line += f" ({missing} without demographics)"
    return {"participants": len(participants), "fields": fields, "without": missing, "line": line}


def _people(n: int) -> str:
    return f"{n} participant" + ("" if n == 1 else "s")


def analyse(state: LogState, read: LogRead | None = None, *, resamples: int = 10000, seed: int = 0,
            merged: Merged | None = None, strengths: bool = True) -> dict:
    """The full report as a JSON-ready dict (withdrawn participants left out). `strengths=False` leaves out the
    Bradley-Terry fit (the slowest part; study planning simulates thousands of reports without it)."""
    withdrawn = set(state.withdrawn)
    all_responses = state.responses()
    responses = [r for r in all_responses if r["participant"] not in withdrawn]
    test = [r for r in responses if r["block"] == "test"]
    if not test:
        raise StudyReportError("the log has no answered test trials yet (warm-up trials are not analysed"
                               + (f"; {len(withdrawn)} withdrawn participant(s) are left out" if withdrawn else "")
                               + ")")
    reference = test[0]["reference"]
    if any(r["reference"] != reference for r in test):
        raise StudyReportError("the log mixes reference conditions; one report per reference")
    comparisons = []
    for baseline in sorted({r["comparison"] for r in test}):
        rows = [r for r in test if r["comparison"] == baseline]
        cr, boot = _clustered(rows, resamples=resamples, seed=seed)
        comparisons.append({"reference": reference, "baseline": baseline, **_counts(rows), "clustered": cr,
                            "bootstrap": boot, "by_garment": _by(rows, "garment"),
                            "by_participant": _by(rows, "participant")})
    cr, boot = _clustered(test, resamples=resamples, seed=seed)
    overall = {**_counts(test), "clustered": cr, "bootstrap": boot, "by_garment": _by(test, "garment"),
               "by_participant": _by(test, "participant")}
    if any("kiosk" in r for r in test):
        overall["by_kiosk"] = _by([{**r, "kiosk": r.get("kiosk", "?")} for r in test], "kiosk")
    bt = None
    conditions = {reference} | {c["baseline"] for c in comparisons}
    if len(conditions) > 2 and strengths:
        wins: dict[tuple[str, str], int] = defaultdict(int)
        for r in test:
            if r["timeout"]:
                continue
            other = r["comparison"]
            pair = (reference, other) if r["chose_reference"] else (other, reference)
            wins[pair] += 1
        for c in conditions:  # a condition with no answered trial still gets a (prior-only) score
            wins.setdefault((c, c), 0)
        strengths = bradley_terry(wins)
        ref_s = strengths[reference]
        bt = {"method": "Bradley-Terry by MM (Hunter 2004), prior: 0.5 virtual win + 0.5 virtual loss per condition "
                        "against a unit-strength opponent",
              "scores": [{"condition": c, "strength": s, "log_strength_vs_reference": math.log(s / ref_s),
                          "p_beats_reference": s / (s + ref_s)}
                         for c, s in sorted(strengths.items(), key=lambda kv: -kv[1])]}
    sessions = [s for s in state.sessions.values() if s.participant not in withdrawn]
    reads = merged.reads if merged is not None else ([(Path("log"), read)] if read is not None else [])
    health = {"records": sum(len(r.records) for _, r in reads) if reads else None,
              "problems": [{"log": p.name, "line": q.line, "offset": q.offset, "reason": q.reason}
                           for p, r in reads for q in r.problems],
              "torn_tail": any(r.torn_tail for _, r in reads),
              "duplicate_responses_ignored": sum(len(s.duplicates) for s in state.sessions.values())
              + (merged.duplicates if merged else 0),
              "conflicting_copies": merged.conflicts if merged else []}
    kinds = {s.started.get("kind", "haptic") for s in state.sessions.values()}
    people = {s.participant for s in sessions}
    return {"study_id": state.study_id, "kind": kinds.pop() if len(kinds) == 1 else "mixed",
            "reference": reference, "log_health": health,
            "participants": len(people), "sessions": len(sessions),
            "complete_sessions": sum(1 for s in sessions if s.next_trial() is None),
            "withdrawn": sorted(withdrawn),
            "withdrawn_responses_excluded": len(all_responses) - len(responses),
            "warmup_responses": sum(1 for r in responses if r["block"] == "warmup"),
            "familiarisation_steps_not_analysed": sum(
                1 for s in sessions for f in s.familiarisation if f.get("action") == "done"),
            "consent": {"agreed": sum(1 for s in sessions if s.consented),
                        "declined": sum(1 for s in sessions if s.consent and not s.consented)},
            "demographics": demographics_summary(state, people),
            "kiosks": dict(sorted(merged.kiosks.items())) if merged else None,
            "comparisons": comparisons, "overall": overall, "bradley_terry": bt}


def _pct(x: float | None) -> str:
    return "   -  " if x is None else f"{100 * x:5.1f}%"


def _ci(ci: list[float] | None) -> str:
    return "-" if not ci else f"[{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"


def format_text(rep: dict) -> str:
    """The report as a plain-text table for the terminal."""
    lines = [f"{rep.get('kind', 'haptic')} study {rep['study_id']}: {_people(rep['participants'])}, "
             f"{rep['sessions']} session(s) ({rep['complete_sessions']} complete), reference {rep['reference']!r}",
             f"log: {rep['log_health']['records']} valid records, {len(rep['log_health']['problems'])} problem(s), "
             f"{rep['log_health']['duplicate_responses_ignored']} duplicate response(s) ignored; "
             f"{rep['warmup_responses']} warm-up response(s) not analysed"]
    if rep.get("withdrawn"):
        lines.append(f"withdrawn (left out, records kept): {', '.join(rep['withdrawn'])} "
                     f"({rep['withdrawn_responses_excluded']} response(s) excluded)")
    if rep.get("demographics"):
        lines.append(f"participants: {rep['demographics']['line']}")
    if rep.get("kiosks"):
        lines.append("trials per kiosk: " + ", ".join(f"{k} {n}" for k, n in rep["kiosks"].items()))
    conflicts = rep["log_health"].get("conflicting_copies") or []
    if conflicts:
        lines.append(f"{len(conflicts)} trial(s) had copies with different answers; the first log's copy counts")
    lines += ["",
             f"{'comparison':<28} {'n':>4} {'prefer':>7}  {'Wilson 95%':<14} {'p (exact)':>10}  "
             f"{'clustered 95%':<14} {'bootstrap 95%':<14} {'timeouts':>8}"]
    rows = [(f"{rep['reference']} vs {c['baseline']}", c) for c in rep["comparisons"]] + [("all", rep["overall"])]
    for name, c in rows:
        lines.append(f"{name:<28} {c['n']:>4} {_pct(c['rate']):>7}  {_ci(c['wilson95']):<14} {c['p_value']:>10.3g}  "
                     f"{_ci(c['clustered']['ci95']):<14} {_ci(c['bootstrap']['ci95']):<14} {c['timeouts']:>8}")
    for title, key in (("per garment", "by_garment"), ("per participant", "by_participant")):
        lines += ["", f"{title} (all comparisons):"]
        label = key.split("_", 1)[1]
        for g in rep["overall"][key]:
            lines.append(f"  {g[label]:<26} {g['n']:>4} {_pct(g['rate']):>7}  {_ci(g['wilson95']):<14} "
                         f"{g['p_value']:>10.3g}")
    if rep["bradley_terry"]:
        lines += ["", "Bradley-Terry (strength relative to the reference; P = chance to be preferred over it):"]
        for s in rep["bradley_terry"]["scores"]:
            lines.append(f"  {s['condition']:<26} log-strength {s['log_strength_vs_reference']:+.3f}  "
                         f"P {s['p_beats_reference']:.3f}")
    lines += ["", "clustered = CR1 cluster-robust over participants; bootstrap = percentile, resampling participants "
                  f"(B={rep['overall']['bootstrap']['resamples']}, seed={rep['overall']['bootstrap']['seed']})"]
    return "\n".join(lines)


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise StudyReportError("the plot needs matplotlib, which is not installed here (pip install matplotlib); "
                               "the numbers are in the text/JSON report") from None
    return plt


STUDY_TITLES = {"haptic": "Haptic user study", "visual": "Visual user study"}


def _bars(ax, rep: dict, title: str) -> None:
    """One study in the paper's layout: a bar per comparison with its Wilson 95 % interval and the 50 % line."""
    comps = rep["comparisons"]
    labels = [c["baseline"] for c in comps]
    rates = [100 * (c["rate"] or 0.0) for c in comps]
    lo = [100 * ((c["rate"] or 0.0) - c["wilson95"][0]) for c in comps]
    hi = [100 * (c["wilson95"][1] - (c["rate"] or 0.0)) for c in comps]
    bars = ax.bar(range(len(comps)), rates, color="#4C72B0", edgecolor="#22395e", linewidth=0.8, width=0.6,
                  yerr=[lo, hi], capsize=4, error_kw={"elinewidth": 1.2, "ecolor": "#222222"})
    ax.axhline(50, color="#C44E52", linestyle="--", linewidth=1.2)
    ax.text(len(comps) - 0.45, 50, "chance\n50%", ha="left", va="center", fontsize=7, color="#C44E52",
            clip_on=False)
    for b, c, r in zip(bars, comps, rates):
        x = b.get_x() + b.get_width() / 2
        if c["n"] and r < 1.0:
            # A 0 % bar has no height: mark it so a reader sees a bar at zero, not a missing bar.
            ax.plot([b.get_x(), b.get_x() + b.get_width()], [0, 0], color="#22395e", linewidth=3,
                    solid_capstyle="butt", clip_on=False, zorder=3)
        ax.text(x, 2 if r >= 12 else r + 2, f"n={c['n']}", ha="center", va="bottom", fontsize=7,
                color="white" if r >= 12 else "#222222")
        ax.text(x, min(100 * c["wilson95"][1] + 1.5, 101), f"{r:.1f}%" if c["n"] else "no data",
                ha="center", va="bottom", fontsize=8)
    ax.set_xticks(range(len(comps)), [f"vs {name}" for name in labels], fontsize=8)
    ax.set_ylim(0, 108)
    ax.set_xlim(-0.5, len(comps) - 0.5)
    ax.set_ylabel(f"prefer {rep['reference']} (%)")
    ax.set_title(textwrap.fill(title, 60), fontsize=8)
    ax.set_xlabel("error bars: Wilson 95% intervals", fontsize=7, color="#555555")
    ax.spines[["top", "right"]].set_visible(False)


def default_title(rep: dict) -> str:
    what = STUDY_TITLES.get(rep.get("kind", "haptic"), "User study")
    return f"{what}: preference for {rep['reference']} ({_people(rep['participants'])})"


def plot(rep: dict, out: Path, *, title: str | None = None) -> Path:
    """Bar chart of the reference's preference rate against each baseline (Wilson 95 %), with the 50 % line."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(1.6 + 1.3 * len(rep["comparisons"]), 3.6), dpi=150)
    _bars(ax, rep, title or default_title(rep))
    return _save(fig, plt, out)


def plot_studies(reps: list[dict], out: Path, *, titles: list[str] | None = None) -> Path:
    """Several studies side by side, like the paper's figure (the visual study, then the haptic study)."""
    if not reps:
        raise StudyReportError("give at least one study report to plot")
    plt = _pyplot()
    widths = [1.6 + 1.3 * len(r["comparisons"]) for r in reps]
    fig, axes = plt.subplots(1, len(reps), figsize=(sum(widths), 3.8), dpi=150,
                             gridspec_kw={"width_ratios": widths}, squeeze=False)
    for i, (ax, rep) in enumerate(zip(axes[0], reps)):
        _bars(ax, rep, (titles[i] if titles else None) or f"({chr(97 + i)}) {default_title(rep)}")
    return _save(fig, plt, out)


def _save(fig, plt, out: Path) -> Path:
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def report_log(path: Path | list[Path], *, resamples: int = 10000, seed: int = 0) -> dict:
    """The report of one log, or of several kiosks' logs of one study pooled (see kiosk.study.merge)."""
    paths = list(path) if isinstance(path, (list, tuple)) else [path]
    merged = merge_logs(paths)
    rep = analyse(merged.state, resamples=resamples, seed=seed, merged=merged)
    rep["log"] = str(paths[0]) if len(paths) == 1 else [str(p) for p in paths]
    return rep


def write_json(rep: dict, out: Path) -> None:
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(rep, indent=2, sort_keys=False) + "\n")
