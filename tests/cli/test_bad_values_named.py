"""Bad command-line values inside the groups' settings classes: each is a ConfigError that
names the key as typed (``scenario.arrangement``, ``data.generator.fps``), not a Python error
from a comparison or a hash, nor a neighbouring field or the library's class name."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir

from iplanner_torch.cli._common import CONF_DIR, dataset_generator, instantiate
from iplanner_torch.errors import ConfigError


def _compose(overrides: list[str]):
    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        return compose("config", overrides=overrides)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        # null for a field that takes no None: "'<' not supported between ... 'NoneType'"
        (["planner.replanner.min_duration_s=null"],
         r"planner\.replanner\.min_duration_s: expected float, got null"),
        (["planner.replanner.acc_max=null"],
         r"planner\.replanner\.acc_max: expected float, got null"),
        # a list or a mapping for a name of a few choices: "unhashable type: 'list'"
        (["scenario.arrangement=[1,2]"], r"scenario\.arrangement: expected str, got \[1, 2\]"),
        (["sim.human.speed={}"], r"sim\.human\.speed: expected str, got \{\}"),
        # named by their own field, not the one checked with them
        (["planner.optimizer.warm_iterations=-1"],
         r"planner\.optimizer\.warm_iterations: expected warm_iterations >= 0, got -1"),
        (["planner.replanner.tracking_bandwidth=0"],
         r"planner\.replanner\.tracking_bandwidth: expected tracking_bandwidth > 0, got 0"),
        # named by the field, not only by the group
        (["scenario.task_order=abc"],
         r"scenario\.task_order: task order 'abc': expected an object id"),
        (["scenario.task_order=''"], r"scenario\.task_order: expected task_order an expression"),
        (["robot.name=ur5"], r"robot\.name: unknown robot 'ur5'; available: kuka_iiwa14, fetch"),
        # a node the command puts together: the key with its group (was "write_mcap: ...")
        (["experiment=safety_seeds", "experiment.write_mcap=null"],
         r"experiment\.write_mcap: expected bool, got null"),
        (["experiment=safety_seeds", "experiment.name={}"],
         r"experiment\.name: expected str, got \{\}"),
        # items that are no scenario settings: an AttributeError once the run started
        (["experiment=safety_seeds", "experiment.scenarios=[1,2]"],
         r"experiment\.scenarios: expected a list of ScenarioCfg settings"),
        # a list for the robot's name looked for conf/robot/[].yaml
        (["experiment=safety_seeds", "experiment.robot=[]"],
         r"experiment\.robot: expected a robot option name or null, got \[\]"),
    ],
)  # fmt: skip
def test_experiment_values_are_named_by_their_key(overrides: list[str], message: str) -> None:
    from iplanner_torch.cli.experiment import build_experiment

    cfg = _compose(overrides)
    with pytest.raises(ConfigError, match=f"^{message}"):
        build_experiment(cfg, {})


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        # the library's class name (ReachingCfg.fps) named the field; the node named the key
        (["data.generator.fps=nan"],
         r"data\.generator\.fps: expected fps > 0 and finite, got nan$"),
        (["data.generator.speeds=abc"],
         r"data\.generator\.speeds: speeds must be a non-empty list"),
        (["data=tasks", "data.generator.idle_s=1.5"],
         r"data\.generator\.idle_s: expected idle_s a sequence of 2 finite numbers, got 1\.5$"),
        # n_subjects was named reaches_per_target
        (["data.generator.n_subjects=0"],
         r"data\.generator\.n_subjects: expected n_subjects an integer >= 1, got 0$"),
        (["data=tasks", "data.generator.n_subjects=0"],
         r"data\.generator\.n_subjects: expected n_subjects an integer >= 1, got 0$"),
        # null or a mapping for a count: "unsupported operand type(s) for %: 'NoneType' and 'int'"
        (["data.generator.n_targets=null"],
         r"data\.generator\.n_targets: expected int, got null$"),
        (["data.generator.reaches_per_target={}"],
         r"data\.generator\.reaches_per_target: expected int, got \{\}$"),
        (["data=tasks", "data.generator.n_demos=null"],
         r"data\.generator\.n_demos: expected int, got null$"),
        (["data=tasks", "data.generator.arrangement=[]"],
         r"data\.generator\.arrangement: expected str, got \[\]$"),
    ],
)  # fmt: skip
def test_generator_values_are_named_by_their_key(overrides: list[str], message: str) -> None:
    cfg = _compose(overrides)
    with pytest.raises(ConfigError, match=f"^{message}"):
        dataset_generator(cfg.data, name="data.generator")


@pytest.mark.parametrize(
    ("override", "message"),
    [
        # a number or a bool for a list of names: "'float' object is not iterable"
        ("data.windows.joints=1.5", r"data\.windows\.joints: expected a list of names, got 1\.5"),
        ("data.windows.progress_actions=true",
         r"data\.windows\.progress_actions: expected a list of names, got True"),
        ("data.windows.feature_kinds=null",
         r"data\.windows\.feature_kinds: expected a list of names, got None"),
    ],
)  # fmt: skip
def test_window_lists_of_the_wrong_kind_are_named(override: str, message: str) -> None:
    from iplanner_torch.data.windows import WindowCfg

    cfg = _compose([override])
    with pytest.raises(ConfigError, match=f"^{message}$"):
        instantiate(cfg.data.windows, WindowCfg, name="data.windows")


def test_null_is_refused_only_where_a_field_takes_no_none() -> None:
    """A field typed ``X | None`` takes null (its default); a bool field does not."""
    from iplanner_torch.cli.experiment import build_experiment
    from iplanner_torch.prediction.predictor import PredictorCfg

    cfg = _compose(["planner.optimizer.acc_max=null", "robot.torso_height=null"])
    build_experiment(cfg, {})
    cfg = _compose(["predictor.svgp.calibrate_floor=null"])
    with pytest.raises(ConfigError, match=r"^predictor\.svgp\.calibrate_floor: expected bool"):
        instantiate(cfg.predictor, PredictorCfg)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("0", r"run\.jobs: expected an integer >= 1, got 0$"),
        ("-2", r"run\.jobs: expected an integer >= 1, got -2$"),
        ("1.5", r"run\.jobs: expected int, got 1\.5$"),
        ("two", r"run\.jobs: expected int, got 'two'$"),
        ("null", r"run\.jobs: expected int, got None$"),
    ],
)
def test_run_jobs_is_named_by_its_key(value: str, message: str) -> None:
    from iplanner_torch.cli.experiment import run_jobs

    assert run_jobs(_compose([])) == 1
    assert run_jobs(_compose(["run.jobs=2"])) == 2
    with pytest.raises(ConfigError, match=f"^{message}"):
        run_jobs(_compose([f"run.jobs={value}"]))
