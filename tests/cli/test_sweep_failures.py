"""A multirun whose jobs, summary or folder go wrong still names what failed and exits 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

import iplanner_torch.cli._common as common
from iplanner_torch.cli.callbacks import GatherSweepResults
from iplanner_torch.recording import EpisodeWriter

#: a short ITOMP job per swept value (as tests/cli/test_cli.py runs its sweep)
TINY = ["run.planners=[itomp]", "run.seeds=[0]", "run.max_duration_s=2", "progress=false"]


def _sweep(args: list[str], cwd: Path, script: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    command = [str(script)] if script else ["-m", "iplanner_torch.cli.experiment"]
    return subprocess.run(
        [sys.executable, *command, "-m", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def _job(sweep: Path, num: int, overrides: str) -> Path:
    job = sweep / str(num)
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(f"- {overrides}\n- run.planners=[itomp]\n")
    return job


def test_a_summary_that_cannot_be_written_is_an_error_and_failed_jobs_are_still_named(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """``summary`` is a file of the user's: gathering fails, which Hydra would turn into a
    warning and exit 0 without naming the failed job; now one error line, the failed job
    named, exit 2, and the file kept."""
    sweep = tmp_path / "sweep"
    meta = {"scenario": "s", "planner": "itomp", "noise": 0.0, "speed": "medium", "seed": 0}
    log_path = _job(sweep, 0, "tracker.noise=0") / "episodes" / "e.mcap"
    with EpisodeWriter(log_path, metadata=meta) as log:
        log.metrics(1.0, {"eval/smoothness": 40.0, "eval/min_distance": 0.1})
    failed = "error: ConfigError: tracker.noise: expected in [0, 1] m, got -1.0"
    (_job(sweep, 1, "tracker.noise=-1") / "FAILED").write_text(failed + "\n")
    (sweep / "summary").write_text("notes\n")
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(sweep)}}})

    with pytest.raises(SystemExit) as stop:
        GatherSweepResults().on_multirun_end(config=config)
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith(f"error: DataError: {sweep / 'summary'}: not a folder")
    assert err[0].endswith("is not written; each job's results are in its folder)")
    assert err[1] == "1 of 2 sweep job(s) failed (the others ran):"
    assert err[2] == f"  {sweep / '1'} [tracker.noise=-1 run.planners=[itomp]]: {failed}"
    assert (sweep / "summary").read_text() == "notes\n"
    # no failed job: the summary's error alone still ends the sweep with 2
    (sweep / "1" / "FAILED").unlink()
    with pytest.raises(SystemExit, match="2"):
        GatherSweepResults().on_multirun_end(config=config)
    assert capsys.readouterr().err.startswith("error: DataError: ")


def test_an_unexpected_error_in_a_sweep_job_fails_that_job_alone(tmp_path: Path) -> None:
    """A bug in one job (an exception that is none of the library's): Hydra's sweeper raised
    it again after the jobs, a traceback and exit 1 with no summary and no FAILED file. Now
    the job leaves its line and traceback in FAILED (and its log), the console gets one line,
    the other job is summarised, and the sweep names the job and exits 2."""
    script = tmp_path / "crash.py"
    script.write_text(
        "import iplanner_torch.eval.experiment as E\n"
        "start = E.start_experiment\n"
        "def crash(exp, out, **kw):\n"
        "    if exp.episode.sim.tracker_noise > 0:\n"
        "        raise ValueError('simulated bug')\n"
        "    return start(exp, out, **kw)\n"
        "E.start_experiment = crash\n"
        "from iplanner_torch.cli.experiment import main\n"
        "main()\n"
    )
    sweep = tmp_path / "sweep"
    res = _sweep([f"hydra.sweep.dir={sweep}", "tracker.noise=0,0.02", *TINY], tmp_path, script)
    assert res.returncode == 2, res.stderr[-3000:]
    assert "Traceback" not in res.stderr
    marker = sweep / "1" / "FAILED"
    line = (
        f"error: ValueError: simulated bug (unexpected: job {sweep / '1'} stopped, traceback "
        f"in {marker})"
    )
    err = res.stderr.strip().splitlines()
    assert err[0] == line
    assert err[1:] == [
        "1 of 2 sweep job(s) failed (the others ran):",
        f"  {sweep / '1'} [tracker.noise=0.02 {' '.join(TINY[:-1])} progress=False]: {line}",
    ]
    text = marker.read_text()
    assert text.startswith(line + "\nTraceback (most recent call last):")
    assert text.rstrip().endswith("ValueError: simulated bug")
    log = (sweep / "1" / "experiment.log").read_text()
    assert line in log and "raise ValueError('simulated bug')" in log
    assert (sweep / "0" / "results.csv").exists()
    assert (sweep / "summary" / "results.csv").exists()


def test_an_unexpected_error_outside_a_sweep_keeps_its_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A single run raises the bug again (Hydra prints its traceback); in a sweep job it ends
    the job with a FAILED file, a RuntimeError that is not out of memory as well."""

    @common.friendly_errors
    def bug(kind: type[Exception]) -> None:
        raise kind("simulated bug")

    monkeypatch.setattr(common, "multirun_job_dir", lambda: None)
    with pytest.raises(ValueError, match="simulated bug"):
        bug(ValueError)
    job = tmp_path / "3"
    job.mkdir()
    monkeypatch.setattr(common, "multirun_job_dir", lambda: job)
    for kind in (KeyError, RuntimeError):
        assert bug(kind) is None
        first, trace = (job / common.FAILED_MARKER).read_text().split("\n", 1)
        assert first.startswith(f"error: {kind.__name__}: ") and str(job) in first
        assert trace.startswith("Traceback") and "simulated bug" in trace


def test_running_out_of_memory_in_a_sweep_job_fails_that_job_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """Its SystemExit(2) ended the whole sweep, with no summary; now the job's FAILED file
    keeps the line (as for a library error) and the sweep goes on."""

    @common.friendly_errors
    def job() -> None:
        raise MemoryError

    monkeypatch.setattr(common, "multirun_job_dir", lambda: tmp_path)
    assert job() is None
    line = capsys.readouterr().err.strip()
    assert line.startswith("error: out of memory (MemoryError); lower planner.optimizer")
    assert (tmp_path / common.FAILED_MARKER).read_text() == line + "\n"


def test_a_sweep_into_a_folder_with_results_is_refused_before_hydra_writes(
    tmp_path: Path,
) -> None:
    """Hydra rewrote the job folders' .hydra/ records before each job refused to replace its
    results, and the summary then labelled the old episodes with the new overrides; now the
    sweep is refused before any job starts, and the folder is untouched."""
    sweep = tmp_path / "sweep"
    job = _job(sweep, 0, "tracker.noise=0")
    for name in ("config.yaml", "hydra.yaml"):
        (job / ".hydra" / name).write_text("earlier: true\n")
    (job / "results.csv").write_text("planner,smoothness\nitomp,40\n")
    (_job(sweep, 1, "tracker.noise=-1") / "FAILED").write_text("error: ConfigError: x\n")
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in sweep.rglob("*") if p.is_file()}

    res = _sweep([f"hydra.sweep.dir={sweep}", "tracker.noise=0.05,0.1", *TINY], tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        f"error: ConfigError: {sweep} already holds the results of an earlier sweep (job "
        "folder(s) 0), whose .hydra/ records this sweep would overwrite; choose another "
        "hydra.sweep.dir (or delete it)"
    ]
    after = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in sweep.rglob("*") if p.is_file()}
    assert after == before


def test_a_sweep_folder_with_failed_jobs_alone_may_be_run_again(tmp_path: Path) -> None:
    """The README's flow: a sweep whose jobs all failed before writing results is run again
    into the same hydra.sweep.dir (each job then removes its earlier FAILED)."""
    sweep = tmp_path / "sweep"
    (_job(sweep, 0, "tracker.noise=-1") / "FAILED").write_text("error: ConfigError: x\n")
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(sweep)}, "sweeper": {}}})
    GatherSweepResults().on_multirun_start(config=config)  # no SystemExit
    (sweep / "0" / "episodes").mkdir()
    with pytest.raises(SystemExit, match="2"):
        GatherSweepResults().on_multirun_start(config=config)


def test_a_sweep_whose_jobs_all_failed_does_not_say_the_others_ran(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    sweep = tmp_path / "sweep"
    for num, value in enumerate(("-1", "-2")):
        failed = f"error: ConfigError: tracker.noise: expected in [0, 1] m, got {value}"
        (_job(sweep, num, f"tracker.noise={value}") / "FAILED").write_text(failed + "\n")
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(sweep)}}})
    with pytest.raises(SystemExit) as stop:
        GatherSweepResults().on_multirun_end(config=config)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "all 2 sweep job(s) failed:" in err and "the others ran" not in err
