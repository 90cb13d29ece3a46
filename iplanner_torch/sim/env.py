"""The MuJoCo environment of the closed loop: robot execution, human, blocks and events.

:meth:`SimEnv.step` advances one control period: the robot's position actuators track the
commanded ``q_des + qd_des * tau`` (``tau`` the time since the command, a first-order hold of
the planned trajectory) for ``physics_dt``-sized MuJoCo steps, ``qd_des`` clipped to the
robot's speed limits ``v_max``. A MuJoCo position actuator
applies ``kp (ctrl - q) - kv qd``; its set point is advanced by ``(kv / kp) qd_des`` so that the
force is the PD tracking law ``kp (q_des - q) + kv (qd_des - qd)`` (no velocity lag). The
human's capsules follow the scripted human at every physics step, and robot-human contacts are
read from ``data.contact``. At the end of every period the robot's distance to the person's
body is measured on MuJoCo's own geometry (:meth:`SimEnv.body_distance`). After the physics,
blocks are picked / placed, the human's script advances and the tracker samples the human.

Blocks are kinematic (mocap): resting on the table, following the robot's tool point after a
pick (fixed offset), resting on the delivery spot after the release, following the human's
hand after the human grasps them, and finally put down beside the human.

Task events (``TaskEvent.kind``): ``fetch_started``, ``picked``, ``delivered``,
``fetch_done``, ``human_take_started``, ``human_grasped``, ``human_took``,
``blocking_started``, ``done`` (every block taken by the human).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.sim.human import HumanCfg, ScriptedHuman
from iplanner_torch.sim.scene import (
    RobotLike,
    SceneCfg,
    SceneHandles,
    build_scene,
    pose_human,
)
from iplanner_torch.sim.tasks import FetchCfg, FetchPhase, FetchTask
from iplanner_torch.sim.tracker import MAX_NOISE_M, MAX_WINDOW, Tracker, TrackerCfg

#: geom pairs farther apart than this are not measured exactly; a distance is capped there [m]
BODY_DISTANCE_MAX = 1.0
#: how far an initial joint position may lie outside its limit (rounding of the limits) [rad]
Q_INIT_TOLERANCE = 1e-6
#: most physics steps in one control period: each is a Python iteration of :meth:`SimEnv.step`
#: (about 0.1 ms), so 10000 take about a second; a physics_dt of 1e-9 s at 100 Hz asked for
#: 10^7 of them and a step never returned
MAX_SUBSTEPS = 10_000


@dataclass(frozen=True, kw_only=True)
class SimCfg:
    """Simulation rates, sensing and the human's behaviour.

    Raises:
        ConfigError: for a value out of range, and when a control period would hold more than
            ``MAX_SUBSTEPS`` physics steps (``control_hz * physics_dt < 1 / MAX_SUBSTEPS``).
    """

    # MuJoCo physics timestep [s]
    physics_dt: float = 0.002
    # rate at which new joint commands are applied [Hz]
    control_hz: float = 100.0
    # tracker frame rate [Hz]
    tracker_fps: float = 15.0
    # tracker noise standard deviation per coordinate [m]
    tracker_noise: float = 0.01
    # probability that a joint is lost in a tracker frame
    tracker_dropout: float = 0.0
    # frames in the tracker window (at most MAX_WINDOW); a predictor that states its window
    # (n_prev) sets it
    tracker_window: int = 15
    # human behaviour (speed, holds, idles, blocking)
    human: HumanCfg = field(default_factory=HumanCfg)
    # robot delivery tolerances
    fetch: FetchCfg = field(default_factory=FetchCfg)

    def __post_init__(self) -> None:
        if not 0.0 < checks.finite("physics_dt", self.physics_dt) <= 0.01:
            raise ConfigError(f"expected physics_dt in (0, 0.01] s, got {self.physics_dt!r}")
        checks.positive("control_hz", self.control_hz)
        ratio = self.control_hz * self.physics_dt  # control periods per physics step
        if ratio > 1.0 + 1e-9:
            raise ConfigError(
                f"expected 0 < control_hz <= 1 / physics_dt, got {self.control_hz} Hz with "
                f"physics_dt {self.physics_dt} s"
            )
        if not ratio > 1.0 / (MAX_SUBSTEPS + 0.5):  # round(1 / ratio) <= MAX_SUBSTEPS
            raise ConfigError(
                f"expected at most {MAX_SUBSTEPS} physics steps per control period "
                f"(control_hz * physics_dt >= {1.0 / MAX_SUBSTEPS:g}), got control_hz "
                f"{self.control_hz} Hz with physics_dt {self.physics_dt} s"
            )
        # the tracker fields under their names here (TrackerCfg checks them again)
        checks.positive("tracker_fps", self.tracker_fps)
        if not checks.non_negative("tracker_noise", self.tracker_noise) <= MAX_NOISE_M:
            raise ConfigError(
                f"expected tracker_noise in [0, {MAX_NOISE_M:g}] m, got {self.tracker_noise!r}"
            )
        if not 0.0 <= checks.finite("tracker_dropout", self.tracker_dropout) < 1.0:
            raise ConfigError(f"expected tracker_dropout in [0, 1), got {self.tracker_dropout!r}")
        if checks.integer("tracker_window", self.tracker_window, minimum=1) > MAX_WINDOW:
            raise ConfigError(
                f"expected tracker_window <= {MAX_WINDOW} frames, got {self.tracker_window!r}"
            )
        self.tracker_cfg()
        if not isinstance(self.human, HumanCfg):
            raise ConfigError(f"expected human a HumanCfg, got {self.human!r}")
        if not isinstance(self.fetch, FetchCfg):
            raise ConfigError(f"expected fetch a FetchCfg, got {self.fetch!r}")

    @property
    def substeps(self) -> int:
        """Physics steps per control period."""
        return max(1, round(1.0 / (self.control_hz * self.physics_dt)))

    def tracker_cfg(self) -> TrackerCfg:
        """The tracker's configuration."""
        return TrackerCfg(
            fps=self.tracker_fps,
            noise_sigma=self.tracker_noise,
            dropout_rate=self.tracker_dropout,
            window=self.tracker_window,
        )


@dataclass(frozen=True, kw_only=True)
class TaskEvent:
    """A task event at a simulated time (kinds in the module docstring)."""

    kind: str
    block: int
    time: float


@dataclass(kw_only=True)
class StepInfo:
    """What happened during one control period.

    Attributes:
        events: task events, in order.
        contact: whether any robot-human contact existed during the period.
        new_contact: whether a contact began in this period (none in the previous one).
    """

    events: list[TaskEvent]
    contact: bool
    new_contact: bool


class SimEnv:
    """The closed-loop simulation of paper sec. 7.

    Args:
        scene_cfg: workspace geometry.
        robot: the robot model (``mjcf_path``, ``joint_names``, ``q_home``, base pose).
        human: the scripted human (its ``targets`` are the delivery grasp points).
        tracker: the skeleton tracker.
        seed: seed of the environment (only the MuJoCo state here; human and tracker carry
            their own seeds), an integer >= 0.
        cfg: rates and tolerances.

    Raises:
        ConfigError: when the robot's limits (``q_min``, ``q_max``, ``v_max``) are not (J,),
            ``seed`` is not a non-negative integer, ``scene_cfg`` / ``cfg`` is not a
            :class:`SceneCfg` / :class:`SimCfg`, or ``human`` / ``tracker`` is not a
            :class:`ScriptedHuman` / :class:`Tracker`.
    """

    def __init__(
        self,
        scene_cfg: SceneCfg,
        robot: RobotLike,
        human: ScriptedHuman,
        tracker: Tracker,
        seed: int,
        cfg: SimCfg | None = None,
    ) -> None:
        if not isinstance(scene_cfg, SceneCfg):
            raise ConfigError(f"expected scene_cfg a SceneCfg, got {type(scene_cfg).__name__}")
        if cfg is not None and not isinstance(cfg, SimCfg):
            raise ConfigError(f"expected cfg a SimCfg or None, got {type(cfg).__name__}")
        if not isinstance(human, ScriptedHuman):
            raise ConfigError(f"expected human a ScriptedHuman, got {type(human).__name__}")
        if not isinstance(tracker, Tracker):
            raise ConfigError(f"expected tracker a Tracker, got {type(tracker).__name__}")
        self.scene_cfg = scene_cfg
        self.robot = robot
        self.human = human
        self.tracker = tracker
        self.seed = checks.seed(seed)
        self.cfg = cfg or SimCfg()
        self.model = build_scene(scene_cfg, robot, physics_dt=self.cfg.physics_dt)
        self.data = mujoco.MjData(self.model)
        self.handles = SceneHandles.resolve(self.model, scene_cfg, robot)
        self.num_joints = len(robot.joint_names)
        self._ctrl_lo = self.model.actuator_ctrlrange[self.handles.actuator_ids, 0].copy()
        self._ctrl_hi = self.model.actuator_ctrlrange[self.handles.actuator_ids, 1].copy()
        limited = self.model.actuator_ctrllimited[self.handles.actuator_ids].astype(bool)
        self._ctrl_lo[~limited] = -np.inf
        self._ctrl_hi[~limited] = np.inf
        kp = -self.model.actuator_biasprm[self.handles.actuator_ids, 1]
        kv = -self.model.actuator_biasprm[self.handles.actuator_ids, 2]
        self._vel_ff_s = np.where(kp > 0, kv / np.where(kp > 0, kp, 1.0), 0.0)  # (J,) [s]
        self._q_lo, self._q_hi = self._position_limits()  # (J,) [rad], -inf / inf if none
        self._unlimited = ~(np.isfinite(self._q_lo) & np.isfinite(self._q_hi))  # (J,) bool
        v_max = getattr(robot, "v_max", None)
        self._v_max = (  # (J,) [rad/s]
            np.full(self.num_joints, np.inf) if v_max is None else _numpy(v_max).reshape(-1)
        )
        for name, lim in (("q_min", self._q_lo), ("q_max", self._q_hi), ("v_max", self._v_max)):
            if lim.shape != (self.num_joints,):
                raise ConfigError(f"expected robot.{name} ({self.num_joints},), got {lim.shape}")
        # the robot geoms that can touch the person (conaffinity bit 2) and the person's geoms
        touching = self.handles.robot_geom & ((self.model.geom_conaffinity & 2) != 0)
        self._robot_geoms = np.nonzero(touching)[0]  # (R,)
        self._human_geoms = np.asarray(self.handles.human_geom_ids)  # (H,)
        self.reset()

    def _position_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(J,) lower and upper joint limits [rad]: the robot's ``q_min`` / ``q_max`` where it
        has them, else the MJCF's joint ranges (infinite for joints without one)."""
        q_min, q_max = getattr(self.robot, "q_min", None), getattr(self.robot, "q_max", None)
        if q_min is not None and q_max is not None:
            return _numpy(q_min).reshape(-1), _numpy(q_max).reshape(-1)
        jids = self.model.dof_jntid[self.handles.dof_adr]
        limited = self.model.jnt_limited[jids].astype(bool)
        lo = np.where(limited, self.model.jnt_range[jids, 0], -np.inf)
        hi = np.where(limited, self.model.jnt_range[jids, 1], np.inf)
        return lo, hi

    # -- state --------------------------------------------------------------------------------

    def reset(self, q_init: np.ndarray | None = None) -> None:
        """Back to t = 0: robot at ``q_init`` (default ``q_home``) at rest, blocks at their far
        positions, human at rest, tracker empty (its first frame is taken here).

        Args:
            q_init: (J,) initial joint positions [rad], within the joint limits (up to
                ``Q_INIT_TOLERANCE``).

        Raises:
            ShapeError: when ``q_init`` is not (J,) real numbers.
            DataError: when ``q_init`` holds NaN or infinity.
            ConfigError: when ``q_init`` lies outside a joint's limits.
        """
        if q_init is None:
            q0 = _numpy(self.robot.q_home)
        else:
            q0 = checks.real_array("q_init", q_init).astype(np.float64)
        if q0.shape != (self.num_joints,):
            raise ShapeError(f"expected q_init ({self.num_joints},), got {q0.shape}")
        if not np.isfinite(q0).all():
            raise DataError(f"expected finite q_init, got {q0}")
        outside = (q0 < self._q_lo - Q_INIT_TOLERANCE) | (q0 > self._q_hi + Q_INIT_TOLERANCE)
        if outside.any():
            j = int(np.flatnonzero(outside)[0])
            raise ConfigError(
                f"expected q_init within the joint limits, got {float(q0[j])} rad for joint "
                f"{self.robot.joint_names[j]!r}, outside its limits "
                f"[{float(self._q_lo[j])}, {float(self._q_hi[j])}]"
            )
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self.handles.qpos_adr] = q0
        self.data.ctrl[self.handles.actuator_ids] = q0
        self.human.reset()
        self.tracker.reset()
        self.block_state: dict[int, str] = {i: "far" for i in self.scene_cfg.block_ids}
        self._block_offset: dict[int, np.ndarray] = {}
        for i in self.scene_cfg.block_ids:
            self.data.mocap_pos[self.handles.block_mocap[i]] = self.scene_cfg.block_position(i)
        self.fetch: FetchTask | None = None
        self.delivered: set[int] = set()
        self.taken: set[int] = set()
        self.contact_steps = 0
        self.contact_onsets = 0
        self._in_contact = False
        self.all_done = False
        pose_human(self.model, self.data, self.handles, self.human.joint_positions(0.0))
        mujoco.mj_forward(self.model, self.data)
        self.min_body_distance = self.body_distance()
        self.tracker.observe(0.0, self.human.joint_positions(0.0))

    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return float(self.data.time)

    @property
    def control_dt(self) -> float:
        """Seconds per :meth:`step`."""
        return self.cfg.substeps * self.model.opt.timestep

    def robot_q(self) -> np.ndarray:
        """(J,) measured joint positions [rad]."""
        return self.data.qpos[self.handles.qpos_adr].copy()

    def robot_qd(self) -> np.ndarray:
        """(J,) measured joint velocities [rad/s]."""
        return self.data.qvel[self.handles.dof_adr].copy()

    def ee_position(self) -> np.ndarray:
        """(3,) the tool point in the table frame [m] (MuJoCo's ``ee_site``)."""
        if self.handles.ee_site < 0:
            return _numpy(self.robot.ee_position(_like_q(self.robot, self.robot_q())))
        return self.data.site_xpos[self.handles.ee_site].copy()

    def human_joints(self) -> np.ndarray:
        """(K, 3) true human joint positions now [m]."""
        return self.human.joint_positions(self.time)

    def block_position(self, block: int) -> np.ndarray:
        """(3,) current centre of a block [m].

        Raises:
            ConfigError: when ``block`` is not one of the scene's block ids.
        """
        return self.data.mocap_pos[
            self.handles.block_mocap[self.scene_cfg.check_block_id(block)]
        ].copy()

    # -- actions ------------------------------------------------------------------------------

    def start_fetch(self, block: int) -> TaskEvent:
        """Begin ``Fetch_block`` (replaces an action in its return phase).

        Raises:
            ConfigError: when ``block`` is not one of the scene's block ids or not waiting at
                its far position, or another fetch is still carrying.
        """
        self.scene_cfg.check_block_id(block)
        if self.block_state.get(block) != "far":
            raise ConfigError(
                f"expected block {block} at its far position, got {self.block_state.get(block)}"
            )
        if self.fetch is not None and self.fetch.phase is not FetchPhase.RETURN:
            raise ConfigError(f"Fetch_{self.fetch.block} is still in {self.fetch.phase.value}")
        self.fetch = FetchTask.create(block, self.scene_cfg, self.cfg.fetch, self.time)
        return TaskEvent(kind="fetch_started", block=block, time=self.time)

    def step(self, q_des: np.ndarray, qd_des: np.ndarray) -> StepInfo:
        """Advance one control period tracking ``q_des + qd_des * tau``.

        Args:
            q_des: (J,) commanded joint positions [rad].
            qd_des: (J,) commanded joint velocities [rad/s]; each is clipped to the robot's
                speed limit ``[-v_max, v_max]`` (a command within the limits is used as is).

        On a joint without position limits (a continuous joint), ``q_des`` is clipped to within
        half a turn (pi) of the joint's position at the start of the period: a servo target
        farther away would only spin the joint round, and one near the float range made
        MuJoCo zero every control. A planner's command lies far inside that window.

        Returns:
            Events and contacts of the period.

        Raises:
            ShapeError: when ``q_des`` or ``qd_des`` is not (J,) real numbers.
            DataError: when ``q_des`` or ``qd_des`` holds NaN or infinity (nothing is
                simulated then).
        """
        q_des = checks.real_array("q_des", q_des).astype(np.float64)
        qd_des = checks.real_array("qd_des", qd_des).astype(np.float64)
        if q_des.shape != (self.num_joints,) or qd_des.shape != (self.num_joints,):
            raise ShapeError(
                f"expected q_des and qd_des ({self.num_joints},), got {q_des.shape}, "
                f"{qd_des.shape}"
            )
        if not (np.isfinite(q_des).all() and np.isfinite(qd_des).all()):
            raise DataError(f"expected finite q_des and qd_des, got {q_des}, {qd_des}")
        qd_des = np.minimum(np.maximum(qd_des, -self._v_max), self._v_max)
        if self._unlimited.any():
            q_now = self.robot_q()
            near = np.minimum(np.maximum(q_des, q_now - np.pi), q_now + np.pi)
            q_des = np.where(self._unlimited, near, q_des)
        m, d, h = self.model, self.data, self.handles
        dt = m.opt.timestep
        contact = False
        for k in range(self.cfg.substeps):
            target = q_des + qd_des * (k * dt + self._vel_ff_s)
            d.ctrl[h.actuator_ids] = np.clip(target, self._ctrl_lo, self._ctrl_hi)
            pose_human(m, d, h, self.human.joint_positions(d.time + dt))
            self._move_blocks()
            mujoco.mj_step(m, d)
            if not contact and d.ncon:
                contact = self._robot_human_contact()
        t = self.time
        events: list[TaskEvent] = []
        new_contact = contact and not self._in_contact
        self._in_contact = contact
        self.contact_steps += int(contact)
        self.contact_onsets += int(new_contact)
        self.min_body_distance = min(self.min_body_distance, self.body_distance())
        events.extend(self._update_fetch(t))
        for ev in self.human.update(t, set(self.delivered)):
            events.append(TaskEvent(kind=ev.kind, block=ev.block, time=ev.time))
            if ev.kind == "human_grasped":
                self.block_state[ev.block] = "human"
                self.delivered.discard(ev.block)
            elif ev.kind == "human_took":
                self.block_state[ev.block] = "taken"
                self.taken.add(ev.block)
        self._move_blocks()
        if (
            not self.all_done
            and self.human.cfg.mode == "tasks"
            and self.taken
            and self.taken == set(self.human.order)
        ):
            self.all_done = True
            events.append(TaskEvent(kind="done", block=-1, time=t))
        self.tracker.observe(t, self.human.joint_positions(t))
        return StepInfo(events=events, contact=contact, new_contact=new_contact)

    def geom_distances(self) -> np.ndarray:
        """(R, H) signed distances [m] between the R robot geoms that can touch the person and
        the person's H capsules and spheres, from MuJoCo's ``mj_geomDistance`` at the state of
        the last physics step (< 0: they overlap by that much). Pairs farther apart than
        ``BODY_DISTANCE_MAX`` read ``BODY_DISTANCE_MAX``."""
        m, d = self.model, self.data
        out = np.empty((self._robot_geoms.size, self._human_geoms.size))
        for i, g1 in enumerate(self._robot_geoms):
            for j, g2 in enumerate(self._human_geoms):
                out[i, j] = mujoco.mj_geomDistance(m, d, int(g1), int(g2), BODY_DISTANCE_MAX, None)
        return out

    def body_distance(self) -> float:
        """The smallest of :meth:`geom_distances` [m]: how close the robot is to the
        person's body (the capsules MuJoCo's contacts are found on, not the planner's sphere
        models). Pairs whose bounding spheres cannot be closer than the best pair so far are
        skipped, which does not change the result; ``BODY_DISTANCE_MAX`` when every pair is
        farther."""
        m, d = self.model, self.data
        r, h = self._robot_geoms, self._human_geoms
        if r.size == 0 or h.size == 0:
            return BODY_DISTANCE_MAX
        gap = np.linalg.norm(d.geom_xpos[r][:, None] - d.geom_xpos[h][None], axis=-1)
        lower = gap - m.geom_rbound[r][:, None] - m.geom_rbound[h][None]  # (R, H)
        best = BODY_DISTANCE_MAX
        for flat in np.argsort(lower, axis=None):
            i, j = divmod(int(flat), h.size)
            if lower[i, j] >= best:
                break
            dist = mujoco.mj_geomDistance(m, d, int(r[i]), int(h[j]), BODY_DISTANCE_MAX, None)
            best = min(best, dist)
        return float(best)

    # -- internals ----------------------------------------------------------------------------

    def _robot_human_contact(self) -> bool:
        d, h = self.data, self.handles
        geoms = d.contact.geom[: d.ncon]  # (ncon, 2)
        rob = h.robot_geom[geoms]
        hum = h.human_geom[geoms]
        return bool(((rob[:, 0] & hum[:, 1]) | (rob[:, 1] & hum[:, 0])).any())

    def robot_human_contacts(self) -> list[tuple[int, int, float]]:
        """(robot geom, human geom, penetration distance [m]) of the current contacts."""
        d, h = self.data, self.handles
        out = []
        for c in range(d.ncon):
            g1, g2 = int(d.contact.geom[c, 0]), int(d.contact.geom[c, 1])
            if h.robot_geom[g1] and h.human_geom[g2]:
                out.append((g1, g2, float(d.contact.dist[c])))
            elif h.robot_geom[g2] and h.human_geom[g1]:
                out.append((g2, g1, float(d.contact.dist[c])))
        return out

    def _update_fetch(self, t: float) -> list[TaskEvent]:
        f = self.fetch
        if f is None:
            return []
        cfg = self.cfg.fetch
        ee = self.ee_position()
        if f.phase is FetchPhase.APPROACH:
            if np.linalg.norm(ee - f.pick_point) <= cfg.pick_radius:
                self.block_state[f.block] = "robot"
                self._block_offset[f.block] = self.block_position(f.block) - ee
                f.phase = FetchPhase.CARRY
                return [TaskEvent(kind="picked", block=f.block, time=t)]
        elif f.phase is FetchPhase.CARRY:
            if np.linalg.norm(ee - f.place_point) <= cfg.place_radius:
                self.block_state[f.block] = "delivered"
                self.delivered.add(f.block)
                f.phase = FetchPhase.RETURN
                return [TaskEvent(kind="delivered", block=f.block, time=t)]
        else:
            err = np.abs(self.robot_q() - _numpy(self.robot.q_home)).max()
            if err <= cfg.home_tolerance:
                self.fetch = None
                return [TaskEvent(kind="fetch_done", block=f.block, time=t)]
        return []

    def _move_blocks(self) -> None:
        d, h, sc = self.data, self.handles, self.scene_cfg
        ee = None
        for i, state in self.block_state.items():
            if state == "robot":
                ee = self.ee_position() if ee is None else ee
                d.mocap_pos[h.block_mocap[i]] = ee + self._block_offset[i]
            elif state == "delivered":
                d.mocap_pos[h.block_mocap[i]] = sc.delivery_position(i)
            elif state == "human":
                carry = self.human.carrying
                if carry is not None and carry[0] == i:
                    hand = self.human.joint_positions(d.time)[carry[1]]
                    d.mocap_pos[h.block_mocap[i]] = hand - np.array([0.0, 0.0, 0.02])
            elif state == "taken":
                d.mocap_pos[h.block_mocap[i]] = sc.stash_position(i)


def _numpy(x: object) -> np.ndarray:
    """A float64 numpy copy of a tensor or array."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()  # type: ignore[union-attr]
    return np.asarray(x, dtype=np.float64)


def _like_q(robot: RobotLike, q: np.ndarray) -> object:
    """``q`` as a tensor on the robot's device and dtype (for its kinematics)."""
    import torch

    ref = robot.q_home
    if isinstance(ref, torch.Tensor):
        return torch.as_tensor(q, dtype=ref.dtype, device=ref.device)
    return q
