"""The MDP task planner: Q-learning finds the obvious order; persistence; validation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.errors import CheckpointError, ConfigError
from iplanner_torch.planning.task_mdp import TaskMDPCfg, TaskPlanner, decode_state, encode_state


class StrictOrder:
    """The human takes the objects in exactly this order."""

    def __init__(self, order: list[int]) -> None:
        self.order = order

    def allowed_next(self, done: set[int]) -> set[int]:
        rest = [i for i in self.order if i not in done]
        return {rest[0]} if rest else set()


def _follow_policy(planner: TaskPlanner, order: list[int]) -> list[int]:
    """Roll out pi with a human who takes each object right after it is fetched."""
    taken: set[int] = set()
    fetched: set[int] = set()
    seq = []
    while (a := planner.policy(taken, fetched)) is not None:
        seq.append(a)
        fetched.add(a)
        nxt = [i for i in order if i not in taken][0]
        if nxt in fetched:
            taken.add(nxt)
    return seq


@pytest.mark.parametrize("order", [[0, 1, 2], [2, 0, 1]])
def test_q_learning_fetches_in_the_human_order(order: list[int]) -> None:
    # p(n | p) from the task order alone (uniform over the allowed objects)
    cfg = TaskMDPCfg(num_objects=3, episodes=400, seed=1)
    planner = TaskPlanner(cfg, StrictOrder(order))
    returns = planner.train()
    assert len(returns) == 400
    assert _follow_policy(planner, order) == order
    # the learned values, not the unseen-state fallback, decide along the whole path
    taken: set[int] = set()
    fetched: set[int] = set()
    for obj in order:
        state = encode_state(taken, fetched, 3)
        assert state in planner.q
        assert int(np.argmax(planner.q_values(state))) == obj
        fetched.add(obj)
        taken.add(obj)


def test_delay_steers_the_choice_between_equally_useful_objects() -> None:
    # any order is fine for the human; fetching object 1 first makes the robot wait 3 s
    class AnyOrder:
        def allowed_next(self, done: set[int]) -> set[int]:
            return {0, 1} - done

    def delay(state: int, action: int, rng: np.random.Generator) -> float:
        taken, fetched = decode_state(state, 2)
        return 3.0 if (action == 1 and fetched == 0) else 0.0

    cfg = TaskMDPCfg(num_objects=2, episodes=600, w_delay=1.0, idle_delay_s=0.0, seed=2)
    planner = TaskPlanner(cfg, AnyOrder(), delay_fn=delay)
    planner.train()
    assert planner.policy(set(), set()) == 0


def test_reward_uses_next_action_probabilities_and_h() -> None:
    probs = {0: [0.2, 0.8]}
    h = np.array([[1.0, 0.0], [-0.5, 1.0]])
    planner = TaskPlanner(TaskMDPCfg(num_objects=2), next_action_probs=probs, h_table=h)
    assert planner.r_prep(0, 0) == pytest.approx(0.2 * 1.0 + 0.8 * -0.5)
    assert planner.r_prep(0, 1) == pytest.approx(0.8)
    assert encode_state({1}, {0, 1}, 2) == 0b1110
    assert decode_state(0b1110, 2) == (0b10, 0b11)


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    planner = TaskPlanner(TaskMDPCfg(num_objects=3, episodes=50), StrictOrder([1, 0, 2]))
    planner.train()
    path = tmp_path / "task_mdp.json"
    planner.save(path)
    loaded = TaskPlanner.load(path)
    assert loaded.cfg == planner.cfg
    assert loaded.q.keys() == planner.q.keys()
    for k in planner.q:
        assert np.array_equal(loaded.q[k], planner.q[k])
    (tmp_path / "bad.json").write_text('{"format": "other"}')
    with pytest.raises(CheckpointError, match="not a task planner file"):
        TaskPlanner.load(tmp_path / "bad.json")
    with pytest.raises(CheckpointError, match="cannot read"):
        TaskPlanner.load(tmp_path / "missing.json")


def test_config_is_validated() -> None:
    with pytest.raises(ConfigError, match="alpha"):
        TaskMDPCfg(num_objects=2, alpha=0.0)
    with pytest.raises(ConfigError, match=r"h_table \(2, 2\)"):
        TaskPlanner(TaskMDPCfg(num_objects=2), h_table=np.eye(3))
