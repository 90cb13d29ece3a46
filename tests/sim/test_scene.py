"""Scene composition: robots attach, arrangements, kinematic human capsules, contact filter."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from sim_fakes import rest_pose

from iplanner_torch.data.skeleton import SEGMENTS
from iplanner_torch.errors import ConfigError
from iplanner_torch.sim.scene import (
    ARRANGEMENT_IDS,
    SceneCfg,
    SceneHandles,
    build_scene,
    pose_human,
)


def _real_robot(name: str):
    from iplanner_torch.robot.model import RobotModel

    return RobotModel.load(name)


@pytest.mark.parametrize("arrangement", ["1x4", "2x2", "2x4"])
def test_fake_arm_scene_builds_and_holds_home(arm, arrangement: str) -> None:
    cfg = SceneCfg(arrangement=arrangement)
    model = build_scene(cfg, arm)
    data = mujoco.MjData(model)
    h = SceneHandles.resolve(model, cfg, arm)
    assert sorted(h.block_mocap) == list(ARRANGEMENT_IDS[arrangement])
    q0 = arm.q_home.numpy()
    data.qpos[h.qpos_adr] = q0
    data.ctrl[h.actuator_ids] = q0
    for _ in range(200):
        mujoco.mj_step(model, data)
    assert np.abs(data.qpos[h.qpos_adr] - q0).max() < 1e-3
    assert np.isfinite(data.qpos).all()


@pytest.mark.parametrize("name", ["kuka_iiwa14", "fetch"])
@pytest.mark.parametrize("arrangement", ["1x4", "2x2", "2x4"])
def test_real_robot_scene_matches_its_kinematics(name: str, arrangement: str) -> None:
    robot = _real_robot(name)
    cfg = SceneCfg(arrangement=arrangement)
    model = build_scene(cfg, robot)
    data = mujoco.MjData(model)
    h = SceneHandles.resolve(model, cfg, robot)
    q = robot.q_home.clone()
    q[0] += 0.3
    data.qpos[h.qpos_adr] = q.numpy()
    data.ctrl[h.actuator_ids] = q.numpy()
    mujoco.mj_forward(model, data)
    # MuJoCo's own kinematics of the attached MJCF agrees with the robot model's FK
    np.testing.assert_allclose(data.site_xpos[h.ee_site], robot.ee_position(q).numpy(), atol=2e-3)
    for _ in range(100):
        mujoco.mj_step(model, data)
    assert np.abs(data.qpos[h.qpos_adr] - q.numpy()).max() < 2e-2


def test_block_layout_matches_reaching_targets() -> None:
    from iplanner_torch.data.reaching import reach_targets

    cfg = SceneCfg(arrangement="2x4")
    targets = reach_targets(8)
    for i in cfg.block_ids:
        np.testing.assert_allclose(cfg.delivery_position(i)[:2], targets[i, :2], atol=1e-9)
        assert cfg.block_position(i)[0] > cfg.delivery_position(i)[0] + 0.2
    assert SceneCfg(arrangement="2x2").block_ids == (1, 2, 5, 6)


def test_human_capsules_follow_joints_exactly(arm) -> None:
    cfg = SceneCfg()
    model = build_scene(cfg, arm)
    data = mujoco.MjData(model)
    h = SceneHandles.resolve(model, cfg, arm)
    rng = np.random.default_rng(3)
    for _ in range(3):
        joints = rest_pose() + rng.normal(0.0, 0.05, size=(10, 3))
        pose_human(model, data, h, joints)
        mujoco.mj_forward(model, data)
        for s, seg in enumerate(SEGMENTS):
            g = h.human_geom_ids[s]
            centre = data.geom_xpos[g]
            axis = data.geom_xmat[g].reshape(3, 3)[:, 2]
            a = joints[h.human_joint_pairs[s, 0]]
            b = joints[h.human_joint_pairs[s, 1]]
            if seg.joint_a == seg.joint_b:
                np.testing.assert_allclose(centre, a, atol=1e-9)
                continue
            half = model.geom_size[g, 1]
            np.testing.assert_allclose(centre - half * axis, a, atol=1e-9)
            np.testing.assert_allclose(centre + half * axis, b, atol=1e-9)
            assert model.geom_size[g, 0] == pytest.approx(seg.radius)


def test_human_only_touches_the_robot(arm) -> None:
    cfg = SceneCfg()
    model = build_scene(cfg, arm)
    data = mujoco.MjData(model)
    h = SceneHandles.resolve(model, cfg, arm)
    joints = rest_pose()
    joints[:, 2] -= 0.3  # the whole body sinks into the table and the chair
    pose_human(model, data, h, joints)
    data.qpos[h.qpos_adr] = arm.q_home.numpy()
    mujoco.mj_forward(model, data)
    pairs = data.contact.geom[: data.ncon]
    assert not h.human_geom[pairs].any()


def test_scene_cfg_rejects_bad_values() -> None:
    with pytest.raises(ConfigError, match="arrangement"):
        SceneCfg(arrangement="3x3")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="column_pitch"):
        SceneCfg(column_pitch=0.01)
