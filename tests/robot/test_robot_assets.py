"""Our URDF / MJCF assets: pytorch-kinematics (URDF) against MuJoCo (MJCF), published numbers."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import pytorch_kinematics as pk
import torch

from iplanner_torch.errors import ConfigError
from iplanner_torch.robot.description import (
    FETCH_DEFAULT_TORSO_HEIGHT,
    ROBOT_NAMES,
    asset_paths,
    fetch_description,
    mjcf_string,
    robot_description,
    urdf_string,
)

#: the robots the FK-versus-MuJoCo tests below cover: every one of ROBOT_NAMES (a robot added
#: to ``description.DESCRIPTIONS`` is tested with no edit here)
ROBOTS = ROBOT_NAMES
#: the shipped robots' tool links, typed in independently (a new robot's comes from its
#: description)
SHIPPED_TOOL = {"kuka_iiwa14": "iiwa_flange", "fetch": "gripper_link"}

# Published numbers, typed in independently of the description module.
IIWA_RANGE_DEG = (170, 120, 170, 120, 170, 120, 175)
IIWA_VEL_DEG = (85, 85, 100, 75, 130, 135, 135)
IIWA_EFFORT = (320, 320, 176, 176, 110, 40, 40)
IIWA_MASS = (5.76, 6.35, 3.5, 3.5, 3.5, 1.8, 1.2)
FETCH_VEL = (1.256, 1.454, 1.571, 1.521, 1.571, 2.268, 2.268)
FETCH_EFFORT = (33.82, 131.76, 76.94, 66.18, 29.35, 25.7, 7.36)
FETCH_RANGE = (
    (-1.6056, 1.6056),
    (-1.221, 1.518),
    None,
    (-2.251, 2.251),
    None,
    (-2.16, 2.16),
    None,
)


def _tool(name: str) -> str:
    return SHIPPED_TOOL.get(name) or robot_description(name).tool_link


def test_the_shipped_robots_are_listed_with_their_tool_links() -> None:
    assert set(SHIPPED_TOOL) <= set(ROBOT_NAMES)
    for name, tool in SHIPPED_TOOL.items():
        assert robot_description(name).tool_link == tool


def _pk_chain(name: str) -> pk.SerialChain:
    urdf_path, _ = asset_paths(name)
    chain = pk.build_serial_chain_from_urdf(urdf_path.read_text(), _tool(name))
    return chain.to(dtype=torch.float64)


def _mj_model(name: str) -> mujoco.MjModel:
    _, mjcf_path = asset_paths(name)
    return mujoco.MjModel.from_xml_path(str(mjcf_path))


def _random_q(model: mujoco.MjModel, n: int, rng: np.random.Generator) -> np.ndarray:
    lo = np.where(model.jnt_limited, model.jnt_range[:, 0], -math.pi)
    hi = np.where(model.jnt_limited, model.jnt_range[:, 1], math.pi)
    return rng.uniform(lo, hi, size=(n, model.njnt))


@pytest.mark.parametrize("name", ROBOTS)
def test_committed_assets_equal_generator_output(name: str) -> None:
    urdf_path, mjcf_path = asset_paths(name)
    desc = robot_description(name)
    assert urdf_path.read_text() == urdf_string(desc)
    assert mjcf_path.read_text() == mjcf_string(desc)


@pytest.mark.parametrize("name", ROBOTS)
def test_pytorch_kinematics_urdf_equals_mujoco_mjcf_on_every_link(name: str) -> None:
    chain = _pk_chain(name)
    model = _mj_model(name)
    data = mujoco.MjData(model)
    assert chain.get_joint_parameter_names() == [model.joint(i).name for i in range(model.njnt)]
    q = _random_q(model, 500, np.random.default_rng(0))
    frames = chain.forward_kinematics(torch.from_numpy(q), end_only=False)
    links = sorted(frames)
    assert len(links) == model.nbody - 1  # every MuJoCo body but the world
    mj_pos = np.empty((500, len(links), 3))
    mj_rot = np.empty((500, len(links), 3, 3))
    for k in range(500):
        data.qpos[:] = q[k]
        mujoco.mj_kinematics(model, data)
        for i, link in enumerate(links):
            mj_pos[k, i] = data.body(link).xpos
            mj_rot[k, i] = data.body(link).xmat.reshape(3, 3)
    for i, link in enumerate(links):
        m = frames[link].get_matrix().numpy()
        assert np.abs(m[:, :3, 3] - mj_pos[:, i]).max() < 1e-5, link
        assert np.abs(m[:, :3, :3] - mj_rot[:, i]).max() < 1e-5, link


def test_iiwa_published_positions() -> None:
    model = _mj_model("kuka_iiwa14")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.site("ee_site").xpos, (0.0, 0.0, 1.306), atol=1e-9)
    np.testing.assert_allclose(data.body("iiwa_link_2").xpos, (0.0, 0.0, 0.36), atol=1e-9)
    data.qpos[:] = (0, 0.785398, 0, -1.5708, 0, 0, 0)
    mujoco.mj_kinematics(model, data)
    assert np.linalg.norm(data.site("ee_site").xpos - np.array([0.669, 0.0, 0.285])) < 0.01


def test_fetch_gripper_in_torso_frame_at_zero() -> None:
    model = _mj_model("fetch")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    torso = data.body("torso_lift_link")
    np.testing.assert_allclose(torso.xmat.reshape(3, 3), np.eye(3), atol=1e-12)
    rel = data.site("ee_site").xpos - torso.xpos
    np.testing.assert_allclose(rel, (1.215, 0.0, 0.4086), atol=1e-3)
    base_to_torso = torso.xpos - data.body("fetch_base").xpos
    np.testing.assert_allclose(
        base_to_torso, (-0.086875, 0.0, 0.37743 + FETCH_DEFAULT_TORSO_HEIGHT), atol=1e-12
    )


def test_fetch_torso_height_is_a_parameter() -> None:
    heights = (0.0, 0.1, 0.38615)
    z = []
    for h in heights:
        model = mujoco.MjModel.from_xml_string(mjcf_string(fetch_description(torso_height=h)))
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        z.append(data.body("shoulder_pan_link").xpos[2])
    np.testing.assert_allclose(np.diff(z), np.diff(heights), atol=1e-12)
    with pytest.raises(ConfigError, match="torso_height"):
        fetch_description(torso_height=0.5)
    for bad in ("0.2", None, [0.2], math.nan):  # text failed with a raw TypeError
        with pytest.raises(ConfigError, match="expected torso_height a finite number"):
            fetch_description(torso_height=bad)  # type: ignore[arg-type]


def test_iiwa_limits_velocities_efforts_masses() -> None:
    chain = _pk_chain("kuka_iiwa14")
    lo, hi = chain.get_joint_limits()
    np.testing.assert_allclose(hi, np.deg2rad(IIWA_RANGE_DEG), atol=1e-12)
    np.testing.assert_allclose(lo, -np.deg2rad(IIWA_RANGE_DEG), atol=1e-12)
    _, vel = chain.get_joint_velocity_limits()
    np.testing.assert_allclose(vel, np.deg2rad(IIWA_VEL_DEG), atol=1e-12)
    _, eff = chain.get_joint_effort_limits()
    np.testing.assert_allclose(eff, IIWA_EFFORT, atol=1e-12)
    model = _mj_model("kuka_iiwa14")
    np.testing.assert_allclose(model.jnt_range[:, 1], np.deg2rad(IIWA_RANGE_DEG), atol=1e-12)
    np.testing.assert_allclose(model.actuator_forcerange[:, 1], IIWA_EFFORT, atol=1e-12)
    masses = [model.body(f"iiwa_link_{i}").mass[0] for i in range(1, 8)]
    np.testing.assert_allclose(masses, IIWA_MASS, atol=1e-12)
    assert model.body("iiwa_base").mass[0] == pytest.approx(5.0)


def test_fetch_limits_velocities_efforts() -> None:
    chain = _pk_chain("fetch")
    lo, hi = chain.get_joint_limits()
    model = _mj_model("fetch")
    for i, rng in enumerate(FETCH_RANGE):
        if rng is None:  # continuous: pytorch-kinematics reports (0, 0), MuJoCo unlimited
            assert (lo[i], hi[i]) == (0, 0)
            assert not model.jnt_limited[i]
            assert not model.actuator_ctrllimited[i]
        else:
            assert (lo[i], hi[i]) == pytest.approx(rng)
            np.testing.assert_allclose(model.jnt_range[i], rng, atol=1e-12)
    _, vel = chain.get_joint_velocity_limits()
    np.testing.assert_allclose(vel, FETCH_VEL, atol=1e-12)
    _, eff = chain.get_joint_effort_limits()
    np.testing.assert_allclose(eff, FETCH_EFFORT, atol=1e-12)


@pytest.mark.parametrize("name", ROBOTS)
def test_mjcf_conventions(name: str) -> None:
    model = _mj_model(name)
    desc = robot_description(name)
    assert model.body(1).name == desc.base_link  # top body is the robot's base
    assert model.body(1).parentid[0] == 0
    n = len(desc.actuated_joints)
    assert model.nu == model.njnt == n
    assert [model.actuator(i).name for i in range(model.nu)] == [
        model.joint(i).name for i in range(model.njnt)
    ]
    assert model.actuator_trnid[:, 0].tolist() == list(range(n))
    assert model.site("ee_site").bodyid[0] == model.body(_tool(name)).id
    assert model.ngeom >= len(desc.sphere_links) + 1  # no floor, only robot geoms
    assert np.all(model.body_gravcomp[1:] == 1.0)
    data = mujoco.MjData(model)
    data.qpos[:] = desc.q_home
    mujoco.mj_forward(model, data)
    assert data.ncon == 0  # no self-contact at the home pose


@pytest.mark.parametrize("name", ROBOTS)
def test_position_actuators_track_a_step(name: str) -> None:
    """The ``<position>`` servos hold a configuration 0.2 rad away from home (towards
    mid-range) in 1.5 s."""
    model = _mj_model(name)
    model.opt.timestep = 0.002
    data = mujoco.MjData(model)
    home = np.array(robot_description(name).q_home)
    data.qpos[:] = home
    target = home + np.where(home > 1.0, -0.2, 0.2)
    data.ctrl[:] = target
    for _ in range(750):
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos))
    assert np.abs(data.qpos - target).max() < 0.02
    assert np.abs(data.qvel).max() < 0.05


@pytest.mark.parametrize("name", ROBOTS)
def test_the_home_pose_holds_the_tool_over_the_table_clear_of_it(name: str) -> None:
    """Every robot's home (where episodes start and end), at its default base pose, has its
    tool point over the table top and above it, by MuJoCo's own kinematics of the scene: a
    new robot with a home pose below the table or off it is caught here, not in an episode."""
    from iplanner_torch.robot.model import RobotModel
    from iplanner_torch.sim.scene import SceneCfg, SceneHandles, build_scene

    robot = RobotModel.load(name)
    cfg = SceneCfg()
    model = build_scene(cfg, robot)
    handles = SceneHandles.resolve(model, cfg, robot)
    data = mujoco.MjData(model)
    data.qpos[handles.qpos_adr] = robot.q_home.numpy()
    mujoco.mj_forward(model, data)
    x, y, z = data.site_xpos[handles.ee_site]  # table frame: the top at z = 0
    assert z > 0.05, (x, y, z)
    assert abs(x - cfg.table_center_x) < cfg.table_size[0] / 2, (x, y, z)
    assert abs(y) < cfg.table_size[1] / 2, (x, y, z)
