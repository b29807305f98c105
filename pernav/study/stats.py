"""Paired comparisons with 95 % bootstrap confidence intervals (methods compared on the same episodes): how the
study judges its methods, and what the diagnostics, recipes and research scripts report.

Example:
    >>> mean, lo, hi = bootstrap_ci([1.0, 2.0, 3.0, 4.0])
    >>> lo < mean < hi
    True
    >>> gap_closed([10.0, 10.0], [5.0, 5.0], [0.0, 0.0])["mean"]
    0.5
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["bootstrap_ci", "gap_closed", "paired_difference", "paired_ratio"]


def bootstrap_ci(values: Sequence[float], level: float = 0.95, resamples: int = 4000,
                 seed: int = 0) -> tuple[float, float, float]:
    """(mean, low, high): the mean and its percentile bootstrap interval (deterministic for a seed)."""
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        raise ValueError("bootstrap_ci needs at least one value")
    if x.size == 1:
        return float(x[0]), float(x[0]), float(x[0])
    idx = np.random.default_rng(seed).integers(0, x.size, size=(resamples, x.size))
    means = x[idx].mean(1)
    a = (1.0 - level) / 2
    return float(x.mean()), float(np.quantile(means, a)), float(np.quantile(means, 1 - a))


def paired_difference(baseline: Sequence[float], method: Sequence[float], **kwargs) -> dict[str, float]:
    """Mean of ``baseline - method`` per paired episode with its 95 % CI (> 0: the method is cheaper)."""
    b, m = np.asarray(baseline, dtype=float), np.asarray(method, dtype=float)
    if b.shape != m.shape:
        raise ValueError(f"paired episodes needed: {b.shape} baseline vs {m.shape} method values")
    mean, lo, hi = bootstrap_ci(b - m, **kwargs)
    return {"mean": mean, "low": lo, "high": hi, "n": int(b.size)}


def gap_closed(explore: Sequence[float], method: Sequence[float], oracle: Sequence[float], resamples: int = 4000,
               seed: int = 0) -> dict[str, float]:
    """Fraction of the explore-to-oracle gap a method closes, ``(E - M) / (E - O)`` of the means, with a
    paired bootstrap CI (episodes resampled together). NaN where the gap is not positive."""
    e, m, o = (np.asarray(v, dtype=float) for v in (explore, method, oracle))
    if not e.shape == m.shape == o.shape:
        raise ValueError("gap_closed needs paired episodes (same length for explore, method and oracle)")

    def ratio(ee: np.ndarray, mm: np.ndarray, oo: np.ndarray) -> np.ndarray:
        gap = ee.mean(-1) - oo.mean(-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(gap > 0, (ee.mean(-1) - mm.mean(-1)) / gap, np.nan)

    point = float(ratio(e, m, o))
    if e.size < 2 or np.isnan(point):
        return {"mean": point, "low": point, "high": point, "n": int(e.size)}
    idx = np.random.default_rng(seed).integers(0, e.size, size=(resamples, e.size))
    r = ratio(e[idx], m[idx], o[idx])
    r = r[~np.isnan(r)]
    return {"mean": point, "low": float(np.quantile(r, 0.025)), "high": float(np.quantile(r, 0.975)), "n": int(e.size)}


def paired_ratio(method: Sequence[float], baseline: Sequence[float], resamples: int = 4000,
                 seed: int = 0) -> dict[str, float]:
    """Ratio of the means ``mean(method) / mean(baseline)`` with a paired bootstrap CI (episodes resampled together).

    >>> paired_ratio([1.0, 3.0], [2.0, 2.0])["mean"]
    1.0
    """
    m, b = np.asarray(method, dtype=float), np.asarray(baseline, dtype=float)
    if m.shape != b.shape or m.size == 0:
        raise ValueError(f"paired episodes needed: {m.shape} method vs {b.shape} baseline values")
    point = float(m.mean() / b.mean())
    idx = np.random.default_rng(seed).integers(0, m.size, size=(resamples, m.size))
    r = m[idx].mean(1) / b[idx].mean(1)
    return {"mean": point, "low": float(np.quantile(r, 0.025)), "high": float(np.quantile(r, 0.975)), "n": int(m.size)}
