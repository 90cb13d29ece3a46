"""What Hydra finds wrong while composing the config (a config file that is not valid YAML, a
misspelt key, an unknown option) is one error line with exit code 2, before the command runs.

The commands run in this process (their ``main``) and stop at composition, so nothing is
generated, trained or run."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from iplanner_torch.errors import ConfigError


def _main(
    module: str, args: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> tuple[object, list[str]]:
    """Run ``iplanner_torch.cli.<module>.main()`` with ``args``; its exit code and the lines
    it wrote to stderr."""
    from hydra.core.global_hydra import GlobalHydra

    monkeypatch.setattr(sys, "argv", [f"iplanner-{module}", *args])
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    GlobalHydra.instance().clear()
    try:
        with pytest.raises(SystemExit) as stop:
            importlib.import_module(f"iplanner_torch.cli.{module}").main()
    finally:
        GlobalHydra.instance().clear()
    assert "HYDRA_FULL_ERROR" not in os.environ  # set while composing only
    return stop.value.code, capsys.readouterr().err.strip().splitlines()


def _user_conf(tmp_path: Path, group: str, name: str, text: str) -> str:
    """Write ``<tmp_path>/conf/<group>/<name>.yaml``; the override that adds that folder to
    the config search path."""
    folder = tmp_path / "conf" / group
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.yaml").write_text(text)
    return f"hydra.searchpath=[file://{tmp_path / 'conf'}]"


@pytest.mark.parametrize(
    ("text", "where", "problem"),
    [
        ("_target_: iplanner_torch.robot.model.RobotCfg\nbase_position: [0.1, 0.2\n",
         "line 3, column 1", "expected ',' or ']', but got '<stream end>' (while parsing a flow "
         "sequence from line 2, column 16)"),
        ("name: mine\nbase:\n\tyaw: 1.0\n", "line 3, column 1",
         "found character '\\t' that cannot start any token"),
        ("name: mine\nname: other\n", "line 2, column 1", "found duplicate key name"),
    ],
)  # fmt: skip
def test_a_config_file_that_is_not_valid_yaml_is_named_in_one_line(
    text: str,
    where: str,
    problem: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    search = _user_conf(tmp_path, "robot", "my_robot", text)
    args = [search, "robot=my_robot", f"hydra.run.dir={tmp_path / 'run'}"]
    code, lines = _main("experiment", args, monkeypatch, capsys)
    assert code == 2
    file = tmp_path / "conf" / "robot" / "my_robot.yaml"
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"error: ConfigError: {file}: malformed YAML at {where}: {problem}")
    assert not (tmp_path / "run").exists()


def test_a_config_file_whose_top_level_is_a_list_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """In a ``@package _global_`` file (composition fails), and as a group's node (the node is
    refused before it is built)."""
    from iplanner_torch.cli._common import instantiate
    from iplanner_torch.robot.model import RobotCfg

    search = _user_conf(tmp_path, "experiment", "mine", "# @package _global_\n- 1\n- 2\n")
    code, lines = _main("experiment", [search, "experiment=mine"], monkeypatch, capsys)
    assert code == 2
    assert lines == [
        "error: ConfigError: config file experiment/mine.yaml: its top level is a list, not a "
        "mapping of keys to values ('key: value' lines)"
    ]
    with pytest.raises(ConfigError) as err:
        instantiate(OmegaConf.create({"robot": [1, 2]}).robot, RobotCfg)
    assert str(err.value).startswith(
        "config node 'robot' is a list, not a mapping of keys to values: its file needs "
        "'_target_: iplanner_torch.robot.model.RobotCfg'"
    )


@pytest.mark.parametrize(
    ("module", "args", "line"),
    [
        # no experiment chosen: the key is looked up in the experiment options
        ("experiment", ["experiment.episode.max_duraton_s=5"],
         "error: ConfigError: unknown key 'experiment.episode.max_duraton_s' (did you mean "
         "'experiment.episode.max_duration_s'? it needs experiment=<option>: "),
        ("experiment", ["experiment.episode.max_duration_s=5"],
         "error: ConfigError: key 'experiment.episode.max_duration_s' needs "
         "experiment=<option> ("),
        ("experiment", ["experiment=table_simulation", "experiment.episode.max_duraton_s=5"],
         "error: ConfigError: unknown key 'experiment.episode.max_duraton_s' (did you mean "
         "'experiment.episode.max_duration_s'?)"),
        ("experiment", ["run.max_duraton_s=5"],
         "error: ConfigError: unknown key 'run.max_duraton_s' (did you mean "
         "'run.max_duration_s'?)"),
        ("experiment", ["sed=3"], "error: ConfigError: unknown key 'sed' (did you mean 'seed'?)"),
        ("experiment", ["experimnt=table_simulation"],
         "error: ConfigError: unknown key 'experimnt' (did you mean 'experiment'?)"),
        ("experiment", ["typo=1"],
         "error: ConfigError: unknown key 'typo' (print the config with --cfg job to see its "
         "keys)"),
        ("train", ["predictor.svgp.epochz=2"],
         "error: ConfigError: unknown key 'predictor.svgp.epochz' (did you mean "
         "'predictor.svgp.epochs'?)"),
        ("train", ["predictor.svgpp.epochs=2"],
         "error: ConfigError: unknown key 'predictor.svgpp.epochs' (did you mean "
         "'predictor.svgp.epochs'?)"),
        ("data", ["info", "data.windows.n_prevv=3"],
         "error: ConfigError: unknown key 'data.windows.n_prevv' (did you mean "
         "'data.windows.n_prev'?)"),
        ("evaluate", ["evaluate.mod=episode"],
         "error: ConfigError: unknown key 'evaluate.mod' (did you mean 'evaluate.mode'?)"),
        ("experiment", ["robot=nope"],
         "error: ConfigError: unknown option robot=nope; robot options: fetch, kuka_iiwa14"),
        ("train", ["x=[1"], "error: ConfigError: cannot parse override 'x=[1': "),
        # keys read when set but absent from the default data options: the + is the fix
        ("data", ["info", "data.format=native"],
         "error: ConfigError: key 'data.format' is not in this config (it is read when set): "
         "add it with +data.format=<value>"),
        ("train", ["data.fps=15"],
         "error: ConfigError: key 'data.fps' is not in this config (it is read when set): "
         "add it with +data.fps=<value>"),
    ],
)  # fmt: skip
def test_a_misspelt_key_or_option_is_named_in_full_in_one_line(
    module: str,
    args: list[str],
    line: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    code, lines = _main(module, [*args, f"hydra.run.dir={tmp_path / 'run'}"], monkeypatch, capsys)
    assert code == 2
    assert len(lines) == 1 and lines[0].startswith(line), lines
    assert "not in struct" not in lines[0]
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("launcher", ["slurm", "submitit_slurm"])
def test_the_slurm_launcher_without_its_plugin_says_how_to_install_it(
    launcher: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """``hydra/launcher=slurm`` without the optional ``slurm`` extra was Hydra's "Could not
    load 'hydra/launcher/submitit_slurm'"; it now names the plugin and the install command."""
    import importlib.util

    if importlib.util.find_spec("hydra_plugins.hydra_submitit_launcher") is not None:
        pytest.skip("hydra-submitit-launcher is installed here")
    sweep = f"hydra.sweep.dir={tmp_path / 'sweep'}"
    code, lines = _main(
        "experiment", ["-m", f"hydra/launcher={launcher}", sweep], monkeypatch, capsys
    )
    assert code == 2
    assert lines == [
        f"error: ConfigError: hydra/launcher={launcher} needs the Hydra plugin "
        'hydra-submitit-launcher, which is not installed: pip install -e ".[slurm]"'
    ]
    assert not (tmp_path / "sweep").exists()


def test_hydra_full_error_leaves_the_report_to_hydra(monkeypatch: pytest.MonkeyPatch) -> None:
    """Set in the environment, HYDRA_FULL_ERROR=1 gives Hydra's own exception."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import ConfigCompositionException

    from iplanner_torch.cli import experiment

    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    monkeypatch.setattr(sys, "argv", ["iplanner-experiment", "run.max_duraton_s=5"])
    GlobalHydra.instance().clear()
    try:
        with pytest.raises(ConfigCompositionException):
            experiment.main()
    finally:
        GlobalHydra.instance().clear()
    assert os.environ["HYDRA_FULL_ERROR"] == "1"


def test_an_error_inside_the_command_is_reported_as_before(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """Once the command runs, Hydra reports an unexpected error itself (exit 1, not 2); a YAML
    file the command reads itself that does not parse is a one-line config error."""
    import hydra
    from hydra.core.global_hydra import GlobalHydra

    from iplanner_torch.cli._common import CONF_DIR, friendly_errors, run_app

    seen: list[str | None] = []
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1\n")

    @hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
    @friendly_errors
    def app(cfg: object) -> None:
        seen.append(os.environ.get("HYDRA_FULL_ERROR"))
        if "seed=1" in sys.argv:  # the case that reads a bad file
            OmegaConf.load(bad)
        raise ValueError("unexpected")

    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    run = [
        f"hydra.run.dir={tmp_path / 'run'}",
        "hydra/job_logging=none",
        "hydra/hydra_logging=none",
    ]
    for extra in ([], ["seed=1"]):
        monkeypatch.setattr(sys, "argv", ["app", *run, *extra])
        GlobalHydra.instance().clear()
        try:
            with pytest.raises((SystemExit, ValueError)) as stop:
                run_app(app)
        finally:
            GlobalHydra.instance().clear()
        assert seen[-1] is None  # Hydra's own report inside the command
        if extra:
            assert isinstance(stop.value, SystemExit) and stop.value.code == 2
            line = capsys.readouterr().err.strip().splitlines()[-1]
            assert line.startswith(
                f"error: ConfigError: {bad}: malformed YAML at line 2, column 1"
            )
        else:
            assert not isinstance(stop.value, SystemExit) or stop.value.code == 1
    assert "HYDRA_FULL_ERROR" not in os.environ


@pytest.mark.parametrize(
    ("module", "args", "line"),
    [
        ("experiment", ["+tracker.nosie=0.05"],
         "unknown key 'tracker.nosie' (did you mean 'tracker.noise'?): added by "
         "+tracker.nosie=0.05, which nothing reads"),
        ("experiment", ["++run.max_duraton_s=2"],
         "unknown key 'run.max_duraton_s' (did you mean 'run.max_duration_s'?): added by "
         "++run.max_duraton_s=2, which nothing reads"),
        ("experiment", ["+seeds=[1]"], "unknown key 'seeds' (did you mean 'seed'?): added by "
         "+seeds=[1], which nothing reads"),
        ("experiment", ["+experiment.episode.max_duration_s=1"],
         "key 'experiment.episode.max_duration_s' needs experiment=<option> (reach_across, "
         "safety_seeds, speed_response, table_simulation): with experiment=null there is no "
         "experiment node: "
         "added by +experiment.episode.max_duration_s=1"),
        ("data", ["info", "data.path=nowhere", "+data.pth=x"],
         "unknown key 'data.pth' (did you mean 'data.path'?): added by +data.pth=x, which "
         "nothing reads"),
        ("train", ["+train.resum=true"],
         "unknown key 'train.resum' (did you mean 'train.resume'?): added by +train.resum=true, "
         "which nothing reads"),
        ("evaluate", ["+evaluate.labls=[a]"],
         "unknown key 'evaluate.labls' (did you mean 'evaluate.labels'?): added by "
         "+evaluate.labls=[a], which nothing reads"),
    ],
)  # fmt: skip
def test_a_key_added_where_nothing_reads_it_is_refused(
    module: str,
    args: list[str],
    line: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    """Hydra adds ``+key=value`` (and ``++key=value`` for a key that is not there) without a
    word; a misspelt key added so would change nothing."""
    run = [f"hydra.run.dir={tmp_path / 'run'}", f"paths.datasets={tmp_path / 'data'}"]
    code, lines = _main(module, [*args, *run], monkeypatch, capsys)
    assert code == 2
    assert lines == [f"error: ConfigError: {line}"]
    assert not (tmp_path / "data").exists()


def test_a_key_that_exists_may_be_force_added(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """``++tracker.noise=...`` overrides the key that is there: it passes the check of added
    keys and reaches the check of its value."""
    args = ["++tracker.noise=-1", f"hydra.run.dir={tmp_path / 'run'}"]
    code, lines = _main("experiment", args, monkeypatch, capsys)
    assert code == 2
    assert len(lines) == 1 and lines[0].startswith("error: ConfigError: tracker.noise:"), lines


def test_added_keys_that_are_read_pass() -> None:
    """Keys under a settings class (which refuses fields it lacks itself), the optional keys,
    group choices and Hydra's own keys are not refused; outside a Hydra run ``++`` overrides
    are left alone."""
    from iplanner_torch.cli._common import check_added_keys

    cfg = OmegaConf.create(
        {
            "tracker": {"noise": 0.01},
            "planner": {"_target_": "x.PlannerCfg", "optimizer": {"iterations": 5}},
            "data": {"path": "d"},
        }
    )
    check_added_keys(
        cfg,
        [
            "+planner.optimizer.foo=1",
            "+data.fps=10",
            "+experiment=speed_response",
            "+hydra.job.env_set.X=1",
            "++tracker.nosie=1",
            "tracker.noise=0.02",
        ],
    )
    with pytest.raises(ConfigError, match=r"unknown key 'data\.pth' \(did you mean 'data\.path'"):
        check_added_keys(cfg, ["+data.pth=x"])


def test_the_commands_that_errors_suggest_run_as_suggested(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """A hint's command, pasted into a shell, reaches Hydra as meant: a folder named 2024 stays
    a string, a missing checkpoint named other than predictor.ckpt gets the training folder
    and the evaluate.checkpoint that reads it, and a list key is named in full."""
    import shlex

    from hydra.core.override_parser.overrides_parser import OverridesParser

    monkeypatch.chdir(tmp_path)
    run = f"hydra.run.dir={tmp_path / 'run'}"
    code, lines = _main("data", ["info", "data.path='2024'", run], monkeypatch, capsys)
    assert code == 2 and len(lines) == 1, lines
    command = re.search(r"generate it with `([^`]+)`", lines[0]).group(1)
    words = shlex.split(command)
    assert words[:2] == ["iplanner-data", "generate"]
    (path,) = OverridesParser.create().parse_overrides(words[2:])
    assert path.key_or_group == "data.path" and path.value() == "2024"

    missing = tmp_path / "ck" / "mine.ckpt"
    args = [f"evaluate.checkpoint={missing}", f"hydra.run.dir={tmp_path / 'run2'}"]
    code, lines = _main("evaluate", args, monkeypatch, capsys)
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"error: CheckpointError: {missing}: no such checkpoint file; ")
    train = shlex.split(re.search(r"train one with `([^`]+)`", lines[0]).group(1))
    assert train[0] == "iplanner-train" and f"train.out_dir={tmp_path / 'ck' / 'mine'}" in train
    assert lines[0].endswith(
        f"then run with evaluate.checkpoint={tmp_path / 'ck' / 'mine' / 'predictor.ckpt'}"
    )
    assert "data=reaching" in train
    # the data option is repeated: without data=lego, iplanner-train read a LEGO folder as
    # native files and failed
    args = [*args[:1], "data=lego", f"hydra.run.dir={tmp_path / 'run3'}"]
    code, lines = _main("evaluate", args, monkeypatch, capsys)
    assert code == 2 and len(lines) == 1, lines
    assert "data=lego" in shlex.split(re.search(r"train one with `([^`]+)`", lines[0]).group(1))

    code, lines = _main("experiment", ["run.seeds=3", f"hydra.run.dir={tmp_path / 'r3'}"],
                        monkeypatch, capsys)  # fmt: skip
    assert code == 2
    assert lines == [
        'error: ConfigError: run.seeds: expected a list of int, got 3 (e.g. "run.seeds=[3]")'
    ]


def test_a_config_error_before_any_work_leaves_no_dated_run_folder(tmp_path: Path) -> None:
    """``run.seeds=3`` is refused after Hydra made ``outputs/experiment/<date_time>/``: that
    folder, holding only Hydra's record and the error line, is deleted, and so are the
    ``outputs/experiment/`` and ``outputs/`` it leaves empty; a folder given with
    ``hydra.run.dir`` is kept."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cmd = [sys.executable, "-m", "iplanner_torch.cli.experiment", "run.seeds=3"]
    res = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert res.returncode == 2 and "run.seeds: expected a list of int" in res.stderr
    assert list(tmp_path.iterdir()) == []  # outputs/experiment/ left empty: gone too
    mine = tmp_path / "mine"
    res = subprocess.run([*cmd, f"hydra.run.dir={mine}"], cwd=tmp_path, env=env,
                         capture_output=True, text=True)  # fmt: skip
    assert res.returncode == 2 and (mine / "experiment.log").is_file()


def test_deleting_a_bare_run_folder_removes_only_the_parents_it_leaves_empty(
    tmp_path: Path,
) -> None:
    """Parents are removed while empty and inside the working directory; one holding another
    run, the working directory itself and folders above it stay."""
    from iplanner_torch.cli._common import delete_run_dir

    root = tmp_path / "work"
    first = root / "outputs" / "experiment" / "2026-11-28_23-00-00"
    other = root / "outputs" / "train" / "2026-11-28_22-00-00"
    for folder in (first, other):
        (folder / ".hydra").mkdir(parents=True)
    delete_run_dir(first, root)
    assert not (root / "outputs" / "experiment").exists()
    assert other.is_dir()  # outputs/ still holds train/
    delete_run_dir(other, root)
    assert root.is_dir() and list(root.iterdir()) == []
    # a run folder outside the working directory: its parents are not touched
    outside = tmp_path / "elsewhere" / "run"
    outside.mkdir(parents=True)
    delete_run_dir(outside, root)
    assert not outside.exists() and (tmp_path / "elsewhere").is_dir()


@pytest.mark.parametrize(
    ("log", "extra", "given_dir", "deleted"),
    [
        ("error: ConfigError: x\n", None, False, True),
        # a library announcing itself at import through Hydra's job logging is not work
        (
            "[2026-11-28 23:15:02,585][OpenGL.acceleratesupport][INFO] - No OpenGL_accelerate "
            "module loaded\nerror: ConfigError: x\n",
            None,
            False,
            True,
        ),
        (
            "[2026-11-28 23:15:02,585][root][WARNING] - careful\nerror: ConfigError: x\n",
            None,
            False,
            False,
        ),
        ("experiment 'main': 3 episode(s)\nerror: ConfigError: x\n", None, False, False),
        ("error: ConfigError: x\n", "results.csv", False, False),
        ("error: ConfigError: x\n", None, True, False),
    ],
)
def test_only_a_bare_dated_run_folder_is_deleted(
    tmp_path: Path, log: str, extra: str | None, given_dir: bool, deleted: bool
) -> None:
    """A folder whose log shows printed work, that holds another file, or that the command
    line named, is never a bare run folder."""
    from hydra.conf import HydraConf
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import bare_run_dir

    folder = tmp_path / "outputs" / "experiment" / "2026-11-28_23-00-00"
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "config.yaml").write_text("seed: 0\n")
    (folder / "experiment.log").write_text(log)
    if extra is not None:
        (folder / extra).write_text("x")
    hydra = OmegaConf.structured(HydraConf)
    hydra.mode = RunMode.RUN
    hydra.runtime.output_dir = str(folder)
    hydra.job.name = "experiment"
    hydra.overrides.hydra = [f"hydra.run.dir={folder}"] if given_dir else []
    saved = HydraConfig.instance().cfg
    HydraConfig.instance().set_config(OmegaConf.create({"hydra": hydra}))
    try:
        found = bare_run_dir("error: ConfigError: x")
    finally:
        HydraConfig.instance().cfg = saved
    assert (found == folder) is deleted


@pytest.mark.parametrize("printed", ["", "training  40%|####      |"])
def test_a_progress_bar_before_the_error_keeps_the_run_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture, printed: str
) -> None:
    """Through the commands' own wrapper: an error at once deletes the dated folder; a bar
    left unfinished on the line (work under way) reaches the log first, and the folder
    stays."""
    from hydra.conf import HydraConf
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import friendly_errors

    folder = tmp_path / "outputs" / "train" / "2026-11-28_23-00-00"
    (folder / ".hydra").mkdir(parents=True)
    hydra = OmegaConf.structured(HydraConf)
    hydra.mode = RunMode.RUN
    hydra.runtime.output_dir = str(folder)
    hydra.job.name = "train"
    hydra.overrides.hydra = []

    @friendly_errors
    def task() -> None:
        sys.stdout.write(printed)
        raise ConfigError("x: expected int")

    saved = HydraConfig.instance().cfg
    HydraConfig.instance().set_config(OmegaConf.create({"hydra": hydra}))
    try:
        with pytest.raises(SystemExit) as stop:
            task()
    finally:
        HydraConfig.instance().cfg = saved
    assert stop.value.code == 2
    assert "error: ConfigError: x: expected int" in capsys.readouterr().err
    assert folder.exists() is bool(printed)
    if printed:
        assert printed in (folder / "train.log").read_text()


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["hydra/launcher=joblib", "+hydra.launcher.n_job=2"],
         "unknown key 'hydra.launcher.n_job' (did you mean 'hydra.launcher.n_jobs'?): added by "
         "+hydra.launcher.n_job=2, which Hydra does not read"),
        (["++hydra.job.chdri=true"],
         "unknown key 'hydra.job.chdri' (did you mean 'hydra.job.chdir'?): added by "
         "++hydra.job.chdri=true, which Hydra does not read"),
        (["+hydra.nosuch=1"],
         "unknown key 'hydra.nosuch': added by +hydra.nosuch=1, which Hydra does not read"),
    ],
)  # fmt: skip
def test_a_hydra_key_added_where_hydra_reads_none_is_refused(
    args: list[str],
    line: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:
    """Hydra adds ``+hydra.<key>`` to its own settings without a word: a misspelt
    ``+hydra.launcher.n_job=2`` ran the sweep's jobs one at a time."""
    run = [f"hydra.run.dir={tmp_path / 'run'}", f"paths.datasets={tmp_path / 'data'}"]
    code, lines = _main("data", ["info", *args, *run], monkeypatch, capsys)
    assert code == 2
    assert lines == [f"error: ConfigError: {line}"]
    assert not (tmp_path / "data").exists()


def test_hydra_keys_added_under_a_free_mapping_pass(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """``hydra.job.env_set`` takes any key; ``++`` of a field Hydra has overrides it. The run
    goes on to the next check (no dataset here)."""
    run = [f"hydra.run.dir={tmp_path / 'run'}", f"data.path={tmp_path / 'none'}"]
    args = ["info", "+hydra.job.env_set.FOO=1", "++hydra.job.chdir=false", *run]
    code, lines = _main("data", args, monkeypatch, capsys)
    assert code == 2
    assert len(lines) == 1 and lines[0].startswith("error: DataError:"), lines


@pytest.mark.parametrize("module", ["train", "experiment"])
def test_the_hydra_config_prints_resolved(module: str, tmp_path: Path) -> None:
    """``--cfg hydra --resolve`` printed a traceback (exit 1): the sweep's job folder was
    ``${hydra:job.num}``, which a single run cannot resolve; Hydra's own form resolves."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("HYDRA_FULL_ERROR", None)
    res = subprocess.run(
        [sys.executable, "-m", f"iplanner_torch.cli.{module}", "--cfg", "hydra", "--resolve"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert "Traceback" not in res.stderr and "subdir:" in res.stdout


@pytest.mark.parametrize(
    ("line", "offered"),
    [
        ("iplanner-data generate data.gen", "data.generator."),
        ("iplanner-data info data=", "data=lego"),
        ("iplanner-data data=", "data=lego"),  # no command typed: generate, as before
    ],
)
def test_shell_completion_after_a_data_command(line: str, offered: str, tmp_path: Path) -> None:
    """``-sc query=bash`` offered nothing once ``generate`` or ``info`` was typed (the word
    read as an override it could not parse, exit 2)."""
    env = dict(os.environ, COMP_LINE=line, COMP_POINT=str(len(line)))
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.data", "-sc", "query=bash"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert offered in res.stdout.split()
