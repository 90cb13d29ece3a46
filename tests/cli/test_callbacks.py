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


def test_a_swept_override_is_kept_apart_and_seed_splits_are_not(tmp_path: Path) -> None:
    """Jobs of ``-m planner.itomp_spread_mps=0,0.1 'experiment.seeds=[0],[1]'``: the spread,
    which no result column names, becomes a column and its own rows in the summary (not an
    average over both values); the seed split is a repeat and stays merged (also a root
    ``seed``, which must not replace the episodes' seeds); a key every job shares adds
    nothing."""
    sweep = tmp_path / "sweep"
    jobs = [(0, "0", "[0]", 40.0), (1, "0", "[1]", 44.0), (2, "0.1", "[0]", 60.0),
            (3, "0.1", "[1]", 70.0)]  # fmt: skip
    for job, spread, seeds, smooth in jobs:
        (sweep / str(job) / ".hydra").mkdir(parents=True)
        (sweep / str(job) / ".hydra" / "overrides.yaml").write_text(
            f"- planner.itomp_spread_mps={spread}\n- experiment.seeds={seeds}\n"
            f"- seed={job}\n- run.max_duration_s=8\n- hydra.launcher.n_jobs=2\n"
        )
        meta = {"scenario": "s", "planner": "itomp", "seed": int(seeds[1])}
        with EpisodeWriter(sweep / str(job) / "episodes" / "e.mcap", metadata=meta) as log:
            log.metrics(1.0, {"eval/smoothness": smooth, "eval/min_distance": 0.1})
    gather_episode_logs(sweep, tmp_path / "summary")
    df = pd.read_csv(tmp_path / "summary" / "results.csv")
    assert list(df["planner.itomp_spread_mps"]) == [0.0, 0.0, 0.1, 0.1]
    assert "run.max_duration_s" not in df.columns
    # an override named like a result column never replaces the episodes' own values
    assert list(df["seed"]) == [0, 1, 0, 1] and list(df["override.seed"]) == [0, 1, 2, 3]
    md = (tmp_path / "summary" / "results.md").read_text()
    header = next(ln for ln in md.splitlines() if ln.startswith("| scenario"))
    cols = [c.strip() for c in header.strip("|").split("|")]
    assert cols[:3] == ["scenario", "planner.itomp_spread_mps", "planner"]
    assert "experiment.seeds" not in cols
    summary = md.split("## Mean ± std")[1]  # after the printed table, mean ± std per group
    rows = [ln for ln in summary.splitlines() if ln.startswith("| s |")]
    assert len(rows) == 2
    assert "| 42.0 ± 2.83 |" in rows[0] and "| 65.0 ± 7.07 |" in rows[1]


def test_jobs_that_wrote_no_logs_are_gathered_from_their_results_csv(tmp_path: Path) -> None:
    """``-m run.stall_fallback_s=2,null run.write_mcap=false``: each job's results.csv stands
    for its logs, its rows are placed in their job (the swept value is a column), a job with
    logs is read from them, and a summary gathered before is not read back."""
    from iplanner_torch.cli.callbacks import run_rows

    sweep = tmp_path / "sweep"
    for job, value, smooth in ((0, "2", [40.0, 41.0]), (1, "null", [50.0, 52.0])):
        folder = sweep / str(job)
        (folder / ".hydra").mkdir(parents=True)
        (folder / ".hydra" / "overrides.yaml").write_text(
            f"- run.stall_fallback_s={value}\n- run.write_mcap=false\n"
        )
        pd.DataFrame(
            {"planner": "iplanner_ni", "scenario": "s", "seed": [0, 1], "smoothness": smooth,
             "min_distance": 0.1}
        ).to_csv(folder / "results.csv", index=False)  # fmt: skip
    (sweep / "summary").mkdir()
    pd.DataFrame({"planner": ["x"], "smoothness": [1e9]}).to_csv(
        sweep / "summary" / "results.csv", index=False
    )
    # a third job that wrote a log: read from it, not from its results.csv
    (sweep / "2" / ".hydra").mkdir(parents=True)
    (sweep / "2" / ".hydra" / "overrides.yaml").write_text(
        "- run.stall_fallback_s=10\n- run.write_mcap=true\n"
    )
    _log(sweep / "2" / "episodes" / "e.mcap", "iplanner_ni", 0.0, 60.0)
    pd.DataFrame({"planner": ["iplanner_ni"], "smoothness": [-1.0]}).to_csv(
        sweep / "2" / "results.csv", index=False
    )
    rows = run_rows(sweep)
    assert sorted(rows["smoothness"]) == [40.0, 41.0, 50.0, 52.0, 60.0]
    gather_episode_logs(sweep, tmp_path / "summary")
    df = pd.read_csv(tmp_path / "summary" / "results.csv")
    by_value = df.groupby("run.stall_fallback_s")["smoothness"].mean().to_dict()
    assert by_value == {2.0: 40.5, 10.0: 60.0}  # a number where it reads as one
    assert list(df.loc[df["run.stall_fallback_s"].isna(), "smoothness"]) == [50.0, 52.0]
    md = (tmp_path / "summary" / "results.md").read_text()
    assert "run.stall_fallback_s" in md
    # one run folder with no log: its own results.csv
    assert list(run_rows(sweep / "0")["smoothness"]) == [40.0, 41.0]
    (tmp_path / "empty").mkdir()
    assert run_rows(tmp_path / "empty").empty and run_rows(tmp_path / "absent").empty
