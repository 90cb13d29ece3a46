"""Closed-loop simulation speed: simulated seconds per wall-clock second.

``sim.realtime_factor`` runs the KUKA delivery scenario with the real ITOMP replanner in the
loop; its reference, ``sim.realtime_factor_physics``, is the same scene with the robot holding
its pose and no planner (MuJoCo, human and tracker only), measured in the same run.

Run: ``python scripts/bench_sim.py [--full]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
import warnings
from dataclasses import replace

import numpy as np


def _physics_only(robot, seconds: float) -> float:
    from iplanner_torch.sim.env import SimEnv
    from iplanner_torch.sim.human import HumanCfg, ScriptedHuman
    from iplanner_torch.sim.scene import SceneCfg
    from iplanner_torch.sim.tracker import Tracker, TrackerCfg

    scene = SceneCfg()
    human = ScriptedHuman(
        HumanCfg(mode="blocking", blocking_start_s=0.2),
        _motion(),
        task_order=None,
        targets={},
        seed=0,
    )
    env = SimEnv(scene, robot, human, Tracker(TrackerCfg(), seed=0), seed=0)
    q = robot.q_home.numpy()
    zero = np.zeros_like(q)
    t0 = time.perf_counter()
    while env.time < seconds:
        env.step(q, zero)
    return env.time / (time.perf_counter() - t0)


def _motion():
    from iplanner_torch.sim.human import ReachingMotionSource

    return ReachingMotionSource(0, seat_x=-0.45)


def run(quick: bool) -> dict[str, dict]:
    """``{figure: {"value", "unit", ...}}`` (quick: a few simulated seconds)."""
    from iplanner_torch.eval.episode import EpisodeCfg, run_episode
    from iplanner_torch.planning.optimizer import OptimizerCfg
    from iplanner_torch.planning.replanner import PlannerCfg
    from iplanner_torch.robot.model import RobotModel

    warnings.filterwarnings("ignore", message="replanning cycle")
    robot = RobotModel.load("kuka_iiwa14")
    sim_s = 1.5 if quick else 20.0
    repeats = 1 if quick else 3
    planner = PlannerCfg(kind="itomp", predictor_variant=None)
    if quick:
        planner = replace(planner, optimizer=OptimizerCfg(iterations=10, num_trajectories=4))
    cfg = EpisodeCfg(max_duration_s=sim_s, planner=planner)
    _physics_only(robot, 0.2)  # warm-up
    ref = statistics.median(_physics_only(robot, sim_s) for _ in range(repeats))
    rtf = statistics.median(
        run_episode(
            cfg, robot=robot, predictor=None, planner_kind="itomp", writer_path=None, seed=s
        ).metrics["sim/realtime_factor"]
        for s in range(repeats)
    )
    return {
        "sim.realtime_factor": {
            "value": float(rtf),
            "unit": "sim s / wall s",
            "reference": float(ref),
            "reference_name": "sim.realtime_factor_physics (no planner)",
            "ratio": float(rtf / ref),
            "sim_seconds": sim_s,
        }
    }


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--full", action="store_true", help="longer episodes, 3 repeats")
    args = parser.parse_args()
    print(json.dumps(run(quick=not args.full), indent=2))
