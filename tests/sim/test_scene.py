"""Scene composition: robots attach, arrangements, kinematic human capsules, contact filter."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch
from sim_fakes import rest_pose

from iplanner_torch.data.skeleton import SEGMENTS
from iplanner_torch.errors import ConfigError, DataError, ShapeError
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


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        (dict(table_size=(1.0,)), "table_size"),
        (dict(table_size=(1.0, float("nan"))), "table_size"),
        (dict(table_size=(1.0, -1.4)), "table_size"),
        (dict(table_height=float("nan")), "table_height"),
        (dict(table_height=float("inf")), "table_height"),
        (dict(table_center_x=float("nan")), "table_center_x"),
        (dict(block_size=float("nan")), "block_size"),
        (dict(column_pitch=float("nan")), "column_pitch"),
        (dict(column_pitch=float("inf")), "column_pitch"),
        (dict(block_rows_x=(0.32, float("nan"))), "block_rows_x"),
        (dict(delivery_rows_x=(0.04,)), "delivery_rows_x"),
        (dict(human_seat_x=float("inf")), "human_seat_x"),
        (dict(robot_gravcomp="no"), "robot_gravcomp"),
    ],
)
def test_scene_cfg_rejects_meaningless_geometry(kw: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        SceneCfg(**kw)


@pytest.mark.parametrize(
    "kw",
    [
        dict(name="fetch", torso_height=0.0),
        dict(name="fetch", torso_height=0.38),
        dict(name="kuka_iiwa14", base_position=(0.7, 0.1, 0.05), base_yaw=2.8),
    ],
    ids=["fetch_torso_0", "fetch_torso_0.38", "kuka_moved"],
)
def test_non_default_robot_scene_is_the_models_own(kw: dict) -> None:
    """The scene holds the model's own description (not the committed default MJCF): MuJoCo's
    kinematics of the tool point equals the model's ``ee_position`` everywhere."""
    from iplanner_torch.robot.model import RobotModel

    robot = RobotModel.load(**kw, dtype=torch.float64)
    cfg = SceneCfg()
    model = build_scene(cfg, robot)
    data = mujoco.MjData(model)
    h = SceneHandles.resolve(model, cfg, robot)
    lo = np.nan_to_num(robot.q_min.numpy(), neginf=-math.pi)
    hi = np.nan_to_num(robot.q_max.numpy(), posinf=math.pi)
    rng = np.random.default_rng(0)
    for q in [robot.q_home.numpy(), *rng.uniform(lo, hi, size=(5, robot.num_joints))]:
        data.qpos[h.qpos_adr] = q
        mujoco.mj_kinematics(model, data)
        expected = robot.ee_position(torch.as_tensor(q)).numpy()
        np.testing.assert_allclose(data.site_xpos[h.ee_site], expected, atol=1e-9)


def test_default_robot_scene_equals_the_committed_mjcf() -> None:
    """For the default robots the scene built from the model's MJCF text is the one built
    from the committed file (every compiled number equal)."""
    from iplanner_torch.robot.model import RobotModel

    class FromFile:
        def __init__(self, robot: RobotModel) -> None:
            self._robot = robot
            self.name, self.joint_names = robot.name, robot.joint_names
            self.mjcf_path = robot.mjcf_path
            self.base_position, self.base_yaw = robot.base_position, robot.base_yaw

    def saved(model: mujoco.MjModel) -> bytes:
        buf = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
        mujoco.mj_saveModel(model, None, buf)
        return buf.tobytes()

    for name in ("kuka_iiwa14", "fetch"):
        robot = RobotModel.load(name)
        cfg = SceneCfg(arrangement="2x4")
        assert saved(build_scene(cfg, robot)) == saved(build_scene(cfg, FromFile(robot)))


def test_a_long_capsule_touched_far_from_its_centre_is_a_contact() -> None:
    """``pose_human`` stretches the capsules to their segments; MuJoCo's broad phase must see
    the whole length (its bounding box), so an overlap near a long forearm's far end, away
    from the hand sphere, is a contact. Reference: MuJoCo's own distance between the geoms."""
    from iplanner_torch.data.skeleton import JOINT_INDEX
    from iplanner_torch.robot.model import RobotModel

    robot = RobotModel.load("kuka_iiwa14")
    cfg = SceneCfg()
    model = build_scene(cfg, robot)
    data = mujoco.MjData(model)
    h = SceneHandles.resolve(model, cfg, robot)
    data.qpos[h.qpos_adr] = robot.q_home.numpy()
    mujoco.mj_forward(model, data)
    rg = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "robot/iiwa_link_5_geom0")
    forearm = next(s for s, seg in enumerate(SEGMENTS) if seg.name == "right_forearm")
    g = h.human_geom_ids[forearm]
    y = np.array([0.0, 1.0, 0.0])
    x = np.array([1.0, 0.0, 0.0])
    half = 0.35  # the touch is 0.2 m from the centre, 0.15 m from the hand sphere

    def pose(offset: float) -> float:
        touch = data.geom_xpos[rg] + offset * x
        centre = touch - 0.2 * y
        joints = np.empty((len(JOINT_INDEX), 3))
        for k in range(len(JOINT_INDEX)):  # the rest of the body on the line, beyond the elbow
            joints[k] = centre - (half + 0.3 + 0.05 * k) * y
        joints[JOINT_INDEX["right_elbow"]] = centre - half * y
        joints[JOINT_INDEX["right_hand"]] = centre + half * y
        pose_human(model, data, h, joints)
        mujoco.mj_forward(model, data)
        return mujoco.mj_geomDistance(model, data, rg, g, 1.0, None)

    offset = 0.3
    gap = pose(offset)
    assert gap > 0.0
    for _ in range(5):  # move in until the geoms overlap by about 1 cm
        offset -= gap + 0.01
        gap = pose(offset)
        if gap < -0.005:
            break
    assert gap < -0.005
    pairs = {frozenset(map(int, pair)) for pair in data.contact.geom[: data.ncon]}
    assert frozenset((rg, int(g))) in pairs
    hand = h.human_geom_ids[next(s for s, seg in enumerate(SEGMENTS) if seg.name == "right_hand")]
    assert mujoco.mj_geomDistance(model, data, rg, hand, 1.0, None) > 0.05  # not the hand


@pytest.mark.parametrize(
    "method", ["block_position", "delivery_position", "stash_position", "check_block_id"]
)
@pytest.mark.parametrize("block", [99, -1, 5, "0", 1.0, True, None])
def test_positions_of_blocks_absent_from_the_scene_are_refused(method: str, block) -> None:
    """Block -1 used to be block 7's spot, 5 one of the 2x4 layout, 99 an IndexError."""
    cfg = SceneCfg()
    with pytest.raises(ConfigError, match=rf"1x4 scene \(0, 1, 2, 3\), got {block!r}"):
        getattr(cfg, method)(block)
    assert getattr(cfg, method)(np.int64(2)) is not None


def test_every_block_has_its_own_stash_spot() -> None:
    """Taken blocks are put down beside the human without overlapping one another, each on
    the side of its delivery spot, on the table top."""
    cfg = SceneCfg(arrangement="2x4")
    spots = np.array([cfg.stash_position(i) for i in cfg.block_ids])  # (8, 3)
    gap = np.abs(spots[:, None] - spots[None]).max(-1)  # (8, 8) box-to-box along the worst axis
    np.fill_diagonal(gap, np.inf)
    assert gap.min() >= cfg.block_size + 0.02 - 1e-12
    for i, spot in zip(cfg.block_ids, spots, strict=True):
        assert np.sign(spot[1]) == np.sign(cfg.delivery_position(i)[1])
        assert spot[2] == pytest.approx(0.5 * cfg.block_size)
        assert abs(spot[1]) + 0.5 * cfg.block_size <= 0.5 * cfg.table_size[1]


def test_blocks_can_collide_with_nothing(arm) -> None:
    """The block bodies are left out of MuJoCo's collision detection altogether, so where a
    block lies (on the table, carried, stashed) cannot change the physics."""
    cfg = SceneCfg(arrangement="2x4")
    model = build_scene(cfg, arm)
    for i in cfg.block_ids:
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"block_{i}")
        assert model.body_contype[b] == 0 and model.body_conaffinity[b] == 0
        g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"block_{i}")
        assert model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0


def test_pose_human_refuses_joints_it_cannot_place(arm) -> None:
    cfg = SceneCfg()
    model = build_scene(cfg, arm)
    data = mujoco.MjData(model)
    h = SceneHandles.resolve(model, cfg, arm)
    good = rest_pose()
    pose_human(model, data, h, good)
    mocap = data.mocap_pos.copy()
    for joints in (good[:5], good[:, :2], good[None], good.ravel()):
        with pytest.raises(ShapeError, match=r"expected joints \(K, 3\) with K >= 10"):
            pose_human(model, data, h, joints)
    with pytest.raises(ShapeError, match="real numbers"):
        pose_human(model, data, h, good.astype(complex))
    for bad in (np.nan, np.inf):
        joints = good.copy()
        joints[3, 1] = bad
        with pytest.raises(DataError, match="finite joints"):
            pose_human(model, data, h, joints)
    np.testing.assert_array_equal(data.mocap_pos, mocap)  # nothing was moved


def test_the_chair_seat_is_at_seat_height_above_the_floor(arm) -> None:
    """The seat's top is about 0.47 m above the floor plane and below the table top
    (z = 0), for two table heights: a chair floating above the table was a colliding geom."""
    for height in (0.72, 0.8):
        model = build_scene(SceneCfg(table_height=height), arm)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        floor = data.geom("floor").xpos[2]
        seat = data.geom("chair_seat").xpos[2] + model.geom("chair_seat").size[2]
        assert seat - floor == pytest.approx(0.47, abs=1e-9) and seat < 0.0
