"""The console scripts run end to end on tiny settings (in a temporary working directory)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

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
    import shlex

    out = tmp_path / "ds"
    args = [
        "iplanner-data",
        "generate",
        f"data.path={out}",
        "data.generator.reaches_per_target=1",
        "data.generator.speeds=[1.0]",  # a shell glob unless quoted
        "progress=false",
    ]
    res = _run(args, tmp_path)
    assert res.returncode == 0, res.stderr
    assert "wrote 8 demonstrations" in res.stdout
    assert len(load_demonstrations(out)) == 8
    # the card's command, pasted into a shell, gives the same arguments
    card = (out / "README.md").read_text().splitlines()
    command = card[card.index("Regenerate with:") + 3]
    assert shlex.split(command) == args, command
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
    # a generator setting is checked as training checks it (it was accepted unread)
    res = _run(["iplanner-data", "info", "data.generator.reaches_per_target=abc"], tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip() == (
        "error: ConfigError: data.generator.reaches_per_target: expected int, got 'abc'"
    )


def test_data_generate_refuses_existing_dataset_then_overwrites(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    gen = ["iplanner-data", "generate", f"data.path={out}", "progress=false"]
    res = _run([*gen, "data.generator.reaches_per_target=2"], tmp_path)
    assert res.returncode == 0, res.stderr
    (out / "notes.txt").write_text("mine")
    res = _run([*gen, "data.generator.reaches_per_target=1"], tmp_path)
    assert res.returncode == 2 and "wrote" not in res.stdout
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: ConfigError: {out} already holds 16")
    assert "data.overwrite=true" in lines[0]
    assert len(load_demonstrations(out)) == 16
    res = _run([*gen, "data.generator.reaches_per_target=1", "data.overwrite=true"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert "deleted 16 earlier demonstration files and its dataset card" in res.stdout
    assert "wrote 8 demonstrations" in res.stdout
    assert len(load_demonstrations(out)) == 8 and (out / "notes.txt").read_text() == "mine"
    assert "| demonstrations | 8 |" in (out / "README.md").read_text()
    res = _run(["iplanner-data", "info", f"data.path={out}"], tmp_path)
    assert res.returncode == 0 and f"{out}: 8 demonstrations" in res.stdout
    res = _run([*gen, "data.overwrite=yes"], tmp_path)
    assert res.returncode == 2 and "data.overwrite: expected true or false" in res.stderr


def test_data_help_anywhere_lists_commands_and_options(tmp_path: Path) -> None:
    import dataclasses

    from iplanner_torch.data.reaching import ReachingCfg
    from iplanner_torch.data.tasks import TaskDatasetCfg

    conf = Path(__file__).resolve().parents[2] / "conf" / "data"
    for args in (["-h"], ["--help"], ["-h", "generate"], ["generate", "--help"],
                 ["info", "data.path=x", "-h"]):  # fmt: skip
        res = _run(["iplanner-data", *args], tmp_path)
        assert res.returncode == 0, (args, res.stderr)
        assert res.stderr == "" and "Traceback" not in res.stdout
        assert "generate" in res.stdout and "info" in res.stdout
    text = res.stdout
    assert "convert" not in text and "``" not in text
    options = sorted(p.stem for p in conf.glob("*.yaml"))
    assert f"data={'|'.join(sorted(options, key=text.index))}" in text
    for key in (
        "data.path=",
        "paths.datasets=",
        "data.overwrite=true",
        "data.generator.",
        "data.windows.joints",
    ):
        assert key in text
    for kind, cfg in (("reaching", ReachingCfg), ("tasks", TaskDatasetCfg)):
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(f"{kind}: "))
        named = [n.strip() for n in line.split(":", 1)[1].split(",") if n.strip()]
        fields = {f.name for f in dataclasses.fields(cfg)}
        assert named and set(named) <= fields, (kind, set(named) - fields)


def test_data_info_names_the_files_training_would_reject(tmp_path: Path) -> None:
    import numpy as np

    from iplanner_torch.data.io import save_demonstration

    out = tmp_path / "ds"
    res = _run(["iplanner-data", "generate", f"data.path={out}",
                "data.generator.reaches_per_target=1", "progress=false"], tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr
    files = sorted(out.glob("*.npz"))
    demos = load_demonstrations(out)
    demos[2].positions[:, 0] = np.nan  # head lost in every frame: reported, not rejected
    save_demonstration(demos[2], files[2])
    res = _run(["iplanner-data", "info", f"data.path={out}"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert "joints NaN in every frame in 1 file(s)" in res.stdout
    assert f"    {files[2]}: head\n" in res.stdout
    demos[5].positions[:] = np.nan  # nothing observed: training cannot use it
    save_demonstration(demos[5], files[5])
    res = _run(["iplanner-data", "info", f"data.path={out}"], tmp_path)
    assert res.returncode == 2
    assert res.stderr.startswith(f"error: DataError: {files[5]}: field 'positions' is NaN in")
    files[5].unlink()
    save_demonstration(demos[6].select_joints(["right_hand", "head"]), files[6])
    res = _run(["iplanner-data", "info", f"data.path={out}"], tmp_path)
    assert res.returncode == 2
    assert res.stderr.startswith(f"error: DataError: {files[6]}: field 'joint_names' ")
    assert "['right_hand', 'head']" in res.stderr and f"of {files[0]}" in res.stderr
    # training selects joints with data.windows.joints; info then checks those alone
    res = _run(["iplanner-data", "info", f"data.path={out}",
                "data.windows.joints=[head,right_hand]"], tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "7 demonstrations" in res.stdout and "joints (2): head, right_hand" in res.stdout
    # one file at another frame rate: the cross-file check training makes
    from dataclasses import replace

    save_demonstration(replace(demos[3], fps=30.0, timestamps=None), files[3])
    res = _run(["iplanner-data", "info", f"data.path={out}",
                "data.windows.joints=[head,right_hand]"], tmp_path)  # fmt: skip
    assert res.returncode == 2
    assert f"error: DataError: demonstration '{files[3].stem}': fps 30.0 differs" in res.stderr


def test_data_missing_folder_errors_say_how_to_fix(tmp_path: Path) -> None:
    res = _run(["iplanner-data", "info", "data=lego"], tmp_path)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "no such file or folder" in lines[0]
    assert "set data.path=" in lines[0]
    res = _run(["iplanner-data", "info", "data.path=nope"], tmp_path)
    assert res.returncode == 2
    assert "`iplanner-data generate data.path=nope`" in res.stderr


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
    # the key under the table says what its columns are, in their units
    assert "\nkey (episode counts, then means over episodes" in res.stdout
    assert re.search(r"\n  distance cm +closest distance of the sphere models \[cm\]", res.stdout)
    mcaps = sorted((tmp_path / "run" / "episodes").glob("*.mcap"))
    assert len(mcaps) == 1
    episode = read_episode(mcaps[0])
    t, q = episode.robot_q()
    assert q.shape[-1] == 7 and len(t) > 10
    # its timeline plot beside it (run.timeline_plots defaults to true)
    assert mcaps[0].with_suffix(".png").stat().st_size > 10_000
    assert "and 1 timeline plot(s) beside them" in res.stdout
    assert f"logs:    1 MCAP episode log(s) in {tmp_path / 'run' / 'episodes'}" in res.stdout
    assert (tmp_path / "run" / "results.md").exists()
    log = (tmp_path / "run" / "experiment.log").read_text()
    assert "experiment 'main': 1 episode(s)" in log and "smoothness" in log
    assert f"results: {tmp_path / 'run' / 'results.md'}" in log and "done in" in log
    # the same folder again: refused before anything is replaced
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "run").rglob("*") if p.is_file()}
    res = _run(["iplanner-experiment", "run.planners=[itomp]", "run.max_duration_s=3",
                "progress=false", f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)  # fmt: skip
    assert res.returncode == 2
    assert "already holds results.csv and episodes of an earlier run" in res.stderr
    # refused before Hydra starts: the earlier run's .hydra/ files and log are untouched too
    after = {p: p.stat().st_mtime_ns for p in (tmp_path / "run").rglob("*") if p.is_file()}
    assert after == before


def test_error_line_reaches_the_job_log(tmp_path: Path) -> None:
    res = _run(["iplanner-experiment", "run.planners=[nope]", "progress=false",
                f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)  # fmt: skip
    assert res.returncode == 2
    line = "error: ConfigError: run.planners: unknown planners ['nope']"
    assert line in res.stderr
    assert line in (tmp_path / "run" / "experiment.log").read_text()


@pytest.mark.slow
def test_main_job_default(tmp_path: Path) -> None:
    """The README's main command on its embedded default (trains two small predictors)."""
    res = _run(["iplanner-experiment", "progress=false"], tmp_path, timeout=1200)
    assert res.returncode == 0, res.stderr[-3000:]
    for planner in ("itomp", "iplanner_no_ni", "iplanner_ni"):
        assert planner in res.stdout


def test_evaluate_episode_table_counts_a_truncated_log_as_unknown(tmp_path: Path) -> None:
    """``iplanner-evaluate evaluate.mode=episode`` on one good and one truncated log prints the
    experiment's columns (cm) and counts the cut episode neither as contact-free nor contact."""
    import numpy as np

    from iplanner_torch.recording import EpisodeWriter

    g = np.random.default_rng(0)
    logs = tmp_path / "logs"
    for name in ("good", "cut"):
        path = logs / f"{name}.mcap"
        with EpisodeWriter(path, metadata={"scenario": "s1", "planner": "itomp"},
                           chunk_size=8 * 1024) as log:  # fmt: skip
            for i in range(2000):
                log.robot_state(i / 15, g.normal(size=7), g.normal(size=7), list("abcdefg"))
            log.metrics(
                2000 / 15,
                {"eval/contact": 0.0, "eval/min_distance": 0.0604, "eval/mhd": 0.0458,
                 "eval/completed": 1.0},
            )  # fmt: skip
    os.truncate(logs / "cut.mcap", int(0.9 * (logs / "cut.mcap").stat().st_size))
    res = _run(["iplanner-evaluate", "evaluate.mode=episode", f"evaluate.logs={logs}",
                f"evaluate.out_dir={tmp_path / 'out'}"], tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    assert "DataWarning" in res.stderr and "cut.mcap: episode log is truncated" in res.stderr
    lines = res.stdout.splitlines()
    at = next(i for i, ln in enumerate(lines) if ln.startswith("scenario"))
    names = [h for h in lines[at].split("  ") if h.strip()]  # headers hold single spaces
    cells = dict(zip((h.strip() for h in names), lines[at + 2].split()))
    assert cells["scenario"] == "s1" and cells["planner"] == "itomp"
    assert (cells["episodes"], cells["contact_free"], cells["contact_unknown"]) == ("2", "1", "1")
    assert cells["completed"] == "1"
    assert cells["distance cm"] == "6.04" and cells["MHD cm"] == "4.58"
    assert lines[at + 3].startswith("key (episode counts")  # the key, right under the table
    assert "truncated or damaged episode logs: 1 of 2" in res.stdout


def test_evaluate_episode_reports_a_results_csv(tmp_path: Path) -> None:
    """``evaluate.logs=<results.csv>`` re-reports episode rows (``eval/`` columns, as an
    experiment writes them) with the experiment's table; a CSV without planners is refused."""
    import pandas as pd

    rows = pd.DataFrame(
        {
            "scenario": ["s1"] * 4,
            "planner": ["itomp", "itomp", "iplanner_ni", "iplanner_ni"],
            "seed": [0, 1, 0, 1],
            "eval/smoothness": [40.0, 44.0, 30.0, 34.0],
            "eval/min_distance": [0.05, 0.07, 0.10, 0.12],
            "eval/contact": [0.0] * 4,
            "eval/efficiency": [1.6, 1.7, 1.5, 1.6],
            "eval/completed": [1.0] * 4,
        }
    )
    rows.to_csv(tmp_path / "results.csv", index=False)
    res = _run(["iplanner-evaluate", "evaluate.mode=episode",
                f"evaluate.logs={tmp_path / 'results.csv'}",
                f"evaluate.out_dir={tmp_path / 'out'}"], tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    lines = res.stdout.splitlines()
    at = next(i for i, ln in enumerate(lines) if ln.startswith("scenario"))
    names = [h.strip() for h in lines[at].split("  ") if h.strip()]
    table = {ln.split()[1]: dict(zip(names, ln.split())) for ln in lines[at + 2 : at + 4]}
    assert table["itomp"]["smoothness"] == "42.0" and table["iplanner_ni"]["distance cm"] == "11.0"
    assert table["itomp"]["episodes"] == "2" and table["iplanner_ni"]["contact_free"] == "2"
    assert (tmp_path / "out" / "results.md").is_file()
    rows.drop(columns="planner").to_csv(tmp_path / "bad.csv", index=False)
    res = _run(["iplanner-evaluate", "evaluate.mode=episode",
                f"evaluate.logs={tmp_path / 'bad.csv'}",
                f"evaluate.out_dir={tmp_path / 'out2'}"], tmp_path)  # fmt: skip
    assert res.returncode == 2 and "bad.csv: no 'planner' column" in res.stderr
    (tmp_path / "header.csv").write_text(",".join(rows.columns) + "\n")
    res = _run(["iplanner-evaluate", "evaluate.mode=episode",
                f"evaluate.logs={tmp_path / 'header.csv'}",
                f"evaluate.out_dir={tmp_path / 'out3'}"], tmp_path)  # fmt: skip
    assert res.returncode == 2 and "header.csv: no episode rows; nothing to report" in res.stderr
    # an experiment's run folder as the report folder: its results.csv was replaced
    run = tmp_path / "run"
    (run / "episodes").mkdir(parents=True)
    rows.to_csv(run / "results.csv", index=False)
    before = (run / "results.csv").read_bytes()
    res = _run(["iplanner-evaluate", "evaluate.mode=episode",
                f"evaluate.logs={run / 'results.csv'}", f"evaluate.out_dir={run}"],
               tmp_path)  # fmt: skip
    assert res.returncode == 2, res.stderr[-3000:]
    assert "is the folder of an iplanner-experiment run (it holds episodes/)" in res.stderr
    assert (run / "results.csv").read_bytes() == before and not (run / "results.md").exists()
    # a folder with an earlier report (a sweep's summary/, an evaluate report): kept as it is
    summary = tmp_path / "summary"
    summary.mkdir()
    rows.to_csv(summary / "results.csv", index=False)
    (summary / "compare_smoothness.png").write_bytes(b"png")
    res = _run(["iplanner-evaluate", "evaluate.mode=episode",
                f"evaluate.logs={summary / 'results.csv'}", f"evaluate.out_dir={summary}"],
               tmp_path)  # fmt: skip
    assert res.returncode == 2, res.stderr[-3000:]
    assert (f"error: ConfigError: evaluate.out_dir={summary} already holds "
            "compare_smoothness.png, results.csv of an earlier report") in res.stderr  # fmt: skip
    assert (summary / "results.csv").read_bytes() == before
    assert sorted(p.name for p in summary.iterdir()) == ["compare_smoothness.png", "results.csv"]


def test_evaluate_episode_compares_labelled_runs_seed_by_seed(tmp_path: Path) -> None:
    """Two results CSVs of the same planners: ``evaluate.labels`` keeps the runs apart
    (``itomp@held``, ``itomp@wide``) and ``evaluate.baseline`` is the planner the paired
    section subtracts, seed by seed. Bad labels and an unknown baseline are refused."""
    import pandas as pd

    def run_rows(itomp: list[float], ni: list[float]) -> pd.DataFrame:
        return pd.DataFrame(
            {
                "scenario": ["s1"] * 6,
                "planner": ["itomp"] * 3 + ["iplanner_ni"] * 3,
                "seed": [0, 1, 2] * 2,
                "eval/smoothness": itomp + ni,
                "eval/min_distance": [0.05] * 6,
                "eval/contact": [0.0] * 6,
            }
        )

    run_rows([40.0, 44.0, 42.0], [30.0, 31.0, 35.0]).to_csv(tmp_path / "a.csv", index=False)
    run_rows([60.0, 50.0, 70.0], [30.0, 31.0, 35.0]).to_csv(tmp_path / "b.csv", index=False)
    logs = f"evaluate.logs=[{tmp_path / 'a.csv'},{tmp_path / 'b.csv'}]"
    res = _run(["iplanner-evaluate", "evaluate.mode=episode", logs,
                "evaluate.labels=[held,wide]", "evaluate.baseline=itomp@wide",
                f"evaluate.out_dir={tmp_path / 'out'}"], tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    assert "12 episode(s)" in res.stdout and "itomp@held" in res.stdout
    md = (tmp_path / "out" / "results.md").read_text()
    assert "Each planner minus `itomp@wide`" in md
    rows = {
        tuple(c.strip() for c in ln.strip("|").split("|")[1:3]): ln
        for ln in md.splitlines()
        if ln.startswith("| s1 |")
    }
    # iplanner_ni@held - itomp@wide per seed: -30, -19, -35 (mean -28); itomp@held: -20, -6, -28
    assert "| -28.0 |" in rows[("iplanner_ni@held", "smoothness")]
    assert "| -18.0 |" in rows[("itomp@held", "smoothness")]
    res = _run(["iplanner-evaluate", "evaluate.mode=episode", logs, "evaluate.labels=[held]",
                f"evaluate.out_dir={tmp_path / 'out2'}"], tmp_path)  # fmt: skip
    assert res.returncode == 2 and "evaluate.labels: expected 2 different" in res.stderr
    res = _run(["iplanner-evaluate", "evaluate.mode=episode", logs,
                "evaluate.baseline=itomp@wide", f"evaluate.out_dir={tmp_path / 'out3'}"],
               tmp_path)  # fmt: skip
    assert res.returncode == 2
    assert "evaluate.baseline='itomp@wide': no episodes of that planner" in res.stderr
    assert "['iplanner_ni', 'itomp']" in res.stderr
    # without labels the two runs' rows are counted together, with a warning saying so
    res = _run(["iplanner-evaluate", "evaluate.mode=episode", logs,
                f"evaluate.out_dir={tmp_path / 'out4'}"], tmp_path)  # fmt: skip
    assert res.returncode == 0 and "12 episode(s)" in res.stdout
    assert (
        "DataWarning: 6 of the 12 episodes repeat the settings (planner, scenario, seed) "
        "of another: is a run given twice" in " ".join(res.stderr.split())
    )


def test_evaluate_refuses_bad_paths_before_it_computes(tmp_path: Path) -> None:
    """A file as the output folder, a folder as the checkpoint, logs cut before their
    metadata: one-line errors with exit code 2, and nothing computed first."""
    from iplanner_torch.recording import EpisodeWriter

    (tmp_path / "a_file").write_text("keep me")
    ckpt_dir = tmp_path / "ckpt"
    ckpt_dir.mkdir()
    res = _run(["iplanner-evaluate", f"evaluate.checkpoint={ckpt_dir}"], tmp_path)
    assert res.returncode == 2
    assert f"error: CheckpointError: {ckpt_dir}: is a folder, not a checkpoint file" in res.stderr
    logs = tmp_path / "logs"
    with EpisodeWriter(logs / "a.mcap", metadata={"scenario": "s", "planner": "itomp"}) as log:
        log.robot_state(0.0, [0.0] * 7, [0.0] * 7, list("abcdefg"))
        log.metrics(0.1, {"eval/contact": 0.0})
    res = _run(["iplanner-evaluate", "evaluate.mode=episode", f"evaluate.logs={logs}",
                f"evaluate.out_dir={tmp_path / 'a_file'}"], tmp_path)  # fmt: skip
    assert res.returncode == 2
    assert f"error: ConfigError: evaluate.out_dir={tmp_path / 'a_file'} is a file" in res.stderr
    assert (tmp_path / "a_file").read_text() == "keep me"
    os.truncate(logs / "a.mcap", 20)
    res = _run(["iplanner-evaluate", "evaluate.mode=episode", f"evaluate.logs={logs}",
                f"evaluate.out_dir={tmp_path / 'out'}"], tmp_path)  # fmt: skip
    assert res.returncode == 2
    assert "none of the 1 episode log(s) could be read as far as its metadata" in res.stderr


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_an_interrupted_experiment_keeps_what_it_wrote(tmp_path: Path, sig: str) -> None:
    """Stopped during its second episode: one line, exit 130, the first episode's row and log
    kept, and the second log closed with what it holds and an ``interrupted`` event."""
    import signal
    import time

    run = tmp_path / "run"
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    proc = subprocess.Popen(
        [sys.executable, "-m", "iplanner_torch.cli.experiment", "run.planners=[itomp]",
         "run.seeds=[0,1]", "progress=false", f"hydra.run.dir={run}"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    second = run / "episodes" / "arrangement_1x4_medium_n0.01_itomp_s1.mcap"
    deadline = time.monotonic() + 300
    while not (second.exists() and second.stat().st_size > 0) and time.monotonic() < deadline:
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    if not second.exists():
        proc.kill()
        out, err = proc.communicate(timeout=60)
        pytest.fail(f"the second episode's log never appeared (exit {proc.returncode}): "
                    f"{err[-2000:]}")  # fmt: skip
    time.sleep(1.5)  # into the second episode (one takes several seconds)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    proc.send_signal(getattr(signal, sig))
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-3000:]
    assert (
        err.strip()
        .splitlines()[-1]
        .startswith(f"interrupted: what was written before is kept in {run}")
    )
    import pandas as pd

    rows = pd.read_csv(run / "results.csv")
    assert list(rows["seed"]) == [0]
    first = read_episode(run / "episodes" / "arrangement_1x4_medium_n0.01_itomp_s0.mcap")
    assert first.complete and "eval/smoothness" in first.metrics()
    cut = read_episode(second)
    assert cut.complete  # closed with a footer, nothing lost to an open chunk
    t, q = cut.robot_q()
    # what it simulated before the signal (a busy machine may have simulated little)
    assert len(t) >= 1 and [e["kind"] for e in cut.events()][-1] == "interrupted"
    assert "interrupted: what was written before is kept" in (run / "experiment.log").read_text()
    assert err.strip().splitlines()[-1].endswith("run.resume=true and that hydra.run.dir goes "
                                                 "on from there")  # fmt: skip
    # and so it does: the interrupted episode runs again, its cut log kept aside
    again_args = ["run.planners=[itomp]", "run.seeds=[0,1]", "progress=false",
                  f"hydra.run.dir={run}", "run.resume=true"]  # fmt: skip
    res = _run(["iplanner-experiment", *again_args], tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert list(pd.read_csv(run / "results.csv")["seed"]) == [0, 1]
    again = read_episode(second)
    assert again.complete and "eval/smoothness" in again.metrics()
    aside = read_episode(run / "interrupted" / second.name)
    assert [e["kind"] for e in aside.events()][-1] == "interrupted"


def test_evaluate_refuses_a_joint_selection_that_drops_checkpoint_joints(tmp_path: Path) -> None:
    """``data.windows.joints`` must keep every joint the checkpoint forecasts (any order, more
    allowed); a narrower one is a ConfigError naming both, not "unknown joint names" later."""
    from types import SimpleNamespace

    from omegaconf import OmegaConf

    from iplanner_torch.cli.evaluate import _check_joints
    from iplanner_torch.errors import ConfigError

    predictor = SimpleNamespace(joint_names=("head", "right_elbow", "right_hand"))
    ckpt = tmp_path / "predictor.ckpt"
    for ok in (None, [], ["right_hand", "head", "right_elbow"], ["a", "head", "right_elbow",
                                                                 "right_hand"]):  # fmt: skip
        _check_joints(OmegaConf.create({"data": {"windows": {"joints": ok}}}), predictor, ckpt)
    _check_joints(OmegaConf.create({"data": {"path": "x"}}), predictor, ckpt)
    cfg = OmegaConf.create({"data": {"windows": {"joints": ["right_hand", "right_elbow"]}}})
    with pytest.raises(ConfigError, match=r"leaves out \['head'\], which .*predictor\.ckpt was "
                       r"trained on .*leave data\.windows\.joints out"):  # fmt: skip
        _check_joints(cfg, predictor, ckpt)


def test_train_writes_a_checkpoint_and_held_out_metrics_and_resumes(tmp_path: Path) -> None:
    """``iplanner-train`` on a small generated dataset: a checkpoint that loads and forecasts,
    the held-out metrics file with what it prints, and a resumed run that reuses the
    sub-models (same forecasts)."""
    import json

    import torch

    from iplanner_torch.data.windows import WindowCfg, build_windows
    from iplanner_torch.prediction.predictor import HumanMotionPredictor

    ds, ck = tmp_path / "ds", tmp_path / "ck"
    gen = ["iplanner-data", "generate", f"data.path={ds}", "progress=false",
           "data.generator.n_targets=2", "data.generator.reaches_per_target=5"]  # fmt: skip
    res = _run(gen, tmp_path)
    assert res.returncode == 0, res.stderr
    train = ["iplanner-train", "trainer=fast", f"data.path={ds}", f"train.out_dir={ck}",
             "data.split=[0.6,0.2,0.2]", "progress=false"]  # fmt: skip
    res = _run([*train, f"hydra.run.dir={tmp_path / 'h1'}"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert f"predictor checkpoint: {ck / 'predictor.ckpt'}" in res.stdout
    metrics = json.loads((ck / "heldout_metrics.json").read_text())
    for key in ("train_windows", "n_windows", "class_precision", "mhd_1s", "coverage95"):
        assert key in metrics and f"  {key}" in res.stdout, key
    # each printed with its unit, the same number as the file's
    line = next(ln for ln in res.stdout.splitlines() if ln.startswith("  mhd_1s "))
    assert line.split()[1:] == [f"{metrics['mhd_1s']:.4g}", "m"], line
    assert f"run folder: {tmp_path / 'h1'}" in res.stdout
    assert metrics["n_windows"] > 0 and 0.0 <= metrics["coverage95"] <= 1.0
    assert sorted(p.name for p in ck.glob("gp_*.ckpt")) and (ck / "classifier.ckpt").exists()
    pred = HumanMotionPredictor.load(ck / "predictor.ckpt")
    demos = load_demonstrations(ds)
    w = build_windows(demos[:2], WindowCfg(n_prev=pred.n_prev, n_future=pred.n_future))
    before = pred.predict(w.f_prev[:4], w.progress[:4])
    assert bool(torch.isfinite(before.mean).all()) and before.horizon == pred.n_future
    stamps = {p.name: p.stat().st_mtime_ns for p in ck.glob("gp_*.ckpt")}
    res = _run([*train, "train.resume=true", f"hydra.run.dir={tmp_path / 'h2'}"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert {p.name: p.stat().st_mtime_ns for p in ck.glob("gp_*.ckpt")} == stamps
    after = HumanMotionPredictor.load(ck / "predictor.ckpt").predict(w.f_prev[:4], w.progress[:4])
    torch.testing.assert_close(after.mean, before.mean)
    torch.testing.assert_close(after.weights, before.weights)


def test_a_sweep_with_bad_values_is_refused_before_any_job_runs(tmp_path: Path) -> None:
    """``-m`` with bad values among good ones: every job's settings are checked before the
    first job starts (a bad value was found only when its job started, after the jobs before
    it had run); each bad job is named with its overrides and nothing runs."""
    sweep = tmp_path / "sweep"
    args = ["iplanner-experiment", "-m", f"hydra.sweep.dir={sweep}", "tracker.noise=0,-1",
            "planner.confidence=0.95,1.5", "run.planners=[itomp]", "run.max_duration_s=2",
            "progress=false"]  # fmt: skip
    res = _run(args, tmp_path)
    assert res.returncode == 2, res.stderr[-2000:]
    noise = "ConfigError: tracker.noise: expected in [0, 1] m, got -1.0"
    confidence = "ConfigError: planner.confidence: expected confidence in (0, 1), got 1.5"
    rest = "run.planners=[itomp] run.max_duration_s=2 progress=False"
    assert res.stderr.strip().splitlines() == [
        "error: ConfigError: 3 of 4 sweep job(s) would stop on a bad setting; no job was run:",
        f"  job 1 [tracker.noise=0 planner.confidence=1.5 {rest}]: {confidence}",
        f"  job 2 [tracker.noise=-1 planner.confidence=0.95 {rest}]: {noise}",
        f"  job 3 [tracker.noise=-1 planner.confidence=1.5 {rest}]: {noise}",
    ]
    assert not sweep.exists()


def test_a_failed_sweep_job_leaves_the_others_running_and_is_named(tmp_path: Path) -> None:
    """A job that fails on what only running it finds (here a predictor checkpoint that is
    missing, with run.train_if_missing=false): the good jobs run and are summarised, the
    failed job leaves its error line in a FAILED file, and the sweep names it and exits 2."""
    sweep, ck = tmp_path / "sweep", tmp_path / "ck"
    args = ["iplanner-experiment", "-m", f"hydra.sweep.dir={sweep}",
            "run.planners=[itomp],[iplanner_ni],[itomp]", "tracker.noise=0",
            "run.train_if_missing=false", f"paths.checkpoints={ck}", "run.max_duration_s=2",
            "progress=false"]  # fmt: skip
    res = _run(args, tmp_path)
    assert res.returncode == 2, res.stderr[-2000:]
    assert (sweep / "0" / "results.csv").exists() and (sweep / "2" / "results.csv").exists()
    assert not (sweep / "1" / "results.csv").exists()
    line = (sweep / "1" / "FAILED").read_text().strip()
    assert line.startswith("error: CheckpointError: ") and "no trained predictor" in line
    assert (sweep / "summary" / "results.csv").exists()
    err = res.stderr.strip().splitlines()
    at = err.index("1 of 3 sweep job(s) failed (the others ran):")
    assert err[at + 1].startswith(f"  {sweep / '1'} [run.planners=[iplanner_ni] ")
    assert err[at + 1].endswith(line)


def test_the_robot_group_configures_every_experiment() -> None:
    """``robot=fetch robot.torso_height=...`` reaches the experiment's robot (its fields used to
    be ignored but for the name); ``experiment.robot=<name>`` picks that group option."""
    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR
    from iplanner_torch.cli.experiment import build_experiment
    from iplanner_torch.errors import ConfigError

    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        cases = {
            ("robot=fetch", "robot.torso_height=0.2"): ("fetch", 0.2, (1.0, 0.0, -0.75)),
            ("experiment=table_simulation", "robot=fetch", "robot.base_position=[1.1,0,-0.75]"): (
                "fetch", 0.26, (1.1, 0.0, -0.75)),
            ("experiment=speed_response", "experiment.robot=fetch"): ("fetch", 0.26, None),
            ("experiment=speed_response",): ("kuka_iiwa14", None, (0.75, 0.0, 0.0)),
        }  # fmt: skip
        for overrides, (name, torso, base) in cases.items():
            robot = build_experiment(compose("config", overrides=list(overrides)), {}).robot
            assert (robot.name, robot.torso_height) == (name, torso), overrides
            assert base is None or robot.base_position == base, overrides
        with pytest.raises(ConfigError, match="unknown robot 'ur5'"):
            build_experiment(compose("config", overrides=["robot.name=ur5"]), {})
        with pytest.raises(ConfigError, match="no config option robot=ur5"):
            bad = ["experiment=speed_response", "experiment.robot=ur5"]
            build_experiment(compose("config", overrides=bad), {})


def test_the_training_command_of_a_missing_predictor_trains_what_the_run_reads() -> None:
    """The command a run without its predictor names (run.train_if_missing=false) composes,
    as iplanner-train's config, the dataset, generator, predictor, trainer and folder the
    run would train with; it used to leave the data out, and so trained on the reaching set
    into the folder of a task dataset."""
    import shlex

    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR, predictor_folder
    from iplanner_torch.cli.experiment import build_experiment, scenario_data_node, train_command

    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        for overrides, data in (
            ([], "tasks"),
            (["experiment=speed_response"], "reaching"),
            (["run.train_trainer=default", "robot=fetch"], "tasks"),
        ):
            cfg = compose("config", overrides=overrides)
            node = scenario_data_node(cfg, build_experiment(cfg, {}).scenarios[0])
            out = predictor_folder(cfg, node) / "iplanner_no_ni"
            words = shlex.split(train_command(cfg, node, "iplanner_no_ni", out))
            assert words[0] == "iplanner-train" and f"data={data}" in words, words
            train = compose("config", overrides=words[1:])
            assert train.data.path == node.path and train.train.out_dir == str(out), words
            assert train.data.generator == node.generator, words
            trainer = compose("config", overrides=[f"trainer={cfg.run.train_trainer}"]).trainer
            assert train.trainer == trainer and train.predictor.svgp.noisy_input == "none"


def test_data_generate_checks_every_setting_before_it_touches_the_folder(tmp_path: Path) -> None:
    """A bad generator setting with data.overwrite=true is refused with one line, exit 2, and
    the earlier dataset is left as it was (it used to be deleted first)."""
    out = tmp_path / "ds"
    gen = ["iplanner-data", "generate", f"data.path={out}", "progress=false"]
    res = _run([*gen, "data.generator.reaches_per_target=1", "data.generator.n_targets=2"],
               tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for bad, named in [
        ("data.generator.fps=-1", "data.generator.fps: expected fps > 0"),
        ("data.generator.seed=-1", "data.generator.seed: expected seed an integer >= 0, got -1"),
        ("data.generator.file_format=xml", "file_format: file_format must be 'npz' or 'csv'"),
    ]:
        res = _run([*gen, "data.overwrite=true", bad], tmp_path)
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 2 and len(lines) == 1, res.stderr
        assert lines[0].startswith("error: ConfigError: data.generator") and named in lines[0]
        assert "deleted" not in res.stdout
        assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    res = _run(["iplanner-data", "generate", "data=tasks", f"data.path={tmp_path / 't'}",
                "data.generator.seed=-1"], tmp_path)  # fmt: skip
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip() == (
        "error: ConfigError: data.generator.seed: expected seed an integer >= 0, got -1"
    )


def test_an_interrupted_generate_keeps_the_earlier_dataset(tmp_path: Path) -> None:
    """SIGTERM during ``generate data.overwrite=true``: one ``interrupted:`` line about the
    dataset (not episodes), exit 130, the earlier dataset as it was and no temporary folder."""
    import signal
    import time

    out = tmp_path / "ds"
    gen = ["iplanner-data", "generate", f"data.path={out}", "progress=false"]
    res = _run([*gen, "data.generator.reaches_per_target=1", "data.generator.n_targets=2"],
               tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    proc = subprocess.Popen(
        [sys.executable, "-m", "iplanner_torch.cli.data", *gen[1:], "data.overwrite=true",
         "data.generator.reaches_per_target=300"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 300
    partial: list[Path] = []
    while time.monotonic() < deadline and proc.poll() is None:
        partial = list(tmp_path.glob("ds.partial-*"))
        if partial and len(list(partial[0].iterdir())) >= 5:
            break
        time.sleep(0.05)
    assert proc.poll() is None and partial, "generate ended before it could be interrupted"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"interrupted: {out} is left as it was"), last
    assert "episode" not in last and "results.csv" not in last
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("ds")) == ["ds"]


def test_the_projects_warnings_are_one_line_without_source(tmp_path: Path) -> None:
    """A DataWarning (here a CSV cut short) prints as ``warning: DataWarning: ...``, not with
    the package file and source line Python's default format adds."""
    out = tmp_path / "ds"
    res = _run(
        ["iplanner-data", "generate", f"data.path={out}", "data.generator.reaches_per_target=1",
         "data.generator.file_format=csv", "progress=false"],
        tmp_path,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    first = sorted(out.glob("*.csv"))[0]
    first.write_text(first.read_text().rstrip("\n"))
    res = _run(["iplanner-data", "info", f"data.path={out}"], tmp_path)
    assert res.returncode == 0, res.stderr
    lines = res.stderr.strip().splitlines()
    assert lines == [
        f"warning: DataWarning: {first}: last line has no line terminator: the file may be cut "
        "short; its last row is dropped"
    ]


def test_one_line_warnings_leaves_other_libraries_format(monkeypatch: pytest.MonkeyPatch) -> None:
    import warnings

    from iplanner_torch.cli._common import one_line_warnings
    from iplanner_torch.errors import DataWarning
    from iplanner_torch.planning.replanner import PlanningOverrunWarning

    monkeypatch.setattr(warnings, "formatwarning", warnings.formatwarning)
    one_line_warnings()
    one_line_warnings()  # idempotent: not wrapped twice
    assert warnings.formatwarning("m", DataWarning, "/x/io.py", 3) == "warning: DataWarning: m\n"
    text = warnings.formatwarning("late", PlanningOverrunWarning, "/x/r.py", 9)
    assert text == "warning: PlanningOverrunWarning: late\n"
    assert warnings.formatwarning("u", UserWarning, "/x/lib.py", 7).startswith(
        "/x/lib.py:7: UserWarning: u"
    )


def test_device_auto_keeps_the_closed_loop_on_the_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where CUDA is present, ``device=auto`` still runs the experiment's closed loop on the
    CPU (faster at the planner's batch sizes); ``device=cuda`` puts it on CUDA."""
    from hydra import compose, initialize_config_dir

    from iplanner_torch.cli._common import CONF_DIR
    from iplanner_torch.cli.experiment import build_experiment

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        for overrides, want in (
            ([], "cpu"),
            (["device=auto", "experiment=speed_response"], "cpu"),
            (["device=cuda"], "cuda"),
            (["device=cuda:0", "experiment=speed_response"], "cuda:0"),
            (["device=cpu"], "cpu"),
        ):
            exp = build_experiment(compose("config", overrides=overrides), {})
            assert exp.device == want, overrides


def test_a_scenario_option_named_otherwise_is_refused(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A new conf/scenario file without its own name took ScenarioCfg's default
    ('arrangement_1x4'), and its episodes were filed under that scenario; a name set on the
    command line is taken, and so is one the file sets itself (a label of the user's: it was
    refused with a message saying the file set none)."""
    import iplanner_torch.cli._common as common
    import iplanner_torch.cli.experiment as experiment
    from iplanner_torch.errors import ConfigError

    (tmp_path / "scenario").mkdir()
    monkeypatch.setattr(experiment, "CONF_DIR", str(tmp_path))
    monkeypatch.setattr(common, "_group_choice", lambda key: "mine")
    monkeypatch.setattr(experiment, "_task_overrides", lambda: ["scenario=mine"])
    (tmp_path / "scenario" / "mine.yaml").write_text("defaults: [arrangement_2x4, _self_]\n")
    named = (
        r"'arrangement_1x4', a name its file does not set .*; add 'name: <label>' "
        r"\(e.g. 'name: mine'\) to conf/scenario/mine.yaml, or set scenario.name=<label>$"
    )
    with pytest.raises(ConfigError, match=r"^scenario=mine: its scenario is named " + named):
        experiment._check_scenario_name("arrangement_1x4")
    experiment._check_scenario_name("mine")
    (tmp_path / "scenario" / "mine.yaml").write_text(
        "defaults: [arrangement_2x4, _self_]\nname: my_label\n"
    )
    experiment._check_scenario_name("my_label")  # the file's own label
    with pytest.raises(ConfigError, match="its scenario is named 'arrangement_2x4'"):
        experiment._check_scenario_name("arrangement_2x4")  # not the file's
    given = ["scenario=mine", "+scenario.name=x"]
    monkeypatch.setattr(experiment, "_task_overrides", lambda: given)
    experiment._check_scenario_name("x")


def test_train_names_a_forecast_shorter_than_a_second_once(tmp_path: Path) -> None:
    """8 future frames at 15 fps forecast 0.53 s, which mhd_1s then covers: said once, by the
    training (before it trains), not again by the held-out evaluation after it."""
    ds = tmp_path / "ds"
    gen = ["iplanner-data", "generate", f"data.path={ds}", "progress=false",
           "data.generator.n_targets=2", "data.generator.reaches_per_target=5"]  # fmt: skip
    assert _run(gen, tmp_path).returncode == 0
    train = ["iplanner-train", "trainer=fast", f"data.path={ds}", "progress=false",
             f"train.out_dir={tmp_path / 'ck'}", "data.split=[0.6,0.2,0.2]",
             "data.windows.n_future=8", f"hydra.run.dir={tmp_path / 'h'}"]  # fmt: skip
    res = _run(train, tmp_path)
    assert res.returncode == 0, res.stderr
    said = [ln for ln in res.stderr.splitlines() if "not 1 s" in ln]
    assert len(said) == 1, res.stderr
    assert "data.windows.n_future=8 at 15 fps forecasts 0.53 s" in said[0]
    assert "data.windows.n_future=15 (and n_prev to match)" in said[0]
