"""Tracker: 15 Hz sampling, noise statistics, dropout rate, window."""

from __future__ import annotations

import numpy as np
import pytest
from sim_fakes import rest_pose

from iplanner_torch.errors import ConfigError, ShapeError
from iplanner_torch.sim.tracker import Tracker, TrackerCfg


def _run(tracker: Tracker, seconds: float, dt: float = 0.01) -> list[np.ndarray]:
    frames = []
    truth = rest_pose()
    for k in range(int(round(seconds / dt)) + 1):
        if tracker.observe(k * dt, truth):
            frames.append(tracker.window()[-1])
    return frames


def test_samples_at_its_frame_rate() -> None:
    tracker = Tracker(TrackerCfg(fps=15.0, noise_sigma=0.0), seed=0)
    frames = _run(tracker, 2.0)
    assert len(frames) == 31  # t = 0, 1/15, ..., 2
    np.testing.assert_allclose(np.diff(tracker.times()), 1.0 / 15.0, atol=0.011)


def test_noise_std_and_dropout_rate() -> None:
    sigma, rate = 0.02, 0.1
    tracker = Tracker(TrackerCfg(noise_sigma=sigma, dropout_rate=rate, window=5), seed=1)
    frames = np.stack(_run(tracker, 60.0))  # 901 frames x 10 joints
    err = frames - rest_pose()[None]
    lost = np.isnan(err).all(-1)
    assert np.isnan(err).any(-1).sum() == lost.sum()  # whole joints drop out
    assert abs(lost.mean() - rate) < 0.02
    std = np.nanstd(err)
    assert abs(std - sigma) < 0.1 * sigma
    assert abs(np.nanmean(err)) < 0.1 * sigma


def test_window_pads_and_latest_pose_fills() -> None:
    tracker = Tracker(TrackerCfg(window=4, noise_sigma=0.0, dropout_rate=0.5), seed=2)
    tracker.observe(0.0, rest_pose())
    win = tracker.window()
    assert win.shape == (4, 10, 3)
    np.testing.assert_array_equal(np.isnan(win[0]), np.isnan(win[-1]))
    _run(tracker, 1.0)
    assert not np.isnan(tracker.latest_pose()).any()
    np.testing.assert_allclose(tracker.latest_pose(), rest_pose(), atol=1e-6)


def test_same_seed_same_observations() -> None:
    a = np.stack(_run(Tracker(TrackerCfg(dropout_rate=0.2), seed=5), 1.0))
    b = np.stack(_run(Tracker(TrackerCfg(dropout_rate=0.2), seed=5), 1.0))
    np.testing.assert_array_equal(a, b)


def test_errors() -> None:
    with pytest.raises(ConfigError, match="dropout_rate"):
        TrackerCfg(dropout_rate=1.0)
    with pytest.raises(ConfigError, match="noise_sigma"):
        TrackerCfg(noise_sigma=-0.1)
    tracker = Tracker(TrackerCfg(), seed=0)
    with pytest.raises(ShapeError, match="no|none"):
        tracker.window()
    with pytest.raises(ShapeError, match=r"expected joints \(K, 3\)"):
        tracker.observe(0.0, np.zeros(10))
