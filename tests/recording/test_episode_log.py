"""EpisodeWriter / read_episode: round trip, JSON schemas, Foxglove shape, truncation recovery."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import torch
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from iplanner_torch.errors import ConfigError, DataError, DataWarning, ShapeError
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.recording import EpisodeWriter, SceneEllipsoid, ellipsoid_pose, read_episode
from iplanner_torch.recording.schemas import TOPIC_SCHEMAS

J, K, A, NF, W = 7, 10, 4, 5, 6
JOINTS = [f"j{i}" for i in range(J)]
HUMAN = [f"k{i}" for i in range(K)]
ACTIONS = [f"Take_{i}" for i in range(A)]
STEPS = 40


def _make_data(seed: int = 0) -> dict:
    g = np.random.default_rng(seed)
    d: dict = {"t": np.round(np.arange(STEPS) * 1 / 15, 6)}
    d["q"] = g.normal(size=(STEPS, J)).astype(np.float32)
    d["qd"] = g.normal(size=(STEPS, J))
    d["true"] = g.normal(size=(STEPS, K, 3))
    tracked = d["true"] + 0.01 * g.normal(size=(STEPS, K, 3))
    tracked[g.random(size=(STEPS, K)) < 0.2] = np.nan  # dropouts
    d["tracked"] = tracked
    w = g.random(size=(STEPS, A))
    d["weights"] = w / w.sum(1, keepdims=True)
    d["mean"] = g.normal(size=(STEPS, A, NF, K, 3))
    d["var"] = g.random(size=(STEPS, A, NF, K, 3)) * 1e-3
    d["times"] = np.arange(W) * 0.25
    d["bound"] = g.random(size=(STEPS, W)) * 0.05
    d["plan_q"] = g.normal(size=(STEPS, W, J))
    d["robot_spheres"] = np.concatenate(
        [g.normal(size=(STEPS, 5, 3)), g.uniform(0.05, 0.1, size=(STEPS, 5, 1))], -1
    )
    d["human_spheres"] = np.concatenate(
        [g.normal(size=(STEPS, 8, 3)), g.uniform(0.05, 0.1, size=(STEPS, 8, 1))], -1
    )
    b = g.normal(size=(3, 3))
    d["cov"] = b @ b.T * 1e-3 + np.eye(3) * 1e-4
    return d


def _write(path: Path, d: dict, chunk_size: int = 256 * 1024, steps: int = STEPS) -> None:
    meta = {"scenario": "arrangements_1", "planner": "iplanner_ni", "seed": 3, "noise": 0.01}
    with EpisodeWriter(path, metadata=meta, chunk_size=chunk_size) as log:
        for i in range(steps):
            t = float(d["t"][i])
            log.robot_state(t, torch.from_numpy(d["q"][i]), d["qd"][i], JOINTS)
            log.human_joints(t, d["true"][i], d["tracked"][i], HUMAN)
            log.forecast(t, d["weights"][i], d["mean"][i], d["var"][i], ACTIONS, 1 / 15, HUMAN)
            log.collision_bound(t, d["times"], d["bound"][i], 0.95)
            log.plan(t, d["times"], d["plan_q"][i], i % 3 != 0, 0.1 * i, 12.5)
            log.scene(
                t,
                d["robot_spheres"][i],
                d["human_spheres"][i],
                [
                    SceneEllipsoid(mean=np.zeros(3), cov=d["cov"]),
                    (np.ones(3), np.array([0.1, 0.2, 0.3]), (1.0, 0.0, 0.0, 0.5)),
                ],
            )
            if i == 10:
                log.task_event(t, "handover", {"object": 2, "gap": math.nan, "who": "human"})
        log.metrics(float(d["t"][-1]), {"eval/smoothness": 1.5, "eval/x": math.inf, "n": None})


@pytest.fixture(scope="module")
def data() -> dict:
    return _make_data()


@pytest.fixture(scope="module")
def log_path(tmp_path_factory: pytest.TempPathFactory, data: dict) -> Path:
    path = tmp_path_factory.mktemp("episode") / "sub" / "episode.mcap"
    _write(path, data, chunk_size=8 * 1024)
    return path


def test_round_trip_every_channel(log_path: Path, data: dict) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a complete file reads without warnings
        ep = read_episode(log_path)
    assert ep.complete
    assert ep.metadata == {
        "scenario": "arrangements_1",
        "planner": "iplanner_ni",
        "seed": 3,
        "noise": 0.01,
    }
    t, q = ep.robot_q()
    assert q.shape == (STEPS, J) and q.dtype == torch.float64
    np.testing.assert_array_equal(t.numpy(), data["t"])
    np.testing.assert_array_equal(q.numpy(), data["q"].astype(np.float64))  # bit exact
    np.testing.assert_array_equal(ep.robot_qd()[1].numpy(), data["qd"])
    assert ep.frames["/robot/joint_state"]["joint_names"].iloc[0] == tuple(JOINTS)

    _, true = ep.human_true()
    _, tracked = ep.human_tracked()
    assert tracked.shape == (STEPS, K, 3)
    np.testing.assert_array_equal(true.numpy(), data["true"])
    np.testing.assert_array_equal(tracked.numpy(), data["tracked"])  # NaN positions equal
    assert np.isnan(tracked.numpy()).sum() == np.isnan(data["tracked"]).sum() > 0

    tf, fc = ep.forecasts(dtype=torch.float64)
    assert isinstance(fc, Forecast) and fc.action_names == tuple(ACTIONS)
    assert fc.mean.shape == (STEPS, A, NF, K, 3) and fc.joint_names == tuple(HUMAN)
    np.testing.assert_array_equal(fc.weights.numpy(), data["weights"])
    np.testing.assert_array_equal(fc.mean.numpy(), data["mean"])
    np.testing.assert_array_equal(fc.var.numpy(), data["var"])
    assert fc.dt == 1 / 15

    tb, times, bound, conf = ep.bounds()
    np.testing.assert_array_equal(bound.numpy(), data["bound"])
    np.testing.assert_array_equal(times.numpy(), np.tile(data["times"], (STEPS, 1)))
    assert torch.all(conf == 0.95)
    assert ep.frames["/planner/bound"]["max_bound"].to_numpy() == pytest.approx(
        data["bound"].max(1)
    )

    plans = ep.frames["/planner/plan"]
    np.testing.assert_array_equal(np.stack(plans["q"]), data["plan_q"])
    assert list(plans["feasible"]) == [i % 3 != 0 for i in range(STEPS)]
    assert plans["wait_s"].to_numpy() == pytest.approx(0.1 * np.arange(STEPS))

    events = ep.events()
    assert len(events) == 1 and events[0]["kind"] == "handover"
    assert events[0]["t"] == data["t"][10]
    assert events[0]["detail"]["object"] == 2 and events[0]["detail"]["who"] == "human"
    assert math.isnan(events[0]["detail"]["gap"])

    m = ep.metrics()
    assert m["eval/smoothness"] == 1.5 and m["eval/x"] == math.inf and m["n"] is None

    ts, robot, human = ep.scene_spheres()
    np.testing.assert_allclose(ts.numpy(), data["t"], atol=1e-9)  # from the ns log time
    np.testing.assert_allclose(robot.numpy(), data["robot_spheres"], rtol=1e-12)
    np.testing.assert_allclose(human.numpy(), data["human_spheres"], rtol=1e-12)
    axis_aligned = ep.frames["/scene"]["ellipsoids"].iloc[0][1]
    np.testing.assert_allclose(axis_aligned["semi_axes"], [0.1, 0.2, 0.3])
    np.testing.assert_allclose(axis_aligned["rgba"], [1.0, 0.0, 0.0, 0.5])


def test_scene_ellipsoid_holds_95_percent_of_its_gaussian(log_path: Path, data: dict) -> None:
    """Monte Carlo: samples of N(mean, cov) fall inside the logged ellipsoid 95 % of the time."""
    ep = read_episode(log_path)
    e = ep.frames["/scene"]["ellipsoids"].iloc[0][0]
    rot = Rotation.from_quat(e["quaternion_xyzw"]).as_matrix()
    assert np.linalg.det(rot) == pytest.approx(1.0)
    g = np.random.default_rng(1)
    n = 40_000
    x = g.multivariate_normal(e["position"], data["cov"], size=n)
    local = (x - e["position"]) @ rot  # coordinates along the ellipsoid's axes
    inside = ((local / e["semi_axes"]) ** 2).sum(1) <= 1.0
    assert inside.mean() == pytest.approx(0.95, abs=0.005)


def test_every_message_validates_against_its_channel_schema(log_path: Path) -> None:
    with open(log_path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        validators = {}
        for ch in summary.channels.values():
            schema = summary.schemas[ch.schema_id]
            assert ch.message_encoding == "json" and schema.encoding == "jsonschema"
            parsed = json.loads(schema.data)
            jsonschema.Draft202012Validator.check_schema(parsed)
            assert schema.name == parsed["title"] == TOPIC_SCHEMAS[ch.topic]["title"]
            validators[ch.topic] = jsonschema.Draft202012Validator(parsed)
        seen = set()
        for _, ch, msg in reader.iter_messages():
            validators[ch.topic].validate(json.loads(msg.data))
            seen.add(ch.topic)
    assert seen == set(TOPIC_SCHEMAS)


def test_scene_is_a_foxglove_scene_update(log_path: Path) -> None:
    with open(log_path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        names = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        assert names["/scene"] == "foxglove.SceneUpdate"
        assert names["/tf"] == "foxglove.FrameTransform"
        _, _, msg = next(iter(reader.iter_messages(topics=["/scene"])))
    scene = json.loads(msg.data)
    assert scene["deletions"] == []
    assert [e["id"] for e in scene["entities"]] == ["robot", "human", "prediction"]
    for e in scene["entities"]:
        assert e["frame_id"] == "world"
        for prim in ("arrows", "cubes", "cylinders", "lines", "triangles", "texts", "models"):
            assert e[prim] == []
        assert set(e["spheres"][0]) == {"pose", "size", "color"}
    robot = scene["entities"][0]["spheres"][0]
    assert robot["pose"]["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    assert robot["size"]["x"] == robot["size"]["y"] == robot["size"]["z"] > 0


def _foxglove_datatypes(schema: dict, name: str) -> dict[str, list[str]]:
    """What Foxglove's JSON-schema loader makes of a channel's schema, or the error it raises.

    A line-by-line Python port of ``parseJsonSchema`` in foxglove/studio
    ``packages/mcap-support/src/parseJsonSchema.ts`` (commit 9abf665; the same in its fork
    Lichtblick): a channel whose schema it rejects is dropped, topic and all. It accepts an
    object's ``properties`` of type boolean, string (base64 content: bytes), number,
    integer, object, or array of one of those; an enum only as a ``oneOf`` of numeric
    ``const``; nothing else (no ``anyOf``, no ``enum``, no type lists, no arrays of arrays,
    no object without ``properties``)."""
    types: dict[str, list[str]] = {}

    def add(node: dict, type_name: str, path: list[str]) -> None:
        if node.get("type") != "object":
            raise ValueError(f'Expected "type": "object" for schema {type_name}')
        if not isinstance(node.get("properties"), dict):  # Object.entries(undefined) throws
            raise TypeError(f"no properties at {'.'.join(path) or type_name}")
        fields = []
        for field, sub in node["properties"].items():
            where = ".".join([*path, field])
            if isinstance(sub.get("oneOf"), list):
                if not all(isinstance(a.get("const"), int | float) for a in sub["oneOf"]):
                    raise ValueError(f"oneOf alternatives must have number values: {where}")
                fields.append(f"{field}: uint32 enum")
                continue
            kind = sub.get("type")
            if kind in ("boolean", "number", "integer"):
                fields.append(f"{field}: {kind}")
            elif kind == "string":
                if sub.get("contentEncoding") not in (None, "base64"):
                    raise ValueError(f"unsupported contentEncoding in {where}")
                fields.append(f"{field}: string")
            elif kind == "object":
                add(sub, f"{type_name}.{field}", [*path, field])
                fields.append(f"{field}: {type_name}.{field}")
            elif kind == "array":
                item = sub.get("items", {})
                item_kind = item.get("type")
                if item_kind == "object":
                    add(item, f"{type_name}.{field}", [*path, field])
                elif item_kind == "string" and item.get("contentEncoding") is not None:
                    raise ValueError(f"unsupported contentEncoding for array item {where}")
                elif item_kind not in ("boolean", "string", "number", "integer"):
                    raise ValueError(f"Unsupported type {item_kind!r} for array item {where}")
                fields.append(f"{field}: {item_kind}[]")
            else:
                raise ValueError(f"Unsupported type {kind!r} for {where}")
        types[type_name] = fields

    add(schema, name, [])
    return types


def test_foxglove_loads_every_channel(log_path: Path) -> None:
    """Foxglove's own JSON-schema loader (ported: :func:`_foxglove_datatypes`) accepts the
    schema of every channel as written in the log, so every channel shows and plots there: a
    bare "enum" on the deletion and line types (the published schema writes a oneOf of
    consts) made it drop /scene, and the numeric channels' arrays of arrays and nullable
    items (NaN as null) made it drop those six channels."""
    with open(log_path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    loaded: dict[str, dict[str, list[str]]] = {}
    for ch in summary.channels.values():
        schema = summary.schemas[ch.schema_id]
        loaded[ch.topic] = _foxglove_datatypes(json.loads(schema.data), schema.name)
    assert set(loaded) == set(TOPIC_SCHEMAS)
    state = loaded["/robot/joint_state"]["iplanner.RobotJointState"]
    assert {"position: number[]", "velocity: number[]", "joint_names: string[]"} <= set(state)
    human = loaded["/human/joints_tracked"]
    assert "positions: object[]" in human["iplanner.HumanJoints"]
    assert human["iplanner.HumanJoints.positions"] == [
        "joint: string",
        "x: number",
        "y: number",
        "z: number",
    ]
    forecast = loaded["/prediction/forecast"]["iplanner.Forecast"]
    assert {"weights: number[]", "mean: number[]", "var: number[]"} <= set(forecast)
    assert "max_bound: number" in loaded["/planner/bound"]["iplanner.CollisionBound"]
    assert "q: number[]" in loaded["/planner/plan"]["iplanner.Plan"]
    scene = _foxglove_datatypes(json.loads(json.dumps(TOPIC_SCHEMAS["/scene"])), "s")
    assert "type: uint32 enum" in scene["s.deletions"]
    assert "spheres: object[]" in scene["s.entities"] and "s.entities.spheres.pose" in scene
    # the port refuses what Foxglove refuses: the forms that dropped /scene and the numbers
    bare = json.loads(json.dumps(TOPIC_SCHEMAS["/scene"]))
    bare["properties"]["deletions"]["items"]["properties"]["type"] = {"enum": [0, 1]}
    with pytest.raises(ValueError, match="Unsupported type None for deletions.type"):
        _foxglove_datatypes(bare, "s")
    nested = {"type": "object", "properties": {"q": {"type": "array", "items": {"type": "array"}}}}
    with pytest.raises(ValueError, match="Unsupported type 'array' for array item q"):
        _foxglove_datatypes(nested, "n")
    nullable = {
        "type": "object",
        "properties": {"q": {"type": "array", "items": {"anyOf": [{"type": "number"}]}}},
    }
    with pytest.raises(ValueError, match="Unsupported type None for array item q"):
        _foxglove_datatypes(nullable, "n")


def test_numeric_channels_are_plain_numbers_and_named_joints(log_path: Path, data: dict):
    """As Foxglove plots them: flat arrays of numbers (row-major) and the human joints as
    ``{joint, x, y, z}`` objects, a joint that dropped out left out of its frame."""
    with open(log_path, "rb") as f:
        msgs: dict[str, list[dict]] = {}
        for _, ch, m in make_reader(f).iter_messages():
            msgs.setdefault(ch.topic, []).append(json.loads(m.data))
    state = msgs["/robot/joint_state"][3]
    assert state["position"] == data["q"][3].astype(np.float64).tolist()
    plan = msgs["/planner/plan"][2]
    assert plan["q"] == data["plan_q"][2].ravel().tolist()  # (W, J) row-major
    forecast = msgs["/prediction/forecast"][1]
    assert forecast["mean"] == data["mean"][1].ravel().tolist()  # (A, n_f, K, 3) row-major
    for i, m in enumerate(msgs["/human/joints_tracked"]):
        kept = [k for k in range(K) if np.isfinite(data["tracked"][i, k]).all()]
        assert [p["joint"] for p in m["positions"]] == [HUMAN[k] for k in kept]
        assert [[p[c] for c in "xyz"] for p in m["positions"]] == data["tracked"][i, kept].tolist()
    assert all(len(m["positions"]) == K for m in msgs["/human/joints_true"])


def test_logs_of_the_earlier_nested_form_read_back_alike(tmp_path: Path) -> None:
    """Logs written before the Foxglove-plottable form (nested arrays; NaN as null and
    infinities as "inf"/"-inf"; every human joint, null where it dropped out; max_bound
    null without waypoints) read back as they did."""
    nan = None
    messages = [
        ("/robot/joint_state", {"t": 0.0, "joint_names": ["a", "b"], "position": [1.0, nan],
                                "velocity": ["inf", "-inf"]}),
        ("/human/joints_tracked", {"t": 0.0, "joint_names": ["h0", "h1"],
                                   "positions": [[0.1, 0.2, 0.3], [nan, nan, nan]]}),
        ("/prediction/forecast", {"t": 0.0, "dt": 0.5, "action_names": ["x", "y"],
                                  "joint_names": ["h0"], "weights": [0.25, 0.75],
                                  "mean": [[[[1.0, 2.0, 3.0]]], [[[4.0, 5.0, 6.0]]]],
                                  "var": [[[[0.1, 0.2, 0.3]]], [[[0.4, 0.5, 0.6]]]]}),
        ("/planner/bound", {"t": 0.0, "times": [], "bound": [], "confidence": 0.95,
                            "max_bound": nan}),
        ("/planner/plan", {"t": 0.0, "times": [0.0, 1.0], "q": [[0.0, 1.0], [2.0, 3.0]],
                           "feasible": True, "wait_s": 0.0, "solve_ms": 1.0}),
    ]  # fmt: skip
    ep = read_episode(_raw_log(tmp_path / "v1.mcap", messages, metadata={"planner": "x"}))
    np.testing.assert_array_equal(ep.robot_q()[1].numpy(), [[1.0, np.nan]])
    np.testing.assert_array_equal(ep.robot_qd()[1].numpy(), [[np.inf, -np.inf]])
    np.testing.assert_array_equal(ep.human_tracked()[1].numpy(), [[[0.1, 0.2, 0.3], [np.nan] * 3]])
    _, fc = ep.forecasts(dtype=torch.float64)
    np.testing.assert_array_equal(fc.mean.numpy(), [[[[[1.0, 2.0, 3.0]]], [[[4.0, 5.0, 6.0]]]]])
    np.testing.assert_array_equal(fc.var.numpy()[0, 1, 0, 0], [0.4, 0.5, 0.6])
    assert math.isnan(ep.frames["/planner/bound"]["max_bound"].iloc[0])
    np.testing.assert_array_equal(ep.frames["/planner/plan"]["q"].iloc[0], [[0, 1], [2, 3]])


def test_a_joint_with_any_coordinate_not_finite_reads_back_as_nan(tmp_path: Path) -> None:
    """JSON has no NaN: a joint with one NaN or infinite coordinate is left out of the message
    whole (reads back NaN in every coordinate); a frame with no joint tracked reads all NaN."""
    tracked = np.array([[0.1, np.nan, 0.3], [1.0, 2.0, np.inf], [4.0, 5.0, 6.0]])
    path = tmp_path / "p.mcap"
    with EpisodeWriter(path, metadata={}) as log:
        log.human_joints(0.0, None, tracked, ["a", "b", "c"])
        log.human_joints(0.1, None, np.full((3, 3), np.nan), ["a", "b", "c"])
    _, got = read_episode(path).human_tracked()
    expected = np.full((2, 3, 3), np.nan)
    expected[0, 2] = [4.0, 5.0, 6.0]
    np.testing.assert_array_equal(got.numpy(), expected)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda log: log.robot_state(0.0, [0.0, math.nan], [0.0, 0.0], ["a", "b"]),
         r"expected q finite, got nan at index 1 \(1 of 2 not finite\)"),
        (lambda log: log.robot_state(0.0, [0.0, 0.0], [math.inf, 0.0], ["a", "b"]),
         "expected qd finite, got inf at index 0"),
        (lambda log: log.plan(0.0, [0.0, 1.0], [[0.0], [-math.inf]], True, 0.0, 1.0),
         r"expected q finite, got -inf at index \(1, 0\)"),
        (lambda log: log.collision_bound(0.0, [0.0, 1.0], [0.0, math.nan], 0.95),
         "expected bound finite, got nan at index 1"),
        (lambda log: log.collision_bound(0.0, [math.nan, 1.0], [0.0, 0.0], 0.95),
         "expected times finite"),
    ],
)  # fmt: skip
def test_numbers_json_cannot_carry_are_refused_and_nothing_is_lost(
    tmp_path: Path, call, match: str
) -> None:
    """NaN and infinities in the robot state, plans and bounds (always finite from the
    simulation and the planner) are refused by name, before anything is written: the log
    keeps what came before and takes what comes after."""
    path = tmp_path / "bad.mcap"
    with EpisodeWriter(path, metadata={}) as log:
        log.robot_state(0.0, [0.0, 1.0], [0.0, 0.0], ["a", "b"])
        with pytest.raises(DataError, match=match):
            call(log)
        log.robot_state(0.1, [2.0, 3.0], [0.0, 0.0], ["a", "b"])
        log.plan(0.1, [0.0, 1.0], [[0.0, 1.0], [2.0, 3.0]], True, 0.0, 1.0)
        log.collision_bound(0.1, [], [], 0.95)
    ep = read_episode(path)
    np.testing.assert_array_equal(ep.robot_q()[1].numpy(), [[0.0, 1.0], [2.0, 3.0]])
    assert len(ep.frames["/planner/plan"]) == 1
    assert math.isnan(ep.frames["/planner/bound"]["max_bound"].iloc[0])  # no waypoints


@pytest.mark.parametrize(
    ("positions", "error"),
    [
        ([{"joint": "c", "x": 0.0, "y": 0.0, "z": 0.0}], "names joint 'c'"),
        ([{"joint": "a", "x": 0.0, "y": 0.0, "z": 0.0}] * 2, "names joint 'a'.*twice"),
        ([{"joint": "a", "x": 0.0, "y": "0", "z": 0.0}], "'y' must be a number"),
        ([{"joint": "a", "x": 0.0, "y": 0.0}], "'z'"),
    ],
)
def test_joint_objects_that_do_not_fit_their_names_are_named(
    tmp_path: Path, positions: list, error: str
) -> None:
    message = {"t": 0.0, "joint_names": ["a", "b"], "positions": positions}
    path = _raw_log(tmp_path / "bad.mcap", [("/human/joints_true", message)], metadata={})
    with pytest.raises(
        DataError, match=rf"cannot decode a message on /human/joints_true.*{error}"
    ):
        read_episode(path)


def test_scene_spheres_left_out_read_back_in_their_slots(tmp_path: Path) -> None:
    """Rows with NaN or an infinity are not drawn (Foxglove has no NaN sphere), yet every other
    sphere reads back in its own row, with NaN rows where some were left out."""
    g = np.random.default_rng(3)
    human = np.concatenate([g.normal(size=(4, 3, 3)), g.uniform(0.05, 0.1, (4, 3, 1))], -1)
    robot = np.concatenate([g.normal(size=(4, 2, 3)), g.uniform(0.05, 0.1, (4, 2, 1))], -1)
    human[1, 1] = np.nan  # a middle row
    human[2, 2, 3] = np.inf  # the last row
    human[3] = np.nan  # every row
    robot[2, 0, 0] = -np.inf
    path = tmp_path / "scene.mcap"
    with EpisodeWriter(path, metadata={}) as log:
        for i in range(4):
            log.scene(0.1 * i, robot[i], human[i])
    _, r, h = read_episode(path).scene_spheres()
    expected_h, expected_r = human.copy(), robot.copy()
    expected_h[~np.isfinite(human).all(-1)] = np.nan
    expected_r[~np.isfinite(robot).all(-1)] = np.nan
    np.testing.assert_array_equal(h.numpy(), expected_h)
    np.testing.assert_array_equal(r.numpy(), expected_r)

    validator = jsonschema.Draft202012Validator(TOPIC_SCHEMAS["/scene"])
    with open(path, "rb") as f:
        scenes = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(["/scene"])]
    for scene in scenes:
        validator.validate(scene)
    metadata = [{kv["key"]: kv["value"] for kv in e["metadata"]} for e in scenes[1]["entities"]]
    assert metadata[1] == {"kind": "human_spheres", "sphere_count": "3", "sphere_rows": "0,2"}
    assert metadata[0] == {"kind": "robot_spheres"}  # every row drawn: as before
    assert len(scenes[3]["entities"][1]["spheres"]) == 0


def test_metadata_nan_and_infinities_read_back(tmp_path: Path) -> None:
    meta = {"nan": math.nan, "inf": math.inf, "ninf": -math.inf, "deep": {"x": [math.nan, 1]}}
    with EpisodeWriter(tmp_path / "m.mcap", metadata=meta):
        pass
    back = read_episode(tmp_path / "m.mcap").metadata
    assert math.isnan(back["nan"]) and back["inf"] == math.inf and back["ninf"] == -math.inf
    assert math.isnan(back["deep"]["x"][0]) and back["deep"]["x"][1] == 1


#: Free-form values that a JSON codec could confuse: None against NaN, and strings that spell
#: the numbers JSON cannot carry, or the escape itself.
TRICKY = {
    "none": None,
    "nan": math.nan,
    "inf": math.inf,
    "ninf": -math.inf,
    "s_nan": "nan",
    "s_inf": "inf",
    "s_ninf": "-inf",
    "s_tilde": "~",
    "s_tilde_inf": "~inf",
    "s_tilde2": "~~x",
    "s_empty": "",
    "s_null": "null",
    "list": [None, "inf", math.nan, -math.inf, "~nan", 1, True],
    "array": np.array([1.5, np.nan, np.inf]),
}


def _same(a: object, b: object) -> bool:
    """Equality where NaN equals NaN and a float is not taken for a string or None."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple | np.ndarray):
        return isinstance(b, list) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return type(a) is type(b) and a == b


def test_free_form_values_read_back_as_written(tmp_path: Path) -> None:
    """Metadata, metrics and event details keep None, NaN, infinities and number-like strings
    apart (each checked value by value, the array as a list of floats)."""
    expected = {**TRICKY, "array": [1.5, math.nan, math.inf]}
    with EpisodeWriter(tmp_path / "v.mcap", metadata=TRICKY) as log:
        log.task_event(0.1, "note", TRICKY)
        log.metrics(0.2, TRICKY)
    ep = read_episode(tmp_path / "v.mcap")
    for name, back in [
        ("metadata", ep.metadata),
        ("detail", ep.events()[0]["detail"]),
        ("metrics", ep.metrics()),
    ]:
        for key, value in expected.items():
            assert _same(value, back[key]), (name, key, value, back[key])


def test_plain_mcap_reader_reads_every_message(log_path: Path) -> None:
    ep = read_episode(log_path)
    with open(log_path, "rb") as f:
        n = sum(1 for _ in make_reader(f).iter_messages())
    assert n == sum(len(df) for df in ep.frames.values())
    assert n == 1 + 6 * STEPS + STEPS + 1 + 1  # tf, 6 per step (2 human), scene, event, metrics


@pytest.mark.parametrize("fraction", [0.0005, 0.05, 0.3, 0.6, 0.95, 0.9995])
def test_truncated_file_reads_a_prefix_with_a_warning(
    log_path: Path, tmp_path: Path, fraction: float
) -> None:
    full = read_episode(log_path)
    blob = log_path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(blob[: int(len(blob) * fraction)])
    with pytest.warns(DataWarning, match="truncated or damaged"):
        ep = read_episode(cut)
    total = 0
    for topic, df in ep.frames.items():
        ref = full.frames[topic]
        assert len(df) <= len(ref)
        np.testing.assert_array_equal(df["t"].to_numpy(), ref["t"].to_numpy()[: len(df)])
        total += len(df)
    if "/robot/joint_state" in ep.frames:
        _, q = ep.robot_q()
        np.testing.assert_array_equal(q.numpy(), full.robot_q()[1].numpy()[: q.shape[0]])
    if fraction >= 0.05:  # metadata precedes the chunks
        assert ep.metadata == full.metadata
    if fraction >= 0.3:  # several 8 KiB chunks survive
        assert total > 0.2 * sum(len(df) for df in full.frames.values())
    # complete exactly when every message survived (a cut in the summary section loses none)
    assert ep.complete == (total == sum(len(df) for df in full.frames.values()))
    assert ep.complete == (fraction > 0.9)


def test_damaged_chunk_stops_the_read_there(log_path: Path, tmp_path: Path) -> None:
    blob = bytearray(log_path.read_bytes())
    mid = len(blob) // 2
    blob[mid : mid + 64] = bytes(64)  # zero a stretch inside a chunk
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(blob))
    with pytest.warns(DataWarning, match="damaged"):
        ep = read_episode(bad)
    n_full = len(read_episode(log_path).frames["/robot/joint_state"])
    assert 0 < len(ep.frames["/robot/joint_state"]) < n_full


@pytest.mark.slow
def test_killed_writer_leaves_a_readable_file(tmp_path: Path) -> None:
    """A process writing an episode is killed; its file reads up to the last chunk."""
    path = tmp_path / "killed.mcap"
    script = textwrap.dedent(
        f"""
        import numpy as np, time
        from iplanner_torch.recording import EpisodeWriter
        log = EpisodeWriter({str(path)!r}, metadata={{"run": "killed"}}, chunk_size=2048)
        i = 0
        while True:
            log.robot_state(i * 0.01, np.full(7, i, dtype=float), np.zeros(7), list("abcdefg"))
            i += 1
            if i % 50 == 0:
                time.sleep(0.01)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script], env=dict(os.environ))
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if path.exists() and path.stat().st_size > 30_000:
                break
            if proc.poll() is not None:
                pytest.fail(f"writer exited early with code {proc.returncode}")
            time.sleep(0.05)
    finally:
        proc.kill()
        proc.wait()
    with pytest.warns(DataWarning, match="truncated"):
        ep = read_episode(path)
    assert ep.metadata == {"run": "killed"}
    _, q = ep.robot_q()
    assert q.shape[0] > 50
    np.testing.assert_array_equal(q[:, 0].numpy(), np.arange(q.shape[0]))


def test_not_an_mcap_file_raises_naming_it(tmp_path: Path) -> None:
    bad = tmp_path / "notes.mcap"
    bad.write_text("hello, this is not MCAP")
    with pytest.raises(DataError, match="notes.mcap is not an MCAP file"):
        read_episode(bad)
    pointer = tmp_path / "lfs.mcap"
    pointer.write_text("version https://git-lfs.github.com/spec/v1\noid sha256:ab\nsize 9\n")
    with pytest.raises(DataError, match="lfs.mcap is not an MCAP file .* Git LFS pointer"):
        read_episode(pointer)
    with pytest.raises(DataError, match="missing.mcap: no such episode log"):
        read_episode(tmp_path / "missing.mcap")
    with pytest.raises(DataError, match="is a folder; read_episode reads one .mcap file"):
        read_episode(tmp_path)


def test_writer_rejects_bad_input(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="chunk_size"):
        EpisodeWriter(tmp_path / "a.mcap", metadata={}, chunk_size=0)
    log = EpisodeWriter(tmp_path / "b.mcap", metadata={})
    with pytest.raises(ShapeError, match=r"expected q \(J\)"):
        log.robot_state(0.0, np.zeros((2, 7)), np.zeros(7), JOINTS)
    with pytest.raises(ShapeError, match="expected qd"):
        log.robot_state(0.0, np.zeros(7), np.zeros(6), JOINTS)
    with pytest.raises(ShapeError, match="expected 7 joint_names, got 2"):
        log.robot_state(0.0, np.zeros(7), np.zeros(7), ["a", "b"])
    with pytest.raises(ShapeError, match="expected mean"):
        log.forecast(
            0.0, np.ones(4), np.zeros((3, 5, 10, 3)), np.zeros((3, 5, 10, 3)), "abcd", 0.1
        )
    with pytest.raises(DataError, match="t >= 0"):
        log.metrics(-1.0, {})
    with pytest.raises(ShapeError, match="exactly one of cov"):
        log.scene(0.0, np.zeros((1, 4)), np.zeros((1, 4)), [SceneEllipsoid(mean=np.zeros(3))])
    log.close()
    log.close()  # idempotent
    with pytest.raises(DataError, match="already closed"):
        log.metrics(1.0, {})
    ep = read_episode(tmp_path / "b.mcap")
    with pytest.raises(DataError, match="no messages on /robot/joint_state"):
        ep.robot_q()
    assert ep.metrics() == {} and ep.events() == []


def test_log_forecast_from_a_batched_forecast(tmp_path: Path) -> None:
    g = torch.Generator().manual_seed(0)
    fc = Forecast(
        weights=torch.softmax(torch.randn(2, A, generator=g), -1),
        mean=torch.randn(2, A, NF, K, 3, generator=g),
        var=torch.rand(2, A, NF, K, 3, generator=g),
        dt=0.1,
        joint_names=tuple(HUMAN),
        action_names=tuple(ACTIONS),
    )
    with EpisodeWriter(tmp_path / "f.mcap", metadata={}) as log:
        log.log_forecast(0.5, fc, index=1)
    _, back = read_episode(tmp_path / "f.mcap").forecasts()
    torch.testing.assert_close(back.mean[0], fc.mean[1], rtol=0, atol=0)
    torch.testing.assert_close(back.weights[0], fc.weights[1], rtol=0, atol=0)


def test_ellipsoid_pose_batch_rebuilds_each_covariance() -> None:
    g = np.random.default_rng(2)
    b = g.normal(size=(2, 6, 3, 3))
    cov = b @ np.swapaxes(b, -1, -2) + 1e-3 * np.eye(3)  # (2, 6, 3, 3)
    semi, quat = ellipsoid_pose(torch.from_numpy(cov), 0.95)
    assert semi.shape == (2, 6, 3) and quat.shape == (2, 6, 4)
    rot = Rotation.from_quat(quat.reshape(-1, 4)).as_matrix().reshape(2, 6, 3, 3)
    scale = chi2.ppf(0.95, df=3)
    rebuilt = rot @ (semi[..., :, None] ** 2 / scale * np.eye(3)) @ np.swapaxes(rot, -1, -2)
    np.testing.assert_allclose(rebuilt, cov, rtol=1e-9, atol=1e-12)
    with pytest.raises(ConfigError, match="confidence in"):
        ellipsoid_pose(cov, 1.0)


def test_unserialisable_values_raise_data_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="metadata is not JSON-serialisable"):
        EpisodeWriter(tmp_path / "m.mcap", metadata={"x": object()})
    with EpisodeWriter(tmp_path / "e.mcap", metadata={}) as log:
        with pytest.raises(DataError, match="/task/events message is not JSON-serialisable"):
            log.task_event(0.0, "bad", {"x": object()})


def test_leaving_the_writer_on_an_exception_logs_where_and_why(tmp_path: Path) -> None:
    path = tmp_path / "stopped.mcap"
    with pytest.raises(KeyboardInterrupt):
        with EpisodeWriter(path, metadata={"planner": "itomp"}) as log:
            log.robot_state(0.5, [0.0] * 7, [0.0] * 7, list("abcdefg"))
            log.robot_state(1.25, [0.0] * 7, [0.0] * 7, list("abcdefg"))
            raise KeyboardInterrupt
    ep = read_episode(path)
    assert ep.complete
    assert ep.events()[-1]["kind"] == "interrupted" and ep.events()[-1]["t"] == 1.25
    assert ep.events()[-1]["detail"] == {"error": "KeyboardInterrupt"}
    with EpisodeWriter(tmp_path / "fine.mcap", metadata={"planner": "itomp"}) as log:
        log.robot_state(0.5, [0.0] * 7, [0.0] * 7, list("abcdefg"))
    assert read_episode(tmp_path / "fine.mcap").events() == []


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="signals cannot be held")
@pytest.mark.parametrize("field", [3, 5, 8])
def test_a_ctrl_c_in_the_middle_of_a_record_leaves_a_readable_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, field: int
) -> None:
    """A real SIGINT that arrives while a message record is half written (after its
    ``field``-th 8-byte field of the run) is handled once the record is whole: the log reads,
    with every state logged before and an ``interrupted`` event. Without the held signals the
    interrupt cut the record, and its length field covered the ``interrupted`` event."""
    from mcap.data_stream import RecordBuilder

    count = {"n": 0}
    write8 = RecordBuilder.write8

    def interrupting_write8(self: RecordBuilder, value: int) -> None:
        count["n"] += 1
        if count["n"] == field:
            os.kill(os.getpid(), signal.SIGINT)
        write8(self, value)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    path = tmp_path / "cut.mcap"
    logged = []
    try:
        with pytest.raises(KeyboardInterrupt):
            with EpisodeWriter(path, metadata={"planner": "itomp"}) as log:
                monkeypatch.setattr(RecordBuilder, "write8", interrupting_write8)
                for i in range(20):
                    log.robot_state(0.1 * i, [0.1 * i] * 7, [0.0] * 7, list("abcdefg"))
                    logged.append(0.1 * i)
    finally:
        signal.signal(signal.SIGINT, previous)
        monkeypatch.undo()
    ep = read_episode(path)
    assert ep.complete
    t, q = ep.robot_q()[:2]
    assert len(logged) < 20 and np.allclose(np.asarray(t)[: len(logged)], logged)
    assert ep.events()[-1]["kind"] == "interrupted"


def test_the_readme_example_runs_on_a_log(log_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The README's example of reading an episode log, run on a log with every channel."""
    import re

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    example = next(b for b in blocks if "read_episode(" in b)
    path = re.search(r'read_episode\("([^"]+)"\)', example)
    assert path is not None and path.group(1).endswith(".mcap")
    namespace: dict = {}
    exec(example.replace(path.group(1), str(log_path)), namespace)  # noqa: S102
    out = capsys.readouterr().out
    assert out.startswith("iplanner_ni None") and "handover" in out
    assert namespace["q"].shape[1] == len(JOINTS) and namespace["joints"].shape[-1] == 3
    assert namespace["over"].shape == namespace["t_b"].shape
    assert namespace["forecast"].batch_size == len(namespace["t_f"])


def _raw_log(path: Path, messages: list[tuple[str, dict]], metadata: object = None) -> Path:
    """A minimal MCAP file written with the plain mcap writer: the episode metadata record
    (``metadata`` as its JSON, unless None) and JSON ``messages`` on their topics."""
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        if metadata is not None:
            w.add_metadata("iplanner.episode", {"json": json.dumps(metadata)})
        schema = w.register_schema("any", "jsonschema", b"{}")
        ids: dict[str, int] = {}
        for i, (topic, msg) in enumerate(messages):
            if topic not in ids:
                ids[topic] = w.register_channel(topic, "json", schema)
            data = json.dumps(msg).encode()
            w.add_message(ids[topic], log_time=i, data=data, publish_time=i)
        w.finish()
    return path


@pytest.mark.parametrize(
    ("topic", "message", "error"),
    [
        ("/robot/joint_state", {"t": 0.0, "joint_names": ["a", "b"], "position": [1.0],
                                "velocity": [0.0, 0.0]}, "'position' has 1 values"),
        ("/human/joints_true", {"t": 0.0, "joint_names": ["a", "b"],
                                "positions": [[0.0] * 4] * 3}, "'positions' has 12 values"),
        ("/robot/joint_state", {"t": "abc", "joint_names": ["a"], "position": [1.0],
                                "velocity": [0.0]}, "'t' must be a number"),
        ("/episode/metrics", {"t": 1.0, "metrics": [1, 2]}, "'metrics' must be an object"),
        ("/planner/plan", {"t": 1.0, "times": [0.0, 1.0], "q": [0.0, 1.0], "feasible": "false",
                           "wait_s": 0.0, "solve_ms": 1.0}, "'feasible' must be true or false"),
        ("/prediction/forecast", {"t": 0.0, "dt": 0.1, "action_names": [["x"]],
                                  "joint_names": ["a"], "weights": [1.0], "mean": [0.0] * 3,
                                  "var": [0.0] * 3}, "'action_names' must be a list of strings"),
    ],
)  # fmt: skip
def test_messages_of_the_wrong_size_or_type_are_named(
    tmp_path: Path, topic: str, message: dict, error: str
) -> None:
    """Arrays that do not fit their names, and fields of the wrong type, raise instead of
    being padded with NaN (a NaN joint would read as a tracker dropout) or reshaped."""
    path = _raw_log(tmp_path / "bad.mcap", [(topic, message)], metadata={"planner": "x"})
    with pytest.raises(DataError, match=rf"bad.mcap: cannot decode a message on {topic}.*{error}"):
        read_episode(path)


def test_a_damaged_summary_falls_back_to_reading_every_chunk(log_path: Path, tmp_path: Path):
    """The summary's checksum is verified: one changed byte there (which the mcap reader
    would follow into dropped or renamed data) gives a warning and a full sequential read."""
    data = bytearray(log_path.read_bytes())
    n = len(data)
    summary_start = int.from_bytes(data[n - 8 - 29 + 9 : n - 8 - 29 + 17], "little")
    assert 0 < summary_start < n - 37
    full = read_episode(log_path)
    for where in (summary_start + 1, (summary_start + n - 37) // 2):
        bad = bytearray(data)
        bad[where] ^= 0x40
        (tmp_path / "s.mcap").write_bytes(bytes(bad))
        with pytest.warns(DataWarning, match="summary section fails its checksum"):
            ep = read_episode(tmp_path / "s.mcap")
        assert ep.complete
        for topic, frame in full.frames.items():
            assert len(ep.frames[topic]) == len(frame), topic


def test_cut_in_the_magic_bytes_or_without_metadata_is_an_incomplete_episode(
    tmp_path: Path,
) -> None:
    for size in (0, 5):  # killed before the first flush
        p = tmp_path / f"cut{size}.mcap"
        p.write_bytes(b"\x89MCAP0\r\n"[:size])
        with pytest.warns(DataWarning, match="cut within the opening magic bytes"):
            ep = read_episode(p)
        assert not ep.complete and ep.metadata == {} and ep.frames == {}
    p = _raw_log(tmp_path / "anon.mcap", [("/episode/metrics", {"t": 1.0, "metrics": {}})])
    with pytest.warns(DataWarning, match="no iplanner.episode metadata record"):
        ep = read_episode(p)
    assert not ep.complete
    p = _raw_log(tmp_path / "list.mcap", [], metadata=[1, 2])
    with pytest.raises(DataError, match="list.mcap: bad episode metadata record: expected a JSON"):
        read_episode(p)


def test_forecasts_that_change_horizon_or_dt_are_named(tmp_path: Path) -> None:
    def fc(t: float, n_f: int, dt: object) -> tuple[str, dict]:
        return "/prediction/forecast", {
            "t": t, "dt": dt, "action_names": ["a"], "joint_names": ["j"], "weights": [1.0],
            "mean": [0.0] * (3 * n_f), "var": [0.01] * (3 * n_f),
        }  # fmt: skip

    path = _raw_log(tmp_path / "h.mcap", [fc(0.0, 4, 0.1), fc(0.1, 3, 0.1)], metadata={})
    with pytest.raises(DataError, match="h.mcap: the forecast horizon changes"):
        read_episode(path).forecasts()
    path = _raw_log(tmp_path / "d.mcap", [fc(0.0, 4, 0.1), fc(0.1, 4, None)], metadata={})
    with pytest.raises(DataError, match="d.mcap: dt changes between forecasts"):
        read_episode(path).forecasts()
    t, f = read_episode(
        _raw_log(tmp_path / "ok.mcap", [fc(0.0, 4, 0.1)] * 2, metadata={})
    ).forecasts()
    assert f.mean.shape == (2, 1, 4, 1, 3)


def test_a_changed_byte_in_the_episode_metadata_is_caught(log_path: Path, tmp_path: Path):
    """Metadata records have no MCAP checksum: the writer stores a CRC beside the JSON, so a
    changed value (a planner name, a seed) reads as unknown, not as another episode."""
    full = read_episode(log_path)
    assert full.metadata and full.complete
    blob = bytearray(log_path.read_bytes())
    key = json.dumps(next(iter(full.metadata))).encode()  # the first key, quoted
    at = blob.index(key) + 1
    blob[at] = ord("X") if blob[at] != ord("X") else ord("Y")
    (tmp_path / "m.mcap").write_bytes(bytes(blob))
    with pytest.warns(DataWarning, match="episode metadata fails its checksum"):
        ep = read_episode(tmp_path / "m.mcap")
    assert ep.metadata == {} and not ep.complete
    assert len(ep.frames["/robot/joint_state"]) == len(full.frames["/robot/joint_state"])


def test_round_trips_of_what_a_reader_could_reorder_or_pad(tmp_path: Path) -> None:
    """Read back as written: a /tf rotation in x, y, z, w order; the last of two metrics
    messages; bounds of 2 and 3 waypoints padded with NaN (a 0 would read as a contact)."""
    from iplanner_torch.recording import EpisodeWriter, read_episode

    path = tmp_path / "r.mcap"
    quat = (0.1, 0.2, 0.3, math.sqrt(1 - 0.14))
    with EpisodeWriter(path, metadata={}) as log:
        log.frame_transform(0.5, "world", "robot", (1.0, 2.0, 3.0), quat)
        log.collision_bound(0.1, [0.0, 0.1], [0.01, 0.02], 0.95)
        log.collision_bound(0.2, [0.0, 0.1, 0.2], [0.03, 0.04, 0.05], 0.95)
        log.metrics(1.0, {"eval/smoothness": 1.0})
        log.metrics(2.0, {"eval/smoothness": 2.0})
    ep = read_episode(path)
    tf = ep.frames["/tf"]
    row = tf[tf["child_frame_id"] == "robot"].iloc[0]
    np.testing.assert_allclose(row["rotation_xyzw"], quat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(row["translation"], (1.0, 2.0, 3.0))
    assert ep.metrics() == {"eval/smoothness": 2.0}
    _, times, bound, _ = ep.bounds()
    assert bound.shape == (2, 3) and math.isnan(float(bound[0, 2])) and math.isnan(times[0, 2])
    torch.testing.assert_close(bound[1], torch.tensor([0.03, 0.04, 0.05], dtype=torch.float64))


def test_codec_keeps_bools_and_integers_of_numpy_as_such() -> None:
    """A numpy bool mask reads back as bools and a numpy integer as an int ("3", not "3.0")."""
    import json

    from iplanner_torch.recording.codec import encode_value

    got = encode_value({"mask": np.array([True, False]), "n": np.int64(3), "b": np.bool_(True)})
    assert json.dumps(got) == '{"mask": [true, false], "n": 3, "b": true}'
