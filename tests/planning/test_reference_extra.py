"""More planning numerics against references computed here by other methods.

* ``smooth_stop``: the docstring's waypoint index ``s(k) = k - k^2 / (2 K)``,
  ``K = min(2 hold, W - 1)``, as hand-listed values and on a straight path (where the result
  is ``s(k) v`` exactly), then numpy's ``interp`` of every joint at ``s(k)`` on a curved path.
* ``joint_limit_violation``, ``goal_distance``, ``goal_distance_ee``: hand-computed sums of
  squares (a 3-4-5 triangle, excesses of 0.2 and 0.3 rad).
* ``Trajectory.resample``: scipy's ``CubicHermiteSpline`` through the original knots with the
  documented tangents (central differences, 0 where a joint holds or turns, ``qd_start`` at
  the start, 0 at the end), computed here in numpy.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.interpolate import CubicHermiteSpline

from iplanner_torch.errors import ConfigError
from iplanner_torch.planning import costs as C
from iplanner_torch.planning.optimizer import smooth_stop
from iplanner_torch.planning.trajectory import Trajectory

F64 = torch.float64


# ------------------------------------------------------------------------------ smooth_stop


def _stop_index(w: int, hold: int) -> np.ndarray:
    """(W,) the docstring's fractional waypoint index: ``k - k^2 / (2 K)`` up to ``K``, then
    ``K / 2``."""
    k_stop = min(2 * hold, w - 1)
    k = np.arange(w, dtype=np.float64)
    return np.where(k <= k_stop, k - k**2 / (2.0 * k_stop), k_stop / 2.0)


@pytest.mark.parametrize(
    ("w", "hold", "want"),
    [
        (5, 1, [0.0, 0.75, 1.0, 1.0, 1.0]),  # K = 2: stops at s = 1 = hold
        (6, 10, [0.0, 0.9, 1.6, 2.1, 2.4, 2.5]),  # K = W - 1 = 5: stops at 2.5
        (2, 1, [0.0, 0.5]),  # the shortest path: K = 1
        (7, 3, [0.0, 11 / 12, 5 / 3, 9 / 4, 8 / 3, 35 / 12, 3.0]),  # K = 6 = W - 1 = 2 hold
    ],
)
def test_smooth_stop_on_a_straight_path_is_the_documented_index_times_the_step(
    w: int, hold: int, want: list[float]
) -> None:
    """On ``q_k = k v`` the linear interpolation at ``s(k)`` is ``s(k) v``: the hand-listed
    ``s(k)`` (float64: atol 1e-12). Catches another stop index (``K = 2 hold`` without the
    ``W - 1`` cap, ``k^2 / K``), a path not held after ``K``, or a floor/ceil slip."""
    v = torch.tensor([0.3, -1.2, 2.0], dtype=F64)
    q = torch.arange(w, dtype=F64).unsqueeze(-1) * v
    got = smooth_stop(q, hold)
    np.testing.assert_allclose(_stop_index(w, hold), want, rtol=0, atol=1e-15)
    expect = np.asarray(want)[:, None] * v.numpy()
    np.testing.assert_allclose(got.numpy(), expect, rtol=0, atol=1e-12)


@pytest.mark.parametrize("w", [2, 3, 8, 21])
def test_smooth_stop_on_a_straight_path_for_every_hold(w: int) -> None:
    """``(k - k^2 / (2 K)) v`` for ``k <= K``, ``(K / 2) v`` after, for every hold from 1 to
    beyond ``W - 1`` (float64: atol 1e-12); never past the held waypoint (``K / 2 <= hold``).
    Catches the same slips as the hand-listed cases on other sizes."""
    v = torch.tensor([0.5, -0.25], dtype=F64)
    q = torch.arange(w, dtype=F64).unsqueeze(-1) * v
    for hold in range(1, w + 2):
        k_stop = min(2 * hold, w - 1)
        k = np.arange(w, dtype=np.float64)
        s = np.where(k <= k_stop, k - k**2 / (2 * k_stop), k_stop / 2)
        got = smooth_stop(q, hold).numpy()
        np.testing.assert_allclose(got, s[:, None] * v.numpy(), rtol=0, atol=1e-12)
        assert got[:, 0].max() <= hold * 0.5 + 1e-12  # never past q_hold (v_0 = 0.5)


@pytest.mark.parametrize("hold", [0, -1])
def test_smooth_stop_refuses_hold_zero(hold: int) -> None:
    """``hold >= 1`` is documented (``hold = 0`` would give ``K = 0`` and a division by 0):
    refused with ConfigError, not a NaN path."""
    with pytest.raises(ConfigError, match="hold"):
        smooth_stop(torch.zeros(5, 2, dtype=F64), hold)


@pytest.mark.parametrize(("w", "hold"), [(12, 1), (12, 4), (12, 10), (12, 11), (30, 7), (3, 1)])
def test_smooth_stop_on_a_curved_path_equals_numpy_interp(w: int, hold: int) -> None:
    """Each joint of a curved, non-monotone path interpolated by ``np.interp`` over the
    waypoint index at the documented ``s(k)`` (float64: atol 1e-12). Catches interpolation
    between the wrong waypoints (an off-by-one in the floor index) or of the wrong weights."""
    rng = np.random.default_rng(w * 100 + hold)
    path = np.cumsum(rng.normal(size=(w, 3)), axis=0)
    got = smooth_stop(torch.from_numpy(path), hold).numpy()
    s = _stop_index(w, hold)
    idx = np.arange(w, dtype=np.float64)
    expect = np.stack([np.interp(s, idx, path[:, j]) for j in range(3)], axis=-1)
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------------- costs


def test_joint_limit_violation_hand_values() -> None:
    """The sum over waypoints and joints of the squared excess beyond the limits: q = (1.2,
    -1.3) with limits +-1 gives 0.2^2 + 0.3^2 = 0.13; a second waypoint inside adds 0; a
    second trajectory with (1.2, -1.3) twice gives 0.26 (float64: rtol 1e-12). Catches an
    unsquared excess (0.5), a mean instead of a sum, or the two sides swapped (4.84 + ...)."""
    q_min = torch.tensor([-1.0, -1.0], dtype=F64)
    q_max = torch.tensor([1.0, 1.0], dtype=F64)
    q = torch.tensor(
        [
            [[1.2, -1.3], [0.5, -0.9]],
            [[1.2, -1.3], [1.2, -1.3]],
            [[1.0, -1.0], [0.0, 0.0]],  # on the limits: no violation
        ],
        dtype=F64,
    )
    got = C.joint_limit_violation(q, q_min, q_max)
    np.testing.assert_allclose(got.numpy(), [0.13, 0.26, 0.0], rtol=1e-12, atol=1e-15)


def test_joint_limit_violation_asymmetric_limits() -> None:
    """Limits (0.5, 2.0) on joint 0 and (-3, -1) on joint 1: q = (0.2, -0.5) is 0.3 below and
    0.5 above, 0.09 + 0.25 = 0.34 (float64: rtol 1e-12). Catches a violation measured from 0
    or from the other limit."""
    q_min = torch.tensor([0.5, -3.0], dtype=F64)
    q_max = torch.tensor([2.0, -1.0], dtype=F64)
    q = torch.tensor([[[0.2, -0.5], [1.0, -2.0]]], dtype=F64)
    got = C.joint_limit_violation(q, q_min, q_max)
    assert float(got[0]) == pytest.approx(0.34, rel=1e-12)


def test_joint_limit_violation_of_a_continuous_joint_is_zero_not_nan() -> None:
    """A continuous joint (limits -inf, +inf) at any finite angle adds exactly 0, not NaN
    (``inf - inf`` nowhere), and its gradient is 0; the other joint's 0.5 rad excess still
    counts 0.25. Catches a violation written in centre / half-range form
    (``|q - (lo + hi) / 2| - (hi - lo) / 2``: ``inf - inf``) or normalised by the range."""
    q_min = torch.tensor([-torch.inf, -1.0], dtype=F64)
    q_max = torch.tensor([torch.inf, 1.0], dtype=F64)
    q = torch.tensor([[[1e6, 1.5], [-37.0, 0.0]]], dtype=F64, requires_grad=True)
    got = C.joint_limit_violation(q, q_min, q_max)
    assert float(got.detach()[0]) == 0.25
    got.sum().backward()
    assert torch.isfinite(q.grad).all()
    np.testing.assert_array_equal(q.grad[0, :, 0].numpy(), [0.0, 0.0])
    np.testing.assert_allclose(q.grad[0, :, 1].numpy(), [2 * 0.5, 0.0])


def test_goal_distance_of_a_3_4_5_offset() -> None:
    """The squared joint-space distance: a (3, 4) offset gives 25, (0, 0) gives 0 and a
    (-3, 0, 4)-style offset in 3 joints gives 25 too (float64, exact). Catches the distance
    instead of its square (5) or a sum of absolute values (7)."""
    goal = torch.tensor([1.0, -2.0], dtype=F64)
    last = torch.tensor([[4.0, 2.0], [1.0, -2.0], [-2.0, -6.0]], dtype=F64)
    np.testing.assert_array_equal(C.goal_distance(last, goal).numpy(), [25.0, 0.0, 25.0])
    goal3 = torch.tensor([0.5, 0.5, 0.5], dtype=F64)
    last3 = torch.tensor([[-2.5, 0.5, 4.5]], dtype=F64)
    np.testing.assert_array_equal(C.goal_distance(last3, goal3).numpy(), [25.0])


def test_goal_distance_ee_of_a_3_4_5_offset() -> None:
    """The squared end-effector distance: offsets (3, 0, 4) and (0, -4, 3) [m] give 25 m^2,
    (0.3, 0.4, 0) gives 0.25 (float64: rtol 1e-12). Catches the distance instead of its
    square or a missing coordinate."""
    target = torch.tensor([0.1, 0.2, 0.3], dtype=F64)
    ee = target + torch.tensor([[3.0, 0.0, 4.0], [0.0, -4.0, 3.0], [0.3, 0.4, 0.0]], dtype=F64)
    np.testing.assert_allclose(
        C.goal_distance_ee(ee, target).numpy(), [25.0, 25.0, 0.25], rtol=1e-12
    )


# ---------------------------------------------------------------------- Trajectory.resample


def _catmull_rom(q: np.ndarray, t: np.ndarray, qd_start: np.ndarray | None) -> np.ndarray:
    """The Trajectory docstring's tangents, vectorised here: ``(q_{i+1} - q_{i-1}) /
    (t_{i+1} - t_{i-1})`` inside, 0 where a joint holds or turns (the neighbouring
    differences' product <= 0), ``qd_start`` (else 0) at the start, 0 at the end."""
    m = np.zeros_like(q)
    central = (q[2:] - q[:-2]) / (t[2:] - t[:-2])[:, None]
    monotone = np.diff(q, axis=0)[1:] * np.diff(q, axis=0)[:-1] > 0
    m[1:-1] = np.where(monotone, central, 0.0)
    if qd_start is not None:
        m[0] = qd_start
    return m


@pytest.mark.parametrize(
    ("t0", "duration", "n", "with_start"),
    [
        (0.2, 1.5, 13, True),  # inside the span
        (0.0, 2.0, 9, False),  # the whole span, from rest
        (1.0, 3.0, 25, True),  # runs past the end: the end pose is held
    ],
)
def test_resample_equals_scipy_cubic_hermite_spline(
    t0: float, duration: float, n: int, with_start: bool
) -> None:
    """The resampled waypoints are scipy's spline (through the original knots with the
    documented tangents) at ``t0 + linspace(0, duration, n)``, the end pose held past the last
    knot (float64: atol 1e-12); the new ``qd_start`` is the spline's derivative at ``t0``
    (atol 1e-10), or 0 past the end. Catches resampling by linear interpolation, tangents not
    scaled by the interval, a ``qd_start`` taken from the old trajectory or from a finite
    difference of the new waypoints, or times not starting at ``t0``."""
    rng = np.random.default_rng(n)
    t = np.linspace(0.0, 2.4, 9)
    q = np.cumsum(rng.normal(size=(9, 3)), axis=0) * 0.3
    q[5, 2] = q[4, 2]  # a hold in one joint
    qd0 = np.array([0.7, -0.2, 0.1]) if with_start else None
    traj = Trajectory(
        q=torch.from_numpy(q),
        times=torch.from_numpy(t),
        qd_start=None if qd0 is None else torch.from_numpy(qd0),
    )
    new = traj.resample(t0, duration, n)
    spline = CubicHermiteSpline(t, q, _catmull_rom(q, t, qd0))
    tq = t0 + np.linspace(0.0, duration, n)
    np.testing.assert_allclose(new.times.numpy(), tq, rtol=0, atol=1e-12)
    inside = tq <= t[-1]
    expect = np.where(inside[:, None], spline(np.minimum(tq, t[-1])), q[-1])
    np.testing.assert_allclose(new.q.numpy(), expect, rtol=0, atol=1e-12)
    qd_expect = spline(t0, 1) if t0 <= t[-1] else np.zeros(3)
    assert new.qd_start is not None
    np.testing.assert_allclose(new.qd_start.numpy(), qd_expect, rtol=0, atol=1e-10)
    # the resampled trajectory itself passes through its own new waypoints
    again, _ = new.sample(new.times)
    np.testing.assert_allclose(again.numpy(), new.q.numpy(), rtol=0, atol=1e-12)


def test_resample_start_velocity_beyond_the_end_is_zero() -> None:
    """Resampling from after the last knot: every waypoint is the end pose and ``qd_start`` is
    0 (the trajectory holds its end pose at rest, as documented). Catches a velocity
    extrapolated past the end."""
    t = np.linspace(0.0, 1.0, 5)
    q = np.stack([t**2, np.sin(t)], axis=-1)
    traj = Trajectory(q=torch.from_numpy(q), times=torch.from_numpy(t))
    new = traj.resample(1.5, 1.0, 4)
    np.testing.assert_array_equal(new.q.numpy(), np.broadcast_to(q[-1], (4, 2)))
    np.testing.assert_array_equal(new.qd_start.numpy(), [0.0, 0.0])
