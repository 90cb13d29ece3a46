"""SpreadCalibrator: residuals scored against sampled observations (calibrated and not),
frame alignment, memory, the scale's bounds, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.prediction.calibration import CalibrationCfg, SpreadCalibrator
from iplanner_torch.prediction.forecast import Forecast

K = len(JOINT_NAMES)
DT = 0.1


def _mixture(mean_a: np.ndarray, var_a: np.ndarray, weights: list[float]) -> Forecast:
    """A one-row forecast whose every frame and joint has the per-action (A, 3) means and
    variances given, over 10 frames."""
    a = len(weights)
    mean = torch.as_tensor(mean_a, dtype=torch.float64).view(1, a, 1, 1, 3).expand(1, a, 10, K, 3)
    var = torch.as_tensor(var_a, dtype=torch.float64).view(1, a, 1, 1, 3).expand_as(mean)
    return Forecast(
        weights=torch.tensor([weights], dtype=torch.float64),
        mean=mean.clone(),
        var=var.clone(),
        dt=DT,
        joint_names=JOINT_NAMES,
        action_names=tuple(f"a{i}" for i in range(a)),
    )


def _sample_mixture(
    rng: np.random.Generator, mean_a, var_a, weights, n: int, widen: float, noise: float
) -> np.ndarray:
    """(n, 3) draws: an action by its weight, then its Gaussian with every standard deviation
    times ``widen``, plus tracker noise; drawn independently of the calibrator's formula."""
    pick = rng.choice(len(weights), size=n, p=weights)
    std = np.sqrt(np.asarray(var_a))[pick] * widen
    return (
        np.asarray(mean_a)[pick]
        + std * rng.standard_normal((n, 3))
        + noise * (rng.standard_normal((n, 3)))
    )


@pytest.mark.parametrize(("widen", "expected_mean_z"), [(1.0, 1.0), (3.0, None)])
def test_mean_residual_matches_sampling_from_the_forecast(widen: float, expected_mean_z) -> None:
    """Observations drawn from the forecast's own mixture (plus the tracker noise) give a mean
    normalised squared error of 1 (scale 1 at tolerance 1.5); drawn 3x wider, the error is
    that of the wider mixture, whose moment-matched variance is computed here from samples."""
    rng = np.random.default_rng(7)
    mean_a = np.array([[0.2, 0.0, 0.1], [0.5, 0.1, 0.1]])
    var_a = np.array([[4e-4, 1e-4, 9e-4], [1e-4, 4e-4, 1e-4]])
    weights = [0.3, 0.7]
    noise = 0.01
    cfg = CalibrationCfg(
        joints=("right_hand",), horizon_s=DT, tolerance=1.5, memory_s=1e6, max_scale=1e6
    )
    cal = SpreadCalibrator(cfg, JOINT_NAMES, noise_std=noise)
    j = JOINT_NAMES.index("right_hand")
    n_frames = 4000
    draws = _sample_mixture(rng, mean_a, var_a, weights, n_frames, widen, noise)
    # one forecast per frame, 0.1 s before it: each frame scored by exactly one forecast
    for i in range(n_frames):
        t0 = 0.1 * i
        cal.record(_mixture(mean_a, var_a, weights), t0)
        frame = np.full((1, K, 3), np.nan)
        frame[0, j] = draws[i]
        cal.observe(np.array([t0 + DT]), frame)
    z = [zz for _, zz in cal._residuals]
    assert len(z) == n_frames
    mean_z = float(np.mean(z))
    if expected_mean_z is None:  # the reference: the wider draws' own spread, from samples
        ref_draws = _sample_mixture(rng, mean_a, var_a, weights, 400_000, widen, noise)
        mu = (np.asarray(weights)[:, None] * mean_a).sum(0)
        second = (np.asarray(weights)[:, None] * (var_a + mean_a**2)).sum(0)
        v = second - mu**2 + noise**2
        expected_mean_z = float((((ref_draws - mu) ** 2) / v).mean())
        assert expected_mean_z > 3.0  # the check below is not the calibrated case again
    assert mean_z == pytest.approx(expected_mean_z, rel=0.08)
    assert cal.scale() == pytest.approx(max(1.0, mean_z / 1.5))
    if widen == 1.0:
        assert cal.scale() == 1.0


def test_each_tracked_frame_is_scored_on_the_forecast_frame_at_its_time() -> None:
    """Frame k of a forecast lies at t0 + (k + 1) dt: an observation equal to that frame's
    mean has no error, one frame off it is far out; frames before t0, beyond horizon_s, lost
    joints and frames already seen are not scored."""
    cfg = CalibrationCfg(joints=("left_hand",), horizon_s=0.5, tolerance=1.0, memory_s=10.0)
    cal = SpreadCalibrator(cfg, JOINT_NAMES, noise_std=0.0)
    j = JOINT_NAMES.index("left_hand")
    mean = torch.zeros(1, 1, 10, K, 3, dtype=torch.float64)
    mean[0, 0, :, j, 0] = torch.arange(10, dtype=torch.float64)  # frame k at x = k [m]
    f = Forecast(
        weights=torch.ones(1, 1, dtype=torch.float64),
        mean=mean,
        var=torch.full_like(mean, 1e-2),
        dt=DT,
        joint_names=JOINT_NAMES,
        action_names=("a",),
    )
    t0 = 2.0
    cal.record(f, t0)
    times = np.array([1.9, 2.0, 2.1, 2.3, 2.5, 2.6])
    frames = np.zeros((6, K, 3))
    frames[:, j, 0] = [5.0, 5.0, 0.0, 2.0, 4.0, 5.0]  # on frames 0, 2, 4 (and 5: beyond 0.5 s)
    frames[3, j, 1] = np.nan  # a lost coordinate: the joint counts as lost in that frame
    cal.observe(times, frames)
    assert [(round(t, 6), z) for t, z in cal._residuals] == [(2.1, 0.0), (2.5, 0.0)]
    assert cal.scale() == 1.0
    # the same frames again (a tracker window overlaps the last): nothing new is scored
    cal.observe(times, frames)
    assert len(cal._residuals) == 2
    # one frame off: a second forecast's frame 1 (x = 1, at 2.9 s) observed at x = 2
    cal.record(f, 2.7)
    late = np.zeros((1, K, 3))
    late[0, j, 0] = 2.0
    cal.observe(np.array([2.9]), late)
    t, z = cal._residuals[-1]
    assert t == pytest.approx(2.9)
    assert z == pytest.approx((2.0 - 1.0) ** 2 / 1e-2 / 3)  # x off by 1 m, y and z exact


def test_frames_that_arrive_one_at_a_time_score_every_frame_of_the_forecast() -> None:
    """The planner's use: one tracked frame per call. A forecast is kept until no frame can
    score it any more (``horizon_s`` after its start), so each of the 10 frames is scored,
    z = (0.05 k)^2 / 0.01 / 3 by hand; forgetting it after its first frame scored one."""
    cfg = CalibrationCfg(joints=("left_hand",), horizon_s=1.0, tolerance=1.0, memory_s=10.0)
    cal = SpreadCalibrator(cfg, JOINT_NAMES, noise_std=0.0)
    j = JOINT_NAMES.index("left_hand")
    mean = torch.zeros(1, 1, 10, K, 3, dtype=torch.float64)
    f = Forecast(
        weights=torch.ones(1, 1, dtype=torch.float64),
        mean=mean,
        var=torch.full_like(mean, 1e-2),
        dt=DT,
        joint_names=JOINT_NAMES,
        action_names=("a",),
    )
    cal.record(f, 0.0)
    for k in range(1, 11):
        frame = np.zeros((1, K, 3))
        frame[0, j, 0] = 0.05 * k
        cal.observe(np.array([0.1 * k]), frame)
    got = [z for _, z in cal._residuals]
    assert got == pytest.approx([(0.05 * k) ** 2 / 1e-2 / 3 for k in range(1, 11)])
    assert cal.scale() == pytest.approx(sum(got) / 10)


def test_residuals_older_than_the_memory_leave_the_scale() -> None:
    cfg = CalibrationCfg(joints=("right_hand",), tolerance=1.0, memory_s=0.5, max_scale=1e9)
    cal = SpreadCalibrator(cfg, JOINT_NAMES, noise_std=0.0)
    j = JOINT_NAMES.index("right_hand")
    f = _mixture(np.zeros((1, 3)), np.full((1, 3), 1e-2), [1.0])
    cal.record(f, 0.0)
    far = np.zeros((1, K, 3))
    far[0, j] = 1.0  # 1 m off on each coordinate: z = 100
    cal.observe(np.array([0.1]), far)
    assert cal.scale() == pytest.approx(100.0)
    cal.record(f, 0.5)
    cal.observe(np.array([0.7]), np.zeros((1, K, 3)))  # z = 0; 0.1 s is 0.6 s old now
    assert cal.scale() == 1.0
    # nothing in memory: 1
    assert SpreadCalibrator(cfg, JOINT_NAMES, noise_std=0.0).scale() == 1.0


def test_apply_widens_by_the_scale_within_max_scale_and_never_narrows() -> None:
    cfg = CalibrationCfg(joints=("right_hand",), tolerance=2.0, memory_s=10.0, max_scale=4.0)
    cal = SpreadCalibrator(cfg, JOINT_NAMES, noise_std=0.0)
    j = JOINT_NAMES.index("right_hand")
    f = _mixture(np.zeros((1, 3)), np.full((1, 3), 1e-2), [1.0])
    assert cal.apply(f) is f  # no residual yet
    cal.record(f, 0.0)
    off = np.zeros((1, K, 3))
    off[0, j] = 0.3  # z = 9: 4.5x the tolerance, capped at 4
    cal.observe(np.array([0.1]), off)
    g = cal.apply(f)
    torch.testing.assert_close(g.var, 4.0 * f.var)
    torch.testing.assert_close(g.mean, f.mean)
    torch.testing.assert_close(g.weights, f.weights)
    assert cal.scales == [1.0, 4.0]


def test_scale_var_multiplies_the_variances_and_refuses_bad_factors() -> None:
    f = _mixture(np.zeros((2, 3)), np.full((2, 3), 1e-2), [0.5, 0.5])
    torch.testing.assert_close(f.scale_var(2.5).var, 2.5 * f.var)
    for bad in (0.0, -1.0, math.nan, math.inf, "2"):
        with pytest.raises(DataError, match="expected factor"):
            f.scale_var(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"joints": ()}, "joints a non-empty list"),
        ({"joints": "right_hand"}, "joints a non-empty list"),
        ({"joints": (1,)}, "joints names"),
        ({"horizon_s": 0.0}, "horizon_s"),
        ({"memory_s": math.nan}, "memory_s"),
        ({"tolerance": -1.0}, "tolerance"),
        ({"max_scale": 0.5}, "max_scale >= 1"),
        ({"max_scale": math.inf}, "max_scale a finite number"),
    ],
)
def test_bad_settings_are_config_errors(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        CalibrationCfg(**kwargs)


def test_unknown_joints_wrong_shapes_and_bad_noise_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"\['nose'\] are not among"):
        SpreadCalibrator(CalibrationCfg(joints=("nose",)), JOINT_NAMES, noise_std=0.0)
    with pytest.raises(ConfigError, match="noise_std"):
        SpreadCalibrator(CalibrationCfg(), JOINT_NAMES, noise_std=-0.01)
    cal = SpreadCalibrator(CalibrationCfg(), JOINT_NAMES, noise_std=0.01)
    with pytest.raises(ShapeError, match=r"expected times \(T,\) and frames \(T, 10, 3\)"):
        cal.observe(np.zeros(2), np.zeros((3, K, 3)))
    other = Forecast(
        weights=torch.ones(1, 1),
        mean=torch.zeros(1, 1, 4, 2, 3),
        var=torch.ones(1, 1, 4, 2, 3),
        dt=DT,
        joint_names=("a", "b"),
        action_names=("x",),
    )
    with pytest.raises(ShapeError, match="expected a forecast of 10 joints, got 2"):
        cal.record(other, 0.0)


def _hand_at_the_origin(memory_s: float) -> tuple[SpreadCalibrator, int]:
    """A calibrator of the right hand alone (tolerance 1, no noise, no scale cap) that has
    recorded a forecast at t = 0 of the hand resting at the origin with variance 1e-2; and
    the hand's joint index."""
    cfg = CalibrationCfg(joints=("right_hand",), tolerance=1.0, memory_s=memory_s, max_scale=1e9)
    cal = SpreadCalibrator(cfg, JOINT_NAMES, noise_std=0.0)
    cal.record(_mixture(np.zeros((1, 3)), np.full((1, 3), 1e-2), [1.0]), 0.0)
    return cal, JOINT_NAMES.index("right_hand")


def test_overlapping_windows_do_not_score_the_boundary_frame_twice() -> None:
    """A tracker window that repeats the last frame seen (here 0.2 s) scores only the frames
    after it. By hand, var 1e-2 and no noise: 0.1 s is 1 m off on each axis, z = 1 / 1e-2 =
    100; 0.2 s and 0.3 s are exact, z = 0. Residuals (100, 0, 0): scale 100 / 3 at tolerance
    1; scoring 0.2 s twice would give (100, 0, 0, 0): 25."""
    cal, j = _hand_at_the_origin(memory_s=10.0)
    frames = np.zeros((3, K, 3))
    frames[0, j] = 1.0
    cal.observe(np.array([0.1, 0.2]), frames[:2])
    assert cal.scale() == pytest.approx(100.0 / 2)
    cal.observe(np.array([0.1, 0.2, 0.3]), frames)
    assert len(cal._residuals) == 3
    assert cal.scale() == pytest.approx(100.0 / 3)


def test_a_residual_exactly_memory_s_old_still_counts() -> None:
    """``memory_s`` keeps residuals "at most this old": with memory 0.5 s, the residual of
    0.5 s (z = 100, 1 m off per axis at var 1e-2) is exactly 0.5 s old when 1.0 s (z = 0) is
    observed, so both count: scale (100 + 0) / 2 = 50 at tolerance 1 (binary-exact times)."""
    cal, j = _hand_at_the_origin(memory_s=0.5)
    far = np.zeros((1, K, 3))
    far[0, j] = 1.0
    cal.observe(np.array([0.5]), far)  # forecast frame 4, at 0.0 + 5 * 0.1 s
    cal.observe(np.array([1.0]), np.zeros((1, K, 3)))  # frame 9, the horizon's last
    assert [t for t, _ in cal._residuals] == [0.5, 1.0]
    assert cal.scale() == pytest.approx(50.0)
