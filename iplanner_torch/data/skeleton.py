"""The tracked upper-body skeleton (paper sec. 4.1: 10 OpenNI upper-body joints).

Positions are metres in the table frame: x points from the human towards the robot across
the table, y to the human's left, z up; the table top is the plane z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

#: The 10 upper-body joints, in the order of the K axis of every positions tensor.
JOINT_NAMES: tuple[str, ...] = (
    "head",
    "neck",
    "torso",
    "waist",
    "left_shoulder",
    "left_elbow",
    "left_hand",
    "right_shoulder",
    "right_elbow",
    "right_hand",
)
K_UPPER_BODY = len(JOINT_NAMES)
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}


@dataclass(frozen=True, kw_only=True)
class Segment:
    """A body segment between two joints that carries collision spheres.

    Attributes:
        name: segment name (``"left_forearm"``).
        joint_a: first joint's name.
        joint_b: second joint's name (equal to ``joint_a`` for a single sphere on a joint).
        radius: sphere radius for a body of the reference size [m]; the simulated person's
            capsule around the segment has this radius.
        n_spheres: spheres spread evenly from ``joint_a`` to ``joint_b``.
        length: ``joint_a`` to ``joint_b`` distance of the reference body [m] (0 for a single
            joint); the covering sphere layout
            (:meth:`~iplanner_torch.collision.human_spheres.HumanSphereMap.from_segments`) is
            designed for it.
    """

    name: str
    joint_a: str
    joint_b: str
    radius: float
    n_spheres: int
    length: float = 0.0


#: Segments of the reference body (height about 1.75 m); radii scale with body size.
SEGMENTS: tuple[Segment, ...] = (
    Segment(name="head", joint_a="head", joint_b="head", radius=0.11, n_spheres=1),
    Segment(name="neck", joint_a="neck", joint_b="head", radius=0.06, n_spheres=1, length=0.20),
    Segment(
        name="upper_torso",
        joint_a="neck",
        joint_b="torso",
        radius=0.15,
        n_spheres=2,
        length=0.30,
    ),
    Segment(
        name="lower_torso",
        joint_a="torso",
        joint_b="waist",
        radius=0.14,
        n_spheres=2,
        length=0.25,
    ),
    Segment(
        name="left_shoulder",
        joint_a="neck",
        joint_b="left_shoulder",
        radius=0.07,
        n_spheres=1,
        length=0.18,
    ),
    Segment(
        name="right_shoulder",
        joint_a="neck",
        joint_b="right_shoulder",
        radius=0.07,
        n_spheres=1,
        length=0.18,
    ),
    Segment(
        name="left_upper_arm",
        joint_a="left_shoulder",
        joint_b="left_elbow",
        radius=0.055,
        n_spheres=3,
        length=0.30,
    ),
    Segment(
        name="right_upper_arm",
        joint_a="right_shoulder",
        joint_b="right_elbow",
        radius=0.055,
        n_spheres=3,
        length=0.30,
    ),
    Segment(
        name="left_forearm",
        joint_a="left_elbow",
        joint_b="left_hand",
        radius=0.045,
        n_spheres=3,
        length=0.28,
    ),
    Segment(
        name="right_forearm",
        joint_a="right_elbow",
        joint_b="right_hand",
        radius=0.045,
        n_spheres=3,
        length=0.28,
    ),
    Segment(name="left_hand", joint_a="left_hand", joint_b="left_hand", radius=0.06, n_spheres=1),
    Segment(
        name="right_hand", joint_a="right_hand", joint_b="right_hand", radius=0.06, n_spheres=1
    ),
)

#: Bones whose length is constant within a demonstration (parent, child).
BONES: tuple[tuple[str, str], ...] = (
    ("neck", "head"),
    ("neck", "torso"),
    ("torso", "waist"),
    ("neck", "left_shoulder"),
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_hand"),
    ("neck", "right_shoulder"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_hand"),
)
