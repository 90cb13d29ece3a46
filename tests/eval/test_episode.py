"""Closed-loop episodes end to end with stand-in planner and predictor (fast), plus a full run."""

from __future__ import annotations

import importlib.util
import math
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.eval.episode import (
    EpisodeCfg,
    StallWatch,
    TableClearance,
    available_blocks,
    defer_crossed_fetch,
    run_episode,
    tracked_hands,
)
from iplanner_torch.eval.metrics import jerkiness, smoothness
from iplanner_torch.prediction.forecast import Forecast
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


def _fake_episode(tmp_path, cfg, kind, replanner, *, predictor=None, path=None, seed=0):
    """``run_episode`` with the stand-in arm and human motion (no MuJoCo robot model)."""
    return run_episode(
        cfg,
        robot=fakes.FakeArm(tmp_path),
        predictor=predictor,
        planner_kind=kind,
        writer_path=path,
        seed=seed,
        replanner=replanner,
        motion=fakes.FakeMotion(),
    )


def test_distance_prediction_time_and_realtime_factor_from_the_log(
    tmp_path: Path, fake_clock
) -> None:
    """``eval/min_distance`` equals a brute-force minimum over every sphere pair of the logged
    robot states and true human joints (logged at the metrics' rate here); the timing
    metrics equal what a fake clock implies: 2.5 ms per forecast, no other wall time."""
    import iplanner_torch.eval.episode as episode_module
    from iplanner_torch.collision.human_spheres import HumanSphereMap
    from iplanner_torch.recording.reader import read_episode

    clock = fake_clock(episode_module)

    class ClockedPredictor(fakes.ConstantPredictor):
        def predict_positions(self, positions, progress):
            clock.now += 0.0025
            return super().predict_positions(positions, progress)

    predictor = ClockedPredictor()
    path = tmp_path / "ep.mcap"
    cfg = replace(_cfg(3.0), metrics_hz=25.0)  # the log follows the metric rate
    res = _fake_episode(tmp_path, cfg, "iplanner_ni", fakes.LinearReplanner(speed=1.5),
                        predictor=predictor, path=path, seed=1)  # fmt: skip
    m = res.metrics
    n_calls = len(predictor.calls)
    assert n_calls >= 6
    assert m["eval/prediction_ms"] == pytest.approx(2.5)
    assert m["sim/realtime_factor"] == pytest.approx(m["sim/duration_s"] / (0.0025 * n_calls))
    ep = read_episode(path)
    t_q, q = ep.robot_q()
    t_h, joints = ep.human_true()
    assert torch.equal(t_q, t_h) and len(t_q) == pytest.approx(25 * 3.0, abs=2)
    assert ep.metadata["metrics_hz"] == ep.metadata["log_hz"] == pytest.approx(25.0)
    # the log holds the metric's own samples: smoothness and jerkiness follow from it
    assert smoothness(t_q, q) == pytest.approx(m["eval/smoothness"], rel=1e-12)
    assert jerkiness(t_q, q) == pytest.approx(m["eval/jerkiness"], rel=1e-12)
    arm = fakes.FakeArm(tmp_path)
    smap = HumanSphereMap.from_segments(JOINT_NAMES)
    robot_c = arm.sphere_centers(q.to(arm.q_home.dtype)).double()  # (T, 5, 3)
    human_c = torch.einsum("sk,tkc->tsc", smap.matrix.double(), joints)  # (T, S_h, 3)
    best = math.inf
    for rc, hc in zip(robot_c.tolist(), human_c.tolist(), strict=True):
        for a, ra in zip(rc, arm.sphere_radii.tolist(), strict=True):
            for b, rb in zip(hc, smap.radii.tolist(), strict=True):
                best = min(best, math.dist(a, b) - ra - rb)
    assert 0.0 < best < 1.0  # the arm works beside the person: a distance worth checking
    assert m["eval/min_distance"] == pytest.approx(best, abs=1e-6)


def test_efficiency_of_a_completed_episode_against_the_closed_form(tmp_path: Path) -> None:
    """A completed episode: ``eval/task_time_s`` is when the person took the last block,
    ``eval/human_alone_s`` the closed-form time of doing every task alone (stand-in reaches
    to each block's far position and delivery spot, plus the mean idle), and
    ``eval/efficiency`` their ratio."""
    cfg = _cfg(60.0)
    res = _fake_episode(tmp_path, cfg, "itomp", fakes.LinearReplanner(speed=1.5), seed=0)
    m = res.metrics
    took = [(t, b) for t, k, b in res.events if k == "human_took"]
    assert m["eval/completed"] == 1.0 and [b for _, b in took] == [0, 1, 2, 3]
    assert m["eval/task_time_s"] == pytest.approx(took[-1][0])
    scene, human = cfg.scene_cfg(), cfg.sim.human
    lift = np.array([0.0, 0.0, 0.04 - 0.5 * scene.block_size])
    far = {i: scene.block_position(i) + lift for i in scene.block_ids}
    spots = {i: scene.delivery_position(i) + lift for i in scene.block_ids}
    alone = fakes.fake_solo_duration(
        (0, 1, 2, 3),
        far,
        spots,
        speed=human.speed_factor,
        hold_s=human.hold_s,
        idle_s=human.idle_s,
    )
    assert m["eval/human_alone_s"] == pytest.approx(alone, rel=1e-9)
    assert m["eval/efficiency"] == pytest.approx(alone / took[-1][0], rel=1e-9)


def test_short_iplanner_episode_writes_mcap(tmp_path: Path) -> None:
    from iplanner_torch.recording.reader import read_episode

    predictor = fakes.ConstantPredictor()
    replanner = fakes.LinearReplanner(speed=1.5)
    path = tmp_path / "ep.mcap"
    res = _fake_episode(
        tmp_path, _cfg(5.0), "iplanner_ni", replanner, predictor=predictor, path=path, seed=3
    )
    kinds = [k for _, k, _ in res.events]
    assert kinds[:3] == ["fetch_started", "picked", "delivered"]
    took = [(t, b) for t, k, b in res.events if k == "human_took"]
    assert took and took[0][1] == 0
    # one forecast per replanning cycle: every m = 0.5 s, and at once after each goal change
    cycle_t = np.array([t for t, _ in replanner.forecasts])
    assert len(predictor.calls) == len(cycle_t) == res.metrics["plan/cycles"]
    changes = [t for t, k, _ in res.events if k in ("picked", "delivered", "fetch_done")]
    assert changes
    for t_ev in changes:
        assert np.abs(cycle_t - t_ev).min() <= 0.011  # the control step after the event
    gaps = np.diff(cycle_t)
    assert gaps.max() <= 0.5 + 1e-6
    regular = [g for g, t1 in zip(gaps, cycle_t[1:]) if min(abs(t1 - c) for c in changes) > 0.011]
    np.testing.assert_allclose(regular, 0.5, atol=0.011)
    assert len(cycle_t) >= 10 + 1
    pos, progress = predictor.calls[-1]
    assert tuple(pos.shape) == (1, 15, 10, 3)
    # Take_i done -> bit of "reach_<i>" (the stand-in knows reach_0 and reach_1 only)
    taken = {b for t, k, b in res.events if k == "human_took" and t <= cycle_t[-1]}
    assert taken and progress.tolist() == [sum(1 << b for b in taken if b < 2)]
    assert predictor.calls[0][1].tolist() == [0]
    m = res.metrics
    assert m["sim/duration_s"] == pytest.approx(5.0, abs=0.02)
    assert m["eval/smoothness"] > 0 and math.isfinite(m["eval/jerkiness"])
    assert math.isnan(m["eval/efficiency"]) and m["eval/completed"] == 0.0
    ep = read_episode(path)
    assert ep.metrics()["plan/cycles"] == len(cycle_t)
    meta = ep.metadata
    assert meta["planner"] == "iplanner_ni" and meta["seed"] == 3
    assert meta["speed"] == "medium" and meta["noise"] == pytest.approx(0.01)
    assert meta["scenario"] == "arrangement_1x4" and meta["confidence"] == pytest.approx(0.95)
    assert [e["kind"] for e in ep.events()][:3] == kinds[:3]
    t, q = ep.robot_q()
    assert q.shape[1] == 3 and len(t) >= 70
    # the 3D scene at scene_hz (5 Hz): the robot's spheres at the logged q, the person's
    # spheres on the true joints, and 2 x K predicted joint ellipsoids from the first forecast
    from iplanner_torch.collision.human_spheres import HumanSphereMap

    t_s, robot_s, human_s = ep.scene_spheres()
    assert len(t_s) == pytest.approx(5.0 * 5.0, abs=1)
    arm = fakes.FakeArm(tmp_path)
    smap = HumanSphereMap.from_segments(JOINT_NAMES)
    t_h, true = ep.human_true()
    same = [(i, int((t - ts).abs().argmin())) for i, ts in enumerate(t_s)]
    same = [(i, j) for i, j in same if float((t[j] - t_s[i]).abs()) < 1e-6]
    assert len(same) >= 3  # steps where the 15 Hz robot state and the 5 Hz scene coincide
    close = dict(atol=1e-6, rtol=0)
    for i, j in same:
        centres = arm.sphere_centers(q[j].to(arm.q_home.dtype)).double()
        torch.testing.assert_close(robot_s[i, :, :3], centres, **close)
        torch.testing.assert_close(robot_s[i, :, 3], arm.sphere_radii.double(), **close)
        torch.testing.assert_close(human_s[i, :, :3], smap.matrix.double() @ true[j], **close)
        torch.testing.assert_close(human_s[i, :, 3], smap.radii.double(), **close)
    counts = [len(e) for e in ep.frames["/scene"]["ellipsoids"]]
    assert counts[-1] == 2 * len(JOINT_NAMES) and set(counts) <= {0, 2 * len(JOINT_NAMES)}
    quiet = tmp_path / "no_scene.mcap"
    no_scene = replace(_cfg(1.0), scene_hz=0.0)
    predictor = fakes.ConstantPredictor()
    _fake_episode(tmp_path, no_scene, "iplanner_ni", fakes.LinearReplanner(),
                  predictor=predictor, path=quiet)  # fmt: skip
    assert "/scene" not in read_episode(quiet).frames


def test_tracked_joints_are_logged_frame_by_frame_at_their_own_times(tmp_path: Path) -> None:
    """Each tracker frame once, stamped with the time it was taken: the k-th at the first
    control step at or after k / 15 s. They used to be sampled on the robot's log grid (every
    7th step) and stamped with its time, up to 60 ms after the frame, and 1 in 20 was never
    logged."""
    from iplanner_torch.recording.reader import read_episode

    path = tmp_path / "ep.mcap"
    cfg = _cfg(3.0)
    cfg = replace(cfg, sim=replace(cfg.sim, tracker_noise=0.0, tracker_dropout=0.0))
    _fake_episode(tmp_path, cfg, "iplanner_ni", fakes.LinearReplanner(),
                  predictor=fakes.ConstantPredictor(), path=path)  # fmt: skip
    ep = read_episode(path)
    t_k, tracked = ep.human_tracked()
    k = np.arange(len(t_k))
    assert len(t_k) == math.floor(3.0 * 15 + 1e-6) + 1  # frames at 0, 1/15, ..., 3 s
    offset = t_k.numpy() - k / 15.0  # the frame waits for the first 0.01 s step
    assert offset.min() >= -1e-9 and offset.max() < 0.01 + 1e-9
    # no noise, no dropout: a frame is the true pose at its own time, wherever the true
    # joints were logged at that time too
    t_h, true = ep.human_true()
    both = [(i, j) for i, ti in enumerate(t_k) for j, tj in enumerate(t_h) if abs(ti - tj) < 1e-9]
    assert len(both) >= 5
    for i, j in both:
        torch.testing.assert_close(tracked[i], true[j], atol=1e-6, rtol=0)
    # the robot state and the true joints stay on the log grid: the metric rate, 25 Hz
    # (every 4th 0.01 s step)
    t_r, _ = ep.robot_q()
    np.testing.assert_allclose(np.diff(t_r.numpy()), 0.04, atol=1e-9)
    torch.testing.assert_close(t_h, t_r)


def test_an_episode_too_short_for_smoothness_still_closes_its_log(tmp_path: Path) -> None:
    """0.1 s at 25 Hz gives 2 metric samples: no acceleration, so NaN smoothness and
    jerkiness; the episode's metrics are still written and its log closed."""
    from iplanner_torch.recording.reader import read_episode

    path = tmp_path / "short.mcap"
    res = _fake_episode(tmp_path, _cfg(0.1), "iplanner_ni", fakes.LinearReplanner(speed=1.5),
                        predictor=fakes.ConstantPredictor(), path=path)  # fmt: skip
    m = res.metrics
    assert math.isnan(m["eval/smoothness"]) and math.isnan(m["eval/jerkiness"])
    assert m["sim/duration_s"] == pytest.approx(0.1) and math.isfinite(m["eval/min_distance"])
    ep = read_episode(path)
    assert ep.complete
    assert math.isnan(ep.metrics()["eval/smoothness"]) and ep.metrics()["plan/cycles"] == 1.0
    # one control step: no metric sample at all
    res = _fake_episode(tmp_path, _cfg(0.01), "itomp", fakes.LinearReplanner(), path=path)
    assert math.isnan(res.metrics["eval/smoothness"]) and read_episode(path).complete
    with pytest.raises(ConfigError, match=r"expected max_duration_s at least one control period"):
        _cfg(0.004)


def test_a_failure_in_the_metrics_still_closes_the_log(tmp_path: Path, monkeypatch) -> None:
    import iplanner_torch.eval.episode as episode_module
    from iplanner_torch.recording.reader import read_episode

    def broken(**kwargs):
        raise RuntimeError("metrics failed")

    monkeypatch.setattr(episode_module, "_metrics", broken)
    path = tmp_path / "ep.mcap"
    with pytest.raises(RuntimeError, match="metrics failed"):
        _fake_episode(tmp_path, _cfg(0.5), "itomp", fakes.LinearReplanner(), path=path)
    ep = read_episode(path)
    assert ep.complete and [e["kind"] for e in ep.events()][-1] == "interrupted"


def test_forecast_ellipsoids_match_samples_of_the_mixture() -> None:
    """The moment-matched ellipsoids against the sample mean and covariance of the action
    mixture itself (Monte Carlo)."""
    import torch

    from iplanner_torch.eval.episode import forecast_ellipsoids

    g = torch.Generator().manual_seed(0)
    a, n_f, k = 3, 15, 2
    mean = torch.randn(1, a, n_f, k, 3, generator=g, dtype=torch.float64) * 0.2
    var = torch.rand(1, a, n_f, k, 3, generator=g, dtype=torch.float64) * 0.01
    weights = torch.tensor([[0.5, 0.3, 0.2]], dtype=torch.float64)
    fc = Forecast(weights=weights, mean=mean, var=var, dt=1 / 15,
                  joint_names=("a", "b"), action_names=("x", "y", "z"))  # fmt: skip
    out = forecast_ellipsoids(fc, (0.4, 1.0, 3.0))  # 3 s lies beyond the 1 s horizon
    assert len(out) == 2 * k
    n = 400_000
    for i, (h, joint) in enumerate([(0.4, 0), (0.4, 1), (1.0, 0), (1.0, 1)]):
        f = round(h * 15) - 1  # the frame at h seconds
        act = torch.multinomial(weights[0], n, replacement=True, generator=g)
        x = mean[0, act, f, joint] + var[0, act, f, joint].sqrt() * torch.randn(
            n, 3, generator=g, dtype=torch.float64
        )
        m, c = out[i]
        np.testing.assert_allclose(m, x.mean(0).numpy(), atol=2e-3)
        np.testing.assert_allclose(c, np.cov(x.numpy().T), atol=2e-3)


def test_itomp_sees_the_observed_pose_only(tmp_path: Path) -> None:
    replanner = fakes.LinearReplanner()
    res = _fake_episode(tmp_path, _cfg(1.2), "itomp", replanner)
    forecast = replanner.forecasts[0][1]
    assert forecast.action_names == ("observed",)
    # the static forecast holds the tracked rest pose (1 cm tracker noise)
    rest = fakes.rest_pose()
    np.testing.assert_allclose(forecast.mean[0, 0, -1].numpy(), rest, atol=0.05)
    assert math.isnan(res.metrics["eval/mhd"]) and res.mcap_path is None
    assert float(forecast.var.max()) == pytest.approx(1e-4)  # 1 cm, held still
    # planner.itomp_spread_mps widens the held pose with time (std 1 cm + 0.2 m/s t)
    base = _cfg(0.6)
    wide = replace(base, planner=replace(base.planner, itomp_spread_mps=0.2))
    replanner = fakes.LinearReplanner()
    _fake_episode(tmp_path, wide, "itomp", replanner)
    forecast = replanner.forecasts[0][1]
    std = forecast.var[0, 0, :, 0, 0].sqrt()
    np.testing.assert_allclose(std.numpy(), (0.01 + 0.2 * forecast.times).numpy(), rtol=1e-5)


def test_oracle_plans_on_the_true_future(tmp_path: Path) -> None:
    """The oracle's forecasts are the poses the simulated person then goes through (read back
    from the episode log), and it fetches in the person's own order."""
    from iplanner_torch.recording.reader import read_episode

    replanner = fakes.LinearReplanner(speed=1.5)
    path = tmp_path / "oracle.mcap"
    cfg = EpisodeCfg(scenario=ScenarioCfg(task_order="(0,1)->(2,3)"), max_duration_s=12.0)
    res = _fake_episode(tmp_path, cfg, "oracle", replanner, path=path, seed=1)
    ep = read_episode(path)
    fetched = [b for _, k, b in res.events if k == "fetch_started"]
    assert len(fetched) >= 2 and fetched == ep.metadata["human_order"][: len(fetched)]
    landed = [t for t, k, _ in res.events if k == "delivered"]
    t_true, true = ep.human_true()
    t_true, true = t_true.numpy(), true.numpy()
    compared = moving = 0
    for t0, forecast in replanner.forecasts:
        assert forecast.action_names == ("oracle",)
        times = t0 + forecast.times.numpy()
        if any(t0 < t_l <= times[-1] for t_l in landed):
            continue  # a delivery within the span changes what the person does
        moving += float(np.ptp(forecast.mean[0, 0].numpy(), axis=0).max()) > 0.05
        for k, tk in enumerate(times):
            i = np.searchsorted(t_true, tk - 1e-6)
            if i < len(t_true) and abs(t_true[i] - tk) < 1e-6:
                np.testing.assert_allclose(forecast.mean[0, 0, k].numpy(), true[i], atol=1e-6)
                compared += 1
    assert compared >= 20 and moving >= 3
    assert res.metrics["eval/mhd"] < 0.005
    t_fc, logged = ep.forecasts()  # the log keeps every forecast the oracle planned on
    assert logged.action_names == ("oracle",) and len(t_fc) == len(replanner.forecasts)


def test_blind_plans_with_nobody_there(tmp_path: Path) -> None:
    """``blind`` hands the replanner no forecast in any cycle and logs none; the person still
    moves and counts. With a replanner that ignores forecasts it is ITOMP's episode exactly
    (same fetch order, events and distances)."""
    from iplanner_torch.recording.reader import read_episode

    cfg = EpisodeCfg(scenario=ScenarioCfg(task_order="(0,1)->(2,3)"), max_duration_s=12.0)
    blind = fakes.LinearReplanner(speed=1.5)
    res = _fake_episode(tmp_path, cfg, "blind", blind, path=tmp_path / "blind.mcap", seed=1)
    assert len(blind.forecasts) > 5 and all(f is None for _, f in blind.forecasts)
    itomp = fakes.LinearReplanner(speed=1.5)
    ref = _fake_episode(tmp_path, cfg, "itomp", itomp, seed=1)
    assert all(f is not None for _, f in itomp.forecasts)
    assert res.events == ref.events and any(k == "delivered" for _, k, _ in res.events)
    for name in ("eval/min_distance", "sim/body_distance", "eval/smoothness"):
        assert res.metrics[name] == ref.metrics[name], name
    assert math.isnan(res.metrics["eval/mhd"])
    ep = read_episode(tmp_path / "blind.mcap")
    assert ep.metadata["planner"] == "blind"
    with pytest.raises(DataError):
        ep.forecasts()


def test_iplanner_cv_plans_on_the_tracked_motion_extended(tmp_path: Path) -> None:
    """``iplanner_cv`` builds its constant-velocity predictor from ``EpisodeCfg.cv``: each
    forecast is numpy's straight line through the last tracked frames of the log, extended;
    with no next-action model it fetches as ITOMP does."""
    from iplanner_torch.prediction.constant_velocity import ACTION, ConstantVelocityCfg
    from iplanner_torch.recording.reader import read_episode

    cfg = EpisodeCfg(
        scenario=ScenarioCfg(task_order="(0,1)->(2,3)"),
        max_duration_s=12.0,
        cv=ConstantVelocityCfg(fit_frames=4, n_future=10, spread_mps=0.2),
    )
    replanner = fakes.LinearReplanner(speed=1.5)
    path = tmp_path / "cv.mcap"
    res = _fake_episode(tmp_path, cfg, "iplanner_cv", replanner, path=path, seed=1)
    ep = read_episode(path)
    assert ep.metadata["planner"] == "iplanner_cv"
    t_tr, tracked = ep.human_tracked()
    t_tr, tracked = t_tr.numpy(), tracked.numpy()
    compared = moving = 0
    for t0, forecast in replanner.forecasts:
        assert forecast.action_names == (ACTION,) and forecast.mean.shape[2] == 10
        i = int(np.searchsorted(t_tr, t0 + 1e-9))  # the frames seen up to t0
        x_fit = tracked[i - 4 : i]
        if i < 4 or not np.isfinite(x_fit).all() or abs(t_tr[i - 1] - t0) > 1e-6:
            continue
        # frames 1 / fps apart, as the predictor takes them (the tracker samples at the
        # control ticks nearest to that)
        t_fit = (np.arange(4) - 3) / cfg.sim.tracker_fps
        ahead = forecast.times.numpy()
        for k in (0, 5, 9):  # joints
            for c in range(3):
                slope, icpt = np.polyfit(t_fit, x_fit[:, k, c], 1)
                np.testing.assert_allclose(
                    forecast.mean[0, 0, :, k, c].numpy(), icpt + slope * ahead, atol=1e-4
                )
        compared += 1
        moving += float(np.ptp(forecast.mean[0, 0].numpy(), axis=0).max()) > 0.02
    assert compared >= 10 and moving >= 2
    assert math.isfinite(res.metrics["eval/mhd"])
    itomp = fakes.LinearReplanner(speed=1.5)
    ref = _fake_episode(tmp_path, cfg, "itomp", itomp, seed=1)
    fetched = [b for _, k, b in res.events if k == "fetch_started"]
    assert fetched == [b for _, k, b in ref.events if k == "fetch_started"] and fetched


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
    with pytest.raises(ConfigError, match="oracle_std"):
        EpisodeCfg(oracle_std=0.0)
    with pytest.raises(ConfigError, match="stall_fallback_s"):
        EpisodeCfg(stall_fallback_s=0.0)
    with pytest.raises(ConfigError, match="still_radius"):
        EpisodeCfg(still_radius=-0.1)
    for bad in (-1.0, math.inf, math.nan):
        with pytest.raises(ConfigError, match="expected scene_hz >= 0 and finite"):
            EpisodeCfg(scene_hz=bad)
    # every rate, horizon and count by name, NaN and infinities refused (NaN passed before)
    for name in ("metrics_hz", "log_hz", "mhd_horizon_s", "static_forecast_dt", "oracle_std"):
        for bad in (0.0, math.inf, math.nan):
            with pytest.raises(ConfigError, match=f"expected {name} > 0 and finite"):
                EpisodeCfg(**{name: bad})
    for name in ("mhd_min_motion", "blocking_tail_s"):
        with pytest.raises(ConfigError, match=f"expected {name} >= 0 and finite"):
            EpisodeCfg(**{name: math.nan})
    for name, bad in (("torch_threads", 1.5), ("task_planner_episodes", 1.5),
                      ("static_forecast_frames", 0)):  # fmt: skip
        with pytest.raises(ConfigError, match=f"expected {name} an integer"):
            EpisodeCfg(**{name: bad})


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        # a text duration failed with "'>' not supported between instances of 'str' and 'int'"
        ({"max_duration_s": "30"}, r"expected max_duration_s > 0, got '30'"),
        ({"max_duration_s": True}, "expected max_duration_s > 0"),
        ({"max_duration_s": None}, "expected max_duration_s > 0"),
        ({"static_forecast_frames": "30"}, "expected static_forecast_frames an integer"),
        ({"static_forecast_dt": "0.1"}, "expected static_forecast_dt > 0 and finite"),
        ({"scene_hz": "5"}, "expected scene_hz >= 0 and finite"),
        ({"torch_threads": "1"}, "expected torch_threads an integer"),
        ({"task_planner_episodes": 300.0}, "expected task_planner_episodes an integer"),
        ({"stall_fallback_s": "5"}, r"expected stall_fallback_s > 0 or None, got '5'"),
        ({"stall_fallback_s": math.nan}, "expected stall_fallback_s > 0 or None"),
        ({"still_radius": "0.08"}, "expected still_radius > 0 and finite"),
        ({"still_radius": math.nan}, "expected still_radius > 0 and finite"),
        ({"still_radius": math.inf}, "expected still_radius > 0 and finite"),
        ({"progress_bar": "yes"}, "expected progress_bar True or False"),
        ({"direct_next_fetch": 1}, "expected direct_next_fetch True or False"),
        ({"replan_on_goal_change": "true"}, "expected replan_on_goal_change True or False"),
        ({"mask_unavailable_actions": None}, "expected mask_unavailable_actions True or False"),
        ({"rest_when_nothing_available": 0}, "expected rest_when_nothing_available True or"),
        ({"mask_by_order": "no"}, "expected mask_by_order True or False"),
        ({"task_crossing_radius": -0.1}, "expected task_crossing_radius >= 0"),
        ({"task_crossing_radius": "0.1"}, "expected task_crossing_radius >= 0"),
        ({"task_crossing_radius": math.nan}, "expected task_crossing_radius >= 0"),
        ({"reaction_s": -0.3}, "expected reaction_s >= 0"),
        ({"reaction_s": "0.3"}, "expected reaction_s >= 0"),
        ({"reaction_s": math.nan}, "expected reaction_s >= 0"),
        ({"spread_tolerance": 0.0}, "expected spread_tolerance > 0"),
        ({"spread_tolerance": "2"}, "expected spread_tolerance > 0"),
        ({"spread_max_scale": 0.5}, "expected spread_max_scale >= 1"),
        ({"spread_max_scale": math.inf}, "expected spread_max_scale a finite number"),
        ({"spread_memory_s": math.nan}, "expected spread_memory_s > 0"),
        ({"scenario": {}}, "expected scenario a ScenarioCfg, got dict"),
        ({"sim": None}, "expected sim a SimCfg, got NoneType"),
        ({"planner": "iplanner"}, "expected planner a PlannerCfg, got str"),
    ],
)
def test_wrongly_typed_settings_are_config_errors_naming_the_field(
    kwargs: dict, match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        EpisodeCfg(**kwargs)


def test_valid_settings_keep_their_values() -> None:
    cfg = EpisodeCfg(
        max_duration_s=math.inf, stall_fallback_s=math.inf, torch_threads=None, scene_hz=0
    )
    assert cfg.max_duration_s == math.inf and cfg.stall_fallback_s == math.inf
    assert EpisodeCfg(max_duration_s=30, stall_fallback_s=None).max_duration_s == 30


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
    res = _fake_episode(
        tmp_path,
        EpisodeCfg(scenario=ScenarioCfg(task_order="(0,1)->(2,3)"), max_duration_s=90.0),
        "iplanner_no_ni",
        fakes.LinearReplanner(speed=1.5),
        predictor=fakes.ConstantPredictor(),
        path=tmp_path / "full.mcap",
        seed=1,
    )
    kinds = [k for _, k, _ in res.events]
    assert kinds.count("delivered") == 4 and kinds.count("human_took") == 4
    assert kinds[-1] == "done" and res.metrics["eval/completed"] == 1.0
    assert res.metrics["eval/efficiency"] > 0
    assert res.metrics["eval/mhd_count"] > 0


@pytest.mark.slow
@pytest.mark.parametrize(
    "kind", ["itomp", "iplanner_no_ni", "iplanner_ni", "iplanner_cv", "oracle", "blind"]
)
def test_real_kuka_episode_delivers_every_block(tmp_path: Path, kind: str) -> None:
    """The real ITOMP / I-Planner optimiser on the KUKA iiwa in MuJoCo (stand-in predictor)."""
    from iplanner_torch.recording.reader import read_episode
    from iplanner_torch.robot.model import RobotModel

    robot = RobotModel.load("kuka_iiwa14")
    path = tmp_path / f"{kind}.mcap"
    res = run_episode(
        EpisodeCfg(scenario=ScenarioCfg(task_order="(0,1)->(2,3)"), max_duration_s=60.0),
        robot=robot,
        predictor=None
        if kind in ("itomp", "iplanner_cv", "oracle", "blind")
        else fakes.ConstantPredictor(),
        planner_kind=kind,  # type: ignore[arg-type]
        writer_path=path,
        seed=0,
    )
    kinds = [k for _, k, _ in res.events]
    assert kinds.count("delivered") == 4 and kinds.count("human_took") == 4
    assert res.metrics["eval/completed"] == 1.0
    for name in ("eval/smoothness", "eval/min_distance", "eval/efficiency", "plan/mean_solve_ms"):
        assert math.isfinite(res.metrics[name]), name
    ep = read_episode(path)
    assert ep.metadata["planner"] == kind
    assert ep.metrics()["eval/completed"] == 1.0


def test_task_policy_follows_the_predicted_next_action() -> None:
    """The Q-learning task planner fetches first what the next-action model says comes next."""
    import torch

    from iplanner_torch.eval.episode import predictor_task_policy
    from iplanner_torch.sim.tasks import parse_order

    class NextPredictor:
        action_names = ("idle", "reach_0", "reach_1", "reach_2", "reach_3", "return")

        def next_action(self, progress: int, current: int) -> torch.Tensor:
            p = torch.full((6,), 0.01)
            # nothing taken: the human goes for block 1, then for block 0; then 3 before 2
            p[2 if progress == 0 else 1 if progress == 1 << 2 else 4] = 1.0
            return p / p.sum()

    order = parse_order("(0,1)->(2,3)", (0, 1, 2, 3))
    policy = predictor_task_policy(NextPredictor(), (0, 1, 2, 3), order, episodes=200, seed=0)
    assert policy is not None
    assert policy(set(), set()) == 1
    assert policy(set(), {1}) == 0
    assert policy({0, 1}, {0, 1}) == 3
    assert policy({0, 1, 2, 3}, {0, 1, 2, 3}) is None
    assert predictor_task_policy(fakes.ConstantPredictor(), (0, 1, 2, 3), order) is None


def test_stall_watch() -> None:
    still = np.array([[0.1, 0.2, 0.3], [0.1, -0.2, 0.3]])
    w = StallWatch(after_s=2.0, radius=0.05)
    for t in np.arange(0.0, 1.95, 0.5):  # still and waiting, but not for 2 s yet
        w.observe_person(t, still + 0.04 * (t % 1.0))  # drift within the radius
        w.observe_plan(t, waited=True)
        assert not w.stalled(t)
    w.observe_person(2.0, still)
    assert w.stalled(2.0) and w.stalled(2.5)  # and it stays so ...
    w.observe_person(2.6, still + np.array([0.0, 0.0, 0.06]))  # ... until a hand moves
    assert not w.stalled(2.6)
    w.observe_plan(3.0, waited=True)
    assert not w.stalled(4.5) and w.stalled(4.6)  # 2 s of stillness since 2.6 s
    w.observe_progress(4.7)  # a task event: the robot is not stuck
    assert not w.stalled(4.7) and not w.stalled(6.6)  # no wait since the progress
    w.observe_plan(6.0, waited=True)
    assert w.stalled(6.7)
    # no wait at all: the robot is on its way, whatever the person does
    free = StallWatch(after_s=1.0, radius=0.05)
    for t in (0.0, 0.5, 1.0, 1.5, 3.0):
        free.observe_person(t, still)
        free.observe_plan(t, waited=False)
    assert not free.stalled(3.0)
    # an untracked hand is not a still hand
    lost = StallWatch(after_s=1.0, radius=0.05)
    lost.observe_person(0.0, still)
    lost.observe_plan(0.0, waited=True)
    lost.observe_person(0.5, np.full((2, 3), np.nan))
    assert not lost.stalled(3.0)
    with pytest.raises(ConfigError, match="after_s"):
        StallWatch(after_s=0.0, radius=0.05)


def test_tracked_hands_average_the_last_frames() -> None:
    from iplanner_torch.data.skeleton import JOINT_INDEX

    window = np.zeros((15, 10, 3))
    lh, rh = JOINT_INDEX["left_hand"], JOINT_INDEX["right_hand"]
    window[:, lh] = np.arange(15)[:, None]
    window[:, rh] = 1.0
    window[-1, lh] = np.nan  # a lost frame is left out
    window[-4:, rh] = np.nan
    got = tracked_hands(window, 4)
    np.testing.assert_allclose(got[0], [12.0, 12.0, 12.0])  # mean of frames 11, 12, 13
    assert np.isnan(got[1]).all()  # no frame of the right hand
    np.testing.assert_allclose(tracked_hands(window, 5)[1], 1.0)


class _StallingReplanner(fakes.LinearReplanner):
    """Waits (no safe plan) under the predictor's forecasts; moves under the held pose."""

    def __init__(self) -> None:
        super().__init__(speed=1.5)
        self.moving = False

    def step(self, t, q_now, forecast, *, forecast_t0):
        super().step(t, q_now, forecast, forecast_t0=forecast_t0)
        self.moving = forecast.action_names == ("observed",)
        return SimpleNamespace(feasible=self.moving, evasive=False)

    def command(self, t):
        if not self.moving:
            self.t = t
            return self.q.clone(), torch.zeros_like(self.q)
        return super().command(t)


def test_a_stall_falls_back_to_the_held_pose(tmp_path: Path) -> None:
    """A forecast that always blocks the robot, for a person who waits for the robot: the
    robot never starts without the fallback, and fetches after ``stall_fallback_s`` with it."""

    def run(fallback):
        replanner = _StallingReplanner()
        cfg = replace(_cfg(4.0), stall_fallback_s=fallback)
        res = _fake_episode(
            tmp_path, cfg, "iplanner_ni", replanner, predictor=fakes.ConstantPredictor()
        )
        return res, replanner

    stuck, _ = run(None)
    assert [k for _, k, _ in stuck.events] == ["fetch_started"]
    assert stuck.metrics["plan/stall_cycles"] == 0
    res, replanner = run(1.0)
    times = {k: t for t, k, _ in reversed(res.events)}  # the first time of each kind
    assert times["stall_fallback"] == pytest.approx(1.0, abs=0.01)
    assert times["picked"] > times["stall_fallback"]
    held = [t for t, f in replanner.forecasts if f.action_names == ("observed",)]
    assert held and held[0] == pytest.approx(times["stall_fallback"])
    assert res.metrics["plan/stall_cycles"] == len(held)


def test_held_window_holds_joints_lost_in_every_frame() -> None:
    """A joint the tracker lost for the whole window sits at its last observation; joints lost
    in some frames stay NaN for the predictor's interpolation; the tracker is untouched."""
    from iplanner_torch.eval.episode import held_window
    from iplanner_torch.sim.tracker import Tracker, TrackerCfg

    tracker = Tracker(TrackerCfg(window=4, noise_sigma=0.0), seed=0)
    truth = np.arange(3 * 3, dtype=np.float64).reshape(3, 3)
    tracker.observe(0.0, truth)  # every joint seen once
    tracker.cfg = TrackerCfg(window=4, noise_sigma=0.0, dropout_rate=0.999)
    for i in range(1, 5):  # then lost in four frames, so in the whole window
        tracker.observe(i / 15, truth + i)
    raw = tracker.window()
    assert np.isnan(raw).all()  # every joint lost in every frame of the window
    win = held_window(tracker)
    np.testing.assert_allclose(win, np.broadcast_to(truth, (4, 3, 3)))  # held where last seen
    assert np.isnan(tracker.window()).all()
    # one joint seen in one frame of the window: it keeps its NaN frames, the others are held
    tracker.cfg = TrackerCfg(window=4, noise_sigma=0.0)
    tracker.observe(5 / 15, truth + 5)
    win = held_window(tracker)
    np.testing.assert_allclose(win[-1], truth + 5)
    assert np.isnan(win[:-1]).all()


def test_dropouts_never_give_the_predictor_a_joint_lost_in_the_whole_window(
    tmp_path: Path,
) -> None:
    cfg = _cfg(4.0)
    cfg = replace(cfg, sim=replace(cfg.sim, tracker_dropout=0.8))
    predictor = fakes.ConstantPredictor()
    _fake_episode(
        tmp_path, cfg, "iplanner_ni", fakes.LinearReplanner(speed=1.5), predictor=predictor
    )
    assert len(predictor.calls) > 5
    partly = 0
    for pos, _ in predictor.calls:
        seen = torch.isfinite(pos).all(-1)  # (1, n_p, K)
        assert bool(seen.any(1).all())  # every joint has a value in some frame
        partly += int((~seen).any())
    assert partly > 0  # dropouts did reach the predictor, as NaN frames


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("seeds", [0, -1], r"expected seeds as integers in \[0, 2\^32 - 1\]"),
        ("seeds", [0.5], r"expected seeds as integers in \[0, 2\^32 - 1\]"),
        ("seeds", [2**32], r"expected seeds as integers in \[0, 2\^32 - 1\]"),
        ("noises", [float("nan")], r"expected noises in \[0, 1\] m"),
        ("noises", [-0.01], r"expected noises in \[0, 1\] m"),
        ("noises", [2.0], r"expected noises in \[0, 1\] m"),
        ("planners", [], "expected planners"),
        ("seeds", [3, 1, 3], "seeds: 3 given twice"),
        ("planners", ["itomp", "itomp"], "planners: itomp given twice"),
        ("speeds", "slow", r"speeds: expected a list, e\.g\. speeds=\[\.\.\.\], got 'slow'"),
        ("seeds", 5, "seeds: expected a list"),
        ("robot", "ur5", "unknown robot 'ur5'"),
    ],
)
def test_experiment_grid_is_checked_before_it_runs(field: str, value: list, match: str) -> None:
    from iplanner_torch.eval.experiment import ExperimentCfg

    with pytest.raises(ConfigError, match=match):
        ExperimentCfg(**{field: value})


def test_each_scenario_of_an_experiment_is_checked_with_the_episode_before_it_runs() -> None:
    """A setting the episode refuses for one of the scenarios (the causal oracle's delay for a
    delivery scenario) stops the experiment when it is made, naming that scenario, not when
    the run reaches it after the others have written their results."""
    from iplanner_torch.eval.experiment import ExperimentCfg

    blocking = ScenarioCfg(name="b", kind="blocking")
    episode = EpisodeCfg(scenario=blocking, oracle_onset_delay_s=0.1)
    ExperimentCfg(scenarios=[blocking], episode=episode)  # fine alone
    with pytest.raises(ConfigError, match=r"scenario 't': oracle_onset_delay_s applies to the"):
        ExperimentCfg(scenarios=[blocking, ScenarioCfg(name="t")], episode=episode)


def test_a_predictor_sets_the_tracker_window_and_must_match_the_tracker_rate() -> None:
    """The window is the predictor's ``n_prev`` (``n_p`` of a stand-in), else the sim's; a
    predictor trained at another frame rate than the tracker's is refused."""
    from iplanner_torch.eval.episode import _predictor_window, check_predictor_rate

    assert _predictor_window(SimpleNamespace(n_prev=10, n_p=7), 15) == 10
    assert _predictor_window(fakes.ConstantPredictor(), 9) == fakes.ConstantPredictor.n_p
    assert _predictor_window(SimpleNamespace(cfg=SimpleNamespace(n_prev=12)), 15) == 12
    assert _predictor_window(SimpleNamespace(n_prev=True), 15) == 15
    assert _predictor_window(object(), 15) == 15
    check_predictor_rate(SimpleNamespace(fps=15.0), 15)
    check_predictor_rate(object(), 30.0)  # a stand-in without a rate
    with pytest.raises(ConfigError, match=r"sim\.tracker_fps=30, but the predictor was trained "
                       r"on 15 Hz frames: set sim\.tracker_fps=15"):  # fmt: skip
        check_predictor_rate(SimpleNamespace(fps=15.0), 30.0)


def test_a_predictor_of_other_joints_is_refused_before_the_episode(tmp_path: Path) -> None:
    """A predictor trained on a subset of the joints (data.windows.joints) or on another
    skeleton is refused by name before the loop runs, not by a shape error at its first
    forecast; one that names no joints is left to the forecast check."""
    from iplanner_torch.data.skeleton import JOINT_NAMES
    from iplanner_torch.eval.episode import check_predictor_joints

    check_predictor_joints(SimpleNamespace(joint_names=tuple(JOINT_NAMES)))
    check_predictor_joints(SimpleNamespace(joint_names=list(JOINT_NAMES)))
    check_predictor_joints(object())
    for names in (("left_hand", "right_hand"), tuple(reversed(JOINT_NAMES))):
        with pytest.raises(ConfigError, match=r"forecasts the joints \[.*but the simulated "
                           r"person has the 10 joints"):  # fmt: skip
            check_predictor_joints(SimpleNamespace(joint_names=names))
    predictor = fakes.ConstantPredictor()
    predictor.joint_names = ("left_hand", "right_hand")
    with pytest.raises(ConfigError, match="data.windows.joints=null"):
        _fake_episode(
            tmp_path, _cfg(0.5), "iplanner_ni", fakes.LinearReplanner(), predictor=predictor
        )


def test_an_unreachable_crossing_is_refused_before_the_episode(tmp_path: Path) -> None:
    cfg = replace(
        _cfg(2.0), scenario=ScenarioCfg(name="b", kind="blocking", crossing_start=(5.0, 5.0, 5.0))
    )
    with pytest.raises(ConfigError, match=r"scenario\.crossing_start=\[5\.0, 5\.0, 5\.0\]: the "
                       r"robot's tool point gets no closer than .* cm to it"):  # fmt: skip
        _fake_episode(tmp_path, cfg, "itomp", fakes.LinearReplanner())
    reach = replace(cfg, scenario=ScenarioCfg(name="b", kind="blocking"))  # the default points
    _fake_episode(tmp_path, reach, "itomp", fakes.LinearReplanner())


def test_itomp_keeps_the_tracker_window_the_sim_config_gives(tmp_path: Path, monkeypatch) -> None:
    """Without a predictor, the tracker keeps sim.tracker_window frames."""
    import iplanner_torch.eval.episode as episode_module

    windows = []
    real = episode_module.Tracker

    def recording(cfg, **kwargs):
        windows.append(cfg.window)
        return real(cfg, **kwargs)

    monkeypatch.setattr(episode_module, "Tracker", recording)
    cfg = _cfg(0.5)
    cfg = replace(cfg, sim=replace(cfg.sim, tracker_window=4))
    _fake_episode(tmp_path, cfg, "itomp", fakes.LinearReplanner())
    assert windows == [4]


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ("tensor", "predict_positions returned a Tensor, expected a Forecast"),
        ("joints", r"joints \['head'.*\], expected the 10 of JOINT_NAMES"),
        ("frames", r"no predicted frame \(n_f = 0\)"),
        ("actions", r"actions \['reach_0'\], but the predictor names \['reach_0', 'reach_1'\]"),
    ],
)
def test_a_custom_predictors_forecast_is_checked_in_the_loop(
    tmp_path: Path, bad: str, message: str
) -> None:
    """A predictor of the PredictorLike protocol whose forecast the loop cannot use (not a
    Forecast, joints missing, no frame, other actions) is named by a ShapeError, not an
    IndexError deep in the planner."""
    from iplanner_torch.errors import ShapeError

    class BadPredictor(fakes.ConstantPredictor):
        def predict_positions(self, positions, progress):
            f = super().predict_positions(positions, progress)
            if bad == "tensor":
                return f.mean
            a, k, n_f = 2, len(JOINT_NAMES), f.horizon
            names, actions = f.joint_names, f.action_names
            if bad == "joints":
                k, names = k - 1, names[:-1]
            elif bad == "frames":
                n_f = 0
            else:
                a, actions = 1, actions[:1]
            mean = f.mean[:, :a, :n_f, :k].contiguous()
            return Forecast(weights=torch.full((1, a), 1.0 / a), mean=mean,
                            var=torch.full_like(mean, 1e-4), dt=f.dt, joint_names=names,
                            action_names=actions)  # fmt: skip

    with pytest.raises(ShapeError, match=message):
        _fake_episode(tmp_path, _cfg(3.0), "iplanner_ni", fakes.LinearReplanner(speed=1.5),
                      predictor=BadPredictor())  # fmt: skip


def _crosses(shoulder: np.ndarray, spot: np.ndarray, point: np.ndarray, radius: float) -> bool:
    """Brute force: ``point`` within ``radius`` (x, y) of one of 10,001 points on the line."""
    s = np.linspace(0.0, 1.0, 10001)[:, None]
    line = shoulder[None, :2] + s * (spot[:2] - shoulder[:2])[None]
    return bool(np.linalg.norm(line - point[None, :2], axis=1).min() <= radius)


@pytest.mark.filterwarnings("ignore:task order .* leaves blocks")
def test_no_delivery_into_a_reach_that_crosses_its_spot(tmp_path: Path) -> None:
    """``task_crossing_radius``: the robot delivers no block while the person reaches for a
    block whose line from the shoulder crosses that block's spot (brute force on the stand-in
    person's shoulders); without it, the same episode delivers block 0 into the reach for
    block 4 behind it."""
    scene = SceneCfg(arrangement="2x4")
    shoulders = {
        side: fakes.rest_pose()[JOINT_NAMES.index(f"{side}_shoulder")]
        for side in ("left", "right")
    }

    def into_reaches(res) -> list[tuple[int, int]]:
        takes = {}
        for t, kind, b in res.events:
            if kind == "human_take_started":
                takes[b] = [t, math.inf]
            elif kind == "human_took":
                takes[b][1] = t
        bad = []
        for t, kind, a in res.events:
            if kind != "delivered":
                continue
            for b, (t0, t1) in takes.items():
                side = "left" if scene.delivery_position(b)[1] > 0 else "right"
                crossing = _crosses(
                    shoulders[side], scene.delivery_position(b), scene.delivery_position(a), 0.1
                )
                if a != b and t0 <= t <= t1 and crossing:
                    bad.append((a, b))
        return bad

    # the first two columns (the stand-in arm's IK does not find every block of the second
    # pair from where this order leaves it); the scene's other blocks come after
    order = "4->0->5->1"

    class GoalLog(fakes.LinearReplanner):
        def __init__(self, speed: float) -> None:
            super().__init__(speed)
            self.goal_times: list[float] = []

        def set_goal(self, q_goal, t=None) -> None:
            self.goal_times.append(t)
            super().set_goal(q_goal, t)

    runs, replanners = {}, {}
    for radius in (None, 0.1):
        cfg = EpisodeCfg(
            scenario=ScenarioCfg(arrangement="2x4", task_order=order),
            max_duration_s=40.0,
            task_crossing_radius=radius,
        )
        replanners[radius] = GoalLog(speed=1.5)
        runs[radius] = _fake_episode(tmp_path, cfg, "oracle", replanners[radius], seed=0)
    assert (0, 4) in into_reaches(runs[None])
    on = runs[0.1]
    assert into_reaches(on) == []
    assert on.metrics["eval/completed"] == 1.0
    assert sorted(b for _, k, b in on.events if k == "human_took") == [0, 1, 4, 5]
    fetched = [b for _, k, b in on.events if k == "fetch_started"]
    assert fetched[:2] == [4, 5]  # block 0 is moved off the reach for block 4
    assert on.metrics["task/deferred_fetches"] >= 1
    held = [b for _, k, b in on.events if k == "delivery_held"]
    assert held and held == [b for _, k, b in on.events if k == "delivery_resumed"]
    # a held block keeps the pick goal: the arm, still moving when it picks, stops there
    # instead of turning back to where the pick was detected
    held_at = [t for t, k, _ in on.events if k == "delivery_held"]
    assert not set(held_at) & set(replanners[0.1].goal_times)
    assert on.metrics["task/held_s"] > 0
    assert runs[None].metrics["task/deferred_fetches"] == 0
    assert runs[None].metrics["task/held_s"] == 0


def test_defer_crossed_fetch_in_the_reach_across_scene() -> None:
    """Back block 4's reach (from the left shoulder) crosses front spot 0 and no other."""
    scene = SceneCfg(arrangement="2x4")
    spots = {i: scene.delivery_position(i) for i in scene.block_ids}
    shoulders = {"left": np.array([-0.45, 0.18, 0.4]), "right": np.array([-0.45, -0.18, 0.4])}
    groups = ((4,), (0,), (5,), (1,), (6,), (2,), (7,), (3,))
    rest = set(range(8)) - {4}
    kw = {"spots": spots, "shoulders": shoulders, "groups": groups, "radius": 0.1}
    assert defer_crossed_fetch(0, remaining=rest, pending={4}, **kw) == 5
    assert defer_crossed_fetch(0, remaining=rest, pending=set(), **kw) == 0
    assert defer_crossed_fetch(1, remaining=rest, pending={4}, **kw) == 1
    # nothing uncrossed in the same or the next group: the first choice stays
    assert defer_crossed_fetch(0, remaining={0, 1}, pending={4, 5}, **kw) == 0
    # one group: the smallest uncrossed id
    assert defer_crossed_fetch(0, remaining=rest, pending={4}, **{**kw, "groups": None}) == 1
    with pytest.raises(ConfigError, match="among the remaining"):
        defer_crossed_fetch(4, remaining=rest, pending=set(), **kw)
    with pytest.raises(ConfigError, match="no delivery spot"):
        defer_crossed_fetch(0, remaining=rest, pending={9}, **kw)


def test_available_blocks_by_order() -> None:
    from iplanner_torch.sim.tasks import parse_order

    order = parse_order("4->0->5->1->6->2->7->3", tuple(range(8)))
    assert available_blocks({1, 6}, set(), None, {4, 0, 5}) == {1, 6}
    assert available_blocks({6}, set(), order, {4, 0, 5}) == set()  # 6 only after 1
    assert available_blocks({1, 6}, {5}, order, {4, 0}) == {5}
    assert available_blocks({1, 6}, set(), order, {4, 0, 5}) == {1}


@pytest.mark.filterwarnings("ignore:task order .* leaves blocks")
def test_a_held_block_the_person_needs_first_is_not_held_for_good(tmp_path: Path) -> None:
    """The robot delivers back block 4 first although the person must take front block 0
    before it: the reach for 4 crosses spot 0, but the person cannot make it before taking
    0, and has nothing else to take, so block 0 is not held back (the hold would never end)."""

    def policy(taken: set[int], fetched: set[int]) -> int | None:
        return next((i for i in (4, 0, 1, 2, 3, 5, 6, 7) if i not in fetched), None)

    cfg = EpisodeCfg(
        scenario=ScenarioCfg(arrangement="2x4", task_order="0->4"), max_duration_s=30.0
    )
    res = run_episode(
        cfg,
        robot=fakes.FakeArm(tmp_path),
        predictor=None,
        planner_kind="oracle",
        writer_path=None,
        seed=0,
        replanner=fakes.LinearReplanner(speed=1.5),
        motion=fakes.FakeMotion(),
        task_policy=policy,
    )
    assert res.metrics["eval/completed"] == 1.0
    assert [b for _, k, b in res.events if k == "human_took"] == [0, 4]
    assert [b for _, k, b in res.events if k == "fetch_started"][:2] == [4, 0]
    assert res.metrics["task/held_s"] == 0.0


def test_a_just_delivered_blocks_reach_starts_after_the_reaction_time(tmp_path: Path) -> None:
    """``reaction_s``: in the forecasts the planner gets, the reach for a block that landed
    less than ``reaction_s`` before the last tracked frame starts no sooner than the reaction
    time allows (the whole frames left, rounded down), and is delayed in some; with None the
    planner gets the predictor's forecasts as they are."""

    class MovingPredictor(fakes.ConstantPredictor):
        """Every action moves the whole body 1 cm a frame along x."""

        def predict_positions(self, positions, progress):
            f = super().predict_positions(positions, progress)
            steps = 0.01 * torch.arange(1, f.horizon + 1, dtype=f.mean.dtype)
            mean = f.mean.clone()
            mean[..., 0] += steps.view(1, 1, -1, 1)
            return replace(f, mean=mean)

    class ForecastLog(fakes.LinearReplanner):
        def step(self, t, q_now, forecast, *, forecast_t0):
            self.forecasts.append((forecast_t0, forecast))
            return super().step(t, q_now, forecast, forecast_t0=forecast_t0)

    delayed = {}
    for reaction in (None, 0.3):
        cfg = replace(_cfg(8.0), reaction_s=reaction)
        log = ForecastLog(speed=1.5)
        res = _fake_episode(tmp_path, cfg, "iplanner_ni", log, predictor=MovingPredictor())
        landed = {b: t for t, kind, b in res.events if kind == "delivered"}
        assert landed, "the stand-in robot delivers within the episode"
        delayed[reaction] = 0
        for t0, f in log.forecasts:
            for a, name in enumerate(f.action_names):
                x = f.mean[0, a, :, 0, 0]
                # frames at the first predicted position, less the first one
                d = int(((x - x[0]).abs() < 1e-9).sum()) - 1
                block = int(name.rsplit("_", 1)[1])
                left = 0.0
                if reaction is not None and block in landed:
                    left = reaction - (t0 - landed[block])
                assert d <= max(0, math.floor(left / f.dt + 1e-9)), (reaction, t0, name, d)
                delayed[reaction] += int(d > 0)
    assert delayed[None] == 0
    assert delayed[0.3] > 0


def test_spread_calibration_widens_the_forecasts_the_planner_gets(tmp_path: Path) -> None:
    """``spread_tolerance``: a predictor that holds the last pose with 1 cm standard deviation
    misses a reaching person by far more, so some forecasts reach the planner with their
    variances multiplied by a factor > 1 (the same for every entry, at most
    ``spread_max_scale``), reported in forecast/spread_scale_*; with None the planner gets the
    predictor's variances and there is no such metric."""

    factors = {}
    for tolerance in (None, 1.0):
        cfg = replace(_cfg(8.0), spread_tolerance=tolerance, spread_max_scale=9.0)
        log = fakes.LinearReplanner(speed=1.5)  # logs (cycle time, forecast)
        res = _fake_episode(tmp_path, cfg, "iplanner_ni", log, predictor=fakes.ConstantPredictor())
        assert log.forecasts
        seen = []
        for _, f in log.forecasts:
            ratio = f.var / 1e-4
            torch.testing.assert_close(ratio, torch.full_like(ratio, float(ratio.flatten()[0])))
            seen.append(float(ratio.flatten()[0]))
        factors[tolerance] = seen
        if tolerance is None:
            assert "forecast/spread_scale_mean" not in res.metrics
        else:
            assert res.metrics["forecast/spread_scale_max"] == pytest.approx(max(seen), rel=1e-6)
            assert res.metrics["forecast/spread_scale_mean"] == pytest.approx(
                float(np.mean(seen)), rel=1e-6
            )
    assert factors[None] == pytest.approx([1.0] * len(factors[None]))
    assert max(factors[1.0]) > 1.0
    assert min(factors[1.0]) >= 1.0 and max(factors[1.0]) <= 9.0 + 1e-9


def test_a_causal_oracle_learns_of_the_block_only_after_its_delay(tmp_path: Path) -> None:
    """``oracle_onset_delay_s``: until that long after the arm starts (``blocking_started``)
    the oracle's forecast holds the person still at the true pose of now; from then on it is
    the true future, which moves. Without the delay the oracle foresees the block before it
    starts. Refused outside the blocking scenario."""

    def spread(f) -> float:  # how far the forecast's joints move over its frames [m]
        return float(np.ptp(f.mean[0, 0].numpy(), axis=0).max())

    from iplanner_torch.recording.reader import read_episode

    base = replace(_cfg(2.0), scenario=ScenarioCfg(name="b", kind="blocking"))
    for delay in (None, 0.3):
        log = fakes.LinearReplanner(speed=1.5)  # logs (cycle time, forecast)
        path = tmp_path / f"oracle_{delay}.mcap"
        cfg = replace(base, oracle_onset_delay_s=delay)
        res = _fake_episode(tmp_path, cfg, "oracle", log, path=path)
        onset = next(t for t, kind, _ in res.events if kind == "blocking_started")
        before = [(t0, f) for t0, f in log.forecasts if t0 < onset + (delay or 0.0) - 1e-9]
        after = [f for t0, f in log.forecasts if t0 >= onset + (delay or 0.0) + 0.05]
        assert before and after
        assert any(spread(f) > 0.05 for f in after)
        if delay is None:  # the true future: a cycle before the onset already sees the arm move
            assert any(spread(f) > 0.05 for _, f in before)
            continue
        assert all(spread(f) == 0.0 for _, f in before)
        # held at the true pose of its cycle (the last logged true pose at or before it; the
        # person rests before the onset, so the two agree there)
        t_true, true = (x.numpy() for x in read_episode(path).human_true())
        compared = 0
        for t0, f in before:
            i = int(np.searchsorted(t_true, t0 + 1e-9)) - 1
            if i >= 0 and t_true[i] < onset:
                np.testing.assert_allclose(f.mean[0, 0, 0].numpy(), true[i], atol=1e-6)
                compared += 1
        assert compared >= 1
    with pytest.raises(ConfigError, match="oracle_onset_delay_s applies to the blocking"):
        replace(_cfg(2.0), oracle_onset_delay_s=0.1)
    with pytest.raises(ConfigError, match="expected oracle_onset_delay_s >= 0"):
        replace(base, oracle_onset_delay_s=-0.1)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("kind", ["itomp", "oracle"])
def test_real_kuka_episode_on_cuda_follows_the_cpu_one(tmp_path: Path, kind: str) -> None:
    """The closed loop with the robot model and the planner on CUDA (as ``device=cuda`` runs
    it) moves the arm as on the CPU: the same task events, and joint paths within 0.02 rad
    (float32 sums in another order may tip an iteration's acceptance, not the motion)."""
    from iplanner_torch.recording.reader import read_episode
    from iplanner_torch.robot.model import RobotModel

    cfg = EpisodeCfg(scenario=ScenarioCfg(task_order="(0,1)->(2,3)"), max_duration_s=4.0)
    runs, qs = {}, {}
    for dev in ("cpu", "cuda"):
        path = tmp_path / f"{dev}.mcap"
        runs[dev] = run_episode(
            cfg,
            robot=RobotModel.load("kuka_iiwa14", device=dev),
            predictor=None,
            planner_kind=kind,  # type: ignore[arg-type]
            writer_path=path,
            seed=0,
        )
        qs[dev] = read_episode(path).robot_q()[1]  # (T, J)
    assert [k for _, k, _ in runs["cuda"].events] == [k for _, k, _ in runs["cpu"].events]
    assert qs["cuda"].shape == qs["cpu"].shape
    assert float((qs["cuda"] - qs["cpu"]).abs().max()) < 0.02
    assert (qs["cpu"][-1] - qs["cpu"][0]).abs().max() > 0.1  # the arm moved
    for name in ("eval/min_distance", "plan/mean_solve_ms"):
        assert math.isfinite(runs["cuda"].metrics[name]), name
