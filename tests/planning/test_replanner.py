"""The replanner: cycles, warm starts, overrun reporting, waits; the planner configs."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import torch
from planning_fakes import PointRobot, approaching, one_sphere_map, static_forecast

from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.planning import costs as C
from iplanner_torch.planning import replanner as replanner_module
from iplanner_torch.planning.itomp import ITOMP
from iplanner_torch.planning.optimizer import (
    MAX_HORIZON_S,
    OptimizerCfg,
    PlanResult,
    TrajectoryOptimizer,
)
from iplanner_torch.planning.replanner import (
    PlannerCfg,
    PlanningOverrunWarning,
    Replanner,
    ReplannerCfg,
    braking_stop,
    build_replanner,
)
from iplanner_torch.planning.trajectory import resample_linear

CONF = Path(__file__).resolve().parents[2] / "conf" / "planner"


class SpyOptimizer(TrajectoryOptimizer):
    """Records the arguments of every solve; with a clock, each solve takes ``solve_s``."""

    def __init__(self, *args, clock: Any = None, solve_s: float = 0.0, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.clock, self.solve_s = clock, solve_s
        self.calls: list[dict] = []

    def solve(self, q_start, q_goal, **kwargs) -> PlanResult:
        self.calls.append({"q_start": q_start.clone(), **kwargs})
        result = super().solve(q_start, q_goal, **kwargs)
        if self.clock is not None:
            self.clock.now += self.solve_s
        return result


def _spy(robot, fake_clock: Any = None, solve_s: float = 0.0) -> SpyOptimizer:
    """A spy optimiser; given the ``fake_clock`` fixture, the replanner reads wall time from a
    fake clock on which every solve takes exactly ``solve_s``."""
    clock = None if fake_clock is None else fake_clock(replanner_module)
    cfg = OptimizerCfg(iterations=5, warm_iterations=2, horizon_s=2.0)
    return SpyOptimizer(
        robot, cfg, human_spheres=one_sphere_map(0.1), clock=clock, solve_s=solve_s
    )


def test_cycles_every_m_and_warm_starts_from_the_shifted_plan(
    point_robot: PointRobot, fake_clock: Any
) -> None:
    opt = _spy(point_robot, fake_clock, solve_s=0.01)
    cfg = ReplannerCfg(
        replan_step_s=0.5, fresh_fraction=0.5, goal_change_lead_s=None, tracking="exact"
    )
    rp = Replanner(opt, cfg)
    q0, qg = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    rp.reset(q0, qg, t=0.0)
    fc = static_forecast([0.0, 0.8, 0.0], 0.05)
    first = rp.step(0.0, q0, fc)
    assert first is not None and opt.calls[0]["q_init"] is None
    assert opt.calls[0]["t0"] == pytest.approx(0.5)
    assert opt.calls[0]["window"] == pytest.approx((0.5, 1.0))
    assert rp.step(0.2, q0, fc) is None  # not due
    # until t + m the old plan (a hold) runs; then the new one
    assert torch.allclose(rp.command(0.3)[0], q0)
    q_mid, _ = first.trajectory().sample(0.75)
    assert torch.allclose(rp.command(0.75)[0], q_mid)
    q_now, _ = rp.command(0.5)
    second = rp.step(0.5, q_now, fc)
    assert second is not None and rp.stats.cycles == 2
    call = opt.calls[1]
    # starts where the first plan is at t + m, with its velocity
    q_s, qd_s = first.trajectory().sample(1.0)
    assert torch.allclose(call["q_start"], q_s) and torch.allclose(call["qd_start"], qd_s)
    # warm start: row 0 is the previous plan shifted onto the new waypoint times, moved to
    # start at q_s with an offset fading out linearly towards the goal
    w = opt.cfg.num_waypoints
    times = 1.0 + torch.linspace(0.0, call["duration"], w)
    ref = resample_linear(first.q.unsqueeze(0), first.times, times)[0]
    ref = ref + torch.linspace(1.0, 0.0, w).unsqueeze(-1) * (q_s - ref[0])
    # every row (shifted or fresh) starts where the plan starts
    rows = opt.cfg.num_trajectories
    assert torch.allclose(call["q_init"][:, 0], q_s.expand(rows, -1), atol=1e-6)
    assert torch.allclose(call["q_init"][0], ref, atol=1e-5)
    assert rp.stats.overruns == 0


def test_one_fresh_candidate_is_the_least_acceleration_cubic(point_robot: PointRobot) -> None:
    """``fresh_fraction`` 1/8 of 8 candidates (the I-Planners' setting): seven warm starts and
    one fresh candidate, the cubic from the plan's start state to rest at the goal, arriving
    where the solve is told to (checked against the cubic's coefficients solved here from its
    four end conditions), with no perturbation."""
    import numpy as np

    opt = _spy(point_robot)
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, fresh_fraction=0.125, tracking="exact"))
    q0, qg = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.3])
    rp.reset(q0, qg, t=0.0)
    first = rp.step(0.0, q0, None)
    assert first is not None
    second = rp.step(0.5, rp.command(0.5)[0], None)
    assert second is not None
    call = opt.calls[1]
    q_init, w = call["q_init"], opt.cfg.num_waypoints
    assert q_init.shape[0] == 8
    dt = call["duration"] / (w - 1)
    n_a = opt.arrival_index(call["duration"], call["arrive"] - call["t0"])
    t_a = n_a * dt
    q_s = call["q_start"].double().numpy()
    qd_s = call["qd_start"].double().numpy()
    # q(t) = c0 + c1 t + c2 t^2 + c3 t^3 with q(0) = q_s, q'(0) = qd_s, q(t_a) = goal,
    # q'(t_a) = 0, then the goal held
    ends = np.array(
        [[1, 0, 0, 0], [0, 1, 0, 0], [1, t_a, t_a**2, t_a**3], [0, 1, 2 * t_a, 3 * t_a**2]]
    )
    coef = np.linalg.solve(ends, np.stack([q_s, qd_s, qg.double().numpy(), np.zeros(2)]))
    ts = np.minimum(np.arange(w) * dt, t_a)
    cubic = np.stack([ts**0, ts, ts**2, ts**3], axis=1) @ coef  # (W, J)
    assert np.allclose(q_init[-1].double().numpy(), cubic, atol=1e-5)
    # the others are the last cycle's candidates shifted (row 0 its plan), not fresh ones
    ref = resample_linear(first.candidates[1:], first.times, call["t0"] + dt * torch.arange(w))
    ref = ref + torch.linspace(1.0, 0.0, w).view(1, w, 1) * (call["q_start"] - ref[:, :1])
    assert torch.allclose(q_init[1:7], ref[:6].to(q_init), atol=1e-5)
    assert not np.allclose(q_init[6].double().numpy(), cubic, atol=1e-3)


def _drive(
    rp: Replanner,
    q: torch.Tensor,
    until: float,
    dt: float = 0.01,
    fc=None,
    t0: float = 0.0,
):
    """Closed loop at 100 Hz with perfect tracking from ``t0``; returns times and commanded
    q, qd."""
    ts, qs, vs = [], [], []
    t = t0
    while t < until - 1e-9:
        rp.step(t, q.float(), fc)
        q, qd = rp.command(t)
        ts.append(t)
        qs.append(q)
        vs.append(qd)
        t = round(t + dt, 10)
    return (
        torch.tensor(ts, dtype=torch.float64),
        torch.stack(qs).double(),
        torch.stack(vs).double(),
    )


def test_goal_change_plan_takes_over_after_the_lead_then_every_m(point_robot) -> None:
    opt = _spy(point_robot)
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, goal_change_lead_s=0.2))
    q0 = torch.tensor([-1.0, 0.0])
    rp.reset(q0, torch.tensor([1.0, 0.0]), t=0.0)
    rp.step(0.0, q0, None)
    assert opt.calls[0]["t0"] == pytest.approx(0.2)
    assert opt.calls[0]["window"] == pytest.approx((0.2, 0.7))
    assert rp.next_cycle == pytest.approx(0.2)
    rp.step(0.2, rp.command(0.2)[0], None)
    assert opt.calls[1]["t0"] == pytest.approx(0.7)  # a regular cycle: m ahead
    assert rp.next_cycle == pytest.approx(0.7)
    rp.set_goal(torch.tensor([0.0, 1.0]), t=0.45)
    assert rp.next_cycle == pytest.approx(0.45)
    rp.step(0.45, rp.command(0.45)[0], None)
    assert opt.calls[2]["t0"] == pytest.approx(0.65) and opt.calls[2]["q_init"] is None
    with pytest.raises(ConfigError, match="goal_change_lead_s"):
        ReplannerCfg(replan_step_s=0.5, goal_change_lead_s=0.6)


def test_filtered_command_limits_acceleration_and_starts_plans_on_its_state(
    point_robot: PointRobot,
) -> None:
    opt = _spy(point_robot)
    cfg = ReplannerCfg(
        replan_step_s=0.5, acc_max=4.0, tracking="filtered", plan_from_reference=True
    )
    rp = Replanner(opt, cfg)
    q0 = torch.tensor([-1.0, 0.0])
    rp.reset(q0, torch.tensor([1.0, 0.5]), t=0.0)
    # a goal change mid-motion reverses the direction: the plan's velocity jumps
    t, q, qd = _drive(rp, q0, 1.3)
    rp.set_goal(torch.tensor([-1.0, -0.5]), t=1.3)
    t2, q2, qd2 = _drive(rp, q[-1], 3.0, t0=1.3)
    t, q, qd = torch.cat([t, t2]), torch.cat([q, q2]), torch.cat([qd, qd2])
    # finite differences of the commanded positions: continuous velocity, bounded acceleration
    vel = torch.diff(q, dim=0) / 0.01
    acc = torch.diff(vel, dim=0) / 0.01
    assert float(acc.abs().max()) <= 4.0 * 1.05
    assert float((vel - qd[1:]).abs().max()) < 0.05  # qd_des is the position's derivative
    assert float(qd.abs().max()) > 0.5  # it did move
    # every executed solve started at the reference state the commands reached at its start
    # (a plan replaced by a goal change before its start never runs)
    checked = 0
    for i, call in enumerate(opt.calls):
        if any(later["t0"] < call["t0"] for later in opt.calls[i + 1 :]):
            continue
        k = int(torch.argmin((t - call["t0"]).abs()))
        if abs(float(t[k]) - call["t0"]) < 1e-6:
            assert torch.allclose(call["q_start"].double(), q[k], atol=1e-5)
            assert torch.allclose(call["qd_start"].double(), qd[k], atol=1e-4)
            checked += 1
    assert checked >= 4


def test_filtered_command_follows_a_smooth_plan_closely(point_robot: PointRobot) -> None:
    """On a slow smooth plan the reference equals the exact plan samples (independent path)."""
    cfg = OptimizerCfg(iterations=5, warm_iterations=2, horizon_s=4.0, perturbation_std=0.0)
    opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(0.1))
    rp_f = Replanner(opt, ReplannerCfg(tracking="filtered", acc_max=50.0))
    q0, qg = torch.tensor([-0.5, 0.0]), torch.tensor([0.5, 0.2])
    rp_f.reset(q0, qg, t=0.0)
    rp_f.step(0.0, q0, None)
    plan = rp_f._next_plan
    assert plan is not None
    t = 0.0
    err = 0.0
    while t < 3.0:
        q, _ = rp_f.command(t)
        if t >= plan.t_start:
            err = max(err, float((q - plan.sample(t)[0]).abs().max()))
        t = round(t + 0.01, 10)
    assert err < 2e-3


def test_overruns_are_counted_and_warned(point_robot: PointRobot, fake_clock: Any) -> None:
    """Solves of 60 ms against a 50 ms budget are two overruns and two warnings; 40 ms ones
    are none (a fake clock: the counts do not depend on the machine's load)."""
    q0, qg = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    opt = _spy(point_robot, fake_clock, solve_s=0.06)
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, budget_s=0.05))
    rp.reset(q0, qg, t=0.0)
    with pytest.warns(PlanningOverrunWarning, match=r"took 0\.060 s, over its budget 0\.050"):
        rp.step(0.0, q0, None)
        rp.step(0.5, rp.command(0.5)[0], None)
    assert rp.stats.cycles == 2 and rp.stats.overruns == 2
    assert rp.stats.mean_solve_ms == pytest.approx(60.0)
    opt.solve_s = 0.04
    rp.reset(q0, qg, t=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlanningOverrunWarning)
        rp.step(0.0, q0, None)
        rp.step(0.5, rp.command(0.5)[0], None)
    assert rp.stats.cycles == 2 and rp.stats.overruns == 0
    assert rp.stats.mean_solve_ms == pytest.approx(40.0)


def test_stop_at_budget_gives_each_solve_its_budget_as_deadline(
    point_robot: PointRobot, fake_clock: Any
) -> None:
    """With ``stop_at_budget`` a solve's deadline is its start plus its budget (the lead's,
    when shorter); a solve that then stops early counts as cut short. Without it, no deadline."""
    q0, qg = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    opt = _spy(point_robot, fake_clock)  # the replanner's clock stands at 100 s
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, budget_s=0.05, stop_at_budget=True))
    rp.reset(q0, qg, t=0.0)
    rp.step(0.0, q0, None)
    rp.set_goal(torch.tensor([1.0, 0.5]), t=0.3)  # its cycle's lead: goal_change_lead_s
    rp.step(0.3, rp.command(0.3)[0], None)
    assert [c["deadline"] for c in opt.calls] == [pytest.approx(100.05)] * 2
    # the optimiser's own clock is real: a deadline 100 s after its epoch has long passed, so
    # every solve runs its first iteration alone (of 5 cold, 2 warm)
    assert rp.stats.cycles == 2 and rp.stats.cut_short == 2
    # a budget longer than the leads: the first cycle's (a new goal's, 0.2 s), then m
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, budget_s=1.0, stop_at_budget=True))
    rp.reset(q0, qg, t=0.0)
    rp.step(0.0, q0, None)
    rp.step(0.2, rp.command(0.2)[0], None)
    assert [c["deadline"] for c in opt.calls[2:]] == [pytest.approx(100.2), pytest.approx(100.5)]
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, budget_s=0.05))
    rp.reset(q0, qg, t=0.0)
    rp.step(0.0, q0, None)
    assert opt.calls[-1]["deadline"] is None and rp.stats.cut_short == 0


def test_wait_delays_the_goal_and_is_counted(point_robot: PointRobot) -> None:
    cfg = OptimizerCfg(iterations=0, warm_iterations=0, horizon_s=2.0, perturbation_std=0.0)
    opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(0.1))
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, goal_change_lead_s=None))
    q0, qg = torch.tensor([-1.0, 0.0]), torch.tensor([0.3, 0.0])
    rp.reset(q0, qg, t=0.0)
    blocker = static_forecast([-0.8, 0.0, 0.0], 0.03)  # right in front of the robot
    res = rp.step(0.0, q0, blocker)
    assert res is not None and not res.feasible
    assert rp.stats.waits == 1 and rp.stats.wait_s == pytest.approx(res.wait_s)
    assert res.wait_s > 0.0 and res.hold_index is not None
    t_goal_before = 0.5 + 2.0
    second = rp.step(0.5, rp.command(0.5)[0], blocker)
    # the second plan ends at the goal, pushed back by the wait
    assert float(second.times[-1]) >= t_goal_before + res.wait_s - 1e-4


def test_reset_is_required_and_goal_change_restarts_cold(point_robot: PointRobot) -> None:
    opt = _spy(point_robot)
    rp = Replanner(opt)
    with pytest.raises(ConfigError, match="reset"):
        rp.step(0.0, torch.zeros(2), None)
    rp.reset(torch.zeros(2), torch.ones(2), t=0.0)
    rp.step(0.0, torch.zeros(2), None)
    rp.set_goal(torch.tensor([-1.0, 0.5]))
    rp.step(0.5, rp.command(0.5)[0], None)
    assert opt.calls[1]["q_init"] is None
    assert not rp.goal_reached(torch.zeros(2))


def test_closed_loop_reaches_the_goal(point_robot: PointRobot) -> None:
    opt = TrajectoryOptimizer(
        point_robot,
        OptimizerCfg(iterations=10, warm_iterations=4, horizon_s=1.5),
        human_spheres=one_sphere_map(0.1),
    )
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, tracking="exact"))
    q, qg = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    rp.reset(q, qg, t=0.0)
    fc = static_forecast([0.0, 0.0, 0.0], 0.05)
    t = 0.0
    while t < 4.0:
        rp.step(t, q, fc)
        q = rp.command(t)[0]
        d = (q - torch.tensor([0.0, 0.0])).norm()
        assert float(d) > 0.15  # never inside the (mean) human sphere
        t += 0.1
    assert rp.goal_reached(q, tol=1e-3)


def test_planner_cfg_validates_and_builds() -> None:
    with pytest.raises(ConfigError, match="predictor_variant"):
        PlannerCfg(kind="iplanner", predictor_variant=None)
    with pytest.raises(ConfigError, match="replan_step_s"):
        ReplannerCfg(replan_step_s=0.0)
    for cls in (ReplannerCfg, PlannerCfg):
        with pytest.raises(ConfigError, match=r"expected replan_step_s in \(0, 10\] s"):
            cls(replan_step_s=1e9)
    cfg = PlannerCfg(kind="itomp", predictor_variant=None, confidence=0.99, replan_step_s=0.25)
    rp = build_replanner(cfg, PointRobot())
    assert isinstance(rp.optimizer, ITOMP)
    assert rp.optimizer.cfg.confidence == 0.99 and rp.cfg.replan_step_s == 0.25
    ip = build_replanner(replace(cfg, kind="iplanner", predictor_variant="ni"), PointRobot())
    assert type(ip.optimizer) is TrajectoryOptimizer  # plans on the predictor's forecast
    assert ip.optimizer.cfg.confidence == 0.99 and ip.cfg.replan_step_s == 0.25
    oracle = build_replanner(replace(cfg, kind="oracle"), PointRobot())
    assert type(oracle.optimizer) is TrajectoryOptimizer  # no ITOMP: it plans on a forecast
    with pytest.raises(ConfigError, match="oracle"):
        PlannerCfg(kind="psychic", predictor_variant=None)  # type: ignore[arg-type]


@pytest.mark.parametrize("name", ["itomp", "iplanner_no_ni", "iplanner_ni"])
def test_planner_option_files_instantiate(name: str) -> None:
    hydra_utils = pytest.importorskip("hydra.utils")
    omegaconf = pytest.importorskip("omegaconf")
    cfg = hydra_utils.instantiate(omegaconf.OmegaConf.load(CONF / f"{name}.yaml"))
    assert isinstance(cfg, PlannerCfg)
    assert cfg.kind == ("itomp" if name == "itomp" else "iplanner")
    assert isinstance(cfg.optimizer, OptimizerCfg) and isinstance(cfg.replanner, ReplannerCfg)
    if name != "itomp":
        assert cfg.predictor_variant == name.removeprefix("iplanner_")


def test_a_committed_plan_the_new_forecast_rules_out_is_replaced_early(point_robot) -> None:
    # The plan committed until t + m runs into a person the new forecast puts on its path:
    # the new plan takes over after emergency_lead_s instead of m; a harmless forecast keeps
    # the regular cadence.
    opt = TrajectoryOptimizer(
        point_robot,
        OptimizerCfg(iterations=5, warm_iterations=2),
        human_spheres=one_sphere_map(0.1),
    )
    cfg = ReplannerCfg(replan_step_s=0.5, goal_change_lead_s=0.2, emergency_lead_s=0.1)
    q0, goal = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    for where, emergency in (([5.0, 5.0, 0.0], False), (None, True)):
        rp = Replanner(opt, cfg)
        rp.reset(q0, goal, t=0.0)
        rp.step(0.0, q0, None)  # plan from 0.2 s on, no person
        t = 0.2
        q_mid = rp._current(0.55).sample(0.55)[0]  # where the committed plan is at 0.55 s
        centre = where if where is not None else [float(q_mid[0]), float(q_mid[1]), 0.0]
        fc = static_forecast(centre, 0.03)
        # the committed configurations' bound, against a bound computed pair by pair
        ts = torch.tensor([0.3, 0.55])
        qs = torch.stack([rp._current(float(x)).sample(float(x))[0] for x in ts])
        b = opt.collision_bound(qs, ts, fc, forecast_t0=t)
        d = torch.tensor(centre) - torch.cat([qs, torch.zeros(2, 1)], -1)
        ref, _ = C.gaussian_ball_bound_diag(d, torch.full((2, 3), 0.03**2), torch.full((2,), 0.15))
        assert torch.allclose(b, ref.clamp(max=1.0), atol=1e-6)
        res = rp.step(t, rp.command(t)[0], fc, forecast_t0=t)
        assert rp.stats.emergencies == int(emergency)
        assert float(res.times[0]) == pytest.approx(t + (0.1 if emergency else 0.5))
    with pytest.raises(ConfigError, match="emergency_lead_s"):
        ReplannerCfg(replan_step_s=0.5, emergency_lead_s=0.7)


def test_the_emergency_check_looks_past_the_hand_over_by_emergency_ahead_s(point_robot) -> None:
    # The committed plan is clear of the person until its successor takes over at t + m.
    # A: the person is predicted where the robot comes to rest if it brakes from its state at
    # t + m: with emergency_ahead_s the check sees it and the new plan takes over early.
    # B: the person is predicted further along the committed path, beyond where the robot can
    # still stop: no emergency (the new plan can stop short of it).
    opt = TrajectoryOptimizer(
        point_robot,
        OptimizerCfg(iterations=5, warm_iterations=2),
        human_spheres=one_sphere_map(0.1),
    )
    q0, goal = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    t, m, early, acc = 0.2, 0.5, 0.1, 20.0
    limit = 1.0 - opt.cfg.confidence
    for case, ahead, emergency in (("A", 0.0, False), ("A", 0.2, True), ("B", 0.2, False)):
        cfg = ReplannerCfg(
            replan_step_s=m, goal_change_lead_s=0.2, emergency_lead_s=early,
            emergency_ahead_s=ahead, acc_max=acc,
        )  # fmt: skip
        rp = Replanner(opt, cfg)
        rp.reset(q0, goal, t=0.0)
        rp.step(0.0, q0, None)  # plan from 0.2 s on, no person
        committed = rp._current(t + m)
        q_h, qd_h = committed.sample(t + m)
        assert float(qd_h[0]) > 1.0  # moving fast at the hand-over
        if case == "A":  # at rest after |qd| / acc of braking
            person = q_h + qd_h.square() / (2.0 * acc) * torch.sign(qd_h)
        else:
            person = committed.sample(t + m + 0.2)[0]
        fc = static_forecast([float(person[0]), float(person[1]), 0.0], 0.015)
        ts = torch.linspace(t + early, t + m, 9)
        qs = torch.stack([rp._current(float(x)).sample(float(x))[0] for x in ts])
        assert float(opt.collision_bound(qs, ts, fc, forecast_t0=t).max()) < limit
        at = opt.collision_bound(person.view(1, -1), torch.tensor([t + m + 0.2]), fc, t)
        assert float(at[0]) > limit  # where the person is, the robot would not be safe
        res = rp.step(t, rp.command(t)[0], fc, forecast_t0=t)
        assert rp.stats.emergencies == int(emergency), case
        assert float(res.times[0]) == pytest.approx(t + (early if emergency else m))
    for bad in (-0.1, 10.5, math.nan):
        with pytest.raises(ConfigError, match="emergency_ahead_s"):
            ReplannerCfg(replan_step_s=0.5, emergency_ahead_s=bad)
    assert (
        ReplannerCfg(
            replan_step_s=0.1, goal_change_lead_s=None, emergency_lead_s=None, wait_lead_s=None
        ).emergency_ahead_s
        == 0.2
    )  # not bound to m


def test_braking_stop_matches_a_stepwise_integration() -> None:
    # each joint decelerates at acc_max until it stops, then holds: against a fine Euler
    # integration of that motion
    q = torch.tensor([0.3, -1.0, 2.0, 0.5], dtype=torch.float64)
    qd = torch.tensor([1.5, -0.6, 0.0, 3.0], dtype=torch.float64)
    acc, h = 4.0, 1e-5
    s = torch.tensor([0.0, 0.05, 0.2, 0.5, 1.0], dtype=torch.float64)
    pos, vel, got, t = q.clone(), qd.clone(), [], 0.0
    for target in s.tolist():
        while t < target - 1e-12:
            step = min(h, target - t)
            dv = torch.clamp(vel.abs(), max=acc * step) * torch.sign(vel)
            pos = pos + (vel - 0.5 * dv) * step
            vel = vel - dv
            t += step
        got.append(pos.clone())
    ref = torch.stack(got)
    out = braking_stop(q, qd, s, acc)
    assert out.shape == (5, 4)
    assert torch.allclose(out, ref, atol=1e-6)
    assert torch.equal(out[0], q)
    assert torch.allclose(out[-1], q + qd * qd.abs() / (2 * acc))  # at rest: v^2 / (2 a)


def test_after_a_wait_the_next_plan_takes_over_after_wait_lead(point_robot) -> None:
    # a person right in front of the robot: the first cycle waits; with wait_lead_s the next
    # cycle's plan takes over 0.2 s after it runs (and the next cycle comes then) instead of m
    cfg = OptimizerCfg(iterations=0, warm_iterations=0, horizon_s=2.0, perturbation_std=0.0)
    opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(0.1))
    blocker = static_forecast([-0.8, 0.0, 0.0], 0.03)
    q0, goal = torch.tensor([-1.0, 0.0]), torch.tensor([0.3, 0.0])
    for wait_lead, expected in ((0.2, 0.2), (None, 0.5)):
        rcfg = ReplannerCfg(replan_step_s=0.5, goal_change_lead_s=None, wait_lead_s=wait_lead)
        rp = Replanner(opt, rcfg)
        rp.reset(q0, goal, t=0.0)
        first = rp.step(0.0, q0, blocker)
        assert not first.feasible and not first.evasive and rp.stats.waits == 1
        t = rp.next_cycle
        assert t == pytest.approx(0.5)
        res = rp.step(t, rp.command(t)[0], blocker)
        assert float(res.times[0]) == pytest.approx(t + expected)
        assert rp.next_cycle == pytest.approx(t + expected)
    with pytest.raises(ConfigError, match="wait_lead_s"):
        ReplannerCfg(replan_step_s=0.5, wait_lead_s=0.6)


def test_a_cycle_that_steps_out_of_the_way_counts_as_an_escape(point_robot) -> None:
    # the person comes straight at where the robot stands and the goal lies beyond them: no
    # plan towards it is safe, holding is not either, so the cycle steps out of the way
    # (OptimizerCfg.escape_within_s)
    cfg = OptimizerCfg(
        iterations=0,
        warm_iterations=0,
        horizon_s=1.0,
        perturbation_std=0.0,
        acc_max=6.0,
        escape_within_s=0.2,
    )
    opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(0.1))
    coming = approaching(0.8, 0.8, -0.04, dtype=torch.float32)  # at the robot by 0.8 s
    # the first cycle's own window (with emergency_ahead_s, the hold the reset made already
    # fails the check: that cycle would take over early and wait in a window still clear)
    rp_cfg = ReplannerCfg(replan_step_s=0.5, goal_change_lead_s=None, emergency_ahead_s=0.0)
    rp = Replanner(opt, rp_cfg)
    q0, goal = torch.zeros(2), torch.tensor([0.9, 0.0])
    rp.reset(q0, goal, t=0.0)
    res = rp.step(0.0, q0, coming, forecast_t0=0.0)
    assert res.evasive and res.escape
    assert (rp.stats.evasions, rp.stats.escapes, rp.stats.waits) == (1, 1, 0)
    assert float(res.q[-1].norm()) > 0.1  # it moved away from where the person arrives


def test_non_finite_measurements_and_times_are_data_errors(point_robot: PointRobot) -> None:
    opt = _spy(point_robot)
    rp = Replanner(opt, ReplannerCfg(tracking="filtered"))
    q0, qg = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    nan_q = torch.tensor([math.nan, 0.0])
    with pytest.raises(DataError, match="q_start is NaN/Inf at joint 0"):
        rp.reset(nan_q, qg, t=0.0)
    with pytest.raises(DataError, match="q_goal is NaN/Inf at joint 1"):
        rp.reset(q0, torch.tensor([1.0, math.inf]), t=0.0)
    with pytest.raises(DataError, match=r"expected t a finite time \[s\], got nan"):
        rp.reset(q0, qg, t=math.nan)
    rp.reset(q0, qg, t=0.0)
    # a NaN measurement never exceeds resync_tol: it must not yield a plan
    with pytest.raises(DataError, match="q_now is NaN/Inf at joint 0"):
        rp.step(0.0, nan_q, None)
    with pytest.raises(DataError, match=r"expected t a finite time \[s\], got nan"):
        rp.step(math.nan, q0, None)
    with pytest.raises(DataError, match=r"expected forecast_t0 a finite time \[s\], got inf"):
        rp.step(0.0, q0, None, forecast_t0=math.inf)
    with pytest.raises(DataError, match=r"expected t a finite time \[s\], got nan"):
        rp.command(math.nan)
    with pytest.raises(DataError, match="q_goal is NaN/Inf"):
        rp.set_goal(nan_q, t=0.0)
    assert not opt.calls  # nothing was planned from the bad inputs
    assert rp.step(0.0, q0, None) is not None  # the replanner is still usable


@pytest.mark.parametrize(
    "field",
    [
        "replan_step_s",
        "budget_s",
        "min_duration_s",
        "resync_tol",
        "emergency_ahead_s",
        "emergency_check_hz",
        "acc_max",
        "tracking_bandwidth",
        "tracking_max_gap_s",
    ],
)
def test_replanner_cfg_rejects_non_finite_values(field: str) -> None:
    with pytest.raises(ConfigError, match=f"expected {field} a finite number, got inf"):
        ReplannerCfg(**{field: math.inf})
    with pytest.raises(ConfigError, match=field):
        ReplannerCfg(**{field: math.nan})
    if field != "budget_s":  # typed float: None is no value (budget_s: None means m)
        with pytest.raises(ConfigError, match=f"expected {field} a finite number, got None"):
            ReplannerCfg(**{field: None})


def test_planner_cfg_rejects_non_finite_values() -> None:
    with pytest.raises(ConfigError, match="expected replan_step_s a finite number, got inf"):
        PlannerCfg(replan_step_s=math.inf)
    with pytest.raises(ConfigError, match="confidence"):
        PlannerCfg(confidence=math.nan)
    for bad in (-0.1, math.inf, math.nan):
        with pytest.raises(ConfigError, match="itomp_spread_mps"):
            PlannerCfg(itomp_spread_mps=bad)


@pytest.mark.parametrize(
    "field", ["warm_start", "replan_on_goal_change", "plan_from_reference", "stop_at_budget"]
)
@pytest.mark.parametrize("value", ["no", 2, None, 1.0])
def test_replanner_cfg_flags_are_true_or_false(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=f"expected {field} True or False, got {value!r}"):
        ReplannerCfg(**{field: value})


def test_replanner_cfg_refuses_a_min_duration_beyond_max_horizon() -> None:
    for bad in (60.5, 1e9):
        match = rf"expected min_duration_s in \(0, 60\] s, got {bad}"
        with pytest.raises(ConfigError, match=match):
            ReplannerCfg(min_duration_s=bad)
    assert ReplannerCfg(min_duration_s=MAX_HORIZON_S).min_duration_s == MAX_HORIZON_S


def test_a_goal_time_beyond_max_horizon_plans_max_horizon(point_robot: PointRobot) -> None:
    """Waits push the goal time back; the plan then spans MAX_HORIZON_S (the optimiser's
    limit) instead of failing the cycle."""
    opt = _spy(point_robot)
    rp = Replanner(opt, ReplannerCfg(tracking="exact", goal_change_lead_s=None))
    q0, qg = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    rp.reset(q0, qg, t=0.0)
    rp._t_goal = 500.0  # as after many waits
    res = rp.step(0.0, q0, None)
    assert res is not None and opt.calls[-1]["duration"] == MAX_HORIZON_S


@pytest.mark.parametrize(
    ("field", "value"), [("optimizer", {"iterations": 1}), ("replanner", None)]
)
def test_planner_cfg_refuses_nested_configs_of_another_type(field: str, value: object) -> None:
    kind = "OptimizerCfg" if field == "optimizer" else "ReplannerCfg"
    got = type(value).__name__
    with pytest.raises(ConfigError, match=f"expected {field} a {kind}, got {got}"):
        PlannerCfg(**{field: value})


@pytest.mark.parametrize("lead", ["goal_change_lead_s", "emergency_lead_s", "wait_lead_s"])
def test_planner_cfg_refuses_a_step_shorter_than_the_replanner_leads(lead: str) -> None:
    leads = {"goal_change_lead_s": None, "emergency_lead_s": None, "wait_lead_s": None}
    replanner = ReplannerCfg(**{**leads, lead: 0.2})
    with pytest.raises(
        ConfigError,
        match=rf"expected replanner.{lead} <= replan_step_s or None, got "
        rf"replanner.{lead}=0.2 with replan_step_s=0.1",
    ):
        PlannerCfg(replan_step_s=0.1, replanner=replanner)
    assert PlannerCfg(replan_step_s=0.2, replanner=replanner).replanner_cfg().replan_step_s == 0.2
    assert PlannerCfg(replan_step_s=0.1, replanner=ReplannerCfg(**leads)) is not None


def test_goal_reached_refuses_a_wrong_shape(point_robot: PointRobot) -> None:
    rp = Replanner(TrajectoryOptimizer(point_robot, OptimizerCfg()), ReplannerCfg())
    with pytest.raises(ShapeError, match=r"expected q_now \(2\), got \(3,\)"):
        rp.goal_reached(torch.zeros(3))
    rp.reset(torch.zeros(2), torch.ones(2), t=0.0)
    with pytest.raises(ShapeError, match=r"expected q_now \(2\), got \(1, 2\)"):
        rp.goal_reached(torch.ones(1, 2))
    assert rp.goal_reached(torch.ones(2))


def test_replanner_refuses_a_goal_outside_the_limits_and_a_bad_tolerance() -> None:
    """A goal beyond the joint limits could never be reached (every plan infeasible); a NaN
    or negative tolerance is never met and a text one was a TypeError."""
    rp = Replanner(TrajectoryOptimizer(PointRobot(), OptimizerCfg(num_trajectories=2)))
    start, goal = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    with pytest.raises(DataError, match=r"expected q_goal within the joint limits"):
        rp.reset(start, torch.tensor([0.0, -3.0]), 0.0)
    rp.reset(start, goal, 0.0)
    with pytest.raises(DataError, match=r"got q_goal\[1\] = -3.0 rad outside"):
        rp.set_goal(torch.tensor([0.0, -3.0]))
    assert torch.equal(rp.goal, goal)  # the goal before stays
    for tol in (math.nan, -1.0, "x"):
        with pytest.raises(ConfigError, match="expected tol >= 0 and finite"):
            rp.goal_reached(start, tol)  # type: ignore[arg-type]
    assert rp.goal_reached(goal, 0.0)


def test_the_filtered_reference_is_a_critically_damped_step_response(
    point_robot: PointRobot,
) -> None:
    """Held at 0.1 rad from a reference at rest at 0 (no limit binding), the reference
    follows ``x(t) = 0.1 (1 - (1 + w t) e^{-w t})``, the critically damped closed form, and
    never overshoots (a damping of w instead of 2 w would overshoot by 16 %)."""
    w = 10.0
    opt = _spy(point_robot)
    cfg = ReplannerCfg(tracking="filtered", acc_max=1e3, tracking_bandwidth=w, tracking_dt=1e-3)
    rp = Replanner(opt, cfg)
    rp.reset(torch.zeros(2), torch.tensor([1.0, 0.0]), t=0.0)
    hold = rp._hold(torch.tensor([0.1, 0.0]), 0.0)
    rp._ref = (0.0, torch.zeros(2), torch.zeros(2))
    worst = peak = 0.0
    for k in range(1, 101):
        t = 0.01 * k
        rp._ref = rp._reference_at(t, hold, None)
        x = float(rp._ref[1][0])
        worst = max(worst, abs(x - 0.1 * (1.0 - (1.0 + w * t) * math.exp(-w * t))))
        peak = max(peak, x)
    assert worst < 1e-3  # 1 % of the step (the integration's step is 1 ms)
    assert peak <= 0.1 + 1e-6


def test_a_resync_moves_the_filtered_command_to_the_measured_pose(
    point_robot: PointRobot,
) -> None:
    """The robot measured 0.5 rad off its reference (beyond ``resync_tol``): the plan is
    re-anchored there and so is the command, which would otherwise jump back."""
    opt = _spy(point_robot)
    rp = Replanner(opt, ReplannerCfg(tracking="filtered", replan_step_s=0.5))
    q0 = torch.tensor([-1.0, 0.0])
    rp.reset(q0, torch.tensor([1.0, 0.0]), t=0.0)
    rp.step(0.0, q0, None)
    q_ref, _ = rp.command(0.5)
    pushed = q_ref + torch.tensor([0.0, 0.5])
    rp.step(0.5, pushed, None)
    q_cmd, _ = rp.command(0.5)
    torch.testing.assert_close(q_cmd, pushed.to(q_cmd), rtol=0, atol=1e-6)


def test_the_emergency_check_runs_the_pending_plan_only_from_its_start(
    point_robot: PointRobot,
) -> None:
    """The running plan holds at A, clear of the person; a pending one holds at B, on the
    person, from its start. Starting after the checked span (0.1-0.5 s), it is not checked:
    no emergency; starting at 0.3 s, it is, from there: an emergency."""
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(), human_spheres=one_sphere_map(0.1))
    cfg = ReplannerCfg(replan_step_s=0.5, emergency_lead_s=0.1, emergency_ahead_s=0.0)
    rp = Replanner(opt, cfg)
    a, b = torch.tensor([-1.5, 0.0]), torch.tensor([1.0, 0.0])
    rp.reset(a, b, t=0.0)
    fc = static_forecast([1.0, 0.0, 0.0], 0.02)
    running = rp._hold(a, 0.0)
    for start, unsafe in ((0.8, False), (0.3, True)):
        rp._next_plan = rp._hold(b, start)
        assert rp._committed_unsafe(0.0, 0.5, running, fc, 0.0) is unsafe, start


def test_fresh_candidates_are_drawn_anew_each_cycle(point_robot: PointRobot) -> None:
    """With ``fresh_fraction`` > 0 every warm-started cycle draws its fresh candidates with
    a seed of its own (the same seed would give the same perturbations every cycle)."""
    opt = _spy(point_robot)
    seeds: list[int] = []
    draw = opt.initial_trajectories

    def recording(q_s, q_g, n, seed, *args, **kwargs):
        seeds.append(seed)
        return draw(q_s, q_g, n, seed, *args, **kwargs)

    opt.initial_trajectories = recording  # type: ignore[method-assign]
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, fresh_fraction=0.5))
    q0 = torch.tensor([-1.0, 0.0])
    rp.reset(q0, torch.tensor([1.0, 0.0]), t=0.0)
    for k in range(4):
        t = 0.5 * k
        rp.step(t, rp.command(t)[0] if k else q0, None)
    fresh = seeds[-3:]  # the warm-started cycles' draws
    assert len(seeds) >= 3 and len(set(fresh)) == 3, seeds


def test_episodes_and_goal_changes_draw_initial_trajectories_of_their_own(
    point_robot: PointRobot,
) -> None:
    """Episodes of neighbouring seeds share no draw of initial trajectories (with ``seed +
    cycle`` episode s's cycle k + 1 drew episode s + 1's cycle k), and the cold start after a
    goal change draws anew (not the episode's first draw again): the perturbations
    themselves (each seed's draw on a path resting at the origin), not only their seeds."""
    draws: dict[int, list[torch.Tensor]] = {}
    for episode_seed in (0, 1):
        opt = _spy(point_robot)
        opt.cfg = replace(opt.cfg, seed=episode_seed)
        draw = opt.initial_trajectories
        got: list[torch.Tensor] = []

        def recording(q_s, q_g, n, seed, *args, _draw=draw, _got=got, **kwargs):
            # the perturbations this seed draws, on a path that stays at the origin
            still = torch.zeros_like(q_s)
            _got.append(_draw(still, still, n, seed))
            return _draw(q_s, q_g, n, seed, *args, **kwargs)

        opt.initial_trajectories = recording  # type: ignore[method-assign]
        rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5, fresh_fraction=0.5))
        q0, goals = torch.tensor([-1.0, 0.0]), (torch.tensor([1.0, 0.0]), torch.tensor([0.5, 0.5]))
        rp.reset(q0, goals[0], t=0.0)
        for k in range(6):
            t = 0.5 * k
            if k == 3:
                rp.set_goal(goals[1], t=t)
            rp.step(t, rp.command(t)[0] if k else q0, None)
        assert len(got) == 6 and [len(d) for d in got] == [8, 4, 4, 8, 4, 4]
        draws[episode_seed] = got
    # the first trajectory of each draw is the unperturbed path
    every = [d[1:] for seed_draws in draws.values() for d in seed_draws]
    for i in range(len(every)):
        for j in range(i):
            if every[i].shape == every[j].shape:
                assert not torch.allclose(every[i], every[j]), (i, j)


def test_the_goal_time_follows_the_arrival_each_plan_was_given(point_robot: PointRobot) -> None:
    """After every cycle the goal time is no earlier than the arrival the cycle's solve was
    given (``arrive``): a goal time left behind would make the next cycle rush."""
    opt = _spy(point_robot)
    rp = Replanner(opt, ReplannerCfg(replan_step_s=0.5))
    q0 = torch.tensor([-1.0, 0.0])
    rp.reset(q0, torch.tensor([1.0, 0.0]), t=0.0)
    rp._t_goal = 0.1  # as if an earlier goal change had asked for an arrival now
    rp.step(0.0, q0, None)
    assert rp._t_goal >= opt.calls[-1]["arrive"] - 1e-12
    assert opt.calls[-1]["arrive"] > 0.6  # the line at 2/3 of the limits takes that long
