"""The optimiser's random initial trajectories and the task planner's Q-learning draw only from
their seeds: the same seed gives the same numbers whatever random state the process had
before, and another seed gives other ones."""

from __future__ import annotations

import random

import numpy as np
import torch
from planning_fakes import PointRobot

from iplanner_torch.planning.optimizer import OptimizerCfg, TrajectoryOptimizer
from iplanner_torch.planning.task_mdp import TaskMDPCfg, TaskPlanner


def _global_state(seed: int) -> None:
    """Seeds the global generators that the planners must not read."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _initial(seed: int, *, global_seed: int) -> torch.Tensor:
    """(8, W, 2) initial trajectories of a point robot across its square."""
    _global_state(global_seed)
    opt = TrajectoryOptimizer(PointRobot(), OptimizerCfg())
    start, goal = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.5])
    return opt.initial_trajectories(start, goal, 8, seed, 2.0)


def test_initial_trajectories_follow_their_seed_only() -> None:
    q = _initial(3, global_seed=1)
    assert torch.equal(_initial(3, global_seed=2), q)
    other = _initial(4, global_seed=1)
    assert torch.equal(other[0], q[0])  # the unperturbed path
    assert not torch.allclose(other[1:], q[1:])


class AnyOrder:
    """The human takes the three objects in any order (each delivered one with equal odds)."""

    def allowed_next(self, done: set[int]) -> set[int]:
        return {0, 1, 2} - done


def _q_learning(seed: int, *, global_seed: int) -> tuple[list[float], dict[int, list[float]]]:
    """The returns of 60 training episodes and the learned Q table."""
    _global_state(global_seed)
    planner = TaskPlanner(TaskMDPCfg(num_objects=3, episodes=60, seed=seed), AnyOrder())
    returns = planner.train()
    return returns, {s: v.tolist() for s, v in sorted(planner.q.items())}


def test_q_learning_follows_its_seed_only() -> None:
    returns, q = _q_learning(3, global_seed=1)
    assert _q_learning(3, global_seed=2) == (returns, q)
    other_returns, other_q = _q_learning(4, global_seed=1)
    assert other_returns != returns and other_q != q


def test_a_second_training_continues_the_stream() -> None:
    """train(a) then train(b) is train(a + b); a second call used to replay the first one's
    episodes from the seed."""
    cfg = TaskMDPCfg(num_objects=3, episodes=60, seed=5)
    split = TaskPlanner(cfg, AnyOrder())
    first = split.train(25)
    second = split.train(35)
    whole = TaskPlanner(cfg, AnyOrder())
    assert first + second == whole.train(60)
    assert {s: v.tolist() for s, v in split.q.items()} == {
        s: v.tolist() for s, v in whole.q.items()
    }
