"""The planner group's ``per_kind`` entries in ``iplanner-experiment``: the defaults, and a
``planner.*`` value of the command line or of an experiment serving every planner."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from hydra import compose
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf, open_dict

from iplanner_torch.cli._common import instantiate
from iplanner_torch.cli.experiment import merged_episode_node
from iplanner_torch.errors import ConfigError
from iplanner_torch.eval.episode import EpisodeCfg, planner_cfg_for

#: every test composes the project's config (conftest.hydra_conf)
pytestmark = pytest.mark.usefixtures("hydra_conf")


def _fresh(overrides: list[str], kind: str) -> float:
    cfg = compose(config_name="config", overrides=overrides)
    episode = instantiate(merged_episode_node(cfg, overrides), EpisodeCfg)
    return planner_cfg_for(episode.planner, kind, 0.95).replanner.fresh_fraction


@pytest.mark.parametrize("option", ["itomp", "iplanner_ni", "iplanner_no_ni"])
def test_every_planner_option_has_the_same_entries(option: str) -> None:
    cfg = compose(config_name="config", overrides=[f"planner={option}"])
    assert OmegaConf.to_container(cfg.planner.per_kind) == {
        "iplanner_no_ni": {"replanner": {"fresh_fraction": 0.125}},
        "iplanner_ni": {"replanner": {"fresh_fraction": 0.125}},
        "iplanner_cv": {"replanner": {"fresh_fraction": 0.125}},
    }


def test_defaults_differ_per_planner() -> None:
    assert _fresh([], "itomp") == 0.5
    assert _fresh([], "oracle") == 0.5
    assert _fresh([], "iplanner_ni") == 0.125
    assert _fresh([], "iplanner_no_ni") == 0.125
    assert _fresh([], "iplanner_cv") == 0.125  # the I-Planners' settings, on another forecast


def test_command_line_value_serves_every_planner() -> None:
    given = ["planner.replanner.fresh_fraction=0.3"]
    for kind in ("itomp", "iplanner_no_ni", "iplanner_ni", "oracle"):
        assert _fresh(given, kind) == 0.3


def test_command_line_entry_changes_one_planner() -> None:
    given = ["planner.per_kind.iplanner_ni.replanner.fresh_fraction=0.75"]
    assert _fresh(given, "iplanner_ni") == 0.75
    assert _fresh(given, "iplanner_no_ni") == 0.125
    assert _fresh(given, "itomp") == 0.5
    added = ["+planner.per_kind.itomp.replanner.fresh_fraction=0.0"]
    assert _fresh(added, "itomp") == 0.0


def test_whole_node_on_the_command_line_replaces_the_entries_node() -> None:
    given = ["planner.replanner={fresh_fraction: 0.2}"]
    cfg = compose(config_name="config", overrides=given)
    node = merged_episode_node(cfg, given)
    assert "replanner" not in node.planner.per_kind.iplanner_ni


def test_experiment_episode_value_serves_every_planner() -> None:
    cfg = compose(config_name="config", overrides=["experiment=safety_seeds"])
    with open_dict(cfg):
        cfg.experiment.episode.planner = {"replanner": {"fresh_fraction": 0.4}}
    episode = instantiate(merged_episode_node(cfg, []), EpisodeCfg)
    for kind in ("itomp", "iplanner_ni"):
        assert planner_cfg_for(episode.planner, kind, 0.95).replanner.fresh_fraction == 0.4


def test_misspelt_entry_key_is_refused_with_its_path() -> None:
    given = ["+planner.per_kind.iplanner_ni.replanner.fresh_fracton=0.1"]
    cfg = compose(config_name="config", overrides=given)
    with pytest.raises(ConfigError, match=r"per_kind.iplanner_ni.replanner.fresh_fracton"):
        instantiate(merged_episode_node(cfg, given), EpisodeCfg)


@pytest.mark.parametrize(
    ("override", "line"),
    [
        ("+planner.per_kind.iplanner_ni.replanner.fresh_fracton=0",
         "error: ConfigError: planner.per_kind.iplanner_ni.replanner.fresh_fracton: unknown "
         "field (did you mean 'fresh_fraction'?)"),
        ("planner.per_kind.itomp.replanner.fresh_fraction=0",
         "error: ConfigError: unknown key 'planner.per_kind.itomp.replanner.fresh_fraction': "
         "planner.per_kind has no entry for 'itomp'; add the setting with "
         "+planner.per_kind.itomp.replanner.fresh_fraction=<value>"),
        ("planner.per_kind.iplanner_ni.replanner.fresh_fraction=3",
         "error: ConfigError: planner.per_kind.iplanner_ni.replanner: expected fresh_fraction "
         "in [0, 1], got 3"),
        ("+planner.per_kind.rrt.replan_step_s=0.3",
         "error: ConfigError: planner.per_kind: unknown planner 'rrt'; expected one of "
         "['itomp', 'iplanner_no_ni', 'iplanner_ni', 'iplanner_cv', 'oracle', 'blind']"),
    ],
)  # fmt: skip
def test_bad_entry_on_the_command_line_is_one_line_before_anything_runs(
    override: str,
    line: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:

    from iplanner_torch.cli import experiment

    monkeypatch.setattr(
        sys, "argv", ["iplanner-experiment", override, f"hydra.run.dir={tmp_path / 'run'}"]
    )
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    GlobalHydra.instance().clear()
    try:
        with pytest.raises(SystemExit) as stop:
            experiment.main()
    finally:
        GlobalHydra.instance().clear()
    lines = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2
    assert lines == [line]
    assert not (tmp_path / "run" / "episodes").exists()


@pytest.mark.parametrize(
    ("overrides", "want"),
    [
        ([], (0.1, True, True, None, None)),
        (["run.task_crossing_radius=null"], (None, True, True, None, None)),
        (
            ["run.mask_by_order=false", "run.rest_when_nothing_available=false"],
            (0.1, False, False, None, None),
        ),
        (
            ["experiment=reach_across", "run.task_crossing_radius=0.2"],
            (0.2, True, True, None, None),
        ),
        (["run.reaction_s=0.3"], (0.1, True, True, 0.3, None)),
        (["experiment=reach_across", "run.reaction_s=0.25"], (0.1, True, True, 0.25, None)),
        (["run.spread_tolerance=2"], (0.1, True, True, None, 2.0)),
        (["experiment=speed_response", "run.spread_tolerance=1.5"], (0.1, True, True, None, 1.5)),
    ],
)
def test_task_choice_settings_reach_the_episode(overrides: list[str], want: tuple) -> None:
    """The ``run.*`` keys of the person's reaches in the task choice (and of the forecast's
    spread calibration) feed every episode of the main job and of an experiment."""
    cfg = compose(config_name="config", overrides=overrides)
    episode = instantiate(merged_episode_node(cfg, overrides), EpisodeCfg)
    got = (
        episode.task_crossing_radius,
        episode.mask_by_order,
        episode.rest_when_nothing_available,
        episode.reaction_s,
        episode.spread_tolerance,
    )
    assert got == want
