"""Scores as sums over resampling units, and the paired hierarchical bootstrap of method differences.

A metric of one run is a ratio of sums over units (held-out touches, or 32 x 32 pixel blocks of the padded frame):
value = f(sum num / sum den), f the identity except for PSNR (from the MSE). Keeping the per-unit sums lets a
difference between two methods be resampled *paired*: the same units for both, then garments, then each method's
seeds, so a confidence interval reflects where on the garment, which garment and which seed, and nothing else.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

PSNR_FLOOR_MSE = 1e-12   # identical images: PSNR is reported as 120 dB instead of dividing by zero


def mse_to_psnr(mse: np.ndarray | float) -> np.ndarray | float:
    """PSNR (dB) of images in [0, 1] from their mean squared error."""
    return 10.0 * np.log10(1.0 / np.maximum(mse, PSNR_FLOOR_MSE))


def psnr_to_mse(psnr: np.ndarray | float) -> np.ndarray | float:
    return 10.0 ** (-np.asarray(psnr, np.float64) / 10.0)


TRANSFORMS: dict[str, Callable] = {"visual_psnr": mse_to_psnr}
INVERSES: dict[str, Callable] = {"visual_psnr": psnr_to_mse}


@dataclass
class Units:
    """Per-unit sums of one metric of one run. Shape: key, num, den (N,); keys unique; den >= 0."""

    key: np.ndarray
    num: np.ndarray
    den: np.ndarray

    def __post_init__(self):
        self.key = np.asarray(self.key, dtype=np.int64).reshape(-1)
        self.num = np.asarray(self.num, dtype=np.float64).reshape(-1)
        self.den = np.asarray(self.den, dtype=np.float64).reshape(-1)
        if not (len(self.key) == len(self.num) == len(self.den)):
            raise ValueError(f"Units: key, num, den must have one length; got {len(self.key)}, {len(self.num)}, "
                             f"{len(self.den)}")
        if len(np.unique(self.key)) != len(self.key):
            raise ValueError("Units: keys must be unique")
        keep = self.den > 0   # a unit with no scored pixel carries no information
        self.key, self.num, self.den = self.key[keep], self.num[keep], self.den[keep]

    def __len__(self) -> int:
        return int(len(self.key))


def reduce(metric: str, num: np.ndarray | float, den: np.ndarray | float) -> np.ndarray | float:
    """The metric's value from summed num and den; NaN where den is 0 (no unit scored), never a division by 0."""
    num, den = np.asarray(num, np.float64), np.asarray(den, np.float64)
    ratio = np.divide(num, den, out=np.full(np.broadcast(num, den).shape, np.nan), where=den > 0)
    out = TRANSFORMS.get(metric, lambda x: x)(ratio)
    return float(out) if np.ndim(out) == 0 else out


def single_unit(metric: str, v: float) -> Units:
    """A run known only by its score (a stored table keeps no per-unit sums): one unit whose value is `v`, so a
    bootstrap over it resamples garments and seeds alone."""
    if not np.isfinite(v):
        raise ValueError(f"{metric}: a score must be finite; got {v}")
    return Units([0], [float(INVERSES.get(metric, lambda x: x)(v))], [1.0])


def value(metric: str, u: Units) -> float:
    return float(reduce(metric, u.num.sum(), u.den.sum()))


@dataclass
class Difference:
    """mean(A) - mean(B) over the garments both have, with its percentile bootstrap interval."""

    diff: float
    lo: float
    hi: float
    garments: int
    units: int

    def as_dict(self) -> dict:
        return {"diff": self.diff, "lo": self.lo, "hi": self.hi, "garments": self.garments, "units": self.units}


def _aligned(runs: Sequence[Units], keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, U) num and den matrices of `runs` on the common `keys` (sorted)."""
    num = np.empty((len(runs), len(keys)))
    den = np.empty((len(runs), len(keys)))
    for i, u in enumerate(runs):
        order = np.argsort(u.key)
        pos = order[np.searchsorted(u.key, keys, sorter=order)]
        num[i], den[i] = u.num[pos], u.den[pos]
    return num, den


def _run_values(metric: str, num: np.ndarray, den: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(B, R) metric values of R runs under B unit weightings w (B, U)."""
    return reduce(metric, w @ num.T, w @ den.T)


def paired_bootstrap(metric: str, a: Mapping[str, Sequence[Units]], b: Mapping[str, Sequence[Units]], *,
                     n_boot: int = 2000, level: float = 0.95, seed: int = 0,
                     chunk: int = 250) -> Difference | None:
    """Paired hierarchical bootstrap of mean_g [mean over A's runs - mean over B's runs] on garment g.

    `a`, `b`: garment -> that method's runs (one Units each: seeds). Per resample: the common units of a garment are
    drawn with replacement (the same draw for every run of both methods: paired), then the garments, then each
    method's runs (seeds) independently. Percentile interval at `level`. None when no garment has units in common.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1); got {level}")
    garments = sorted(g for g in a if g in b and a[g] and b[g])
    per_garment, point, n_units = [], [], 0
    rng = np.random.default_rng(seed)
    for g in garments:
        keys = a[g][0].key
        for u in list(a[g]) + list(b[g]):
            keys = np.intersect1d(keys, u.key)
        if len(keys) == 0:
            continue
        n_units += len(keys)
        na, da = _aligned(a[g], keys)
        nb, db = _aligned(b[g], keys)
        ones = np.ones((1, len(keys)))
        point.append(float(np.mean(_run_values(metric, na, da, ones)) - np.mean(_run_values(metric, nb, db, ones))))
        draws = []
        for start in range(0, n_boot, chunk):
            m = min(chunk, n_boot - start)
            w = rng.multinomial(len(keys), np.full(len(keys), 1.0 / len(keys)), size=m).astype(np.float64)
            va, vb = _run_values(metric, na, da, w), _run_values(metric, nb, db, w)   # (m, Ra), (m, Rb)
            ia = rng.integers(0, va.shape[1], size=va.shape)
            ib = rng.integers(0, vb.shape[1], size=vb.shape)
            draws.append(np.take_along_axis(va, ia, 1).mean(1) - np.take_along_axis(vb, ib, 1).mean(1))
        per_garment.append(np.concatenate(draws))
    if not per_garment:
        return None
    d = np.stack(per_garment, 1)                                   # (n_boot, G)
    gw = rng.multinomial(d.shape[1], np.full(d.shape[1], 1.0 / d.shape[1]), size=n_boot)
    boot = (gw * d).sum(1) / d.shape[1]
    boot = boot[np.isfinite(boot)]
    if boot.size == 0:
        return None
    lo, hi = np.quantile(boot, [(1 - level) / 2, (1 + level) / 2])
    return Difference(float(np.mean(point)), float(lo), float(hi), len(per_garment), n_units)
