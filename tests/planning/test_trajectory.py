"""Trajectories: finite differences, Hermite sampling, holds, resampling."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch

from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.planning.trajectory import (
    TIME_RESOLUTION,
    Trajectory,
    accelerations,
    resample_linear,
    uniform_times,
    velocities,
)


def test_differences_of_a_quadratic_are_exact() -> None:
    t = torch.linspace(0.0, 2.0, 11, dtype=torch.float64)
    a = torch.tensor([0.5, -1.5], dtype=torch.float64)
    q = (t[:, None] ** 2) * a  # (W, J)
    dt = float(t[1] - t[0])
    acc = accelerations(q.unsqueeze(0), dt)[0]
    assert torch.allclose(acc, (2 * a).expand_as(acc), atol=1e-9)
    vel = velocities(q, dt)
    assert torch.allclose(vel, (t[:-1] + t[1:])[:, None] * a, atol=1e-9)
    acc0 = accelerations(q.unsqueeze(0), dt, qd_start=torch.zeros(2, dtype=torch.float64))[0]
    assert acc0.shape == (10, 2)
    assert torch.allclose(acc0[0], 2 * a, atol=1e-9)  # from rest: q_1 - q_0 = a dt^2


def test_sample_passes_waypoints_and_velocity_is_derivative() -> None:
    gen = torch.Generator().manual_seed(3)
    times = uniform_times(1.0, 2.0, 9, torch.zeros((), dtype=torch.float64))
    q = torch.randn(9, 3, generator=gen, dtype=torch.float64)
    traj = Trajectory(
        q=q, times=times, qd_start=torch.tensor([0.3, 0.0, -0.2], dtype=torch.float64)
    )
    pos, _ = traj.sample(times)
    assert torch.allclose(pos, q, atol=1e-12)
    # velocity against central finite differences of the sampled positions
    tq = torch.linspace(1.01, 2.99, 57, dtype=torch.float64)
    h = 1e-6
    p_plus, _ = traj.sample(tq + h)
    p_minus, _ = traj.sample(tq - h)
    _, vel = traj.sample(tq)
    assert torch.allclose(vel, (p_plus - p_minus) / (2 * h), atol=1e-4)
    _, v0 = traj.sample(times[0])
    assert torch.allclose(v0, traj.qd_start)
    _, v_end = traj.sample(times[-1] - 1e-12)
    assert float(v_end.abs().max()) < 1e-6


def test_sample_holds_outside_and_linear_motion_is_reproduced() -> None:
    times = torch.linspace(0.0, 1.0, 5)
    q = torch.linspace(0.0, 1.0, 5)[:, None].repeat(1, 2)
    traj = Trajectory(q=q, times=times, qd_start=torch.ones(2))
    qa, va = traj.sample(-1.0)
    qb, vb = traj.sample(5.0)
    assert torch.equal(qa, q[0]) and torch.equal(qb, q[-1])
    assert float(va.abs().max()) == 0.0 and float(vb.abs().max()) == 0.0
    qm, vm = traj.sample(torch.tensor([0.3, 0.6]))
    assert torch.allclose(qm[:, 0], torch.tensor([0.3, 0.6]), atol=1e-6)
    assert torch.allclose(vm, torch.ones(2, 2), atol=1e-5)


def test_with_hold_and_resample() -> None:
    times = torch.linspace(0.0, 1.0, 6)
    q = torch.arange(12.0).view(6, 2)
    held = Trajectory(q=q, times=times).with_hold(2, until=3.0)
    assert held.q.shape == (4, 2) and torch.equal(held.q[3], q[2])
    assert held.t_end == pytest.approx(3.0)
    assert torch.equal(held.sample(2.5)[0], q[2])
    with pytest.raises(ConfigError, match="hold index"):
        Trajectory(q=q, times=times).with_hold(9, until=2.0)
    new_t = torch.linspace(-0.5, 1.5, 13)
    out = resample_linear(q.unsqueeze(0), times, new_t)[0]
    for j in range(2):
        ref = np.interp(new_t.numpy(), times.numpy(), q[:, j].numpy())
        assert np.allclose(out[:, j].numpy(), ref, atol=1e-6)
    re = Trajectory(q=q, times=times).resample(0.2, 0.5, 4)
    assert re.q.shape == (4, 2) and re.t_start == pytest.approx(0.2)


def test_trajectory_validates_inputs() -> None:
    with pytest.raises(ShapeError, match=r"expected times \(3\), got \(4,\)"):
        Trajectory(q=torch.zeros(3, 2), times=torch.zeros(4))
    with pytest.raises(ConfigError, match="strictly increasing"):
        Trajectory(q=torch.zeros(3, 2), times=torch.tensor([0.0, 0.0, 1.0]))


def test_non_finite_times_and_waypoints_are_rejected_at_construction() -> None:
    q = torch.zeros(4, 2)
    with pytest.raises(DataError, match="times is NaN/Inf at waypoint 1"):
        Trajectory(q=q, times=torch.tensor([0.0, math.nan, 2.0, 3.0]))
    with pytest.raises(DataError, match="times is NaN/Inf at waypoint 3"):
        Trajectory(q=q, times=torch.tensor([0.0, 1.0, 2.0, math.inf]))
    bad_q = q.clone()
    bad_q[2, 1] = math.nan
    with pytest.raises(DataError, match="q is NaN/Inf at waypoint 2, joint 1"):
        Trajectory(q=bad_q, times=torch.arange(4.0))
    with pytest.raises(DataError, match="qd_start is NaN/Inf at joint 1"):
        Trajectory(q=q, times=torch.arange(4.0), qd_start=torch.tensor([0.0, math.inf]))
    with pytest.raises(ConfigError, match="expected until a finite time"):
        Trajectory(q=q, times=torch.arange(4.0)).with_hold(1, until=math.nan)


def test_sample_rejects_a_non_finite_python_time() -> None:
    traj = Trajectory(q=torch.zeros(3, 2), times=torch.arange(3.0))
    for t in (math.nan, math.inf, -math.inf):
        with pytest.raises(DataError, match="expected t a finite time"):
            traj.sample(t)
    # far outside the span but finite: the end pose is held
    assert torch.equal(traj.sample(1e9)[0], traj.q[-1])


@pytest.mark.parametrize("dt", [0.0, -0.1, math.nan, math.inf])
def test_differences_reject_a_bad_dt(dt: float) -> None:
    q = torch.zeros(1, 5, 2)
    with pytest.raises(ConfigError, match="expected dt > 0 and finite"):
        velocities(q, dt)
    with pytest.raises(ConfigError, match="expected dt > 0 and finite"):
        accelerations(q, dt, qd_start=torch.zeros(2))


def test_uniform_times_rejects_non_finite_or_empty_spans() -> None:
    like = torch.zeros(())
    with pytest.raises(ConfigError, match="expected t0 a finite time"):
        uniform_times(math.nan, 1.0, 5, like)
    with pytest.raises(ConfigError, match="duration > 0 and finite"):
        uniform_times(0.0, math.inf, 5, like)
    with pytest.raises(ConfigError, match="duration > 0 and finite"):
        uniform_times(0.0, 0.0, 5, like)
    with pytest.raises(ConfigError, match="duration > 0 and finite"):
        Trajectory(q=torch.zeros(3, 2), times=torch.arange(3.0)).resample(0.0, math.nan, 4)


def test_hold_of_the_first_waypoint_holds_despite_a_start_velocity() -> None:
    q = torch.tensor([[0.0], [0.5], [1.0]])
    traj = Trajectory(q=q, times=torch.tensor([0.0, 0.5, 1.0]), qd_start=torch.tensor([2.0]))
    held = traj.with_hold(0, until=1.0)
    pos, vel = held.sample(torch.linspace(0.0, 1.0, 11))
    assert torch.equal(pos, torch.zeros(11, 1)) and torch.equal(vel, torch.zeros(11, 1))
    # later holds keep the start velocity, and hold all the same
    later = traj.with_hold(1, until=2.0)
    assert torch.equal(later.qd_start, traj.qd_start)
    assert torch.equal(later.sample(torch.linspace(0.5, 2.0, 7))[0], q[1].expand(7, 1))


@pytest.mark.parametrize(("index", "until"), [(2, 0.5), (2, 1.0), (0, -1.0), (1, 0.5)])
def test_with_hold_refuses_an_until_not_after_the_held_waypoint(index: int, until: float) -> None:
    traj = Trajectory(q=torch.zeros(3, 2), times=torch.tensor([0.0, 0.5, 1.0]))
    with pytest.raises(ConfigError, match=rf"expected until later than times\[{index}\]"):
        traj.with_hold(index, until)


@pytest.mark.parametrize("index", [True, 1.5])
def test_with_hold_refuses_a_non_integer_index(index: object) -> None:
    traj = Trajectory(q=torch.zeros(3, 2), times=torch.arange(3.0))
    with pytest.raises(ConfigError, match="expected hold index an integer"):
        traj.with_hold(index, until=5.0)  # type: ignore[arg-type]


@pytest.mark.parametrize("n", [0, 1, -1, 2.5, True])
def test_resample_refuses_a_bad_waypoint_count(n: object) -> None:
    traj = Trajectory(q=torch.zeros(3, 2), times=torch.arange(3.0))
    with pytest.raises(ConfigError, match="expected num_waypoints an integer >= 2"):
        traj.resample(0.0, 1.0, n)  # type: ignore[arg-type]


def test_resample_linear_validates_its_times() -> None:
    q = torch.zeros(1, 3, 2)
    new_t = torch.tensor([0.5])
    with pytest.raises(ShapeError, match=r"expected at least 2 times, got times \(1,\)"):
        resample_linear(q[:, :1], torch.tensor([0.0]), new_t)
    with pytest.raises(ConfigError, match="expected strictly increasing times"):
        resample_linear(q, torch.tensor([2.0, 1.0, 0.0]), new_t)
    with pytest.raises(ConfigError, match="expected strictly increasing times"):
        resample_linear(q, torch.tensor([0.0, 1.0, 1.0]), new_t)
    with pytest.raises(DataError, match="times is NaN/Inf at waypoint 1"):
        resample_linear(q, torch.tensor([0.0, math.nan, 2.0]), new_t)
    with pytest.raises(ShapeError, match=r"expected times \(3\), got \(2,\)"):
        resample_linear(q, torch.tensor([0.0, 1.0]), new_t)
    # a NaN query gave a NaN row; infinite ones hold the end poses
    with pytest.raises(DataError, match=r"^new_times is NaN at query 1$"):
        resample_linear(q, torch.tensor([0.0, 1.0, 2.0]), torch.tensor([0.5, math.nan]))
    ramp = torch.tensor([[[0.0, 0.0], [1.0, 2.0], [2.0, 4.0]]])
    ends = torch.tensor([-math.inf, math.inf])
    held = resample_linear(ramp, torch.tensor([0.0, 1.0, 2.0]), ends)
    assert held.tolist() == [[[0.0, 0.0], [2.0, 4.0]]]


@pytest.mark.parametrize("dtype", [torch.bool, torch.int64])
def test_trajectory_refuses_non_floating_waypoints(dtype: torch.dtype) -> None:
    with pytest.raises(ShapeError, match=f"expected q of a floating dtype, got {dtype}"):
        Trajectory(q=torch.zeros(3, 2, dtype=dtype), times=torch.arange(3.0))


def test_trajectory_refuses_mixed_float_dtypes() -> None:
    q = torch.zeros(3, 2)
    times64 = torch.arange(3.0, dtype=torch.float64)
    with pytest.raises(
        ShapeError, match=r"expected times torch.float32 \(as q\), got torch.float64"
    ):
        Trajectory(q=q, times=times64)
    with pytest.raises(
        ShapeError, match=r"expected times torch.float64 \(as q\), got torch.float32"
    ):
        Trajectory(q=q.double(), times=torch.arange(3.0))
    with pytest.raises(ShapeError, match=r"expected qd_start torch.float32 \(as q\)"):
        Trajectory(q=q, times=torch.arange(3.0), qd_start=torch.zeros(2, dtype=torch.float64))


def test_sample_refuses_a_time_tensor_of_more_than_one_dimension() -> None:
    traj = Trajectory(q=torch.zeros(3, 2), times=torch.arange(3.0))
    with pytest.raises(ShapeError, match=r"expected t a scalar or \(N,\), got \(1, 2\)"):
        traj.sample(torch.tensor([[0.5, 1.5]]))
    assert traj.sample(torch.tensor(0.5))[0].shape == (2,)
    assert traj.sample(torch.tensor([0.5, 1.5]))[0].shape == (2, 2)


def test_uniform_times_refuse_a_t0_float32_cannot_resolve() -> None:
    """A Unix timestamp in float32 (spacing 128 s at 1.7e9 s) used to give equal times."""
    like = torch.zeros(())
    with pytest.raises(ConfigError, match="pass times relative to the episode start"):
        uniform_times(1.7e9, 1.0, 20, like)
    with pytest.raises(ConfigError, match=r"numbers are 128 s apart"):
        Trajectory(q=torch.zeros(3, 2), times=torch.arange(3.0)).resample(1.7e9, 1.0, 20)
    # float64 resolves it
    times = uniform_times(1.7e9, 1.0, 20, like.double())
    assert bool((times[1:] > times[:-1]).all())
    # episodes of hours of simulated time still plan in float32: the default plan (20
    # waypoints over 1 s) keeps its intervals within TIME_RESOLUTION of 1/19 s
    for t0 in (0.0, 60.0, 3600.0, 4 * 3600.0, -4 * 3600.0):
        times = uniform_times(t0, 1.0, 20, like)
        step = (times[1:] - times[:-1]).double()
        assert float((step - 1.0 / 19).abs().max()) <= TIME_RESOLUTION / 19, t0
        Trajectory(q=torch.zeros(20, 2), times=times)  # strictly increasing


def test_uniform_times_refuse_integer_times_and_bad_counts() -> None:
    """An integer ``like`` used to truncate the times to [0, 0, 1]; a bad count raised raw."""
    with pytest.raises(ShapeError, match="expected like of a floating dtype.*torch.int64"):
        uniform_times(0.0, 1.0, 3, torch.zeros((), dtype=torch.int64))
    with pytest.raises(ShapeError, match="expected like to be a torch.Tensor, got float"):
        uniform_times(0.0, 1.0, 3, 0.0)  # type: ignore[arg-type]
    for n in (-1, 2.5, 1, True):
        with pytest.raises(ConfigError, match="expected num_waypoints an integer >= 2"):
            uniform_times(0.0, 1.0, n, torch.zeros(()))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("times", "where"),
    [([0.0, 1.0, 2.0, 3.0, math.inf], 4), ([-math.inf, 1.0, 2.0, 3.0, 4.0], 0)],
)
def test_resample_linear_refuses_infinite_times(times: list[float], where: int) -> None:
    """Increasing times ending in inf used to pass (the docstring promised DataError)."""
    q = torch.zeros(1, 5, 2)
    with pytest.raises(DataError, match=f"times is NaN/Inf at waypoint {where}"):
        resample_linear(q, torch.tensor(times), torch.tensor([0.5]))


def test_differences_refuse_waypoints_without_a_joint_axis() -> None:
    """A (W,) path used to raise IndexError (or, with W = 1, index out of range)."""
    with pytest.raises(ShapeError, match=r"expected q \(\.\.\., W, J\), got \(5,\)"):
        velocities(torch.zeros(5), 0.1)
    with pytest.raises(ShapeError, match=r"expected q \(\.\.\., W, J\), got \(5,\)"):
        accelerations(torch.zeros(5), 0.1)
    with pytest.raises(ShapeError, match=r"expected qd_start \(\.\.\., 2\), got \(3,\)"):
        accelerations(torch.zeros(1, 4, 2), 0.1, torch.zeros(3))
    with pytest.raises(ShapeError, match="with W >= 2 when qd_start is given"):
        accelerations(torch.zeros(1, 1, 2), 0.1, torch.zeros(2))


def test_uniform_times_beyond_the_dtype_range_are_a_config_error() -> None:
    """A float32 span past 3.4e38 s was a bare RuntimeError from torch.linspace."""
    with pytest.raises(ConfigError, match=r"expected waypoint times within torch.float32's"):
        uniform_times(0.0, 1e300, 5, torch.zeros(1))
    assert uniform_times(0.0, 1e300, 5, torch.zeros(1, dtype=torch.float64))[-1] == 1e300


def test_accelerations_refuse_a_start_velocity_that_does_not_broadcast() -> None:
    """It was torch's size-mismatch or expand error; one that broadcasts is taken, and a
    batch of start velocities gives each trajectory its own first row."""
    q = torch.randn(3, 8, 7, dtype=torch.float64)
    for bad in (torch.zeros(5, 7), torch.zeros(2, 3, 7)):
        with pytest.raises(ShapeError, match=r"qd_start .*broadcast to those of q \(3, 8, 7\): "
                           rf"\(3,\), got {re.escape(str(tuple(bad.shape)))}"):  # fmt: skip
            accelerations(q, 0.1, bad.double())
    with pytest.raises(ShapeError, match=r"broadcast to those of q \(8, 7\): \(\), got \(3, 7\)"):
        accelerations(q[0], 0.1, torch.zeros(3, 7, dtype=torch.float64))
    qd = torch.randn(3, 7, dtype=torch.float64)
    acc = accelerations(q, 0.1, qd)
    assert acc.shape == (3, 7, 7)
    for b in range(3):
        torch.testing.assert_close(acc[b], accelerations(q[b], 0.1, qd[b]))
    torch.testing.assert_close(
        accelerations(q, 0.1, qd[:1]), accelerations(q, 0.1, qd[:1].expand(3, 7))
    )
    torch.testing.assert_close(accelerations(q, 0.1, qd[0]), accelerations(q, 0.1, qd[:1]))


def test_a_hold_lasts_at_least_a_millisecond() -> None:
    """An ``until`` a microsecond after the held waypoint (0.5 s) still holds to 0.5 + 1e-3 s;
    an ``until`` farther away is kept as given."""
    f64 = torch.float64
    traj = Trajectory(
        q=torch.tensor([[0.0], [1.0], [2.0]], dtype=f64),
        times=torch.tensor([0.0, 0.5, 1.0], dtype=f64),
    )
    short = traj.with_hold(1, until=0.5 + 1e-6)
    assert short.times.tolist() == pytest.approx([0.0, 0.5, 0.501], abs=1e-12)
    assert torch.equal(short.q[-1], traj.q[1])
    assert traj.with_hold(1, until=0.75).times.tolist() == [0.0, 0.5, 0.75]
