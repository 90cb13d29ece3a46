"""Space-time waypoint trajectories (paper sec. 3.2: Q = [q_s q_1 ... q_g; t_0 ... t_n]).

Waypoints are uniformly spaced in time. Between waypoints the executed motion is a cubic
Hermite spline whose tangents are central differences (Catmull-Rom), with a given velocity at
the start (continuity with the previous plan), rest at the end and where a joint holds or
turns (so a hold does not overshoot); before the first and after
the last waypoint the trajectory holds its end pose.

Inputs are checked where it is cheap: a :class:`Trajectory` checks its waypoints and times once,
at construction; :meth:`Trajectory.sample` checks a Python-number time (and the rank of a
tensor), the finite-difference helpers check a Python-number ``dt`` and the shapes of their
tensors, :func:`uniform_times` its Python numbers, and :func:`resample_linear` its times. The
values of tensors given to ``sample``, ``velocities`` and ``accelerations`` are not checked (the
optimiser calls them every iteration): a NaN there gives NaN in the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from iplanner_torch.checks import finite_time, integer, positive
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.types import check_finite, check_shape

#: Largest spacing of the floating-point numbers around the waypoint times that
#: :func:`uniform_times` accepts, as a share of the time between waypoints: each waypoint time
#: is rounded by up to half a spacing, so each interval is off by up to this share. In float32
#: the spacing is 2^-10 s (about 1 ms) from 8192 s to 16384 s after the time origin, so a plan
#: of the default 20 waypoints over at least 1 s (0.053 s apart) is accepted for the first
#: 16384 s (4.5 h) of an episode; a Unix timestamp (1.7e9 s, spacing 128 s) is refused.
TIME_RESOLUTION = 0.02


def _check_positive(name: str, value: float | torch.Tensor) -> None:
    """:func:`~iplanner_torch.checks.positive` for a Python number (a tensor is not checked)."""
    if not isinstance(value, torch.Tensor):
        positive(name, value)


def _check_waypoints(q: torch.Tensor, qd_start: torch.Tensor | None = None) -> None:
    """ShapeError unless ``q`` is (..., W, J) and ``qd_start`` (when given) (..., J) with W >= 2
    (the first waypoint's acceleration needs the second waypoint)."""
    check_shape("q", q, ("...", "W", "J"))
    if qd_start is not None:
        check_shape("qd_start", qd_start, ("...", q.shape[-1]))
        lead, given = tuple(q.shape[:-2]), tuple(qd_start.shape[:-1])
        # broadcastable to q's leading dimensions (a Python test, no torch call)
        if len(given) > len(lead) or any(
            s not in (1, t) for s, t in zip(reversed(given), reversed(lead), strict=False)
        ):
            raise ShapeError(
                f"expected qd_start (..., J) whose leading dimensions broadcast to those of q "
                f"{tuple(q.shape)}: {lead}, got {tuple(qd_start.shape)}"
            )
        if q.shape[-2] < 2:
            raise ShapeError(
                f"expected q (..., W, J) with W >= 2 when qd_start is given, got {tuple(q.shape)}"
            )


def velocities(q: torch.Tensor, dt: float) -> torch.Tensor:
    """Forward-difference velocities between consecutive waypoints.

    Args:
        q: (..., W, J) joint positions [rad].
        dt: seconds between waypoints, finite and > 0.

    Returns:
        (..., W - 1, J) velocities [rad/s]; entry i is (q_{i+1} - q_i) / dt.

    Raises:
        ShapeError: when ``q`` has fewer than 2 dimensions (no joint axis).
        ConfigError: when ``dt`` (a Python number) is not finite and > 0.
    """
    _check_waypoints(q)
    _check_positive("dt", dt)
    return (q[..., 1:, :] - q[..., :-1, :]) / dt


def accelerations(
    q: torch.Tensor, dt: float, qd_start: torch.Tensor | None = None
) -> torch.Tensor:
    """Second-difference accelerations at the interior waypoints.

    Args:
        q: (..., W, J) joint positions [rad].
        dt: seconds between waypoints, finite and > 0.
        qd_start: (..., J) or (J,) velocity at the first waypoint [rad/s], its leading
            dimensions broadcastable to those of ``q``; when given, the
            acceleration at the first waypoint ``2 ((q_1 - q_0) / dt - qd_start) / dt`` is
            prepended: the change from ``qd_start`` to the first segment's mean velocity,
            which is the velocity half a step later (exact for a constant acceleration, as the
            second differences are).

    Returns:
        (..., W - 2, J) accelerations [rad/s^2] (``W - 1`` rows when ``qd_start`` is given).

    Raises:
        ShapeError: when ``q`` has fewer than 2 dimensions (no joint axis), ``qd_start`` does
            not end in J or its leading dimensions do not broadcast to ``q``'s, or
            ``qd_start`` is given with fewer than 2 waypoints.
        ConfigError: when ``dt`` (a Python number) is not finite and > 0.
    """
    _check_waypoints(q, qd_start)
    _check_positive("dt", dt)
    acc = (q[..., 2:, :] - 2.0 * q[..., 1:-1, :] + q[..., :-2, :]) / (dt * dt)
    if qd_start is None:
        return acc
    a0 = 2.0 * ((q[..., 1, :] - q[..., 0, :]) / dt - qd_start) / dt
    return torch.cat([a0.unsqueeze(-2).expand(*acc.shape[:-2], 1, acc.shape[-1]), acc], dim=-2)


def uniform_times(
    t0: float, duration: float, num_waypoints: int, like: torch.Tensor
) -> torch.Tensor:
    """(W,) waypoint times [s] from ``t0`` to ``t0 + duration``, on ``like``'s device/dtype.

    Args:
        t0: time of the first waypoint [s]; relative to the start of the episode (a Unix
            timestamp is too large for float32 times, see :data:`TIME_RESOLUTION`).
        duration: seconds from the first to the last waypoint, finite and > 0.
        num_waypoints: W, an integer >= 2.
        like: any tensor of a floating dtype: the device and dtype of the times.

    Raises:
        ShapeError: when ``like`` is not a tensor of a floating dtype (integer times would be
            truncated).
        ConfigError: when ``t0`` is not finite or ``duration`` not finite and > 0 (Python
            numbers; tensors are not checked), when ``num_waypoints`` is not an integer >= 2,
            or when ``like``'s dtype cannot hold the times or resolve the waypoint spacing at
            ``t0`` (its rounding there exceeds :data:`TIME_RESOLUTION` of the spacing; Python
            numbers only).
    """
    if not isinstance(like, torch.Tensor):
        raise ShapeError(f"expected like to be a torch.Tensor, got {type(like).__name__}")
    if not like.is_floating_point():
        raise ShapeError(f"expected like of a floating dtype (the times'), got {like.dtype}")
    integer("num_waypoints", num_waypoints, minimum=2)
    _check_positive("duration", duration)
    if not isinstance(t0, torch.Tensor):
        start = finite_time("t0", t0)
        if not isinstance(duration, torch.Tensor):
            _check_resolution(start, float(duration), num_waypoints, like.dtype)
    return t0 + torch.linspace(0.0, duration, num_waypoints, device=like.device, dtype=like.dtype)


def _check_resolution(t0: float, duration: float, num_waypoints: int, dtype: torch.dtype) -> None:
    """ConfigError when the spacing of ``dtype``'s numbers at the waypoint times exceeds
    :data:`TIME_RESOLUTION` times the time between waypoints."""
    step = duration / (num_waypoints - 1)
    largest = max(abs(t0), abs(t0 + duration))
    if largest > torch.finfo(dtype).max:  # torch.linspace would raise a bare RuntimeError
        raise ConfigError(
            f"expected waypoint times within {dtype}'s range (<= {torch.finfo(dtype).max:.3g}), "
            f"got t0={t0!r} s and duration={duration!r} s"
        )
    # spacing of the floats in [2^(e-1), 2^e) that holds ``largest``: eps * 2^(e-1)
    spacing = math.inf
    if math.isfinite(largest):  # (t0 + duration may overflow)
        spacing = torch.finfo(dtype).eps * 2.0 ** (math.frexp(largest)[1] - 1)
    if spacing > TIME_RESOLUTION * step:
        raise ConfigError(
            f"expected waypoint times that {dtype} resolves: at t0={t0!r} s its numbers are "
            f"{spacing:.3g} s apart, too coarse for waypoints {step:.3g} s apart (at most "
            f"{TIME_RESOLUTION:g} of it); pass times relative to the episode start, not "
            "absolute (Unix) times"
        )


@dataclass(kw_only=True)
class Trajectory:
    """One space-time trajectory.

    Attributes:
        q: (W, J) waypoint joint positions [rad], finite.
        times: (W,) waypoint times [s], finite and strictly increasing (uniform from the
            optimiser; a hold segment may make the last interval longer).
        qd_start: (J,) velocity at the first waypoint [rad/s], finite; None means rest.

    Raises:
        ShapeError: for mismatched shapes, fewer than 2 waypoints, a dtype that is not
            floating or differs from ``q``'s, or a device other than ``q``'s (or ``meta``).
        DataError: for a NaN or infinite waypoint, time or start velocity.
        ConfigError: for times that are not strictly increasing.
    """

    q: torch.Tensor
    times: torch.Tensor
    qd_start: torch.Tensor | None = None
    # (W, J) tangents, computed on the first sample (the waypoints are not changed after)
    _tangent_cache: torch.Tensor | None = field(
        default=None, init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        check_shape("q", self.q, ("W", "J"))
        check_shape("times", self.times, (self.q.shape[0],))
        if self.q.shape[0] < 2:
            raise ShapeError(f"expected at least 2 waypoints, got q {tuple(self.q.shape)}")
        if self.qd_start is not None:
            check_shape("qd_start", self.qd_start, (self.q.shape[1],))
        if not self.q.is_floating_point():
            raise ShapeError(f"expected q of a floating dtype, got {self.q.dtype}")
        for name in ("times", "qd_start"):
            x = getattr(self, name)
            if x is not None and x.dtype != self.q.dtype:
                raise ShapeError(f"expected {name} {self.q.dtype} (as q), got {x.dtype}")
            if x is not None and x.device != self.q.device:  # (torch's error named neither)
                raise ShapeError(f"expected {name} on {self.q.device} (as q), got {x.device}")
        if self.q.device.type == "meta":  # no values to check or sample
            raise ShapeError("expected q with values, got a tensor on the 'meta' device")
        # one host synchronisation for all checks (a trajectory is built once per cycle)
        checks = [
            torch.isfinite(self.times).all(),
            torch.isfinite(self.q).all(),
            (self.times[1:] > self.times[:-1]).all(),
        ]
        if self.qd_start is not None:
            checks.append(torch.isfinite(self.qd_start).all())
        ok = torch.stack(checks).tolist()
        if not ok[0]:
            check_finite("times", self.times, ("waypoint",))
        if not ok[1]:
            check_finite("q", self.q, ("waypoint", "joint"))
        if not ok[2]:
            raise ConfigError("expected strictly increasing waypoint times")
        if self.qd_start is not None and not ok[3]:
            check_finite("qd_start", self.qd_start, ("joint",))

    @property
    def t_start(self) -> float:
        """Time of the first waypoint [s]."""
        return float(self.times[0])

    @property
    def t_end(self) -> float:
        """Time of the last waypoint [s]."""
        return float(self.times[-1])

    def _tangents(self) -> torch.Tensor:
        """(W, J) Catmull-Rom tangents [rad/s]; given velocity at the start, rest at the end
        and wherever a joint holds or turns."""
        q, t = self.q, self.times
        m = torch.zeros_like(q)
        if q.shape[0] > 2:
            m[1:-1] = (q[2:] - q[:-2]) / (t[2:] - t[:-2]).unsqueeze(-1)
            # rest at holds and turning points (no overshoot past a waypoint)
            turn = (q[2:] - q[1:-1]) * (q[1:-1] - q[:-2]) <= 0.0
            m[1:-1] = torch.where(turn, torch.zeros_like(m[1:-1]), m[1:-1])
        if self.qd_start is not None:
            m[0] = self.qd_start
        return m

    def sample(self, t: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Positions and velocities of the cubic Hermite spline at times ``t``.

        Args:
            t: scalar or (N,) query times [s]; outside [t_start, t_end] the end pose is held
                with zero velocity. A Python number must be finite; a tensor is not checked
                (a NaN time gives NaN rows).

        Returns:
            q (J,) or (N, J) [rad] and qd of the same shape [rad/s].

        Raises:
            DataError: when ``t`` is a NaN or infinite Python number.
            ShapeError: when ``t`` is a tensor of more than one dimension.
        """
        if not isinstance(t, torch.Tensor):
            finite_time("t", t, error=DataError)
            scalar = True
        else:
            if t.dim() > 1:
                raise ShapeError(f"expected t a scalar or (N,), got {tuple(t.shape)}")
            scalar = t.dim() == 0
        tq = torch.as_tensor(t, dtype=self.times.dtype, device=self.times.device).reshape(-1)
        times, q = self.times, self.q
        if self._tangent_cache is None:
            self._tangent_cache = self._tangents()
        m = self._tangent_cache
        idx = torch.searchsorted(times, tq, right=True) - 1
        idx = idx.clamp(0, times.shape[0] - 2)
        t_a, t_b = times[idx], times[idx + 1]
        h = (t_b - t_a).unsqueeze(-1)  # (N, 1)
        s = ((tq - t_a) / (t_b - t_a)).clamp(0.0, 1.0).unsqueeze(-1)  # (N, 1)
        p0, p1, m0, m1 = q[idx], q[idx + 1], m[idx] * h, m[idx + 1] * h
        s2, s3 = s * s, s * s * s
        pos = (
            (2 * s3 - 3 * s2 + 1) * p0
            + (s3 - 2 * s2 + s) * m0
            + (-2 * s3 + 3 * s2) * p1
            + (s3 - s2) * m1
        )
        vel = (
            (6 * s2 - 6 * s) * p0
            + (3 * s2 - 4 * s + 1) * m0
            + (-6 * s2 + 6 * s) * p1
            + (3 * s2 - 2 * s) * m1
        ) / h
        outside = ((tq < times[0]) | (tq > times[-1])).unsqueeze(-1)
        vel = torch.where(outside, torch.zeros_like(vel), vel)
        if scalar:
            return pos[0], vel[0]
        return pos, vel

    def resample(self, t0: float, duration: float, num_waypoints: int) -> Trajectory:
        """The trajectory sampled at ``num_waypoints`` uniform times from ``t0`` (a warm start).

        Args:
            t0: new start time [s].
            duration: new span [s].
            num_waypoints: W of the result.

        Raises:
            ConfigError: when ``num_waypoints`` is not an integer >= 2 (a trajectory has at
                least 2 waypoints), or ``t0`` or ``duration`` is not valid
                (:func:`uniform_times`).
        """
        integer("num_waypoints", num_waypoints, minimum=2)
        times = uniform_times(t0, duration, num_waypoints, self.times)
        q, qd = self.sample(times)
        return Trajectory(q=q, times=times, qd_start=qd[0])

    def with_hold(self, index: int, until: float) -> Trajectory:
        """Keep waypoints ``0..index`` and hold ``q[index]`` until time ``until`` (paper sec. 5:
        a waypoint appended at the last safe pose makes the robot wait).

        The robot is at rest at ``q[index]`` and stays there: holding the first waypoint
        drops ``qd_start``.

        Args:
            index: last waypoint kept.
            until: time [s] to hold the pose to; later than ``times[index]`` (the hold lasts at
                least 1 ms).

        Raises:
            ConfigError: when ``index`` is not an integer in range, or ``until`` is not finite
                or not later than ``times[index]``.
        """
        n = self.q.shape[0]
        integer("hold index", index)
        if not 0 <= index < n:
            raise ConfigError(f"expected hold index in [0, {n}), got {index}")
        finite_time("until", until)
        q = self.q[: index + 1]
        times = self.times[: index + 1]
        if not float(until) > float(times[-1]):
            raise ConfigError(
                f"expected until later than times[{index}] = {float(times[-1])!r} s, "
                f"got {float(until)!r}"
            )
        t_hold = max(float(until), float(times[-1]) + 1e-3)
        q = torch.cat([q, q[-1:]], dim=0)
        times = torch.cat([times, times.new_tensor([t_hold])])
        qd_start = None if index == 0 else self.qd_start
        return replace(self, q=q, times=times, qd_start=qd_start)


def resample_linear(q: torch.Tensor, times: torch.Tensor, new_times: torch.Tensor) -> torch.Tensor:
    """Piecewise-linear resampling of a batch of trajectories (holding the end poses).

    Args:
        q: (B, W, J) joint positions [rad] at ``times``.
        times: (W,) strictly increasing times [s], W >= 2.
        new_times: (W',) query times [s]; those outside ``times`` (an infinity included)
            hold the end poses.

    Returns:
        (B, W', J) joint positions [rad].

    Raises:
        ShapeError: on inputs of the wrong shape, or fewer than 2 times.
        DataError: when ``times`` holds NaN or inf, or ``new_times`` NaN.
        ConfigError: when ``times`` is not strictly increasing.
    """
    check_shape("q", q, ("B", "W", "J"))
    check_shape("times", times, (q.shape[1],))
    check_shape("new_times", new_times, ("W'",))
    if times.shape[0] < 2:
        raise ShapeError(f"expected at least 2 times, got times {tuple(times.shape)}")
    # strictly increasing times hold no NaN and can only be infinite at their ends: one host
    # synchronisation tests both
    ends = torch.isfinite(times[0]) & torch.isfinite(times[-1])
    queries = ~torch.isnan(new_times).any()  # (NaN would give NaN rows)
    if not bool((times[1:] > times[:-1]).all() & ends & queries):
        check_finite("times", times, ("waypoint",))
        if not bool(queries):
            i = int(torch.isnan(new_times).nonzero()[0, 0])
            raise DataError(f"new_times is NaN at query {i}")
        raise ConfigError("expected strictly increasing times")
    tq = new_times.clamp(times[0], times[-1])
    idx = (torch.searchsorted(times, tq, right=True) - 1).clamp(0, times.shape[0] - 2)
    a = ((tq - times[idx]) / (times[idx + 1] - times[idx])).view(1, -1, 1)  # (1, W', 1)
    return (1.0 - a) * q[:, idx] + a * q[:, idx + 1]
