"""Every config composes, every group option instantiates, and typos fail at compose time."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest
from hydra import compose
from hydra.errors import ConfigCompositionException
from omegaconf import DictConfig, OmegaConf

from iplanner_torch.cli._common import CONF_DIR, instantiate
from iplanner_torch.cli.experiment import merged_episode_node
from iplanner_torch.errors import ConfigError

GROUPS = ("data", "predictor", "trainer", "robot", "scenario", "planner", "sim", "experiment")


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (Path(CONF_DIR) / group).glob("*.yaml"))


#: every test composes the project's config (conftest.hydra_conf)
pytestmark = pytest.mark.usefixtures("hydra_conf")


def _targets(node: object) -> list[DictConfig]:
    """Every sub-node with a _target_ that is not inside another one."""
    if isinstance(node, DictConfig):
        if "_target_" in node:
            return [node]
        return [t for v in node.values() for t in _targets(v)]
    if OmegaConf.is_list(node):
        return [t for v in node for t in _targets(v)]
    return []


def test_every_group_has_options() -> None:
    for group in GROUPS:
        assert _options(group), f"conf/{group} has no option"


@pytest.mark.parametrize(
    ("group", "option"), [(g, o) for g in GROUPS for o in _options(g)], ids=lambda x: str(x)
)
def test_every_option_composes_and_instantiates(group: str, option: str) -> None:
    cfg = compose(config_name="config", overrides=[f"{group}={option}"])
    if group == "experiment" and cfg.experiment.get("episode") is not None:
        # as iplanner-experiment builds it: merged over the groups (speed_response changes
        # one cost weight of the planner)
        cfg.experiment.episode = merged_episode_node(cfg)
    node = cfg[group] if group != "experiment" else cfg.experiment
    targets = _targets(node)
    if group in ("data",):
        assert "windows" in node
    else:
        assert targets, f"{group}={option} has nothing to instantiate"
    for t in targets:
        module, _, name = str(t._target_).rpartition(".")
        cls = getattr(importlib.import_module(module), name)
        assert isinstance(instantiate(t), cls), t._target_


def test_default_config_composes_with_every_section() -> None:
    cfg = compose(config_name="config")
    for key in (*GROUPS[:-1], "seed", "device", "paths", "run", "train", "evaluate", "tracker"):
        assert key in cfg
    assert cfg.get("experiment") is None


def test_misspelt_key_fails_at_compose_time() -> None:
    with pytest.raises(ConfigCompositionException, match="trackr"):
        compose(config_name="config", overrides=["sim.trackr_noise=0.1"])
    with pytest.raises(ConfigCompositionException, match="confidance"):
        compose(config_name="config", overrides=["planner.confidance=0.9"])


def test_unknown_group_option_fails_and_lists_options() -> None:
    with pytest.raises(ConfigCompositionException, match="kuka_iiwa14"):
        compose(config_name="config", overrides=["robot=kuka"])


def test_bad_value_is_a_config_error() -> None:
    cfg = compose(config_name="config", overrides=["scenario.confidence=1.5"])
    with pytest.raises(ConfigError, match="confidence"):
        instantiate(cfg.scenario)


def test_sweep_aliases_reach_the_simulation() -> None:
    cfg = compose(
        config_name="config",
        overrides=["tracker.noise=0.05", "human.speed=fast", "tracker.dropout=0.01"],
    )
    sim = instantiate(cfg.sim)
    assert sim.tracker_noise == 0.05
    assert sim.tracker_dropout == 0.01
    assert sim.human.speed == "fast"


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ([], 0.95),
        (["scenario.confidence=0.99"], 0.99),
        (["planner.confidence=0.9"], 0.9),
        (["planner=itomp", "scenario=confidence", "scenario.confidence=0.9"], 0.9),
    ],
)
def test_main_job_confidence_follows_either_key(overrides: list[str], expected: float) -> None:
    """``scenario.confidence`` and ``planner.confidence`` both set the main job's level."""
    from iplanner_torch.cli.experiment import build_experiment

    cfg = compose(config_name="config", overrides=overrides)
    exp = build_experiment(cfg, {})
    assert exp.scenarios[0].confidence == expected
    assert exp.episode.scenario.confidence == expected


def test_comparison_table_keeps_swept_settings_apart() -> None:
    """Rows of different speeds are separate rows; a setting with one value adds no column."""
    import pandas as pd

    from iplanner_torch.eval.report import comparison_table

    df = pd.DataFrame(
        {
            "scenario": ["s"] * 6,
            "planner": ["a", "a", "a", "b", "b", "b"],
            "speed": ["slow", "fast", "fast", "slow", "fast", "fast"],
            "noise": [0.01] * 6,
            "smoothness": [1.0, 2.0, 4.0, 10.0, 20.0, 40.0],
        }
    )
    table = comparison_table(df)
    assert list(table.columns[:3]) == ["scenario", "speed", "planner"]
    assert "noise" not in table.columns
    got = {(r.speed, r.planner): (r.episodes, r.smoothness) for r in table.itertuples()}
    assert got == {
        ("slow", "a"): (1, 1.0),
        ("fast", "a"): (2, 3.0),
        ("slow", "b"): (1, 10.0),
        ("fast", "b"): (2, 30.0),
    }


def test_human_sphere_layout_reaches_the_optimiser() -> None:
    """``planner.optimizer.human_spheres`` from the command line to the optimiser's config;
    an unknown layout is a ConfigError naming the key."""
    base = instantiate(compose(config_name="config").planner)
    assert base.optimizer_cfg().human_spheres == "inner"
    cfg = compose(config_name="config", overrides=["planner.optimizer.human_spheres=cover"])
    assert instantiate(cfg.planner).optimizer_cfg().human_spheres == "cover"
    bad = compose(config_name="config", overrides=["planner.optimizer.human_spheres=outer"])
    with pytest.raises(ConfigError, match="human_spheres"):
        instantiate(bad.planner)
