"""Interleaved planning and execution (paper sec. 5, ITOMP's replanning with step m).

At a cycle due at time ``t`` the plan currently executing is kept until ``t + m``; the new plan
starts where the current one will be at ``t + m`` (position and velocity) and is checked
against the human over its execution window ``[t + m, t + 2m]``. Solves are warm-started from
the previous cycle's trajectories shifted in time, mixed with fresh ones. A solve that takes
longer than its budget (``m`` by default) would miss its deadline on a real robot: it is
counted and warned about (:class:`PlanningOverrunWarning`), not raised.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace
from typing import Literal

import torch

from iplanner_torch.errors import ConfigError
from iplanner_torch.planning.optimizer import OptimizerCfg, PlanResult, TrajectoryOptimizer
from iplanner_torch.planning.trajectory import Trajectory, resample_linear
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import check_shape

#: Tolerance on times [s] (cycle times accumulate rounding errors).
TIME_EPS = 1e-6


class PlanningOverrunWarning(UserWarning):
    """A replanning cycle took longer than its wall-clock budget."""


@dataclass(frozen=True, kw_only=True)
class ReplannerCfg:
    """Settings of :class:`Replanner`."""

    # m, the replanning time step [s] (paper: 0.5 s)
    replan_step_s: float = 0.5
    # wall-clock budget of one solve [s]; None means replan_step_s
    budget_s: float | None = None
    # shortest span of a plan [s] (a plan near its goal still covers the window)
    min_duration_s: float = 1.0
    # warm-start each solve from the previous cycle's trajectories
    warm_start: bool = True
    # share of the B trajectories re-initialised cold at each warm-started cycle
    fresh_fraction: float = 0.5
    # joint distance [rad] between the measured and the planned state that re-anchors the plan
    resync_tol: float = 0.2
    # set_goal(q, t) makes a cycle due at t (a task event replans at once, not at the next tick)
    replan_on_goal_change: bool = True

    def __post_init__(self) -> None:
        if not self.replan_step_s > 0.0:
            raise ConfigError(f"expected replan_step_s > 0, got {self.replan_step_s}")
        if self.budget_s is not None and not self.budget_s > 0.0:
            raise ConfigError(f"expected budget_s > 0 or None, got {self.budget_s}")
        if not self.min_duration_s > 0.0:
            raise ConfigError(f"expected min_duration_s > 0, got {self.min_duration_s}")
        if not 0.0 <= self.fresh_fraction <= 1.0:
            raise ConfigError(f"expected fresh_fraction in [0, 1], got {self.fresh_fraction}")
        if not self.resync_tol > 0.0:
            raise ConfigError(f"expected resync_tol > 0, got {self.resync_tol}")


@dataclass(frozen=True, kw_only=True)
class PlannerCfg:
    """A whole motion planner as the experiments name it (``conf/planner/*.yaml``).

    ``confidence`` and ``replan_step_s`` here override the nested configs' values, so sweeps
    set them in one place.
    """

    # "itomp": the observed pose only; "iplanner": the predicted human
    kind: Literal["itomp", "iplanner"] = "iplanner"
    # predictor variant the planner reads ("no_ni" or "ni"); None for itomp
    predictor_variant: Literal["no_ni", "ni"] | None = "ni"
    # delta_CL, the confidence level of the collision constraint
    confidence: float = 0.95
    # m, the replanning time step [s]
    replan_step_s: float = 0.5
    # the trajectory optimiser
    optimizer: OptimizerCfg = field(default_factory=OptimizerCfg)
    # the replanning loop
    replanner: ReplannerCfg = field(default_factory=ReplannerCfg)

    def __post_init__(self) -> None:
        if self.kind not in ("itomp", "iplanner"):
            raise ConfigError(f"expected kind 'itomp' or 'iplanner', got {self.kind!r}")
        if self.kind == "iplanner" and self.predictor_variant not in ("no_ni", "ni"):
            raise ConfigError(
                f"expected predictor_variant 'no_ni' or 'ni' for iplanner, "
                f"got {self.predictor_variant!r}"
            )
        if not 0.0 < self.confidence < 1.0:
            raise ConfigError(f"expected confidence in (0, 1), got {self.confidence}")
        if not self.replan_step_s > 0.0:
            raise ConfigError(f"expected replan_step_s > 0, got {self.replan_step_s}")

    def optimizer_cfg(self) -> OptimizerCfg:
        """The optimiser's settings with this planner's confidence."""
        return replace(self.optimizer, confidence=self.confidence)

    def replanner_cfg(self) -> ReplannerCfg:
        """The replanner's settings with this planner's step."""
        return replace(self.replanner, replan_step_s=self.replan_step_s)


def build_replanner(
    cfg: PlannerCfg, robot: object, static_scene: object | None = None
) -> Replanner:
    """The replanner of a :class:`PlannerCfg` for ``robot`` (ITOMP or I-Planner).

    Args:
        cfg: the planner.
        robot: a ``KinematicModel``.
        static_scene: static obstacles with ``clearance``, or None.
    """
    from iplanner_torch.planning.itomp import ITOMP

    cls = ITOMP if cfg.kind == "itomp" else TrajectoryOptimizer
    return Replanner(cls(robot, cfg.optimizer_cfg(), static_scene), cfg.replanner_cfg())


@dataclass
class ReplannerStats:
    """Counters of a replanning run.

    Attributes:
        cycles: solves run.
        overruns: solves whose wall-clock time exceeded the budget.
        waits: solves that ended in a wait (no trajectory met the confidence constraint).
        wait_s: total seconds of waits planned.
        solve_ms: wall-clock milliseconds of each solve.
    """

    cycles: int = 0
    overruns: int = 0
    waits: int = 0
    wait_s: float = 0.0
    solve_ms: list[float] = field(default_factory=list)

    @property
    def mean_solve_ms(self) -> float:
        """Mean wall-clock milliseconds per solve (0 before the first)."""
        return sum(self.solve_ms) / len(self.solve_ms) if self.solve_ms else 0.0


class Replanner:
    """Drives a :class:`TrajectoryOptimizer` in a closed loop with step m.

    Args:
        optimizer: the trajectory optimiser (or ITOMP).
        cfg: settings.
    """

    def __init__(self, optimizer: TrajectoryOptimizer, cfg: ReplannerCfg | None = None) -> None:
        self.optimizer = optimizer
        self.cfg = cfg or ReplannerCfg()
        self.stats = ReplannerStats()
        self._plan: Trajectory | None = None
        self._next_plan: Trajectory | None = None
        self._last: PlanResult | None = None
        self._goal: torch.Tensor | None = None
        self._t_goal = 0.0
        self._next_cycle = 0.0
        self._goal_changed = True

    @property
    def budget_s(self) -> float:
        """Wall-clock budget of one solve [s]."""
        return self.cfg.budget_s if self.cfg.budget_s is not None else self.cfg.replan_step_s

    @property
    def last_result(self) -> PlanResult | None:
        """The most recent solve's result."""
        return self._last

    @property
    def goal(self) -> torch.Tensor | None:
        """(J,) the current goal [rad]."""
        return self._goal

    def _hold(self, q: torch.Tensor, t: float) -> Trajectory:
        q2 = torch.stack([q, q])
        return Trajectory(q=q2, times=torch.tensor([t, t + 1e-3], dtype=q.dtype, device=q.device))

    def _to(self, q: torch.Tensor) -> torch.Tensor:
        return q.to(self.optimizer.device, self.optimizer.dtype)

    def reset(self, q_start: torch.Tensor, q_goal: torch.Tensor, t: float) -> None:
        """Start a new motion: hold at ``q_start`` and plan towards ``q_goal`` from ``t``.

        Args:
            q_start: (J,) current configuration [rad].
            q_goal: (J,) goal [rad].
            t: current time [s]; the first cycle is due now.
        """
        j = self.optimizer.num_joints
        check_shape("q_start", q_start, (j,))
        check_shape("q_goal", q_goal, (j,))
        self.stats = ReplannerStats()
        self._plan = self._hold(self._to(q_start), t)
        self._next_plan = None
        self._last = None
        self._next_cycle = t
        self.set_goal(q_goal, t=t)

    def set_goal(self, q_goal: torch.Tensor, t: float | None = None) -> None:
        """Change the goal; the next cycle plans to it from cold initial trajectories.

        Args:
            q_goal: (J,) goal [rad].
            t: current time [s] (the goal time is set from it, and with
                ``cfg.replan_on_goal_change`` a cycle is due from it); None uses the next
                cycle's.
        """
        check_shape("q_goal", q_goal, (self.optimizer.num_joints,))
        self._goal = self._to(q_goal)
        if t is not None and self.cfg.replan_on_goal_change:
            self._next_cycle = min(self._next_cycle, t)
        t_ref = self._next_cycle if t is None else t
        self._t_goal = t_ref + self.cfg.replan_step_s + self.optimizer.cfg.horizon_s
        self._goal_changed = True

    def _current(self, t: float) -> Trajectory:
        if self._next_plan is not None and t >= self._next_plan.t_start - TIME_EPS:
            self._plan, self._next_plan = self._next_plan, None
        if self._plan is None:
            raise ConfigError("call reset(q_start, q_goal, t) before step or command")
        return self._plan

    def command(self, t: float) -> tuple[torch.Tensor, torch.Tensor]:
        """The plan sampled at ``t`` (holding at its end).

        Args:
            t: time [s].

        Returns:
            q_des (J,) [rad] and qd_des (J,) [rad/s].
        """
        return self._current(t).sample(t)

    def step(
        self,
        t: float,
        q_now: torch.Tensor,
        forecast: Forecast | None,
        *,
        forecast_t0: float | None = None,
    ) -> PlanResult | None:
        """Run a replanning cycle when one is due.

        Args:
            t: current time [s].
            q_now: (J,) measured configuration [rad]; when it is further than
                ``cfg.resync_tol`` from the plan, the plan is re-anchored at it.
            forecast: the predicted human (ITOMP: ``static_human_forecast`` of the observed
                pose), or None.
            forecast_t0: time of the forecast's last observed frame [s]; None means ``t``.

        Returns:
            The new plan (it takes over at ``t + m``), or None when no cycle is due.
        """
        if self._goal is None or self._plan is None:
            raise ConfigError("call reset(q_start, q_goal, t) before step")
        check_shape("q_now", q_now, (self.optimizer.num_joints,))
        if t < self._next_cycle - TIME_EPS:
            return None
        m = self.cfg.replan_step_s
        plan = self._current(t + TIME_EPS)  # a plan due now takes over before it is replaced
        q_plan_now, _ = plan.sample(t)
        q_now = self._to(q_now)
        if float((q_plan_now - q_now).abs().max()) > self.cfg.resync_tol:
            plan = self._plan = self._hold(q_now, t)
            self._next_plan = None
        t_plan = t + m
        q_s, qd_s = plan.sample(t_plan)
        opt = self.optimizer
        travel = max(self._t_goal - t_plan, opt.min_duration(q_s, self._goal))
        duration = max(travel, self.cfg.min_duration_s)
        q_init = self._warm_start(q_s, t_plan, duration)
        t_wall = time.perf_counter()
        result = opt.solve(
            q_s,
            self._goal,
            forecast=forecast,
            forecast_t0=t if forecast_t0 is None else forecast_t0,
            t0=t_plan,
            duration=duration,
            window=(t_plan, t_plan + m),
            q_init=q_init,
            qd_start=qd_s,
            arrive=t_plan + travel,
        )
        wall = time.perf_counter() - t_wall
        self.stats.cycles += 1
        self.stats.solve_ms.append(1e3 * wall)
        if wall > self.budget_s:
            self.stats.overruns += 1
            warnings.warn(
                f"replanning cycle at t={t:.2f} s took {wall:.3f} s, over its budget "
                f"{self.budget_s:.3f} s",
                PlanningOverrunWarning,
                stacklevel=2,
            )
        if not result.feasible:
            self.stats.waits += 1
            self.stats.wait_s += result.wait_s
            self._t_goal += result.wait_s
        self._t_goal = max(self._t_goal, t_plan + travel)
        self._next_plan = result.trajectory()
        self._last = result
        self._goal_changed = False
        self._next_cycle += m
        if self._next_cycle <= t:
            self._next_cycle = t + m
        return result

    def _warm_start(
        self, q_s: torch.Tensor, t_plan: float, duration: float
    ) -> torch.Tensor | None:
        """(B, W, J) previous trajectories shifted to the new times, the rest fresh."""
        last = self._last
        if not self.cfg.warm_start or last is None or self._goal_changed:
            return None
        opt = self.optimizer
        b, w = opt.cfg.num_trajectories, opt.cfg.num_waypoints
        new_times = t_plan + torch.linspace(
            0.0, duration, w, device=last.times.device, dtype=last.times.dtype
        )
        cand = last.candidates.clone()
        cand[0] = last.q
        q_init = resample_linear(cand, last.times, new_times)  # (B, W, J)
        n_fresh = int(round(self.cfg.fresh_fraction * b))
        if n_fresh > 0:
            seed = opt.cfg.seed + self.stats.cycles + 1
            fresh = opt.initial_trajectories(q_s, self._goal, n_fresh + 1, seed)[1:]
            q_init[b - n_fresh :] = fresh
        return q_init

    def goal_reached(self, q_now: torch.Tensor, tol: float = 1e-2) -> bool:
        """Whether ``q_now`` (J,) [rad] is within ``tol`` [rad] of the goal in every joint."""
        if self._goal is None:
            return False
        return float((self._to(q_now) - self._goal).abs().max()) <= tol
