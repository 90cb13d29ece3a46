#!/usr/bin/env python
"""Benchmark of one replanning cycle (forecast to optimised plan) on the KUKA iiwa 14.

B = 8 and B = 64 trajectories, 20 waypoints, 7 joints, the 22 spheres of the upper body
(``OptimizerCfg.human_spheres="inner"``; the B = 8 cycle is timed with the 42 covering
spheres too), A = 10 actions. The forecast is synthetic (the predictor is timed by its own
benchmark), so ``predict_ms`` counts only turning the forecast into Gaussian spheres at the
waypoint times. Cycles are warm-started, as in closed loop: each timing is one
``Replanner.step`` after a first cold one, with the closed loop's acceleration limit and the
check of the committed plans against the new forecast. Runs single-threaded
(``torch.set_num_threads(1)``): these tensors are small and intra-op threads only add
synchronisation.

Usage::

    python scripts/bench_planning.py [--quick]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from _timing import reference_ms

from iplanner_torch.collision.human_spheres import SphereLayout
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.planning.optimizer import OptimizerCfg, TrajectoryOptimizer
from iplanner_torch.planning.replanner import Replanner, ReplannerCfg
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import torch_threads

#: the cycle-time goal [ms] for B = 8 on a 2-core CPU
GOAL_MS = 50.0


def synthetic_forecast(num_actions: int = 10, n_f: int = 30, dt: float = 1 / 15) -> Forecast:
    """A seated person across the table reaching with the right hand towards A targets."""
    gen = torch.Generator().manual_seed(0)
    pose = torch.tensor(
        [
            [0.95, 0.00, 0.55],  # head
            [0.95, 0.00, 0.40],  # neck
            [0.97, 0.00, 0.20],  # torso
            [1.00, 0.00, 0.00],  # waist
            [0.95, 0.18, 0.38],  # left shoulder
            [0.85, 0.25, 0.15],  # left elbow
            [0.70, 0.20, 0.05],  # left hand
            [0.95, -0.18, 0.38],  # right shoulder
            [0.80, -0.25, 0.20],  # right elbow
            [0.62, -0.20, 0.08],  # right hand
        ]
    )
    pose[:, 0] += 0.35  # seated across the table from the robot's home pose
    targets = pose[9] + 0.25 * torch.randn(num_actions, 3, generator=gen) * torch.tensor(
        [1.0, 1.0, 0.3]
    )
    s = torch.linspace(0.0, 1.0, n_f).view(1, n_f, 1)  # (1, n_f, 1)
    mean = pose.expand(num_actions, n_f, 10, 3).clone()  # (A, n_f, K, 3)
    hand_path = pose[9] + s * (targets.view(-1, 1, 3) - pose[9])  # (A, n_f, 3)
    mean[:, :, 9] = hand_path
    mean[:, :, 8] = 0.5 * (pose[8] + hand_path)
    std = 0.01 + 0.04 * s.unsqueeze(-1)  # (1, n_f, 1, 1)
    var = (std**2).expand(num_actions, n_f, 10, 3).clone()
    weights = torch.softmax(torch.randn(num_actions, generator=gen), 0)
    return Forecast(
        weights=weights.unsqueeze(0),
        mean=mean.unsqueeze(0),
        var=var.unsqueeze(0),
        dt=dt,
        joint_names=JOINT_NAMES,
        action_names=tuple(f"reach_{a}" for a in range(num_actions)),
    )


def started_replanner(
    robot, b: int, forecast: Forecast, layout: SphereLayout = "inner"
) -> tuple[Replanner, TrajectoryOptimizer, torch.Tensor, torch.Tensor]:
    """The benchmark's replanner (B = ``b``, W = 20, 6 warm iterations) after its cold start
    at t = 0 towards a goal 1.2 and 0.4 rad away in joints 0 and 3: ``(replanner, its
    optimiser, start (J,), goal (J,))``. Also the cycle of ``count_cycle_ops.py``."""
    rcfg = ReplannerCfg(replan_step_s=0.5)  # filtered tracking, committed-plan check on
    cfg = OptimizerCfg(
        num_trajectories=b,
        num_waypoints=20,
        iterations=20,
        warm_iterations=6,
        acc_max=rcfg.acc_max,  # as in closed loop (PlannerCfg.optimizer_cfg)
        human_spheres=layout,
    )
    opt = TrajectoryOptimizer(robot, cfg)
    rp = Replanner(opt, rcfg)
    q0 = robot.q_home.clone()
    qg = q0.clone()
    qg[0] += 1.2
    qg[3] += 0.4
    rp.reset(q0, qg, t=0.0)
    rp.step(0.0, q0, forecast)  # cold start
    return rp, opt, q0, qg


def _cycle_times(
    robot, b: int, forecast: Forecast, repeats: int, layout: SphereLayout = "inner"
) -> dict[str, float]:
    rp, opt, q0, qg = started_replanner(robot, b, forecast, layout)
    totals, ratios = [], []
    parts: dict[str, list[float]] = {"predict_ms": [], "collision_ms": [], "optimiser_ms": []}
    t = 0.5
    for i in range(repeats + 2):  # two warm-up cycles
        q_now = rp.command(t)[0]
        t_wall = time.perf_counter()
        res = rp.step(t, q_now, forecast, forecast_t0=t)
        ms = 1e3 * (time.perf_counter() - t_wall)
        if i >= 2:
            totals.append(ms)
            ratios.append(ms / reference_ms())  # the machine's speed right now
            for k in parts:
                parts[k].append(res.timings[k])
        t += 0.5
        if t > 2.5:  # restart the motion so every cycle plans a real move
            rp.reset(q0, qg, t=t)
            rp.step(t, q0, forecast)
            t += 0.5
    out = {"cycle_ms": statistics.median(totals), "per_reference": statistics.median(ratios)}
    out.update({k: statistics.median(v) for k, v in parts.items()})
    out["feasible_rate"] = rp.stats.cycles and 1.0 - rp.stats.waits / rp.stats.cycles
    out["human_spheres"] = opt._spheres_for(tuple(forecast.joint_names)).num_spheres
    return out


def run(quick: bool) -> dict[str, dict]:
    """Replanning-cycle figures (medians over repeated warm-started cycles)."""
    from iplanner_torch.robot.model import RobotModel

    with torch_threads(1):
        robot = RobotModel.load("kuka_iiwa14")
        forecast = synthetic_forecast()
        repeats = 5 if quick else 30
        b8 = _cycle_times(robot, 8, forecast, repeats)
        b64 = _cycle_times(robot, 64, forecast, max(3, repeats // 3))
        b8_cover = _cycle_times(robot, 8, forecast, repeats, layout="cover")
    note = (
        f"iiwa, W=20, S_r={robot.num_spheres}, S_h={b8['human_spheres']}, A=10, warm-started "
        "(6 iterations), 1 thread; synthetic forecast: predict_ms excludes the predictor"
    )
    return {
        "replan.cycle_b8_ms": {
            "value": b8["cycle_ms"],
            "unit": "ms",
            "reference": GOAL_MS,
            "ratio": b8["cycle_ms"] / GOAL_MS,
            "note": note,
            "feasible_rate": b8["feasible_rate"],
        },
        "replan.cycle_b64_ms": {
            "value": b64["cycle_ms"],
            "unit": "ms",
            "reference": b8["cycle_ms"],
            "ratio": b64["cycle_ms"] / b8["cycle_ms"],
            "note": "reference: the B = 8 cycle of the same run",
        },
        "replan.cycle_b8_cover_spheres_ms": {
            "value": b8_cover["cycle_ms"],
            "unit": "ms",
            "reference": b8["cycle_ms"],
            "ratio": b8_cover["cycle_ms"] / b8["cycle_ms"],
            "note": f"human_spheres=cover (S_h={b8_cover['human_spheres']}); reference: the "
            "B = 8 cycle with the inner spheres, same run",
        },
        "replan.cycle_b8_per_reference": {
            "value": b8["per_reference"],
            "unit": "x reference",
            "reference": "scripts/_timing.reference_ms, timed after each cycle",
            "note": "median of cycle / reference workload: compare this across runs, as it "
            "follows the machine's drift less than the cycle time itself",
        },
        "replan.cycle_b8_predict_ms": {"value": b8["predict_ms"], "unit": "ms", "note": note},
        "replan.cycle_b8_collision_ms": {"value": b8["collision_ms"], "unit": "ms"},
        "replan.cycle_b8_optimiser_ms": {"value": b8["optimiser_ms"], "unit": "ms"},
    }


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    for name, fig in run(args.quick).items():
        extra = {k: v for k, v in fig.items() if k not in ("value", "unit", "note")}
        print(f"{name:32s} {fig['value']:10.2f} {fig['unit']}  {extra}")
