"""The Python route to what the command runs: :func:`iplanner_torch.cli.experiment_config`
gives the settings ``iplanner-experiment`` runs (the dataclasses' own defaults are the
paper's and differ), and ``run_experiment(..., predictors=...)`` runs a grid with a predictor
object instead of a checkpoint."""

from __future__ import annotations

import importlib.util
import sys
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import pytest
import yaml
from hydra.core.global_hydra import GlobalHydra

from iplanner_torch.cli import experiment_config
from iplanner_torch.cli._common import CONF_DIR
from iplanner_torch.errors import ConfigError, DataWarning
from iplanner_torch.eval.episode import run_episode
from iplanner_torch.eval.experiment import ExperimentCfg, run_experiment
from iplanner_torch.planning.optimizer import OptimizerCfg
from iplanner_torch.robot.model import RobotModel
from iplanner_torch.sim.tasks import ScenarioCfg

_FAKES = Path(__file__).resolve().parents[1] / "sim" / "sim_fakes.py"
_spec = importlib.util.spec_from_file_location("sim_fakes", _FAKES)
fakes = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("sim_fakes", fakes)
_spec.loader.exec_module(fakes)


def test_experiment_config_is_the_shipped_planner_not_the_dataclass_defaults() -> None:
    shipped = yaml.safe_load((Path(CONF_DIR) / "planner" / "iplanner_ni.yaml").read_text())
    exp = experiment_config()
    opt = exp.episode.planner.optimizer
    for key in ("iterations", "warm_iterations", "safe_hold", "keep_start", "lr"):
        assert getattr(opt, key) == shipped["optimizer"][key], key
    # the point: these differ from the dataclass's own (the paper's) defaults
    assert (opt.iterations, opt.warm_iterations, opt.safe_hold, opt.keep_start) != (
        OptimizerCfg().iterations,
        OptimizerCfg().warm_iterations,
        OptimizerCfg().safe_hold,
        OptimizerCfg().keep_start,
    )
    assert exp.episode.planner.per_kind["iplanner_ni"] == {"replanner": {"fresh_fraction": 0.125}}
    assert exp.planners == ["itomp", "iplanner_no_ni", "iplanner_ni"] and exp.seeds == [0]
    assert exp.robot.name == "kuka_iiwa14" and exp.predictor_paths == {}
    assert not GlobalHydra.instance().is_initialized()  # left as found: it can run again


def test_experiment_config_takes_overrides_as_the_command_does() -> None:
    exp = experiment_config(
        "robot=fetch", "scenario=arrangement_2x2", "planner.optimizer.lr=0.001"
    )
    assert exp.robot.name == "fetch" and exp.scenarios[0].name == "arrangement_2x2"
    assert exp.episode.planner.optimizer.lr == 0.001
    sr = experiment_config("experiment=speed_response")
    assert sr.name == "speed_response" and sr.speeds == ["slow", "medium", "fast"]
    assert sr.episode.planner.optimizer.weights.human_lookahead_penalty == 10.0


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        (["planner.optimizer.lrr=1"], "unknown key 'planner.optimizer.lrr'.*did you mean"),
        (["robot=ur5"], "unknown option robot=ur5"),
        (["planner.optimizer.lr=-1"], "planner.optimizer.lr: expected lr > 0"),
        ([3], "expected overrides as strings"),
    ],
)
def test_experiment_config_refuses_what_the_command_refuses(overrides, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        experiment_config(*overrides)
    assert not GlobalHydra.instance().is_initialized()


def _grid() -> ExperimentCfg:
    exp = experiment_config()
    return replace(
        exp,
        name="objects",
        planners=["iplanner_ni"],
        scenarios=[ScenarioCfg(name="s", task_order="0->1->2->3")],
        episode=replace(exp.episode, max_duration_s=1.5),
    )


def test_a_grid_runs_with_a_predictor_object(tmp_path: Path) -> None:
    predictor = fakes.ConstantPredictor()
    df = run_experiment(_grid(), tmp_path, predictors={"iplanner_ni": predictor})
    assert list(df["planner"]) == ["iplanner_ni"] and len(predictor.calls) > 0
    assert (tmp_path / "results.csv").is_file() and len(list(tmp_path.glob("episodes/*.mcap")))


@pytest.mark.parametrize(
    ("predictors", "pool", "match"),
    [
        ({"itomp": object()}, False, r"predictors: \['itomp'\] are not planners of this grid"),
        ({"iplanner_no_ni": object()}, False, "are not planners of this grid"),
        ({"iplanner_ni": object()}, True, "predictor objects run in this process"),
        ({}, False, r"planner 'iplanner_ni' needs predictor_paths\['ni'\]"),
    ],
)
def test_predictor_objects_that_cannot_serve_are_refused_before_any_episode(
    tmp_path: Path, predictors: dict, pool: bool, match: str
) -> None:
    with ThreadPoolExecutor(1) as executor, pytest.raises(ConfigError, match=match):
        run_experiment(
            _grid(), tmp_path, predictors=predictors, executor=executor if pool else None
        )
    assert not (tmp_path / "results.csv").exists()


class _ShortPredictor(fakes.ConstantPredictor):
    """Two frames of 0.1 s: a forecast that ends long before the plans' 1 s."""

    def predict_positions(self, positions, progress):
        fc = super().predict_positions(positions, progress)
        return replace(fc, mean=fc.mean[:, :, :2], var=fc.var[:, :, :2])


@pytest.mark.parametrize(
    ("predictor", "warned"), [(_ShortPredictor, 1), (fakes.ConstantPredictor, 0)]
)
def test_a_forecast_shorter_than_the_plans_reach_is_said_once(predictor, warned: int) -> None:
    """Past its last frame the person is held there (not conservative): a custom model of
    0.2 s ran without a word before; a 2 s one (and the shipped 1 s ones) is quiet."""
    exp = experiment_config()
    episode = replace(exp.episode, max_duration_s=2.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run_episode(
            episode,
            robot=RobotModel.from_cfg(exp.robot),
            predictor=predictor(),
            planner_kind="iplanner_ni",
            writer_path=None,
            seed=0,
        )
    short = [w for w in caught if "the plans are checked over" in str(w.message)]
    assert len(short) == warned and all(w.category is DataWarning for w in short)
    if warned:
        assert "forecasts 2 frames of 0.1 s (0.2 s), less than the 1 s" in str(short[0].message)
