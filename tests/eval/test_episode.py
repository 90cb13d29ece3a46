"""Closed-loop episodes end to end with stand-in planner and predictor (fast), plus a full run."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.errors import ConfigError
from iplanner_torch.eval.episode import EpisodeCfg, TableClearance, run_episode
from iplanner_torch.sim.scene import SceneCfg
from iplanner_torch.sim.tasks import ScenarioCfg

_FAKES = Path(__file__).resolve().parents[1] / "sim" / "sim_fakes.py"
_spec = importlib.util.spec_from_file_location("sim_fakes", _FAKES)
fakes = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("sim_fakes", fakes)
_spec.loader.exec_module(fakes)


def _cfg(seconds: float, **scenario) -> EpisodeCfg:
    return EpisodeCfg(
        scenario=ScenarioCfg(task_order="0->1->2->3", **scenario), max_duration_s=seconds
    )


def test_short_iplanner_episode_writes_mcap(tmp_path: Path) -> None:
    from iplanner_torch.recording.reader import read_episode

    arm = fakes.FakeArm(tmp_path)
    predictor = fakes.ConstantPredictor()
    replanner = fakes.LinearReplanner(speed=1.5)
    path = tmp_path / "ep.mcap"
    res = run_episode(
        _cfg(5.0),
        robot=arm,
        predictor=predictor,
        planner_kind="iplanner_ni",
        writer_path=path,
        seed=3,
        replanner=replanner,
        motion=fakes.FakeMotion(),
    )
    kinds = [k for _, k, _ in res.events]
    assert kinds[:3] == ["fetch_started", "picked", "delivered"]
    took = [(t, b) for t, k, b in res.events if k == "human_took"]
    assert took and took[0][1] == 0
    # one forecast per replanning step m = 0.5 s, from the 15-frame tracker window
    assert len(predictor.calls) == 10 == res.metrics["plan/cycles"]
    pos, progress = predictor.calls[-1]
    assert tuple(pos.shape) == (1, 15, 10, 3)
    assert progress.tolist() == [1]  # Take_0 done -> bit of "reach_0"
    assert predictor.calls[0][1].tolist() == [0]
    m = res.metrics
    assert m["sim/duration_s"] == pytest.approx(5.0, abs=0.02)
    assert m["eval/smoothness"] > 0 and math.isfinite(m["eval/jerkiness"])
    assert 0.0 < m["eval/min_distance"] < 2.0
    assert m["eval/prediction_ms"] > 0
    assert math.isnan(m["eval/efficiency"]) and m["eval/completed"] == 0.0
    ep = read_episode(path)
    assert ep.metrics()["plan/cycles"] == 10
    assert [e["kind"] for e in ep.events()][:3] == kinds[:3]
    t, q = ep.robot_q()
    assert q.shape[1] == 3 and len(t) >= 70


def test_itomp_sees_the_observed_pose_only(tmp_path: Path) -> None:
    replanner = fakes.LinearReplanner()
    res = run_episode(
        _cfg(1.2),
        robot=fakes.FakeArm(tmp_path),
        predictor=None,
        planner_kind="itomp",
        writer_path=None,
        seed=0,
        replanner=replanner,
        motion=fakes.FakeMotion(),
    )
    forecast = replanner.forecasts[0][1]
    assert forecast.action_names == ("observed",)
    # the static forecast holds the tracked rest pose (1 cm tracker noise)
    rest = fakes.rest_pose()
    np.testing.assert_allclose(forecast.mean[0, 0, -1].numpy(), rest, atol=0.05)
    assert math.isnan(res.metrics["eval/mhd"]) and res.mcap_path is None


def test_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="needs a predictor"):
        run_episode(
            _cfg(1.0), robot=fakes.FakeArm(tmp_path), predictor=None,
            planner_kind="iplanner_ni", writer_path=None, seed=0,
        )  # fmt: skip
    with pytest.raises(ConfigError, match="planner_kind"):
        run_episode(
            _cfg(1.0), robot=fakes.FakeArm(tmp_path), predictor=None,
            planner_kind="rrt", writer_path=None, seed=0,  # type: ignore[arg-type]
        )  # fmt: skip
    with pytest.raises(ConfigError, match="max_duration_s"):
        EpisodeCfg(max_duration_s=0.0)


def test_table_clearance_against_brute_force() -> None:
    import torch

    scene = SceneCfg()
    table = TableClearance(scene, np.array([0.75, 0.0]))
    c = torch.tensor([[0.0, 0.0, 0.10], [0.0, 0.0, -0.01], [2.0, 0.0, 0.0]])
    r = torch.tensor([0.05, 0.01, 0.05])
    d = table.clearance(c, r)
    # above the top: height minus radius; inside: minus depth to the top and radius
    assert d[0] == pytest.approx(0.05) and d[1] == pytest.approx(-0.02)
    far_x = scene.table_center_x + 0.5 * scene.table_size[0]
    assert d[2] == pytest.approx(2.0 - far_x - 0.05)


@pytest.mark.slow
def test_full_episode_completes_all_tasks(tmp_path: Path) -> None:
    res = run_episode(
        EpisodeCfg(scenario=ScenarioCfg(task_order="(0,1)->(2,3)"), max_duration_s=90.0),
        robot=fakes.FakeArm(tmp_path),
        predictor=fakes.ConstantPredictor(),
        planner_kind="iplanner_no_ni",
        writer_path=tmp_path / "full.mcap",
        seed=1,
        replanner=fakes.LinearReplanner(speed=1.5),
        motion=fakes.FakeMotion(),
    )
    kinds = [k for _, k, _ in res.events]
    assert kinds.count("delivered") == 4 and kinds.count("human_took") == 4
    assert kinds[-1] == "done" and res.metrics["eval/completed"] == 1.0
    assert res.metrics["eval/efficiency"] > 0
    assert res.metrics["eval/mhd_count"] > 0
