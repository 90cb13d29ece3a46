"""Task order expressions and task demonstrations."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from iplanner_torch.data.io import load_demonstrations
from iplanner_torch.data.kinematic_human import sample_body
from iplanner_torch.data.skeleton import BONES, JOINT_INDEX
from iplanner_torch.data.tasks import (
    TaskDatasetCfg,
    arrangement_targets,
    generate_task_dataset,
    generate_task_demonstration,
    parse_task_order,
)
from iplanner_torch.data.windows import next_action_labels, progress_bitmask
from iplanner_torch.errors import ConfigError


def _brute_force(order, ids):
    """Orders of ``ids`` in which every id of a group comes before every id of later groups."""
    rank = {i: g for g, grp in enumerate(order.groups) for i in grp}
    return sorted(
        list(p) for p in itertools.permutations(ids)
        if all(rank[a] <= rank[b] for a, b in zip(p, p[1:]))
    )  # fmt: skip


def test_paper_example_gives_the_four_orders():
    order = parse_task_order("(0,1)->(2,3)")
    assert order.orders() == [[0, 1, 2, 3], [0, 1, 3, 2], [1, 0, 2, 3], [1, 0, 3, 2]]


@pytest.mark.parametrize(
    "expr, n",
    [("0->(1,2)->3", 2), ("0->1->2->3", 1), ("(0,4)->(1,5)->(2,6)->(3,7)", 16),
     ("(1,5)->(2,6)", 4), (" ( 0 , 2 ) → ( 1 , 3 ) ", 4)],
)  # fmt: skip
def test_orders_match_brute_force(expr, n):
    order = parse_task_order(expr)
    got = order.orders()
    assert len(got) == n == order.num_orders()
    assert sorted(got) == _brute_force(order, order.ids)


def test_random_is_every_permutation():
    order = parse_task_order("random", n_objects=4)
    assert len(order.orders()) == 24
    with pytest.raises(ConfigError, match="needs n_objects"):
        parse_task_order("random")


def test_allowed_next_and_sample():
    order = parse_task_order("0->(1,2)->3")
    assert order.allowed_next(set()) == {0}
    assert order.allowed_next({0}) == {1, 2}
    assert order.allowed_next({0, 2}) == {1}
    assert order.allowed_next({0, 1, 2}) == {3}
    assert order.allowed_next({0, 1, 2, 3}) == set()
    with pytest.raises(ConfigError, match="breaks the order"):
        order.allowed_next({3})
    with pytest.raises(ConfigError, match="unknown object ids"):
        order.allowed_next({9})
    rng = np.random.default_rng(0)
    seen = {tuple(order.sample(rng)) for _ in range(50)}
    assert seen == {(0, 1, 2, 3), (0, 2, 1, 3)}


@pytest.mark.parametrize(
    "expr, pos",
    [("(0,1", 4), ("0->", 3), ("0->>1", 3), ("(0,,1)", 3), ("a", 0), ("0 1", 2),
     ("(0,1)-(2,3)", 5), ("", 0), ("0->\u00b2", 3), ("(0,\u2460)", 3)],
)  # fmt: skip
def test_syntax_errors_name_the_position(expr, pos):
    with pytest.raises(ConfigError, match=f"at position {pos}$"):
        parse_task_order(expr)


def test_semantic_errors():
    with pytest.raises(ConfigError, match="repeated object id"):
        parse_task_order("(0,1)->1")
    with pytest.raises(ConfigError, match="out of range"):
        parse_task_order("0->5", n_objects=4)
    with pytest.raises(ConfigError, match="arrangement 1x4 has"):
        TaskDatasetCfg(order="(1,5)->(2,6)", arrangement="1x4")


def test_task_demonstration_labels_and_kinematics():
    ids, targets = arrangement_targets("2x2")
    body = sample_body(np.random.default_rng(2))
    d = generate_task_demonstration([5, 1, 6, 2], targets, body, np.random.default_rng(3),
                                    object_ids=ids)  # fmt: skip
    assert d.action_names == ("idle", "take_1", "take_2", "take_5", "take_6")
    segs = [int(a) for i, a in enumerate(d.labels) if i == 0 or a != d.labels[i - 1]]
    assert [a for a in segs if a] == [3, 1, 4, 2]
    assert segs[0] == 0 and segs[-1] == 0
    c = d.clean_positions.astype(float)
    for a, b in BONES:
        length = np.linalg.norm(c[:, JOINT_INDEX[a]] - c[:, JOINT_INDEX[b]], axis=1)
        assert (length.max() - length.min()) / length.mean() < 1e-5
    for a, oid in zip([3, 1, 4, 2], [5, 1, 6, 2]):
        p = targets[ids.index(oid)]
        hand = c[:, JOINT_INDEX["left_hand" if p[1] > 0 else "right_hand"]]
        assert np.linalg.norm(hand[d.labels == a] - p, axis=1).min() < 0.03
    # progress and next action follow the order
    prog = progress_bitmask(d.labels, [1, 2, 3, 4]).numpy()
    assert prog[-1] == sum(1 << a for a in (1, 2, 3, 4))
    nxt = next_action_labels(d.labels)
    assert nxt[d.labels == 3][0] == 0 and nxt[np.flatnonzero(d.labels == 3)[-1] + 1] == 1


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"fps": float("inf")}, "expected fps > 0 and finite, got inf"),
        ({"fps": 0.0}, r"expected fps > 0 and finite, got 0.0"),
        ({"noise_sigma": float("nan")}, "expected noise_sigma >= 0 and finite, got nan"),
        ({"dropout_rate": 1.0}, r"expected dropout_rate in \[0, 1\), got 1.0"),
        ({"idle_s": (1.0, 0.5)}, r"idle_s must be \(low, high\) with 0 <= low <= high"),
        (
            {"hold_s": (0.1, float("inf"))},
            r"expected hold_s a sequence of 2 finite numbers, got \(0.1, inf\)",
        ),
    ],
)
def test_task_demonstration_refuses_bad_numbers(kwargs, message):
    """The generator function checks its numbers as TaskDatasetCfg does (fps=inf overflowed)."""
    ids, targets = arrangement_targets("1x4")
    body = sample_body(np.random.default_rng(2))
    with pytest.raises(ConfigError, match=message):
        generate_task_demonstration(
            ids, targets, body, np.random.default_rng(3), object_ids=ids, **kwargs
        )


def test_task_dataset_round_trip(tmp_path):
    cfg = TaskDatasetCfg(order="0->(1,2)->3", n_demos=3, noise_sigma=0.0, dropout_rate=0.0)
    s = generate_task_dataset(cfg, tmp_path, progress=False)
    demos = load_demonstrations(tmp_path)
    assert s.n_demonstrations == 3 == len(demos)
    for d in demos:
        assert d.metadata["order"][0] == 0 and d.metadata["order"][-1] == 3
        np.testing.assert_array_equal(d.positions, d.clean_positions)
    assert "0->(1,2)->3" in (tmp_path / "README.md").read_text()


@pytest.mark.parametrize("bad", [float("inf"), float("-inf"), float("nan")])
@pytest.mark.parametrize("field", ["fps", "noise_sigma", "dropout_rate", "idle_s"])
def test_non_finite_config_values_raise(field, bad):
    value = (0.5, bad) if field == "idle_s" else bad  # fps=inf was an OverflowError
    with pytest.raises(ConfigError, match=rf"^expected TaskDatasetCfg\.{field} (a |>|in )"):
        TaskDatasetCfg(**{field: value})


def test_bad_config_messages_name_the_field():
    with pytest.raises(
        ConfigError, match=r"^expected TaskDatasetCfg\.fps > 0 and finite, got -15"
    ):
        TaskDatasetCfg(fps=-15)
    with pytest.raises(ConfigError, match=r"^expected TaskDatasetCfg\.dropout_rate in \[0, 1\)"):
        TaskDatasetCfg(dropout_rate=1.0)
    with pytest.raises(ConfigError, match=r"^TaskDatasetCfg\.idle_s must be \(low, high\)"):
        TaskDatasetCfg(idle_s=(2.0, 1.0))


def test_order_id_off_the_arrangement_names_its_position_and_the_objects():
    # was: "object id 9 out of range for 8 objects at position 0"
    with pytest.raises(
        ConfigError,
        match=r"^task order '\(0,1\)->\(2,9\)': object id 9 at position 10 is not on the table: "
        r"arrangement 1x4 has objects \[0, 1, 2, 3\] \(ids number the 2 x 4 grid",
    ):
        TaskDatasetCfg(order="(0,1)->(2,9)", arrangement="1x4")
    with pytest.raises(ConfigError, match=r"object id 5 at position 3 .* arrangement 1x4 has"):
        TaskDatasetCfg(order="(1,5)->(2,6)", arrangement="1x4")
    with pytest.raises(ConfigError, match=r"leaves object\(s\) \[3\] out: arrangement 1x4 has"):
        TaskDatasetCfg(order="(0,1)->2", arrangement="1x4")
    assert TaskDatasetCfg(order="random", arrangement="2x2").task_order().ids == (1, 2, 5, 6)


def test_semantic_errors_name_the_position_of_the_id():
    with pytest.raises(
        ConfigError, match=r"object id 5 out of range for 4 objects \(ids 0\.\.3\) at position 5$"
    ):
        parse_task_order("0 -> 5->1", n_objects=4)
    with pytest.raises(ConfigError, match=r"repeated object id 1 in \[0, 1, 1\] at position 7$"):
        parse_task_order("(0,1)->1")
