"""A sweep of closed-loop episodes gives the same numbers whether its jobs run side by side
(``hydra/launcher=joblib``, each with its episodes in worker processes, ``run.jobs=2``) or one
after another: each episode is a function of its seed and settings, not of the process it ran
in."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import torch

from iplanner_torch.recording import read_episode

#: results.csv columns that measure the wall clock, not the episode
WALL_CLOCK = {"prediction_ms", "sim/realtime_factor", "plan/overruns", "plan/mean_solve_ms"}


def _sweep(tmp_path: Path, name: str, *launcher: str) -> Path:
    sweep = tmp_path / name
    args = [
        "-m", *launcher, "run.planners=[itomp]", "run.seeds=[0,1]", "run.max_duration_s=2",
        "run.timeline_plots=false", "run.scene_hz=0", "tracker.noise=0,0.02", "progress=false",
        f"hydra.sweep.dir={sweep}", f"paths.datasets={tmp_path / 'datasets'}",
        f"paths.checkpoints={tmp_path / 'checkpoints'}",
    ]  # fmt: skip
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.experiment", *args],
        cwd=tmp_path,
        env=dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg"),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return sweep


@pytest.mark.slow
def test_joblib_sweep_gives_the_episodes_of_a_serial_one(tmp_path: Path) -> None:
    # each job running its episodes in two workers of its own too (run.jobs)
    parallel = _sweep(
        tmp_path, "parallel", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "run.jobs=2"
    )
    serial = _sweep(tmp_path, "serial")
    for job in ("0", "1"):
        a = pd.read_csv(parallel / job / "results.csv").sort_values("seed", ignore_index=True)
        b = pd.read_csv(serial / job / "results.csv").sort_values("seed", ignore_index=True)
        assert list(a["seed"]) == [0, 1]
        columns = [c for c in a.columns if c not in WALL_CLOCK]
        pd.testing.assert_frame_equal(a[columns], b[columns])
        assert a.loc[0, "min_distance"] != a.loc[1, "min_distance"]  # two seeds, two episodes
        logs = sorted(p.name for p in (parallel / job / "episodes").glob("*.mcap"))
        assert len(logs) == 2
        for name in logs:
            ea = read_episode(parallel / job / "episodes" / name)
            eb = read_episode(serial / job / "episodes" / name)
            assert ea.metadata == eb.metadata and ea.events() == eb.events()
            for series in ("robot_q", "human_true", "human_tracked"):
                (ta, xa), (tb, xb) = getattr(ea, series)(), getattr(eb, series)()
                assert torch.equal(ta, tb), (name, series)
                assert torch.equal(xa.nan_to_num(7.0), xb.nan_to_num(7.0)), (name, series)
            plans_a, plans_b = ea.frames["/planner/plan"], eb.frames["/planner/plan"]
            assert len(plans_a) == len(plans_b)
            for qa, qb in zip(plans_a["q"], plans_b["q"], strict=True):
                assert (qa == qb).all(), name
