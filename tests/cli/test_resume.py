"""``iplanner-experiment run.resume=true``: a run that stopped, continued in its folder, gives
the table of the run made at once; other settings or predictors are refused."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pandas as pd
import pytest
from omegaconf import OmegaConf

from iplanner_torch.cli import experiment as cli
from iplanner_torch.errors import ConfigError, ConfigWarning

#: a short run of two planners without predictors
RUN = ["run.planners=[itomp,blind]", "run.seeds=[0,1]", "run.max_duration_s=2", "progress=false"]
#: columns that measure this machine's speed, not the episode
TIMING = ("sim/realtime_factor", "plan/mean_solve_ms", "prediction_ms", "plan/overruns")


def _experiment(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    cmd = [sys.executable, "-m", "iplanner_torch.cli.experiment", *args]
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def _table(path: Path) -> pd.DataFrame:
    df = pd.read_csv(path)
    return df[[c for c in df.columns if c not in TIMING]]


def test_resume_continues_a_stopped_run(tmp_path: Path) -> None:
    run = tmp_path / "run"
    res = _experiment([*RUN, f"hydra.run.dir={run}"], tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    full = _table(run / "results.csv")
    assert len(full) == 4
    # as if stopped in its second episode: one row, that episode's log cut short
    pd.read_csv(run / "results.csv").iloc[:1].to_csv(run / "results.csv", index=False)
    cut = run / "episodes" / "arrangement_1x4_medium_n0.01_itomp_s1.mcap"
    os.truncate(cut, cut.stat().st_size // 2)
    cut_size = cut.stat().st_size
    stopped = (run / "results.csv").read_text()
    record = {p.name: p.read_text() for p in (run / ".hydra").iterdir()}

    # other settings: refused, naming them, before anything is replaced
    res = _experiment([*RUN, f"hydra.run.dir={run}", "run.resume=true", "tracker.noise=0.02"],
                      tmp_path)  # fmt: skip
    assert res.returncode == 2
    assert f"error: ConfigError: run.resume=true: the run in {run} began with other settings" in (
        res.stderr
    )
    assert "sim.tracker_noise: 0.01 -> 0.02" in res.stderr
    assert (run / "results.csv").read_text() == stopped and cut.exists()
    # Hydra's record of the command that made the run is put back
    assert {p.name: p.read_text() for p in (run / ".hydra").iterdir()} == record
    # so is it after a value that is no bool (named inside the run, not taken for a new run)
    res = _experiment([*RUN, f"hydra.run.dir={run}", "run.resume=yes"], tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip().splitlines()[-1] == (
        "error: ConfigError: run.resume: expected bool, got 'yes'"
    )
    assert {p.name: p.read_text() for p in (run / ".hydra").iterdir()} == record

    # in two worker processes (run.jobs does not change an episode, so it may differ)
    res = _experiment([*RUN, f"hydra.run.dir={run}", "run.resume=true", "run.jobs=2"], tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "2 episodes at once, each in a process of its own (run.jobs)" in res.stdout
    assert "resuming: 1 finished episode(s) of scenario arrangement_1x4 kept" in res.stdout
    assert f"3 log(s) of unfinished episodes kept in {run / 'interrupted'}" in res.stdout
    pd.testing.assert_frame_equal(_table(run / "results.csv"), full)
    assert len(list((run / "episodes").glob("*.mcap"))) == 4
    assert len(list((run / "episodes").glob("*.png"))) == 4  # each log's timeline plot
    assert (run / "interrupted" / cut.name).stat().st_size == cut_size < cut.stat().st_size
    assert "| itomp " in (run / "results.md").read_text()

    # the grid grows: a third seed runs, the four finished episodes are kept
    res = _experiment([*RUN[:1], "run.seeds=[0,1,2]", *RUN[2:], f"hydra.run.dir={run}",
                       "run.resume=true"], tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    assert "resuming: 4 finished episode(s) of scenario arrangement_1x4 kept" in res.stdout
    grown = _table(run / "results.csv")
    assert list(grown["seed"]) == [0, 1, 2, 0, 1, 2]
    pd.testing.assert_frame_equal(
        grown[grown["seed"] < 2].reset_index(drop=True), full.reset_index(drop=True)
    )
    assert json.loads((run / cli.RUN_INPUTS).read_text())["settings"]["run.seeds"] == [0, 1, 2]
    # and may not shrink again
    res = _experiment([*RUN, f"hydra.run.dir={run}", "run.resume=true"], tmp_path)
    assert res.returncode == 2 and "(run.seeds: [0, 1, 2] -> [0, 1])" in res.stderr

    # a folder without a run to resume
    res = _experiment([*RUN, f"hydra.run.dir={tmp_path / 'none'}", "run.resume=true"], tmp_path)
    assert res.returncode == 2
    assert f"run.resume=true: {tmp_path / 'none'} holds no run to resume" in res.stderr


def test_resume_continues_a_stopped_sweep(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    args = ["-m", "tracker.noise=0,0.02", "run.planners=[itomp]", "run.max_duration_s=2",
            "progress=false", f"hydra.sweep.dir={sweep}"]  # fmt: skip
    res = _experiment(args, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    full = _table(sweep / "summary" / "results.csv")
    (sweep / "1" / "results.csv").unlink()  # the second job stopped in its episode
    res = _experiment(args, tmp_path)
    assert res.returncode == 2 and "already holds the results of an earlier sweep" in res.stderr
    # other settings: every job refused before the first runs, the job folders untouched
    record = {p: p.read_text() for p in sorted(sweep.glob("*/.hydra/*.yaml"))}
    res = _experiment([*args, "run.resume=true", "run.max_duration_s=3"], tmp_path)
    assert res.returncode == 2
    assert "2 of 2 sweep job(s) would stop on a bad setting; no job was run" in res.stderr
    assert (
        f"ConfigError: run.resume=true: the run in {sweep / '1'} began with other settings "
        "(run.max_duration_s: 2 -> 3" in res.stderr
    )
    assert {p: p.read_text() for p in sorted(sweep.glob("*/.hydra/*.yaml"))} == record
    res = _experiment([*args, "run.resume=true"], tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "resuming: 1 finished episode(s)" in res.stdout
    assert "resuming: 0 finished episode(s)" in res.stdout
    # the summary counts the episodes once: the set-aside log is left out
    assert list((sweep / "1" / "interrupted").glob("*.mcap"))
    got = _table(sweep / "summary" / "results.csv")
    assert len(got) == 2
    pd.testing.assert_frame_equal(got.drop(columns="path"), full.drop(columns="path"))
    # a job the sweep never began starts afresh
    shutil.rmtree(sweep / "1")
    res = _experiment([*args, "run.resume=true"], tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.count("resuming:") == 1
    got = _table(sweep / "summary" / "results.csv")
    pd.testing.assert_frame_equal(got.drop(columns="path"), full.drop(columns="path"))
    # a sweep folder that holds no sweep: refused before any job
    res = _experiment([*args[:-1], f"hydra.sweep.dir={tmp_path / 'none'}", "run.resume=true"],
                      tmp_path)  # fmt: skip
    assert res.returncode == 2
    assert f"run.resume=true: {tmp_path / 'none'} holds no sweep to resume" in res.stderr
    assert not (tmp_path / "none").exists() or not any((tmp_path / "none").glob("*/*.mcap"))


def _cfg(resume: bool, noise: float = 0.01, confidence: float = 0.95) -> OmegaConf:
    scenarios = [{"name": "a", "confidence": 0.9}, {"name": "b", "confidence": confidence}]
    return OmegaConf.create({"run": {"resume": resume, "timeline_plots": True}, "seeds": [0, 1],
                             "progress": True, "sim": {"noise": noise},
                             "experiment": {"scenarios": scenarios}})  # fmt: skip


def test_begin_run_records_and_compares(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(cli, "_code_commit", lambda: "abc")
    assert cli.begin_run(_cfg(False), tmp_path) is False
    inputs = json.loads((tmp_path / cli.RUN_INPUTS).read_text())
    # run.resume and the display keys left out; lists of mappings by index
    assert inputs["settings"] == {
        "seeds": [0, 1], "sim.noise": 0.01, "experiment.scenarios[]": 2,
        "experiment.scenarios[0].name": "a", "experiment.scenarios[0].confidence": 0.9,
        "experiment.scenarios[1].name": "b", "experiment.scenarios[1].confidence": 0.95,
    }  # fmt: skip
    (tmp_path / "results.csv").write_text("planner\n")
    with pytest.raises(ConfigError, match="already holds results.csv"):
        cli.begin_run(_cfg(False), tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert cli.begin_run(_cfg(True), tmp_path) is True
    with pytest.raises(ConfigError, match=r"other settings \(sim.noise: 0.01 -> 0.02\)"):
        cli.begin_run(_cfg(True, 0.02), tmp_path)
    with pytest.raises(
        ConfigError, match=r"\(experiment.scenarios\[1\].confidence: 0.95 -> 0.9\)"
    ):
        cli.begin_run(_cfg(True, confidence=0.9), tmp_path)
    monkeypatch.setattr(cli, "_code_commit", lambda: "def")
    with pytest.warns(ConfigWarning, match="commit abc; now 0.1.0, def"):
        cli.begin_run(_cfg(True), tmp_path)
    (tmp_path / cli.RUN_INPUTS).write_text("{not json")
    with pytest.raises(ConfigError, match="cannot be read"):
        cli.begin_run(_cfg(True), tmp_path)


@pytest.mark.parametrize(
    ("before", "after", "refused"),
    [
        ([0, 1], [0, 1, 2], False),
        ([0, 1], [2, 1, 0], False),
        ([0, 1], [0, 2], True),
        ([], [0], True),  # an empty list of speeds means the episode's own speed
    ],
)
def test_a_grid_list_may_grow(tmp_path: Path, before, after, refused) -> None:
    for key in ("experiment.seeds", "experiment.speeds"):
        args = (tmp_path, {key: before, "sim.noise": 0.01}, {key: after, "sim.noise": 0.01})
        if refused:
            with pytest.raises(ConfigError, match=rf"\({key}: "):
                cli._refuse_other_settings(*args)
        else:
            cli._refuse_other_settings(*args)
    # not a grid list
    with pytest.raises(ConfigError, match=r"\(sim.seeds: "):
        cli._refuse_other_settings(tmp_path, {"sim.seeds": [0]}, {"sim.seeds": [0, 1]})


def test_record_predictors_refuses_a_retrained_one(tmp_path: Path) -> None:
    cli.begin_run(_cfg(False), tmp_path)
    ckpt = tmp_path / "predictor.ckpt"
    ckpt.write_bytes(b"first")
    cli.record_predictors(tmp_path, "s", {"ni": str(ckpt)})
    cli.record_predictors(tmp_path, "s", {"ni": str(ckpt)})  # the same: fine
    cli.record_predictors(tmp_path, "t", {"ni": str(ckpt)})
    ckpt.write_bytes(b"second")
    with pytest.raises(ConfigError, match=f"the predictor {ckpt} of scenario 's' is not the one"):
        cli.record_predictors(tmp_path, "s", {"ni": str(ckpt)})
    recorded = json.loads((tmp_path / cli.RUN_INPUTS).read_text())["predictors"]
    assert recorded["s"] == recorded["t"] and set(recorded) == {"s", "t"}


def test_a_resumed_sweep_job_refuses_a_retrained_predictor_before_any_job(
    tmp_path: Path, monkeypatch
) -> None:
    """The sweep's pre-check compares the job's recorded checkpoints with the files there now,
    before Hydra writes the job's record of the command in its folder; a checkpoint deleted
    since is trained again there first."""
    from types import SimpleNamespace

    from hydra.types import RunMode

    job = tmp_path / "sweep" / "0"
    job.mkdir(parents=True)
    ckpt = tmp_path / "ckpt" / "ds" / "iplanner_ni" / "predictor.ckpt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_bytes(b"first")
    cfg = OmegaConf.create({"run": {"resume": False, "train_data": "data"}, "progress": True,
                            "paths": {"checkpoints": str(tmp_path / "ckpt")},
                            "data": {"path": str(tmp_path / "ds")}})  # fmt: skip
    cli.begin_run(cfg, job)
    cli.record_predictors(job, "s", {"ni": str(ckpt)})
    basic = {"_target_": "hydra._internal.core_plugins.basic_launcher.BasicLauncher"}
    hc = SimpleNamespace(mode=RunMode.MULTIRUN, sweep=SimpleNamespace(dir=job.parent, subdir="0"),
                         launcher=basic)  # fmt: skip
    monkeypatch.setattr(cli.HydraConfig, "get", staticmethod(lambda: hc))
    cfg.run.resume = True
    nodes = {"s": cfg.data}
    assert cli.predictor_checkpoint(cli.predictor_folder(cfg, cfg.data), "ni") == ckpt
    trained, retrained = [], b"first"

    def train(cfg, variants, node):  # as ensure_predictors: the same bytes, or others
        trained.append((list(variants), node.path))
        ckpt.write_bytes(retrained)
        return {"ni": str(ckpt)}

    monkeypatch.setattr(cli, "ensure_predictors", train)
    cli.check_resumed_job(cfg, nodes, ["ni"])  # the same checkpoint
    cli.check_resumed_job(cfg, {}, [])  # no predicting planner: nothing to compare
    ckpt.write_bytes(b"second")
    with pytest.raises(ConfigError, match=f"the predictor {ckpt} of scenario 's' is not the one"):
        cli.check_resumed_job(cfg, nodes, ["ni"])
    assert trained == []  # present: nothing trained
    # missing: trained again here, before any job; the same file goes on
    ckpt.unlink()
    cli.check_resumed_job(cfg, nodes, ["ni"])
    assert trained == [(["ni"], cfg.data.path)] and ckpt.read_bytes() == b"first"
    # and one that comes out otherwise is refused before any job
    ckpt.unlink()
    retrained = b"third"
    with pytest.raises(ConfigError, match=f"the predictor {ckpt} of scenario 's' is not the one"):
        cli.check_resumed_job(cfg, nodes, ["ni"])
    assert len(trained) == 2
    # jobs on a cluster: trained there by the job, not on the node that submits
    ckpt.unlink()
    hc.launcher = {"_target_": "hydra_plugins.hydra_submitit_launcher.submitit_launcher."
                   "SlurmLauncher"}  # fmt: skip
    cli.check_resumed_job(cfg, nodes, ["ni"])
    assert len(trained) == 2 and not ckpt.exists()
    plugins = "hydra_plugins.hydra_"
    for local in ("joblib_launcher.joblib_launcher.JoblibLauncher",
                  "submitit_launcher.submitit_launcher.LocalLauncher"):  # fmt: skip
        hc.launcher = {"_target_": plugins + local}
        ckpt.unlink(missing_ok=True)
        with pytest.raises(ConfigError, match="is not the one"):
            cli.check_resumed_job(cfg, nodes, ["ni"])
    assert len(trained) == 4


def test_resume_continues_a_run_of_several_scenarios(tmp_path: Path) -> None:
    """An experiment of several scenarios keeps each scenario's rows in its own folder and
    the logs of all in ``episodes/``: stopped during its last scenario, it goes on there."""
    run = tmp_path / "run"
    args = ["experiment=table_simulation", "experiment.planners=[itomp]", "experiment.seeds=[0]",
            "experiment.episode.max_duration_s=1.5", "experiment.write_mcap=true",
            "run.timeline_plots=false", "progress=false", f"hydra.run.dir={run}"]  # fmt: skip
    res = _experiment(args, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    full = _table(run / "results.csv")
    assert len(full) == 9
    # stopped in the last scenario's episode: its log written, no row; no final table
    (run / "confidence_0.99" / "results.csv").unlink()
    (run / "results.csv").unlink()
    res = _experiment([*args, "run.resume=true"], tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.count("finished episode(s) of scenario") == 9
    assert "resuming: 0 finished episode(s) of scenario confidence_0.99 kept" in res.stdout
    assert f"1 log(s) of unfinished episodes kept in {run / 'interrupted'}" in res.stdout
    assert [p.name for p in (run / "interrupted").iterdir()] == [
        "confidence_0.99_medium_n0.01_itomp_s0.mcap"
    ]
    pd.testing.assert_frame_equal(_table(run / "results.csv"), full)


def test_a_run_record_nested_too_deep_is_one_config_error(tmp_path: Path) -> None:
    """A damaged run_inputs.json ("[" * 100000) is refused as any unreadable record is,
    not with the JSON decoder's RecursionError."""
    (tmp_path / cli.RUN_INPUTS).write_text("[" * 100000)
    with pytest.raises(ConfigError, match=r"cannot be read \(JSON nested too deep\), so the run"):
        cli._read_run_inputs(tmp_path)


def test_record_predictors_keeps_the_settings_each_checkpoint_was_trained_with(
    tmp_path: Path,
) -> None:
    """A variant trained on purpose into the folder a run reads (ivm_max_import 30 against the
    config group's 60) was recorded only by its SHA-256, beside the group's settings: now its
    own settings are recorded with its path."""
    import torch

    cli.begin_run(_cfg(False), tmp_path)
    ckpt = tmp_path / "predictor.ckpt"
    torch.save({"cfg": {"ivm_max_import": 30, "svgp": {"num_inducing": 50}}}, ckpt)
    broken = tmp_path / "broken.ckpt"
    broken.write_bytes(b"not a checkpoint")
    cli.record_predictors(tmp_path, "s", {"ni": str(ckpt), "no_ni": str(broken)})
    inputs = json.loads((tmp_path / cli.RUN_INPUTS).read_text())
    entry = inputs["predictor_checkpoints"]["s"]
    assert entry["ni"] == {
        "path": str(ckpt),
        "predictor": {"ivm_max_import": 30, "svgp": {"num_inducing": 50}},
    }
    assert entry["no_ni"] == {"path": str(broken)}  # a file that does not read: its path
    assert set(inputs["predictors"]["s"]) == {"ni", "no_ni"}
