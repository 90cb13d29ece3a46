"""EpisodeWriter / read_episode on bad input: typed errors naming the argument, the channel or
the path, and files of other tools read as far as they are ours."""

from __future__ import annotations

import json
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from foreign_mcap import write_foreign_mcap
from mcap.writer import Writer

from iplanner_torch.errors import ConfigError, DataError, DataWarning, ShapeError
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.recording import EpisodeWriter, SceneEllipsoid, ellipsoid_pose, read_episode
from iplanner_torch.recording.codec import MAX_VALUE_DEPTH

ARM = ["shoulder", "elbow"]
HANDS = ["left_hand", "right_hand"]


def _mcap(
    path: Path,
    messages: list[tuple[str, dict | bytes]],
    encodings: dict[str, str] | None = None,
    metadata: dict | None = None,
    record: dict[str, str] | None = None,
) -> Path:
    """An MCAP file written with the plain mcap writer: the episode metadata record and
    ``messages`` on their topics, each JSON-encoded unless it is bytes already; a topic's
    channel has the message encoding ``encodings[topic]`` ("json" when not given). ``record``
    replaces the whole metadata record (``metadata`` is then not used)."""
    encodings = encodings or {}
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("iplanner.episode", record or {"json": json.dumps(metadata or {})})
        ids: dict[str, int] = {}
        for i, (topic, msg) in enumerate(messages):
            if topic not in ids:
                encoding = encodings.get(topic, "json")
                schema = 0
                if encoding != "":  # a schemaless channel has schema id 0
                    is_json = encoding == "json"
                    schema = w.register_schema(
                        f"{topic}.schema",
                        "jsonschema" if is_json else encoding,
                        b"{}" if is_json else b"\x0a\x01x",  # a protobuf descriptor's bytes
                    )
                ids[topic] = w.register_channel(topic, encoding, schema)
            data = msg if isinstance(msg, bytes) else json.dumps(msg).encode()
            w.add_message(ids[topic], log_time=i, data=data, publish_time=i)
        w.finish()
    return path


def _scene(log: EpisodeWriter, ellipsoid: SceneEllipsoid | tuple) -> None:
    log.scene(0.0, np.zeros((1, 4)), np.zeros((1, 4)), [ellipsoid])


def _state(t: float, names: list[str]) -> tuple[str, dict]:
    n = len(names)
    return "/robot/joint_state", {
        "t": t, "joint_names": names, "position": [1.0] * n, "velocity": [0.0] * n,
    }  # fmt: skip


def _human(topic: str, t: float, names: list[str]) -> tuple[str, dict]:
    return topic, {"t": t, "joint_names": names, "positions": [[0.0, 0.0, 1.0]] * len(names)}


# -- 1. joint names that change within a channel ------------------------------------------------


def test_the_writer_refuses_joint_names_that_change_on_a_channel(tmp_path: Path) -> None:
    """A third joint appears in front of the others; the writer refuses
    it (a bad log is never written) and what came before still reads back."""
    path = tmp_path / "ragged.mcap"
    with EpisodeWriter(path, metadata={}) as log:
        log.robot_state(0.0, [1.0, 2.0], [0, 0], ARM)
        log.robot_state(0.05, [1.5, 2.5], [0, 0], tuple(ARM))  # the same names: fine
        with pytest.raises(
            DataError,
            match=r"ragged.mcap: joint_names changed on /robot/joint_state: "
            r"\['shoulder', 'elbow'\] before, \['base', 'shoulder', 'elbow'\] now",
        ):
            log.robot_state(0.1, [9.0, 1.0, 2.0], [0, 0, 0], ["base", *ARM])
        with pytest.raises(DataError, match=r"\['shoulder', 'elbow'\] before, \['elbow', 'sh"):
            log.robot_state(0.1, [1.0, 2.0], [0, 0], ARM[::-1])  # reordered
        log.human_joints(0.0, np.zeros((2, 3)), None, HANDS)
        with pytest.raises(DataError, match=r"on /human/joints_true: \['left_hand', 'right_h"):
            log.human_joints(0.1, np.zeros((1, 3)), np.zeros((1, 3)), ["right_hand"])
        log.human_joints(0.2, None, np.zeros((1, 3)), ["right_hand"])  # tracked: its first
        with pytest.raises(DataError, match=r"action_names changed on /prediction/forecast"):
            for actions in (["reach"], ["place"]):
                log.forecast(
                    0.0, [1.0], np.zeros((1, 2, 2, 3)), np.ones((1, 2, 2, 3)), actions, 0.1
                )
    ep = read_episode(path)
    t, q = ep.robot_q()
    np.testing.assert_array_equal(q.numpy(), [[1.0, 2.0], [1.5, 2.5]])
    assert ep.human_true()[1].shape == (1, 2, 3) and ep.human_tracked()[1].shape == (1, 1, 3)
    assert ep.forecasts()[1].action_names == ("reach",)


@pytest.mark.parametrize(
    ("messages", "accessor", "error"),
    [
        ([_state(0.0, ARM), _state(0.1, ["base", *ARM])], "robot_q",
         r"/robot/joint_state: \['shoulder', 'elbow'\] at t=0 s, then "
         r"\['base', 'shoulder', 'elbow'\] at t=0.1 s"),
        ([_state(0.0, ARM), _state(0.1, ARM), _state(0.2, ARM[::-1])], "robot_qd",
         r"/robot/joint_state: \['shoulder', 'elbow'\] at t=0 s, then \['elbow', 'shoulder'\] "
         r"at t=0.2 s"),
        ([_human("/human/joints_true", 0.0, HANDS), _human("/human/joints_true", 0.1, ["r"])],
         "human_true", r"/human/joints_true: \['left_hand', 'right_hand'\] at t=0 s, then "
         r"\['r'\] at t=0.1 s"),
        ([_human("/human/joints_tracked", 0.0, ["r"]),
          _human("/human/joints_tracked", 0.1, HANDS)],
         "human_tracked", r"/human/joints_tracked: \['r'\] at t=0 s, then \['left_hand'"),
    ],
    ids=["robot_q_added", "robot_qd_reordered", "human_true_dropped", "human_tracked_added"],
)  # fmt: skip
def test_accessors_refuse_joint_names_that_change_between_messages(
    tmp_path: Path, messages: list, accessor: str, error: str
) -> None:
    """A log from another writer whose names change is not NaN-padded into mixed columns."""
    path = _mcap(tmp_path / "ragged.mcap", messages)
    with pytest.raises(
        DataError, match=rf"ragged.mcap: joint_names changes between messages on {error}"
    ):
        getattr(read_episode(path), accessor)()


def test_forecasts_name_the_names_that_change(tmp_path: Path) -> None:
    def fc(t: float, joints: list[str]) -> tuple[str, dict]:
        k = len(joints)
        return "/prediction/forecast", {
            "t": t, "dt": 0.1, "action_names": ["a"], "joint_names": joints, "weights": [1.0],
            "mean": [0.0] * (6 * k), "var": [0.01] * (6 * k),
        }  # fmt: skip

    path = _mcap(tmp_path / "fc.mcap", [fc(0.0, ["x", "y"]), fc(0.5, ["y"])])
    with pytest.raises(
        DataError,
        match=r"fc.mcap: joint_names changes between messages on /prediction/forecast: "
        r"\['x', 'y'\] at t=0 s, then \['y'\] at t=0.5 s",
    ):
        read_episode(path).forecasts()


# -- 2. channels of other tools ----------------------------------------------------------------


def test_channels_neither_ours_nor_json_are_skipped_with_one_warning(tmp_path: Path) -> None:
    """An MCAP from another tool with protobuf, schemaless binary and JSON channels of its own:
    the first two are skipped, named in one warning; its JSON channel is kept."""
    messages = [
        _state(0.0, ARM),
        ("/odom", b"\x08\x96\x01\xff\x00"),
        ("/camera/raw", bytes(range(256))),
        ("/odom", b"\x08\x97\x01"),
        ("/notes", {"text": "hello"}),
        _state(0.1, ARM),
    ]
    encodings = {"/odom": "protobuf", "/camera/raw": ""}
    path = _mcap(tmp_path / "other.mcap", messages, encodings, metadata={"robot": "x"})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ep = read_episode(path)
    assert [str(w.message) for w in caught] == [
        f"{path}: skipped 3 messages on channels that are not episode-log topics and not "
        "JSON-encoded: /camera/raw (message encoding ''), /odom (message encoding 'protobuf')"
    ]
    assert caught[0].category is DataWarning
    assert ep.complete and ep.metadata == {"robot": "x"}
    assert set(ep.frames) == {"/robot/joint_state", "/notes"}
    assert ep.frames["/notes"]["message"].iloc[0] == {"text": "hello"}
    assert ep.robot_q()[1].shape == (2, 2)

    cut = tmp_path / "cut.mcap"  # without its summary: read record by record
    blob = path.read_bytes()
    summary_start = int.from_bytes(blob[-8 - 29 + 9 : -8 - 29 + 17], "little")
    cut.write_bytes(blob[:summary_start])
    with pytest.warns(DataWarning) as caught:
        ep = read_episode(cut)
    assert sorted(str(w.message).split(": ", 1)[1][:30] for w in caught) == [
        "episode log is truncated or da",
        "skipped 3 messages on channels",
    ]
    assert set(ep.frames) == {"/robot/joint_state", "/notes"}


def test_our_topics_and_json_channels_with_bad_data_still_raise(tmp_path: Path) -> None:
    path = _mcap(tmp_path / "p.mcap", [("/robot/joint_state", b"\x08\x96")], {
        "/robot/joint_state": "protobuf"
    })  # fmt: skip
    with pytest.raises(DataError, match="p.mcap: cannot decode a message on /robot/joint_sta"):
        read_episode(path)
    path = _mcap(tmp_path / "j.mcap", [("/notes", b"\xff\x00not json")])
    with pytest.raises(DataError, match="j.mcap: cannot decode a message on /notes"):
        read_episode(path)


def test_a_complete_mcap_of_another_program_is_named_not_an_episode_log(tmp_path: Path) -> None:
    """A complete MCAP file written by another program (the mcap package's writer: no
    iplanner.episode metadata record) was reported as truncated or damaged: it is read,
    marked ``foreign``, with one warning saying it is not an iplanner episode log. The same
    file cut before its end is not foreign (our log cut before its metadata looks the
    same): truncated, as before."""
    path = write_foreign_mcap(tmp_path / "other.mcap")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ep = read_episode(path)
    assert [str(w.message) for w in caught] == [
        f"{path}: not an iplanner episode log: a valid MCAP file with no iplanner.episode "
        "metadata record (written by another program?); read 3 messages of its channels"
    ]
    assert caught[0].category is DataWarning
    assert ep.foreign and not ep.complete and ep.metadata == {}
    assert len(ep.frames["/odom"]) == 3
    blob = path.read_bytes()
    summary_start = int.from_bytes(blob[-8 - 29 + 9 : -8 - 29 + 17], "little")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(blob[: summary_start - 13])  # without its data end record
    with pytest.warns(DataWarning, match="cut.mcap: episode log is truncated or damaged"):
        ep = read_episode(cut)
    assert not ep.foreign and not ep.complete
    with EpisodeWriter(tmp_path / "ours.mcap", metadata={"planner": "itomp"}) as log:
        log.metrics(1.0, {"eval/contact": 0.0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ep = read_episode(tmp_path / "ours.mcap")
    assert not ep.foreign and ep.complete


# -- 3. messages nested too deep ---------------------------------------------------------------


@pytest.mark.parametrize("topic", ["/robot/joint_state", "/notes"])
def test_a_message_nested_too_deep_is_a_data_error(tmp_path: Path, topic: str) -> None:
    """100000 nested arrays overflow the JSON decoder's recursion: a DataError, not a
    RecursionError."""
    deep = b"[" * 100_000 + b"]" * 100_000
    path = _mcap(tmp_path / "deep.mcap", [(topic, deep)])
    with pytest.raises(DataError, match=f"deep.mcap: cannot decode a message on {topic}: Rec"):
        read_episode(path)


def test_a_task_event_detail_nested_too_deep_is_a_data_error(tmp_path: Path) -> None:
    """JSON a little shallower than the decoder's limit, but too deep to decode after it."""
    detail: dict = {}
    for _ in range(600):
        detail = {"x": detail}
    data = b'{"t":0.0,"kind":"deep","detail":' + json.dumps(detail).encode() + b"}"
    json.loads(data)  # the JSON decoder itself takes it
    path = _mcap(tmp_path / "deep.mcap", [("/task/events", data)])
    with pytest.raises(DataError, match="deep.mcap: cannot decode a message on /task/events"):
        read_episode(path)


# -- 4. writer arguments -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda log: log.robot_state("x", [1.0], [0.0], ["a"]), DataError,
         r"w.mcap: expected a finite time t >= 0 s, got 'x'"),
        (lambda log: log.robot_state("0.5", [1.0], [0.0], ["a"]), DataError,
         r"w.mcap: expected a finite time t >= 0 s, got '0.5'"),
        (lambda log: log.metrics(None, {}), DataError,
         r"w.mcap: expected a finite time t >= 0 s, got None"),
        (lambda log: log.robot_state(0.0, ["a"], [0.0], ["a"]), ShapeError,
         r"expected q \(J\) of numbers, got \['a'\]"),
        (lambda log: log.robot_state(0.0, [1.0], ["1.0"], ["a"]), ShapeError,
         r"expected qd \(1\) of numbers, got \['1.0'\]"),
        (lambda log: log.human_joints(0.0, [[0, 0, 0], [1, 1]], None, ["a", "b"]), ShapeError,
         r"expected true \(K, 3\) of numbers, got \[\[0, 0, 0\], \[1, 1\]\]"),
        (lambda log: log.collision_bound(0.0, [0, 1], [0, 0], "high"), DataError,
         r"w.mcap: expected confidence a number, got 'high'"),
        (lambda log: log.collision_bound(0.0, [0, 1], [0, 0], 2.0), DataError,
         r"w.mcap: expected confidence in \(0, 1\), got 2.0"),
        (lambda log: log.collision_bound(0.0, [0, 1], [0, 0], 0.0), DataError,
         r"w.mcap: expected confidence in \(0, 1\), got 0.0"),
        (lambda log: log.plan(0.0, [0.0], [[1.0]], "false", 0.0, 1.0), DataError,
         r"w.mcap: expected feasible True or False, got 'false'"),
        (lambda log: log.plan(0.0, [0.0], [[1.0]], 1, 0.0, 1.0), DataError,
         r"w.mcap: expected feasible True or False, got 1"),
        (lambda log: log.plan(0.0, [0.0], [[1.0]], True, None, 1.0), DataError,
         r"w.mcap: expected wait_s a number, got None"),
        (lambda log: log.plan(0.0, [0.0], [[1.0]], True, 0.0, "fast"), DataError,
         r"w.mcap: expected solve_ms a number, got 'fast'"),
        (lambda log: log.forecast(0.0, [1.0], np.zeros((1, 2, 1, 3)), np.ones((1, 2, 1, 3)),
                                  ["a"], "0.1"), DataError,
         r"w.mcap: expected dt a number, got '0.1'"),
        (lambda log: log.robot_state(0.0, [1.0], [0.0], [3]), DataError,
         r"w.mcap: expected joint_names as strings, got \[3\]"),
        (lambda log: log.human_joints(0.0, np.zeros((1, 3)), None, [b"hand"]), DataError,
         r"w.mcap: expected joint_names as strings, got \[b'hand'\]"),
        (lambda log: log.forecast(0.0, [1.0], np.zeros((1, 2, 1, 3)), np.ones((1, 2, 1, 3)),
                                  [None], 0.1), DataError,
         r"w.mcap: expected action_names as strings, got \[None\]"),
        (lambda log: log.frame_transform(0.0, "world", "cam", ("1", 0, 0)), ShapeError,
         r"expected translation \(3\) of numbers"),
        (lambda log: log.frame_transform(0.0, 5, "x"), DataError,
         r"w.mcap: expected parent a string, got 5"),
        (lambda log: log.frame_transform(0.0, "world", None), DataError,
         r"w.mcap: expected child a string, got None"),
        (lambda log: log.metrics(0.0, [1, 2]), DataError,
         r"w.mcap: expected metrics a mapping of name -> value, got \[1, 2\]"),
        (lambda log: log.task_event(0.0, "k", ["a"]), DataError,
         r"w.mcap: expected detail a mapping of name -> value, got \['a'\]"),
        (lambda log: log.robot_state(1.9e10, [1.0], [0.0], ["a"]), DataError,
         r"w.mcap: time t = 19000000000.0 s gives a log time beyond 2\^64 - 1 ns"),
        (lambda log: _scene(log, (np.zeros(3), np.full((3, 3), np.nan))), DataError,
         r"w.mcap: expected ellipsoid mean and cov finite, got mean \[0.0, 0.0, 0.0\] and "
         r"cov \[\[nan"),
        (lambda log: _scene(log, SceneEllipsoid(mean=np.zeros(3), cov=np.diag([1, np.inf, 1]))),
         DataError, r"w.mcap: expected ellipsoid mean and cov finite"),
        (lambda log: _scene(log, (np.zeros(3), np.array([np.nan, 1, 1]))), DataError,
         r"w.mcap: expected ellipsoid mean and axes finite"),
        (lambda log: _scene(log, (["a", "b", "c"], np.eye(3))), ShapeError,
         r"expected ellipsoid mean \(3\) of numbers, got \['a', 'b', 'c'\]"),
        (lambda log: _scene(log, (np.zeros(3), np.eye(3), (1, 1, 1))), ShapeError,
         r"expected ellipsoid rgba \(4\), got \(3,\)"),
        (lambda log: _scene(log, (np.zeros(3), np.eye(3), (1, 1, "x", 1))), ShapeError,
         r"expected ellipsoid rgba \(4\) of numbers"),
        (lambda log: _scene(log, (np.zeros(3), np.eye(3), (1, 1, 1, np.nan))), DataError,
         r"w.mcap: expected ellipsoid rgba in \[0, 1\], got \[1.0, 1.0, 1.0, nan\]"),
        (lambda log: _scene(log, (np.zeros(3), np.eye(3), (1, 1, 1, 1.5))), DataError,
         r"w.mcap: expected ellipsoid rgba in \[0, 1\]"),
        (lambda log: log.robot_state(1e300, [1.0], [0.0], ["a"]), DataError,
         r"w.mcap: time t = 1e\+300 s gives a log time beyond 2\^64 - 1 ns"),
        (lambda log: log.metrics(10**400, {}), DataError,
         r"w.mcap: expected a finite time t >= 0 s, got 1000"),
        (lambda log: log.robot_state(0.0, [10**400], [0.0], ["a"]), ShapeError,
         r"expected q \(J\) of numbers, got \[1000"),
        (lambda log: log.robot_state(0.0, torch.tensor([1 + 1j]), [0.0], ["a"]), ShapeError,
         r"expected q \(J\) of real numbers, got dtype torch.complex64"),
        (lambda log: log.plan(0.0, [0.0], [[1.0]], True, 10**400, 1.0), DataError,
         r"w.mcap: expected wait_s a number, got 1000"),
        (lambda log: log.plan(0.0, [0.0], [[1.0]], True, math.nan, 1.0), DataError,
         r"w.mcap: expected wait_s a finite number, got nan"),
        (lambda log: log.collision_bound(0.0, [0.0], [0.0], np.complex128(0.9 + 1j)), DataError,
         r"w.mcap: expected confidence a number, got np.complex128"),
        (lambda log: log.frame_transform(0.0, "world", "x", (math.nan, 0, 0)), DataError,
         r"w.mcap: expected translation and rotation_xyzw finite, got \[nan, 0.0, 0.0\]"),
        (lambda log: log.robot_state(0.0, [1.0], [0.0], None), DataError,
         r"w.mcap: expected joint_names a sequence of strings, got None"),
        (lambda log: log.robot_state(0.0, [1.0, 2.0], [0.0, 0.0], "ab"), DataError,
         r"w.mcap: expected joint_names a sequence of strings, got 'ab'"),
        (lambda log: log.task_event(0.0, None), DataError,
         r"w.mcap: expected kind a string, got None"),
        (lambda log: log.scene(0.0, np.zeros((1, 4)), np.zeros((1, 4)), None), ShapeError,
         r"expected ellipsoids a sequence of SceneEllipsoid or tuples, got None"),
    ],
    ids=["t_str", "t_numeric_str", "t_none", "q_str", "qd_numeric_str", "true_ragged",
         "confidence_str", "confidence_above_1", "confidence_0", "feasible_str",
         "feasible_int", "wait_s_none", "solve_ms_str",
         "dt_str", "joint_names_int", "joint_names_bytes", "action_names_none",
         "translation_str", "parent_int", "child_none", "metrics_list", "detail_list",
         "t_beyond_uint64_ns", "cov_nan", "cov_inf", "axes_nan", "mean_str", "rgba_3",
         "rgba_str", "rgba_nan", "rgba_above_1", "t_1e300", "t_huge_int", "q_huge_int",
         "q_complex_tensor", "wait_s_huge_int", "wait_s_nan", "confidence_complex",
         "translation_nan", "joint_names_none", "joint_names_one_string", "kind_none",
         "ellipsoids_none"],
)  # fmt: skip
def test_writer_arguments_of_the_wrong_type_are_named(
    tmp_path: Path, call, error: type[Exception], match: str
) -> None:
    path = tmp_path / "w.mcap"
    with EpisodeWriter(path, metadata={}) as log:
        with pytest.raises(error, match=match):
            call(log)
        log.robot_state(0.0, [1.0], [0.0], ["a"])  # the log goes on
    ep = read_episode(path)
    assert len(ep.frames["/robot/joint_state"]) == 1 and "/planner/plan" not in ep.frames


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ({"d": {"self": None}}, "nested deeper than 100 levels"),
        ({"d": {1: "a", "1": "b"}}, "keys must be strings"),
        ({"d": np.array([1 + 2j])}, "complex values are not real numbers"),
        ({"d": torch.tensor([1 + 2j])}, "complex values are not real numbers"),
    ],
    ids=["holds_itself", "int_key", "complex_array", "complex_tensor"],
)
def test_free_form_values_that_would_not_read_back_are_refused(
    tmp_path: Path, value: dict, match: str
) -> None:
    """Metadata, metrics and event details: a value that holds itself (or nests deeper than
    the reader decodes) was a RecursionError, or written so that the whole log failed to
    read; an int key read back as a string (and {1: .., "1": ..} kept one value); a complex
    array lost its imaginary parts. Each is a DataError, and the log goes on."""
    if isinstance(value["d"], dict) and "self" in value["d"]:
        value["d"]["self"] = value["d"]  # holds itself
    with pytest.raises(DataError, match=f"metadata is not JSON-serialisable: .*{match}"):
        EpisodeWriter(tmp_path / "m.mcap", metadata=value)
    path = tmp_path / "v.mcap"
    with EpisodeWriter(path, metadata={}) as log:
        log.metrics(0.0, {"x": 1.0})
        with pytest.raises(
            DataError, match=f"v.mcap: metrics is not JSON-serialisable: .*{match}"
        ):
            log.metrics(0.5, value)
        with pytest.raises(DataError, match=f"v.mcap: detail is not JSON-serialisable: .*{match}"):
            log.task_event(0.5, "k", value)
        log.metrics(1.0, {"x": 2.0})
    ep = read_episode(path)
    assert ep.complete and ep.frames["/episode/metrics"]["t"].tolist() == [0.0, 1.0]
    assert ep.events() == []


def test_values_nested_as_deep_as_allowed_read_back(tmp_path: Path) -> None:
    deep: dict = {}
    for _ in range(MAX_VALUE_DEPTH - 1):  # with the metadata dict: nested the limit deep
        deep = {"x": deep}
    with EpisodeWriter(tmp_path / "d.mcap", metadata={"d": deep}) as log:
        log.task_event(0.0, "k", deep)
    ep = read_episode(tmp_path / "d.mcap")
    assert ep.metadata == {"d": deep} and ep.events()[0]["detail"] == deep


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"path": None}, DataError, "expected path a file path .*, got NoneType None"),
        ({"chunk_size": "big"}, ConfigError, "expected chunk_size an integer >= 1, got 'big'"),
        ({"compression": ["zstd"]}, ConfigError, r"expected compression in \['lz4'"),
        ({"ellipsoid_confidence": "0.9"}, ConfigError,
         r"expected ellipsoid_confidence in \(0, 1\), got '0.9'"),
        ({"time_offset_ns": 1.5}, ConfigError, "expected time_offset_ns an integer >= 0, got 1.5"),
        ({"time_offset_ns": None}, ConfigError, "expected time_offset_ns an integer >= 0"),
    ],
    ids=["path_none", "chunk_str", "compression_list", "confidence_str", "offset_float",
         "offset_none"],
)  # fmt: skip
def test_writer_settings_of_the_wrong_type_are_config_errors(
    tmp_path: Path, kwargs: dict, error: type[Exception], match: str
) -> None:
    """They were bare TypeErrors (or, for a fractional time offset, silently rounded down)."""
    kwargs = {"path": tmp_path / "s.mcap", "metadata": {}, **kwargs}
    with pytest.raises(error, match=match):
        EpisodeWriter(**kwargs)


def test_log_forecast_index_that_is_not_an_integer_is_named(tmp_path: Path) -> None:
    mean = torch.zeros(2, 1, 2, 1, 3)
    fc = Forecast(
        weights=torch.ones(2, 1), mean=mean, var=mean + 1, dt=0.1,
        joint_names=("head",), action_names=("idle",),
    )  # fmt: skip
    with EpisodeWriter(tmp_path / "f.mcap", metadata={}) as log:
        for index in (0.5, "0", None):
            with pytest.raises(ShapeError, match=r"expected index in \[0, 2\), got"):
                log.log_forecast(0.0, fc, index)
        log.log_forecast(0.0, fc, torch.tensor(1))
    assert len(read_episode(tmp_path / "f.mcap").frames["/prediction/forecast"]) == 1


def test_log_times_stop_at_the_largest_unsigned_64_bit_time(tmp_path: Path) -> None:
    """An MCAP log time is a uint64 [ns]: a larger offset is a setting out of range, and a time
    that passes the limit with the offset is refused before anything is written."""
    with pytest.raises(ConfigError, match=r"expected time_offset_ns in \[0, 2\^64 - 1\]"):
        EpisodeWriter(tmp_path / "o.mcap", metadata={}, time_offset_ns=2**64)
    path = tmp_path / "edge.mcap"
    with EpisodeWriter(path, metadata={}, time_offset_ns=2**64 - 2_000_000_000) as log:
        log.robot_state(1.0, [1.0], [0.0], ["a"])
        with pytest.raises(DataError, match=r"edge.mcap: time t = 3.0 s gives a log time beyond"):
            log.robot_state(3.0, [2.0], [0.0], ["a"])
    ep = read_episode(path)
    assert ep.complete and ep.robot_q()[1].tolist() == [[1.0]]


def test_ellipsoid_pose_refuses_covariances_with_nan() -> None:
    with pytest.raises(DataError, match="expected cov finite, got NaN or an infinity"):
        ellipsoid_pose(np.full((2, 3, 3), np.nan), 0.95)


def test_ellipsoid_pose_refuses_covariances_that_are_no_covariances() -> None:
    """A negative definite one gave semi-axes 0 (its eigenvalues clipped) and an asymmetric
    one was symmetrised, both without a word; rounding stays accepted."""
    good = np.diag([0.04, 0.01, 0.0025])
    batch = np.stack([good, -np.eye(3) * 0.01])
    with pytest.raises(DataError, match=r"positive semi-definite, got an eigenvalue of -0.01 "
                       r"\(covariance 1 of the flattened batch\)"):  # fmt: skip
        ellipsoid_pose(batch, 0.95)
    skew = good.copy()
    skew[0, 1] = 0.005
    with pytest.raises(DataError, match=r"expected cov symmetric, .* by 0.005 \(covariance 0"):
        ellipsoid_pose(skew, 0.95)
    # the tolerance is 1e-6 of the largest entry (0.04): 1e-7 of skew or of a negative
    # eigenvalue (2.5 times it) is refused, rounding (1e-12) is not
    small_skew = good.copy()
    small_skew[0, 1] = 1e-7
    with pytest.raises(DataError, match="expected cov symmetric"):
        ellipsoid_pose(small_skew, 0.95)
    with pytest.raises(DataError, match="positive semi-definite, got an eigenvalue of -1e-07"):
        ellipsoid_pose(np.diag([0.04, 0.01, -1e-7]), 0.95)
    near = good + 1e-12 * np.array([[0, 1, 0], [0, 0, 0], [0, 0, -1]])  # rounding
    semi, _ = ellipsoid_pose(near, 0.95)
    np.testing.assert_allclose(semi, ellipsoid_pose(good, 0.95)[0], rtol=1e-9)
    assert ellipsoid_pose(np.zeros((3, 3)), 0.95)[0].tolist() == [0.0, 0.0, 0.0]


def test_a_refused_message_fixes_no_channel_names(tmp_path: Path) -> None:
    """A channel's names come from its first message that is written: a message refused for
    another argument (dt, t, the tracked array) leaves the channel free."""
    path = tmp_path / "names.mcap"
    mean = np.zeros((1, 2, 1, 3))
    with EpisodeWriter(path, metadata={}) as log:
        with pytest.raises(DataError, match="expected dt a number"):
            log.forecast(0.0, [1.0], mean, mean, ["walk"], "0.1", ["head"])
        log.forecast(0.0, [1.0], mean, mean, ["idle"], 0.1, ["hand"])
        with pytest.raises(DataError, match="expected a finite time"):
            log.robot_state(math.nan, [1.0], [0.0], ["x"])
        log.robot_state(0.0, [1.0, 2.0], [0.0, 0.0], ARM)
        with pytest.raises(ShapeError, match="expected tracked"):
            log.human_joints(0.0, np.zeros((1, 3)), np.zeros((1, 2)), ["nose"])
        log.human_joints(0.0, np.zeros((2, 3)), None, HANDS)
    ep = read_episode(path)
    _, fc = ep.forecasts()
    assert fc.action_names == ("idle",) and fc.joint_names == ("hand",)
    assert ep.frames["/robot/joint_state"]["joint_names"].tolist() == [tuple(ARM)]
    assert ep.frames["/human/joints_true"]["joint_names"].tolist() == [tuple(HANDS)]


def test_writer_takes_numpy_and_torch_scalars_and_names(tmp_path: Path) -> None:
    path = tmp_path / "np.mcap"
    with EpisodeWriter(path, metadata={}) as log:
        log.robot_state(np.float32(0.5), [1.0], [0.0], np.array(["a"]))
        log.robot_state(torch.tensor(1.0), [1.0], [0.0], ("a",))
        log.plan(0.5, [0.0], [[1.0]], np.bool_(False), np.float64(0.25), torch.tensor(3.0))
        log.plan(1.0, [0.0], [[1.0]], torch.tensor(True), 0, 1)
        log.collision_bound(0.5, [0.0], [0.0], np.float32(0.95))
    ep = read_episode(path)
    assert ep.frames["/robot/joint_state"]["joint_names"].tolist() == [("a",), ("a",)]
    assert ep.frames["/planner/plan"]["feasible"].tolist() == [False, True]
    assert ep.frames["/planner/plan"]["solve_ms"].tolist() == [3.0, 1.0]


def test_writer_path_that_is_a_folder_or_below_a_file_is_named(tmp_path: Path) -> None:
    folder = re.escape(str(tmp_path))
    with pytest.raises(DataError, match=rf"{folder}: is a folder; EpisodeWriter writes one"):
        EpisodeWriter(tmp_path, metadata={})
    (tmp_path / "notes").write_text("a file")
    for path, why in (
        (tmp_path / "notes" / "x.mcap", "it is a file"),
        (tmp_path / "notes" / "sub" / "x.mcap", "a folder above it is a file"),
    ):
        parent = re.escape(str(path.parent))
        with pytest.raises(
            DataError,
            match=rf"{re.escape(str(path))}: cannot write the episode log: {parent} is not a "
            rf"folder \({why}\)",
        ):
            EpisodeWriter(path, metadata={})
    assert (tmp_path / "notes").read_text() == "a file"


@pytest.mark.parametrize("path", [None, 3, 1.5, b"ep.mcap", ["ep.mcap"]])
def test_read_episode_of_something_not_a_path_is_a_data_error(path: object) -> None:
    """None and 3 raised a raw TypeError from pathlib."""
    with pytest.raises(DataError, match="expected path a file path .* of an .mcap episode log"):
        read_episode(path)  # type: ignore[arg-type]


def test_another_programs_tf_channel_is_read_as_theirs(tmp_path: Path) -> None:
    """``/tf`` is a common topic name (ROS bags, Foxglove's FrameTransforms). In a file with no
    episode metadata record it is that program's: a protobuf one is skipped with the warning,
    a JSON one of another layout kept as dicts. Both used to end the read with a DataError
    ("cannot decode a message on /tf")."""
    path = tmp_path / "bag.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        proto = w.register_schema("foxglove.FrameTransforms", "protobuf", b"\x0a\x01x")
        tf = w.register_channel("/tf", "protobuf", proto)
        js = w.register_schema("foxglove.FrameTransforms", "jsonschema", b"{}")
        tf_json = w.register_channel("/tf_static", "json", js)
        scene = w.register_channel("/scene", "json", js)
        for i in range(2):
            w.add_message(tf, log_time=i, data=b"\x08\x96\x01", publish_time=i)
            w.add_message(tf_json, log_time=i, data=b'{"transforms": []}', publish_time=i)
            w.add_message(scene, log_time=i, data=b'{"transforms": [1]}', publish_time=i)
        w.finish()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ep = read_episode(path)
    text = " | ".join(str(w.message) for w in caught)
    assert "not an iplanner episode log" in text and "/tf (message encoding 'protobuf')" in text
    assert ep.foreign and set(ep.frames) == {"/tf_static", "/scene"}
    assert ep.frames["/scene"]["message"].tolist() == [{"transforms": [1]}] * 2


def test_an_empty_forecast_is_refused_before_it_makes_the_log_unreadable(tmp_path: Path) -> None:
    """A forecast with no action, frame or joint was written, and the reader then refused the
    whole log ("not a multiple of 0")."""
    path = tmp_path / "f.mcap"
    with EpisodeWriter(path, metadata={}) as log:
        log.robot_state(0.0, [0.0, 0.0], [0.0, 0.0], ARM)
        for a, n_f, k in ((0, 2, 1), (1, 0, 1), (1, 2, 0)):
            with pytest.raises(ShapeError, match="at least one action, frame and joint"):
                log.forecast(0.1, np.ones(a) / max(a, 1), np.zeros((a, n_f, k, 3)),
                             np.ones((a, n_f, k, 3)), ["a"] * a, 0.1)  # fmt: skip
        log.forecast(0.2, [1.0], np.zeros((1, 2, 1, 3)), np.ones((1, 2, 1, 3)), ["a"], 0.1)
    ep = read_episode(path)
    assert ep.forecasts()[1].mean.shape == (1, 1, 2, 1, 3) and len(ep.robot_q()[0]) == 1


@pytest.mark.parametrize(
    ("weights", "mean", "message"),
    [
        ([float("nan"), 0.5], 0.0, "forecast weights is NaN/Inf for action 'a'"),
        ([0.9, 0.5], 0.0, "forecast weights of batch 0 are not probabilities"),
        ([0.5, 0.5], float("inf"), "forecast mean is NaN/Inf for joint 'joint_0'"),
        ([0.5, 0.5], 1e4, "forecast mean is 10000 m for joint 'joint_0'"),
    ],
)
def test_a_forecast_the_reader_would_refuse_is_refused_before_it_is_written(
    tmp_path: Path, weights: list[float], mean: float, message: str
) -> None:
    """A forecast with NaN weights was written without a word, and the reader, which builds
    one Forecast of all of them, then refused every forecast of the log."""
    path = tmp_path / "f.mcap"
    var = np.full((2, 2, 1, 3), 0.01)
    with EpisodeWriter(path, metadata={}) as log:
        log.forecast(0.1, [0.5, 0.5], np.zeros((2, 2, 1, 3)), var, ["a", "b"], 0.1)
        with pytest.raises(DataError, match=rf"f.mcap: forecast at t=0.2 not written: {message}"):
            log.forecast(0.2, weights, np.full((2, 2, 1, 3), mean), var, ["a", "b"], 0.1)
        log.forecast(0.3, [0.2, 0.8], np.zeros((2, 2, 1, 3)), var, ["a", "b"], 0.1)
    t, fc = read_episode(path).forecasts()
    assert t.tolist() == [0.1, 0.3] and fc.weights[1].tolist() == pytest.approx([0.2, 0.8])


def test_unencodable_metrics_and_event_details_are_data_errors(tmp_path: Path) -> None:
    """A numpy array of strings in a metric or event detail escaped as a bare ValueError, and
    the refused call had already moved the log's last time (where an interruption is put)."""
    path = tmp_path / "m.mcap"
    with pytest.raises(RuntimeError, match="stop"):
        with EpisodeWriter(path, metadata={}) as log:
            log.task_event(0.5, "picked", {"block": 1})
            with pytest.raises(DataError, match=r"m.mcap: metrics is not JSON-serialisable"):
                log.metrics(3.0, {"names": np.array(["a", "b"])})
            with pytest.raises(DataError, match=r"m.mcap: detail is not JSON-serialisable"):
                log.task_event(4.0, "picked", {"who": np.array(["a"])})
            raise RuntimeError("stop")
    events = read_episode(path).events()
    assert [(e["t"], e["kind"]) for e in events] == [(0.5, "picked"), (0.5, "interrupted")]


def test_negative_sphere_radii_and_semi_axes_are_refused(tmp_path: Path) -> None:
    with EpisodeWriter(tmp_path / "s.mcap", metadata={}) as log:
        good = np.array([[0.0, 0.0, 0.0, 0.1]])
        with pytest.raises(DataError, match=r"robot_spheres radii >= 0 \[m\], got \[-0.1\]"):
            log.scene(0.0, np.array([[0.0, 0.0, 0.0, 0.1], [1.0, 0.0, 0.0, -0.1]]), good)
        with pytest.raises(DataError, match=r"human_spheres radii >= 0"):
            log.scene(0.0, good, -good)
        with pytest.raises(DataError, match=r"semi-axes >= 0 \[m\], got \[-0.1, 0.2, 0.3\]"):
            log.scene(0.0, good, good, [(np.zeros(3), np.array([-0.1, 0.2, 0.3]))])
        nan_row = np.array([[np.nan, 0.0, 0.0, np.nan]])
        log.scene(0.0, good, nan_row)  # a NaN row is not drawn, as before


# -- free-form values of logs written before the value codec was recorded ------------------------


def test_a_log_without_a_value_codec_reads_null_and_inf_as_numbers(tmp_path: Path) -> None:
    """Such logs wrote a free-form NaN as null: metadata, metrics and details read as then."""
    path = _mcap(
        tmp_path / "old.mcap",
        [
            ("/task/events", {"t": 0.5, "kind": "k", "detail": {"gap": None, "d": "-inf"}}),
            ("/episode/metrics", {"t": 1.0, "metrics": {"mhd": None, "x": "inf", "s": "~a"}}),
        ],
        metadata={"nan": None, "inf": "inf"},
    )
    ep = read_episode(path)
    assert math.isnan(ep.metadata["nan"]) and ep.metadata["inf"] == math.inf
    detail = ep.events()[0]["detail"]
    assert math.isnan(detail["gap"]) and detail["d"] == -math.inf
    m = ep.metrics()
    assert math.isnan(m["mhd"]) and m["x"] == math.inf and m["s"] == "~a"


def test_a_damaged_metadata_record_names_the_time_offset_it_drops(tmp_path: Path) -> None:
    """The writer's time offset lives in the metadata record: when its checksum fails the
    offset is dropped with the rest, and the warning says that the scene's times (taken from
    log times) then count from log time 0."""
    path = tmp_path / "offset.mcap"
    with EpisodeWriter(path, metadata={"planner": "itomp"}, time_offset_ns=5_000_000_000) as log:
        log.robot_state(1.0, [1.0, 2.0], [0, 0], ARM)
        log.scene(1.0, np.zeros((1, 4)), np.zeros((1, 4)), [])
    assert read_episode(path).frames["/scene"]["t"].tolist() == [1.0]
    data = path.read_bytes()
    i = data.index(b'"planner"') + 1
    path.write_bytes(data[:i] + b"P" + data[i + 1 :])
    said = r"checksum \(dropped\); its time offset \('5000000000' ns\) is not trusted either: "
    with pytest.warns(DataWarning, match=said + "times count from log time 0"):
        ep = read_episode(path)
    assert ep.metadata == {} and ep.frames["/scene"]["t"].tolist() == [6.0]
    assert ep.frames["/robot/joint_state"]["t"].tolist() == [1.0]  # its own time field


def test_a_value_codec_this_version_does_not_read_is_named(tmp_path: Path) -> None:
    from iplanner_torch.recording.reader import metadata_crc

    text = json.dumps({"a": 1})
    record = {"json": text, "time_offset_ns": "0", "value_codec": "9"}
    record["crc32"] = str(metadata_crc(text, "0", "9"))
    path = _mcap(tmp_path / "new.mcap", [], record=record)
    with pytest.raises(DataError, match=r"value codec '9' is not one this version reads"):
        read_episode(path)


def test_a_changed_value_codec_fails_the_metadata_checksum(tmp_path: Path) -> None:
    """The codec is part of the record's checksum: a log whose codec was changed is read as
    damaged (its metadata dropped, with a warning), and its values as the codec this version
    writes (the only one that records itself)."""
    path = tmp_path / "ours.mcap"
    with EpisodeWriter(path, metadata={"planner": "itomp"}) as log:
        log.metrics(1.0, {"x": "inf"})
    data = path.read_bytes()
    assert data.count(b"value_codec") == 1
    i = data.index(b"value_codec") + len(b"value_codec") + 4  # the u32 length of the value
    assert data[i : i + 1] == b"2"
    path.write_bytes(data[:i] + b"1" + data[i + 1 :])
    with pytest.warns(DataWarning, match="episode metadata fails its checksum"):
        ep = read_episode(path)
    assert ep.metadata == {} and not ep.complete
    assert ep.metrics()["x"] == "inf"  # the string, as written
