"""Bad input to the simulation's public API: typed errors instead of hangs or bare errors."""

from __future__ import annotations

import numpy as np
import pytest
from sim_fakes import FakeMotion, FakeOrder, deadline

from iplanner_torch.errors import ConfigError, ShapeError
from iplanner_torch.sim.env import MAX_SUBSTEPS, SimCfg, SimEnv
from iplanner_torch.sim.human import MIN_PREVIEW_STEP_S, HumanCfg, ScriptedHuman
from iplanner_torch.sim.scene import SceneCfg, build_scene
from iplanner_torch.sim.tracker import MAX_WINDOW, Tracker, TrackerCfg


def _parts(scene: SceneCfg) -> tuple[ScriptedHuman, Tracker]:
    targets = {i: scene.delivery_position(i) + [0.0, 0.0, 0.015] for i in scene.block_ids}
    human = ScriptedHuman(
        HumanCfg(), FakeMotion(), task_order=FakeOrder(scene.block_ids), targets=targets, seed=0
    )
    return human, Tracker(TrackerCfg(), seed=0)


@pytest.mark.parametrize(
    "kw", [dict(physics_dt=1e-9), dict(physics_dt=1e-300), dict(control_hz=1e-3)]
)
def test_sim_cfg_refuses_control_periods_of_too_many_physics_steps(kw: dict) -> None:
    """These made one SimEnv.step run 10^7 and more physics steps (it never returned)."""
    with pytest.raises(ConfigError, match="physics steps per control period"):
        SimCfg(**kw)


def test_sim_cfg_takes_the_largest_allowed_number_of_physics_steps() -> None:
    cfg = SimCfg(physics_dt=0.002, control_hz=1.0 / (MAX_SUBSTEPS * 0.002))
    assert cfg.substeps == MAX_SUBSTEPS


@pytest.mark.parametrize("seed", ["x", None, float("nan"), 1.5, -1, True])
def test_env_refuses_a_seed_that_is_not_a_non_negative_integer(arm, seed: object) -> None:
    scene = SceneCfg()
    with pytest.raises(ConfigError, match="seed"):
        SimEnv(scene, arm, *_parts(scene), seed=seed)  # type: ignore[arg-type]


def test_env_refuses_settings_of_the_wrong_kind(arm) -> None:
    scene = SceneCfg()
    with pytest.raises(ConfigError, match="scene_cfg a SceneCfg, got NoneType"):
        SimEnv(None, arm, *_parts(scene), seed=0)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="cfg a SimCfg or None, got HumanCfg"):
        SimEnv(scene, arm, *_parts(scene), seed=0, cfg=HumanCfg())  # type: ignore[arg-type]
    human, tracker = _parts(scene)
    with pytest.raises(ConfigError, match="human a ScriptedHuman, got NoneType"):
        SimEnv(scene, arm, None, tracker, seed=0)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="tracker a Tracker, got TrackerCfg"):
        SimEnv(scene, arm, human, TrackerCfg(), seed=0)  # type: ignore[arg-type]


def test_preview_refuses_a_step_or_times_that_are_not_numbers() -> None:
    human, _ = _parts(SceneCfg())
    with deadline(10.0), pytest.raises(ConfigError, match="step_s"):
        human.preview(np.array([0.5]), set(), "0.01")  # type: ignore[arg-type]
    with pytest.raises(ShapeError, match="times an array of real numbers"):
        human.preview(["a"], set(), 0.01)  # type: ignore[arg-type]


def test_preview_refuses_a_step_too_small_to_step_through_a_motion() -> None:
    """step_s=1e-9 stepped the copy one nanosecond at a time through each reach: the call
    never returned."""
    human, _ = _parts(SceneCfg())
    with deadline(10.0), pytest.raises(ConfigError, match=r"expected step_s >= 0.0001 s"):
        human.preview(np.array([3.0]), {0, 1}, 1e-9)  # two blocks delivered: reaches run
    assert human.preview(np.array([3.0]), {0, 1}, MIN_PREVIEW_STEP_S).shape[0] == 1


@pytest.mark.parametrize("dt", [-1.0, 0.0, float("nan"), "0.002"])
def test_build_scene_refuses_a_timestep_that_is_not_positive(arm, dt: object) -> None:
    """-1 and NaN compiled, and MuJoCo then ran time backwards or into NaN positions with
    warnings; a string was a bare TypeError."""
    with pytest.raises(ConfigError, match="physics_dt"):
        build_scene(SceneCfg(), arm, physics_dt=dt)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="cfg a SceneCfg, got NoneType"):
        build_scene(None, arm)  # type: ignore[arg-type]


def test_tracker_window_is_bounded() -> None:
    """A window of 10^12 frames was accepted and Tracker.window ran out of memory."""
    assert TrackerCfg(window=MAX_WINDOW).window == MAX_WINDOW
    with pytest.raises(ConfigError, match="expected window <= "):
        TrackerCfg(window=10**12)
    with pytest.raises(ConfigError, match="expected tracker_window <= "):
        SimCfg(tracker_window=MAX_WINDOW + 1)
