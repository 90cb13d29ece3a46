"""Tracker: 15 Hz sampling, noise statistics, dropout rate, window."""

from __future__ import annotations

import numpy as np
import pytest
from sim_fakes import deadline, rest_pose

from iplanner_torch.errors import ConfigError, DataError, ShapeError
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
    with pytest.raises(ShapeError, match="expected at least one tracked frame, got none"):
        tracker.window()
    with pytest.raises(ShapeError, match=r"expected joints \(K, 3\)"):
        tracker.observe(0.0, np.zeros(10))


def _loop_schedule(fps: float, times: list[float]) -> list[bool]:
    """Which of ``times`` take a frame, by the catch-up loop (an independent reference)."""
    next_t, period, taken = 0.0, 1.0 / fps, []
    for t in times:
        due = not t + 1e-9 < next_t
        if due:
            while next_t <= t + 1e-9:
                next_t += period
        taken.append(due)
    return taken


def test_schedule_equals_the_catch_up_loop() -> None:
    """Control ticks and gaps (short ones are caught up one period at a time, long ones
    arithmetically) sample exactly where the one period at a time catch-up does (the closed
    loop's numbers depend on it)."""
    rng = np.random.default_rng(0)
    ticks = np.cumsum(np.full(3000, 0.01)).tolist()  # 30 s of 100 Hz control, summed up
    gaps = np.cumsum(rng.choice([0.01, 0.02, 0.5, 7.3, 40.0, 100.0, 1234.5], size=400)).tolist()
    for times in (ticks, gaps):
        tracker = Tracker(TrackerCfg(noise_sigma=0.0), seed=0)
        taken = [tracker.observe(t, rest_pose()) for t in times]
        assert taken == _loop_schedule(15.0, times)


@pytest.mark.parametrize("t_far", [1e4, 1e9, 1e300])
def test_far_times_do_not_stall(t_far: float) -> None:
    tracker = Tracker(TrackerCfg(noise_sigma=0.0), seed=0)
    with deadline(5.0):
        assert tracker.observe(0.0, rest_pose())
        assert tracker.observe(t_far, rest_pose())
        assert not tracker.observe(t_far, rest_pose())  # the next sample lies after t_far
    assert tracker.times()[-1] == t_far
    if t_far < 1e12:  # the next sample is the first multiple of the period after t_far
        assert not tracker.observe(t_far + 0.5 / 15.0, rest_pose())
        assert tracker.observe(t_far + 1.0 / 15.0 + 1e-6, rest_pose())


def test_rejects_bad_times_joints_and_settings() -> None:
    tracker = Tracker(TrackerCfg(), seed=0)
    tracker.observe(0.0, rest_pose())
    for t in (float("nan"), float("inf"), -float("inf")):
        with deadline(5.0), pytest.raises(DataError, match="finite time"):
            tracker.observe(t, rest_pose())
    assert np.isfinite(tracker.times()).all() and tracker.num_frames == 1
    with pytest.raises(ShapeError, match=r"\(10, 3\) like the stored frames, got K = 12"):
        tracker.observe(1.0, np.zeros((12, 3)))
    with pytest.raises(ShapeError, match="joints an array of real numbers, got dtype <U1"):
        tracker.observe(1.0, np.full((10, 3), "a"))
    with pytest.raises(ShapeError, match="ragged"):
        tracker.observe(1.0, [[0.0, 0.0, 0.0], [0.0, 0.0]])
    for kw, field in [
        (dict(fps=float("inf")), "fps"),
        (dict(fps=float("nan")), "fps"),
        (dict(fps=0.0), "fps"),
        (dict(noise_sigma=float("nan")), "noise_sigma"),
        (dict(noise_sigma=float("inf")), "noise_sigma"),
        (dict(dropout_rate=float("nan")), "dropout_rate"),
        (dict(window=2.5), "window"),
        (dict(window=0), "window"),
    ]:
        with pytest.raises(ConfigError, match=field):
            TrackerCfg(**kw)
    with pytest.raises(ConfigError, match="seed"):
        Tracker(TrackerCfg(), seed=-1)


def test_list_joints_equal_array_joints() -> None:
    a = Tracker(TrackerCfg(dropout_rate=0.3), seed=3)
    b = Tracker(TrackerCfg(dropout_rate=0.3), seed=3)
    for k in range(20):
        truth = rest_pose() + 0.01 * k
        assert a.observe(k / 15.0, truth) == b.observe(k / 15.0, truth.tolist())
    np.testing.assert_array_equal(a.window(), b.window())
    np.testing.assert_array_equal(a.latest_pose(), b.latest_pose())


def test_a_non_finite_true_joint_is_a_lost_joint() -> None:
    """NaN or inf in the true joints (a caller that could not place a joint) is a dropout of
    that joint: NaN in the window, held at its last observation in latest_pose; the first
    frame, which initialises the held pose, must be finite. Finite frames draw the same noise
    as before (the same seed, the same observations)."""
    pose = np.arange(12, dtype=float).reshape(4, 3) / 10
    tr = Tracker(TrackerCfg(fps=10.0, noise_sigma=0.001, window=3), seed=4)
    ref = Tracker(TrackerCfg(fps=10.0, noise_sigma=0.001, window=3), seed=4)
    with pytest.raises(DataError, match=r"first frame \(t = 0 s\) has non-finite true joints "
                       r"\(index \[1\]\)"):  # fmt: skip
        Tracker(TrackerCfg(fps=10.0), seed=0).observe(0.0, np.where(np.arange(4)[:, None] == 1,
                                                                     np.nan, pose))  # fmt: skip
    for t in (0.0, 0.1):
        tr.observe(t, pose)
        ref.observe(t, pose)
    held = tr.latest_pose()
    bad = pose.copy()
    bad[2] = np.nan
    bad[3, 0] = np.inf
    assert tr.observe(0.2, bad) and ref.observe(0.2, pose)
    win, want = tr.window(), ref.window()
    assert np.isnan(win[-1, 2:]).all()
    np.testing.assert_array_equal(win[-1, :2], want[-1, :2])
    np.testing.assert_array_equal(tr.latest_pose()[2:], held[2:])
    assert np.isfinite(tr.latest_pose()).all()


@pytest.mark.parametrize("dtype", [complex, bool, object])
def test_only_real_joint_positions_are_taken(dtype: type) -> None:
    """Complex positions would lose their imaginary part when the window is read."""
    tracker = Tracker(TrackerCfg(), seed=0)
    with pytest.raises(ShapeError, match="joints an array of real numbers"):
        tracker.observe(0.0, rest_pose().astype(dtype))
    assert tracker.num_frames == 0


def test_a_tensor_with_a_gradient_is_taken_as_its_values() -> None:
    """``torch.Tensor`` joints that need a gradient failed inside numpy with a RuntimeError."""
    import torch

    pose = rest_pose()
    a, b = Tracker(TrackerCfg(), seed=0), Tracker(TrackerCfg(), seed=0)
    assert a.observe(0.0, pose)
    assert b.observe(0.0, torch.tensor(pose, requires_grad=True))
    np.testing.assert_array_equal(a.window(), b.window())


def test_the_held_pose_is_the_noisy_frame_and_the_padding_the_oldest() -> None:
    """``latest_pose`` is what the tracker saw (noisy), not the truth; before the window
    fills, the oldest frame is repeated in front, not the newest."""
    tr = Tracker(TrackerCfg(noise_sigma=0.05, window=4), seed=0)
    first, second = rest_pose(), rest_pose() + 1.0
    tr.observe(0.0, first)
    tr.observe(1.0 / 15.0, second)
    win = tr.window()
    np.testing.assert_array_equal(tr.latest_pose(), win[-1])
    assert not np.allclose(tr.latest_pose(), second, atol=1e-3)  # noisy, 5 cm
    np.testing.assert_array_equal(win[:3], np.stack([win[0]] * 3))
    assert np.abs(win[0] - first).max() < 0.5 and np.abs(win[3] - second).max() < 0.5
