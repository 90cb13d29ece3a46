"""The simulated workspace of paper sec. 7, composed with ``mujoco.MjSpec``.

A seated human faces the robot across a table. Blocks wait at far positions on the robot's
side; the robot (``Fetch_i``) carries block ``i`` to its delivery spot ``i`` near the human,
who then takes it (``Take_i``).

Frame: the table frame of :mod:`iplanner_torch.data.skeleton`: x from the human towards the
robot, y to the human's left, z up, table top at z = 0.

Block ids (the paper's task orders name them): ``id = 4 row + col`` with ``col`` 0..3 running
from the human's left (+y) to the human's right (-y) and ``row`` 0 (front, nearer the human) or
1 (back, nearer the robot). Delivery spot ``i`` is exactly target ``i`` of the reaching data set
(:func:`iplanner_torch.data.reaching.reach_targets` with 8 targets: rows at x = 0.04 and
0.18 m, columns at y = 0.36, 0.12, -0.12, -0.36 m), so ``Take_i`` is the reach ``reach_i`` the
predictor was trained on.

====  ====================  =================================
name  arrangement           ids
====  ====================  =================================
1x4   one row of four       0, 1, 2, 3
2x2   two rows, middle two  1, 2, 5, 6
2x4   two rows of four      0, 1, 2, 3, 4, 5, 6, 7
====  ====================  =================================

Far position ``i`` uses the same columns, with rows on the robot's side of the table.

Model contents (names are stable and used by :class:`SceneHandles`):

* ``floor`` plane, ``table`` box, ``chair_seat`` / ``chair_back`` boxes;
* ``block_<i>``: mocap bodies with one visual box each (kinematic: resting, carried by the
  robot's tool point, or carried by the human's hand; they never push anything);
* ``delivery_<i>``: flat visual sites;
* ``robot/...``: the robot MJCF attached at its base pose (bodies gravity-compensated when
  :attr:`SceneCfg.robot_gravcomp`; contacts between the static base and its child bodies
  excluded, since MuJoCo's parent-child filter skips bodies welded to the world);
* ``human/<segment>``: one mocap body per :data:`~iplanner_torch.data.skeleton.SEGMENTS` entry
  holding a capsule (sphere for one-joint segments), posed each step from two joint positions.

Contact filtering: human geoms have ``contype = 2, conaffinity = 0`` and every colliding robot
geom gets bit 2 added to its ``conaffinity``; world geoms keep bit 1 only. Human capsules thus
touch only the robot (never the table, the chair or each other).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import mujoco
import numpy as np

from iplanner_torch import checks
from iplanner_torch.data.skeleton import JOINT_INDEX, SEGMENTS
from iplanner_torch.errors import ConfigError, DataError, ShapeError

Arrangement = Literal["1x4", "2x2", "2x4"]

#: Block ids used by each arrangement (see the module docstring for the layout).
ARRANGEMENT_IDS: dict[str, tuple[int, ...]] = {
    "1x4": (0, 1, 2, 3),
    "2x2": (1, 2, 5, 6),
    "2x4": (0, 1, 2, 3, 4, 5, 6, 7),
}
#: Prefix of every robot element in the composed model.
ROBOT_PREFIX = "robot/"
#: Prefix of the human's segment bodies and geoms.
HUMAN_PREFIX = "human/"
#: contype / conaffinity bit reserved for human-robot contacts.
HUMAN_CONTACT_BIT = 2


class RobotLike(Protocol):
    """The part of :class:`iplanner_torch.robot.model.RobotModel` that the scene needs.

    The scene is built from ``robot.mjcf_xml()`` when the robot has that method (the MJCF of
    its own description: a Fetch at a non-default torso height differs from the committed
    file), else from the file at ``robot.mjcf_path``.
    """

    name: str
    joint_names: tuple[str, ...]
    mjcf_path: Path


@dataclass(frozen=True, kw_only=True)
class SceneCfg:
    """Geometry of the table-top delivery workspace.

    Positions are metres in the table frame.
    """

    # block layout, one of "1x4", "2x2", "2x4" (ids in the module docstring)
    arrangement: Arrangement = "1x4"
    # table extent along x (towards the robot) and y [m]
    table_size: tuple[float, float] = (1.0, 1.4)
    # x of the table centre [m]
    table_center_x: float = 0.2
    # table top height above the floor [m]
    table_height: float = 0.75
    # edge length of the cubic blocks [m]
    block_size: float = 0.05
    # y spacing between block columns [m]
    column_pitch: float = 0.24
    # x of the front (row 0) and back (row 1) far block positions [m]
    block_rows_x: tuple[float, float] = (0.32, 0.44)
    # x of the front (row 0) and back (row 1) delivery spots [m]
    delivery_rows_x: tuple[float, float] = (0.04, 0.18)
    # x of the seated human's torso; the chair is placed behind it [m]
    human_seat_x: float = -0.45
    # whether the robot's bodies are gravity-compensated (joint-torque controllers do this)
    robot_gravcomp: bool = True

    def __post_init__(self) -> None:
        if self.arrangement not in ARRANGEMENT_IDS:
            raise ConfigError(
                f"expected arrangement in {sorted(ARRANGEMENT_IDS)}, got {self.arrangement!r}"
            )
        size = checks.finite_tuple("table_size", self.table_size, 2)
        if min(size) <= 0:
            raise ConfigError(f"expected positive table_size, got {self.table_size!r}")
        checks.positive("table_height", self.table_height)
        if not 0.0 < checks.finite("block_size", self.block_size) < 0.3:
            raise ConfigError(f"expected block_size in (0, 0.3) m, got {self.block_size!r}")
        if checks.finite("column_pitch", self.column_pitch) <= self.block_size:
            raise ConfigError(
                f"expected column_pitch > block_size, got {self.column_pitch} <= {self.block_size}"
            )
        for name in ("block_rows_x", "delivery_rows_x"):
            checks.finite_tuple(name, getattr(self, name), 2)
        for name in ("table_center_x", "human_seat_x"):
            checks.finite(name, getattr(self, name))
        checks.flag("robot_gravcomp", self.robot_gravcomp)

    @property
    def block_ids(self) -> tuple[int, ...]:
        """The block ids present in this arrangement, ascending."""
        return ARRANGEMENT_IDS[self.arrangement]

    def check_block_id(self, block_id: object) -> int:
        """``block_id`` as an int.

        Raises:
            ConfigError: unless it is an integer (not a bool) among :attr:`block_ids`.
        """
        if (
            isinstance(block_id, (bool, np.bool_))
            or not isinstance(block_id, numbers.Integral)
            or block_id not in self.block_ids
        ):
            raise ConfigError(
                f"expected a block id of the {self.arrangement} scene {self.block_ids}, "
                f"got {block_id!r}"
            )
        return int(block_id)

    def _grid_xy(self, block_id: int, rows_x: tuple[float, float]) -> tuple[float, float]:
        row, col = divmod(self.check_block_id(block_id), 4)
        return float(rows_x[row]), float((1.5 - col) * self.column_pitch)

    def block_position(self, block_id: int) -> np.ndarray:
        """(3,) centre of block ``block_id`` resting at its far position [m].

        Raises:
            ConfigError: when ``block_id`` is not one of :attr:`block_ids`.
        """
        x, y = self._grid_xy(block_id, self.block_rows_x)
        return np.array([x, y, 0.5 * self.block_size])

    def delivery_position(self, block_id: int) -> np.ndarray:
        """(3,) centre of block ``block_id`` resting on its delivery spot [m].

        Raises:
            ConfigError: when ``block_id`` is not one of :attr:`block_ids`.
        """
        x, y = self._grid_xy(block_id, self.delivery_rows_x)
        return np.array([x, y, 0.5 * self.block_size])

    def stash_position(self, block_id: int) -> np.ndarray:
        """(3,) where a block the human has taken is put down (beside the human) [m].

        Each block has its own spot, on the side of its delivery spot: a 2 x 2 grid per side,
        the block's row along x (row 1 farther from the human) and its column along y (the
        outer column farther out), one block size plus 2 cm apart. Blocks never collide, so
        where they lie changes nothing but the picture.

        Raises:
            ConfigError: when ``block_id`` is not one of :attr:`block_ids`.
        """
        row, col = divmod(self.check_block_id(block_id), 4)
        side = 1.0 if col < 2 else -1.0  # the side of the delivery spot (y > 0 for 0 and 1)
        outer = 1 if col in (0, 3) else 0
        pitch = self.block_size + 0.02
        return np.array(
            [
                self.human_seat_x + 0.15 + pitch * row,
                side * (0.55 + pitch * outer),
                0.5 * self.block_size,
            ]
        )


def yaw_quat(yaw: float) -> np.ndarray:
    """(4,) quaternion (w, x, y, z) of a rotation by ``yaw`` [rad] about z."""
    return np.array([math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)])


def robot_base_pose(robot: RobotLike) -> tuple[np.ndarray, float]:
    """The robot's base position (3,) [m] and yaw [rad] in the table frame.

    Read from ``robot.base_position`` / ``robot.base_yaw`` (the pose its forward kinematics
    uses), so the simulated arm and the planner's model coincide.
    """
    pos = getattr(robot, "base_position", (0.75, 0.0, 0.0))
    if hasattr(pos, "detach"):
        pos = pos.detach().cpu().numpy()
    pos = np.asarray(pos, dtype=np.float64)
    yaw = float(getattr(robot, "base_yaw", math.pi))
    return pos.reshape(3), yaw


def build_scene(cfg: SceneCfg, robot: RobotLike, *, physics_dt: float = 0.002) -> mujoco.MjModel:
    """Compose the workspace with the robot and a kinematic human, and compile it.

    Args:
        cfg: workspace geometry.
        robot: the robot; its MJCF (``robot.mjcf_xml()`` where the robot has that method,
            else the file ``robot.mjcf_path``) holds a top body, ``<name>_base`` or else the
            first body of its worldbody, and position actuators on its joints.
        physics_dt: MuJoCo timestep [s].

    Returns:
        The compiled model (names as in the module docstring).

    Raises:
        ConfigError: when ``cfg`` is not a :class:`SceneCfg`, ``physics_dt`` is not a finite
            real number > 0, or the robot MJCF has no body or lacks a joint of
            ``robot.joint_names``.
    """
    if not isinstance(cfg, SceneCfg):
        raise ConfigError(f"expected cfg a SceneCfg, got {type(cfg).__name__}")
    checks.positive("physics_dt", physics_dt)
    spec = mujoco.MjSpec()
    spec.modelname = f"iplanner_{cfg.arrangement}_{robot.name}"
    spec.option.timestep = physics_dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    world = spec.worldbody
    geom = mujoco.mjtGeom
    world.add_light(pos=[0.0, 0.0, 3.0], dir=[0.0, 0.0, -1.0], diffuse=[0.8, 0.8, 0.8])
    world.add_camera(
        name="overview", pos=[-1.6, -1.3, 1.2], xyaxes=[0.63, -0.77, 0.0, 0.3, 0.25, 0.92]
    )
    world.add_geom(
        name="floor",
        type=geom.mjGEOM_PLANE,
        size=[3.0, 3.0, 0.1],
        pos=[0.0, 0.0, -cfg.table_height],
        rgba=[0.85, 0.85, 0.85, 1.0],
    )
    thick = 0.04
    world.add_geom(
        name="table",
        type=geom.mjGEOM_BOX,
        size=[0.5 * cfg.table_size[0], 0.5 * cfg.table_size[1], 0.5 * thick],
        pos=[cfg.table_center_x, 0.0, -0.5 * thick],
        rgba=[0.6, 0.45, 0.3, 1.0],
    )
    seat_h = 0.45 - cfg.table_height
    world.add_geom(
        name="chair_seat",
        type=geom.mjGEOM_BOX,
        size=[0.22, 0.22, 0.02],
        pos=[cfg.human_seat_x - 0.05, 0.0, seat_h],
        rgba=[0.3, 0.3, 0.35, 1.0],
    )
    world.add_geom(
        name="chair_back",
        type=geom.mjGEOM_BOX,
        size=[0.02, 0.22, 0.3],
        pos=[cfg.human_seat_x - 0.27, 0.0, seat_h + 0.3],
        rgba=[0.3, 0.3, 0.35, 1.0],
    )
    half = 0.5 * cfg.block_size
    palette = np.array(
        [[0.9, 0.2, 0.2], [0.2, 0.7, 0.2], [0.2, 0.3, 0.9], [0.9, 0.8, 0.1]], dtype=float
    )
    for i in cfg.block_ids:
        rgb = palette[i % 4] * (0.65 if i >= 4 else 1.0)
        body = world.add_body(name=f"block_{i}", mocap=True, pos=cfg.block_position(i))
        body.add_geom(
            name=f"block_{i}",
            type=geom.mjGEOM_BOX,
            size=[half, half, half],
            contype=0,
            conaffinity=0,
            rgba=[*rgb, 1.0],
        )
        spot = cfg.delivery_position(i)
        world.add_site(
            name=f"delivery_{i}",
            type=geom.mjGEOM_CYLINDER,
            size=[1.2 * half, 0.001, 0.0],
            pos=[spot[0], spot[1], 0.001],
            rgba=[*rgb, 0.35],
        )
    for seg in SEGMENTS:
        body = world.add_body(name=f"{HUMAN_PREFIX}{seg.name}", mocap=True, pos=[-0.5, 0.0, 0.3])
        one_joint = seg.joint_a == seg.joint_b
        body.add_geom(
            name=f"{HUMAN_PREFIX}{seg.name}",
            type=geom.mjGEOM_SPHERE if one_joint else geom.mjGEOM_CAPSULE,
            size=[seg.radius, 0.0 if one_joint else 0.05, 0.0],
            contype=HUMAN_CONTACT_BIT,
            conaffinity=0,
            rgba=[0.95, 0.75, 0.6, 0.9],
        )
    _attach_robot(spec, cfg, robot)
    return spec.compile()


def _robot_spec(robot: RobotLike) -> tuple[mujoco.MjSpec, str]:
    """The robot's own MJCF as a spec, and where it came from (for messages).

    ``robot.mjcf_xml()`` is preferred over the committed file ``robot.mjcf_path``: the file
    holds the default description only (the Fetch at its default torso height), while the
    method writes this model's description, the one its kinematics use.
    """
    mjcf_xml = getattr(robot, "mjcf_xml", None)
    if callable(mjcf_xml):
        return mujoco.MjSpec.from_string(mjcf_xml()), f"the MJCF of {robot!r}"
    return mujoco.MjSpec.from_file(str(robot.mjcf_path)), str(robot.mjcf_path)


def _attach_robot(spec: mujoco.MjSpec, cfg: SceneCfg, robot: RobotLike) -> None:
    child, source = _robot_spec(robot)
    base = child.body(f"{robot.name}_base") or child.worldbody.first_body()
    if base is None:
        raise ConfigError(f"expected a top body in {source}, found none")
    base_name = base.name
    pos, yaw = robot_base_pose(robot)
    frame = spec.worldbody.add_frame(pos=pos, quat=yaw_quat(yaw))
    frame.attach_body(base, ROBOT_PREFIX, "")
    joint_names = {j.name for j in spec.joints}
    missing = [n for n in robot.joint_names if ROBOT_PREFIX + n not in joint_names]
    if missing:
        raise ConfigError(f"expected joints {missing} in {source}, found none")
    base_full = ROBOT_PREFIX + base_name
    for body in spec.bodies:
        if cfg.robot_gravcomp and body.name.startswith(ROBOT_PREFIX):
            body.gravcomp = 1.0
        parent = body.parent
        if parent is not None and parent.name == base_full:
            # the base is welded to the world, where MuJoCo's parent-child filter does not act
            spec.add_exclude(bodyname1=base_full, bodyname2=body.name)
    for g in spec.geoms:
        if g.name.startswith(HUMAN_PREFIX) or not _in_robot(g):
            continue
        if g.contype or g.conaffinity:
            g.conaffinity = int(g.conaffinity) | HUMAN_CONTACT_BIT


def _in_robot(g: mujoco.MjsGeom) -> bool:
    parent = g.parent
    return parent is not None and parent.name.startswith(ROBOT_PREFIX)


@dataclass(kw_only=True)
class SceneHandles:
    """Ids and addresses in a compiled scene, resolved once by name.

    Attributes:
        qpos_adr: (J,) qpos addresses of the robot joints, in ``robot.joint_names`` order.
        dof_adr: (J,) dof addresses of the same joints.
        actuator_ids: (J,) the position actuator driving each joint.
        ee_site: id of the tool-point site, or -1 when the MJCF has none.
        robot_geom: (ngeom,) bool, geoms of the robot.
        human_geom: (ngeom,) bool, geoms of the human.
        human_mocap: (S_seg,) mocap ids of the human segment bodies, in ``SEGMENTS`` order.
        human_geom_ids: (S_seg,) geom ids of the human segments.
        human_joint_pairs: (S_seg, 2) joint indices (K axis) at the two ends of each segment.
        block_mocap: block id -> mocap id.
        delivery_site: block id -> site id.
    """

    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    actuator_ids: np.ndarray
    ee_site: int
    robot_geom: np.ndarray
    human_geom: np.ndarray
    human_mocap: np.ndarray
    human_geom_ids: np.ndarray
    human_joint_pairs: np.ndarray
    block_mocap: dict[int, int] = field(default_factory=dict)
    delivery_site: dict[int, int] = field(default_factory=dict)

    @classmethod
    def resolve(cls, model: mujoco.MjModel, cfg: SceneCfg, robot: RobotLike) -> SceneHandles:
        """Look up every id the environment needs.

        Raises:
            ConfigError: when a robot joint has no position actuator.
        """
        obj = mujoco.mjtObj
        jids = [
            mujoco.mj_name2id(model, obj.mjOBJ_JOINT, ROBOT_PREFIX + n) for n in robot.joint_names
        ]
        act = np.full(len(jids), -1, dtype=np.int64)
        for a in range(model.nu):
            if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
                jid = int(model.actuator_trnid[a, 0])
                if jid in jids:
                    act[jids.index(jid)] = a
        if (act < 0).any():
            missing = [robot.joint_names[i] for i in np.flatnonzero(act < 0)]
            raise ConfigError(f"expected a position actuator on joints {missing}, found none")
        base = model.body_rootid[model.jnt_bodyid[jids[0]]]
        robot_geom = model.body_rootid[model.geom_bodyid] == base
        human_ids = np.array(
            [mujoco.mj_name2id(model, obj.mjOBJ_GEOM, HUMAN_PREFIX + s.name) for s in SEGMENTS]
        )
        human_geom = np.zeros(model.ngeom, dtype=bool)
        human_geom[human_ids] = True
        mocap = np.array(
            [
                model.body_mocapid[mujoco.mj_name2id(model, obj.mjOBJ_BODY, HUMAN_PREFIX + s.name)]
                for s in SEGMENTS
            ]
        )
        pairs = np.array([[JOINT_INDEX[s.joint_a], JOINT_INDEX[s.joint_b]] for s in SEGMENTS])
        blocks = {
            i: int(model.body_mocapid[mujoco.mj_name2id(model, obj.mjOBJ_BODY, f"block_{i}")])
            for i in cfg.block_ids
        }
        sites = {
            i: mujoco.mj_name2id(model, obj.mjOBJ_SITE, f"delivery_{i}") for i in cfg.block_ids
        }
        return cls(
            qpos_adr=model.jnt_qposadr[jids].copy(),
            dof_adr=model.jnt_dofadr[jids].copy(),
            actuator_ids=act,
            ee_site=mujoco.mj_name2id(model, obj.mjOBJ_SITE, ROBOT_PREFIX + "ee_site"),
            robot_geom=robot_geom,
            human_geom=human_geom,
            human_mocap=mocap,
            human_geom_ids=human_ids,
            human_joint_pairs=pairs,
            block_mocap=blocks,
            delivery_site=sites,
        )


def pose_human(
    model: mujoco.MjModel, data: mujoco.MjData, handles: SceneHandles, joints: np.ndarray
) -> None:
    """Place the human's capsules on the joint positions (kinematic, no physics).

    Each capsule runs exactly from its segment's first joint to its second one: the body sits
    at the midpoint, its z axis along the segment and the capsule's half-length is set to half
    the joint distance (one-joint segments are spheres on their joint).

    Args:
        model: the compiled scene (its ``geom_size``, ``geom_rbound`` and ``geom_aabb`` are
            updated).
        data: the simulation state (its ``mocap_pos`` / ``mocap_quat`` are set).
        handles: ids from :meth:`SceneHandles.resolve`.
        joints: (K, 3) true joint positions [m], table frame (K covers every joint of
            :data:`~iplanner_torch.data.skeleton.SEGMENTS`).

    Raises:
        ShapeError: when ``joints`` is not (K, 3) real numbers with K large enough.
        DataError: when ``joints`` holds NaN or infinity (nothing is changed then).
    """
    joints = checks.real_array("joints", joints)
    try:  # too few joints fail the indexing: no per-step search for the largest index
        if joints.ndim != 2 or joints.shape[1] != 3:
            raise IndexError
        a = joints[handles.human_joint_pairs[:, 0]]  # (S_seg, 3)
        b = joints[handles.human_joint_pairs[:, 1]]  # (S_seg, 3)
    except IndexError:
        need = int(handles.human_joint_pairs.max()) + 1
        raise ShapeError(f"expected joints (K, 3) with K >= {need}, got {joints.shape}") from None
    if not np.isfinite(joints).all():
        raise DataError("expected finite joints, got NaN or inf joint positions")
    mid = 0.5 * (a + b)
    vec = b - a
    length = np.linalg.norm(vec, axis=1)
    data.mocap_pos[handles.human_mocap] = mid
    quat = np.empty(4)
    for s, (m_id, g_id) in enumerate(zip(handles.human_mocap, handles.human_geom_ids)):
        if length[s] > 1e-9:
            mujoco.mju_quatZ2Vec(quat, vec[s] / length[s])
            data.mocap_quat[m_id] = quat
            if model.geom_type[g_id] == mujoco.mjtGeom.mjGEOM_CAPSULE:
                half = 0.5 * length[s]
                model.geom_size[g_id, 1] = half
                model.geom_rbound[g_id] = half + model.geom_size[g_id, 0]
                # the broad phase tests the geom's bounding box (centre, half-sizes in the
                # geom frame): a stale one would miss contacts with the capsule's far part
                model.geom_aabb[g_id, 5] = half + model.geom_size[g_id, 0]
