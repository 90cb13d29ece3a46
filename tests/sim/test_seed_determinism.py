"""The scripted human and the tracker draw only from their own seeds: the same seed gives the
same motion and the same observations whatever random state the process had before, and
another seed gives other ones."""

from __future__ import annotations

import random

import numpy as np
import torch
from sim_fakes import rest_pose

from iplanner_torch.sim.human import HumanCfg, ReachingMotionSource, ScriptedHuman
from iplanner_torch.sim.scene import SceneCfg
from iplanner_torch.sim.tasks import parse_order
from iplanner_torch.sim.tracker import Tracker, TrackerCfg

SCENE = SceneCfg()
TARGETS = {i: SCENE.delivery_position(i) + [0.0, 0.0, 0.015] for i in SCENE.block_ids}


def _global_state(seed: int) -> None:
    """Seeds the global generators that the human and the tracker must not read."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _motion(seed: int, *, body_seed: int, global_seed: int) -> tuple[list[int], np.ndarray]:
    """The personal order and (T, K, 3) joint positions of 8 s of a reaching human (its body
    drawn with ``body_seed``) with every block delivered, sampled every 0.05 s."""
    _global_state(global_seed)
    human = ScriptedHuman(
        HumanCfg(),
        ReachingMotionSource(body_seed, seat_x=SCENE.human_seat_x),
        task_order=parse_order("(0,1)->(2,3)", SCENE.block_ids),
        targets=TARGETS,
        seed=seed,
    )
    poses = []
    for k in range(1, 161):
        human.update(0.05 * k, set(TARGETS))
        poses.append(human.joint_positions())
    return list(human.order), np.stack(poses)


def test_the_human_follows_its_seed_only() -> None:
    order, poses = _motion(5, body_seed=5, global_seed=1)
    again_order, again = _motion(5, body_seed=5, global_seed=2)
    assert again_order == order
    np.testing.assert_array_equal(again, poses)
    # the same body, another script: other idle times and reaches
    _, other = _motion(6, body_seed=5, global_seed=1)
    assert not np.allclose(other, poses, atol=1e-3)
    _, other_body = _motion(5, body_seed=6, global_seed=1)
    assert not np.allclose(other_body, poses, atol=1e-3)


def _observations(seed: int, *, global_seed: int) -> np.ndarray:
    """(F, K, 3) frames of 1 s of a still person, NaN where lost."""
    _global_state(global_seed)
    tracker = Tracker(TrackerCfg(noise_sigma=0.01, dropout_rate=0.2), seed=seed)
    frames = [tracker.window()[-1] for k in range(101) if tracker.observe(0.01 * k, rest_pose())]
    return np.stack(frames)


def test_the_tracker_follows_its_seed_only() -> None:
    frames = _observations(5, global_seed=1)
    np.testing.assert_array_equal(_observations(5, global_seed=2), frames)
    other = _observations(6, global_seed=1)
    assert not np.array_equal(np.isnan(other), np.isnan(frames))  # other dropouts
    both = ~np.isnan(other) & ~np.isnan(frames)
    assert not np.allclose(other[both], frames[both])  # other noise
