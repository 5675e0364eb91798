"""The statistics of a two-alternative preference study, in numpy and the standard library only.

- `wilson_interval`: the Wilson score interval for a binomial proportion (good coverage at small n and near 0/1,
  unlike the Wald interval).
- `binom_test_two_sided`: the exact two-sided binomial test with the "as or less likely" rule: the p-value sums the
  probabilities of every outcome no more likely than the observed one. This is the method of
  `scipy.stats.binomtest(k, n, p).pvalue` (R's `binom.test` too); at p = 0.5 it is computed in exact integer
  arithmetic, otherwise from log-probabilities with scipy's relative tolerance of 1e-7 for ties.
- `cluster_robust_interval`: choices repeat within a participant, so the binomial interval is too narrow when
  participants differ. The ratio estimator K/N with a CR1 cluster-robust (sandwich) variance over participants:
  V = G/(G-1) * sum_g (k_g - p n_g)^2 / N^2, normal 95% interval.
- `bootstrap_interval`: the percentile bootstrap over participants (resample whole participants with replacement),
  a fixed seed so the report is reproducible.
- `bradley_terry`: strengths from pairwise wins by Hunter's (2004) MM algorithm, with a weak prior (each condition
  wins and loses half a virtual game against a fixed unit-strength opponent) so a condition that never wins stays
  finite.
"""
from __future__ import annotations

import math
from fractions import Fraction
from typing import Mapping, Sequence

import numpy as np

Z95 = 1.959963984540054  # the 97.5 % standard normal quantile


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of k successes in n trials; (0, 1) when n == 0."""
    if not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return 0.0, 1.0
    p = k / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def _log_pmf(i: int, n: int, p: float) -> float:
    return (math.lgamma(n + 1) - math.lgamma(i + 1) - math.lgamma(n - i + 1)
            + (i * math.log(p) if i else 0.0) + ((n - i) * math.log1p(-p) if n - i else 0.0))


def binom_test_two_sided(k: int, n: int, p: float = 0.5) -> float:
    """Exact two-sided binomial p-value (sum of P(X = i) over outcomes i with P(X = i) <= P(X = k))."""
    if not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if not 0.0 < p < 1.0:
        raise ValueError(f"p must be in (0, 1), got {p}")
    if n == 0:
        return 1.0
    if p == 0.5:
        ck = math.comb(n, k)
        tail = sum(c for c in (math.comb(n, i) for i in range(n + 1)) if c <= ck)
        return float(min(Fraction(tail, 2 ** n), Fraction(1)))
    lk = _log_pmf(k, n, p)
    bound = lk + math.log1p(1e-7)
    total = sum(math.exp(lp) for lp in (_log_pmf(i, n, p) for i in range(n + 1)) if lp <= bound)
    return min(1.0, total)


def cluster_robust_interval(wins: Sequence[int], counts: Sequence[int], z: float = Z95) -> dict:
    """K/N with a CR1 sandwich variance over clusters (participants). Needs >= 2 clusters with data."""
    k = np.asarray(wins, float)
    n = np.asarray(counts, float)
    keep = n > 0
    k, n = k[keep], n[keep]
    g, big_n = len(n), float(n.sum())
    if g < 2:
        return {"rate": (float(k.sum()) / big_n) if big_n else None, "se": None, "ci95": None,
                "design_effect": None, "clusters": g}
    p = float(k.sum()) / big_n
    var = g / (g - 1) * float(((k - p * n) ** 2).sum()) / big_n ** 2
    se = math.sqrt(var)
    naive = p * (1 - p) / big_n
    return {"rate": p, "se": se, "ci95": [max(0.0, p - z * se), min(1.0, p + z * se)],
            "design_effect": (var / naive) if naive > 0 else None, "clusters": g}


def bootstrap_interval(wins: Sequence[int], counts: Sequence[int], *, resamples: int = 10000, seed: int = 0,
                       level: float = 0.95) -> dict:
    """Percentile bootstrap of K/N resampling whole clusters (participants) with replacement."""
    k = np.asarray(wins, np.int64)
    n = np.asarray(counts, np.int64)
    keep = n > 0
    k, n = k[keep], n[keep]
    g = len(n)
    out = {"method": "percentile bootstrap over participants", "resamples": resamples, "seed": seed,
           "clusters": g, "ci95": None}
    if g < 2:
        return out
    rng = np.random.Generator(np.random.PCG64(seed))
    idx = rng.integers(0, g, size=(resamples, g))
    rates = k[idx].sum(axis=1) / n[idx].sum(axis=1)
    a = (1 - level) / 2
    lo, hi = np.quantile(rates, [a, 1 - a])
    out["ci95"] = [float(lo), float(hi)]
    return out


def bradley_terry(wins: Mapping[tuple[str, str], int], *, prior: float = 0.5, tol: float = 1e-12,
                  max_iter: int = 100000) -> dict[str, float]:
    """Strengths pi_i (> 0) from wins[(winner, loser)] counts, by MM with a virtual-opponent prior.

    Maximises sum_{i,j} w_ij log(pi_i / (pi_i + pi_j)) + prior * sum_i [log(pi_i / (pi_i + 1)) + log(1 / (pi_i + 1))],
    i.e. every condition also wins and loses `prior` games against a fixed opponent of strength 1, which pins the
    scale and keeps zero-win conditions finite. The MM update (Hunter 2004) is
    pi_i <- (W_i + prior) / (sum_j n_ij / (pi_i + pi_j) + 2 * prior / (pi_i + 1)).
    """
    names = sorted({a for pair in wins for a in pair})
    if prior <= 0 and names:
        raise ValueError("prior must be > 0 (it keeps conditions without wins finite)")
    index = {c: i for i, c in enumerate(names)}
    m = len(names)
    w = np.zeros((m, m))
    for (a, b), c in wins.items():
        if c < 0:
            raise ValueError("win counts must be >= 0")
        if a != b:
            w[index[a], index[b]] += c
    games = w + w.T
    total_wins = w.sum(axis=1)
    pi = np.ones(m)
    for _ in range(max_iter):
        denom = (games / (pi[:, None] + pi[None, :])).sum(axis=1) + 2 * prior / (pi + 1)
        new = (total_wins + prior) / denom
        if np.max(np.abs(np.log(new) - np.log(pi))) < tol:
            pi = new
            break
        pi = new
    return {c: float(pi[index[c]]) for c in names}
