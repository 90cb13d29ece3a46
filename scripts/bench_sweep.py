#!/usr/bin/env python
"""Benchmark of a sweep's training jobs run side by side on this machine.

A sweep with ``hydra/launcher=joblib hydra.launcher.n_jobs=2`` trains two predictors at once,
each on ``trainer.num_threads`` = 2 OpenMP threads. The sweep gives its job processes
``OMP_WAIT_POLICY=PASSIVE`` (``iplanner_torch.cli.callbacks.passive_omp_waits``); this
measures why.

Figures (``run(quick) -> dict``):

* ``sweep.parallel_train_s``: the slower of two trainings run at the same time, in two
  processes with passive OpenMP waits; reference: the same two with OpenMP's default
  waits (``OMP_WAIT_POLICY`` unset), measured in the same run. The training time is
  measured inside each process, without its start and imports.
* ``sweep.single_train_s``: one such training alone, default waits, for scale.
* ``sweep.single_train_passive_s``: the same with passive waits, against it: why a sweep
  whose jobs have the cores to themselves keeps the default.
* ``sweep.single_train_spin_s``: the same with ``GOMP_SPINCOUNT=1000``, the bounded spin
  every command sets (``iplanner_torch.cli.bounded_omp_spin``), against the default.
* ``sweep.busy_train_s``: one training while a one-thread Python loop keeps a core busy
  (another program on the machine), with the bounded spin; reference: the same with
  OpenMP's default waits. Why the commands bound the spin.

Each training is the quick predictor of ``bench_prediction`` (its ``training_inputs``: 8
targets x 4 reaches, 40 SVGP steps) with ``TrainerCfg(num_threads=2)``.

* ``sweep.grid_jobs2_s``: a grid of closed-loop episodes (ITOMP and ``blind``, 4 seeds of
  6 simulated seconds; ``quick``: 2 seeds of 3 s) run by ``run_experiment`` in two worker
  processes (``episode_pool(2)``, as ``run.jobs=2``), wall clock with the workers' start;
  reference: the same grid one episode after the other in this process (``run.jobs=1``),
  measured in the same run. The rows of the two runs are compared, and must be the same but
  for the wall-clock columns.

Usage::

    python scripts/bench_sweep.py
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from iplanner_torch.cli import OMP_SPIN_COUNT

#: one training, printed as {"train_s": ...}; run in a fresh process per measurement
_TRAIN = r"""
import json, sys, tempfile, time
sys.path.insert(0, sys.argv[1])
from bench_prediction import training_inputs
from iplanner_torch.prediction.training import TrainerCfg, train_predictor

w_train, w_val, _, _, cfg = training_inputs(quick=True)
with tempfile.TemporaryDirectory() as tmp:
    t0 = time.perf_counter()
    train_predictor((w_train, w_val), predictor_cfg=cfg, trainer_cfg=TrainerCfg(num_threads=2),
                    out_dir=tmp, progress=False)
    print(json.dumps({"train_s": time.perf_counter() - t0}))
"""


#: a one-thread busy loop: another program keeping one core busy
_BUSY = "import time\nt = time.time()\nwhile time.time() - t < 900:\n    pass\n"


def _trainings(n: int, policy: str | None, spin: str | None = None) -> list[float]:
    """Run ``n`` trainings at the same time, each in its own process with
    ``OMP_WAIT_POLICY=policy`` and ``GOMP_SPINCOUNT=spin`` (None: unset, OpenMP's default);
    their training seconds."""
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    for key in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "IPLANNER_TORCH_SET_GOMP_SPINCOUNT"):
        env.pop(key, None)
    if policy is not None:
        env["OMP_WAIT_POLICY"] = policy
    if spin is not None:
        env["GOMP_SPINCOUNT"] = spin
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _TRAIN, str(Path(__file__).resolve().parent)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        for _ in range(n)
    ]
    out = []
    for proc in procs:
        stdout, _ = proc.communicate(timeout=900)
        if proc.returncode != 0:
            raise RuntimeError(f"training process failed with exit code {proc.returncode}")
        out.append(float(json.loads(stdout.strip().splitlines()[-1])["train_s"]))
    return out


#: the wall-clock columns of an episode's row (all others must agree between the two runs)
_TIMING = ("sim/realtime_factor", "plan/mean_solve_ms", "eval/prediction_ms", "plan/overruns")


def _grid_jobs(quick: bool) -> dict[str, dict]:
    """``sweep.grid_jobs2_s``: a grid of episodes in two workers against one after the other."""
    import tempfile
    import time
    import warnings

    import pandas as pd

    from iplanner_torch.eval.episode import EpisodeCfg
    from iplanner_torch.eval.experiment import ExperimentCfg, episode_pool, run_experiment
    from iplanner_torch.sim.tasks import ScenarioCfg

    warnings.filterwarnings("ignore", message="replanning cycle")
    grid = ExperimentCfg(
        name="bench",
        planners=["itomp", "blind"],
        seeds=[0, 1] if quick else [0, 1, 2, 3],
        scenarios=[ScenarioCfg(name="s", task_order="(0,1)->(2,3)")],
        episode=EpisodeCfg(max_duration_s=3.0 if quick else 6.0),
        write_mcap=False,
    )
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        serial = run_experiment(grid, Path(tmp) / "serial")
        serial_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        with episode_pool(2) as pool:
            workers = run_experiment(grid, Path(tmp) / "workers", executor=pool)
        workers_s = time.perf_counter() - t0
    cols = [c for c in serial.columns if c not in _TIMING]
    pd.testing.assert_frame_equal(serial[cols], workers[cols])
    return {
        "sweep.grid_jobs2_s": {
            "value": workers_s,
            "unit": "s",
            "reference": serial_s,
            "reference_name": "the same grid one episode after the other (run.jobs=1)",
            "ratio": workers_s / serial_s,
            "episodes": len(serial),
            "cores": os.cpu_count(),
        }
    }


def run(quick: bool = False) -> dict[str, dict]:
    """Time one training alone (after a warm-up one), with the default and with passive
    waits, then two side by side with each (``quick`` changes nothing: the trainings are
    small already); then a grid of episodes in two workers (``quick``: a smaller one)."""
    _trainings(1, None)  # warm-up: the first process compiles (and caches) numba's DTW
    single = _trainings(1, None)[0]
    single_passive = _trainings(1, "PASSIVE")[0]
    single_spin = _trainings(1, None, OMP_SPIN_COUNT)[0]
    passive = max(_trainings(2, "PASSIVE"))
    default = max(_trainings(2, None))
    busy = subprocess.Popen([sys.executable, "-c", _BUSY])
    try:
        busy_spin = _trainings(1, None, OMP_SPIN_COUNT)[0]
        busy_default = _trainings(1, None)[0]
    finally:
        busy.kill()
        busy.wait()
    cores = os.cpu_count()
    return {
        **_grid_jobs(quick),
        "sweep.single_train_s": {"value": single, "unit": "s", "cores": cores},
        "sweep.single_train_passive_s": {
            "value": single_passive,
            "unit": "s",
            "reference": single,
            "reference_name": "sweep.single_train_s (OpenMP's default waits)",
            "ratio": single_passive / single,
            "cores": cores,
        },
        "sweep.single_train_spin_s": {
            "value": single_spin,
            "unit": "s",
            "reference": single,
            "reference_name": "sweep.single_train_s (OpenMP's default waits)",
            "ratio": single_spin / single,
            "cores": cores,
        },
        "sweep.busy_train_s": {
            "value": busy_spin,
            "unit": "s",
            "reference": busy_default,
            "reference_name": "the same training beside the busy loop, OpenMP's default waits",
            "ratio": busy_spin / busy_default,
            "cores": cores,
        },
        "sweep.parallel_train_s": {
            "value": passive,
            "unit": "s",
            "reference": default,
            "reference_name": "the same two trainings with OpenMP's default waits",
            "ratio": passive / default,
            "cores": cores,
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a smaller grid of episodes")
    args = parser.parse_args()
    print(json.dumps(run(args.quick), indent=2))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main()
