"""`vtkiosk study plan`: how many participants a study needs, by simulating the design the report analyses.

The design: every participant answers `garments` test trials per comparison (one per test garment). Participants
differ: each one's preference for the reference against a baseline is drawn from a Beta distribution with mean
`rate` and standard deviation `spread` (0: everyone the same). The analysis is the report's primary one: the
ratio estimator with a CR1 cluster-robust interval over participants (`kiosk.study.stats.cluster_robust_interval`);
a comparison is "detected" when its 95 % interval excludes 50 %. Power is the share of simulated studies that
detect it, estimated with its Monte Carlo standard error; "all" is the share that detect every comparison. The
reference row of every count is the same design at a true rate of 50 %: how often the analysis "detects" a
preference that is not there (it should be near 5 %; with few participants the clustered interval is too narrow
and this rate is higher, which the table shows instead of hiding).

Timeouts are not modelled (they remove trials; plan for a few more participants if many are expected).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from kiosk.contract.errors import InputError
from kiosk.study.stats import Z95


@dataclass(frozen=True)
class PlanRow:
    participants: int
    power: dict[str, float]       # comparison -> power
    power_all: float
    false_positive: float         # the same design at a true 50 %: how often the analysis detects a preference
    mc_se: float                  # the largest Monte Carlo standard error in the row


def beta_params(rate: float, spread: float) -> tuple[float, float] | None:
    """Beta(a, b) with mean `rate` and standard deviation `spread`; None when spread is 0 (no spread)."""
    if not 0.0 < rate < 1.0:
        raise InputError(f"a preference rate must lie strictly between 0 and 1, got {rate}")
    if spread < 0:
        raise InputError(f"spread must be >= 0, got {spread}")
    if spread == 0:
        return None
    limit = math.sqrt(rate * (1 - rate))
    if spread >= limit:
        raise InputError(f"spread {spread} is too large for rate {rate} (a Beta distribution needs spread < "
                         f"{limit:.3f})")
    k = rate * (1 - rate) / spread ** 2 - 1
    return rate * k, (1 - rate) * k


def participant_rates(rng: np.random.Generator, rate: float, spread: float, size: tuple[int, ...]) -> np.ndarray:
    ab = beta_params(rate, spread)
    return np.full(size, rate) if ab is None else rng.beta(ab[0], ab[1], size=size)


def detected(wins: np.ndarray, counts: np.ndarray, z: float = Z95) -> np.ndarray:
    """Per simulated study (rows): does the CR1 cluster-robust 95 % interval over participants exclude 50 %?

    The same estimator as `cluster_robust_interval`, vectorised over studies: p = K/N,
    V = G/(G-1) * sum_g (k_g - p n_g)^2 / N^2, interval p +- z sqrt(V), clipped to [0, 1].
    """
    k = wins.astype(np.float64)
    n = counts.astype(np.float64)
    g = n.shape[1]
    if g < 2:
        return np.zeros(n.shape[0], bool)      # the report gives no clustered interval for one participant
    big_n = n.sum(axis=1)
    p = k.sum(axis=1) / big_n
    var = g / (g - 1) * ((k - p[:, None] * n) ** 2).sum(axis=1) / big_n ** 2
    half = z * np.sqrt(var)
    lo, hi = np.maximum(0.0, p - half), np.minimum(1.0, p + half)
    return (lo > 0.5) | (hi < 0.5)


def power_at(participants: int, garments: int, rates: Mapping[str, float], spread: float, *, sims: int,
             seed: int) -> PlanRow:
    """Power of every comparison (and of all together) with this many participants."""
    if participants < 1 or garments < 1 or sims < 1:
        raise InputError("participants, garments and sims must be at least 1")
    rng = np.random.Generator(np.random.PCG64(seed))
    hits = []
    for comparison in sorted(rates):
        p = participant_rates(rng, rates[comparison], spread, (sims, participants))
        wins = rng.binomial(garments, p)
        hits.append(detected(wins, np.full_like(wins, garments)))
    stacked = np.vstack(hits)
    power = {c: float(h.mean()) for c, h in zip(sorted(rates), hits)}
    power_all = float(stacked.all(axis=0).mean())
    p0 = participant_rates(rng, 0.5, spread, (sims, participants))
    wins0 = rng.binomial(garments, p0)
    false_positive = float(detected(wins0, np.full_like(wins0, garments)).mean())
    se = max(math.sqrt(v * (1 - v) / sims) for v in [*power.values(), power_all, false_positive])
    return PlanRow(participants, power, power_all, false_positive, max(se, 1.0 / sims))


def plan(rates: Mapping[str, float], *, garments: int, spread: float, target: float = 0.8,
         participants: Sequence[int] = tuple(range(4, 41, 2)), sims: int = 4000, seed: int = 0) -> dict:
    """Power over a range of participant counts; the smallest count that reaches `target` for every comparison."""
    if not rates:
        raise InputError("give at least one comparison's expected preference rate")
    if not 0.0 < target < 1.0:
        raise InputError(f"target power must lie between 0 and 1, got {target}")
    rows = [power_at(n, garments, rates, spread, sims=sims, seed=seed + n) for n in sorted(set(participants))]
    enough = next((r.participants for r in rows if r.power_all >= target), None)
    return {"rates": dict(rates), "garments": garments, "spread": spread, "target": target, "alpha": 0.05,
            "sims": sims, "seed": seed, "analysis": "CR1 cluster-robust 95% interval over participants excludes 50%",
            "rows": [{"participants": r.participants, "power": r.power, "power_all": r.power_all,
                      "false_positive_at_50": r.false_positive, "mc_se": r.mc_se} for r in rows],
            "participants_needed": enough}


def format_plan(p: dict) -> str:
    names = sorted(p["rates"])
    lines = [f"study plan: {p['garments']} test garment(s) per participant, one trial per comparison each; "
             f"participants' rates spread with SD {p['spread']:g}",
             "expected preference for the reference: " + ", ".join(f"{c} {100 * p['rates'][c]:.1f}%" for c in names),
             f"analysis: {p['analysis']} (alpha {p['alpha']}); {p['sims']} simulated studies per row", "",
             f"{'participants':>12} " + " ".join(f"{c[:14]:>14}" for c in names) + f" {'all':>8} {'at 50%':>8} {'MC SE':>7}"]
    for r in p["rows"]:
        lines.append(f"{r['participants']:>12} " + " ".join(f"{100 * r['power'][c]:>13.1f}%" for c in names)
                     + f" {100 * r['power_all']:>7.1f}% {100 * r['false_positive_at_50']:>7.1f}% {100 * r['mc_se']:>6.1f}%")
    need = p["participants_needed"]
    lines += ["", "at 50%: the same design with no true preference; how often the analysis claims one (ideal 5%)",
              f"participants needed for {100 * p['target']:.0f}% power on every comparison: "
              + (str(need) if need is not None else "more than the largest count tried")]
    return "\n".join(lines)
