"""The ITOMP baseline (paper sec. 7): the same optimiser, with the human as currently seen.

ITOMP replans against the observed pose only: no prediction and no uncertainty. To run the
same code path, the observed pose becomes a degenerate forecast: one action of weight 1, the
pose repeated over the horizon, and a tiny variance.

ITOMP's own paper (Park, Pan and Manocha, ICAPS 2012) plans against a conservative local
bound on where each moving obstacle can be over a short time. ``spread`` gives the held pose
a Gaussian stand-in for that bound: its standard deviation grows linearly with the time since
the observation. 0 (the default) is the pose held still.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch

from iplanner_torch.checks import integer, non_negative, positive
from iplanner_torch.errors import ConfigError
from iplanner_torch.planning.optimizer import PlanResult, TrajectoryOptimizer
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import check_shape


def static_human_forecast(
    pose: torch.Tensor,
    n_f: int,
    dt: float,
    joint_names: Sequence[str],
    *,
    std: float = 0.01,
    spread: float = 0.0,
) -> Forecast:
    """A forecast in which the human stays at ``pose`` (one action, weight 1).

    Args:
        pose: (K, 3) observed joint positions [m], world frame.
        n_f: frames of the forecast.
        dt: seconds between frames.
        joint_names: the K joint names.
        std: per-coordinate standard deviation at the observation [m] (1 cm: the pose is
            taken as exact).
        spread: growth of that standard deviation per second after the observation [m/s]:
            frame k (at ``k dt``, k = 1..n_f) has ``std + spread k dt``. 0 holds the pose
            still; > 0 stands in for ITOMP's conservative bound on a moving obstacle.

    Returns:
        Forecast with weights (1, 1), mean and var (1, 1, n_f, K, 3).

    Raises:
        ShapeError: when ``pose`` is not (K, 3) with K = len(joint_names).
        ConfigError: when n_f is not an integer >= 1, dt or std is not a finite number > 0,
            spread is negative or not finite, or ``joint_names`` is not a sequence of
            strings (one string is not).
    """
    check_shape("pose", pose, (len(_names(joint_names)), 3))
    integer("n_f", n_f, minimum=1)
    positive("dt", dt)
    positive("std", std)
    spread = non_negative("spread", spread)
    path = pose.unsqueeze(0).expand(n_f, *pose.shape)
    fc = path_forecast(path, dt, joint_names, std=std, action="observed")
    if spread > 0.0:
        t = dt * torch.arange(1, n_f + 1, dtype=fc.var.dtype, device=fc.var.device)  # (n_f,)
        s = std + spread * t
        fc = replace(fc, var=(s * s).view(1, 1, n_f, 1, 1).expand_as(fc.var).clone())
    return fc


def _names(joint_names: Sequence[str]) -> tuple[str, ...]:
    """``joint_names`` as a tuple; ConfigError unless it is a sequence of strings (a single
    string would be split into one-letter names)."""
    if isinstance(joint_names, str | bytes) or not isinstance(joint_names, Sequence):
        raise ConfigError(f"expected joint_names a sequence of strings, got {joint_names!r}")
    return tuple(joint_names)


def path_forecast(
    path: torch.Tensor,
    dt: float,
    joint_names: Sequence[str],
    *,
    std: float,
    action: str,
) -> Forecast:
    """A forecast in which the human follows ``path`` (one action of weight 1, isotropic
    ``std`` on every joint and frame).

    Args:
        path: (n_f, K, 3) joint positions [m] at dt, 2 dt, ..., n_f dt after the forecast's
            start, world frame.
        dt: seconds between frames.
        joint_names: the K joint names.
        std: per-coordinate standard deviation [m].
        action: the one action's name.

    Returns:
        Forecast with weights (1, 1), mean and var (1, 1, n_f, K, 3).

    Raises:
        ShapeError: when ``path`` is not (n_f, K, 3) with K = len(joint_names).
        ConfigError: when n_f < 1, dt or std is not a finite number > 0 (a bool is not one),
            or ``joint_names`` is not a sequence of strings (one string is not).
    """
    names = _names(joint_names)
    check_shape("path", path, ("n_f", len(names), 3))
    if path.shape[0] < 1:
        raise ConfigError(f"expected path with n_f >= 1 frames, got {tuple(path.shape)}")
    dt = positive("dt", dt)
    std = positive("std", std)
    mean = path.unsqueeze(0).unsqueeze(0).clone()
    return Forecast(
        weights=torch.ones(1, 1, dtype=path.dtype, device=path.device),
        mean=mean,
        var=torch.full_like(mean, std * std),
        dt=dt,
        joint_names=names,
        action_names=(action,),
    )


class ITOMP(TrajectoryOptimizer):
    """:class:`TrajectoryOptimizer` that sees only the currently observed human pose."""

    #: per-coordinate std of the observed pose [m]
    pose_std: float = 0.01

    def forecast_from_pose(
        self, pose: torch.Tensor, joint_names: Sequence[str], *, n_f: int = 30, dt: float = 0.1
    ) -> Forecast:
        """The degenerate forecast of :func:`static_human_forecast` for this planner."""
        return static_human_forecast(pose, n_f, dt, joint_names, std=self.pose_std)

    def solve_observed(
        self,
        q_start: torch.Tensor,
        q_goal: torch.Tensor,
        *,
        pose: torch.Tensor,
        joint_names: Sequence[str],
        t0: float = 0.0,
        **kwargs: object,
    ) -> PlanResult:
        """Plan against the observed pose.

        Args:
            q_start: (J,) start [rad].
            q_goal: (J,) goal [rad].
            pose: (K, 3) observed joint positions [m].
            joint_names: the K joint names.
            t0: plan start time [s]; the pose is taken as observed at ``t0``.
            **kwargs: further arguments of :meth:`TrajectoryOptimizer.solve`.
        """
        forecast = self.forecast_from_pose(pose, joint_names)
        return self.solve(q_start, q_goal, forecast=forecast, forecast_t0=t0, t0=t0, **kwargs)
