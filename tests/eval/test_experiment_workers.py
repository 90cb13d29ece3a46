"""Episodes of a grid run in worker processes (``run_experiment(..., executor=episode_pool(2))``):
checked against the same grid run one episode after the other in this process."""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from iplanner_torch.errors import ConfigError, DataError, DataWarning
from iplanner_torch.eval.episode import EpisodeCfg
from iplanner_torch.eval.experiment import (
    ExperimentCfg,
    _episode_in_worker,
    _init_worker,
    _portable_filters,
    episode_pool,
    episode_stem,
    finish_experiments,
    run_experiment,
    start_experiment,
    stop_pool,
)
from iplanner_torch.planning.replanner import PlanningOverrunWarning
from iplanner_torch.recording import read_episode
from iplanner_torch.sim.tasks import ScenarioCfg

#: the columns that measure this machine's speed, not the episode
TIMING = ("sim/realtime_factor", "plan/mean_solve_ms", "eval/prediction_ms", "plan/overruns")


def _grid() -> ExperimentCfg:
    """Two planners that need no predictor, two seeds, 2 simulated seconds each."""
    return ExperimentCfg(
        name="workers",
        planners=["itomp", "blind"],
        seeds=[0, 1],
        scenarios=[ScenarioCfg(name="s", task_order="0->1->2->3")],
        episode=EpisodeCfg(max_duration_s=2.0),
    )


def _episodes(df: pd.DataFrame) -> pd.DataFrame:
    return df[[c for c in df.columns if c not in TIMING]]


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pd.DataFrame]:
    out = tmp_path_factory.mktemp("serial")
    return out, run_experiment(_grid(), out)


def test_workers_give_the_rows_and_logs_of_the_serial_run(serial_run, tmp_path) -> None:
    serial, expected = serial_run
    done: list[int] = []
    with episode_pool(2) as pool:
        got = run_experiment(_grid(), tmp_path, executor=pool, on_done=done.append)
    assert done == [1, 1, 1, 1]
    # the same rows in the grid's order, in the frame and in the file
    pd.testing.assert_frame_equal(_episodes(got), _episodes(expected))
    pd.testing.assert_frame_equal(
        _episodes(pd.read_csv(tmp_path / "results.csv")),
        _episodes(pd.read_csv(serial / "results.csv")),
    )
    logs = sorted(p.name for p in (tmp_path / "episodes").glob("*.mcap"))
    assert logs == sorted(p.name for p in (serial / "episodes").glob("*.mcap")) and len(logs) == 4
    for name in logs:  # each log written by a worker holds the serial run's episode
        a, b = read_episode(serial / "episodes" / name), read_episode(tmp_path / "episodes" / name)
        assert a.events() == b.events()
        topic = "/robot/joint_state"
        pd.testing.assert_frame_equal(a.frames[topic], b.frames[topic])


def test_grids_begun_on_one_pool_finish_together(serial_run, tmp_path) -> None:
    # two grids (one seed each) queued on the same workers, then waited for at once: the
    # rows of the serial run of both seeds
    _, expected = serial_run
    grids = {"a": replace(_grid(), seeds=[0]), "b": replace(_grid(), seeds=[1])}
    with episode_pool(2) as pool:
        runs = [start_experiment(g, tmp_path / k, executor=pool) for k, g in grids.items()]
        assert all(len(run.pending) == 2 for run in runs)  # queued: start does not wait
        frames = finish_experiments(runs)
    assert all(not run.pending for run in runs)
    for k, frame in zip(grids, frames, strict=True):
        assert list(frame["seed"]) == [0 if k == "a" else 1] * 2
        written = pd.read_csv(tmp_path / k / "results.csv")  # each grid's own file, whole
        assert list(written["planner"]) == ["itomp", "blind"] == list(frame["planner"])
        assert list(written["eval/smoothness"]) == list(frame["eval/smoothness"])
    both = pd.concat(frames).sort_values(["planner", "seed"], ignore_index=True)
    want = expected.sort_values(["planner", "seed"], ignore_index=True)
    pd.testing.assert_frame_equal(_episodes(both), _episodes(want))


def test_a_failed_episode_stops_the_run_and_the_finished_rows_stay(tmp_path) -> None:
    grid = _grid()
    # the first episode's log cannot be written: its path is a folder
    bad = episode_stem("s", "medium", 0.01, "itomp", 0)
    (tmp_path / "episodes" / f"{bad}.mcap").mkdir(parents=True)
    with episode_pool(2) as pool:
        run = start_experiment(grid, tmp_path, executor=pool)
        deadline = time.monotonic() + 120.0
        while not run.failed() and time.monotonic() < deadline:  # seen without waiting
            time.sleep(0.05)
        assert run.failed()
        with pytest.raises(DataError, match="is a folder"):
            finish_experiments([run])
    rows = pd.read_csv(tmp_path / "results.csv")
    stems = [
        episode_stem(r.scenario, r.speed, r.noise, r.planner, r.seed) for r in rows.itertuples()
    ]
    # the episode that was running beside it ended and kept its row; the failed one has none;
    # every row has its log
    assert 1 <= len(stems) <= 3 and bad not in stems
    assert all((tmp_path / "episodes" / f"{s}.mcap").is_file() for s in stems)


def test_the_pool_refuses_a_bad_number_of_workers() -> None:
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ConfigError, match="jobs"):
            episode_pool(bad)  # type: ignore[arg-type]


def test_workers_take_the_warning_filters_of_the_parent() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PlanningOverrunWarning)
        warnings.filterwarnings("error", message="a .* message", category=DataWarning)
        filters = _portable_filters()
    # a filter whose category a worker cannot import is left out, the others kept in order
    filters.insert(0, ("error", None, "no_such_module:NoWarning", None, 0))
    with warnings.catch_warnings():
        _init_worker(filters)
        assert warnings.filters[0][0] == "error" and warnings.filters[0][2] is DataWarning
        with pytest.raises(DataWarning):
            warnings.warn("a data message", DataWarning, stacklevel=1)
        with warnings.catch_warnings(record=True) as seen:
            warnings.warn("slow", PlanningOverrunWarning, stacklevel=1)
        assert seen == []


def test_stop_pool_interrupts_the_running_episode_and_starts_no_other(tmp_path) -> None:
    grid = _grid()
    cfg = replace(grid.episode, max_duration_s=60.0, progress_bar=False)
    logs = [tmp_path / f"e{i}.mcap" for i in range(3)]
    pool = episode_pool(1)
    futures = [
        pool.submit(_episode_in_worker, grid.robot, "cpu", None, cfg, "itomp", log, 0)
        for log in logs
    ]
    deadline = time.monotonic() + 120.0
    while not logs[0].exists() and time.monotonic() < deadline:  # the first has begun
        time.sleep(0.05)
    time.sleep(1.0)
    t0 = time.monotonic()
    stop_pool(pool)
    assert time.monotonic() - t0 < 8.0  # an episode of up to 60 s was not waited for
    assert not futures[0].cancelled()
    with pytest.raises(KeyboardInterrupt):
        futures[0].result()
    # the episode queued in the worker did not start, the one waiting here was cancelled
    assert not logs[1].exists() and not logs[2].exists()
    assert futures[2].cancelled()
    # the interrupted episode's log reads up to where it stopped
    assert read_episode(logs[0]).frames["/robot/joint_state"].shape[0] > 0


#: a process that another pool started, as a job of a sweep on hydra/launcher=joblib is (its
#: start method joblib's loky, which a fresh Python does not know), runs a grid in workers
_NESTED = """
import multiprocessing, sys
from pathlib import Path
import joblib.externals.loky.backend.context  # registers the "loky" start method
multiprocessing.set_start_method("loky", force=True)
from iplanner_torch.eval.episode import EpisodeCfg
from iplanner_torch.eval.experiment import ExperimentCfg, episode_pool, run_experiment
from iplanner_torch.sim.tasks import ScenarioCfg
grid = ExperimentCfg(name="nested", planners=["blind"], seeds=[0, 1],
                     scenarios=[ScenarioCfg(name="s", task_order="0->1->2->3")],
                     episode=EpisodeCfg(max_duration_s=1.0), write_mcap=False)
with episode_pool(2) as pool:
    df = run_experiment(grid, Path(sys.argv[1]), executor=pool)
print(len(df))
"""


def test_workers_start_in_a_process_of_another_pool(tmp_path) -> None:
    import subprocess
    import sys

    res = subprocess.run(
        [sys.executable, "-c", _NESTED, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip().splitlines()[-1] == "2"
