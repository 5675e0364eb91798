"""The report against numbers computed by hand on a small known log, and the statistics against scipy."""
from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.study.log import StudyLog
from kiosk.study.report import StudyReportError, format_text, plot, report_log
from kiosk.study.stats import (binom_test_two_sided, bootstrap_interval, bradley_terry, cluster_robust_interval,
                               wilson_interval)

from .helpers import run_session, study_config

Z = 1.959963984540054

# The known log: warm-up g00, test garments g01..g03 (all three for everyone), comparisons pix2pix and pix2pixhd,
# so 6 test trials per participant. Choices ("ours" = the reference wins):
#   P01: always ours.
#   P02: ours against pix2pix everywhere; against pix2pixhd only on g01.
#   P03: against pix2pix ours on g01 and g02 and a timeout on g03; against pix2pixhd never ours.
RULES = {
    "P01": lambda t: True,
    "P02": lambda t: t.comparison == "pix2pix" or t.garment == "g01",
    "P03": lambda t: None if (t.comparison, t.garment) == ("pix2pix", "g03") else t.comparison == "pix2pix",
}


@pytest.fixture(scope="module")
def known(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("known")
    cfg = study_config(tmp, garments=["g00", "g01", "g02", "g03"], test_garments=3)
    with StudyLog.open(cfg.log, cfg.id) as log:
        for code, rule in RULES.items():
            def choose(schedule, i, rule=rule):
                t = schedule.trials[i]
                if t.block == "warmup":
                    return "left"
                ours = rule(t)
                return None if ours is None else (t.side_of("ours") if ours else t.side_of(t.comparison))
            run_session(log, cfg, code, choose)
    return cfg, report_log(cfg.log, resamples=2000, seed=3)


def _wilson_by_hand(k, n):
    p = k / n
    centre = (p + Z * Z / (2 * n)) / (1 + Z * Z / n)
    half = Z / (1 + Z * Z / n) * math.sqrt(p * (1 - p) / n + Z * Z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def test_counts_rates_and_exact_p_values(known):
    _, rep = known
    by = {c["baseline"]: c for c in rep["comparisons"]}
    p2p, hd, allc = by["pix2pix"], by["pix2pixhd"], rep["overall"]
    # pix2pix: P01 3/3, P02 3/3, P03 2/2 (+1 timeout) -> 8/8.  P(X=8) + P(X=0) = 2/256
    assert (p2p["wins"], p2p["n"], p2p["timeouts"]) == (8, 8, 1)
    assert p2p["p_value"] == pytest.approx(2 / 256, rel=1e-12)
    # pix2pixhd: P01 3/3, P02 1/3, P03 0/3 -> 4/9. pmf(4) = 126/512 is the largest: every outcome counts -> 1
    assert (hd["wins"], hd["n"], hd["timeouts"]) == (4, 9, 0)
    assert hd["p_value"] == 1.0
    # all: 12/17. P(X >= 12) = (C(17,12)+...+C(17,17)) / 2^17 = (6188+2380+680+136+17+1)/131072 = 9402/131072
    assert (allc["wins"], allc["n"], allc["timeouts"]) == (12, 17, 1)
    assert allc["rate"] == pytest.approx(12 / 17)
    assert allc["p_value"] == pytest.approx(2 * 9402 / 131072, rel=1e-12)
    assert rep["warmup_responses"] == 3 and rep["participants"] == 3 and rep["complete_sessions"] == 3


def test_wilson_intervals_by_hand(known):
    _, rep = known
    by = {c["baseline"]: c for c in rep["comparisons"]}
    # 8/8: p = 1 -> centre = (1 + z^2/16) / (1 + z^2/8), half = z/(1 + z^2/8) * sqrt(z^2/256)
    z2 = Z * Z
    lo = (1 + z2 / 16) / (1 + z2 / 8) - Z / (1 + z2 / 8) * (Z / 16)
    assert by["pix2pix"]["wilson95"] == pytest.approx([lo, 1.0])
    assert lo == pytest.approx(0.67559, abs=1e-5)            # the textbook value for 8/8
    assert by["pix2pixhd"]["wilson95"] == pytest.approx(_wilson_by_hand(4, 9))
    assert by["pix2pixhd"]["wilson95"] == pytest.approx([0.18878, 0.73335], abs=1e-5)
    assert rep["overall"]["wilson95"] == pytest.approx([0.46867, 0.86720], abs=1e-5)


def test_breakdowns_by_hand(known):
    _, rep = known
    garments = {g["garment"]: (g["wins"], g["n"], g["timeouts"]) for g in rep["overall"]["by_garment"]}
    # g01: P01 2/2, P02 2/2, P03 1/2;  g02: P01 2/2, P02 1/2, P03 1/2;  g03: P01 2/2, P02 1/2, P03 0/1 + timeout
    assert garments == {"g01": (5, 6, 0), "g02": (4, 6, 0), "g03": (3, 5, 1)}
    people = {p["participant"]: (p["wins"], p["n"], p["timeouts"]) for p in rep["overall"]["by_participant"]}
    assert people == {"P01": (6, 6, 0), "P02": (4, 6, 0), "P03": (2, 5, 1)}
    p01 = next(p for p in rep["overall"]["by_participant"] if p["participant"] == "P01")
    assert p01["p_value"] == pytest.approx(2 / 64)            # 6/6: P(6) + P(0)


def test_participant_clustered_interval_by_hand(known):
    _, rep = known
    cr = rep["overall"]["clustered"]
    p = 12 / 17
    # residuals k_g - p n_g: 6 - 6p, 4 - 6p, 2 - 5p; V = G/(G-1) * sum r^2 / N^2 with G = 3, N = 17
    resid = [6 - 6 * p, 4 - 6 * p, 2 - 5 * p]
    var = 3 / 2 * sum(r * r for r in resid) / 17 ** 2
    assert var == pytest.approx(0.0285916, abs=1e-6)
    assert cr["se"] == pytest.approx(math.sqrt(var))
    assert cr["ci95"] == pytest.approx([p - Z * math.sqrt(var), min(1.0, p + Z * math.sqrt(var))])
    assert cr["design_effect"] == pytest.approx(var / (p * (1 - p) / 17))
    assert cr["design_effect"] > 1                            # participants differ: wider than the binomial CI
    boot = rep["overall"]["bootstrap"]
    assert boot["method"].startswith("percentile bootstrap over participants") and boot["seed"] == 3
    # every resample is a mix of the three participants' rates: within [2/5, 1]
    assert 2 / 5 <= boot["ci95"][0] <= p <= boot["ci95"][1] <= 1.0


def test_bradley_terry_on_the_known_log(known):
    _, rep = known
    bt = {s["condition"]: s for s in rep["bradley_terry"]["scores"]}
    # ours beat pix2pix 8-0 and lost to pix2pixhd 4-5: pix2pixhd > ours > pix2pix
    assert [s["condition"] for s in rep["bradley_terry"]["scores"]] == ["pix2pixhd", "ours", "pix2pix"]
    assert bt["ours"]["log_strength_vs_reference"] == 0.0
    assert 0.5 < bt["pix2pixhd"]["p_beats_reference"] < 0.6 and bt["pix2pix"]["p_beats_reference"] < 0.1
    pi = {c: s["strength"] for c, s in bt.items()}
    # the MM fixed point satisfies the penalised score equations (W_i + a)/pi_i = sum_j n_ij/(pi_i+pi_j) + 2a/(pi_i+1)
    a = 0.5
    games = {("ours", "pix2pix"): 8, ("ours", "pix2pixhd"): 9}
    wins = {"ours": 12, "pix2pix": 0, "pix2pixhd": 5}
    for c in pi:
        rhs = sum(n / (pi[x] + pi[y]) for (x, y), n in games.items() if c in (x, y)) + 2 * a / (pi[c] + 1)
        assert (wins[c] + a) / pi[c] == pytest.approx(rhs, rel=1e-8)


def test_text_json_and_plot(known, tmp_path):
    _, rep = known
    text = format_text(rep)
    assert "ours vs pix2pix" in text and "100.0%" in text and "Bradley-Terry" in text
    json.dumps(rep, allow_nan=False)
    out = plot(rep, tmp_path / "fig.png")
    assert out.stat().st_size > 5000 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_needs_test_trials(tmp_path):
    cfg = study_config(tmp_path)
    with StudyLog.open(cfg.log, cfg.id) as log:
        run_session(log, cfg, "P01", lambda s, i: "left", stop_after=1)    # only the warm-up
    with pytest.raises(StudyReportError, match="no answered test trials"):
        report_log(cfg.log)


def test_plot_without_matplotlib_says_so(known, tmp_path, monkeypatch):
    import builtins

    real = builtins.__import__

    def no_mpl(name, *a, **k):
        if name.startswith("matplotlib"):
            raise ImportError("No module named 'matplotlib'")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_mpl)
    with pytest.raises(StudyReportError, match="needs matplotlib"):
        plot(known[1], tmp_path / "x.png")


# --- the statistics alone ------------------------------------------------------------------------------------------


def test_hand_values():
    assert wilson_interval(7, 10) == pytest.approx((0.39678, 0.89221), abs=1e-5)   # textbook 7/10
    assert wilson_interval(0, 0) == (0.0, 1.0)
    assert binom_test_two_sided(7, 10) == 352 / 1024          # 2 * (120+45+10+1) / 2^10
    assert binom_test_two_sided(5, 10) == 1.0
    assert binom_test_two_sided(0, 4) == 2 / 16
    assert binom_test_two_sided(0, 0) == 1.0
    # p != 0.5: k=0 of n=3 at p=0.3: pmf = .343 .441 .189 .027 -> outcomes no likelier than .343: 0, 2, 3
    assert binom_test_two_sided(0, 3, 0.3) == pytest.approx(0.343 + 0.189 + 0.027)
    assert cluster_robust_interval([3], [5])["se"] is None    # one participant: no clustered estimate
    same = bootstrap_interval([2, 2, 2], [4, 4, 4], resamples=500, seed=1)
    assert same["ci95"] == [0.5, 0.5]                          # identical participants: nothing to resample
    assert bootstrap_interval([5, 3, 1], [5, 5, 4], seed=9) == bootstrap_interval([5, 3, 1], [5, 5, 4], seed=9)


def test_bradley_terry_limits():
    # one pair, many games: the prior barely matters, pi_a / pi_b -> w / l
    pi = bradley_terry({("a", "b"): 3000, ("b", "a"): 1000})
    assert pi["a"] / pi["b"] == pytest.approx(3.0, rel=0.01)
    zero = bradley_terry({("a", "b"): 10, ("a", "c"): 10})
    assert all(math.isfinite(v) and v > 0 for v in zero.values())
    assert zero["a"] > zero["b"] == pytest.approx(zero["c"])


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 300), data=st.data(), p=st.sampled_from([0.5, 0.2, 0.37, 0.9]))
def test_matches_scipy(n, data, p):
    scipy_stats = pytest.importorskip("scipy.stats")
    k = data.draw(st.integers(0, n))
    res = scipy_stats.binomtest(k, n, p)
    assert binom_test_two_sided(k, n, p) == pytest.approx(res.pvalue, rel=1e-9, abs=1e-15)
    if p == 0.5:
        ci = res.proportion_ci(confidence_level=0.95, method="wilson")
        assert wilson_interval(k, n) == pytest.approx((ci.low, ci.high), abs=1e-9)
