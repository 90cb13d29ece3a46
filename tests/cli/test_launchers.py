"""The Submitit launchers of ``conf/hydra/launcher`` (the ``slurm`` extra): the SLURM config is
one the plugin and Submitit accept, and a sweep runs and is summarised under Submitit's local
executor and under its SLURM executor on a stand-in cluster (``fake_slurm``). Skipped where
``hydra-submitit-launcher`` is not installed (``pip install -e ".[slurm]"``; the ``dev`` extra
installs it too)."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from hydra.errors import MissingConfigException

from iplanner_torch.cli._common import composition_error_text


def test_a_missing_launcher_plugin_is_named_with_its_install_command() -> None:
    """The exception Hydra raises for ``hydra/launcher=slurm`` without the plugin (its
    defaults name ``submitit_slurm``, which only the plugin registers) becomes one line."""
    exc = MissingConfigException(
        "In 'hydra/launcher/slurm': Could not load 'hydra/launcher/submitit_slurm'.",
        missing_cfg_file="hydra/launcher/submitit_slurm",
    )
    assert composition_error_text(exc) == (
        "hydra/launcher=slurm needs the Hydra plugin hydra-submitit-launcher, which is not "
        'installed: pip install -e ".[slurm]"'
    )
    exc = MissingConfigException(
        "Could not load 'hydra/launcher/submitit_local'.",
        missing_cfg_file="hydra/launcher/submitit_local",
    )
    assert composition_error_text(exc).startswith("hydra/launcher=submitit_local needs ")
    # another group's missing option is still Hydra's own message
    exc = MissingConfigException("Could not load 'robot/ur5'.", missing_cfg_file="robot/ur5")
    assert composition_error_text(exc) == "Could not load 'robot/ur5'."


def _slurm_launcher_params() -> dict:
    """The launcher parameters ``hydra/launcher=slurm`` composes to."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import CONF_DIR

    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            cfg = compose(
                "config",
                overrides=["hydra/launcher=slurm", "hydra.sweep.dir=sweep"],
                return_hydra_config=True,
            )
            params = OmegaConf.to_container(cfg.hydra.launcher, resolve=True)
    finally:
        GlobalHydra.instance().clear()
    assert isinstance(params, dict)
    return params


def test_the_slurm_config_is_one_submitit_accepts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``conf/hydra/launcher/slurm.yaml`` composes with the plugin's schema (a key it lacks
    would fail there), and Submitit's SLURM executor takes every parameter the launcher
    derives from it, as the launcher passes them (an unknown one raises); a fake ``srun`` on
    the PATH stands in for the cluster the executor looks for."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    import submitit
    from hydra_plugins.hydra_submitit_launcher.config import BaseQueueConf
    from omegaconf import OmegaConf

    params = _slurm_launcher_params()
    assert params["_target_"].endswith(".SlurmLauncher")
    assert (params["timeout_min"], params["cpus_per_task"], params["mem_gb"]) == (120, 4, 16)
    assert params["array_parallelism"] == 64 and params["gpus_per_node"] == 0

    srun = tmp_path / "bin" / "srun"
    srun.parent.mkdir()
    srun.write_text("#!/bin/sh\nexit 0\n")
    srun.chmod(srun.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{srun.parent}{os.pathsep}{os.environ['PATH']}")
    # the launcher's own translation (BaseSubmititLauncher.launch)
    params.pop("_target_")
    folder = params.pop("submitit_folder")
    executor = submitit.AutoExecutor(
        cluster="slurm",
        folder=tmp_path / folder,
        slurm_max_num_timeout=params.pop("max_num_timeout"),
    )
    base = set(OmegaConf.structured(BaseQueueConf).keys())
    executor.update_parameters(
        **{k if k in base else f"slurm_{k}": v for k, v in params.items() if v is not None}
    )
    with pytest.raises(NameError, match="partitoin"):  # the check can fail
        executor.update_parameters(slurm_partitoin="gpu")


def _two_job_sweep(tmp_path: Path, launcher: list[str], env: dict | None = None) -> Path:
    """Run ``iplanner-experiment -m`` with the ``launcher`` overrides on a two-job sweep (ITOMP,
    2 s, tracker noise 0 and 0.02) and check that it succeeded: each job's results and log,
    and the sweep summary of both. Returns the sweep folder."""
    sweep = tmp_path / "sweep"
    full_env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg", **(env or {}))
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.experiment", "-m", *launcher,
         f"hydra.sweep.dir={sweep}", "tracker.noise=0,0.02", "run.planners=[itomp]",
         "run.max_duration_s=2", "run.timeline_plots=false", "progress=false"],
        cwd=tmp_path, env=full_env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    for job in ("0", "1"):
        assert (sweep / job / "results.csv").is_file()
        assert len(list((sweep / job / "episodes").glob("*.mcap"))) == 1
    import pandas as pd

    rows = pd.read_csv(sweep / "summary" / "results.csv")
    assert sorted(rows["noise"]) == [0.0, 0.02]
    return sweep


def test_a_sweep_runs_on_submitits_local_executor(tmp_path: Path) -> None:
    """``hydra/launcher=submitit_local``: each job runs in a process of its own that Submitit
    starts, and the sweep summary gathers them, as with the basic and joblib launchers."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    sweep = _two_job_sweep(tmp_path, ["hydra/launcher=submitit_local"])
    assert (sweep / ".submitit").is_dir()  # Submitit ran them


def test_the_slurm_launcher_off_a_cluster_is_one_line(tmp_path: Path) -> None:
    """``hydra/launcher=slurm`` where no ``srun`` is on the PATH: Submitit's RuntimeError was a
    traceback with exit code 1; it is one line naming the way out, with exit code 2."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    bin_dir = tmp_path / "bin"  # a PATH with this Python only (no srun wherever SLURM is)
    bin_dir.mkdir()
    (bin_dir / "python").symlink_to(sys.executable)
    env = dict(os.environ, PATH=str(bin_dir), PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.experiment", "-m", "hydra/launcher=slurm",
         f"hydra.sweep.dir={tmp_path / 'sweep'}", "tracker.noise=0"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    assert "Traceback" not in res.stderr
    lines = res.stderr.strip().splitlines()
    assert lines[-1].startswith("error: ConfigError: hydra/launcher=slurm submits jobs to a SLURM")
    assert "no `srun` is on the PATH" in lines[-1] and "hydra/launcher=joblib" in lines[-1]
    assert not (tmp_path / "sweep").exists()  # no job ran: no sweep folder is left behind
    # nor a dated one under multirun/; a sweep folder that existed before is kept as it was
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine")
    for sweep_dir in ([], [f"hydra.sweep.dir={kept}"]):
        res = subprocess.run(
            [sys.executable, "-m", "iplanner_torch.cli.experiment", "-m", "hydra/launcher=slurm",
             *sweep_dir, "tracker.noise=0"],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert res.returncode == 2, res.stderr[-2000:]
    assert not (tmp_path / "multirun").exists()
    assert sorted(p.name for p in kept.iterdir()) == ["multirun.yaml", "notes.txt"]


def test_a_sweep_runs_through_sbatch_on_a_stand_in_cluster(tmp_path: Path) -> None:
    """``hydra/launcher=slurm`` end to end against stand-in ``sbatch``, ``srun`` and ``sacct``
    (:mod:`fake_slurm`): the sweep is submitted as one job array whose batch script carries
    ``conf/hydra/launcher/slurm.yaml``'s resources and a partition from the command line, each
    task runs in the environment SLURM gives it, and the sweep summary gathers the jobs."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    from fake_slurm import install

    bin_dir = tmp_path / "bin"
    env = install(bin_dir, tmp_path / "slurm_state")
    env["PATH"] = f"{bin_dir}{os.pathsep}{os.environ['PATH']}"
    launcher = ["hydra/launcher=slurm", "hydra.launcher.partition=debug"]
    sweep = _two_job_sweep(tmp_path, launcher, env)
    scripts = list((sweep / ".submitit").rglob("*_submission.sh"))
    assert len(scripts) == 1, scripts  # one array for the two jobs
    text = scripts[0].read_text()
    for flag in (
        "#SBATCH --array=0-1%2",  # array_parallelism 64, at most the 2 tasks
        "#SBATCH --partition=debug",
        "#SBATCH --cpus-per-task=4",
        "#SBATCH --mem=16GB",
        "#SBATCH --time=120",
    ):
        assert flag in text, text
    states = sorted((tmp_path / "slurm_state").glob("1001_*"))
    assert [s.name for s in states] == ["1001_0", "1001_1"]
    assert all(s.read_text() == "COMPLETED" for s in states)
