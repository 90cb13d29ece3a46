"""Sweeps of iplanner-train, iplanner-evaluate and iplanner-data: every job is checked before
the first runs (a bad value, or two jobs writing one folder; for iplanner-experiment, two jobs
training one folder of predictors with different settings), a training sweep ends with one
table of its jobs' held-out metrics, and jobs side by side get passive OpenMP waits."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from iplanner_torch.cli.callbacks import gather_job_metrics, shared_outputs, shared_trainings

MODULES = {
    "iplanner-experiment": "iplanner_torch.cli.experiment",
    "iplanner-data": "iplanner_torch.cli.data",
    "iplanner-train": "iplanner_torch.cli.train",
    "iplanner-evaluate": "iplanner_torch.cli.evaluate",
}


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", MODULES[args[0]], *args[1:]],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_shared_outputs_names_each_place_several_jobs_write() -> None:
    a, b = Path("/x/a"), Path("/x/b")
    written = [(0, {"train.out_dir": a}), (1, {"train.out_dir": b}), (2, {"train.out_dir": a}),
               (3, {}), (4, {"train.out_dir": a, "data.path": b})]  # fmt: skip
    assert shared_outputs(written) == [("train.out_dir", a, [0, 2, 4])]
    assert shared_outputs([(0, {"data.path": a}), (1, {"data.path": b})]) == []
    tagged = [(0, {"s1": (a, "seed=0")}), (1, {"s1": (a, "seed=0")})]
    assert shared_outputs(tagged) == []  # a folder of predictors: shared_trainings' to judge


def test_shared_trainings_names_folders_asked_for_with_different_settings() -> None:
    a, b = Path("/ck/a"), Path("/ck/b")
    written = [(0, {"x": (a, "seed=0"), "y": (b, "seed=0")}), (1, {"x": (a, "seed=0")}),
               (2, {}), (3, {"x": (a, "seed=1"), "y": (b, "seed=0")})]  # fmt: skip
    assert shared_trainings(written) == [(a, {"seed=0": [0, 1], "seed=1": [3]})]


@pytest.mark.parametrize(
    ("command", "args", "line"),
    [
        ("iplanner-train", ["predictor.svgp.num_inducing=16,32"],
         "  jobs 0, 1 would all write train.out_dir={cwd}/checkpoints/reaching/iplanner_ni"),
        ("iplanner-data", ["generate", "data.generator.seed=0,1,2"],
         "  jobs 0, 1, 2 would all write data.path={cwd}/datasets/reaching"),
        ("iplanner-evaluate", ["evaluate.noises=[0.0],[0.02]", "evaluate.mode=noise_sweep",
                               "evaluate.out_dir=tables"],
         "  jobs 0, 1 would all write evaluate.out_dir={cwd}/tables"),
    ],
)  # fmt: skip
def test_a_sweep_whose_jobs_would_write_one_folder_is_refused_before_any_runs(
    tmp_path: Path, command: str, args: list[str], line: str
) -> None:
    """Two jobs into one folder: the later would replace the earlier's predictor (dataset,
    tables), or mix with it when they run in parallel. Refused with the key and folder, and
    how to give each job its own; nothing is written."""
    sweep = tmp_path / "sweep"
    first, rest = (args[:1], args[1:]) if command == "iplanner-data" else ([], args)
    res = _run([command, *first, "-m", *rest, f"hydra.sweep.dir={sweep}", "progress=false"],
               tmp_path)  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    key = line.split(" would all write ")[1].split("=")[0]
    assert res.stderr.strip().splitlines() == [
        "error: ConfigError: sweep jobs would write into the same place, each replacing what "
        "the one before wrote (or mixing with it when they run in parallel); no job was run:",
        line.format(cwd=tmp_path.resolve()),
        f"  give each job its own, e.g. '{key}=<folder>/${{hydra:job.num}}'",
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no sweep folder, no data


def test_an_experiment_sweep_training_one_folder_with_different_settings_is_refused(
    tmp_path: Path,
) -> None:
    """``iplanner-experiment -m seed=0,1``: both jobs would train the scenario's predictors
    into one folder, and the second would stop on the first's seed after the first had run.
    Refused before any job runs. Jobs that ask the same of a folder (a noise sweep), and one
    folder per seed, pass this check (here a bad confidence in two jobs then stops them)."""
    sweep = tmp_path / "sweep"
    rest = [f"hydra.sweep.dir={sweep}", "progress=false"]
    res = _run(["iplanner-experiment", "-m", "seed=0,1", "run.train_trainer=fast,default",
                *rest], tmp_path)  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    folder = tmp_path.resolve() / "checkpoints" / "tasks_1x4_any0-1_then_any2-3"
    assert res.stderr.strip().splitlines() == [
        "error: ConfigError: sweep jobs would train predictors into the same folder with "
        "different settings (the first trains them, the others stop on the difference or use "
        "them unchecked); no job was run:",
        f"  {folder}: job 0 with seed=0 run.train_trainer=fast; job 1 with seed=0 "
        "run.train_trainer=default; job 2 with seed=1 run.train_trainer=fast; job 3 with "
        "seed=1 run.train_trainer=default",
        "  give each setting its own folder, e.g. 'paths.checkpoints=checkpoints/seed${seed}' "
        "for a sweep of seed, or 'paths.checkpoints=checkpoints/${hydra:job.num}'",
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    # with run.train_data=data, the window settings a checkpoint is compared on count too
    res = _run(["iplanner-experiment", "-m", "run.train_data=data", "data.windows.n_prev=10,15",
                *rest], tmp_path)  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    assert res.stderr.strip().splitlines()[1] == (
        f"  {tmp_path.resolve() / 'checkpoints' / 'reaching'}: job 0 with seed=0 "
        "run.train_trainer=fast data.windows.n_prev=10; job 1 with seed=0 "
        "run.train_trainer=fast data.windows.n_prev=15"
    )
    bad_confidence = "2 of 4 sweep job(s) would stop on a bad setting"
    for sweep_args in (["tracker.noise=0,0.02"], ["seed=0,1", "paths.checkpoints=ck/s${seed}"]):
        res = _run(["iplanner-experiment", "-m", *sweep_args, "planner.confidence=0.95,2",
                    *rest], tmp_path)  # fmt: skip
        assert res.returncode == 2 and bad_confidence in res.stderr, res.stderr[-2000:]
        assert "would train predictors" not in res.stderr


@pytest.mark.parametrize(
    ("command", "args", "bad", "error"),
    [
        ("iplanner-train", ["predictor.svgp.num_inducing=16,-2",
                            "train.out_dir=ck/${hydra:job.num}"],
         "predictor.svgp.num_inducing=-2",
         "predictor.svgp.num_inducing: expected num_inducing an integer >= 1, got -2"),
        ("iplanner-train", ["data.split=[0.6,0.2,0.2],[0.9,0.2,0.2]",
                            "train.out_dir=ck/${hydra:job.num}"],
         "data.split=[0.9,0.2,0.2]", "data.split: "),
        ("iplanner-data", ["generate", "data.generator.n_targets=2,0",
                           "data.path=ds/${hydra:job.num}"],
         "data.generator.n_targets=0", "data.generator.n_targets: "),
        ("iplanner-evaluate", ["evaluate.mode=prediction,noise", "seed=0"],
         "evaluate.mode=noise",
         "evaluate.mode must be one of ('prediction', 'noise_sweep', 'episode'), got 'noise'"),
        ("iplanner-evaluate", ["evaluate.mode=noise_sweep", "evaluate.noises=[0.0],[-1.0]"],
         "evaluate.noises=[-1.0]", "evaluate."),
    ],
)  # fmt: skip
def test_a_bad_value_in_one_job_of_a_sweep_is_named_before_any_job_runs(
    tmp_path: Path, command: str, args: list[str], bad: str, error: str
) -> None:
    """As iplanner-experiment's sweeps: the job with the bad value is named with its
    overrides and the error its run would have stopped on; no job runs."""
    sweep = tmp_path / "sweep"
    first, rest = (args[:1], args[1:]) if command == "iplanner-data" else ([], args)
    res = _run([command, *first, "-m", *rest, f"hydra.sweep.dir={sweep}", "progress=false"],
               tmp_path)  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    lines = res.stderr.strip().splitlines()
    assert lines[0] == (
        "error: ConfigError: 1 of 2 sweep job(s) would stop on a bad setting; no job was run:"
    )
    assert len(lines) == 2 and lines[1].startswith("  job 1 [") and bad in lines[1]
    assert f"]: ConfigError: {error}" in lines[1]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("args", "error"),
    [
        (["hydra/launcher=joblib", "+hydra.launcher.n_job=2"],
         "error: ConfigError: unknown key 'hydra.launcher.n_job' (did you mean "
         "'hydra.launcher.n_jobs'?): added by +hydra.launcher.n_job=2, which Hydra does not read"),
        (["data.windows.joints=right_hand"],
         "ConfigError: data.windows.joints: expected a list of joint names, got the single "
         "string 'right_hand'"),
        (["+data.format=foo"], "ConfigError: data.format: expected one of native, lego_assembly"),
    ],
)  # fmt: skip
def test_a_sweep_refuses_what_a_single_run_refuses_before_any_job_runs(
    tmp_path: Path, args: list[str], error: str
) -> None:
    """A misspelt launcher key (the jobs would run one at a time) and the data settings
    ``iplanner-data info`` reads are refused as a single run refuses them, before a job
    starts (no job folder), not after every job has failed."""
    sweep = tmp_path / "sweep"
    paths = f"data.path={tmp_path / 'a'},{tmp_path / 'b'}"
    res = _run(["iplanner-data", "info", "-m", *args, paths, f"hydra.sweep.dir={sweep}"],
               tmp_path)  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    assert error in res.stderr and "Traceback" not in res.stderr
    assert not sweep.exists() or not any(p.is_dir() for p in sweep.iterdir())


def _job(sweep: Path, name: str, overrides: list[str], metrics: dict | None) -> None:
    job = sweep / name
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    if metrics is not None:
        (job / "heldout_metrics.json").write_text(json.dumps(metrics))


def test_the_metrics_of_a_training_sweep_are_gathered_into_one_table(tmp_path: Path) -> None:
    """One row per job that wrote metrics, in job order (10 after 2), with the swept
    overrides as columns; a plot against the swept value."""
    sweep = tmp_path / "sweep"
    _job(
        sweep,
        "0",
        ["predictor.svgp.num_inducing=64", "trainer=fast"],
        {"checkpoint": "a", "mhd_1s": 0.05, "coverage95": 0.9, "train_seconds": 3.0},
    )
    _job(
        sweep,
        "10",
        ["predictor.svgp.num_inducing=8", "trainer=fast"],
        {"checkpoint": "c", "mhd_1s": 0.09, "coverage95": 0.8, "train_seconds": 1.0},
    )
    _job(
        sweep,
        "2",
        ["predictor.svgp.num_inducing=16", "trainer=fast"],
        {"checkpoint": "b", "mhd_1s": 0.07, "coverage95": 0.85, "train_seconds": 2.0},
    )
    _job(sweep, "3", ["predictor.svgp.num_inducing=32", "trainer=fast"], None)  # failed job
    written = gather_job_metrics(sweep, tmp_path / "summary")
    assert [p.name for p in written] == ["results.csv", "results.md", "metrics.png"]
    df = pd.read_csv(tmp_path / "summary" / "results.csv")
    assert list(df["job"]) == [0, 2, 10]
    assert list(df["predictor.svgp.num_inducing"]) == [64, 16, 8]
    assert list(df["mhd_1s"]) == [0.05, 0.07, 0.09]
    assert "trainer" not in df.columns  # the same in every job
    md = (tmp_path / "summary" / "results.md").read_text()
    assert "| job | predictor.svgp.num_inducing |" in md and "path" not in md.splitlines()[4]
    # the table has no path column: the sentence points to the CSV's
    assert "the `path` column of `results.csv` names each job's metrics file" in md
    assert (tmp_path / "summary" / "metrics.png").stat().st_size > 0
    assert gather_job_metrics(tmp_path / "nothing", tmp_path / "s2") == []


def test_a_metrics_sweep_prints_its_table(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """With echo (as the sweep's end calls it), the jobs, the swept override and the plotted
    metrics are printed, one line per job; the checkpoint path is left to the files."""
    sweep = tmp_path / "sweep"
    for job, m, mhd in (("0", 64, 0.05), ("1", 8, 0.0912345)):
        _job(sweep, job, [f"predictor.svgp.num_inducing={m}"],
             {"checkpoint": f"/x/{job}", "mhd_1s": mhd, "class_accuracy": 0.75})  # fmt: skip
    gather_job_metrics(sweep, tmp_path / "summary", echo=True)
    lines = [line.split() for line in capsys.readouterr().out.strip().splitlines()]
    assert lines == [
        ["job", "predictor.svgp.num_inducing", "mhd_1s", "class_accuracy"],
        ["0", "64", "0.05", "0.75"],
        ["1", "8", "0.09123", "0.75"],
    ]


def test_a_training_sweep_trains_one_predictor_per_job_and_summarises_them(
    tmp_path: Path,
) -> None:
    """A real two-job training sweep, each job into its own folder
    (``train.out_dir=<folder>/${hydra:job.num}``): two checkpoints trained with the job's
    setting, and ``summary/results.csv`` with each job's held-out metrics, as they are in its
    checkpoint folder."""
    ds, ck, sweep = tmp_path / "ds", tmp_path / "ck", tmp_path / "sweep"
    gen = ["iplanner-data", "generate", f"data.path={ds}", "progress=false",
           "data.generator.n_targets=2", "data.generator.reaches_per_target=5"]  # fmt: skip
    res = _run(gen, tmp_path)
    assert res.returncode == 0, res.stderr
    train = ["iplanner-train", "-m", "trainer=fast", f"data.path={ds}", "data.split=[0.6,0.2,0.2]",
             "predictor.svgp.num_inducing=8,16", f"train.out_dir={ck}/${{hydra:job.num}}",
             f"hydra.sweep.dir={sweep}", "progress=false"]  # fmt: skip
    res = _run(train, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert f"sweep summary: {sweep / 'summary' / 'results.md'}" in res.stdout
    assert "job  predictor.svgp.num_inducing  mhd_1s" in res.stdout  # the printed table
    df = pd.read_csv(sweep / "summary" / "results.csv")
    assert list(df["predictor.svgp.num_inducing"]) == [8, 16]
    for job, row in df.iterrows():
        inputs = json.loads((ck / str(job) / "training_inputs.json").read_text())
        assert f'"num_inducing": {row["predictor.svgp.num_inducing"]}' in json.dumps(inputs)
        held_out = json.loads((ck / str(job) / "heldout_metrics.json").read_text())
        assert row["checkpoint"] == str(ck / str(job) / "predictor.ckpt")
        assert row["mhd_1s"] == pytest.approx(held_out["mhd_1s"])
    assert (sweep / "summary" / "metrics.png").exists()


def test_a_dataset_sweep_ends_with_a_table_of_its_jobs(tmp_path: Path) -> None:
    """``iplanner-data generate -m`` and ``iplanner-data info -m``: each job records its
    dataset's counts in its folder (dataset_summary.json), and the sweep prints them as a
    table and writes summary/results.csv; the counts are those the datasets hold (read back
    with load_demonstrations). A data sweep ended with Hydra's lines alone."""
    from iplanner_torch.data.io import load_demonstrations

    sweep, info = tmp_path / "sweep", tmp_path / "info"
    gen = ["iplanner-data", "generate", "-m", "data.generator.seed=1,2",
           f"data.path={tmp_path}/ds${{hydra:job.num}}", "data.generator.n_targets=2",
           "data.generator.reaches_per_target=1", f"hydra.sweep.dir={sweep}",
           "progress=false"]  # fmt: skip
    res = _run(gen, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    head = ["job", "data.generator.seed", "dataset", "demonstrations", "frames", "megabytes",
            "seconds"]  # fmt: skip
    assert head in [line.split() for line in res.stdout.splitlines()], res.stdout
    assert f"sweep summary: {sweep / 'summary' / 'results.md'}" in res.stdout
    df = pd.read_csv(sweep / "summary" / "results.csv")
    assert list(df["data.generator.seed"]) == [1, 2]
    for job, row in df.iterrows():
        demos = load_demonstrations(tmp_path / f"ds{job}")
        assert row["dataset"] == str(tmp_path / f"ds{job}")
        assert row["demonstrations"] == len(demos)
        assert row["frames"] == sum(d.num_frames for d in demos)
    # the command word after -m (it was taken for an override: "cannot parse override 'info'")
    res = _run(["iplanner-data", "-m", "info", f"data.path={tmp_path / 'ds0'},{tmp_path / 'ds1'}",
                f"hydra.sweep.dir={info}"], tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    rows = pd.read_csv(info / "summary" / "results.csv")
    assert list(rows["frames"]) == list(df["frames"]) and list(rows["joints"]) == [10, 10]
    assert "nan_values" in res.stdout


@pytest.mark.parametrize(
    ("args", "at"),
    [
        (["generate", "seed=1"], 0),
        (["-m", "info", "data.path=a,b"], 1),
        (["--multirun", "data.generator.seed=1,2", "generate"], 2),
        (["--cfg", "job", "info"], 2),
        (["-cn", "config", "~data.fps", "info"], 3),
        (["--info", "all", "generate"], 2),
        (["--info", "info"], 1),
        (["data.path=x", "+data.fps=15", "-m"], None),
        ([], None),
        (["-m", "genrate"], 1),  # named as an unknown command by main()
    ],
)
def test_the_data_command_word_is_found_among_hydras_flags(
    args: list[str], at: int | None
) -> None:
    from iplanner_torch.cli.data import command_index

    assert command_index(args) == at


JOBLIB = "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher"
LOCAL = "hydra_plugins.hydra_submitit_launcher.submitit_launcher.LocalLauncher"
SLURM = "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"
BASIC = "hydra._internal.core_plugins.basic_launcher.BasicLauncher"


@pytest.mark.parametrize(
    ("launcher", "trainer", "cores", "n_jobs", "preset", "expected"),
    [
        ({"_target_": JOBLIB}, {}, 2, 4, None, "PASSIVE"),  # n_jobs -1: both cores
        ({"_target_": JOBLIB, "n_jobs": 2}, {"num_threads": 2}, 2, 4, None, "PASSIVE"),
        ({"_target_": JOBLIB, "n_jobs": 2}, {"num_threads": 1}, 2, 4, None, None),  # 2 threads
        ({"_target_": JOBLIB, "n_jobs": 1}, {}, 2, 4, None, None),  # one after another
        ({"_target_": JOBLIB, "n_jobs": 2}, {}, 2, 1, None, None),  # a single job
        ({"_target_": JOBLIB, "n_jobs": 2}, {}, 16, 4, None, None),  # 4 threads on 16 cores
        ({"_target_": JOBLIB, "n_jobs": -9}, {}, 16, 20, None, None),  # 8 at once x 2 = 16
        ({"_target_": JOBLIB, "n_jobs": -8}, {}, 16, 20, None, "PASSIVE"),  # 9 x 2 > 16
        ({"_target_": JOBLIB, "n_jobs": 2}, {"num_threads": None}, 16, 4, None, "PASSIVE"),
        ({"_target_": LOCAL}, {}, 2, 2, None, "PASSIVE"),
        ({"_target_": LOCAL, "array_parallelism": 1}, {}, 2, 2, None, None),
        ({"_target_": BASIC}, {}, 2, 4, None, None),
        ({"_target_": SLURM}, {}, 2, 4, None, None),  # each job on its own node
        ({"_target_": JOBLIB}, {}, 2, 4, "ACTIVE", "ACTIVE"),  # the user's setting stays
    ],
)
def test_jobs_side_by_side_with_more_threads_than_cores_get_passive_openmp_waits(
    monkeypatch: pytest.MonkeyPatch,
    launcher: dict,
    trainer: dict,
    cores: int,
    n_jobs: int,
    preset: str | None,
    expected: str | None,
) -> None:
    """Two 2-thread trainings at once on 2 cores took 15-25x longer with OpenMP's spinning
    waits (scripts/bench_sweep.py); a lone training is slower with passive ones, so jobs
    that have the cores to themselves, jobs one after another or on a cluster's nodes, and a
    policy the user set are left alone."""
    from omegaconf import OmegaConf

    from iplanner_torch.cli.callbacks import passive_omp_waits

    monkeypatch.setattr(os, "cpu_count", lambda: cores)
    if preset is None:
        monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    else:
        monkeypatch.setenv("OMP_WAIT_POLICY", preset)
    config = OmegaConf.create({"hydra": {"launcher": launcher}, "trainer": trainer})
    assert passive_omp_waits(config, n_jobs) is (expected == "PASSIVE" and preset is None)
    assert os.environ.get("OMP_WAIT_POLICY") == expected


def test_a_failed_job_is_named_with_its_overrides_as_typed(tmp_path: Path) -> None:
    """Hydra records a job's ``${...}`` override escaped (``ck/$\\{hydra\\:job.num\\}``); the
    failed-job line shows it as it was typed."""
    from iplanner_torch.cli._common import FAILED_MARKER
    from iplanner_torch.cli.callbacks import failed_jobs

    _job(tmp_path, "1", ["data.path=nope", r"train.out_dir=ck/$\{hydra\:job.num\}",
                         "data.split=[0.6,0.2,0.2]"], None)  # fmt: skip
    (tmp_path / "1" / FAILED_MARKER).write_text("error: DataError: nope\n")
    [(job, overrides, error)] = failed_jobs(tmp_path)
    assert job == tmp_path / "1" and error == "error: DataError: nope"
    assert overrides == "data.path=nope train.out_dir=ck/${hydra:job.num} data.split=[0.6,0.2,0.2]"


def test_the_metrics_of_a_prediction_evaluation_sweep_are_gathered(tmp_path: Path) -> None:
    """``iplanner-evaluate -m predictor=iplanner_ni,iplanner_no_ni``: each job's
    ``prediction_metrics.json``, one row per job, the option as a column, the plot's x axis
    the options in job order; a damaged file loses only its row."""
    sweep = tmp_path / "sweep"
    for num, (option, mhd) in enumerate([("iplanner_ni", 0.047), ("iplanner_no_ni", 0.048)]):
        _job(sweep, str(num), [f"predictor={option}"], None)
        record = {"n_windows": 868, "mhd_1s": mhd, "class_accuracy": 0.81}
        (sweep / str(num) / "prediction_metrics.json").write_text(json.dumps(record))
    _job(sweep, "2", ["predictor=other"], None)
    (sweep / "2" / "prediction_metrics.json").write_text("{not json")
    written = gather_job_metrics(sweep, tmp_path / "summary")
    assert [p.name for p in written] == ["results.csv", "results.md", "metrics.png"]
    df = pd.read_csv(tmp_path / "summary" / "results.csv")
    assert list(df["predictor"]) == ["iplanner_ni", "iplanner_no_ni"]
    assert list(df["mhd_1s"]) == [0.047, 0.048]


def test_the_commands_bound_openmp_spinning_before_torch_loads(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Every command imports iplanner_torch.cli before torch, which sets GOMP_SPINCOUNT (read
    by libgomp when torch loads) unless the environment sets it or OMP_WAIT_POLICY."""
    import subprocess
    import sys

    from iplanner_torch.cli import OMP_SPIN_COUNT, SPIN_SET_MARK, bounded_omp_spin

    probe = (
        "import os, sys\n"
        "import iplanner_torch.cli\n"
        "loaded = 'torch' in sys.modules\n"
        "import iplanner_torch.cli.experiment\n"
        "print(loaded, os.environ.get('GOMP_SPINCOUNT'), 'torch' in sys.modules)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    out = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["False", OMP_SPIN_COUNT, "True"]
    for preset in ({"GOMP_SPINCOUNT": "7"}, {"OMP_WAIT_POLICY": "ACTIVE"}):
        out = subprocess.run(
            [sys.executable, "-c", probe], env={**env, **preset}, capture_output=True,
            text=True, check=True,
        ).stdout.split()  # fmt: skip
        assert out[1] == preset.get("GOMP_SPINCOUNT", "None")

    monkeypatch.delenv("GOMP_SPINCOUNT", raising=False)
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    monkeypatch.delenv(SPIN_SET_MARK, raising=False)
    assert bounded_omp_spin() is True and os.environ["GOMP_SPINCOUNT"] == OMP_SPIN_COUNT
    assert bounded_omp_spin() is False  # set already


@pytest.mark.parametrize("ours", [True, False])
def test_passive_waits_remove_the_commands_spin_count_not_the_users(
    monkeypatch: pytest.MonkeyPatch, ours: bool
) -> None:
    """libgomp lets GOMP_SPINCOUNT override OMP_WAIT_POLICY: a sweep that sets passive waits
    drops the spin count the commands set, and keeps one the user set."""
    from omegaconf import OmegaConf

    from iplanner_torch.cli import SPIN_SET_MARK
    from iplanner_torch.cli.callbacks import passive_omp_waits

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    monkeypatch.setenv("GOMP_SPINCOUNT", "1000")
    if ours:
        monkeypatch.setenv(SPIN_SET_MARK, "1")
    else:
        monkeypatch.delenv(SPIN_SET_MARK, raising=False)
    config = OmegaConf.create({"hydra": {"launcher": {"_target_": JOBLIB}}, "trainer": {}})
    assert passive_omp_waits(config, 2) is True
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    assert os.environ.get("GOMP_SPINCOUNT") == (None if ours else "1000")
    assert SPIN_SET_MARK not in os.environ
