"""The intervals over runs (`jaml.evaluation.intervals`) against hand computations."""

import math

import numpy as np
import pytest
from scipy import stats

from jaml.evaluation.intervals import mean_interval, paired_interval, welch_interval


def test_mean_interval_matches_a_hand_computation():
    """[1, 2, 3, 6]: mean 3, s = √(14/3), t(0.95, 3) = 2.35336; one run is its own interval."""
    mean, low, high = mean_interval([1.0, 2.0, 3.0, 6.0])
    half = 2.3533634 * math.sqrt(14 / 3) / 2
    assert mean == 3.0
    assert (low, high) == pytest.approx((3.0 - half, 3.0 + half), rel=1e-6)
    assert mean_interval([0.5]) == (0.5, 0.5, 0.5)


def test_welch_interval_matches_a_hand_computation():
    a, b = [1.0, 2.0, 3.0], [2.0, 4.0, 6.0, 8.0]
    diff, low, high = welch_interval(a, b)
    va, vb = np.var(a, ddof=1) / 3, np.var(b, ddof=1) / 4  # 1/3, 20/12
    dof = (va + vb) ** 2 / (va**2 / 2 + vb**2 / 3)
    assert dof == pytest.approx(4.0755, abs=1e-4)  # (1/3 + 5/3)² / ((1/3)²/2 + (5/3)²/3)
    half = stats.t.ppf(0.95, dof) * math.sqrt(va + vb)
    assert diff == -3.0
    assert (low, high) == pytest.approx((-3.0 - half, -3.0 + half), abs=2e-3)


def test_paired_interval_matches_a_hand_computation_and_beats_welch_on_shared_noise():
    """Seed s's two values share its noise: the paired interval sees only the differences
    (0.01, 0.02, 0.03: mean 0.02, s = 0.01, t(0.95, 2) = 2.91999), Welch's the seeds' spread."""
    base = {0: 0.10, 1: 0.30, 2: 0.50, 7: 0.9}  # seed 7 has no partner: left out
    aml = {0: 0.11, 1: 0.32, 2: 0.53}
    d, lo, hi, n = paired_interval(aml, base)
    half = 2.9199856 * 0.01 / math.sqrt(3)
    assert (d, n) == (pytest.approx(0.02), 3)
    assert (lo, hi) == pytest.approx((0.02 - half, 0.02 + half), rel=1e-6)
    _, wlo, whi = welch_interval(list(aml.values()), [base[s] for s in (0, 1, 2)])
    assert whi - wlo > 10 * (hi - lo)
