"""Interleaved planning and execution (paper sec. 5, ITOMP's replanning with step m).

At a cycle due at time ``t`` the plan currently executing is kept until ``t + m``; the new plan
starts where the current one will be at ``t + m`` (position and velocity) and is checked
against the human over its execution window ``[t + m, t + 2m]``. Solves are warm-started from
the previous cycle's trajectories shifted in time, mixed with fresh ones. A solve that takes
longer than its budget (``m`` by default) would miss its deadline on a real robot: it is
counted and warned about (:class:`PlanningOverrunWarning`), not raised.

Execution (``ReplannerCfg.tracking``): with ``"exact"`` :meth:`Replanner.command` samples the
plan. With ``"filtered"`` (the default) it is the robot's trajectory interface, as industrial
controllers have one (online trajectory generation): a reference state ``(q, qd)`` follows the
plan with the plan's acceleration as feed-forward plus a critically damped correction of
bandwidth ``tracking_bandwidth``, its acceleration clipped to ``acc_max`` and its velocity to
the joint limits. A plan switch, a wait cut short at a waypoint, a goal change or a re-anchor
then never makes the commanded motion jump: accelerations stay within ``acc_max``; on a smooth
plan the reference equals the plan up to integration error. The optimiser is given the same
limit (``PlannerCfg.optimizer_cfg``: ``OptimizerCfg.acc_max``), so that the plans, and the waits
(:func:`~iplanner_torch.planning.optimizer.smooth_stop`), stay within it and the executed motion
is the one whose collision bound was checked (without it, a closed-loop episode measured up to
0.32 rad between command and plan, and the arm touched the person's hand off the checked path).
By default a cycle plans from the current plan's state at ``t + m`` (the plans form one
continuous trajectory, position and velocity, which the reference tracks);
``plan_from_reference`` plans from the reference's own state rolled out to ``t + m`` instead
(exact agreement of plan and execution), which in the closed loop let the reference lag plans
near the velocity limits and caused many more waits.

Every cycle first re-checks, against its new forecast, the plans already committed until its own
plan takes over; when they break the confidence limit (the person did something the previous
forecast did not expect) the new plan takes over after ``emergency_lead_s`` instead of ``m``
(``ReplannerStats.emergencies``). With ``emergency_ahead_s`` the check goes on that long past
``t + m``, with the robot stopping there at ``acc_max`` (:func:`braking_stop`): the new plan
starts from the committed state at ``t + m`` and cannot turn away at once, so a committed plan
that arrives where the person is predicted to come just after the hand-over (a delivery on
the person's way back) leaves it no safe move unless it takes over early. A plan that only
passes through a region the person may enter later can still stop before it, and does not
count. After a cycle that ended in a wait, the next plan takes over
``wait_lead_s`` after its cycle and cycles follow at that pace while the waits last, so a wait
ends soon after the way is free instead of up to ``2 m`` later (in arrangement_1x4, seeds 0-4,
the I-Planner's mean efficiency went from 1.42 to 1.50 with 0.2 s).

A goal change (task event) starts a cycle at once whose plan takes over ``goal_change_lead_s``
later (its solve budget; overruns are counted against it) instead of ``m`` later, so the robot
does not dwell at a pick or place point; the regular cadence resumes from the take-over.
"""

from __future__ import annotations

import dataclasses
import difflib
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import torch

from iplanner_torch.checks import (
    FieldKind,
    field_kind,
    finite,
    finite_time,
    fits_kind,
    flag,
    non_negative,
    optional,
)
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.planning.optimizer import (
    MAX_HORIZON_S,
    OptimizerCfg,
    PlanResult,
    TrajectoryOptimizer,
)
from iplanner_torch.planning.trajectory import Trajectory, resample_linear
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.seeds import PLANNER_COLD_START, PLANNER_FRESH, derive_seed
from iplanner_torch.types import check_finite, check_shape

#: Tolerance on times [s] (cycle times accumulate rounding errors).
TIME_EPS = 1e-6


class PlanningOverrunWarning(UserWarning):
    """A replanning cycle took longer than its wall-clock budget."""


#: longest replanning step ``m`` [s]: the paper replans every fraction of a second; a step of
#: minutes leaves the robot blind to the person for that long (1e9 s exhausted the memory)
MAX_REPLAN_STEP_S = 10.0


@dataclass(frozen=True, kw_only=True)
class ReplannerCfg:
    """Settings of :class:`Replanner`."""

    # m, the replanning time step [s] (paper: 0.5 s)
    replan_step_s: float = 0.5
    # wall-clock budget of one solve [s]; None means replan_step_s
    budget_s: float | None = None
    # each solve stops iterating where it would pass its budget (the acceptance check still
    # runs in full), as a robot's planner must: the episode keeps pace with real time where
    # the solves are too slow, but the plans then depend on the machine's speed and load (the
    # same seed no longer gives the same numbers); False: every iteration runs, an overrun is
    # counted
    stop_at_budget: bool = False
    # shortest span of a plan [s] (a plan near its goal still covers the window), at most
    # MAX_HORIZON_S
    min_duration_s: float = 1.0
    # warm-start each solve from the previous cycle's trajectories
    warm_start: bool = True
    # share of the B trajectories re-initialised cold at each warm-started cycle
    fresh_fraction: float = 0.5
    # joint distance [rad] between the measured and the planned state that re-anchors the plan
    resync_tol: float = 0.2
    # set_goal(q, t) makes a cycle due at t (a task event replans at once, not at the next tick)
    replan_on_goal_change: bool = True
    # lead time [s] of the cycle a goal change starts: its plan takes over this long after the
    # event (its solve budget) instead of m later; None means m
    goal_change_lead_s: float | None = 0.2
    # a cycle first checks, against its new forecast, the plans that run until its own plan
    # would take over (t + m); when they break the confidence limit the new plan takes over
    # after this lead [s] instead (an emergency re-plan); None: never
    emergency_lead_s: float | None = 0.2
    # the check also covers this many seconds past t + m [s], with the robot stopping from the
    # committed plans' state at t + m at acc_max (joint by joint): the new plan starts from
    # that state and cannot turn away at once, so committed plans that bring the robot where
    # the person is predicted to come just after the hand-over, too fast to stop clear of it or
    # to stay, are replaced early too; 0: until t + m only
    emergency_ahead_s: float = 0.2
    # configurations checked per second of that span
    emergency_check_hz: float = 20.0
    # after a cycle that ended in a wait, the next plan takes over this long after its cycle
    # [s] instead of m (and cycles follow at that pace while the waits last), so a wait ends
    # soon after the way is free; None: m
    wait_lead_s: float | None = 0.2
    # "exact": command() samples the plan; "filtered": acceleration-limited tracking (module doc)
    tracking: Literal["exact", "filtered"] = "filtered"
    # per-joint acceleration limit of the filtered reference [rad/s^2]
    acc_max: float = 6.0
    # bandwidth of the filtered reference's correction towards the plan [rad/s]
    tracking_bandwidth: float = 20.0
    # filtered: a cycle plans from the reference's state rolled out to t + m (True) or from the
    # current plan's state there (False: the plans form one continuous trajectory that the
    # reference tracks; measured to give fewer waits, see the module docstring)
    plan_from_reference: bool = False
    # integration step of the filtered reference [s] (a larger gap between command() calls is
    # integrated in steps of at most this)
    tracking_dt: float = 0.01
    # a command() call further than this from the previous one (or earlier) restarts the
    # filtered reference at the plan's state [s]
    tracking_max_gap_s: float = 0.1

    def __post_init__(self) -> None:
        for name in ("budget_s", "goal_change_lead_s", "emergency_lead_s", "wait_lead_s"):
            optional(finite, name, getattr(self, name))  # typed float | None
        for name in (
            "replan_step_s",
            "min_duration_s",
            "fresh_fraction",
            "resync_tol",
            "emergency_ahead_s",
            "emergency_check_hz",
            "acc_max",
            "tracking_bandwidth",
            "tracking_dt",
            "tracking_max_gap_s",
        ):  # typed float: None is refused too
            finite(name, getattr(self, name))
        for name in (
            "warm_start",
            "replan_on_goal_change",
            "plan_from_reference",
            "stop_at_budget",
        ):
            flag(name, getattr(self, name))
        if not 0.0 < self.replan_step_s <= MAX_REPLAN_STEP_S:
            raise ConfigError(
                f"expected replan_step_s in (0, {MAX_REPLAN_STEP_S:g}] s, got {self.replan_step_s}"
            )
        if self.budget_s is not None and not self.budget_s > 0.0:
            raise ConfigError(f"expected budget_s > 0 or None, got {self.budget_s}")
        if not 0.0 < self.min_duration_s <= MAX_HORIZON_S:
            raise ConfigError(
                f"expected min_duration_s in (0, {MAX_HORIZON_S:g}] s, got {self.min_duration_s}"
            )
        if not 0.0 <= self.fresh_fraction <= 1.0:
            raise ConfigError(f"expected fresh_fraction in [0, 1], got {self.fresh_fraction}")
        if not self.resync_tol > 0.0:
            raise ConfigError(f"expected resync_tol > 0, got {self.resync_tol}")
        if self.goal_change_lead_s is not None and not (
            0.0 < self.goal_change_lead_s <= self.replan_step_s
        ):
            raise ConfigError(
                f"expected goal_change_lead_s in (0, replan_step_s] or None, got "
                f"{self.goal_change_lead_s}"
            )
        if self.emergency_lead_s is not None and not (
            0.0 < self.emergency_lead_s <= self.replan_step_s
        ):
            raise ConfigError(
                f"expected emergency_lead_s in (0, replan_step_s] or None, got "
                f"{self.emergency_lead_s}"
            )
        if self.wait_lead_s is not None and not 0.0 < self.wait_lead_s <= self.replan_step_s:
            raise ConfigError(
                f"expected wait_lead_s in (0, replan_step_s] or None, got {self.wait_lead_s}"
            )
        if not 0.0 <= self.emergency_ahead_s <= MAX_REPLAN_STEP_S:
            raise ConfigError(
                f"expected emergency_ahead_s in [0, {MAX_REPLAN_STEP_S:g}] s, got "
                f"{self.emergency_ahead_s}"
            )
        if not self.emergency_check_hz > 0.0:
            raise ConfigError(f"expected emergency_check_hz > 0, got {self.emergency_check_hz}")
        if self.tracking not in ("exact", "filtered"):
            raise ConfigError(f"expected tracking 'exact' or 'filtered', got {self.tracking!r}")
        for name in ("acc_max", "tracking_bandwidth"):  # each by name
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"expected {name} > 0, got {getattr(self, name)}")
        if not 0.0 < self.tracking_dt <= self.tracking_max_gap_s:
            raise ConfigError(
                f"expected 0 < tracking_dt <= tracking_max_gap_s, got {self.tracking_dt}, "
                f"{self.tracking_max_gap_s}"
            )


@dataclass(frozen=True, kw_only=True)
class PlannerCfg:
    """A whole motion planner as the experiments name it (``conf/planner/*.yaml``).

    ``confidence`` and ``replan_step_s`` here override the nested configs' values, so sweeps
    set them in one place.
    """

    # "itomp": the observed pose only; "iplanner": the predicted human; "oracle": the person's
    # true future (an upper bound on what prediction can give; no predictor)
    kind: Literal["itomp", "iplanner", "oracle"] = "iplanner"
    # predictor variant the planner reads ("no_ni" or "ni", trained; "cv": constant velocity);
    # None for itomp and oracle
    predictor_variant: Literal["no_ni", "ni", "cv"] | None = "ni"
    # delta_CL, the confidence level of the collision constraint
    confidence: float = 0.95
    # m, the replanning time step [s]; at least the replanner's goal_change_lead_s,
    # emergency_lead_s and wait_lead_s
    replan_step_s: float = 0.5
    # the trajectory optimiser
    optimizer: OptimizerCfg = field(default_factory=OptimizerCfg)
    # the replanning loop
    replanner: ReplannerCfg = field(default_factory=ReplannerCfg)
    # itomp only: the observed pose's standard deviation grows by this much per second after
    # the observation [m/s] (:func:`~iplanner_torch.planning.itomp.static_human_forecast`), a
    # Gaussian stand-in for ITOMP's conservative bound on where a moving obstacle can be;
    # 0: the pose held still (the paper's baseline as reproduced here)
    itomp_spread_mps: float = 0.0
    # settings of one planner of a run only, over the ones above: planner name (one of
    # PLANNER_NAMES) -> nested fields, e.g. {"iplanner_ni": {"replanner": {"fresh_fraction":
    # 0.0}}}; :meth:`for_planner` applies them (kind, predictor_variant, confidence and
    # optimizer.seed are set per episode and cannot be changed here)
    per_kind: dict[str, dict[str, Any]] = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        finite("confidence", self.confidence)
        finite("replan_step_s", self.replan_step_s)
        non_negative("itomp_spread_mps", self.itomp_spread_mps)
        for name, kind in (("optimizer", OptimizerCfg), ("replanner", ReplannerCfg)):
            value = getattr(self, name)
            if not isinstance(value, kind):
                raise ConfigError(f"expected {name} a {kind.__name__}, got {type(value).__name__}")
        if self.kind not in ("itomp", "iplanner", "oracle"):
            raise ConfigError(f"expected kind 'itomp', 'iplanner' or 'oracle', got {self.kind!r}")
        if self.kind == "iplanner" and self.predictor_variant not in ("no_ni", "ni", "cv"):
            raise ConfigError(
                f"expected predictor_variant 'no_ni', 'ni' or 'cv' for iplanner, "
                f"got {self.predictor_variant!r}"
            )
        if not 0.0 < self.confidence < 1.0:
            raise ConfigError(f"expected confidence in (0, 1), got {self.confidence}")
        if not 0.0 < self.replan_step_s <= MAX_REPLAN_STEP_S:
            raise ConfigError(
                f"expected replan_step_s in (0, {MAX_REPLAN_STEP_S:g}] s, got {self.replan_step_s}"
            )
        for name in ("goal_change_lead_s", "emergency_lead_s", "wait_lead_s"):
            lead = getattr(self.replanner, name)
            if lead is not None and lead > self.replan_step_s:
                raise ConfigError(
                    f"expected replanner.{name} <= replan_step_s or None, got "
                    f"replanner.{name}={lead} with replan_step_s={self.replan_step_s}"
                )
        if not isinstance(self.per_kind, Mapping):
            raise ConfigError(
                f"expected per_kind a mapping of planner names to settings, got "
                f"{type(self.per_kind).__name__}"
            )
        for name in self.per_kind:
            self.for_planner(name)  # every entry is checked when the settings are made

    def for_planner(self, name: str) -> PlannerCfg:
        """These settings with ``per_kind[name]`` applied (themselves when it has none).

        Args:
            name: a planner of the run (one of :data:`PLANNER_NAMES`).

        Raises:
            ConfigError: on an unknown planner name, an unknown or fixed field in its
                entry, or a value the settings refuse, naming ``per_kind.<name>.<field>``.
        """
        if name not in PLANNER_NAMES:
            raise ConfigError(
                f"per_kind: unknown planner {name!r}; expected one of {list(PLANNER_NAMES)}"
            )
        changes = self.per_kind.get(name) or {}
        if not changes:
            return self
        where = f"per_kind.{name}"
        if not isinstance(changes, Mapping):
            raise ConfigError(
                f"{where}: expected a mapping of settings, got {type(changes).__name__}"
            )
        for key in PER_KIND_FIXED:
            head, _, rest = key.partition(".")
            entry = changes.get(head)
            if head in changes and (not rest or (isinstance(entry, Mapping) and rest in entry)):
                raise ConfigError(
                    f"{where}.{key}: set for every episode by the run (the planners list, "
                    "the scenario or the seeds), not per planner"
                )
        return _with_fields(replace(self, per_kind={}), changes, where)

    def optimizer_cfg(self) -> OptimizerCfg:
        """The optimiser's settings with this planner's confidence; with filtered tracking
        and no ``acc_max`` of its own, the tracking's acceleration limit."""
        acc_max = self.optimizer.acc_max
        if acc_max is None and self.replanner.tracking == "filtered":
            acc_max = self.replanner.acc_max
        return replace(self.optimizer, confidence=self.confidence, acc_max=acc_max)

    def replanner_cfg(self) -> ReplannerCfg:
        """The replanner's settings with this planner's step."""
        return replace(self.replanner, replan_step_s=self.replan_step_s)


#: The planner names of a run (``experiment.planners``), the keys of ``PlannerCfg.per_kind``.
PLANNER_NAMES: tuple[str, ...] = (
    "itomp",
    "iplanner_no_ni",
    "iplanner_ni",
    "iplanner_cv",
    "oracle",
    "blind",
)
#: PlannerCfg fields each episode sets, which ``per_kind`` cannot change.
PER_KIND_FIXED: tuple[str, ...] = (
    "kind",
    "predictor_variant",
    "confidence",
    "per_kind",
    "optimizer.seed",
)


def braking_stop(
    q: torch.Tensor, qd: torch.Tensor, s: torch.Tensor, acc_max: float
) -> torch.Tensor:
    """Positions of a robot that stops from ``(q, qd)``, each joint at ``acc_max`` until its
    velocity is 0 and then holding, ``s`` seconds later.

    Args:
        q: (J,) positions [rad].
        qd: (J,) velocities [rad/s].
        s: (N,) times after the start [s], >= 0.
        acc_max: the deceleration [rad/s^2], > 0.

    Returns:
        (N, J) positions [rad]: ``q + qd u - sign(qd) acc_max u^2 / 2`` with ``u = min(s,
        |qd| / acc_max)`` per joint.
    """
    u = torch.minimum(s.unsqueeze(-1), qd.abs() / acc_max)  # (N, J)
    return q + qd * u - 0.5 * acc_max * torch.sign(qd) * u.square()


def _with_fields(obj: Any, changes: Mapping[str, Any], where: str) -> Any:
    """The dataclass ``obj`` with the nested field values of ``changes`` (a mapping whose
    values are mappings for dataclass fields); built again, so its own checks run.

    Raises:
        ConfigError: on an unknown field (with the closest name), a mapping where one value
            is expected, a value of another kind than the field's, or a value the
            dataclass refuses; each names ``<where>.<field>``.
    """
    fields = {f.name: f for f in dataclasses.fields(obj)}
    updates: dict[str, Any] = {}
    for key, value in changes.items():
        key_s = str(key)
        at = f"{where}.{key_s}"
        if key_s not in fields:
            near = difflib.get_close_matches(key_s, list(fields), n=1, cutoff=0.6)
            hint = f"did you mean {near[0]!r}?" if near else f"{type(obj).__name__} has "
            raise ConfigError(f"{at}: unknown field ({hint}{'' if near else sorted(fields)})")
        current = getattr(obj, key_s)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, Mapping):
                raise ConfigError(f"{at}: expected a mapping of {type(current).__name__} fields")
            updates[key_s] = _with_fields(current, value, at)
            continue
        if isinstance(value, Mapping):
            raise ConfigError(f"{at}: expected one value, got a mapping {dict(value)!r}")
        _check_kind(at, value, field_kind(type(obj), key_s))
        updates[key_s] = value
    try:
        return replace(obj, **updates)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def _check_kind(at: str, value: Any, kind: FieldKind | None) -> None:
    """Refuse ``value`` when the field takes bool, int, float or str (or a Literal of them,
    possibly ``| None``: :func:`~iplanner_torch.checks.field_kind`) and ``value`` is none of
    those."""
    if kind is None:
        return
    if kind.choices is not None:
        if value not in kind.choices and not (value is None and kind.nullable):
            raise ConfigError(f"{at}: expected one of {list(kind.choices)}, got {value!r}")
        return
    if value is None:
        if not kind.nullable:
            raise ConfigError(f"{at}: expected {kind.base.__name__}, got null")
        return
    if not fits_kind(value, kind.base):
        raise ConfigError(f"{at}: expected {kind.base.__name__}, got {value!r}")


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
        evasions: solves where no trajectory met the constraint and holding was riskier than
            moving (``PlanResult.evasive``: the least risky trajectory, no wait).
        escapes: the evasions among them that stepped out of the person's way rather than
            heading for the goal (``PlanResult.escape``: no candidate was less risky than
            holding).
        emergencies: cycles whose new forecast put the plans already committed above the
            confidence limit, so that the new plan took over after ``emergency_lead_s``.
        cut_short: solves that stopped iterating at their budget
            (``ReplannerCfg.stop_at_budget``).
        solve_ms: wall-clock milliseconds of each solve.
    """

    cycles: int = 0
    overruns: int = 0
    waits: int = 0
    wait_s: float = 0.0
    evasions: int = 0
    escapes: int = 0
    emergencies: int = 0
    cut_short: int = 0
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
        # filtered reference: (time [s], q (J,) [rad], qd (J,) [rad/s]) or None
        self._ref: tuple[float, torch.Tensor, torch.Tensor] | None = None
        # last plan sample of the filtered reference: (time, plan, (q, qd))
        self._target_cache: tuple[float, Trajectory, tuple[torch.Tensor, torch.Tensor]] | None
        self._target_cache = None

    @property
    def budget_s(self) -> float:
        """Wall-clock budget of one solve [s]."""
        return self.cfg.budget_s if self.cfg.budget_s is not None else self.cfg.replan_step_s

    @property
    def last_result(self) -> PlanResult | None:
        """The most recent solve's result."""
        return self._last

    @property
    def next_cycle(self) -> float:
        """Time [s] at which the next replanning cycle is due."""
        return self._next_cycle

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

        Raises:
            ShapeError: when ``q_start`` or ``q_goal`` is not (J,).
            DataError: when one of them or ``t`` is NaN or infinite, or ``q_goal`` is outside
                the joint limits.
        """
        j = self.optimizer.num_joints
        check_shape("q_start", q_start, (j,))
        check_shape("q_goal", q_goal, (j,))
        finite_time("t", t, error=DataError)
        check_finite("q_start", q_start, ("joint",))
        self.stats = ReplannerStats()
        self._plan = self._hold(self._to(q_start), t)
        self._next_plan = None
        self._last = None
        self._next_cycle = t
        q0 = self._to(q_start)
        self._ref = (float(t), q0.clone(), torch.zeros_like(q0))
        self.set_goal(q_goal, t=t)

    def set_goal(self, q_goal: torch.Tensor, t: float | None = None) -> None:
        """Change the goal; the next cycle plans to it from cold initial trajectories.

        Args:
            q_goal: (J,) goal [rad].
            t: current time [s] (the goal time is set from it, and with
                ``cfg.replan_on_goal_change`` a cycle is due from it); None uses the next
                cycle's.

        Raises:
            ShapeError: when ``q_goal`` is not (J,).
            DataError: when ``q_goal`` or ``t`` is NaN or infinite, or ``q_goal`` is outside
                the joint limits (it could never be reached).
        """
        check_shape("q_goal", q_goal, (self.optimizer.num_joints,))
        if t is not None:
            finite_time("t", t, error=DataError)
        check_finite("q_goal", q_goal, ("joint",))
        self.optimizer.check_goal(q_goal)
        self._goal = self._to(q_goal)
        if t is not None and self.cfg.replan_on_goal_change:
            self._next_cycle = min(self._next_cycle, t)
        t_ref = self._next_cycle if t is None else t
        self._t_goal = t_ref + self._lead(True) + self.optimizer.cfg.horizon_s
        self._goal_changed = True

    def _lead(self, goal_changed: bool) -> float:
        """Seconds from a cycle to the take-over of its plan [s]."""
        lead = self.cfg.goal_change_lead_s
        return lead if goal_changed and lead is not None else self.cfg.replan_step_s

    def _current(self, t: float) -> Trajectory:
        if self._next_plan is not None and t >= self._next_plan.t_start - TIME_EPS:
            self._plan, self._next_plan = self._next_plan, None
        if self._plan is None:
            raise ConfigError("call reset(q_start, q_goal, t) before step or command")
        return self._plan

    def command(self, t: float) -> tuple[torch.Tensor, torch.Tensor]:
        """The commanded state at ``t``: the plan sampled at ``t`` (holding at its end), or
        with ``cfg.tracking == "filtered"`` the acceleration-limited reference (module
        docstring), integrated from the previous call.

        Args:
            t: time [s]; filtered tracking expects non-decreasing calls (an earlier time or a
                gap over ``cfg.tracking_max_gap_s`` restarts the reference at the plan).

        Returns:
            q_des (J,) [rad] and qd_des (J,) [rad/s].

        Raises:
            DataError: when ``t`` is NaN or infinite.
        """
        finite_time("t", t, error=DataError)
        if self.cfg.tracking == "exact":
            return self._current(t).sample(t)
        if self._plan is None:
            raise ConfigError("call reset(q_start, q_goal, t) before step or command")
        self._ref = self._reference_at(t, self._plan, self._next_plan)
        self._current(t)
        _, q, qd = self._ref
        return q.clone(), qd.clone()

    def _target(
        self, tau: float, plan: Trajectory, nxt: Trajectory | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(J,) position [rad] and velocity [rad/s] of the plan executing at ``tau``; at the
        take-over time itself the old plan (its state there is what the new one starts from)."""
        p = nxt if nxt is not None and tau > nxt.t_start + TIME_EPS else plan
        cache = self._target_cache
        if cache is not None and cache[0] == tau and cache[1] is p:
            return cache[2]  # the previous step's end state, on the same plan
        out = p.sample(tau)
        self._target_cache = (tau, p, out)
        return out

    def _reference_at(
        self, t: float, plan: Trajectory, nxt: Trajectory | None, *, predict: bool = False
    ) -> tuple[float, torch.Tensor, torch.Tensor]:
        """The filtered reference rolled out from its last state to ``t`` along ``plan``
        (then ``nxt`` from its start); restarted at the plan's state after a jump in time
        unless ``predict`` (a look-ahead of a cycle)."""
        cfg = self.cfg
        ref = self._ref
        jump = ref is not None and t - ref[0] > cfg.tracking_max_gap_s and not predict
        if ref is None or t < ref[0] - TIME_EPS or jump:
            q, qd = self._target(t, plan, nxt)
            return float(t), q, qd
        t_f, x, v = ref
        w, a_max = cfg.tracking_bandwidth, cfg.acc_max
        v_max = self.optimizer.v_max
        q0, v0 = self._target(t_f, plan, nxt)
        while t_f < t - TIME_EPS:
            h = min(cfg.tracking_dt, t - t_f)
            q1, v1 = self._target(t_f + h, plan, nxt)
            # plan acceleration as feed-forward, critically damped correction, then limits
            acc = (v1 - v0) / h + w * w * (q0 - x) + 2.0 * w * (v0 - v)
            acc = acc.clamp(-a_max, a_max)
            v_new = torch.maximum(torch.minimum(v + acc * h, v_max), -v_max)
            x = x + 0.5 * (v + v_new) * h
            v = v_new
            t_f += h
            q0, v0 = q1, v1
        return t_f, x, v

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

        Raises:
            ConfigError: before :meth:`reset`.
            ShapeError: when ``q_now`` is not (J,).
            DataError: when ``t``, ``forecast_t0`` or ``q_now`` is NaN or infinite (a NaN
                measurement would never re-anchor the plan).
        """
        if self._goal is None or self._plan is None:
            raise ConfigError("call reset(q_start, q_goal, t) before step")
        check_shape("q_now", q_now, (self.optimizer.num_joints,))
        finite_time("t", t, error=DataError)
        if forecast_t0 is not None:
            finite_time("forecast_t0", forecast_t0, error=DataError)
        check_finite("q_now", q_now, ("joint",))
        if t < self._next_cycle - TIME_EPS:
            return None
        m = self.cfg.replan_step_s
        filtered = self.cfg.tracking == "filtered"
        if filtered:  # the reference up to now, along the plans as they were
            self._ref = self._reference_at(t, self._plan, self._next_plan)
        plan = self._current(t + TIME_EPS)  # a plan due now takes over before it is replaced
        q_ref_now = self._ref[1] if filtered and self._ref is not None else plan.sample(t)[0]
        q_now = self._to(q_now)
        if float((q_ref_now - q_now).abs().max()) > self.cfg.resync_tol:
            plan = self._plan = self._hold(q_now, t)
            self._next_plan = None
            if filtered and self._ref is not None:  # re-anchor where the robot is, same speed
                self._ref = (float(t), q_now.clone(), self._ref[2])
        lead = self._lead(self._goal_changed)
        last = self._last
        waited = last is not None and not (last.feasible or last.evasive)
        if self.cfg.wait_lead_s is not None and waited:  # the last cycle ended in a wait
            lead = min(lead, self.cfg.wait_lead_s)
        if forecast is not None and self._committed_unsafe(t, lead, plan, forecast, forecast_t0):
            lead = float(self.cfg.emergency_lead_s)  # type: ignore[arg-type]
            self.stats.emergencies += 1
        t_plan = t + lead
        if filtered and self.cfg.plan_from_reference:
            _, q_s, qd_s = self._reference_at(t_plan, plan, None, predict=True)
        else:
            q_s, qd_s = plan.sample(t_plan)
        opt = self.optimizer
        # a straight line at 2/3 of the velocity limits, plus (filtered tracking) the time to
        # reach that speed and to change the current velocity within acc_max
        ramp = 0.0
        if filtered and self.cfg.plan_from_reference:
            speed = (2.0 / 3.0) * opt.v_max
            ramp = float(((speed + qd_s.abs()) / self.cfg.acc_max).max())
        travel = max(self._t_goal - t_plan, opt.min_duration(q_s, self._goal, qd_s) + ramp)
        # waits push the goal time back; the optimiser plans at most MAX_HORIZON_S ahead
        duration = min(max(travel, self.cfg.min_duration_s), MAX_HORIZON_S)
        q_init = self._warm_start(q_s, qd_s, t_plan, duration, travel)
        budget = min(self.budget_s, lead)
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
            deadline=t_wall + budget if self.cfg.stop_at_budget else None,
            seed=derive_seed(opt.cfg.seed, PLANNER_COLD_START, self.stats.cycles),
        )
        wall = time.perf_counter() - t_wall
        self.stats.cycles += 1
        self.stats.solve_ms.append(1e3 * wall)
        self.stats.cut_short += int(result.cut_short)
        if wall > budget:
            self.stats.overruns += 1
            warnings.warn(
                f"replanning cycle at t={t:.2f} s took {wall:.3f} s, over its budget "
                f"{budget:.3f} s",
                PlanningOverrunWarning,
                stacklevel=2,
            )
        if result.evasive:
            self.stats.evasions += 1
            self.stats.escapes += int(result.escape)
        elif not result.feasible:
            self.stats.waits += 1
            self.stats.wait_s += result.wait_s
            self._t_goal += result.wait_s
        self._t_goal = max(self._t_goal, t_plan + travel)
        self._next_plan = result.trajectory()
        self._last = result
        self._goal_changed = False
        # the next cycle plans what follows this plan's window
        self._next_cycle = t + lead if lead < m else self._next_cycle + m
        if self._next_cycle <= t:
            self._next_cycle = t + m
        return result

    def _committed_unsafe(
        self,
        t: float,
        lead: float,
        plan: Trajectory,
        forecast: Forecast,
        forecast_t0: float | None,
    ) -> bool:
        """Whether the plans that run from ``t + emergency_lead_s`` until ``t + lead`` break
        the confidence limit under ``forecast``, or (``emergency_ahead_s`` > 0) a stop from
        their state at ``t + lead`` does in the ``emergency_ahead_s`` after it (see
        ``ReplannerCfg.emergency_lead_s`` and ``emergency_ahead_s``)."""
        early = self.cfg.emergency_lead_s
        if early is None or lead <= early + TIME_EPS:
            return False
        n = max(2, int(round((lead - early) * self.cfg.emergency_check_hz)) + 1)
        opt = self.optimizer
        ts = torch.linspace(t + early, t + lead, n, dtype=opt.dtype, device=opt.device)
        nxt = self._next_plan

        def committed(times: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            q, qd = plan.sample(times)  # (n, J) each
            if nxt is not None:  # the pending plan runs from its start on
                later = (times > nxt.t_start + TIME_EPS).unsqueeze(-1)
                if bool(later.any()):
                    q_n, qd_n = nxt.sample(times)
                    q, qd = torch.where(later, q_n, q), torch.where(later, qd_n, qd)
            return q, qd

        q = committed(ts)[0]
        ahead = self.cfg.emergency_ahead_s
        if ahead > 0.0:
            k = max(1, int(round(ahead * self.cfg.emergency_check_hz)))
            s = torch.linspace(0.0, ahead, k + 1, dtype=opt.dtype, device=opt.device)[1:]
            q_h, qd_h = committed(ts[-1:])
            stop = braking_stop(q_h[0], qd_h[0], s, self.cfg.acc_max)  # (k, J)
            stop = torch.minimum(torch.maximum(stop, opt.q_min), opt.q_max)
            q, ts = torch.cat([q, stop]), torch.cat([ts, ts[-1] + s])
        bound = opt.collision_bound(q, ts, forecast, t if forecast_t0 is None else forecast_t0)
        return bool(float(bound.max()) > 1.0 - opt.cfg.confidence)

    def _warm_start(
        self,
        q_s: torch.Tensor,
        qd_s: torch.Tensor,
        t_plan: float,
        duration: float,
        travel: float,
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
        # each previous trajectory is moved to start where this plan starts (a re-anchor or a
        # wait leaves them elsewhere): the offset fades out linearly towards the goal
        fade = torch.linspace(1.0, 0.0, w, device=q_init.device, dtype=q_init.dtype)
        q_init = q_init + fade.view(1, w, 1) * (q_s.to(q_init) - q_init[:, :1])
        n_fresh = int(round(self.cfg.fresh_fraction * b))
        if n_fresh > 0:  # the least-acceleration path and smooth perturbations of it
            seed = derive_seed(opt.cfg.seed, PLANNER_FRESH, self.stats.cycles)
            fresh = opt.initial_trajectories(
                q_s,
                self._goal,
                n_fresh,
                seed,
                duration,
                qd_start=qd_s,
                arrival=opt.arrival_index(duration, travel),
            )
            q_init[b - n_fresh :] = fresh.to(q_init)
        return q_init

    def goal_reached(self, q_now: torch.Tensor, tol: float = 1e-2) -> bool:
        """Whether ``q_now`` (J,) [rad] is within ``tol`` [rad] of the goal in every joint.

        Raises:
            ShapeError: when ``q_now`` is not (J,).
            ConfigError: when ``tol`` is not a finite number >= 0 (a NaN or negative one
                would never be met).
        """
        check_shape("q_now", q_now, (self.optimizer.num_joints,))
        non_negative("tol", tol)
        if self._goal is None:
            return False
        return float((self._to(q_now) - self._goal).abs().max()) <= tol
