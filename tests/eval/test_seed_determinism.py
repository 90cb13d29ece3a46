"""The episode seed decides an episode: the same seed gives the same metrics, events and logged
messages (all but the wall-clock timings), whatever random state the process had before;
another seed gives another person and other tracker noise; every seed the experiment grid
accepts runs."""

from __future__ import annotations

import importlib.util
import math
import random
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch

from iplanner_torch.checks import MAX_SEED
from iplanner_torch.eval.episode import EpisodeCfg, EpisodeResult, run_episode
from iplanner_torch.eval.experiment import ExperimentCfg
from iplanner_torch.recording import read_episode
from iplanner_torch.sim.tasks import ScenarioCfg

_FAKES = Path(__file__).resolve().parents[1] / "sim" / "sim_fakes.py"
_spec = importlib.util.spec_from_file_location("sim_fakes", _FAKES)
fakes = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("sim_fakes", fakes)
_spec.loader.exec_module(fakes)

#: metrics that measure the wall clock, not the episode
WALL_CLOCK_METRICS = {
    "eval/prediction_ms",
    "plan/mean_solve_ms",
    "plan/overruns",
    "sim/realtime_factor",
}
#: logged columns that measure the wall clock
WALL_CLOCK_COLUMNS = {"solve_ms"}


def _episode(tmp_path: Path, seed: int, name: str, *, global_seed: int) -> EpisodeResult:
    """A 2 s I-Planner episode with the stand-in arm, human motion, predictor and planner,
    logged to ``tmp_path / name``, after seeding the global generators with ``global_seed``
    (which the episode must not read)."""
    random.seed(global_seed)
    np.random.seed(global_seed)
    torch.manual_seed(global_seed)
    return run_episode(
        EpisodeCfg(
            scenario=ScenarioCfg(task_order="(0,1)->(2,3)"),
            max_duration_s=2.0,
            task_planner_episodes=20,
        ),
        robot=fakes.FakeArm(tmp_path),
        predictor=fakes.ConstantPredictor(),
        planner_kind="iplanner_ni",
        writer_path=tmp_path / name,
        seed=seed,
        replanner=fakes.LinearReplanner(speed=1.5),
        motion=fakes.FakeMotion(),
    )


def _same(a: Any, b: Any) -> bool:
    """Equal values, NaN equal to NaN, nested in dicts, lists and arrays."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return isinstance(b, list | tuple) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and np.array_equal(a, b, equal_nan=True)
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return bool(a == b)


def _episode_metrics(metrics: dict[str, float]) -> dict[str, float]:
    return {k: v for k, v in metrics.items() if k not in WALL_CLOCK_METRICS}


def _log_differences(a: Path, b: Path) -> list[str]:
    """``topic/column`` of every logged column whose values differ between two logs (wall
    clock timings left out), and ``metadata/<key>`` of every differing metadata entry."""
    ea, eb = read_episode(a), read_episode(b)
    out = [f"metadata/{k}" for k in ea.metadata.keys() | eb.metadata.keys()
           if not _same(ea.metadata.get(k), eb.metadata.get(k))]  # fmt: skip
    for topic in sorted(ea.frames.keys() | eb.frames.keys()):
        fa = ea.frames.get(topic, pd.DataFrame())
        fb = eb.frames.get(topic, pd.DataFrame())
        for col in sorted(set(fa.columns) | set(fb.columns)):
            if col in WALL_CLOCK_COLUMNS:
                continue
            if col not in fa or col not in fb or len(fa) != len(fb):
                out.append(f"{topic}/{col}")
                continue
            values = zip(fa[col], fb[col], strict=True)
            if col == "metrics":
                values = ((_episode_metrics(x), _episode_metrics(y)) for x, y in values)
            if not all(_same(x, y) for x, y in values):
                out.append(f"{topic}/{col}")
    return out


def test_same_seed_same_episode_whatever_the_global_random_state(tmp_path: Path) -> None:
    a = _episode(tmp_path, 3, "a.mcap", global_seed=1)
    b = _episode(tmp_path, 3, "b.mcap", global_seed=2)
    assert _same(_episode_metrics(a.metrics), _episode_metrics(b.metrics))
    assert a.events == b.events
    assert _log_differences(tmp_path / "a.mcap", tmp_path / "b.mcap") == []


def test_another_seed_another_person_and_tracker_noise(tmp_path: Path) -> None:
    """Seeds 3 and 4: the person's own task order differs (drawn from the seed), and so do
    the tracked joints where the true ones do not (the 2 s here precede any difference in
    the person's motion), which is the tracker's noise alone."""
    _episode(tmp_path, 3, "a.mcap", global_seed=1)
    _episode(tmp_path, 4, "b.mcap", global_seed=1)
    differ = _log_differences(tmp_path / "a.mcap", tmp_path / "b.mcap")
    assert "metadata/seed" in differ
    assert "metadata/human_order" in differ  # another person
    assert "/human/joints_true/positions" not in differ
    assert "/human/joints_tracked/positions" in differ  # the tracker's noise


def test_every_seed_the_experiment_grid_accepts_runs_an_episode(tmp_path: Path) -> None:
    """The grid takes seeds up to 2^32 - 1; the tracker's seed is derived from the episode's
    and must stay in range for the largest one too (it was the episode seed + 1 and failed)."""
    assert ExperimentCfg(seeds=[MAX_SEED]).seeds == [MAX_SEED]
    res = run_episode(
        EpisodeCfg(scenario=ScenarioCfg(task_order="0->1->2->3"), max_duration_s=0.5),
        robot=fakes.FakeArm(tmp_path),
        predictor=None,
        planner_kind="itomp",
        writer_path=None,
        seed=MAX_SEED,
        replanner=fakes.LinearReplanner(speed=1.5),
        motion=fakes.FakeMotion(),
    )
    assert res.seed == MAX_SEED and res.metrics["sim/duration_s"] == pytest.approx(0.5, abs=0.02)
