"""Command-line input: values of the wrong type are refused up front with their key; --help."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from iplanner_torch.cli._common import cfg_list, cfg_scalar, instantiate
from iplanner_torch.errors import ConfigError, DataWarning
from iplanner_torch.prediction.training import TrainerCfg
from iplanner_torch.sim.human import HumanCfg


def _root(**trainer: object):
    node = {"_target_": "iplanner_torch.prediction.training.TrainerCfg", **trainer}
    return OmegaConf.create({"seed": 0, "trainer": node})


def test_instantiate_accepts_fitting_types() -> None:
    cfg = instantiate(_root(max_steps=5, seed=3, tensorboard=False).trainer)
    assert isinstance(cfg, TrainerCfg) and cfg.max_steps == 5 and cfg.tensorboard is False
    assert instantiate(_root(max_steps=None).trainer).max_steps is None  # int | None
    # an int where a float is expected is fine; lists and literals are left to the dataclass
    human = instantiate(
        OmegaConf.create({"_target_": "iplanner_torch.sim.human.HumanCfg", "hold_s": 1})
    )
    assert isinstance(human, HumanCfg) and human.hold_s == 1


def test_a_node_without_target_is_refused_with_the_way_to_write_it(tmp_path: Path) -> None:
    """A new group file that lists only the fields it changes builds a dict: refused by name,
    with the two ways to write it; the way with a defaults list composes to a PredictorCfg."""
    from iplanner_torch.prediction.predictor import PredictorCfg

    root = OmegaConf.create({"predictor": {"ivm_max_import": 30, "svgp": {"num_inducing": 50}}})
    with pytest.raises(ConfigError) as err:
        instantiate(root.predictor, PredictorCfg)
    msg = str(err.value)
    assert msg.startswith("config node 'predictor' built a dict, not a PredictorCfg")
    assert "_target_: iplanner_torch.prediction.predictor.PredictorCfg" in msg
    assert "defaults: [<that file>, _self_]" in msg
    with pytest.raises(ConfigError, match="config node 'experiment' built a dict"):
        instantiate(OmegaConf.create({"name": "x"}), PredictorCfg, name="experiment")
    # the documented way: a defaults list on an existing file of the group
    conf = tmp_path / "predictor"
    conf.mkdir()
    (conf / "small.yaml").write_text(
        "defaults: [iplanner_ni, _self_]\nivm_max_import: 30\nsvgp: {num_inducing: 50}\n"
    )
    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(
            "config",
            overrides=["predictor=small", f"hydra.searchpath=[file://{tmp_path}]"],
        )
    built = instantiate(cfg.predictor, PredictorCfg)
    assert built.ivm_max_import == 30 and built.svgp.num_inducing == 50
    assert built.svgp.noisy_input == "simple"  # the rest from iplanner_ni.yaml


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("max_steps", "abc", "trainer.max_steps: expected int, got 'abc'"),
        ("max_steps", 1.5, "trainer.max_steps: expected int, got 1.5"),
        ("tensorboard", 1, "trainer.tensorboard: expected bool, got 1"),
        ("seed", True, "trainer.seed: expected int, got True"),
    ],
)
def test_instantiate_names_the_wrong_key(key: str, value: object, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        instantiate(_root(**{key: value}).trainer)
    assert str(err.value) == message


def test_nested_nodes_are_checked() -> None:
    node = OmegaConf.create(
        {
            "episode": {
                "_target_": "iplanner_torch.eval.episode.EpisodeCfg",
                "sim": {
                    "_target_": "iplanner_torch.sim.env.SimCfg",
                    "human": {"_target_": "iplanner_torch.sim.human.HumanCfg", "hold_s": "x"},
                },
            }
        }
    )
    with pytest.raises(ConfigError, match=r"episode\.sim\.human\.hold_s: expected float"):
        instantiate(node.episode)


def test_cfg_scalar_and_list() -> None:
    cfg = OmegaConf.create({"seed": 3, "run": {"seeds": [0, 1], "bad": "zero", "x": 0.5}})
    assert cfg_scalar(cfg, "seed", int) == 3
    assert cfg_scalar(cfg.run, "x", float) == 0.5
    assert cfg_list(cfg.run, "seeds", int) == [0, 1]
    with pytest.raises(ConfigError, match=r"run\.bad: expected a list of int, got 'zero'"):
        cfg_list(cfg.run, "bad", int)
    with pytest.raises(ConfigError, match=r"run\.x: expected int, got 0\.5"):
        cfg_scalar(cfg.run, "x", int)


def test_console_script_reports_a_wrong_type_in_one_line(tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.experiment", "seed=abc"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip() == "error: ConfigError: seed: expected int, got 'abc'"


@pytest.mark.parametrize(
    ("root", "message"),
    [
        ({"tracker": {"noise": -1}}, "tracker.noise: expected in [0, 1] m, got -1.0"),
        ({"tracker": {"noise": float("nan")}}, "tracker.noise: expected in [0, 1] m, got nan"),
        ({"tracker": {"noise": float("inf")}}, "tracker.noise: expected in [0, 1] m, got inf"),
        ({"tracker": {"noise": 100}}, "tracker.noise: expected in [0, 1] m, got 100.0"),
        (
            {"human": {"speed": "turbo"}},
            "human.speed: expected one of ['fast', 'medium', 'slow'], got 'turbo'",
        ),
        ({"tracker": {"dropout": 1.0}}, "tracker.dropout: expected in [0, 1), got 1.0"),
        ({"tracker": {"dropout": "x"}}, "tracker.dropout: expected float, got 'x'"),
        ({"run": {"scene_hz": -1}}, "run.scene_hz: expected >= 0 [Hz], got -1.0"),
        ({"progress": "yes"}, "progress: expected bool, got 'yes'"),
        ({"device": "tpu"}, "device: unknown device 'tpu'"),
        ({"seed": -1}, "seed: expected an integer in [0, 2^32 - 1], got -1"),
        ({"seed": 2**32}, f"seed: expected an integer in [0, 2^32 - 1], got {2**32}"),
        ({"paths": {"datasets": None}}, "paths.datasets: expected a path, got null"),
        ({"data": {"path": ""}}, "data.path: expected a path, got ''"),
        ({"evaluate": {"checkpoint": None}}, "evaluate.checkpoint: expected a path, got null"),
        # a number or a list where a path is expected ended in a TypeError traceback
        (
            {"data": {"path": 123}},
            "data.path: expected a path (a string), got 123 (quote a path that reads as a "
            "number: data.path=\"'123'\")",
        ),
        ({"data": {"path": ["a"]}}, "data.path: expected a path (a string), got ['a']"),
        ({"train": {"out_dir": 123}}, "train.out_dir: expected a path (a string), got 123"),
        ({"evaluate": {"checkpoint": 12.5}}, "evaluate.checkpoint: expected a path (a string)"),
        ({"evaluate": {"out_dir": 123}}, "evaluate.out_dir: expected a path (a string), got 123"),
        (
            {"evaluate": {"logs": 123}},
            "evaluate.logs: expected a path (a string) or a list of paths, got 123",
        ),
        (
            {"evaluate": {"logs": ["a.csv", 1]}},
            "evaluate.logs: expected a list of paths (strings), got ['a.csv', 1]",
        ),
        # run.* settings a run of itomp alone never read: refused up front by their full key
        (
            {"run": {"train_if_missing": "maybe"}},
            "run.train_if_missing: expected bool, got 'maybe'",
        ),
        ({"run": {"train_if_missing": 0}}, "run.train_if_missing: expected bool, got 0"),
        (
            {"run": {"train_trainer": "nope"}},
            "run.train_trainer: expected a trainer option (default, fast), got 'nope'",
        ),
        (
            {"run": {"stall_fallback_s": "abc"}},
            "run.stall_fallback_s: expected a number > 0 [s] or null (never), got 'abc'",
        ),
        (
            {"run": {"stall_fallback_s": 0}},
            "run.stall_fallback_s: expected a number > 0 [s] or null (never), got 0",
        ),
        (
            {"run": {"task_crossing_radius": -0.1}},
            "run.task_crossing_radius: expected a distance >= 0 [m] or null (off), got -0.1",
        ),
        (
            {"run": {"task_crossing_radius": "near"}},
            "run.task_crossing_radius: expected a distance >= 0 [m] or null (off), got 'near'",
        ),
        ({"run": {"mask_by_order": "yes"}}, "run.mask_by_order: expected bool, got 'yes'"),
        (
            {"run": {"rest_when_nothing_available": 1}},
            "run.rest_when_nothing_available: expected bool, got 1",
        ),
        (
            {"run": {"reaction_s": -0.3}},
            "run.reaction_s: expected a time >= 0 [s] or null (off), got -0.3",
        ),
        (
            {"run": {"reaction_s": "soon"}},
            "run.reaction_s: expected a time >= 0 [s] or null (off), got 'soon'",
        ),
        (
            {"run": {"spread_tolerance": 0}},
            "run.spread_tolerance: expected a number > 0 (a mean normalised squared error) or "
            "null (off), got 0",
        ),
        (
            {"run": {"spread_tolerance": "wide"}},
            "run.spread_tolerance: expected a number > 0 (a mean normalised squared error) or "
            "null (off), got 'wide'",
        ),
    ],
)
def test_root_keys_and_sweep_aliases_are_checked_by_the_typed_key(
    root: dict, message: str
) -> None:
    from iplanner_torch.cli._common import check_root_keys

    check_root_keys(OmegaConf.create({"seed": 0, "tracker": {"noise": 0.0, "dropout": 0.5}}))
    check_root_keys(OmegaConf.create({"tracker": {"noise": 1.0}, "human": {"speed": "slow"}}))
    # a path key that interpolates a resolver it cannot resolve here is left to its command
    check_root_keys(OmegaConf.create({"train": {"out_dir": "${hydra:runtime.choices.x}"}}))
    # the optional paths may be null, and evaluate.logs a list; the run.* defaults pass
    check_root_keys(OmegaConf.create({"evaluate": {"out_dir": None, "logs": ["a", "b"]}}))
    run = {"train_if_missing": False, "train_trainer": "fast", "stall_fallback_s": None}
    check_root_keys(OmegaConf.create({"run": run}))
    run = {
        "task_crossing_radius": None,
        "mask_by_order": False,
        "rest_when_nothing_available": True,
        "reaction_s": None,
    }
    check_root_keys(OmegaConf.create({"run": {**run, "task_crossing_radius": 0.1}}))
    check_root_keys(OmegaConf.create({"run": {**run, "reaction_s": 0.3}}))
    check_root_keys(OmegaConf.create({"run": {**run, "spread_tolerance": 2}}))
    check_root_keys(OmegaConf.create({"run": run}))
    with pytest.raises(ConfigError) as err:
        check_root_keys(OmegaConf.create(root))
    text = str(err.value)
    assert text == message or (
        text.startswith(message)  # then torch's own reason, or how to quote a number
        and ("device" in root or "(quote a path that reads as a number: " in text)
    ), text


def test_unknown_training_data_source_is_refused(tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.experiment", "run.train_data=bogus",
         "progress=false", f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert "run.train_data must be one of ('tasks', 'data'), got 'bogus'" in res.stderr
    assert not (tmp_path / "datasets").exists()  # refused before generating anything


@pytest.mark.parametrize("module", ["experiment", "data"])
def test_sweep_with_cfg_print_is_one_line(module: str, tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, "-m", f"iplanner_torch.cli.{module}", "-m", "--cfg", "job"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2
    assert res.stderr.strip() == (
        "error: --cfg prints the config of a single run; drop -m (--multirun) to see it"
    )


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ("data=reaching,nonexistent", "unknown option data=nonexistent; data options: lego"),
        ("data=reaching,tasks", "unknown key 'data.generator.n_targets'"),  # tasks lacks it
    ],
)
def test_a_batched_sweep_checks_every_job_before_the_first_runs(
    bad: str, message: str, tmp_path: Path
) -> None:
    """With ``hydra.sweeper.max_batch_size`` Hydra composes each batch only when it comes to
    it: a later job's bad config stopped the sweep midway with Hydra's own report (exit 1),
    after the first job had written its files."""
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.data", "generate", "-m",
         "hydra.sweeper.max_batch_size=1", bad, "data.generator.n_targets=2",
         "data.generator.reaches_per_target=1", f"data.path={tmp_path / 'd'}",
         f"hydra.sweep.dir={tmp_path / 'sweep'}", "progress=false"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().startswith("error: ConfigError: "), res.stderr
    assert message in res.stderr
    assert not (tmp_path / "d").exists()  # no job ran


def test_help_lists_groups_options_and_defaults() -> None:
    from iplanner_torch.cli._common import command_help

    text = command_help("``x``: a command, see :func:`~a.b.run`.\n\nExamples::\n\n    x a=1\n")
    lines = text.splitlines()
    assert lines[:3] == ["x: a command, see run.", "", "Examples:"]  # no markup in a terminal
    groups = {
        ln.split()[0]: ln.split(None, 1)[1]
        for ln in lines
        if ln.startswith("  ") and not ln.startswith("    ")
    }
    conf = Path(__file__).resolve().parents[2] / "conf"
    assert set(groups) == {d.name for d in conf.iterdir() if d.is_dir() and d.name != "hydra"} | {
        "hydra/launcher"
    }
    assert groups["trainer"] == "default*, fast"
    assert (
        groups["experiment"].startswith("null*, ") and "table_simulation" in groups["experiment"]
    )
    assert groups["hydra/launcher"] == (
        "basic*, joblib, slurm, submitit_local (slurm, submitit_local: pip install -e '.[slurm]')"
    )  # submitit_local, the README's way to run a sweep as a cluster does, was not listed
    assert "Root keys: seed=<int>, device=auto|cpu|cuda, progress=true|false." in lines


@pytest.mark.parametrize(
    ("module", "groups", "root_keys"),
    [
        ("train", ["data", "predictor", "trainer"], ["seed", "progress"]),
        ("data", ["data"], ["progress"]),
        ("experiment", ["data", "experiment", "planner", "robot", "scenario", "sim"],
         ["seed", "device", "progress"]),
    ],
)  # fmt: skip
def test_help_of_a_command_lists_the_groups_and_root_keys_it_reads(
    module: str, groups: list[str], root_keys: list[str]
) -> None:
    """--help lists only what the command reads: iplanner-train no device, iplanner-data no
    seed or device, iplanner-experiment not the predictor and trainer groups, which they
    refuse."""
    result = subprocess.run(
        [sys.executable, "-m", f"iplanner_torch.cli.{module}", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    after = lines[lines.index("Config groups (group=option; * the default):") + 1 :]
    listed = [ln.split()[0] for ln in after if ln.startswith("  ")]
    assert listed == [*groups, "hydra/launcher"]
    root = next(ln for ln in lines if ln.startswith("Root keys:")).split("(")[0]
    named = [k for k in ("seed", "device", "progress") if k in root]
    assert named == root_keys


def test_console_help_exits_zero(tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.evaluate", "evaluate.mode=episode", "-h"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("iplanner-evaluate:") and "Config groups" in res.stdout


def test_copy_output_to_keeps_printed_lines_and_last_bar_state(tmp_path: Path) -> None:
    """What a command prints reaches the job log too; a redrawn bar leaves its last state."""
    import sys

    from iplanner_torch.cli._common import copy_output_to

    log = tmp_path / "job.log"
    log.write_text("[hydra] first record\n")
    with copy_output_to(log):
        print("table row 1")
        sys.stderr.write("bar  10%\rbar  50%\rbar 100%\n")
        print("done")
        sys.stderr.write("open bar 3%\ropen bar 7%")
    assert log.read_text().splitlines() == [
        "[hydra] first record",
        "table row 1",
        "bar 100%",
        "done",
        "open bar 7%",
    ]
    before = log.read_text()
    with copy_output_to(None):
        print("not copied")
    assert log.read_text() == before


def test_library_errors_and_running_out_of_memory_are_one_line(capsys) -> None:
    """Outside a sweep a library error exits 2 with its line; running out of memory (torch's
    allocator raises RuntimeError) exits 2 with what to lower; other errors pass through."""
    from iplanner_torch.cli._common import friendly_errors

    def raising(exc: BaseException):
        @friendly_errors
        def job() -> None:
            raise exc

        return job

    with pytest.raises(SystemExit) as stop:
        raising(ConfigError("bad knob"))()
    assert stop.value.code == 2
    assert capsys.readouterr().err.strip() == "error: ConfigError: bad knob"
    alloc = RuntimeError("[enforce fail at alloc_cpu.cpp:117] DefaultCPUAllocator: can't "
                         "allocate memory: you tried to allocate 79999999988 bytes.")  # fmt: skip
    for exc in (alloc, MemoryError()):
        with pytest.raises(SystemExit) as stop:
            raising(exc)()
        assert stop.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith("error: out of memory (") and "num_trajectories" in err
    with pytest.raises(RuntimeError, match="something else"):
        raising(RuntimeError("something else"))()


def test_a_log_file_that_cannot_be_opened_is_one_line(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Hydra opens the run's log file before the command starts; Python's logging reports a
    run folder that is not writable as ``ValueError: Unable to configure handler 'file'``
    (a 56-line traceback, exit 1): the PermissionError behind it is the one line, exit 2."""
    from iplanner_torch.cli._common import run_app

    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)

    def app() -> None:
        try:
            raise PermissionError(13, "Permission denied", "/r/data.log")
        except PermissionError as exc:
            raise ValueError("Unable to configure handler 'file'") from exc

    with pytest.raises(SystemExit) as stop:
        run_app(app)
    assert stop.value.code == 2
    line = "error: PermissionError: [Errno 13] Permission denied: '/r/data.log'"
    assert capsys.readouterr().err.strip() == line

    def other() -> None:
        raise ValueError("a ValueError of its own")

    with pytest.raises(ValueError, match="of its own"):  # not an operating system error
        run_app(other)


def test_a_run_folder_without_write_permission_is_one_line(tmp_path: Path) -> None:
    """End to end, where the operating system refuses the write (as root, without the
    capability that overrides file permissions: setpriv)."""
    import shutil

    run = tmp_path / "r"
    run.mkdir()
    prefix: list[str] = []
    if os.geteuid() == 0:
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            pytest.skip("root without setpriv: file permissions are not enforced")
        prefix = [setpriv, "--bounding-set=-dac_override,-dac_read_search,-fowner", "--"]
    run.chmod(0o555)
    try:
        probe = subprocess.run(
            [*prefix, sys.executable, "-c", f"open({str(run / 'x')!r}, 'w')"],
            capture_output=True, timeout=60,
        )  # fmt: skip
        if probe.returncode == 0:
            pytest.skip("file permissions are not enforced here")
        env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
        env.pop("HYDRA_FULL_ERROR", None)
        res = subprocess.run(
            [*prefix, sys.executable, "-m", "iplanner_torch.cli.data", "info",
             f"data.path={tmp_path / 'nowhere'}", f"hydra.run.dir={run}", "progress=false"],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
    finally:
        run.chmod(0o755)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: PermissionError: "), res.stderr
    assert str(run) in lines[0]


def test_a_sweep_job_removes_the_failed_marker_of_its_earlier_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A sweep run again into the same folder: a job that failed before and runs fine now no
    longer leaves the earlier FAILED file, which the sweep reported as this run's error; a
    job that fails again writes its new line."""
    import iplanner_torch.cli._common as common

    job = tmp_path / "1"
    job.mkdir()
    (job / common.FAILED_MARKER).write_text("error: ConfigError: an earlier run's\n")
    monkeypatch.setattr(common, "multirun_job_dir", lambda: job)

    @common.friendly_errors
    def fine() -> str:
        return "ran"

    assert fine() == "ran"
    assert not (job / common.FAILED_MARKER).exists()

    @common.friendly_errors
    def failing() -> None:
        raise ConfigError("this run's")

    assert failing() is None
    assert (job / common.FAILED_MARKER).read_text() == "error: ConfigError: this run's\n"


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("sim.tracker_fps=0", r"sim\.tracker_fps: expected tracker_fps > 0"),
        ("sim.human.hold_s=-1", r"sim\.human\.hold_s: expected hold_s >= 0"),
        (
            "planner.optimizer.horizon_s=inf",
            r"planner\.optimizer\.horizon_s: expected horizon_s in \(0, 60\] s",
        ),
        ("planner.confidence=2", r"planner\.confidence: expected confidence in \(0, 1\)"),
        (
            "planner.optimizer.iterations=-3",
            r"planner\.optimizer\.iterations: expected iterations >= 0, got -3",
        ),
        ("scenario.arrangement=3x3", r"scenario\.arrangement: expected arrangement in"),
        ("robot.base_yaw=nan", r"robot\.base_yaw: expected a finite base_yaw"),
        ("run.max_duration_s=nan", r"run\.max_duration_s: expected > 0 \[s\], got nan"),
    ],
)
def test_experiment_settings_are_named_by_their_group(override: str, message: str) -> None:
    """A bad value inside a group's dataclasses is named by its full dotted key."""
    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR
    from iplanner_torch.cli.experiment import build_experiment

    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        cfg = compose("config", overrides=[override])
        with pytest.raises(ConfigError, match=f"^{message}"):
            build_experiment(cfg, {})


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["run.seeds=[]"], r"run\.seeds: expected at least one, got \[\]"),
        (["run.seeds=[3,3]"], r"run\.seeds: 3 given twice"),
        (["run.stall_fallback_s=-1"], r"run\.stall_fallback_s: expected stall_fallback_s > 0"),
        (
            ["experiment=table_simulation", "experiment.seeds=[]"],
            r"experiment\.seeds: expected at least one, got \[\]",
        ),
        (
            ["experiment=table_simulation", "experiment.episode.max_duration_s=-1"],
            r"experiment\.episode\.max_duration_s: expected max_duration_s > 0",
        ),
    ],
)
def test_run_and_experiment_settings_are_named_by_their_key(
    overrides: list[str], message: str
) -> None:
    """The episode grid's settings are named as the command line writes them."""
    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR
    from iplanner_torch.cli.experiment import build_experiment

    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        cfg = compose("config", overrides=overrides)
        with pytest.raises(ConfigError, match=f"^{message}"):
            build_experiment(cfg, {})


def test_experiment_names_the_overrides_it_would_not_read() -> None:
    """predictor/trainer/train/evaluate are never read by iplanner-experiment, the data group
    only with run.train_data=data; everything else is."""
    from iplanner_torch.cli.experiment import unused_overrides

    overrides = [
        "trainer.max_steps=5",
        "predictor=iplanner_no_ni",
        "+predictor.svgp.num_inducing=8",
        "train.resume=true",
        "evaluate.mode=episode",
        "data.windows.n_prev=5",
        "data=lego",
        "tracker.noise=0.02",
        "planner.confidence=0.99",
        "scenario=arrangement_2x2",
        "robot=fetch",
        "run.train_data=tasks",
        "hydra/launcher=joblib",
        "paths.datasets=/tmp/d",
    ]
    assert unused_overrides(overrides, "tasks") == overrides[:7]
    assert unused_overrides(overrides, "data") == overrides[:5]
    assert unused_overrides(["tracker.noise=0", "human.speed=fast"], "tasks") == []


def test_experiment_refuses_an_override_it_would_not_read(tmp_path: Path) -> None:
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "iplanner_torch.cli.experiment",
            "trainer.max_steps=5",
            "progress=false",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],  # fmt: skip
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 2
    assert "error: ConfigError: iplanner-experiment does not read trainer.max_steps=5" in (
        res.stderr
    )
    assert not (tmp_path / "run" / "results.csv").exists()


def test_a_checkpoint_trained_with_other_window_settings_is_named(tmp_path: Path) -> None:
    """ensure_predictors' check: the checkpoint's window settings against the ones the command
    line gives; settings it does not give are not compared."""
    from dataclasses import asdict, replace

    import torch
    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR
    from iplanner_torch.cli.experiment import checkpoint_differences
    from iplanner_torch.data.windows import WindowCfg

    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        cfg = compose("config", overrides=["data.windows.n_prev=5", "data.windows.stride=2"])
    windows = instantiate(cfg.data.windows, WindowCfg)
    ckpt = tmp_path / "predictor.ckpt"
    saved = asdict(replace(windows, n_prev=15, stride=1, n_future=10))
    torch.save({"window_cfg": saved | {"retired_field": 1}}, ckpt)
    given = {"n_prev", "stride"}
    assert checkpoint_differences(ckpt, cfg.data, given) == ["n_prev: 15 -> 5", "stride: 1 -> 2"]
    assert checkpoint_differences(ckpt, cfg.data, {"stride"}) == ["stride: 1 -> 2"]
    assert checkpoint_differences(ckpt, cfg.data, set()) == []  # n_future 10 -> 15 not given
    torch.save({"window_cfg": asdict(windows)}, ckpt)
    assert checkpoint_differences(ckpt, cfg.data, given) == []
    ckpt.write_bytes(b"not a checkpoint")  # the loader reports this one
    assert checkpoint_differences(ckpt, cfg.data, given) == []


def test_a_checkpoint_trained_with_another_trainer_or_seed_is_named(tmp_path: Path) -> None:
    """ensure_predictors' check of the recorded training: run.train_trainer's budget and seed
    against training_inputs.json, each only when the command line gives it."""
    import json
    from dataclasses import asdict

    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR
    from iplanner_torch.cli.experiment import option_node, training_differences
    from iplanner_torch.eval.prediction import INPUTS_FILE
    from iplanner_torch.prediction.training import TrainerCfg

    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        cfg = compose("config", overrides=["seed=3"])
    fast = option_node("trainer", "fast", cfg)  # max_steps 40, seed ${seed} = 3
    default = option_node("trainer", "default", cfg)  # max_steps None
    ckpt = tmp_path / "predictor.ckpt"
    record = {"trainer_cfg": asdict(TrainerCfg(max_steps=40, seed=0)), "split": {"seed": 0}}
    (tmp_path / INPUTS_FILE).write_text(json.dumps(record))
    assert training_differences(ckpt, fast, seed=None, budget=True) == []
    assert training_differences(ckpt, default, seed=None, budget=True) == [
        "trainer max_steps: 40 -> None"
    ]
    assert training_differences(ckpt, default, seed=None, budget=False) == []  # not given
    assert training_differences(ckpt, fast, seed=3, budget=False) == [
        "trainer seed: 0 -> 3",
        "split seed: 0 -> 3",
    ]
    assert training_differences(ckpt, fast, seed=3, budget=True) == [
        "trainer seed: 0 -> 3",
        "split seed: 0 -> 3",
    ]
    (tmp_path / INPUTS_FILE).write_text("{broken")  # no record to compare: used as it is
    unchecked = r"used as it is, unchecked against the command line's seed"
    with pytest.warns(DataWarning, match=rf"unreadable .*{unchecked} and run.train_trainer"):
        assert training_differences(ckpt, default, seed=3, budget=True) == []
    (tmp_path / INPUTS_FILE).write_text("[1, 2]")
    with pytest.warns(DataWarning, match=rf"expected a JSON object, got list.*{unchecked}$"):
        assert training_differences(ckpt, default, seed=3, budget=False) == []
    # the record of a later run (seed 3, interrupted) beside a checkpoint trained with seed 0:
    # the checkpoint keeps the digest of its own record, so its own seed is what is compared
    import torch

    from iplanner_torch.eval.prediction import inputs_digest

    ours = dict(record, split={"seed": 0, "fractions": [0.8, 0.1, 0.1]})
    later = dict(ours, trainer_cfg=asdict(TrainerCfg(max_steps=40, seed=3)))
    later["split"] = {"seed": 3, "fractions": [0.8, 0.1, 0.1]}
    torch.save({"inputs_digest": inputs_digest(ours), "cfg": {"seed": 0}}, ckpt)
    (tmp_path / INPUTS_FILE).write_text(json.dumps(later))
    other_run = "records another training run than the checkpoint's"
    with pytest.warns(DataWarning, match=other_run):
        assert training_differences(ckpt, fast, seed=3, budget=True) == ["predictor seed: 0 -> 3"]
    with pytest.warns(DataWarning, match=other_run):
        assert training_differences(ckpt, fast, seed=0, budget=False) == []
    (tmp_path / INPUTS_FILE).write_text(json.dumps(ours))  # its own record: read as before
    assert training_differences(ckpt, fast, seed=3, budget=False) == [
        "trainer seed: 0 -> 3",
        "split seed: 0 -> 3",
    ]
    (tmp_path / INPUTS_FILE).write_text("{}")  # a record without trainer settings
    assert training_differences(ckpt, default, seed=3, budget=True) == []
    (tmp_path / INPUTS_FILE).unlink()
    assert training_differences(ckpt, default, seed=3, budget=True) == []


def test_experiment_names_overrides_that_another_setting_replaces() -> None:
    """With experiment=..., the experiment's lists, scenarios and episode settings replace the
    main job's; planner.kind / predictor_variant are set per episode in every run."""
    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR
    from iplanner_torch.cli.experiment import replaced_overrides

    def replaced(overrides: list[str]) -> list[str]:
        with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
            cfg = compose("config", overrides=overrides)
        return [
            line.split(" (", 1)[0] for line in replaced_overrides(overrides, cfg.get("experiment"))
        ]

    main_job = ["run.seeds=[0,1]", "human.speed=fast", "planner.confidence=0.99",
                "run.max_duration_s=5", "scenario=arrangement_2x2",
                "tracker.noise=0.02"]  # fmt: skip
    assert replaced(main_job) == []
    always = ["planner.kind=itomp", "planner.predictor_variant=ni", "sim.human.mode=blocking",
              "planner.optimizer.seed=3"]  # fmt: skip
    assert replaced(always) == always
    speed = ["experiment=speed_response", "run.seeds=[5]", "run.planners=[itomp]",
             "run.write_mcap=false", "human.speed=slow", "planner.confidence=0.5",
             "scenario=arrangement_2x2", "run.max_duration_s=2",
             "planner.optimizer.weights.human_lookahead_penalty=0", "sim.human.mode=tasks",
             # not replaced: the experiment lists no noises and sets none of these
             "tracker.noise=0.02", "planner.itomp_spread_mps=0.1", "sim.human.hold_s=0.3",
             "run.stall_fallback_s=3", "experiment.seeds=[1]",
             "hydra/launcher=joblib"]  # fmt: skip
    assert replaced(speed) == speed[1:10]
    table = ["experiment=table_simulation", "human.speed=slow", "run.max_duration_s=30"]
    assert replaced(table) == ["run.max_duration_s=30"]  # the table lists no speeds


def test_the_planner_group_option_narrows_the_run_to_that_planner() -> None:
    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR
    from iplanner_torch.cli.experiment import choose_planner

    def planners(overrides: list[str]) -> list[str]:
        with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
            cfg = compose("config", overrides=overrides)
        choose_planner(cfg, overrides)
        node = cfg.experiment if cfg.get("experiment") is not None else cfg.run
        return list(node.planners)

    assert planners([]) == ["itomp", "iplanner_no_ni", "iplanner_ni"]
    assert planners(["planner=itomp"]) == ["itomp"]
    assert planners(["planner=iplanner_no_ni", "run.planners=[iplanner_no_ni]"]) == [
        "iplanner_no_ni"
    ]
    assert planners(["experiment=table_simulation", "planner=iplanner_ni"]) == ["iplanner_ni"]
    with pytest.raises(ConfigError, match=r"planner=itomp runs the itomp planner alone, but "
                       r"run\.planners=\[iplanner_ni\] lists others"):  # fmt: skip
        planners(["planner=itomp", "run.planners=[iplanner_ni]"])
    with pytest.raises(ConfigError, match=r"experiment\.planners=\[itomp,iplanner_ni\]"):
        planners(["experiment=speed_response", "planner=itomp",
                  "experiment.planners=[itomp,iplanner_ni]"])  # fmt: skip


@pytest.mark.parametrize(
    ("module", "args", "line"),
    [
        ("experiment", ["run.train_if_missing=no"],
         "error: ConfigError: run.train_if_missing: expected bool, got 'no'"),
        # read after the episodes: checked before the first
        ("experiment", ["run.planners=[itomp]", "run.timeline_plots=yes"],
         "error: ConfigError: run.timeline_plots: expected bool, got 'yes'"),
        ("data", ["info", "data.path=nowhere", "+data.fps=0"],
         "error: ConfigError: data.fps: expected a frame rate > 0 [Hz], got 0"),
        ("data", ["info", "data.path=nowhere", "+data.fps=abc"],
         "error: ConfigError: data.fps: expected a frame rate > 0 [Hz], got 'abc'"),
        ("data", ["info", "data.path=nowhere", "data.windows.joints=[]"],
         "error: ConfigError: data.windows.joints: joints must be non-empty and unique"),
        # each window setting under its own key (n_future=0 was named data.windows.n_prev)
        ("data", ["info", "data.path=nowhere", "data.windows.n_future=0"],
         "error: ConfigError: data.windows.n_future: expected an integer >= 1, got 0"),
        ("train", ["data.windows.stride=0"],
         "error: ConfigError: data.windows.stride: expected an integer >= 1, got 0"),
        # an unknown format was read as native files
        ("train", ["+data.format=lego"],
         "error: ConfigError: data.format: expected one of native, lego_assembly, got 'lego'"),
        ("data", ["generate", "data.path=a_file/sub"],
         "error: NotADirectoryError: [Errno 20] Not a directory: "),
        ("evaluate", ["evaluate.checkpoint=null"],
         "error: ConfigError: evaluate.checkpoint: expected a path, got null"),
        # a number where a path is expected: a TypeError traceback, exit 1
        ("train", ["data.path=2024"],
         "error: ConfigError: data.path: expected a path (a string), got 2024"),
        ("data", ["info", "data.path=123"],
         "error: ConfigError: data.path: expected a path (a string), got 123"),
        ("evaluate", ["evaluate.mode=episode", "evaluate.logs=r.csv", "evaluate.out_dir=123"],
         "error: ConfigError: evaluate.out_dir: expected a path (a string), got 123"),
        # a run of itomp alone never read them
        ("experiment", ["run.planners=[itomp]", "run.train_trainer=nope"],
         "error: ConfigError: run.train_trainer: expected a trainer option"),
    ],
)  # fmt: skip
def test_bad_values_get_one_line_before_any_work(
    module: str, args: list[str], line: str, tmp_path: Path
) -> None:
    """A string for a bool, a frame rate of 0 or text, an empty joint list, a path through a
    file, a null path: one error line and exit code 2, with nothing trained or generated."""
    (tmp_path / "a_file").write_text("not a folder\n")
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    if module != "data":  # it does not read paths.checkpoints
        args = [*args, f"paths.checkpoints={tmp_path / 'ck'}"]
    res = subprocess.run(
        [sys.executable, "-m", f"iplanner_torch.cli.{module}", *args, "progress=false",
         f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(line), res.stderr
    assert not (tmp_path / "ck").exists() and not (tmp_path / "datasets").exists()
    assert not (tmp_path / "run" / "episodes").exists()  # no episode ran


def test_window_settings_of_the_wrong_kind_are_named(tmp_path: Path) -> None:
    """``data.windows.joints=right_hand`` (a string) was split into letters ("names joint(s)
    ['h'] more than once"), and ``data.windows.n_prev=null`` failed in a comparison of None."""
    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import load_dataset
    from iplanner_torch.data.io import save_demonstration
    from iplanner_torch.data.reaching import ReachingCfg, reaching_demonstrations
    from iplanner_torch.data.windows import WindowCfg

    demo = reaching_demonstrations(ReachingCfg(n_targets=2, reaches_per_target=1), 0, 0)[0]
    save_demonstration(demo, tmp_path / "d.npz")
    node = OmegaConf.create({"path": str(tmp_path), "windows": {"joints": "right_hand"}})
    with pytest.raises(ConfigError, match=r"data\.windows\.joints: expected a list of joint "
                       r"names, got the single string 'right_hand'"):  # fmt: skip
        load_dataset(node)
    for key, value, least in (("n_prev", None, 3), ("n_future", 1.5, 1), ("stride", "2", 1)):
        with pytest.raises(ConfigError, match=rf"^{key}: expected an integer >= {least}, got"):
            WindowCfg(**{key: value})
