"""The console scripts run end to end on tiny settings (in a temporary working directory)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from iplanner_torch.data.io import load_demonstrations
from iplanner_torch.recording import read_episode


def _run(args: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    module = {
        "iplanner-data": "iplanner_torch.cli.data",
        "iplanner-train": "iplanner_torch.cli.train",
        "iplanner-evaluate": "iplanner_torch.cli.evaluate",
        "iplanner-experiment": "iplanner_torch.cli.experiment",
    }[args[0]]
    return subprocess.run(
        [sys.executable, "-m", module, *args[1:]],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_data_generate_and_info(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    res = _run(
        [
            "iplanner-data",
            "generate",
            f"data.path={out}",
            "data.generator.reaches_per_target=1",
            "progress=false",
        ],
        tmp_path,
    )
    assert res.returncode == 0, res.stderr
    assert "wrote 8 demonstrations" in res.stdout
    assert len(load_demonstrations(out)) == 8
    assert (out / "README.md").exists()
    res = _run(["iplanner-data", "info", f"data.path={out}"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert "8 demonstrations" in res.stdout and "reach_7" in res.stdout


def test_data_errors_are_one_line_with_exit_code_2(tmp_path: Path) -> None:
    res = _run(["iplanner-data", "info", f"data.path={tmp_path / 'nope'}"], tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip().startswith("error: DataError:")
    res = _run(["iplanner-data", "frobnicate"], tmp_path)
    assert res.returncode == 2 and "unknown command" in res.stderr
    res = _run(["iplanner-data", "info", "data.pth=x"], tmp_path)
    assert res.returncode != 0 and "pth" in res.stderr


def test_experiment_itomp_short_episode(tmp_path: Path) -> None:
    res = _run(
        [
            "iplanner-experiment",
            "run.planners=[itomp]",
            "run.max_duration_s=3",
            "progress=false",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        tmp_path,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert "itomp" in res.stdout and "smoothness" in res.stdout
    mcaps = sorted((tmp_path / "run" / "episodes").glob("*.mcap"))
    assert len(mcaps) == 1
    episode = read_episode(mcaps[0])
    t, q = episode.robot_q()
    assert q.shape[-1] == 7 and len(t) > 10
    assert (tmp_path / "run" / "results.md").exists()


@pytest.mark.slow
def test_main_job_default(tmp_path: Path) -> None:
    """The README's main command on its embedded default (trains two small predictors)."""
    res = _run(["iplanner-experiment", "progress=false"], tmp_path, timeout=1200)
    assert res.returncode == 0, res.stderr[-3000:]
    for planner in ("itomp", "iplanner_no_ni", "iplanner_ni"):
        assert planner in res.stdout
