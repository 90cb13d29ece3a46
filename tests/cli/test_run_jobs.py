"""``iplanner-experiment run.jobs=N``: what the run does in its own process around the workers."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd

#: the CLI with its predictor check and its queueing of a scenario's episodes reported on stdout
SCRIPT = """\
import iplanner_torch.cli.experiment as cli
import iplanner_torch.eval.experiment as E

ensure, start = cli.ensure_predictors, E.start_experiment

def ensure_reported(cfg, variants, node):
    print("EVENT predictors", flush=True)
    return ensure(cfg, variants, node)

def start_reported(exp, out, **kw):
    print("EVENT episodes", exp.scenarios[0].name, flush=True)
    return start(exp, out, **kw)

if __name__ == "__main__":  # the spawned workers import this file again
    cli.ensure_predictors, E.start_experiment = ensure_reported, start_reported
    cli.main()
"""


def test_every_scenarios_predictors_come_before_the_first_episode(tmp_path: Path) -> None:
    """Predictors trained while the workers run episodes would share the cores with them:
    every scenario's are checked (and trained when missing) before any episode is queued."""
    script = tmp_path / "run.py"
    script.write_text(SCRIPT)
    run = tmp_path / "run"
    args = ["experiment=table_simulation", "experiment.planners=[itomp]", "experiment.seeds=[0]",
            "experiment.episode.max_duration_s=0.5", "experiment.write_mcap=false",
            "run.timeline_plots=false", "run.jobs=2", "progress=false",
            f"hydra.run.dir={run}"]  # fmt: skip
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    res = subprocess.run(
        [sys.executable, str(script), *args],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-3000:]
    events = [line.split()[1] for line in res.stdout.splitlines() if line.startswith("EVENT")]
    assert events == ["predictors"] * 9 + ["episodes"] * 9
    assert "2 episodes at once, each in a process of its own (run.jobs)" in res.stdout
    assert len(pd.read_csv(run / "results.csv")) == 9
    # no episodes/ folder is named where no log was written
    assert "logs:    none (experiment.write_mcap=false)" in res.stdout
    assert not (run / "episodes").exists() and "MCAP episode log(s)" not in res.stdout
