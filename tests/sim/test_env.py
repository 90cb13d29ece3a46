"""SimEnv: actuator tracking, robot-human contacts, pick and delivery, task events."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from sim_fakes import FakeMotion, FakeOrder

from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.sim.env import SimCfg, SimEnv
from iplanner_torch.sim.human import HumanCfg, ScriptedHuman
from iplanner_torch.sim.scene import SceneCfg
from iplanner_torch.sim.tracker import Tracker, TrackerCfg


def _env(robot, human_cfg: HumanCfg | None = None, order=(0, 1, 2, 3)) -> SimEnv:
    scene = SceneCfg()
    targets = {i: scene.delivery_position(i) + [0.0, 0.0, 0.015] for i in scene.block_ids}
    cfg = human_cfg or HumanCfg()
    human = ScriptedHuman(
        cfg,
        FakeMotion(),
        task_order=FakeOrder(order) if cfg.mode == "tasks" else None,
        targets=targets,
        seed=0,
    )
    return SimEnv(scene, robot, human, Tracker(TrackerCfg(), seed=0), seed=0)


def _track(env: SimEnv, q0: np.ndarray, amp: float, seconds: float) -> float:
    worst = 0.0
    w = 2 * np.pi * 0.5
    while env.time < seconds:
        t = env.time
        q_des = q0 + amp * np.sin(w * t)
        qd_des = np.full_like(q0, amp * w * np.cos(w * t))
        env.step(q_des, qd_des)
        worst = max(worst, np.abs(env.robot_q() - (q0 + amp * np.sin(w * env.time))).max())
    return worst


def test_position_actuators_track_a_slow_trajectory(arm) -> None:
    env = _env(arm)
    assert _track(env, arm.q_home.numpy(), 0.2, 2.0) < 0.02


def test_real_robot_tracks_a_slow_trajectory() -> None:
    from iplanner_torch.robot.model import RobotModel

    robot = RobotModel.load("kuka_iiwa14")
    env = _env(robot)
    assert _track(env, robot.q_home.numpy(), 0.15, 1.0) < 0.03


@pytest.mark.parametrize("name", ["kuka_iiwa14", "fetch"])
def test_real_robots_track_motion_at_the_planners_acceleration_limit(name: str) -> None:
    """Every joint swings at 1 Hz with peak acceleration 6 rad/s^2 (the replanner's default
    ``acc_max``) from the home pose: the servos keep within 0.03 rad of the command, so the
    executed motion stays near the path whose collision bound was checked."""
    from iplanner_torch.planning.replanner import ReplannerCfg
    from iplanner_torch.robot.model import RobotModel

    robot = RobotModel.load(name)
    env = _env(robot)
    q0 = robot.q_home.numpy()
    w = 2 * np.pi  # 1 Hz
    lo, hi = robot.q_min.numpy(), robot.q_max.numpy()
    bounded = np.isfinite(lo) & np.isfinite(hi)
    mid = np.zeros_like(q0)  # continuous joints: any direction
    mid[bounded] = 0.5 * (lo[bounded] + hi[bounded])
    amp = ReplannerCfg().acc_max / w**2 * np.where(q0 > mid, -1.0, 1.0)  # towards mid-range
    worst = 0.0
    while env.time < 2.0:  # q0 + amp (1 - cos w t): starts at rest
        t = env.time
        env.step(q0 + amp * (1 - np.cos(w * t)), amp * w * np.sin(w * t))
        ref = q0 + amp * (1 - np.cos(w * env.time))
        worst = max(worst, float(np.abs(env.robot_q() - ref).max()))
    assert worst < 0.03


def _ik_path(arm, q0: torch.Tensor, point: np.ndarray, n: int = 150) -> list[np.ndarray]:
    q1 = arm.ik(torch.tensor(point), q0)
    return [(q0 + (q1 - q0) * s).numpy() for s in np.linspace(0.0, 1.0, n)]


def _blocked_env(arm) -> SimEnv:
    """An environment whose person has held the right hand in the robot's workspace since
    the start (150 control periods in, the robot at home)."""
    cfg = HumanCfg(
        mode="blocking",
        blocking_start_s=0.0,
        blocking_target=(0.15, -0.05, 0.2),
        blocking_hold_s=5.0,
    )
    env = _env(arm, cfg)
    for _ in range(150):  # the human's right hand moves into the workspace
        env.step(arm.q_home.numpy(), np.zeros(3))
    return env


def test_contact_when_arm_goes_through_the_human(arm) -> None:
    env = _blocked_env(arm)
    assert env.contact_steps == 0
    hand = env.human_joints()[9]
    q = torch.as_tensor(env.robot_q(), dtype=torch.float32)
    seen, listed = [], []
    for q_des in _ik_path(arm, q, hand) + [None] * 50:
        info = env.step(q_des if q_des is not None else env.robot_q(), np.zeros(3))
        seen.append(info.contact)
        listed.append(len(env.robot_human_contacts()))
    assert env.contact_onsets >= 1
    assert env.contact_steps == sum(seen) >= 1
    # an onset is a step in contact after one without (none before the path: checked above)
    onsets = sum(now and not before for before, now in zip([False] + seen[:-1], seen))
    assert env.contact_onsets == onsets < env.contact_steps
    assert max(listed) >= 1
    # MuJoCo's contacts and its distances agree: the body distance went below zero
    assert env.min_body_distance < 0.0


def test_no_contact_far_from_the_human(arm) -> None:
    env = _env(arm)
    for _ in range(100):
        env.step(arm.q_home.numpy(), np.zeros(3))
    assert env.contact_steps == 0
    assert env.min_body_distance > 0.05


def test_body_distance_where_no_bounding_spheres_overlap(arm) -> None:
    """The robot at home, the person at rest: every pair's bounding spheres lie apart (the
    pruning's lower bounds are all > 0), and the body distance is still the smallest pair
    distance found by trying every pair, not the BODY_DISTANCE_MAX cap."""
    env = _env(arm)
    for _ in range(100):
        env.step(arm.q_home.numpy(), np.zeros(3))
    m, d = env.model, env.data
    r, h = env._robot_geoms, env._human_geoms
    centres = np.linalg.norm(d.geom_xpos[r][:, None] - d.geom_xpos[h][None], axis=-1)
    assert (centres - m.geom_rbound[r][:, None] - m.geom_rbound[h][None]).min() > 0.0
    brute = float(env.geom_distances().min())
    assert 0.05 < brute < 1.0
    assert env.body_distance() == pytest.approx(brute, abs=1e-12)


def _axis_gap(env: SimEnv, g1: int, g2: int) -> float:
    """The smallest distance between points along the axes of geoms g1 and g2 less both
    radii, by brute force: 300 points along each axis, then 200 along each around the closest
    pair, within one coarse step either side (a step of at most a few mm there: the sampled
    minimum is then within a few hundredths of a mm of the true one)."""
    m, d = env.model, env.data
    ends = []
    for g in (g1, g2):
        half = m.geom_size[g, 1] if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
        ends.append((d.geom_xpos[g], d.geom_xmat[g].reshape(3, 3)[:, 2], float(half)))

    def points(k: int, lo: float, hi: float, n: int) -> np.ndarray:
        centre, z, _ = ends[k]
        return centre + np.linspace(lo, hi, n)[:, None] * z

    (_, _, ha), (_, _, hb) = ends
    a, b = points(0, -ha, ha, 300), points(1, -hb, hb, 300)
    dist = np.linalg.norm(a[:, None] - b[None], axis=-1)
    i, j = np.unravel_index(int(dist.argmin()), dist.shape)
    sa, sb = np.linspace(-ha, ha, 300), np.linspace(-hb, hb, 300)
    step_a, step_b = 2 * ha / 299, 2 * hb / 299
    a = points(0, max(sa[i] - step_a, -ha), min(sa[i] + step_a, ha), 200)
    b = points(1, max(sb[j] - step_b, -hb), min(sb[j] + step_b, hb), 200)
    fine = float(np.linalg.norm(a[:, None] - b[None], axis=-1).min())
    return min(fine, float(dist.min())) - float(m.geom_size[g1, 0]) - float(m.geom_size[g2, 0])


def test_body_distance_against_brute_force_capsule_distances(arm) -> None:
    """Each robot-capsule to human-capsule distance equals the brute-force distance between
    points along the two axes, less both radii (:func:`_axis_gap`); the pruned body distance
    is the smallest of all pairs."""
    env = _blocked_env(arm)
    hand = env.human_joints()[9]
    q = torch.as_tensor(env.robot_q(), dtype=torch.float32)
    path = _ik_path(arm, q, hand, n=60)
    capsule = mujoco.mjtGeom.mjGEOM_CAPSULE
    checked = 0
    for q_des in path[::6]:
        for _ in range(8):
            env.step(q_des, np.zeros(3))
        dist = env.geom_distances()  # (R, H)
        assert env.body_distance() == pytest.approx(float(dist.min()), abs=1e-12)
        for i, g1 in enumerate(env._robot_geoms):
            if env.model.geom_type[g1] != capsule:
                continue
            for j, g2 in enumerate(env._human_geoms):
                brute = _axis_gap(env, int(g1), int(g2))
                if brute < 0.9:
                    assert dist[i, j] == pytest.approx(brute, abs=1e-4)
                    checked += 1
    assert checked > 50
    assert env.min_body_distance <= float(dist.min()) + 1e-12


def test_pick_and_deliver_by_a_scripted_path(arm) -> None:
    env = _env(arm, order=(1, 0, 2, 3))
    events = [env.start_fetch(1)]
    q = torch.as_tensor(env.robot_q(), dtype=torch.float32)
    above = env.fetch.pick_point + [0.0, 0.0, 0.1]
    for point in (above, env.fetch.pick_point, above, env.fetch.place_point):
        for q_des in _ik_path(arm, q, point, n=100) + [None] * 30:
            events += env.step(q_des if q_des is not None else q.numpy(), np.zeros(3)).events
        q = torch.as_tensor(env.robot_q(), dtype=torch.float32)
    kinds = [e.kind for e in events]
    assert kinds[:3] == ["fetch_started", "picked", "delivered"]
    assert env.block_state[1] in ("delivered", "human", "taken")
    # the block was carried: it left its far position and lies on its spot now
    grasped = 0
    for _ in range(300):
        step_events = env.step(q.numpy(), np.zeros(3)).events
        events += step_events
        if env.block_state[1] == "delivered":
            np.testing.assert_allclose(env.block_position(1), env.scene_cfg.delivery_position(1))
        if any(e.kind == "human_grasped" and e.block == 1 for e in step_events):
            grasped += 1
            assert 1 not in env.delivered  # in the person's hand, no longer on its spot
    assert "human_take_started" in [e.kind for e in events]
    assert grasped == 1
    with pytest.raises(ConfigError, match="far position"):
        env.start_fetch(1)


def test_step_rejects_bad_commands(arm) -> None:
    env = _env(arm)
    with pytest.raises(ShapeError, match=r"expected q_des and qd_des \(3,\)"):
        env.step(np.zeros(4), np.zeros(4))
    with pytest.raises(ConfigError, match="control_hz"):
        SimCfg(control_hz=1000.0, physics_dt=0.002)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_step_and_reset_reject_non_finite_commands(arm, bad: float) -> None:
    env = _env(arm)
    q = arm.q_home.numpy().copy()
    qpos = env.data.qpos.copy()
    with pytest.raises(DataError, match="finite q_des and qd_des"):
        env.step(np.array([q[0], bad, q[2]]), np.zeros(3))
    with pytest.raises(DataError, match="finite q_des and qd_des"):
        env.step(q, np.array([0.0, 0.0, bad]))
    assert env.time == 0.0  # nothing was simulated
    np.testing.assert_array_equal(env.data.qpos, qpos)
    with pytest.raises(DataError, match="finite q_init"):
        env.reset(q_init=np.array([bad, 0.0, 0.0]))
    env.step(q, np.zeros(3))
    assert np.isfinite(env.robot_q()).all()


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        (dict(control_hz=float("nan")), "control_hz"),
        (dict(control_hz=float("inf")), "control_hz"),
        (dict(control_hz=0.0), "control_hz"),
        (dict(physics_dt=float("nan")), "physics_dt"),
        (dict(tracker_window=2.5), "tracker_window"),
        (dict(tracker_window=0), "tracker_window"),
        (dict(tracker_fps=float("inf")), "tracker_fps"),
        (dict(tracker_fps=float("nan")), "tracker_fps"),
        (dict(tracker_noise=float("nan")), "tracker_noise"),
        (dict(tracker_noise=float("inf")), "tracker_noise"),
        (dict(tracker_noise=1.5), r"tracker_noise in \[0, 1\] m"),
        (dict(tracker_dropout=float("nan")), "tracker_dropout"),
        (dict(human={"speed": "fast"}), "human"),
        (dict(fetch=None), "fetch"),
    ],
)
def test_sim_cfg_rejects_meaningless_values(kw: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        SimCfg(**kw)


@pytest.mark.parametrize(
    "bad",
    [["a", "b", "c"], [0.0, [1.0, 2.0], 0.0], None, [0.0, None, 0.0], [0.0, 1j, 0.0], [True] * 3],
)
def test_step_and_reset_refuse_commands_that_are_no_real_numbers(arm, bad) -> None:
    env = _env(arm)
    q = arm.q_home.numpy()
    with pytest.raises(ShapeError, match="q_des an array of real numbers"):
        env.step(bad, np.zeros(3))
    with pytest.raises(ShapeError, match="qd_des an array of real numbers"):
        env.step(q, bad)
    if bad is not None:  # None is the default q_init (the home pose)
        with pytest.raises(ShapeError, match="q_init an array of real numbers"):
            env.reset(q_init=bad)
    assert env.time == 0.0
    env.step(q.tolist(), [0, 0, 0])  # lists of numbers remain welcome


def test_reset_refuses_q_init_outside_the_joint_limits(arm) -> None:
    env = _env(arm)  # FakeArm limits: j1 [-3, 3], j2 [-2.5, 2.5], j3 [-2.8, 2.8]
    with pytest.raises(ConfigError, match=r"joint 'j2', outside its limits \[-2.5, 2.5\]"):
        env.reset(q_init=np.array([0.0, -2.6, 0.0]))
    with pytest.raises(ConfigError, match=r"got 3.1 rad for joint 'j1'"):
        env.reset(q_init=np.array([3.1, 0.0, 0.0]))
    env.reset(q_init=np.array([3.0 + 5e-7, -2.5, 2.8]))  # on a limit, up to rounding
    np.testing.assert_array_equal(env.robot_q(), [3.0 + 5e-7, -2.5, 2.8])


def test_reset_leaves_continuous_joints_unlimited() -> None:
    from iplanner_torch.robot.model import RobotModel

    robot = RobotModel.load("fetch")
    env = _env(robot)
    q = robot.q_home.numpy().astype(np.float64)
    q[2] = 10.0  # upperarm_roll_joint is continuous
    env.reset(q_init=q)
    assert env.robot_q()[2] == 10.0
    q[0] = 3.0
    with pytest.raises(ConfigError, match="'shoulder_pan_joint', outside its limits"):
        env.reset(q_init=q)


def test_commanded_speeds_are_clipped_to_the_speed_limits() -> None:
    """A finite but absurd desired speed on a continuous joint (no control range) used to
    reach MuJoCo, which zeroed the controls with a warning; it now acts as the limit itself,
    while a command within the limits reaches the actuators exactly as given."""
    from iplanner_torch.robot.model import RobotModel

    robot = RobotModel.load("fetch")
    q = robot.q_home.numpy().astype(np.float64)
    v_max = robot.v_max.numpy().astype(np.float64)
    envs = [_env(robot), _env(robot)]
    for speed, env in zip((1e12, v_max[2]), envs, strict=True):
        qd = np.zeros(7)
        qd[2] = speed
        for _ in range(5):
            env.step(q, qd)
        assert env.data.warning[mujoco.mjtWarning.mjWARN_BADCTRL].number == 0
    np.testing.assert_array_equal(envs[0].data.qpos, envs[1].data.qpos)
    assert envs[0].robot_qd()[2] > 0.5 * v_max[2]  # the joint did turn
    env = _env(robot)
    qd = np.linspace(-0.9, 0.9, 7) * v_max
    env.step(q, qd)
    tau = (env.cfg.substeps - 1) * env.model.opt.timestep + env._vel_ff_s
    ids = env.handles.actuator_ids
    expect = np.clip(q + qd * tau, env._ctrl_lo, env._ctrl_hi)
    np.testing.assert_array_equal(env.data.ctrl[ids], expect)


@pytest.mark.parametrize("far", [1e300, -1e300, 50.0])
def test_positions_on_continuous_joints_are_kept_within_half_a_turn(far: float) -> None:
    """A finite but absurd position command on a continuous joint (no position limits, no
    control range) used to reach MuJoCo, which zeroed every control with a warning; it now
    acts as a target half a turn away from where the joint is, and joints with limits get
    their command as before."""
    from iplanner_torch.robot.model import RobotModel

    robot = RobotModel.load("fetch")
    q = robot.q_home.numpy().astype(np.float64)
    envs = [_env(robot), _env(robot)]
    for target, env in zip((far, q[2] + np.copysign(np.pi, far)), envs, strict=True):
        for _ in range(3):
            q_des = q.copy()
            q_des[2] = target if target == far else env.robot_q()[2] + np.copysign(np.pi, far)
            env.step(q_des, np.zeros(7))
        assert env.data.warning[mujoco.mjtWarning.mjWARN_BADCTRL].number == 0
    np.testing.assert_array_equal(envs[0].data.qpos, envs[1].data.qpos)
    ids = envs[0].handles.actuator_ids
    assert np.isfinite(envs[0].data.ctrl[ids]).all()
    assert abs(envs[0].data.ctrl[ids][2] - envs[0].robot_q()[2]) < 2 * np.pi
    np.testing.assert_array_equal(envs[0].data.ctrl[ids][[0, 1, 3, 5]], q[[0, 1, 3, 5]])


@pytest.mark.parametrize("block", [99, -1, "0", 1.5, None])
def test_block_ids_absent_from_the_scene_are_refused(arm, block) -> None:
    env = _env(arm)
    with pytest.raises(ConfigError, match=rf"scene \(0, 1, 2, 3\), got {block!r}"):
        env.block_position(block)
    with pytest.raises(ConfigError, match=rf"scene \(0, 1, 2, 3\), got {block!r}"):
        env.start_fetch(block)
    assert env.fetch is None


def test_where_a_stashed_block_lies_changes_no_physics(arm) -> None:
    """A taken block put down inside the robot's links touches nothing: the robot moves
    exactly as without it, and MuJoCo reports no contact with it."""

    class StashOnTheRobot(SceneCfg):
        def stash_position(self, block_id: int) -> np.ndarray:
            return env_a.data.xpos[3].copy()  # link2 of the fake arm

    env_a = _env(arm)
    env_b = _env(arm)
    env_b.scene_cfg = StashOnTheRobot()
    for env in (env_a, env_b):
        env.block_state[0] = "taken"
    q = torch.as_tensor(env_a.robot_q(), dtype=torch.float32)
    for q_des in _ik_path(arm, q, np.array([0.3, 0.3, 0.2]), n=60):
        for env in (env_a, env_b):
            env.step(q_des, np.zeros(3))
        np.testing.assert_array_equal(env_a.data.qpos, env_b.data.qpos)
        np.testing.assert_array_equal(env_a.data.qvel, env_b.data.qvel)
        assert env_a.data.ncon == env_b.data.ncon
    block = env_b.handles.block_mocap[0]
    np.testing.assert_allclose(env_b.data.mocap_pos[block], env_a.data.xpos[3], atol=0.05)
