"""Closed-loop simulation speed: simulated seconds per wall-clock second.

``sim.realtime_factor`` runs the KUKA delivery scenario with the real planner in the loop:
I-Planner (NI) with the real predictor when a checkpoint is given (``--predictor PATH`` or the
environment variable ``IPLANNER_PREDICTOR``), else ITOMP; its reference,
``sim.realtime_factor_physics``, is the same scene with the robot holding its pose and no
planner (MuJoCo, human and tracker only), measured in the same run. Episodes run with one
torch thread (``EpisodeCfg.torch_threads``) and the planner settings of
``conf/planner/itomp.yaml``, read from the file (with its ``per_kind`` entries, so the
I-Planner runs as in the experiments). ``plan.solve_ms`` is the mean wall-clock time of a
replanning solve in those episodes, against the step m = 0.5 s.

Run: ``python scripts/bench_sim.py [--quick | --full] [--predictor PATH]`` (``--quick``, a few
simulated seconds, is the default here; ``scripts/bench.py`` runs the full size unless given
``--quick``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
import warnings

import numpy as np
from _report import main_guard


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


def run(quick: bool, predictor_path: str | None = None) -> dict[str, dict]:
    """``{figure: {"value", "unit", ...}}`` (quick: a few simulated seconds)."""
    from pathlib import Path

    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import CONF_DIR, instantiate
    from iplanner_torch.eval.episode import EpisodeCfg, run_episode
    from iplanner_torch.planning.replanner import PlannerCfg
    from iplanner_torch.robot.model import RobotModel

    warnings.filterwarnings("ignore", message="replanning cycle")
    robot = RobotModel.load("kuka_iiwa14")
    sim_s = 3.0 if quick else 20.0
    repeats = 1 if quick else 3
    predictor_path = predictor_path or os.environ.get("IPLANNER_PREDICTOR")
    predictor = None
    kind = "itomp"
    if predictor_path:
        from iplanner_torch.prediction.predictor import HumanMotionPredictor

        predictor = HumanMotionPredictor.load(predictor_path)
        kind = "iplanner_ni"
    # the experiments' planner settings (their interpolations fall back to their defaults)
    node = OmegaConf.load(Path(CONF_DIR) / "planner" / "itomp.yaml")
    planner = instantiate(node, PlannerCfg, name="planner")
    cfg = EpisodeCfg(max_duration_s=sim_s, planner=planner)
    _physics_only(robot, 0.2)  # warm-up
    ref = statistics.median(_physics_only(robot, sim_s) for _ in range(repeats))
    runs = [
        run_episode(
            cfg, robot=robot, predictor=predictor, planner_kind=kind, writer_path=None, seed=s
        ).metrics
        for s in range(repeats)
    ]
    rtf = statistics.median(m["sim/realtime_factor"] for m in runs)
    solve = statistics.median(m["plan/mean_solve_ms"] for m in runs)
    return {
        "plan.solve_ms": {
            "value": float(solve),
            "unit": "ms",
            "reference": 500.0,
            "reference_name": "replanning step m",
            "ratio": float(solve / 500.0),
            "planner": kind,
        },
        "sim.realtime_factor": {
            "value": float(rtf),
            "unit": "sim s / wall s",
            "reference": float(ref),
            "reference_name": "sim.realtime_factor_physics (no planner)",
            "ratio": float(rtf / ref),
            "sim_seconds": sim_s,
            "planner": kind,
        },
    }


@main_guard
def main() -> None:
    """The command line: a bad checkpoint is one ``error:`` line, exit 2."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="a few simulated seconds (default)")
    size.add_argument("--full", action="store_true", help="longer episodes, 3 repeats")
    parser.add_argument("--predictor", default=None, help="predictor checkpoint (I-Planner)")
    args = parser.parse_args()
    print(json.dumps(run(quick=not args.full, predictor_path=args.predictor), indent=2))


if __name__ == "__main__":
    main()
