"""Planning numerics against references computed here by other methods.

* ``Trajectory.sample``: scipy's ``CubicHermiteSpline`` through the waypoints, with the
  documented tangents computed here in numpy.
* Waypoint differences and the smoothness cost: numpy's ``diff`` and Taylor expansions of
  polynomial motions (exact for quadratics).
* ``forecast_to_obstacle``: numpy's ``interp`` of every forecast coordinate, then the sphere
  map's rows applied one sphere at a time.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.interpolate import CubicHermiteSpline

from iplanner_torch.collision.human_spheres import HumanSphereMap
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.planning import costs as C
from iplanner_torch.planning.trajectory import Trajectory, accelerations, velocities
from iplanner_torch.prediction.forecast import Forecast

F64 = torch.float64


def _tangents(q: np.ndarray, t: np.ndarray, qd_start: np.ndarray | None) -> np.ndarray:
    """The documented tangents: central differences over the neighbouring waypoints, 0 where
    a joint holds or turns, ``qd_start`` (else 0) at the start, 0 at the end."""
    m = np.zeros_like(q)
    for i in range(1, len(t) - 1):
        for j in range(q.shape[1]):
            if (q[i + 1, j] - q[i, j]) * (q[i, j] - q[i - 1, j]) > 0:
                m[i, j] = (q[i + 1, j] - q[i - 1, j]) / (t[i + 1] - t[i - 1])
    if qd_start is not None:
        m[0] = qd_start
    return m


@pytest.mark.parametrize("uniform", [True, False])
def test_sample_equals_scipy_cubic_hermite_spline(uniform: bool) -> None:
    """Positions and velocities inside the span against scipy's spline and its derivative
    (float64: atol 1e-12), the end poses held at rest outside. Non-uniform times include a
    hold segment (``with_hold``), whose last interval is longer."""
    rng = np.random.default_rng(0 if uniform else 1)
    q = np.cumsum(rng.normal(size=(9, 3)), axis=0) * 0.2
    q[4, 1] = q[3, 1]  # a hold in one joint
    t = np.linspace(0.5, 2.5, 9) if uniform else np.cumsum(rng.uniform(0.1, 0.4, 9))
    qd0 = np.array([0.4, -0.3, 0.0])
    traj = Trajectory(q=torch.from_numpy(q), times=torch.from_numpy(t), qd_start=torch.tensor(qd0))
    if not uniform:
        traj = traj.with_hold(6, until=float(t[6]) + 0.9)
    tt, qq = traj.times.numpy(), traj.q.numpy()
    spline = CubicHermiteSpline(tt, qq, _tangents(qq, tt, traj.qd_start.numpy()))
    tq = np.concatenate([rng.uniform(tt[0], tt[-1], 200), tt])
    pos, vel = traj.sample(torch.from_numpy(tq))
    np.testing.assert_allclose(pos.numpy(), spline(tq), rtol=0, atol=1e-12)
    np.testing.assert_allclose(vel[:200].numpy(), spline(tq[:200], 1), rtol=0, atol=1e-10)
    before, v_before = traj.sample(float(tt[0]) - 1.0)
    after, v_after = traj.sample(float(tt[-1]) + 1.0)
    np.testing.assert_array_equal(before.numpy(), qq[0])
    np.testing.assert_array_equal(after.numpy(), qq[-1])
    assert not v_before.any() and not v_after.any()


def test_differences_and_smoothness_cost_equal_numpy() -> None:
    """``velocities``, interior ``accelerations`` and ``joint_acc_l2 = dt sum ||qdd||^2``
    against numpy's ``diff`` on random waypoints (float64: rtol 1e-12)."""
    rng = np.random.default_rng(2)
    q = rng.normal(size=(4, 11, 3))
    dt = 0.15
    vel = np.diff(q, axis=1) / dt
    acc = np.diff(q, n=2, axis=1) / dt**2
    qt = torch.from_numpy(q)
    np.testing.assert_allclose(velocities(qt, dt).numpy(), vel, rtol=1e-12)
    np.testing.assert_allclose(accelerations(qt, dt).numpy(), acc, rtol=1e-12, atol=1e-12)
    want = dt * (acc**2).sum(axis=(1, 2))
    np.testing.assert_allclose(C.joint_acc_l2(qt, dt).numpy(), want, rtol=1e-12)


def test_first_waypoint_acceleration_of_a_constant_acceleration_is_exact() -> None:
    """``q(t) = q0 + v0 t + a t^2 / 2`` with ``qd_start = v0``: Taylor's expansion gives the
    acceleration ``2 (q_1 - q_0 - v0 dt) / dt^2 = a`` exactly at the first waypoint, as the
    second differences give it at the interior ones (float64: rtol 1e-9)."""
    dt = 0.1
    t = dt * np.arange(8)
    v0, a = np.array([0.5, -1.0]), np.array([3.0, 2.0])
    q = v0 * t[:, None] + 0.5 * a * t[:, None] ** 2
    acc = accelerations(torch.from_numpy(q)[None], dt, qd_start=torch.from_numpy(v0))[0]
    np.testing.assert_allclose(acc[1:].numpy(), np.broadcast_to(a, (6, 2)), rtol=1e-9)
    np.testing.assert_allclose(acc[0].numpy(), a, rtol=1e-9)


def test_smoothness_cost_from_a_start_velocity_is_the_integral_of_the_squared_acceleration(
) -> None:  # fmt: skip
    """With a start velocity, the accelerations stand for the time from the start to the last
    segment's mid-point: ``(W - 1.5) dt``, the first one for its half step. On a motion of
    constant acceleration ``a`` the cost is then ``|a|^2 (W - 1.5) dt`` exactly (float64:
    rtol 1e-9)."""
    dt, w = 0.1, 8
    t = dt * np.arange(w)
    v0, a = np.array([0.5, -1.0]), np.array([3.0, 2.0])
    q = torch.from_numpy(v0 * t[:, None] + 0.5 * a * t[:, None] ** 2)[None]
    got = float(C.joint_acc_l2(q, dt, torch.from_numpy(v0))[0])
    assert got == pytest.approx(float(a @ a) * (w - 1.5) * dt, rel=1e-9)
    # without it, from the first interior waypoint's segment mid-point on: (W - 2) dt
    assert float(C.joint_acc_l2(q, dt)[0]) == pytest.approx(float(a @ a) * (w - 2) * dt, rel=1e-9)


def test_forecast_to_obstacle_equals_numpy_interpolation_and_the_sphere_rows() -> None:
    """Sphere-centre means and variances at query times before, between, on and after the
    forecast frames: every joint coordinate's mean and variance interpolated by ``np.interp``
    over the frame times ``t0 + (f + 1) dt`` (held at the ends), then each sphere's row of
    the map applied to the joints (``sum_k M_sk mu_k``, ``sum_k M_sk^2 var_k``), float64:
    rtol 1e-12; variances floored at 1e-10 as documented."""
    rng = np.random.default_rng(3)
    smap = HumanSphereMap.from_segments(JOINT_NAMES)
    n_f, k, a = 6, len(JOINT_NAMES), 2
    mean = rng.normal(size=(1, a, n_f, k, 3))
    var = rng.uniform(0.0, 0.01, size=(1, a, n_f, k, 3))
    var[0, 0, 2, 3, 1] = 0.0  # a zero variance: floored
    fc = Forecast(
        weights=torch.tensor([[0.3, 0.7]], dtype=F64),
        mean=torch.from_numpy(mean),
        var=torch.from_numpy(var),
        dt=0.1,
        joint_names=JOINT_NAMES,
        action_names=("a", "b"),
    )
    t0 = 5.0
    times = np.array([4.0, 5.0, 5.1, 5.137, 5.25, 5.6, 5.61, 9.0])
    obs = C.forecast_to_obstacle(fc, torch.from_numpy(times), t0, smap)
    frames = t0 + 0.1 * np.arange(1, n_f + 1)
    m_j = np.empty((len(times), a, k, 3))
    v_j = np.empty((len(times), a, k, 3))
    for ai in range(a):
        for kj in range(k):
            for c in range(3):
                m_j[:, ai, kj, c] = np.interp(times, frames, mean[0, ai, :, kj, c])
                v_j[:, ai, kj, c] = np.interp(times, frames, var[0, ai, :, kj, c])
    rows = smap.matrix.double().numpy()
    m_s = np.stack([sum(r[j] * m_j[:, :, j] for j in range(k)) for r in rows], axis=2)
    v_s = np.stack([sum(r[j] ** 2 * v_j[:, :, j] for j in range(k)) for r in rows], axis=2)
    np.testing.assert_allclose(obs.mean.numpy(), m_s, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(obs.var.numpy(), np.maximum(v_s, 1e-10), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(obs.radii.numpy(), smap.radii.double().numpy())
    np.testing.assert_allclose(obs.weights.numpy(), [0.3, 0.7])
