"""``iplanner-evaluate evaluate.mode=episode`` on the sources it is given: a sweep's summary CSV
keeps the swept overrides apart, a run reached twice below one folder is said to repeat while
the jobs of a sweep are not, and ``.mcap`` files that are not episode logs are left out of a
folder (named) and refused when given by their path."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import pytest
from foreign_mcap import write_foreign_mcap
from hydra import compose

import iplanner_torch.cli.evaluate as evaluate
from iplanner_torch.cli.callbacks import gather_episode_logs
from iplanner_torch.errors import DataError, DataWarning
from iplanner_torch.recording import EpisodeWriter

#: every test composes the project's config (conftest.hydra_conf)
pytestmark = pytest.mark.usefixtures("hydra_conf")


def _evaluate(
    monkeypatch: pytest.MonkeyPatch, logs: Path | str, out: Path
) -> list[warnings.WarningMessage]:
    """Run ``iplanner-evaluate evaluate.mode=episode evaluate.logs=<logs>`` in this process
    (the overrides as its command line); the warnings it gave."""
    overrides = ["evaluate.mode=episode", f"evaluate.logs={logs}", f"evaluate.out_dir={out}"]
    monkeypatch.setattr(evaluate, "_task_overrides", lambda: list(overrides))
    cfg = compose(config_name="config", overrides=["progress=false", *overrides])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        evaluate._episode(cfg)
    return caught


def _log(path: Path, seed: int, smoothness: float, planner: str = "itomp") -> None:
    meta = {"scenario": "s", "planner": planner, "speed": "medium", "seed": seed}
    with EpisodeWriter(path, metadata=meta) as log:
        log.metrics(1.0, {"eval/smoothness": smoothness, "eval/min_distance": 0.1})


def _sweep(root: Path) -> Path:
    """The folder of ``-m planner.itomp_spread_mps=0,0.1 run.seeds=[0,1]``: two jobs, each
    with two seeds, and its ``summary/`` as the sweep's callback writes it."""
    for job, spread, smooth in ((0, "0", (40.0, 44.0)), (1, "0.1", (60.0, 70.0))):
        (root / str(job) / ".hydra").mkdir(parents=True)
        (root / str(job) / ".hydra" / "overrides.yaml").write_text(
            f"- planner.itomp_spread_mps={spread}\n- run.seeds=[0,1]\n"
        )
        for seed in (0, 1):
            _log(root / str(job) / "episodes" / f"s{seed}.mcap", seed, smooth[seed])
    gather_episode_logs(root, root / "summary")
    return root


def _summary_rows(out: Path) -> list[str]:
    """The rows of results.md's mean ± std table."""
    summary = (out / "results.md").read_text().split("## Mean ± std")[1]
    return [ln for ln in summary.splitlines() if ln.startswith("| s |")]


def _repeats(caught: list[warnings.WarningMessage]) -> list[str]:
    return [str(w.message) for w in caught if "episodes repeat the settings" in str(w.message)]


def test_a_baseline_without_two_shared_seeds_is_said_to_be_unpaired(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """``evaluate.logs=[a,b] evaluate.labels=[held,spread] evaluate.baseline=itomp@spread``
    with one seed per run wrote no "Paired by seed" section and printed nothing about it."""
    for run in ("a", "b"):
        for planner in ("itomp", "iplanner_ni"):
            _log(tmp_path / run / "episodes" / f"{planner}.mcap", 0, 40.0, planner=planner)
    logs = f"[{tmp_path / 'a' / 'episodes'},{tmp_path / 'b' / 'episodes'}]"
    overrides = ["evaluate.mode=episode", f"evaluate.logs={logs}",
                 "evaluate.labels=[held,spread]", "evaluate.baseline=itomp@spread",
                 f"evaluate.out_dir={tmp_path / 'out'}"]  # fmt: skip
    monkeypatch.setattr(evaluate, "_task_overrides", lambda: list(overrides))
    evaluate._episode(compose(config_name="config", overrides=["progress=false", *overrides]))
    said = (
        "paired comparison skipped: needs at least 2 seeds shared by itomp@spread and another "
        "planner in one setting; found 1"
    )
    assert said in capsys.readouterr().out.splitlines()
    md = (tmp_path / "out" / "results.md").read_text()
    assert "## Paired by seed\n\nP" + said[1:] + "." in md


def test_a_sweep_summary_csv_keeps_its_swept_override_apart(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The summary CSV's ``planner.itomp_spread_mps`` column was pooled into one row: it is
    kept apart (in results.md and the printed table) as when the sweep folder is read."""
    sweep = _sweep(tmp_path / "sweep")
    caught = _evaluate(monkeypatch, sweep / "summary" / "results.csv", tmp_path / "from_csv")
    rows = _summary_rows(tmp_path / "from_csv")
    assert len(rows) == 2
    assert "| 0 | itomp | 2 |" in rows[0] and "| 42.0 ± 2.83 |" in rows[0]
    assert "| 0.1 | itomp | 2 |" in rows[1] and "| 65.0 ± 7.07 |" in rows[1]
    printed = capsys.readouterr().out
    assert "planner.itomp_spread_mps" in printed.splitlines()[0]
    assert not _repeats(caught)
    _evaluate(monkeypatch, sweep, tmp_path / "from_folder")
    assert _summary_rows(tmp_path / "from_folder") == rows


def test_a_run_reached_twice_below_one_folder_is_said_to_repeat(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``cp -r run mix/a; cp -r run mix/b; evaluate.logs=mix`` counted every episode twice
    without a word; a sweep folder, whose jobs differ in an override, gives no warning, nor
    do jobs that split the seeds (``-m planner.itomp_spread_mps=0,0.1
    'run.seeds=[0],[1]'``, the shape of the callbacks' sweep test)."""
    run = tmp_path / "run"
    for seed in (0, 1):
        _log(run / "episodes" / f"s{seed}.mcap", seed, 40.0 + seed)
    for copy in ("a", "b"):
        shutil.copytree(run, tmp_path / "mix" / copy)
    caught = _evaluate(monkeypatch, tmp_path / "mix", tmp_path / "out_mix")
    assert len(_repeats(caught)) == 1
    assert _repeats(caught)[0].startswith("2 of the 4 episodes repeat the settings")
    assert "copied twice below one folder" in _repeats(caught)[0]
    assert not _repeats(_evaluate(monkeypatch, run, tmp_path / "out_run"))
    assert not _repeats(_evaluate(monkeypatch, _sweep(tmp_path / "sweep"), tmp_path / "out_sw"))
    split = tmp_path / "split"
    for job, (spread, seed) in enumerate((("0", 0), ("0", 1), ("0.1", 0), ("0.1", 1))):
        (split / str(job) / ".hydra").mkdir(parents=True)
        (split / str(job) / ".hydra" / "overrides.yaml").write_text(
            f"- planner.itomp_spread_mps={spread}\n- run.seeds=[{seed}]\n- seed={job}\n"
        )
        _log(split / str(job) / "episodes" / "e.mcap", seed, 40.0 + job)
    assert not _repeats(_evaluate(monkeypatch, split, tmp_path / "out_split"))
    assert len(_summary_rows(tmp_path / "out_split")) == 2


def test_mcap_files_that_are_not_episode_logs_are_left_out_of_a_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An unfetched Git LFS pointer (``text.mcap``) in a folder ended the whole report with
    ``DataError: ... is not an MCAP file``: it and another program's MCAP file are left out,
    named in one warning, and the logs are reported. A folder of nothing but such files, and
    either file given by its path, are refused, saying what they are."""
    logs = tmp_path / "logs"
    for seed in (0, 1):
        _log(logs / f"s{seed}.mcap", seed, 40.0 + seed)
    text = logs / "text.mcap"
    text.write_text("version https://git-lfs.github.com/spec/v1\noid sha256:ab\nsize 9\n")
    foreign = write_foreign_mcap(logs / "foreign.mcap")
    caught = _evaluate(monkeypatch, logs, tmp_path / "out")
    left_out = [w for w in caught if "left out" in str(w.message)]
    assert len(left_out) == 1 and left_out[0].category is DataWarning
    message = str(left_out[0].message)
    assert message.startswith(f"{logs}: left out 2 of its 4 .mcap file(s)")
    assert f"{text} is not an MCAP file" in message
    assert f"{foreign}: not an iplanner episode log" in message
    assert not any("truncated or damaged" in str(w.message) for w in caught)
    rows = _summary_rows(tmp_path / "out")
    assert len(rows) == 1 and "| itomp | 2 |" in rows[0]
    bad = tmp_path / "bad"
    bad.mkdir()
    shutil.copy(text, bad / "text.mcap")
    shutil.copy(foreign, bad / "foreign.mcap")
    with pytest.raises(DataError, match="bad: none of its .mcap files is a readable episode log"):
        _evaluate(monkeypatch, bad, tmp_path / "out_bad")
    with pytest.raises(DataError, match=r"foreign.mcap: not an iplanner episode log \(a valid"):
        _evaluate(monkeypatch, foreign, tmp_path / "out_foreign")
    with pytest.raises(DataError, match="text.mcap is not an MCAP file"):
        _evaluate(monkeypatch, text, tmp_path / "out_text")


def test_one_results_csv_is_checked_as_a_folder_is(monkeypatch, tmp_path: Path) -> None:
    """A single results CSV whose rows repeat an episode (two tables pasted together) is
    warned about as two sources are; a ``completed`` that is no number and a negative count
    or efficiency are read as missing, each with a warning, not counted or averaged."""
    head = "planner,scenario,speed,seed,smoothness,efficiency,sim/contacts,completed\n"
    rows = ["itomp,s,medium,0,1.0,1.5,0,1\n", "itomp,s,medium,1,2.0,1.6,0,1\n"]
    twice = tmp_path / "twice.csv"
    twice.write_text(head + "".join(rows + rows))
    caught = _evaluate(monkeypatch, twice, tmp_path / "out1")
    assert any("2 of the 4 episodes repeat the settings" in str(w.message) for w in caught)
    bad = tmp_path / "bad.csv"
    bad.write_text(head + rows[0] + "itomp,s,medium,1,2.0,-1,-3,maybe\n")
    caught = _evaluate(monkeypatch, bad, tmp_path / "out2")
    said = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
    assert any("value(s) of 'completed' are not numbers" in m for m in said), said
    assert any("value(s) of 'efficiency' are negative" in m for m in said), said
    assert any("value(s) of 'sim/contacts' are negative" in m for m in said), said
    assert not any("repeat the settings" in m for m in said)
    import pandas as pd

    back = pd.read_csv(tmp_path / "out2" / "results.csv")
    assert back["efficiency"].tolist()[0] == 1.5 and pd.isna(back["efficiency"].tolist()[1])
    assert pd.isna(back["sim/contacts"].tolist()[1]) and pd.isna(back["completed"].tolist()[1])
