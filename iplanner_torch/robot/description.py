"""The single source of truth of our robot models, and the URDF / MJCF writers built from it.

Two arms of the paper's experiments (sec. 7) are described here from public kinematic facts:
the KUKA LBR iiwa 14 R820 and the Fetch arm. Each description lists links (mass, primitive
collision geometry) and joints (origin, axis, position / velocity / effort limits, position
servo gains). :func:`urdf_string` and :func:`mjcf_string` write the same numbers into both
formats, so the two files cannot drift apart; ``python -m iplanner_torch.robot.description``
regenerates the committed files in ``assets/``.

The Fetch torso lift joint is written as a *fixed* joint whose height is a parameter
(``torso_height`` in [0, 0.38615] m): for the planner the arm has 7 joints. The committed Fetch
files use :data:`FETCH_DEFAULT_TORSO_HEIGHT`; for another height use ``mjcf_string(
fetch_description(torso_height=h))`` (or :meth:`RobotModel.mjcf_xml`).

MJCF conventions: ``<compiler angle="radian"/>``; body names equal URDF link names and joint
names equal URDF joint names; the top body is the robot's base link (``iiwa_base`` or
``fetch_base``) at the origin, with no floor or light, ready to be attached into a scene at a
base pose; every body has ``gravcomp="1"`` (gravity compensated, as the arms' controllers do);
contacts excluded between bodies one or two joints apart (and the pairs in
``contact_excludes``); one ``<position>`` actuator per joint, named like the joint, with
``forcerange`` equal to the joint's effort limit; a site ``ee_site`` at the tool point. MuJoCo
carries no velocity limits: the planner enforces :attr:`JointSpec.velocity` itself.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from iplanner_torch.checks import finite
from iplanner_torch.errors import ConfigError
from iplanner_torch.robot.geometry import Box, Capsule, Cylinder, Geometry, Vec3

ASSETS_DIR = Path(__file__).resolve().parent / "assets"


FETCH_TORSO_RANGE: tuple[float, float] = (0.0, 0.38615)
# Torso lift putting the Fetch shoulder about 0.3 m above a 0.75 m table.
FETCH_DEFAULT_TORSO_HEIGHT = 0.26

JointType = Literal["revolute", "continuous", "prismatic", "fixed"]


@dataclass(frozen=True, kw_only=True)
class LinkSpec:
    """One rigid link: mass and primitive collision geometry in the link frame."""

    name: str  # link name (URDF link, MJCF body)
    mass: float  # [kg]; 0 for a massless frame (tool point)
    geometry: tuple[Geometry, ...] = ()  # collision primitives in the link frame
    rgba: tuple[float, float, float, float] = (0.9, 0.45, 0.1, 1.0)  # display colour

    def __post_init__(self) -> None:
        if self.mass < 0:
            raise ConfigError(f"expected LinkSpec.mass >= 0 for {self.name}, got {self.mass}")


@dataclass(frozen=True, kw_only=True)
class JointSpec:
    """One joint: the child link's frame relative to the parent's, plus limits and gains."""

    name: str  # joint name (URDF and MJCF)
    type: JointType  # revolute (limited), continuous (unlimited), prismatic or fixed
    parent: str  # parent link name
    child: str  # child link name
    xyz: Vec3  # origin translation in the parent frame [m]
    rpy: Vec3 = (0.0, 0.0, 0.0)  # origin roll, pitch, yaw (fixed axes x, y, z) [rad]
    axis: Vec3 = (0.0, 0.0, 1.0)  # joint axis in the child frame (unit vector)
    lower: float = -math.inf  # position lower limit [rad or m]; -inf when unlimited
    upper: float = math.inf  # position upper limit [rad or m]; +inf when unlimited
    velocity: float = 0.0  # speed limit [rad/s or m/s]; 0 for fixed joints
    effort: float = 0.0  # torque / force limit [N m or N]; 0 for fixed joints
    kp: float = 0.0  # position servo stiffness of the MJCF actuator [N m/rad]
    kv: float = 0.0  # position servo damping of the MJCF actuator [N m s/rad]
    damping: float = 0.0  # viscous joint damping in the MJCF [N m s/rad]
    armature: float = 0.0  # reflected rotor inertia in the MJCF [kg m^2]

    def __post_init__(self) -> None:
        if self.type not in ("revolute", "continuous", "prismatic", "fixed"):
            raise ConfigError(f"unknown joint type {self.type!r} for {self.name}")
        norm = math.sqrt(sum(a * a for a in self.axis))
        if abs(norm - 1.0) > 1e-9:
            raise ConfigError(f"expected a unit axis for {self.name}, got {self.axis}")
        if self.type in ("revolute", "prismatic"):
            if not (math.isfinite(self.lower) and math.isfinite(self.upper)):
                raise ConfigError(f"expected finite limits for {self.type} joint {self.name}")
            if not self.lower < self.upper:
                raise ConfigError(f"expected lower < upper for {self.name}")
        if self.type != "fixed" and not (self.velocity > 0 and self.effort > 0):
            raise ConfigError(f"expected velocity and effort limits > 0 for {self.name}")

    @property
    def actuated(self) -> bool:
        """True for joints the planner moves (every type but ``fixed``)."""
        return self.type != "fixed"


@dataclass(frozen=True, kw_only=True)
class RobotDescription:
    """A serial robot arm: links and joints from the base link to the tool link."""

    name: str  # robot name, e.g. "kuka_iiwa14"
    links: tuple[LinkSpec, ...]  # every link, base first
    joints: tuple[JointSpec, ...]  # every joint, in chain order from the base
    base_link: str  # root link (top MJCF body)
    tool_link: str  # link whose origin is the tool point (``ee_site``)
    sphere_links: tuple[str, ...]  # links covered by bounding spheres (the moving ones)
    q_home: tuple[float, ...]  # home configuration of the actuated joints [rad]
    default_base_position: Vec3  # base origin in the table frame [m]
    default_base_yaw: float  # base rotation about the table's z axis [rad]
    torso_height: float | None = None  # Fetch torso lift [m]; None for robots without one
    # Body pairs beyond parent-child whose primitives overlap at every configuration (a
    # compact wrist): their MuJoCo contacts are excluded.
    contact_excludes: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        names = [link.name for link in self.links]
        if len(set(names)) != len(names):
            raise ConfigError(f"duplicate link names in {self.name}")
        prev = self.base_link
        for j in self.joints:
            if j.parent != prev:
                raise ConfigError(
                    f"{self.name} is not a serial chain: joint {j.name} has parent "
                    f"{j.parent}, expected {prev}"
                )
            if j.child not in names:
                raise ConfigError(f"joint {j.name} names unknown link {j.child}")
            prev = j.child
        if prev != self.tool_link:
            raise ConfigError(f"chain of {self.name} ends at {prev}, not {self.tool_link}")
        if len(self.q_home) != len(self.actuated_joints):
            raise ConfigError(
                f"expected q_home of length {len(self.actuated_joints)}, got {len(self.q_home)}"
            )
        chain = [self.base_link] + [j.child for j in self.joints]
        if list(self.sphere_links) != [n for n in chain if n in self.sphere_links]:
            raise ConfigError(f"expected sphere_links of {self.name} in chain order")
        for s in self.sphere_links:
            if not self.link(s).geometry:
                raise ConfigError(f"sphere link {s} of {self.name} has no geometry")

    @property
    def actuated_joints(self) -> tuple[JointSpec, ...]:
        """The joints the planner moves, in chain order."""
        return tuple(j for j in self.joints if j.actuated)

    def link(self, name: str) -> LinkSpec:
        """The link called ``name``."""
        for link in self.links:
            if link.name == name:
                return link
        raise ConfigError(f"unknown link {name!r} of {self.name}")


# --------------------------------------------------------------------------- the two robots


def iiwa14_description() -> RobotDescription:
    """KUKA LBR iiwa 14 R820: 7 revolute joints about local z; tool point at the flange."""
    hp = math.pi / 2
    deg = math.pi / 180
    rows = [  # xyz, rpy, range deg, velocity deg/s, effort, kp, kv
        ((0, 0, 0.1575), (0, 0, 0), 170, 85, 320, 2000, 200),
        ((0, 0, 0.2025), (hp, 0, math.pi), 120, 85, 320, 2000, 200),
        ((0, 0.2045, 0), (hp, 0, math.pi), 170, 100, 176, 1000, 100),
        ((0, 0, 0.2155), (hp, 0, 0), 120, 75, 176, 1000, 100),
        ((0, 0.1845, 0), (-hp, math.pi, 0), 170, 130, 110, 500, 50),
        ((0, 0, 0.2155), (hp, 0, 0), 120, 135, 40, 300, 30),
        ((0, 0.081, 0), (-hp, math.pi, 0), 175, 135, 40, 200, 20),
    ]
    masses = (5.76, 6.35, 3.5, 3.5, 3.5, 1.8, 1.2)
    # Capsule axes run from each link's origin to the next joint's origin.
    capsules = [
        ((0, 0, 0.03), (0, 0, 0.2025), 0.08),
        ((0, 0, 0), (0, 0.2045, 0), 0.08),
        ((0, 0, 0), (0, 0, 0.2155), 0.07),
        ((0, 0, 0), (0, 0.1845, 0), 0.07),
        ((0, 0, 0), (0, 0, 0.2155), 0.06),
        ((0, 0, 0), (0, 0.081, 0), 0.05),
        ((0, 0, 0), (0, 0, 0.01), 0.05),
    ]
    grey = (0.85, 0.85, 0.85, 1.0)
    orange = (0.95, 0.45, 0.05, 1.0)
    links = [
        LinkSpec(
            name="iiwa_base",
            mass=5.0,
            geometry=(Cylinder(a=(0, 0, 0), b=(0, 0, 0.1575), radius=0.1),),
            rgba=grey,
        )
    ]
    joints = []
    parent = "iiwa_base"
    for i, (row, m, cap) in enumerate(zip(rows, masses, capsules), start=1):
        xyz, rpy, rng, vel, eff, kp, kv = row
        child = f"iiwa_link_{i}"
        links.append(
            LinkSpec(
                name=child,
                mass=m,
                geometry=(Capsule(a=cap[0], b=cap[1], radius=cap[2]),),
                rgba=orange if i in (2, 4, 6) else grey,
            )
        )
        joints.append(
            JointSpec(
                name=f"iiwa_joint_{i}",
                type="revolute",
                parent=parent,
                child=child,
                xyz=_f3(xyz),
                rpy=_f3(rpy),
                lower=-rng * deg,
                upper=rng * deg,
                velocity=vel * deg,
                effort=float(eff),
                kp=float(kp),
                kv=float(kv),
                damping=0.5,
                armature=0.1,
            )
        )
        parent = child
    links.append(LinkSpec(name="iiwa_flange", mass=0.0))
    joints.append(
        JointSpec(
            name="iiwa_flange_joint",
            type="fixed",
            parent=parent,
            child="iiwa_flange",
            xyz=(0.0, 0.0, 0.045),
        )
    )
    return RobotDescription(
        name="kuka_iiwa14",
        links=tuple(links),
        joints=tuple(joints),
        base_link="iiwa_base",
        tool_link="iiwa_flange",
        sphere_links=tuple(f"iiwa_link_{i}" for i in range(1, 8)),
        q_home=(0.0, 0.785398, 0.0, -1.5708, 0.0, 0.0, 0.0),
        default_base_position=(0.75, 0.0, 0.0),
        default_base_yaw=math.pi,
        contact_excludes=(("iiwa_link_5", "iiwa_link_7"),),
    )


def fetch_description(torso_height: float = FETCH_DEFAULT_TORSO_HEIGHT) -> RobotDescription:
    """Fetch arm on its mobile base, torso lift fixed at ``torso_height`` [m].

    Raises:
        ConfigError: when ``torso_height`` lies outside the joint's range [0, 0.38615] m.
    """
    lo, hi = FETCH_TORSO_RANGE
    finite("torso_height", torso_height)
    if not lo <= torso_height <= hi:
        raise ConfigError(f"expected Fetch torso_height in [{lo}, {hi}] m, got {torso_height}")
    grey = (0.75, 0.75, 0.78, 1.0)
    blue = (0.15, 0.35, 0.75, 1.0)
    links = [
        LinkSpec(
            name="fetch_base",
            mass=70.0,
            geometry=(Cylinder(a=(0, 0, 0.02), b=(0, 0, 0.36), radius=0.28),),
            rgba=grey,
        ),
        LinkSpec(
            name="torso_lift_link",
            mass=10.0,
            geometry=(Box(center=(-0.02, 0.0, -0.05), half_extents=(0.11, 0.16, 0.3)),),
            rgba=grey,
        ),
    ]
    joints = [
        JointSpec(
            name="torso_lift_joint",
            type="fixed",
            parent="fetch_base",
            child="torso_lift_link",
            xyz=(-0.086875, 0.0, 0.37743 + float(torso_height)),
        )
    ]
    rows = [  # joint stem, type, xyz, axis, |lower|, upper (None: continuous)
        ("shoulder_pan", "revolute", (0.119525, 0, 0.34858), (0, 0, 1), 1.6056, 1.6056),
        ("shoulder_lift", "revolute", (0.117, 0, 0.06), (0, 1, 0), 1.221, 1.518),
        ("upperarm_roll", "continuous", (0.219, 0, 0), (1, 0, 0), None, None),
        ("elbow_flex", "revolute", (0.133, 0, 0), (0, 1, 0), 2.251, 2.251),
        ("forearm_roll", "continuous", (0.197, 0, 0), (1, 0, 0), None, None),
        ("wrist_flex", "revolute", (0.1245, 0, 0), (0, 1, 0), 2.16, 2.16),
        ("wrist_roll", "continuous", (0.1385, 0, 0), (1, 0, 0), None, None),
    ]
    velocity = (1.256, 1.454, 1.571, 1.521, 1.571, 2.268, 2.268)
    effort = (33.82, 131.76, 76.94, 66.18, 29.35, 25.7, 7.36)
    # Servo gains: stiff enough that motion at the planner's acceleration limit (6 rad/s^2)
    # stays within 0.03 rad of the command (at a quarter of these, 0.22 rad: the gripper,
    # which works a few cm above the table, struck it and its measured jerkiness was 2-7x
    # the iiwa's).
    kp = (1200.0, 2400.0, 800.0, 800.0, 400.0, 400.0, 200.0)
    kv = (120.0, 240.0, 80.0, 80.0, 40.0, 40.0, 20.0)
    masses = (2.5587, 2.6615, 2.3311, 2.1299, 1.6563, 1.725, 0.1354)
    # Capsule axes from each link's origin to the next joint's origin.
    capsules = [
        ((0, 0, 0), (0.117, 0, 0.06), 0.065),
        ((0, 0, 0), (0.219, 0, 0), 0.065),
        ((0, 0, 0), (0.133, 0, 0), 0.06),
        ((0, 0, 0), (0.197, 0, 0), 0.06),
        ((0, 0, 0), (0.1245, 0, 0), 0.055),
        ((0, 0, 0), (0.1385, 0, 0), 0.05),
        ((0, 0, 0), (0.03, 0, 0), 0.045),
    ]
    parent = "torso_lift_link"
    for i, (row, m, cap) in enumerate(zip(rows, masses, capsules)):
        stem, jtype, xyz, axis, lo_mag, hi_mag = row
        child = f"{stem}_link"
        links.append(
            LinkSpec(
                name=child,
                mass=m,
                geometry=(Capsule(a=_f3(cap[0]), b=_f3(cap[1]), radius=cap[2]),),
                rgba=blue if i % 2 == 0 else grey,
            )
        )
        joints.append(
            JointSpec(
                name=f"{stem}_joint",
                type=jtype,
                parent=parent,
                child=child,
                xyz=_f3(xyz),
                axis=_f3(axis),
                lower=-lo_mag if lo_mag is not None else -math.inf,
                upper=hi_mag if hi_mag is not None else math.inf,
                velocity=velocity[i],
                effort=effort[i],
                kp=kp[i],
                kv=kv[i],
                damping=0.5,
                armature=0.05,
            )
        )
        parent = child
    links.append(
        LinkSpec(
            name="gripper_link",
            mass=1.5175,
            geometry=(Box(center=(-0.06, 0.0, 0.0), half_extents=(0.075, 0.065, 0.03)),),
            rgba=grey,
        )
    )
    joints.append(
        JointSpec(
            name="gripper_axis",
            type="fixed",
            parent=parent,
            child="gripper_link",
            xyz=(0.16645, 0.0, 0.0),
        )
    )
    return RobotDescription(
        name="fetch",
        links=tuple(links),
        joints=tuple(joints),
        base_link="fetch_base",
        tool_link="gripper_link",
        sphere_links=tuple(link.name for link in links[2:]),
        # folded back: the gripper rests over the far block rows, out of the person's way
        # (a home over the delivery spots put it where the person reaches)
        q_home=(0.0, -1.1, 0.0, 1.3, 0.0, 2.0, 0.0),
        default_base_position=(1.0, 0.0, -0.75),
        default_base_yaw=math.pi,
        torso_height=float(torso_height),
        contact_excludes=(("wrist_flex_link", "gripper_link"),),
    )


#: Robot name -> the function that builds its description (a robot with a torso lift takes
#: ``torso_height``). A robot added here is in :data:`ROBOT_NAMES`: ``python -m
#: iplanner_torch.robot.description`` writes its URDF and MJCF, and the asset tests (FK against
#: MuJoCo's) cover it.
DESCRIPTIONS: dict[str, Callable[..., RobotDescription]] = {
    "kuka_iiwa14": iiwa14_description,
    "fetch": fetch_description,
}
#: The robots there are descriptions (and assets) of.
ROBOT_NAMES: tuple[str, ...] = tuple(DESCRIPTIONS)


def robot_description(name: str, torso_height: float | None = None) -> RobotDescription:
    """The description of robot ``name`` (one of :data:`ROBOT_NAMES`, from
    :data:`DESCRIPTIONS`).

    Args:
        name: a robot name, e.g. "kuka_iiwa14" or "fetch".
        torso_height: torso lift [m] of a robot that has one (the Fetch); None for its
            default. Must be None for a robot without.

    Raises:
        ConfigError: for an unknown name, or a torso height given for a robot without a torso.
    """
    build = DESCRIPTIONS.get(name) if isinstance(name, str) else None
    if build is None:
        raise ConfigError(f"unknown robot {name!r}; available: {', '.join(ROBOT_NAMES)}")
    if torso_height is None:
        return build()
    if not has_torso(name):
        raise ConfigError(f"{name} has no torso: expected torso_height=None")
    return build(torso_height=float(torso_height))


def has_torso(name: str) -> bool:
    """Whether robot ``name`` (of :data:`ROBOT_NAMES`) has a torso lift: its description
    function takes ``torso_height``."""
    return "torso_height" in inspect.signature(DESCRIPTIONS[name]).parameters


# --------------------------------------------------------------------------- math helpers


def _f3(v: Sequence[float]) -> Vec3:
    return (float(v[0]), float(v[1]), float(v[2]))


def rpy_to_matrix(rpy: Sequence[float]) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes) to a rotation matrix ``Rz(y) @ Ry(p) @ Rx(r)``."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrix to a unit quaternion (w, x, y, z) with w >= 0."""
    m = np.asarray(m, dtype=np.float64)
    tr = float(np.trace(m))
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = np.array(
            [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        )
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = np.array(
            [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        )
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = np.array(
            [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        )
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = np.array(
            [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
        )
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def _z_to_direction_rpy(d: np.ndarray) -> Vec3:
    """Roll-pitch-yaw of a rotation taking the z axis onto the unit vector ``d``."""
    pitch = math.atan2(math.hypot(d[0], d[1]), d[2])
    yaw = math.atan2(d[1], d[0]) if math.hypot(d[0], d[1]) > 1e-12 else 0.0
    return (0.0, pitch, yaw)


def _primary_inertia(link: LinkSpec) -> tuple[np.ndarray, np.ndarray]:
    """Centre of mass (3,) and inertia tensor (3, 3) about it, in the link frame.

    The mass is spread as a solid cylinder over the first capsule / cylinder (capsule caps
    add 2 r to the length) or as a solid box; links without geometry get a small sphere.
    """
    m = link.mass
    if not link.geometry:
        r = 0.02
        return np.zeros(3), np.eye(3) * (0.4 * m * r * r)
    g = link.geometry[0]
    if isinstance(g, Box):
        hx, hy, hz = g.half_extents
        diag = np.array([hy * hy + hz * hz, hx * hx + hz * hz, hx * hx + hy * hy]) * m / 3.0
        return np.asarray(g.center, dtype=np.float64), np.diag(diag)
    a, b = np.asarray(g.a, dtype=np.float64), np.asarray(g.b, dtype=np.float64)
    length = float(np.linalg.norm(b - a)) + (2 * g.radius if isinstance(g, Capsule) else 0.0)
    r = g.radius
    axial = 0.5 * m * r * r
    trans = m * (3 * r * r + length * length) / 12.0
    d = b - a
    rot = np.eye(3)
    if np.linalg.norm(d) > 1e-12:
        rot = rpy_to_matrix(_z_to_direction_rpy(d / np.linalg.norm(d)))
    inertia = rot @ np.diag([trans, trans, axial]) @ rot.T
    return 0.5 * (a + b), inertia


def _fmt(*vals: float) -> str:
    return " ".join(repr(float(0.0 if abs(v) < 1e-15 else v)) for v in vals)


# --------------------------------------------------------------------------- URDF writer


def urdf_string(desc: RobotDescription) -> str:
    """The URDF of ``desc``: capsules are written as a cylinder plus two end spheres."""
    out = [
        '<?xml version="1.0"?>',
        f"<!-- {desc.name}: generated by iplanner_torch.robot.description; do not edit. -->",
        f'<robot name="{desc.name}">',
    ]
    for link in desc.links:
        out.append(f'  <link name="{link.name}">')
        if link.mass > 0:
            com, inertia = _primary_inertia(link)
            out += [
                "    <inertial>",
                f'      <origin xyz="{_fmt(*com)}" rpy="0 0 0"/>',
                f'      <mass value="{link.mass!r}"/>',
                f'      <inertia ixx="{_fmt(inertia[0, 0])}" ixy="{_fmt(inertia[0, 1])}" '
                f'ixz="{_fmt(inertia[0, 2])}" iyy="{_fmt(inertia[1, 1])}" '
                f'iyz="{_fmt(inertia[1, 2])}" izz="{_fmt(inertia[2, 2])}"/>',
                "    </inertial>",
            ]
        for g in link.geometry:
            for xyz, rpy, shape in _urdf_shapes(g):
                for tag in ("visual", "collision"):
                    out += [
                        f"    <{tag}>",
                        f'      <origin xyz="{_fmt(*xyz)}" rpy="{_fmt(*rpy)}"/>',
                        f"      <geometry>{shape}</geometry>",
                        f"    </{tag}>",
                    ]
        out.append("  </link>")
    for j in desc.joints:
        out += [
            f'  <joint name="{j.name}" type="{j.type}">',
            f'    <parent link="{j.parent}"/>',
            f'    <child link="{j.child}"/>',
            f'    <origin xyz="{_fmt(*j.xyz)}" rpy="{_fmt(*j.rpy)}"/>',
        ]
        if j.actuated:
            out.append(f'    <axis xyz="{_fmt(*j.axis)}"/>')
            if j.type == "continuous":
                out.append(f'    <limit effort="{j.effort!r}" velocity="{j.velocity!r}"/>')
            else:
                out.append(
                    f'    <limit lower="{j.lower!r}" upper="{j.upper!r}" '
                    f'effort="{j.effort!r}" velocity="{j.velocity!r}"/>'
                )
            out.append(f'    <dynamics damping="{j.damping!r}"/>')
        out.append("  </joint>")
    out.append("</robot>")
    return "\n".join(out) + "\n"


def _urdf_shapes(g: Geometry) -> list[tuple[Vec3, Vec3, str]]:
    """(origin xyz, origin rpy, geometry element) triples representing one primitive."""
    if isinstance(g, Box):
        size = _fmt(*(2 * h for h in g.half_extents))
        return [(g.center, (0.0, 0.0, 0.0), f'<box size="{size}"/>')]
    a, b = np.asarray(g.a, dtype=np.float64), np.asarray(g.b, dtype=np.float64)
    length = float(np.linalg.norm(b - a))
    shapes: list[tuple[Vec3, Vec3, str]] = []
    if length > 1e-12:
        rpy = _z_to_direction_rpy((b - a) / length)
        mid = _f3(0.5 * (a + b))
        shapes.append((mid, rpy, f'<cylinder radius="{g.radius!r}" length="{length!r}"/>'))
    if isinstance(g, Capsule):
        for end in (a, b) if length > 1e-12 else (a,):
            shapes.append((_f3(end), (0.0, 0.0, 0.0), f'<sphere radius="{g.radius!r}"/>'))
    return shapes


# --------------------------------------------------------------------------- MJCF writer


def mjcf_string(desc: RobotDescription) -> str:
    """The MJCF of ``desc``: standalone, no floor or light; attach it into a scene."""
    cls = desc.name
    out = [
        f'<mujoco model="{desc.name}">',
        "  <!-- generated by iplanner_torch.robot.description; do not edit. -->",
        '  <compiler angle="radian" autolimits="true"/>',
        "  <default>",
        f'    <default class="{cls}">',
        '      <geom contype="1" conaffinity="1" condim="3" group="0"/>',
        '      <site group="3" size="0.01"/>',
        "    </default>",
        "  </default>",
        "  <worldbody>",
    ]
    by_child = {j.child: j for j in desc.joints}
    depth = 2

    def emit_body(link: LinkSpec, joint: JointSpec | None) -> None:
        pad = "  " * depth
        attrs = f'name="{link.name}"'
        if joint is None:
            attrs += f' childclass="{cls}"'
        else:
            quat = matrix_to_quat(rpy_to_matrix(joint.rpy))
            attrs += f' pos="{_fmt(*joint.xyz)}" quat="{_fmt(*quat)}"'
        out.append(f'{pad}<body {attrs} gravcomp="1">')
        inner = pad + "  "
        if link.mass > 0:
            com, inertia = _primary_inertia(link)
            full = _fmt(
                inertia[0, 0],
                inertia[1, 1],
                inertia[2, 2],
                inertia[0, 1],
                inertia[0, 2],
                inertia[1, 2],
            )
            out.append(
                f'{inner}<inertial pos="{_fmt(*com)}" mass="{link.mass!r}" fullinertia="{full}"/>'
            )
        if joint is not None and joint.actuated:
            jtype = "slide" if joint.type == "prismatic" else "hinge"
            jattrs = (
                f'name="{joint.name}" type="{jtype}" axis="{_fmt(*joint.axis)}" '
                f'damping="{joint.damping!r}" armature="{joint.armature!r}" '
                f'actuatorfrcrange="{_fmt(-joint.effort, joint.effort)}"'
            )
            if joint.type == "continuous":
                jattrs += ' limited="false"'
            else:
                jattrs += f' range="{_fmt(joint.lower, joint.upper)}"'
            out.append(f"{inner}<joint {jattrs}/>")
        rgba = _fmt(*link.rgba)
        for k, g in enumerate(link.geometry):
            gname = f'name="{link.name}_geom{k}"'
            if isinstance(g, Box):
                out.append(
                    f'{inner}<geom {gname} type="box" pos="{_fmt(*g.center)}" '
                    f'size="{_fmt(*g.half_extents)}" rgba="{rgba}"/>'
                )
            elif g.length > 1e-12:
                gtype = "capsule" if isinstance(g, Capsule) else "cylinder"
                out.append(
                    f'{inner}<geom {gname} type="{gtype}" fromto="{_fmt(*g.a, *g.b)}" '
                    f'size="{g.radius!r}" rgba="{rgba}"/>'
                )
            else:
                out.append(
                    f'{inner}<geom {gname} type="sphere" pos="{_fmt(*g.a)}" '
                    f'size="{g.radius!r}" rgba="{rgba}"/>'
                )
        if link.name == desc.tool_link:
            out.append(f'{inner}<site name="ee_site" pos="0 0 0"/>')

    # Serial chain: open one nested body per link, then close them all.
    chain = [desc.base_link] + [j.child for j in desc.joints]
    for name in chain:
        emit_body(desc.link(name), by_child.get(name))
        depth += 1
    for _ in chain:
        depth -= 1
        out.append("  " * depth + "</body>")
    out.append("  </worldbody>")
    # Overlapping primitives at each joint must not collide. MuJoCo filters parent-child
    # contacts by itself only below the first moving joint, so list every pair explicitly;
    # links two joints apart are excluded as well: our primitives are fatter than the real
    # links, and within the joint limits they touched where the real arm does not (the Fetch
    # shoulder lift and elbow flex links at elbow flex 2.1 rad), which the planner, which has
    # no self-collision model, cannot foresee.
    parent_of = {j.child: j.parent for j in desc.joints}
    pairs: list[tuple[str, str]] = []
    for j in desc.joints:
        pairs.append((j.parent, j.child))
        if j.parent in parent_of:
            pairs.append((parent_of[j.parent], j.child))
    pairs += [p for p in desc.contact_excludes if p not in pairs and p[::-1] not in pairs]
    out.append("  <contact>")
    for a, b in pairs:
        out.append(f'    <exclude body1="{a}" body2="{b}"/>')
    out.append("  </contact>")
    out.append("  <actuator>")
    for j in desc.actuated_joints:
        rng = (
            f'ctrlrange="{_fmt(j.lower, j.upper)}"'
            if j.type != "continuous"
            else 'ctrllimited="false"'
        )
        out.append(
            f'    <position name="{j.name}" joint="{j.name}" kp="{j.kp!r}" kv="{j.kv!r}" '
            f'{rng} forcerange="{_fmt(-j.effort, j.effort)}"/>'
        )
    out.append("  </actuator>")
    out.append("</mujoco>")
    return "\n".join(out) + "\n"


def asset_paths(name: str) -> tuple[Path, Path]:
    """(URDF path, MJCF path) of the committed files of robot ``name``."""
    if name not in ROBOT_NAMES:
        raise ConfigError(f"unknown robot {name!r}; available: {', '.join(ROBOT_NAMES)}")
    return ASSETS_DIR / f"{name}.urdf", ASSETS_DIR / f"{name}.xml"


def write_assets(directory: Path | None = None) -> list[Path]:
    """Write the URDF and MJCF of every robot (default descriptions) into ``directory``."""
    directory = ASSETS_DIR if directory is None else Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name in ROBOT_NAMES:
        desc = robot_description(name)
        for suffix, text in ((".urdf", urdf_string(desc)), (".xml", mjcf_string(desc))):
            path = directory / f"{name}{suffix}"
            path.write_text(text)
            written.append(path)
    return written


if __name__ == "__main__":
    for p in write_assets():
        print(p)
