"""JSON schemas of every channel of an episode log.

``/scene`` and ``/tf`` follow Foxglove's ``foxglove.SceneUpdate`` and ``foxglove.FrameTransform``
JSON schemas (field names, nesting and required fields as Foxglove publishes them; our own copy,
without the optional lineage fields), so Foxglove replays an episode in its 3D panel. The other
channels use small schemas of our own, named ``iplanner.*``.

Every channel's schema is one that Foxglove's JSON-schema loader takes (objects with
``properties``; arrays of numbers, strings or objects; enums as a ``oneOf`` of numeric consts),
so Foxglove shows and plots every channel (e.g. ``/robot/joint_state.position[0]``,
``/human/joints_tracked.positions[:]{joint=="right_hand"}.x``, ``/planner/bound.max_bound``):

- numeric fields hold finite numbers only (the writer refuses others, as JSON has no NaN);
- an array of more than one axis is written flat in row-major order (its shape follows from
  the names and sizes in the same message: ``mean`` of a forecast is (A, n_f, K, 3));
- human joints are objects ``{joint, x, y, z}``, and a joint not tracked in a frame (NaN) is
  left out of that message (read back as NaN).

Logs of writers before this form (nested arrays, NaN written as ``null`` and infinities as
``"inf"`` / ``"-inf"``, every human joint written) read back alike
(:mod:`iplanner_torch.recording.reader`).
"""

from __future__ import annotations

from typing import Any

#: Foxglove's frame for everything we log: the table frame of :mod:`iplanner_torch.data.skeleton`.
WORLD_FRAME = "world"

# ---------------------------------------------------------------------------------------------
# Building blocks


def _number(description: str = "") -> dict[str, Any]:
    return {"type": "number", "description": description} if description else {"type": "number"}


def _xyz(title: str, description: str) -> dict[str, Any]:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": {k: _number(f"{k} coordinate") for k in "xyz"},
        "required": ["x", "y", "z"],
    }


def vector3(description: str = "Vector in 3D space") -> dict[str, Any]:
    """Schema of ``foxglove.Vector3``."""
    return _xyz("foxglove.Vector3", description)


def point3(description: str = "A point in 3D space") -> dict[str, Any]:
    """Schema of ``foxglove.Point3``."""
    return _xyz("foxglove.Point3", description)


def quaternion(description: str = "Quaternion denoting orientation in 3D space") -> dict:
    """Schema of ``foxglove.Quaternion`` (x, y, z, w)."""
    return {
        "title": "foxglove.Quaternion",
        "description": description,
        "type": "object",
        "properties": {k: _number(f"{k} value") for k in "xyzw"},
        "required": ["x", "y", "z", "w"],
    }


def pose(description: str = "Position and orientation") -> dict[str, Any]:
    """Schema of ``foxglove.Pose``."""
    return {
        "title": "foxglove.Pose",
        "description": description,
        "type": "object",
        "properties": {"position": vector3(), "orientation": quaternion()},
        "required": ["position", "orientation"],
    }


def color(description: str = "A color in RGBA format") -> dict[str, Any]:
    """Schema of ``foxglove.Color`` (components in [0, 1])."""
    return {
        "title": "foxglove.Color",
        "description": description,
        "type": "object",
        "properties": {
            k: {"type": "number", "minimum": 0, "maximum": 1, "description": f"{k} in [0, 1]"}
            for k in "rgba"
        },
        "required": ["r", "g", "b", "a"],
    }


def time_schema(description: str = "Timestamp") -> dict[str, Any]:
    """Schema of Foxglove's ``time`` (sec, nsec)."""
    return {
        "type": "object",
        "title": "time",
        "description": description,
        "properties": {
            "sec": {"type": "integer", "minimum": 0},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
        },
        "required": ["sec", "nsec"],
    }


def duration_schema(description: str = "Duration") -> dict[str, Any]:
    """Schema of Foxglove's ``duration`` (sec, nsec)."""
    return {
        "type": "object",
        "title": "duration",
        "description": description,
        "properties": {
            "sec": {"type": "integer"},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
        },
        "required": ["sec", "nsec"],
    }


def _array(items: dict[str, Any], description: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {"type": "array", "items": items}
    if description:
        out["description"] = description
    return out


def _object(
    title: str, description: str, properties: dict[str, Any], required: list[str] | None = None
) -> dict[str, Any]:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": list(properties) if required is None else required,
    }


#: One numeric item of a logged array: a finite number (JSON has no NaN or infinity).
NUMBER: dict[str, Any] = {"type": "number"}


def flat_array(description: str) -> dict[str, Any]:
    """Schema of a (flattened, row-major) array of finite numbers."""
    return _array(dict(NUMBER), description)


# ---------------------------------------------------------------------------------------------
# Foxglove scene primitives


def _primitive(title: str, description: str, fields: dict[str, Any]) -> dict[str, Any]:
    return _object(title, description, {"pose": pose(), **fields})


SPHERE_PRIMITIVE = _primitive(
    "foxglove.SpherePrimitive",
    "A primitive representing a sphere or ellipsoid",
    {"size": vector3("Size (diameter) of the sphere along each axis"), "color": color()},
)
CUBE_PRIMITIVE = _primitive(
    "foxglove.CubePrimitive",
    "A primitive representing a cube or rectangular prism",
    {"size": vector3("Size of the cube along each axis"), "color": color()},
)
ARROW_PRIMITIVE = _primitive(
    "foxglove.ArrowPrimitive",
    "A primitive representing an arrow",
    {
        "shaft_length": _number("Length of the arrow shaft"),
        "shaft_diameter": _number("Diameter of the arrow shaft"),
        "head_length": _number("Length of the arrow head"),
        "head_diameter": _number("Diameter of the arrow head"),
        "color": color(),
    },
)
CYLINDER_PRIMITIVE = _primitive(
    "foxglove.CylinderPrimitive",
    "A primitive representing a cylinder, elliptic cylinder, or truncated cone",
    {
        "size": vector3("Size of the cylinder's bounding box"),
        "bottom_scale": _number("0-1, ratio of the bottom diameter to size.x, size.y"),
        "top_scale": _number("0-1, ratio of the top diameter to size.x, size.y"),
        "color": color(),
    },
)
LINE_PRIMITIVE = _primitive(
    "foxglove.LinePrimitive",
    "A primitive representing a series of points connected by lines",
    {
        "type": {
            "title": "foxglove.LineType",
            "description": "0: LINE_STRIP, 1: LINE_LOOP, 2: LINE_LIST",
            # the published schema's form: Foxglove's JSON-schema loader reads an enum only
            # as a oneOf of numeric consts (a bare "enum" made it drop the whole channel)
            "oneOf": [
                {"title": "LINE_STRIP", "const": 0},
                {"title": "LINE_LOOP", "const": 1},
                {"title": "LINE_LIST", "const": 2},
            ],
        },
        "thickness": _number("Line thickness"),
        "scale_invariant": {"type": "boolean"},
        "points": _array(point3()),
        "color": color(),
        "colors": _array(color()),
        "indices": _array({"type": "integer", "minimum": 0}),
    },
)
TRIANGLE_LIST_PRIMITIVE = _primitive(
    "foxglove.TriangleListPrimitive",
    "A primitive representing a set of triangles",
    {
        "points": _array(point3()),
        "color": color(),
        "colors": _array(color()),
        "indices": _array({"type": "integer", "minimum": 0}),
    },
)
TEXT_PRIMITIVE = _primitive(
    "foxglove.TextPrimitive",
    "A primitive representing a text label",
    {
        "billboard": {"type": "boolean"},
        "font_size": _number("Font size"),
        "scale_invariant": {"type": "boolean"},
        "color": color(),
        "text": {"type": "string"},
    },
)
MODEL_PRIMITIVE = _primitive(
    "foxglove.ModelPrimitive",
    "A primitive representing a 3D model file",
    {
        "scale": vector3("Scale factor to apply to the model along each axis"),
        "color": color(),
        "override_color": {"type": "boolean"},
        "url": {"type": "string"},
        "media_type": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
)

SCENE_ENTITY = _object(
    "foxglove.SceneEntity",
    "A visual element in a 3D scene",
    {
        "timestamp": time_schema("Timestamp of the entity"),
        "frame_id": {"type": "string", "description": "Frame of reference"},
        "id": {"type": "string", "description": "Identifier of the entity"},
        "lifetime": duration_schema("Time after which the entity is removed; zero: never"),
        "frame_locked": {"type": "boolean"},
        "metadata": _array(
            _object(
                "foxglove.KeyValuePair",
                "A key with its associated value",
                {"key": {"type": "string"}, "value": {"type": "string"}},
            )
        ),
        "arrows": _array(ARROW_PRIMITIVE),
        "cubes": _array(CUBE_PRIMITIVE),
        "spheres": _array(SPHERE_PRIMITIVE),
        "cylinders": _array(CYLINDER_PRIMITIVE),
        "lines": _array(LINE_PRIMITIVE),
        "triangles": _array(TRIANGLE_LIST_PRIMITIVE),
        "texts": _array(TEXT_PRIMITIVE),
        "models": _array(MODEL_PRIMITIVE),
    },
)

SCENE_ENTITY_DELETION = _object(
    "foxglove.SceneEntityDeletion",
    "Command to remove previously published entities",
    {
        "timestamp": time_schema("Only matching entities earlier than this are deleted"),
        "type": {
            "title": "foxglove.SceneEntityDeletionType",
            "description": "0: MATCHING_ID, 1: ALL",
            "oneOf": [{"title": "MATCHING_ID", "const": 0}, {"title": "ALL", "const": 1}],
        },
        "id": {"type": "string"},
    },
)

#: ``foxglove.SceneUpdate``: the ``/scene`` channel.
SCENE_UPDATE = _object(
    "foxglove.SceneUpdate",
    "An update to the entities displayed in a 3D scene",
    {"deletions": _array(SCENE_ENTITY_DELETION), "entities": _array(SCENE_ENTITY)},
)

#: ``foxglove.FrameTransform``: the ``/tf`` channel.
FRAME_TRANSFORM = _object(
    "foxglove.FrameTransform",
    "A transform between two reference frames in 3D space",
    {
        "timestamp": time_schema("Timestamp of transform"),
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": vector3("Translation component of the transform"),
        "rotation": quaternion("Rotation component of the transform"),
    },
)

# ---------------------------------------------------------------------------------------------
# Our own channels

_STAMP = {"timestamp": time_schema("Simulation time"), "t": _number("Simulation time [s]")}
_NAMES = _array({"type": "string"})

ROBOT_JOINT_STATE = _object(
    "iplanner.RobotJointState",
    "Robot joint positions and velocities",
    {
        **_STAMP,
        "joint_names": _NAMES,
        "position": flat_array("(J,) joint positions [rad]"),
        "velocity": flat_array("(J,) joint velocities [rad/s]"),
    },
)

JOINT_POSITION = _object(
    "iplanner.JointPosition",
    "A joint's position [m], world frame",
    {"joint": {"type": "string"}, **{k: _number(f"{k} [m]") for k in "xyz"}},
)

HUMAN_JOINTS = _object(
    "iplanner.HumanJoints",
    "Human joint positions; a joint not tracked in this frame is left out of positions",
    {
        **_STAMP,
        "joint_names": _array({"type": "string"}, "The K joints of the channel, in order"),
        "positions": _array(JOINT_POSITION, "The joints of joint_names that have a position"),
    },
)

FORECAST = _object(
    "iplanner.Forecast",
    "Mixture over actions of Gaussian future joint positions",
    {
        **_STAMP,
        "dt": _number("Seconds between predicted frames"),
        "action_names": _NAMES,
        "joint_names": _NAMES,
        "weights": flat_array("(A,) action probabilities, in the order of action_names"),
        "mean": flat_array("(A, n_f, K, 3) predicted joint positions [m], row-major"),
        "var": flat_array("(A, n_f, K, 3) per-coordinate variances [m^2], row-major"),
    },
)

COLLISION_BOUND = _object(
    "iplanner.CollisionBound",
    "Upper bound of the human collision probability along the planned trajectory",
    {
        **_STAMP,
        "times": flat_array("(W,) waypoint times [s]"),
        "bound": flat_array("(W,) collision probability bound"),
        "confidence": _number("Confidence level; a plan is safe where bound <= 1 - confidence"),
        "max_bound": _number("Largest bound over the waypoints (absent without waypoints)"),
    },
    required=["timestamp", "t", "times", "bound", "confidence"],
)

PLAN = _object(
    "iplanner.Plan",
    "The trajectory chosen by the planner",
    {
        **_STAMP,
        "times": flat_array("(W,) waypoint times [s]"),
        "q": flat_array("(W, J) waypoint joint positions [rad], row-major"),
        "feasible": {"type": "boolean"},
        "wait_s": _number("Time the robot waits before executing [s]"),
        "solve_ms": _number("Planner wall time [ms]"),
    },
)

_ANY_JSON: dict[str, Any] = {}

TASK_EVENT = _object(
    "iplanner.TaskEvent",
    "A task-level event (action started or finished, object handed over, ...)",
    # "properties": {} (no fields named, any allowed): Foxglove's loader needs the key
    {**_STAMP, "kind": {"type": "string"}, "detail": {"type": "object", "properties": {}}},
)

EPISODE_METRICS = _object(
    "iplanner.EpisodeMetrics",
    'Metric values (NaN as "nan", infinities as "inf" / "-inf", None as null; a string '
    "that would read as one of them, or starts with ~, has a ~ in front)",
    {
        **_STAMP,
        "metrics": {
            "type": "object",
            "properties": {},
            "additionalProperties": {
                "anyOf": [
                    {"type": ["number", "null", "boolean", "string"]},
                    {"type": "array"},
                    {"type": "object"},
                ]
            },
        },
    },
)

#: Topic -> JSON schema of its messages (the schema's ``title`` is the MCAP schema name).
TOPIC_SCHEMAS: dict[str, dict[str, Any]] = {
    "/tf": FRAME_TRANSFORM,
    "/robot/joint_state": ROBOT_JOINT_STATE,
    "/human/joints_true": HUMAN_JOINTS,
    "/human/joints_tracked": HUMAN_JOINTS,
    "/prediction/forecast": FORECAST,
    "/planner/bound": COLLISION_BOUND,
    "/planner/plan": PLAN,
    "/task/events": TASK_EVENT,
    "/episode/metrics": EPISODE_METRICS,
    "/scene": SCENE_UPDATE,
}
