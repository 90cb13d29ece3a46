"""Sweep gathering: the episode logs of a folder become one table and plots."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from iplanner_torch.cli.callbacks import gather_episode_logs
from iplanner_torch.recording import EpisodeWriter


def _log(path: Path, planner: str, noise: float, smoothness: float) -> None:
    meta = {"scenario": "s", "planner": planner, "noise": noise, "speed": "medium", "seed": 0}
    with EpisodeWriter(path, metadata=meta) as log:
        log.metrics(1.0, {"eval/smoothness": smoothness, "eval/min_distance": 0.1})


def test_logs_in_numbered_job_folders_are_read_in_job_order(tmp_path: Path) -> None:
    for job in (0, 1, 2, 10, 11):  # a glob sorts 10 and 11 before 2
        noise = 0.01 * job
        _log(tmp_path / "sweep" / str(job) / "episodes" / "itomp.mcap", "itomp", noise, job)
    written = gather_episode_logs(tmp_path / "sweep", tmp_path / "summary")
    names = {p.name for p in written}
    assert {"results.csv", "results.md", "sweep_smoothness.png"} <= names
    df = pd.read_csv(tmp_path / "summary" / "results.csv")
    assert list(df["smoothness"]) == [0.0, 1.0, 2.0, 10.0, 11.0]


def test_a_folder_of_logs_without_job_folders_is_gathered(tmp_path: Path) -> None:
    """``iplanner-evaluate evaluate.mode=episode evaluate.logs=<run>/episodes``."""
    for planner, s in (("itomp", 2.0), ("iplanner_ni", 1.0)):
        _log(tmp_path / "episodes" / f"{planner}.mcap", planner, 0.0, s)
    written = gather_episode_logs(tmp_path / "episodes", tmp_path / "summary")
    assert {"results.csv", "results.md"} <= {p.name for p in written}
    md = (tmp_path / "summary" / "results.md").read_text()
    assert md.index("| itomp |") < md.index("| iplanner_ni |")
    assert gather_episode_logs(tmp_path / "empty", tmp_path / "none") == []
