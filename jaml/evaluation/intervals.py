"""Confidence intervals over runs (Student's t): a mean's, Welch's for the difference of two
means, and the paired one for differences seed by seed. The figures and reports share these."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import stats


def mean_interval(samples: Sequence[float]) -> tuple[float, float, float]:
    """(mean, low, high): the mean over runs and its 90 % Student-t confidence interval
    (degenerate, low = high = mean, for one run)."""
    a = np.asarray(samples, np.float64)
    mean = float(a.mean())
    if a.size < 2:
        return mean, mean, mean
    half = float(stats.t.ppf(0.95, a.size - 1)) * float(a.std(ddof=1)) / math.sqrt(a.size)
    return mean, mean - half, mean + half


def welch_interval(a, b, confidence: float = 0.90) -> tuple[float, float, float]:
    """(mean(a) − mean(b), low, high): Welch's interval for the difference of two means
    (scipy's unequal-variance t-test)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    diff = float(a.mean() - b.mean())
    if a.size < 2 or b.size < 2:
        return diff, float("nan"), float("nan")
    if a.var() == 0 and b.var() == 0:
        return diff, diff, diff
    ci = stats.ttest_ind(a, b, equal_var=False).confidence_interval(confidence)
    return diff, float(ci.low), float(ci.high)


def paired_interval(a: dict[int, float], b: dict[int, float], confidence: float = 0.90):
    """(mean of a_s − b_s over the seeds s in both, low, high, n): the paired t interval."""
    common = sorted(a.keys() & b.keys())
    d = np.asarray([a[s] - b[s] for s in common], np.float64)
    if d.size < 2:
        return (float(d.mean()) if d.size else float("nan")), float("nan"), float("nan"), d.size
    half = float(stats.t.ppf(0.5 + confidence / 2, d.size - 1)) * d.std(ddof=1) / math.sqrt(d.size)
    return float(d.mean()), float(d.mean() - half), float(d.mean() + half), int(d.size)
