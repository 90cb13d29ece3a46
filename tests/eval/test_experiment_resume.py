"""A grid run that stopped, continued with ``run_experiment(..., resume=True)``: checked
against the same grid run at once, start to end (an independent run, not the resumed code's
own output)."""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import pandas as pd
import pytest

import iplanner_torch.eval.experiment as experiment_mod
from iplanner_torch.errors import ConfigError, DataError, DataWarning
from iplanner_torch.eval.episode import EpisodeCfg
from iplanner_torch.eval.experiment import (
    ExperimentCfg,
    episode_stem,
    kept_episodes,
    read_finished,
    run_experiment,
    set_aside,
)
from iplanner_torch.eval.report import episode_logs, gather_results
from iplanner_torch.sim.tasks import ScenarioCfg

#: the columns that measure this machine's speed, not the episode
TIMING = ("sim/realtime_factor", "plan/mean_solve_ms", "eval/prediction_ms", "plan/overruns")


def _grid() -> ExperimentCfg:
    """Two planners that need no predictor, two seeds, 2 simulated seconds each."""
    return ExperimentCfg(
        name="resume",
        planners=["itomp", "blind"],
        seeds=[0, 1],
        scenarios=[ScenarioCfg(name="s", task_order="0->1->2->3")],
        episode=EpisodeCfg(max_duration_s=2.0),
    )


def _episode_columns(df: pd.DataFrame) -> list[str]:
    return [c for c in df.columns if c not in TIMING]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pd.DataFrame]:
    out = tmp_path_factory.mktemp("full")
    return out, run_experiment(_grid(), out)


def _stop_after_first(full: Path, tmp: Path) -> Path:
    """A copy of the full run as if it had stopped during its second episode and then lost
    the log of its third: one row; the second episode's log cut short; the fourth's log whole
    (the run stopped after writing it, before its row) with its timeline plot beside it."""
    run = tmp / "run"
    shutil.copytree(full, run)
    df = pd.read_csv(run / "results.csv")
    df.iloc[:1].to_csv(run / "results.csv", index=False)
    logs = run / "episodes"
    cut = logs / f"{episode_stem('s', 'medium', 0.01, 'itomp', 1)}.mcap"
    os.truncate(cut, cut.stat().st_size // 2)
    (logs / f"{episode_stem('s', 'medium', 0.01, 'blind', 0)}.mcap").unlink()
    (logs / f"{episode_stem('s', 'medium', 0.01, 'blind', 1)}.png").write_bytes(b"plot")
    return run


def test_resumed_run_equals_the_run_made_at_once(full_run, tmp_path, monkeypatch) -> None:
    full, expected = full_run
    run = _stop_after_first(full, tmp_path)
    kept_log = run / "episodes" / f"{episode_stem('s', 'medium', 0.01, 'itomp', 0)}.mcap"
    kept_time = kept_log.stat().st_mtime_ns
    ran: list[tuple[str, int]] = []
    real = experiment_mod.run_episode

    def counting(cfg, *, planner_kind, seed, **kw):
        ran.append((planner_kind, seed))
        return real(cfg, planner_kind=planner_kind, seed=seed, **kw)

    monkeypatch.setattr(experiment_mod, "run_episode", counting)
    assert set(kept_episodes(_grid(), run)) == {episode_stem("s", "medium", 0.01, "itomp", 0)}
    done: list[int] = []
    got = run_experiment(_grid(), run, resume=True, on_done=done.append)
    # the finished episode is kept, the other three run again
    assert ran == [("itomp", 1), ("blind", 0), ("blind", 1)]
    assert done == [1, 1, 1, 1]  # the kept one, then each run
    assert kept_log.stat().st_mtime_ns == kept_time
    cols = _episode_columns(expected)
    pd.testing.assert_frame_equal(got[cols], expected[cols], check_dtype=False)
    on_disk = pd.read_csv(run / "results.csv")
    pd.testing.assert_frame_equal(on_disk[cols], pd.read_csv(full / "results.csv")[cols])
    # the two logs without a row are set aside (the plot with its log), not overwritten
    aside = sorted(p.name for p in (run / "interrupted").iterdir())
    assert aside == [
        f"{episode_stem('s', 'medium', 0.01, 'blind', 1)}.mcap",
        f"{episode_stem('s', 'medium', 0.01, 'blind', 1)}.png",
        f"{episode_stem('s', 'medium', 0.01, 'itomp', 1)}.mcap",
    ]
    assert (run / "interrupted" / aside[1]).read_bytes() == b"plot"
    assert len(list((run / "episodes").glob("*.mcap"))) == 4
    # folder reads leave the set-aside logs out: four episodes, not six
    assert len(episode_logs(run)) == 4
    assert len(gather_results(run)) == 4


def test_a_finished_run_resumed_runs_nothing(full_run, tmp_path, monkeypatch) -> None:
    full, expected = full_run
    run = tmp_path / "run"
    shutil.copytree(full, run)
    # as the CLI leaves it: the table rewritten by the report, metrics without "eval/"
    gather_results(expected.to_dict("records")).to_csv(run / "results.csv", index=False)
    monkeypatch.setattr(experiment_mod, "run_episode", None)  # calling it would fail
    done: list[int] = []
    got = run_experiment(_grid(), run, resume=True, on_done=done.append)
    assert done == [4]
    cols = _episode_columns(expected)
    pd.testing.assert_frame_equal(got[cols], expected[cols], check_dtype=False)
    assert not (run / "interrupted").exists()


def test_read_finished_keeps_text_and_names(tmp_path) -> None:
    csv = tmp_path / "results.csv"
    pd.DataFrame(
        [
            {"planner": "itomp", "scenario": "b", "task_order": "0", "speed": "fast",
             "noise": 0.0, "seed": 3, "smoothness": 1.5, "sim/contacts": 0},
        ]
    ).to_csv(csv, index=False)  # fmt: skip
    (row,) = read_finished(csv).values()
    assert row["task_order"] == "0" and row["eval/smoothness"] == 1.5
    assert row["sim/contacts"] == 0 and "smoothness" not in row
    assert read_finished(csv).keys() == {episode_stem("b", "fast", 0.0, "itomp", 3)}
    assert read_finished(tmp_path / "none.csv") == {}


def test_read_finished_leaves_out_a_last_row_cut_short(tmp_path) -> None:
    """A table without its last line end was cut short while written (even a row with every
    cell may end in a cut number): that row's episode runs again, with a warning."""
    csv = tmp_path / "results.csv"
    head = "planner,scenario,speed,noise,seed,smoothness\n"
    whole = "itomp,s,medium,0.0,0,1.5\n"
    csv.write_text(head + whole + "itomp,s,medium,0.0,1,2.25")
    with pytest.warns(DataWarning, match="no line end.*run again"):
        got = read_finished(csv)
    assert got.keys() == {episode_stem("s", "medium", 0.0, "itomp", 0)}
    csv.write_text(head + whole)  # the same table whole: no warning, both ways
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_finished(csv).keys() == got.keys()
    csv.write_text(head.rstrip("\n"))  # a header alone: nothing finished, nothing dropped
    assert read_finished(csv) == {}


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("planner,scenario,speed,seed\nitomp,s,medium,0\n", "no column noise"),
        ("planner,scenario,speed,noise,seed\nitomp,s,medium,0.01,x\n", "a row without"),
        (
            "planner,scenario,speed,noise,seed\nitomp,s,medium,0.01,0\nitomp,s,medium,0.01,0\n",
            "has two rows",
        ),
        ('planner,scenario\n"itomp,s\n', "not a results table"),
    ],
)
def test_read_finished_refuses_bad_tables(tmp_path, text, match) -> None:
    csv = tmp_path / "results.csv"
    csv.write_text(text)
    with pytest.raises(DataError, match=match):
        read_finished(csv)


def test_resume_refuses_another_grid(full_run, tmp_path) -> None:
    full, _ = full_run
    run = tmp_path / "run"
    shutil.copytree(full, run)
    from dataclasses import replace

    with pytest.raises(ConfigError, match=r"holds episodes that are not in this grid \(s_"):
        run_experiment(replace(_grid(), seeds=[0]), run, resume=True)


def test_set_aside_numbers_a_taken_name(tmp_path) -> None:
    folder = tmp_path / "episodes"
    folder.mkdir()
    aside = tmp_path / "interrupted"
    for i in range(3):
        (folder / "a_s0.mcap").write_text(f"log {i}")
        (folder / "a_s0.png").write_text(f"plot {i}")
        (folder / "a_s0x.mcap").write_text("another episode")
        moved = set_aside(folder / "a_s0.mcap", aside)
        assert moved.read_text() == f"log {i}"
        assert moved.with_suffix(".png").read_text() == f"plot {i}"
    assert sorted(p.name for p in aside.iterdir()) == [
        "a_s0.1.mcap", "a_s0.1.png", "a_s0.2.mcap", "a_s0.2.png", "a_s0.mcap", "a_s0.png",
    ]  # fmt: skip
    assert (folder / "a_s0x.mcap").read_text() == "another episode"
    # a file of the stem with two suffixes (a writer's temporary) is not the episode's
    (folder / "a_s0.mcap").write_text("log")
    (folder / "a_s0.mcap.tmp").write_text("temporary")
    set_aside(folder / "a_s0.mcap", aside)
    assert (folder / "a_s0.mcap.tmp").read_text() == "temporary"


def test_episode_stems_tell_noise_levels_apart() -> None:
    """Every noise level of a grid names its own logs (0.01 and 0.02 would both be 'n0.0'
    with one decimal, and their logs would overwrite each other)."""
    stems = {episode_stem("s", "medium", n, "itomp", 0) for n in (0.0, 0.005, 0.01, 0.02, 0.1)}
    assert len(stems) == 5
    assert episode_stem("s", "medium", 0.01, "itomp", 3) == "s_medium_n0.01_itomp_s3"


def test_results_written_whole_or_not_at_all(tmp_path, monkeypatch) -> None:
    path = tmp_path / "results.csv"
    experiment_mod._write_rows([{"a": 1}], path)
    before = path.read_text()

    def broken(self, target, **kw):
        Path(target).write_text("a\n2\n3")  # part of the table, then the process dies
        raise KeyboardInterrupt

    monkeypatch.setattr(pd.DataFrame, "to_csv", broken)
    with pytest.raises(KeyboardInterrupt):
        experiment_mod._write_rows([{"a": 2}, {"a": 3}, {"a": 4}], path)
    assert path.read_text() == before


def test_without_logs_the_rows_alone_are_kept(full_run, tmp_path, monkeypatch) -> None:
    """A grid that writes no logs keeps every finished row (there is no log to ask for); one
    that writes them runs an episode again whose log is gone."""
    from dataclasses import replace

    full, expected = full_run
    run = tmp_path / "run"
    shutil.copytree(full, run)
    shutil.rmtree(run / "episodes")
    assert kept_episodes(_grid(), run) == {}
    no_logs = replace(_grid(), write_mcap=False)
    assert len(kept_episodes(no_logs, run)) == 4
    monkeypatch.setattr(experiment_mod, "run_episode", None)  # calling it would fail
    got = run_experiment(no_logs, run, resume=True)
    cols = _episode_columns(expected)
    pd.testing.assert_frame_equal(got[cols], expected[cols], check_dtype=False)
