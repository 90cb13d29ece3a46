"""The MDP task planner: Q-learning finds the obvious order; persistence; validation."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.errors import CheckpointError, ConfigError, DataError, ShapeError
from iplanner_torch.planning.task_mdp import (
    TaskMDPCfg,
    TaskPlanner,
    decode_state,
    encode_state,
    reach_crossings,
)


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


def _saved(tmp_path: Path) -> dict:
    """The JSON of a small trained planner (2 objects)."""
    planner = TaskPlanner(TaskMDPCfg(num_objects=2, episodes=20), StrictOrder([0, 1]))
    planner.train()
    path = tmp_path / "good.json"
    planner.save(path)
    return json.loads(path.read_text())


def _drop(key: str) -> Callable[[dict], dict]:
    return lambda d: {k: v for k, v in d.items() if k != key}


def _with_cfg(**changes: object) -> Callable[[dict], dict]:
    return lambda d: {**d, "cfg": {**d["cfg"], **changes}}


def _with_q(q: object) -> Callable[[dict], dict]:
    return lambda d: {**d, "q": q}


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: [d], "expected a JSON object, got list"),
        (_drop("cfg"), "missing 'cfg'"),
        (_drop("q"), "missing 'q'"),
        (_with_cfg(bogus=1), r"unknown cfg keys \['bogus'\]"),
        (_with_cfg(num_objects=0), "invalid cfg: expected num_objects in"),
        (_with_cfg(episodes=1.5), "invalid cfg: expected episodes an int"),
        (lambda d: {**d, "h_table": [[1.0]]}, r"h_table \(2, 2\), got shape \(1, 1\)"),
        (_with_q({"x": [0.0, 0.0]}), "q key 'x' is not a progress state"),
        (_with_q({"16": [0.0, 0.0]}), "q key '16' is not a progress state"),
        (_with_q({"0": [0.5]}), r"expected q\[0\] of shape \(2,\).*got \(1,\)"),
        (_with_q({"0": [[0.5, 1.0]]}), r"expected q\[0\] of shape \(2,\)"),
        (_with_q({"0": ["a", 1.0]}), r"q\[0\] is not numeric"),
        (_with_q({"0": [math.nan, 1.0]}), r"q\[0\] has non-finite values"),
        (_with_q([[0.0, 0.0]]), "expected q an object"),
    ],
)
def test_load_rejects_malformed_files_naming_the_file(
    tmp_path: Path, edit: Callable[[dict], object], match: str
) -> None:
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(edit(_saved(tmp_path))))
    with pytest.raises(CheckpointError, match=match) as info:
        TaskPlanner.load(path)
    assert str(path) in str(info.value)


def test_load_rejects_a_binary_file(tmp_path: Path) -> None:
    path = tmp_path / "binary.json"
    path.write_bytes(b"\xff\xfe\x00\x81\x9c")
    with pytest.raises(CheckpointError, match="cannot read task planner .*binary.json"):
        TaskPlanner.load(path)


def test_load_keeps_a_valid_q_table_policy_usable(tmp_path: Path) -> None:
    data = _saved(tmp_path)
    path = tmp_path / "valid.json"
    path.write_text(json.dumps(data))
    loaded = TaskPlanner.load(path)
    assert all(v.shape == (2,) for v in loaded.q.values())
    assert loaded.policy(set(), set()) in (0, 1)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"episodes": 1.5}, "expected episodes an integer, got 1.5"),
        ({"num_objects": 2.0}, "expected num_objects an int"),
        ({"seed": True}, "expected seed an int"),
        ({"seed": -1}, "expected seed >= 0"),
        ({"w_prep": math.nan}, "expected w_prep a finite number, got nan"),
        ({"w_delay": math.inf}, "expected w_delay a finite number"),
        ({"idle_delay_s": "2"}, "expected idle_delay_s a finite number"),
        ({"gamma": math.nan}, "expected gamma a finite number"),
    ],
)
def test_config_rejects_wrong_types_and_non_finite_values(changes: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        TaskMDPCfg(**{"num_objects": 2, **changes})


def test_policy_rejects_unknown_objects() -> None:
    planner = TaskPlanner(TaskMDPCfg(num_objects=4))
    with pytest.raises(
        ConfigError, match=r"unknown object 9 in taken: expected indices in \[0, 4\)"
    ):
        planner.policy(taken={9}, fetched=set())
    with pytest.raises(ConfigError, match="unknown object -1 in fetched"):
        planner.policy(taken=set(), fetched={-1})
    with pytest.raises(ConfigError, match="expected fetched a bitmask of 4 objects, got 16"):
        planner.policy(taken=0, fetched=16)
    assert planner.policy(taken={0}, fetched={0, 1}) in (2, 3)


def test_nan_next_action_probabilities_are_a_data_error() -> None:
    table = TaskPlanner(TaskMDPCfg(num_objects=2), next_action_probs={0: [math.nan, 1.0]})
    with pytest.raises(DataError, match="finite next-action probabilities for taken mask 0"):
        table.human_next_probs(0)
    fn = TaskPlanner(TaskMDPCfg(num_objects=2), next_action_probs=lambda taken: [0.5, math.inf])
    with pytest.raises(DataError, match="finite next-action probabilities"):
        fn.r_prep(0, 1)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_h_table_is_a_data_error(value: float) -> None:
    table = np.eye(3)
    table[1, 2] = value
    with pytest.raises(DataError, match=r"expected a finite h_table, got h_table\[1, 2\]"):
        TaskPlanner(TaskMDPCfg(num_objects=3), h_table=table)


def test_non_numeric_h_table_is_a_data_error() -> None:
    with pytest.raises(DataError, match=r"expected h_table a numeric \(n, n\) table"):
        TaskPlanner(TaskMDPCfg(num_objects=2), h_table=[["a", "b"], ["c", "d"]])


def test_policy_takes_numpy_integer_bitmasks() -> None:
    planner = TaskPlanner(TaskMDPCfg(num_objects=3, episodes=50))
    planner.train()
    taken, fetched = 0b001, 0b011
    assert planner.policy(np.int64(taken), np.int64(fetched)) == planner.policy(taken, fetched)
    assert planner.policy(np.int32(0), np.int64(0)) == planner.policy(0, 0)


@pytest.mark.parametrize(
    ("taken", "fetched"), [({0}, set()), ({1}, {0}), (0b010, 0b001), ({0, 2}, {0, 1})]
)
def test_policy_refuses_an_object_taken_but_never_fetched(taken: object, fetched: object) -> None:
    planner = TaskPlanner(TaskMDPCfg(num_objects=3))
    with pytest.raises(DataError, match=r"expected every taken object fetched"):
        planner.policy(taken, fetched)


def test_policy_refuses_neither_bitmask_nor_indices() -> None:
    planner = TaskPlanner(TaskMDPCfg(num_objects=3))
    with pytest.raises(ConfigError, match="expected taken a set of object indices or a bitmask"):
        planner.policy(None, set())  # type: ignore[arg-type]


@pytest.mark.parametrize("action", [3, -1, 1.5, "0"])
def test_simulate_step_refuses_an_action_out_of_range(action: object) -> None:
    planner = TaskPlanner(TaskMDPCfg(num_objects=3))
    with pytest.raises(ConfigError, match="expected action an"):
        planner.simulate_step(0, action, np.random.default_rng(0))  # type: ignore[arg-type]


@pytest.mark.parametrize("episodes", [-1, 2.5, True, "3"])
def test_train_refuses_a_bad_episode_count(episodes: object) -> None:
    planner = TaskPlanner(TaskMDPCfg(num_objects=2))
    with pytest.raises(ConfigError, match="expected episodes an integer >= 0"):
        planner.train(episodes)  # type: ignore[arg-type]
    assert planner.train(0) == []


@pytest.mark.parametrize("delay", [math.nan, math.inf, -1.0, "2", None])
def test_a_bad_delay_is_a_data_error_naming_state_and_action(delay: object) -> None:
    # NaN, inf or a negative delay went into the Q table silently; a string or None raised a
    # bare ValueError/TypeError from float()
    planner = TaskPlanner(TaskMDPCfg(num_objects=2, episodes=3), delay_fn=lambda s, a, r: delay)
    with pytest.raises(DataError, match=r"expected delay_fn\(state=0, action=\d\) a"):
        planner.train()
    assert all(np.isfinite(v).all() for v in planner.q.values())


def test_a_complex_h_table_is_a_data_error() -> None:
    # the imaginary part was dropped with only a numpy ComplexWarning
    with pytest.raises(DataError, match=r"expected h_table a real \(n, n\) table, got complex"):
        TaskPlanner(TaskMDPCfg(num_objects=2), h_table=np.eye(2) * (1 + 1j))


@pytest.mark.parametrize("raw", [[0.5, 0.5j], [{1}, 0.5], "ab"])
def test_next_action_probabilities_that_are_not_real_are_a_data_error(raw: object) -> None:
    planner = TaskPlanner(TaskMDPCfg(num_objects=2), next_action_probs={0: raw})
    with pytest.raises(
        DataError, match="expected real next-action probabilities for taken mask 0"
    ):
        planner.human_next_probs(0)


@pytest.mark.parametrize(
    ("args", "error", "match"),
    [
        ((0, 2, 1.0, None), ConfigError, r"expected action an object index in \[0, 2\), got 2"),
        ((0, -1, 1.0, None), ConfigError, r"expected action an object index in \[0, 2\), got -1"),
        ((-1, 0, 1.0, None), ConfigError, r"expected state a progress bitmask of 2 objects"),
        ((0, 0, 1.0, 16), ConfigError, r"expected next_state a progress bitmask .* got 16"),
        ((0, 0, math.nan, None), DataError, "expected reward a finite number, got nan"),
    ],
)
def test_update_refuses_out_of_range_indices_and_a_nan_reward(
    args: tuple, error: type[Exception], match: str
) -> None:
    # action 2 raised a bare IndexError; action -1, state -1, next_state 16 and a NaN reward
    # wrote into the wrong or a nonexistent Q entry silently
    planner = TaskPlanner(TaskMDPCfg(num_objects=2))
    with pytest.raises(error, match=match):
        planner.update(*args)
    assert planner.q == {}


@pytest.mark.parametrize(
    ("taken", "fetched", "match"),
    [
        ({-1}, set(), r"unknown object -1 in taken: expected indices in \[0, 2\)"),
        ({2}, set(), r"unknown object 2 in taken"),
        (0, 4, "expected fetched a bitmask of 2 objects, got 4"),
        (None, 0, "expected taken a set of object indices or a bitmask"),
    ],
)
def test_encode_state_refuses_objects_out_of_range(taken: object, fetched: object, match: str):
    # {-1} raised a bare ValueError (negative shift), {2} and the mask 4 set another object's
    # bit silently
    with pytest.raises(ConfigError, match=match):
        encode_state(taken, fetched, 2)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"expected state a progress bitmask of 2 objects"):
        decode_state(-1, 2)
    assert decode_state(encode_state({0}, {0, 1}, 2), 2) == (0b01, 0b11)


def test_load_and_save_refuse_a_path_that_is_not_one(tmp_path: Path) -> None:
    # Path(None) raised a bare TypeError
    planner = TaskPlanner(TaskMDPCfg(num_objects=2))
    with pytest.raises(ConfigError, match=r"expected path a file path \(str or os.PathLike\)"):
        TaskPlanner.load(None)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected path a file path"):
        planner.save(3)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda p: p.r_prep(0, -1), r"expected action an object index in \[0, 2\), got -1"),
        (lambda p: p.r_prep(16, 0), r"expected state a progress bitmask of 2 objects"),
        (lambda p: p.available("0"), r"expected state a progress bitmask \(an integer\)"),
        (lambda p: p.q_values(1.5), r"expected state a progress bitmask \(an integer\)"),
        (lambda p: p.human_next_probs(4), "expected taken a bitmask of 2 objects, got 4"),
        (lambda p: p.human_next_probs(None), "expected taken a set of object indices"),
        (lambda p: p.simulate_step(-1, 0, np.random.default_rng(0)), "expected state a"),
    ],
)
def test_the_other_public_methods_refuse_a_state_or_action_out_of_range(
    call: Callable[[TaskPlanner], object], match: str
) -> None:
    # r_prep(s, -1) used the last column of H silently; the others raised a bare TypeError or
    # IndexError, or read another state's bits
    planner = TaskPlanner(TaskMDPCfg(num_objects=2))
    with pytest.raises(ConfigError, match=match):
        call(planner)
    assert planner.human_next_probs({0}).tolist() == [0.0, 1.0]  # a set of indices works too


def test_reach_crossings_against_points_sampled_along_the_reaches() -> None:
    """The closest point of each reach, seen from above, against 20,001 points sampled on it;
    the heights (third coordinate) play no part."""
    rng = np.random.default_rng(3)
    starts = rng.uniform(-0.5, 0.5, (4, 3))
    ends = rng.uniform(-0.5, 0.5, (4, 3))
    ends[3] = starts[3]  # a reach of length 0: a point
    points = rng.uniform(-0.6, 0.6, (300, 3))
    s = np.linspace(0.0, 1.0, 20001)[:, None, None]
    samples = starts[None, :, :2] + s * (ends - starts)[None, :, :2]  # (S, P, 2)
    dist = np.linalg.norm(points[:, None, None, :2] - samples[None], axis=-1).min(axis=(1, 2))
    for radius in (0.02, 0.1, 0.25):
        clear = np.abs(dist - radius) > 1e-4  # leave out points on the edge of the sampling
        got = reach_crossings(starts, ends, points, radius)
        assert clear.sum() > 250
        np.testing.assert_array_equal(got[clear], (dist <= radius)[clear])
    lifted = points.copy()
    lifted[:, 2] += 5.0
    np.testing.assert_array_equal(
        reach_crossings(starts, ends, lifted, 0.1), reach_crossings(starts, ends, points, 0.1)
    )
    assert not reach_crossings(np.zeros((0, 3)), np.zeros((0, 3)), points, 1.0).any()


@pytest.mark.parametrize(
    ("args", "error", "match"),
    [
        ((np.zeros((2, 3)), np.zeros((1, 3)), np.zeros((1, 3)), 0.1), ShapeError, "starts"),
        ((np.zeros((2, 1)), np.zeros((2, 1)), np.zeros((1, 1)), 0.1), ShapeError, "D >= 2"),
        ((np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((1, 2)), 0.1), ShapeError, "points"),
        ((np.zeros((1, 3)), np.full((1, 3), np.nan), np.zeros((1, 3)), 0.1), DataError, "ends"),
        ((np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), -0.1), ConfigError, "radius"),
        ((np.zeros((1, 3)), np.zeros((1, 3)), [["a", "b", "c"]], 0.1), ShapeError, "points"),
    ],
)
def test_reach_crossings_bad_input(args: tuple, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        reach_crossings(*args)


class _AnyOrder:
    @staticmethod
    def allowed_next(done: set[int]) -> set[int]:
        return {0, 1, 2} - set(done)


def test_next_probabilities_drop_negative_entries() -> None:
    """A table entry [0.6, -0.2, 0.6] (a fit's rounding) is no probability of -0.2: the
    negative entry is dropped and the rest renormalised, [0.5, 0, 0.5]."""
    probs = {0: [0.6, -0.2, 0.6]}
    planner = TaskPlanner(TaskMDPCfg(num_objects=3), _AnyOrder(), next_action_probs=probs)
    np.testing.assert_allclose(planner.human_next_probs(0), [0.5, 0.0, 0.5])


def test_an_update_into_a_finished_state_adds_no_future() -> None:
    """The one object fetched: nothing is left to do, so the update is alpha * reward (the
    largest Q of no action would be -inf)."""
    cfg = TaskMDPCfg(num_objects=1, alpha=0.5)
    planner = TaskPlanner(cfg, StrictOrder([0]))
    planner.update(0, 0, 1.0, encode_state(set(), {0}, 1))
    assert planner.q[0][0] == pytest.approx(0.5)


def test_an_untrained_policy_follows_the_preparation_reward() -> None:
    """No Q-values yet: the object the person is predicted to take next (probability 1 on
    object 2, H the identity) is fetched, not the first one."""
    probs = {0: [0.0, 0.0, 1.0]}
    planner = TaskPlanner(
        TaskMDPCfg(num_objects=3), _AnyOrder(), next_action_probs=probs, h_table=np.eye(3)
    )
    assert planner.policy(set(), set()) == 2


def test_a_point_exactly_at_the_radius_is_crossed() -> None:
    """Within ``radius`` includes the radius: (0.5, 0.25) lies 0.25 m off the reach from
    (0, 0) to (1, 0) (all exact in binary), so radius 0.25 crosses it and 0.24 does not."""
    starts, ends, points = [[0.0, 0.0]], [[1.0, 0.0]], [[0.5, 0.25]]
    assert reach_crossings(starts, ends, points, 0.25).tolist() == [True]
    assert reach_crossings(starts, ends, points, 0.24).tolist() == [False]
