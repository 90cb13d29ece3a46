"""Scenarios, task orders and the default task choice; the conf option files instantiate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.errors import ConfigError
from iplanner_torch.planning.replanner import PlannerCfg
from iplanner_torch.sim.tasks import FetchCfg, ScenarioCfg, next_feasible, parse_order

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_orders_of_the_paper_table() -> None:
    order = parse_order("(1,5)->(2,6)", (1, 2, 5, 6))
    assert order.allowed_next(set()) == {1, 5}
    assert next_feasible(order, {1, 5}, (1, 2, 5, 6)) == 2
    rnd = parse_order("random", (0, 1, 2, 3))
    samples = {tuple(rnd.sample(np.random.default_rng(s))) for s in range(20)}
    assert len(samples) > 3 and all(sorted(s) == [0, 1, 2, 3] for s in samples)
    assert next_feasible(order, {1, 2, 5, 6}, (1, 2, 5, 6)) == -1
    with pytest.raises(ConfigError, match="names blocks"):
        parse_order("(0,4)->(1,5)", (0, 1, 2, 3))
    with pytest.raises(ConfigError, match="confidence"):
        ScenarioCfg(confidence=1.0)


def test_next_feasible_after_deliveries_out_of_order() -> None:
    """A robot that delivered a later block first (moved off the person's reach) still gets
    the earliest block of the order it has not delivered, where ``allowed_next`` of its
    deliveries would refuse them as an order the person could not follow."""
    ids = (0, 1, 2, 3, 4, 5, 6, 7)
    order = parse_order("4->0->5->1->6->2->7->3", ids)
    with pytest.raises(ConfigError, match="breaks the order"):
        order.allowed_next({4, 5})
    assert next_feasible(order, {4, 5}, ids) == 0
    assert next_feasible(order, {4, 5, 0, 6}, ids) == 1
    groups = parse_order("(0,4)->(1,5)->(2,6)->(3,7)", ids)
    assert next_feasible(groups, {4, 1}, ids) == 0
    assert next_feasible(groups, {0, 4, 5, 6}, ids) == 1
    # in order, the same block as the smallest id the order allows next
    for done in ({4}, {4, 0}, {4, 0, 5, 1, 6}):
        assert next_feasible(order, done, ids) == min(order.allowed_next(done))
    partial = parse_order("1->0", (0, 1, 2, 3))  # blocks the order leaves out come last
    assert next_feasible(partial, {1, 0}, (0, 1, 2, 3)) == 2


def test_conf_option_files_instantiate() -> None:
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from iplanner_torch.eval.experiment import ExperimentCfg
    from iplanner_torch.sim.env import SimCfg

    for path in sorted((CONF / "scenario").glob("*.yaml")):
        sc = instantiate(OmegaConf.load(path), _convert_="all")
        assert isinstance(sc, ScenarioCfg) and sc.name == path.stem
        if sc.kind == "delivery":
            parse_order(sc.task_order, sc.scene().block_ids)
    # conf/sim reads the root sweep aliases tracker.* and human.speed (conf/config.yaml)
    root = OmegaConf.create(
        {
            "tracker": {"noise": 0.01, "dropout": 0.0},
            "human": {"speed": "medium"},
            "sim": OmegaConf.load(CONF / "sim" / "default.yaml"),
        }
    )
    assert isinstance(instantiate(root.sim), SimCfg)
    # an experiment's episode.planner holds only what it changes: iplanner-experiment merges
    # it over the planner group's node (cli/experiment.build_experiment), as done here
    planner = OmegaConf.load(CONF / "planner" / "iplanner_ni.yaml")
    for name in ("table_simulation", "speed_response"):
        node = OmegaConf.load(CONF / "experiment" / f"{name}.yaml")
        episode = node.experiment.episode
        episode.planner = OmegaConf.merge(planner, episode.get("planner") or {})
        exp = instantiate(node.experiment, _convert_="all")
        assert isinstance(exp, ExperimentCfg) and exp.name == name
        assert isinstance(exp.episode.planner, PlannerCfg)
    assert exp.episode.planner.optimizer.weights.human_lookahead_penalty == 10.0  # speed_response


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        (dict(task_order=None), "task_order"),
        (dict(task_order=3), "task_order"),
        (dict(task_order="0->->1"), r"task order '0->->1': .* at position 3"),
        (dict(task_order="(0,1"), "position"),
        (dict(task_order="(0,4)->(1,5)"), "names blocks"),  # 4 and 5 are not in 1x4
        (dict(task_order="0->²"), "position 3"),
        (dict(confidence=float("nan")), "confidence"),
        (dict(confidence="0.9"), "confidence"),
        (dict(name=""), "name"),
        (dict(crossing_start=(0.1, 0.2)), "crossing_start"),
        (dict(crossing_goal=(0.1, 0.2, float("nan"))), "crossing_goal"),
    ],
)
def test_scenario_cfg_fails_at_config_time(kw: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        ScenarioCfg(**kw)


def test_scenario_cfg_accepts_valid_orders() -> None:
    assert ScenarioCfg(arrangement="2x2", task_order="(1,5)->(2,6)").task_order == "(1,5)->(2,6)"
    assert ScenarioCfg(task_order="random").task_order == "random"
    assert ScenarioCfg(task_order="0 → 1 → (2, 3)").task_order == "0 → 1 → (2, 3)"
    # blocking runs do not use the order: any well-formed one over the block ids passes
    assert ScenarioCfg(kind="blocking", arrangement="2x2", task_order="0").kind == "blocking"
    with pytest.raises(ConfigError, match="position"):
        ScenarioCfg(kind="blocking", task_order="0->")


def test_an_order_that_leaves_blocks_out_is_used_with_a_warning() -> None:
    import warnings

    from iplanner_torch.errors import ConfigWarning

    with pytest.warns(ConfigWarning, match=r"leaves blocks \[3\] of the scene untouched"):
        order = parse_order("0->1->2", (0, 1, 2, 3))
    assert order.sample(np.random.default_rng(0)) == [0, 1, 2]
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConfigWarning)
        parse_order("(0,1)->(2,3)", (0, 1, 2, 3))
        parse_order("random", (0, 1, 2, 3))
        parse_order("0", (0, 1, 2, 3), warn_untouched=False)
        ScenarioCfg(kind="blocking", task_order="0")  # the order of a blocking run is unused


def test_parse_order_names_the_position_of_odd_digits() -> None:
    with pytest.raises(ConfigError, match=r"object id \(digits 0-9\), got '²' at position 3"):
        parse_order("0->²", (0, 1, 2, 3))
    with pytest.raises(ConfigError, match=r"object id \(digits 0-9\), got '①' at position 4"):
        parse_order("(0, ①)", (0, 1, 2, 3))
    with pytest.raises(ConfigError, match="task order"):
        parse_order(None, (0, 1, 2, 3))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        (dict(pick_radius=float("nan")), "pick_radius"),
        (dict(place_radius=float("inf")), "place_radius"),
        (dict(home_tolerance=0.0), "home_tolerance"),
        (dict(grasp_clearance=float("nan")), "grasp_clearance"),
    ],
)
def test_fetch_cfg_rejects_meaningless_values(kw: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        FetchCfg(**kw)


@pytest.mark.parametrize("expr", ["(0,9223372036854775808)", "99999999999999999999"])
def test_a_block_id_beyond_every_integer_type_is_named(expr: str) -> None:
    big = expr.strip("()").split(",")[-1]
    with pytest.raises(ConfigError, match=f"names blocks \\[{big}\\]"):
        parse_order(expr, (0, 1, 2, 3))
    with pytest.raises(ConfigError, match=f"names blocks \\[{big}\\]"):
        ScenarioCfg(task_order=expr)


@pytest.mark.parametrize("block", [99, -1, 4, "0", 1.0, True])
def test_a_fetch_of_a_block_absent_from_the_scene_is_refused(block) -> None:
    from iplanner_torch.sim.scene import SceneCfg
    from iplanner_torch.sim.tasks import FetchTask

    with pytest.raises(
        ConfigError, match=rf"block id of the 1x4 scene \(0, 1, 2, 3\), got {block!r}"
    ):
        FetchTask.create(block, SceneCfg(), FetchCfg(), 0.0)


def test_next_feasible_puts_unnamed_ids_last_and_takes_the_smallest_allowed() -> None:
    """Groups [[0], [1]] with ids (0, 1, 2): 2, which the order does not name, comes after
    both. An order without groups that allows {1, 2}: the smallest, 1."""

    class Grouped:
        groups = ((0,), (1,))

    class Free:
        @staticmethod
        def allowed_next(done: set[int]) -> set[int]:
            return {1, 2}

    assert next_feasible(Grouped(), set(), (0, 1, 2)) == 0
    assert next_feasible(Grouped(), {0, 1}, (0, 1, 2)) == 2
    assert next_feasible(Free(), set(), (0, 1, 2, 3)) == 1


def test_fetch_grasp_points_lie_clearance_above_the_top_face() -> None:
    """Block 5 of the 2x4 scene (row 1, column 1) with 8 cm blocks, a 25 cm column pitch and a
    3 cm clearance: x from the row, y = (1.5 - 1) * 0.25 = 0.125, and the grasp point 0.08
    (top face of a block resting on the table) + 0.03 = 0.11 m high, above the block and
    above its delivery spot alike."""
    from iplanner_torch.sim.scene import SceneCfg
    from iplanner_torch.sim.tasks import FetchPhase, FetchTask

    scene = SceneCfg(arrangement="2x4", block_size=0.08, column_pitch=0.25)
    task = FetchTask.create(5, scene, FetchCfg(grasp_clearance=0.03), 1.5)
    assert task.phase is FetchPhase.APPROACH and task.t_start == 1.5
    np.testing.assert_allclose(task.pick_point, [scene.block_rows_x[1], 0.125, 0.11])
    np.testing.assert_allclose(task.place_point, [scene.delivery_rows_x[1], 0.125, 0.11])


def test_next_feasible_falls_back_to_the_smallest_remaining_block() -> None:
    """An order without groups that allows nothing of what is left (here nothing at all) does
    not end the episode early: the smallest undelivered id, 1, comes next (-1 means done)."""

    class Stuck:
        @staticmethod
        def allowed_next(done: set[int]) -> set[int]:
            return set()

    assert next_feasible(Stuck(), {0}, (0, 1, 2, 3)) == 1
    assert next_feasible(Stuck(), {0, 1, 3}, (3, 2, 1, 0)) == 2
