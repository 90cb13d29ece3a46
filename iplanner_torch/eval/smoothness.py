"""Where a trajectory's roughness comes from: waits, and the plans themselves.

The paper's smoothness (eq. smoothness, :func:`~iplanner_torch.eval.metrics.smoothness`) is one
number per episode. To tell why one planner is rougher than another, it is split here in two
ways:

- by time: the share of ``int sum_i qdd_i^2 dt`` that falls in *wait windows* (from the
  take-over of a plan that waits, ``wait_s > 0``, to ``settle_s`` after the take-over of the
  next plan that does not: the stop and the start again), and the smoothness of the rest;
- by plan: the mean ``sum_i qdd_i^2`` of each plan's own waypoints over the part that runs
  before the next plan takes over, i.e. how rough the plans are that the robot executes (the
  filtered tracking follows them up to its acceleration limit); and how far each plan moves
  the path from the one before it (``plan_change``), since a robot whose successive plans
  take different ways round an obstacle is rough however smooth each plan is;
- by risk: the share of time and of the integral while plans run whose collision bound came
  near the confidence limit (above ``near_fraction`` of ``1 - confidence``): the I-Planner's
  confidence penalty makes a plan hurry past or bend round where the forecast puts the
  person, and this says how much of the roughness that is.

:func:`episode_breakdown` reads them from an episode log (``/robot/joint_state``,
``/planner/plan`` and ``/planner/bound``); the log's robot state is sampled more sparsely
than the metrics' trajectory, so its smoothness is lower than ``eval/smoothness`` and only
ratios between planners measured the same way should be compared.
``scripts/smoothness_breakdown.py`` prints the breakdown of every log of a run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from iplanner_torch.checks import finite, increasing_times, is_real, real_array
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.eval.metrics import joint_accelerations


@dataclass(frozen=True, kw_only=True)
class PlanRecord:
    """One plan as the replanner logged it.

    ``times`` and ``q`` may be given as lists or tensors; they are kept as float64 numpy
    arrays, ``wait_s`` as a float.

    Attributes:
        times: (W,) waypoint times [s], increasing, W >= 1; ``times[0]`` is when the plan
            takes over.
        q: (W, J) waypoints [rad] (the shape is checked against the trajectory by
            :func:`smoothness_breakdown`).
        wait_s: the delay the plan reports (> 0: the plan stops and waits) [s], finite.
        max_bound: the plan's largest collision bound over its waypoints, or NaN when not
            known.
        limit: the confidence limit ``1 - confidence`` the plan was held to, or NaN.

    Raises:
        ShapeError: for ``times`` or ``q`` that are not arrays of real numbers, ``times``
            that is not 1-D with at least one entry, or ``q`` not (W, J).
        DataError: for ``times`` that are not finite and strictly increasing, a ``wait_s``
            that is not a finite number, or a ``max_bound`` or ``limit`` that is not a number
            (NaN allowed).
    """

    times: np.ndarray
    q: np.ndarray
    wait_s: float
    max_bound: float = math.nan
    limit: float = math.nan

    def __post_init__(self) -> None:
        times = real_array("times", self.times).astype(np.float64)
        if times.ndim != 1 or times.shape[0] == 0:
            raise ShapeError(f"expected plan times (W,) with W >= 1, got shape {times.shape}")
        increasing_times("plan times", times)  # (a later error named the breakdown's t)
        q = real_array("q", self.q).astype(np.float64)
        if q.ndim != 2 or q.shape[0] != times.shape[0]:
            raise ShapeError(f"expected plan q (W, J) with W = {times.shape[0]}, got {q.shape}")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "wait_s", finite("wait_s", self.wait_s, error=DataError))
        for name in ("max_bound", "limit"):
            value = getattr(self, name)
            if not is_real(value):
                raise DataError(f"expected {name} a number (NaN: not known), got {value!r}")
            object.__setattr__(self, name, float(value))


@dataclass(frozen=True, kw_only=True)
class SmoothnessBreakdown:
    """The split of :func:`smoothness_breakdown` (module docstring).

    Attributes:
        smoothness: ``(1/T) int sum_i qdd_i^2 dt`` of the whole trajectory [rad^2/s^4].
        waits: plans that wait.
        wait_time_share: share of the duration inside wait windows.
        wait_share: share of the integral inside wait windows.
        smoothness_outside: the smoothness of the time outside wait windows [rad^2/s^4]
            (NaN when there is none).
        plan_executed: mean over plans of the mean ``sum_i qdd_i^2`` of the plan's interior
            waypoints before the next take-over [rad^2/s^4] (NaN without such waypoints).
        plan_change: median over successive plans of the largest joint difference between a
            plan's waypoints and the plan before it (linearly interpolated at their times,
            where the two overlap) [rad] (NaN when no two plans overlap).
        near_limit_time_share: share of the duration while plans run (take-over to the next
            take-over) whose ``max_bound`` exceeds ``near_fraction * limit`` (NaN when no plan
            has both).
        near_limit_share: share of the integral in that time (NaN as above, 0 for a
            trajectory without acceleration).
    """

    smoothness: float
    waits: int
    wait_time_share: float
    wait_share: float
    smoothness_outside: float
    plan_executed: float
    plan_change: float
    near_limit_time_share: float = math.nan
    near_limit_share: float = math.nan


def wait_windows(plans: Sequence[PlanRecord], settle_s: float = 1.0) -> list[tuple[float, float]]:
    """The wait windows of a plan sequence [s]: from the take-over of each waiting plan to
    ``settle_s`` after the take-over of the next plan that does not wait (to the end of the
    waiting plan's own waypoints plus ``settle_s`` when none follows).

    Args:
        plans: the plans in take-over order.
        settle_s: time after the wait within which the robot is taken to start again [s].

    Raises:
        ConfigError: when ``settle_s`` is not a number >= 0.
    """
    if not (is_real(settle_s) and settle_s >= 0.0):
        raise ConfigError(f"expected settle_s >= 0, got {settle_s!r}")
    out: list[tuple[float, float]] = []
    for k, plan in enumerate(plans):
        if not plan.wait_s > 0.0:
            continue
        start = float(plan.times[0])
        end = float(plan.times[-1]) + settle_s
        for later in plans[k + 1 :]:
            if not later.wait_s > 0.0:
                end = float(later.times[0]) + settle_s
                break
        out.append((start, end))
    return out


def _plan_executed(plans: Sequence[PlanRecord]) -> float:
    values = []
    for k, plan in enumerate(plans):
        if plan.times.shape[0] < 3:
            continue
        qdd, _ = joint_accelerations(plan.times, plan.q)  # (W - 2, J)
        until = float(plans[k + 1].times[0]) if k + 1 < len(plans) else math.inf
        run = torch.as_tensor(plan.times[1:-1]) < until
        if bool(run.any()):
            values.append(float(qdd.square().sum(-1)[run].mean()))
    return float(np.mean(values)) if values else math.nan


def plan_changes(plans: Sequence[PlanRecord]) -> np.ndarray:
    """(P,) for each plan that overlaps the one before it in time, the largest joint
    difference [rad] between its waypoints inside that plan's span and that plan linearly
    interpolated at their times: how far replanning moved the path. Pairs without a common
    waypoint time are left out.

    Raises:
        ShapeError: when two successive plans have different joint counts.
    """
    out = []
    for k, (before, plan) in enumerate(zip(plans[:-1], plans[1:], strict=True)):
        if before.q.ndim != 2 or plan.q.ndim != 2 or before.q.shape[1] != plan.q.shape[1]:
            raise ShapeError(
                f"plans {k} and {k + 1}: expected q (W, J) with one J, got {before.q.shape} "
                f"and {plan.q.shape}"
            )
        inside = (plan.times >= before.times[0]) & (plan.times <= before.times[-1])
        if not inside.any():
            continue
        t = plan.times[inside]
        then = np.stack(
            [np.interp(t, before.times, before.q[:, j]) for j in range(before.q.shape[1])], 1
        )
        out.append(float(np.abs(plan.q[inside] - then).max()))
    return np.asarray(out, dtype=np.float64)


def near_limit_windows(
    plans: Sequence[PlanRecord], near_fraction: float = 0.1
) -> list[tuple[float, float]] | None:
    """The times [s] while plans run whose collision bound came near the confidence limit:
    from the take-over of each plan with ``max_bound > near_fraction * limit`` to the
    take-over of the next plan (to its own last waypoint when none follows).

    Args:
        plans: the plans in take-over order.
        near_fraction: the share of the limit above which a plan counts, in (0, 1].

    Returns:
        The half-open windows ``[start, end)``; None when no plan has a known ``max_bound``
        and ``limit``.

    Raises:
        ConfigError: when ``near_fraction`` is not a number in (0, 1].
    """
    if not (is_real(near_fraction) and 0.0 < near_fraction <= 1.0):
        raise ConfigError(f"expected near_fraction in (0, 1], got {near_fraction!r}")
    if not any(math.isfinite(p.max_bound) and math.isfinite(p.limit) for p in plans):
        return None
    out = []
    for k, plan in enumerate(plans):
        if plan.max_bound > near_fraction * plan.limit:  # False for NaN
            end = float(plans[k + 1].times[0]) if k + 1 < len(plans) else float(plan.times[-1])
            out.append((float(plan.times[0]), end))
    return out


def smoothness_breakdown(
    t: Any,
    q: Any,
    plans: Sequence[PlanRecord],
    *,
    settle_s: float = 1.0,
    near_fraction: float = 0.1,
) -> SmoothnessBreakdown:
    """Split the smoothness of an executed trajectory (module docstring).

    Args:
        t: (T,) sample times [s], strictly increasing, T >= 3.
        q: (T, J) executed joint positions [rad].
        plans: the plans in take-over order (each ``times`` (W,), ``q`` (W, J)).
        settle_s: see :func:`wait_windows` [s].
        near_fraction: see :func:`near_limit_windows`.

    Raises:
        ShapeError: when a plan's ``q`` is not (W, J) with its ``times`` (W,).
        ConfigError: when ``settle_s`` is not a number >= 0 or ``near_fraction`` not in
            (0, 1].
    """
    qdd, w = joint_accelerations(t, q)  # (T - 2, J), (T - 2,)
    n_j = qdd.shape[1]
    for i, plan in enumerate(plans):
        if plan.times.ndim != 1 or plan.q.shape != (plan.times.shape[0], n_j):
            raise ShapeError(
                f"plan {i}: expected times (W,) and q (W, {n_j}), got {plan.times.shape} "
                f"and {plan.q.shape}"
            )
    a2 = qdd.square().sum(-1) * w  # (T - 2,) integral per sample
    t_in = torch.as_tensor(np.asarray(t, dtype=np.float64))[1:-1]
    inside = torch.zeros_like(t_in, dtype=torch.bool)
    for start, end in wait_windows(plans, settle_s):
        inside |= (t_in >= start) & (t_in <= end)
    total_w, total_a = float(w.sum()), float(a2.sum())
    out_w = float(w[~inside].sum())
    changes = plan_changes(plans)  # (P,) [rad]
    near_time = near_share = math.nan
    windows = near_limit_windows(plans, near_fraction)
    if windows is not None:
        near = torch.zeros_like(t_in, dtype=torch.bool)
        for start, end in windows:
            near |= (t_in >= start) & (t_in < end)
        near_time = float(w[near].sum()) / total_w
        near_share = float(a2[near].sum()) / total_a if total_a > 0.0 else 0.0
    return SmoothnessBreakdown(
        smoothness=total_a / total_w,
        waits=sum(int(p.wait_s > 0.0) for p in plans),
        wait_time_share=float(w[inside].sum()) / total_w,
        wait_share=float(a2[inside].sum()) / total_a if total_a > 0.0 else 0.0,
        smoothness_outside=float(a2[~inside].sum()) / out_w if out_w > 0.0 else math.nan,
        plan_executed=_plan_executed(plans),
        plan_change=float(np.median(changes)) if changes.size else math.nan,
        near_limit_time_share=near_time,
        near_limit_share=near_share,
    )


def episode_breakdown(
    episode: Any, *, settle_s: float = 1.0, near_fraction: float = 0.1
) -> SmoothnessBreakdown:
    """:func:`smoothness_breakdown` of an episode read by
    :func:`~iplanner_torch.recording.read_episode`. Each plan's ``max_bound`` and ``limit``
    come from the ``/planner/bound`` message of the same waypoint times (NaN without one).

    Raises:
        DataError: when the log has no plans, fewer than 3 robot states or states at repeated
            or decreasing times (naming the log's file).
    """
    where = f"{episode.path}: " if getattr(episode, "path", None) else ""
    t, q = episode.robot_q()
    if t.shape[0] < 3:
        raise DataError(f"{where}expected at least 3 robot states in the log, got {t.shape[0]}")
    frame = episode.frames.get("/planner/plan")
    if frame is None or frame.empty:
        raise DataError(f"{where}the log has no /planner/plan messages")
    bounds: dict[float, tuple[float, float]] = {}  # first waypoint time -> (max, limit)
    bound_frame = episode.frames.get("/planner/bound")
    if bound_frame is not None and not bound_frame.empty:
        for row in bound_frame.itertuples():
            times, bound = np.asarray(row.times, dtype=np.float64), np.asarray(row.bound)
            if times.size and bound.size and not np.isnan(bound).all():
                key = round(float(times[0]), 9)
                bounds[key] = (float(np.nanmax(bound)), 1.0 - float(row.confidence))
    plans = []
    for row in frame.itertuples():
        times = np.asarray(row.times, dtype=np.float64)
        max_bound, limit = bounds.get(round(float(times[0]), 9), (math.nan, math.nan))
        plans.append(
            PlanRecord(
                times=times,
                q=np.asarray(row.q, dtype=np.float64),
                wait_s=float(row.wait_s),
                max_bound=max_bound,
                limit=limit,
            )
        )
    try:
        return smoothness_breakdown(t, q, plans, settle_s=settle_s, near_fraction=near_fraction)
    except DataError as err:  # e.g. robot states logged at repeated times
        raise DataError(f"{where}{err}") from err
