"""Tracker noise against the chi-square distribution of independent N(0, sigma^2) samples.

The documented noise is isotropic Gaussian, standard deviation ``noise_sigma`` per coordinate,
independent between coordinates, joints and frames. With the true positions known, the sum of
the squared errors over sigma^2 of n such samples is chi-square with n degrees of freedom;
its 99.9 % interval (scipy's ``chi2.ppf``) on 72,000 samples is about +-1.7 % of the
variance (+-0.9 % of sigma), ten times tighter than the 10 % of ``test_tracker.py``. Sums and
differences of disjoint pairs of independent samples are N(0, 2 sigma^2), chi-square again.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from iplanner_torch.sim.tracker import Tracker, TrackerCfg

SIGMA = 0.02
FPS = 15.0
FRAMES = 60
K = 400
P = 0.999  # two-sided coverage of every interval


def _chi2_interval(n: int) -> tuple[float, float]:
    return stats.chi2.ppf((1 - P) / 2, n), stats.chi2.ppf((1 + P) / 2, n)


@pytest.fixture(scope="module")
def errors() -> np.ndarray:
    """(FRAMES, K, 3) tracked minus true positions [m] (float64), K = 400 joints spread over a
    2 m cube, one frame per period, no dropout; fixed seed."""
    truth = np.random.default_rng(123).uniform(-1.0, 1.0, size=(K, 3))
    tracker = Tracker(TrackerCfg(fps=FPS, noise_sigma=SIGMA, window=FRAMES), seed=7)
    for i in range(FRAMES):
        assert tracker.observe(i / FPS, truth)
    win = tracker.window().astype(np.float64)  # float32 rounding: < 1e-7 m, 5e-6 sigma
    assert not np.isnan(win).any()
    return win - truth


def test_noise_variance_is_in_the_chi_square_interval(errors: np.ndarray) -> None:
    """``sum e^2 / sigma^2`` over all 72,000 coordinates, and over each axis's 24,000, lies
    in the chi-square 99.9 % interval of its count; the mean error lies within the 99.9 %
    normal interval ``3.29 sigma / sqrt(n)``. Catches a sigma off by 2 % or more (the variance
    by 4 %: a variance passed as standard deviation, a sqrt(3) split over the coordinates, a
    uniform or scaled draw), noise on one axis only, or a biased noise."""
    z = errors / SIGMA
    n = z.size
    lo, hi = _chi2_interval(n)
    assert lo <= float((z**2).sum()) <= hi, (lo, float((z**2).sum()), hi)
    assert abs(lo / n - 1) < 0.02 and abs(hi / n - 1) < 0.02  # the interval is tight
    lo_a, hi_a = _chi2_interval(n // 3)
    for axis in range(3):
        s = float((z[..., axis] ** 2).sum())
        assert lo_a <= s <= hi_a, (axis, lo_a, s, hi_a)
    bound = stats.norm.ppf((1 + P) / 2) / np.sqrt(n)
    assert abs(float(z.mean())) <= bound


def test_noise_is_independent_between_frames_and_joints(errors: np.ndarray) -> None:
    """Differences of disjoint pairs of consecutive frames (0-1, 2-3, ...) and sums of
    disjoint pairs of joints (0+1, 2+3, ...) are N(0, 2 sigma^2) when the samples are
    independent: ``sum d^2 / (2 sigma^2)`` lies in the chi-square 99.9 % interval of its
    36,000 terms. Catches noise drawn once and reused in later frames (differences 0), or
    drawn once per frame and shared by every joint (sums of variance 4 sigma^2)."""
    z = errors / SIGMA
    diff = z[1::2] - z[0::2]  # (FRAMES / 2, K, 3)
    lo, hi = _chi2_interval(diff.size)
    s = float((diff**2).sum() / 2)
    assert lo <= s <= hi, (lo, s, hi)
    both = z[:, 1::2] + z[:, 0::2]  # (FRAMES, K / 2, 3)
    lo, hi = _chi2_interval(both.size)
    s = float((both**2).sum() / 2)
    assert lo <= s <= hi, (lo, s, hi)


def test_zero_sigma_gives_the_true_positions_exactly() -> None:
    """``noise_sigma = 0``: every tracked coordinate is the true one as float32 (no noise,
    however small). Catches a noise floor added to a zero sigma."""
    truth = np.random.default_rng(5).uniform(-1.0, 1.0, size=(10, 3))
    tracker = Tracker(TrackerCfg(fps=FPS, noise_sigma=0.0, window=4), seed=1)
    for i in range(4):
        tracker.observe(i / FPS, truth)
    np.testing.assert_array_equal(
        tracker.window(), np.broadcast_to(truth, (4, 10, 3)).astype(np.float32)
    )
