"""``PlannerCfg.per_kind``: settings of one planner of a run, over the shared ones."""

from __future__ import annotations

import pytest

from iplanner_torch.errors import ConfigError
from iplanner_torch.eval.episode import PLANNER_KINDS, planner_cfg_for
from iplanner_torch.planning.replanner import PLANNER_NAMES, PlannerCfg


def _cfg(**per_kind: dict) -> PlannerCfg:
    return PlannerCfg(per_kind=per_kind)


def test_planner_names_are_the_episode_kinds() -> None:
    assert set(PLANNER_NAMES) == set(PLANNER_KINDS)


def test_entry_applies_to_its_planner_only() -> None:
    base = _cfg(iplanner_ni={"replanner": {"fresh_fraction": 0.0}, "replan_step_s": 0.4})
    ni = base.for_planner("iplanner_ni")
    assert ni.replanner.fresh_fraction == 0.0
    assert ni.replan_step_s == 0.4
    assert ni.replanner_cfg().replan_step_s == 0.4
    assert ni.per_kind == {}
    # the other fields of the nested settings are the base's
    assert ni.replanner.acc_max == base.replanner.acc_max
    assert ni.optimizer == base.optimizer
    for other in ("itomp", "iplanner_no_ni", "oracle"):
        cfg = base.for_planner(other)
        assert cfg.replanner.fresh_fraction == 0.5
        assert cfg.replan_step_s == 0.5
    assert base.replanner.fresh_fraction == 0.5  # the base itself is unchanged


def test_nested_dataclass_two_levels_down() -> None:
    base = _cfg(itomp={"optimizer": {"weights": {"human_lookahead_penalty": 2.5}}})
    got = base.for_planner("itomp").optimizer
    assert got.weights.human_lookahead_penalty == 2.5
    assert got.weights.joint_acc_l2 == base.optimizer.weights.joint_acc_l2
    assert got.num_trajectories == base.optimizer.num_trajectories


def test_episode_settings_take_the_entry_then_the_kind() -> None:
    base = _cfg(iplanner_no_ni={"replanner": {"fresh_fraction": 0.25}})
    cfg = planner_cfg_for(base, "iplanner_no_ni", 0.9)
    assert (cfg.kind, cfg.predictor_variant, cfg.confidence) == ("iplanner", "no_ni", 0.9)
    assert cfg.replanner.fresh_fraction == 0.25
    assert planner_cfg_for(base, "iplanner_ni", 0.9).replanner.fresh_fraction == 0.5


@pytest.mark.parametrize(
    ("entry", "match"),
    [
        ({"itmop": {}}, r"unknown planner 'itmop'"),
        ({"itomp": {"replanner": {"fresh_fracton": 0.0}}}, r"did you mean 'fresh_fraction'"),
        ({"itomp": {"replanner": {"fresh_fraction": "a lot"}}}, r"fresh_fraction: expected"),
        ({"itomp": {"replanner": {"fresh_fraction": True}}}, r"fresh_fraction: expected float"),
        ({"itomp": {"replanner": {"fresh_fraction": 2.0}}}, r"fresh_fraction in \[0, 1\]"),
        ({"itomp": {"replanner": 0.3}}, r"per_kind.itomp.replanner: expected a mapping"),
        ({"itomp": {"replan_step_s": {"a": 1}}}, r"replan_step_s: expected one value"),
        ({"itomp": {"replanner": {"tracking": "loose"}}}, r"tracking: expected one of"),
        ({"itomp": {"confidence": 0.99}}, r"per_kind.itomp.confidence: set for every"),
        ({"itomp": {"kind": "iplanner"}}, r"per_kind.itomp.kind: set for every"),
        ({"itomp": {"optimizer": {"seed": 3}}}, r"per_kind.itomp.optimizer.seed: set for"),
        ({"itomp": [1, 2]}, r"per_kind.itomp: expected a mapping"),
    ],
)
def test_bad_entries_are_refused_when_the_settings_are_made(entry: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        PlannerCfg(per_kind=entry)


def test_bad_value_names_the_entry() -> None:
    with pytest.raises(ConfigError) as info:
        _cfg(iplanner_ni={"replanner": {"fresh_fraction": -1.0}})
    assert "per_kind.iplanner_ni.replanner" in str(info.value)


def test_per_kind_must_be_a_mapping() -> None:
    with pytest.raises(ConfigError, match="per_kind a mapping"):
        PlannerCfg(per_kind=[("itomp", {})])  # type: ignore[arg-type]


def test_empty_entry_is_the_base() -> None:
    base = _cfg(itomp={})
    assert base.for_planner("itomp") is base
    with pytest.raises(ConfigError, match="unknown planner"):
        base.for_planner("rrt")


def test_settings_with_entries_stay_hashable() -> None:
    """A frozen settings class hashes its fields; a dict field would make hash() fail."""
    base = _cfg(iplanner_ni={"replanner": {"fresh_fraction": 0.0}})
    assert hash(base) == hash(_cfg(iplanner_ni={"replanner": {"fresh_fraction": 0.0}}))
    assert base == _cfg(iplanner_ni={"replanner": {"fresh_fraction": 0.0}})
    assert base != _cfg(iplanner_ni={"replanner": {"fresh_fraction": 0.5}})
