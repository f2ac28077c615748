"""Statistics of policy evaluation: bootstrap confidence intervals, rank agreement between two evaluators.

All functions are pure (NumPy in, floats out) and tested on hand-made examples (``tests/agents/test_stats.py``).
Pearson and Spearman use SciPy when it is installed and the NumPy formulas below otherwise; both agree.

MMRV, the mean maximum rank violation (Li et al. 2024, "Evaluating Real-World Robot Manipulation Policies in
Simulation", SIMPLER), measures how badly a proxy evaluator (here: the dream) misorders policies, weighted by
how much the misordering matters in reality::

    MMRV = 1/N sum_i max_j |real_i - real_j| * 1[(proxy_i < proxy_j) != (real_i < real_j)]

0 when the proxy orders every pair as reality does; it is in the units of the real scores.
"""

from __future__ import annotations

import numpy as np


def _as_1d(x, name: str) -> np.ndarray:
    arr = np.asarray(x, np.float64)
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D sequence, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def _paired(x, y) -> tuple[np.ndarray, np.ndarray]:
    x, y = _as_1d(x, "x"), _as_1d(y, "y")
    if x.shape != y.shape:
        raise ValueError(f"x and y must have the same length, got {x.size} and {y.size}")
    return x, y


# ---------------------------------------------------------------------------------------------
# Confidence intervals
# ---------------------------------------------------------------------------------------------


def bootstrap_ci(samples, confidence: float = 0.95, resamples: int = 10_000,
                 seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean of ``samples``: (low, high).

    ``resamples`` means of ``len(samples)`` draws with replacement; the interval is their
    ((1 - confidence) / 2, (1 + confidence) / 2) quantiles. One sample gives (x, x).
    """
    x = _as_1d(samples, "samples")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if resamples < 1:
        raise ValueError(f"resamples must be >= 1, got {resamples}")
    rng = np.random.default_rng(seed)
    means_R = x[rng.integers(0, x.size, size=(resamples, x.size))].mean(axis=1)
    tail = (1.0 - confidence) / 2.0
    low, high = np.quantile(means_R, [tail, 1.0 - tail])
    return float(low), float(high)


def summarize(samples, confidence: float = 0.95, resamples: int = 10_000, seed: int = 0) -> dict:
    """``{"mean", "ci_low", "ci_high", "n", "returns"}`` of one policy's episode returns."""
    x = _as_1d(samples, "samples")
    low, high = bootstrap_ci(x, confidence, resamples, seed)
    return {"mean": float(x.mean()), "ci_low": low, "ci_high": high, "n": int(x.size), "returns": x.tolist()}


# ---------------------------------------------------------------------------------------------
# Correlation
# ---------------------------------------------------------------------------------------------


def rankdata(x) -> np.ndarray:
    """Ranks 1..N, ties get the average of the ranks they span (SciPy's ``rankdata(method="average")``)."""
    x = _as_1d(x, "x")
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(x.size, np.float64)
    ranks[order] = np.arange(1, x.size + 1)
    for value in np.unique(x):  # average over ties
        tied = x == value
        ranks[tied] = ranks[tied].mean()
    return ranks


def _pearson_numpy(x: np.ndarray, y: np.ndarray) -> float:
    dx, dy = x - x.mean(), y - y.mean()
    denom = np.sqrt((dx * dx).sum() * (dy * dy).sum())
    return float("nan") if denom == 0.0 else float((dx * dy).sum() / denom)


def pearson(x, y) -> float:
    """Pearson correlation of paired scores (nan when either is constant, or with fewer than 2 pairs)."""
    x, y = _paired(x, y)
    if x.size < 2 or np.ptp(x) == 0.0 or np.ptp(y) == 0.0:
        return float("nan")
    try:
        from scipy import stats
    except ImportError:
        return _pearson_numpy(x, y)
    return float(stats.pearsonr(x, y).statistic)


def spearman(x, y) -> float:
    """Spearman rank correlation (Pearson of the average ranks; nan when either is constant)."""
    x, y = _paired(x, y)
    if x.size < 2 or np.ptp(x) == 0.0 or np.ptp(y) == 0.0:
        return float("nan")
    try:
        from scipy import stats
    except ImportError:
        return _pearson_numpy(rankdata(x), rankdata(y))
    return float(stats.spearmanr(x, y).statistic)


# ---------------------------------------------------------------------------------------------
# Rank violations
# ---------------------------------------------------------------------------------------------


def mmrv(real, proxy) -> float:
    """Mean maximum rank violation of ``proxy`` scores against ``real`` scores (see the module docstring).

    A pair (i, j) is violated when the proxy's strict order differs from the real one; ties count as
    "not less", so a pair tied in both is never a violation.
    """
    real, proxy = _paired(real, proxy)
    real_less_NN = real[:, None] < real[None, :]
    proxy_less_NN = proxy[:, None] < proxy[None, :]
    violation_NN = real_less_NN != proxy_less_NN
    weight_NN = np.abs(real[:, None] - real[None, :])
    return float((weight_NN * violation_NN).max(axis=1).mean())
