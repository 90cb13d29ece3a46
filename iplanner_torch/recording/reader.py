"""read_episode: an episode's MCAP log back as pandas frames and tensors.

A complete file is read through its summary (indexed reader), after checking the summary's
checksum. A file without summary or footer (an episode killed midway) or with a damaged
record or summary is read sequentially up to the last complete chunk, with a
:class:`~iplanner_torch.errors.DataWarning`. Channels of other tools are kept when they are
JSON-encoded (one ``message`` column), and skipped, with a ``DataWarning``, when they are not.
A complete MCAP file with no ``iplanner.episode`` metadata record is another program's file,
not an episode log: it is read, marked ``Episode.foreign`` (and incomplete), with a
``DataWarning`` saying so (not one saying it is truncated).

Numeric arrays are read in either form a writer has used: flat and row-major with finite
numbers, human joints as ``{joint, x, y, z}`` objects (a joint left out of a message reads as
NaN), as the writer writes them now; or nested, with NaN as ``null`` and infinities as
``"inf"`` / ``"-inf"``, every joint a row, as earlier writers wrote them.

Scene spheres: the writer leaves out sphere rows with NaN or an infinity (Foxglove draws no NaN
sphere) and then names, in the entity's metadata, the number of rows (``sphere_count``) and
the rows of its spheres in order (``sphere_rows``, comma-separated indices), so every sphere
is read back in its slot and the rows left out are NaN. An entity without them (every row
drawn, or a log of an earlier writer) is read as it is. A ``sphere_count`` above 2^20 rows is
taken as damage (a ``DataError``), not allocated.
"""

from __future__ import annotations

import functools
import json
import math
import reprlib
import struct
import warnings
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import (
    Channel,
    Chunk,
    DataEnd,
    Footer,
    McapRecord,
    Message,
    Metadata,
    Statistics,
)
from mcap.stream_reader import StreamReader, breakup_chunk

from iplanner_torch.checks import path_argument
from iplanner_torch.errors import DataError, DataWarning
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.recording.codec import (
    VALUE_CODEC,
    VALUE_CODECS,
    decode_array,
    decode_scalar,
    decode_value,
    loads,
)

__all__ = [
    "Episode",
    "read_episode",
    "EPISODE_METADATA_NAME",
    "SPHERE_COUNT_KEY",
    "SPHERE_ROWS_KEY",
    "metadata_crc",
]

#: Name of the MCAP metadata record holding the episode's metadata dict.
EPISODE_METADATA_NAME = "iplanner.episode"
#: Scene entity metadata keys: the number of sphere rows, and the rows its spheres are.
SPHERE_COUNT_KEY = "sphere_count"
SPHERE_ROWS_KEY = "sphere_rows"
#: the most sphere rows a scene entity's ``sphere_count`` may name (more is taken as damage)
_MAX_SPHERE_ROWS = 2**20
_MAGIC = b"\x89MCAP0\r\n"
#: the largest log time an MCAP record holds (an unsigned 64-bit integer) [ns]
_MAX_LOG_TIME_NS = 2**64 - 1
#: how a Git LFS pointer file (left where a file was never fetched) begins
_LFS_POINTER = b"version https://git-lfs.github.com/spec/"


def metadata_crc(json_text: str, time_offset_ns: str, value_codec: str | None = None) -> int:
    """CRC-32 of the episode metadata record's ``json``, ``time_offset_ns`` and (in logs that
    record it) ``value_codec`` values, stored beside them as ``crc32`` (MCAP metadata records
    have no checksum of their own)."""
    text = f"{time_offset_ns}\n{json_text}"
    if value_codec is not None:
        text = f"{value_codec}\n{text}"
    return zlib.crc32(text.encode())


def _t_of_stamp(stamp: dict[str, int], offset_ns: int) -> float:
    sec, nsec = stamp["sec"], stamp["nsec"]
    for v in (sec, nsec):  # a string or a list would be repeated 10^9 times below
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ValueError(f"timestamp sec and nsec must be numbers, got {reprlib.repr(stamp)}")
    return (sec * 1_000_000_000 + nsec - offset_ns) * 1e-9


def _sphere_slots(entity: dict[str, Any], n_drawn: int) -> tuple[int, list[int]] | None:
    """``(S, the rows of the drawn spheres)`` from an entity's metadata, or None when it does
    not name them (every row was drawn)."""
    pairs = entity.get("metadata") or []
    meta = {kv.get("key"): kv.get("value") for kv in pairs if isinstance(kv, dict)}
    if SPHERE_ROWS_KEY not in meta:
        return None
    count, rows = meta.get(SPHERE_COUNT_KEY), meta[SPHERE_ROWS_KEY]
    if not isinstance(count, str) or not isinstance(rows, str):
        raise ValueError(
            f"scene entity {SPHERE_COUNT_KEY!r} and {SPHERE_ROWS_KEY!r} must be strings"
        )
    n = int(count)
    if n > _MAX_SPHERE_ROWS:  # each row is allocated: a damaged count must not take the memory
        raise ValueError(
            f"scene entity {entity.get('id')!r}: {SPHERE_COUNT_KEY} {reprlib.repr(count)} is "
            f"more than {_MAX_SPHERE_ROWS} rows"
        )
    idx = [int(i) for i in rows.split(",")] if rows else []
    if (
        len(idx) != n_drawn
        or any(b <= a for a, b in zip(idx, idx[1:]))
        or (idx and not (0 <= idx[0] and idx[-1] < n))
    ):
        raise ValueError(
            f"scene entity {entity.get('id')!r}: {SPHERE_ROWS_KEY} {rows!r} are not "
            f"{n_drawn} increasing rows of {SPHERE_COUNT_KEY} {count!r}"
        )
    return n, idx


def _sphere_rows(entity: dict[str, Any]) -> np.ndarray:
    """(S, 4) centres and radii of an entity's spheres (radius = size.x / 2), each in its row;
    rows the writer left out (NaN) are NaN."""
    rows = [
        [
            s["pose"]["position"]["x"],
            s["pose"]["position"]["y"],
            s["pose"]["position"]["z"],
            0.5 * s["size"]["x"],
        ]
        for s in entity["spheres"]
    ]
    drawn = np.array(rows, dtype=np.float64).reshape(len(rows), 4)
    slots = _sphere_slots(entity, len(rows))
    if slots is None:
        return drawn
    n, idx = slots
    out = np.full((n, 4), np.nan)
    out[idx] = drawn
    return out


def _ellipsoid_rows(entity: dict[str, Any]) -> list[dict[str, np.ndarray]]:
    out = []
    for s in entity["spheres"]:
        p, o, z, c = s["pose"]["position"], s["pose"]["orientation"], s["size"], s["color"]
        out.append(
            {
                "position": np.array([p["x"], p["y"], p["z"]]),
                "semi_axes": 0.5 * np.array([z["x"], z["y"], z["z"]]),
                "quaternion_xyzw": np.array([o["x"], o["y"], o["z"], o["w"]]),
                "rgba": np.array([c["r"], c["g"], c["b"], c["a"]]),
            }
        )
    return out


def _number(m: dict[str, Any], key: str) -> float:
    """``m[key]`` as a float: a JSON number, or null (NaN) / "inf" as the codec writes them;
    anything else (a string, a bool, a list) is a ValueError."""
    v = decode_scalar(m[key])
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ValueError(f"field {key!r} must be a number, got {m[key]!r}")
    return float(v)


def _names(m: dict[str, Any], key: str) -> tuple[str, ...]:
    v = m[key]
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise ValueError(f"field {key!r} must be a list of strings, got {v!r}")
    return tuple(v)


def _sized(m: dict[str, Any], key: str, shape: tuple[int, ...]) -> np.ndarray:
    """``m[key]`` decoded and of exactly ``shape`` (-1: any size on that axis)."""
    x = decode_array(m[key])
    n_fixed = math.prod(n for n in shape if n >= 0)
    if -1 in shape:
        free = x.size // n_fixed if n_fixed else 0
        if n_fixed == 0 or x.size % n_fixed or free == 0:
            raise ValueError(f"field {key!r} has {x.size} values, not a multiple of {n_fixed}")
        shape = tuple(free if n < 0 else n for n in shape)
    if x.size != math.prod(shape):
        raise ValueError(f"field {key!r} has {x.size} values, expected shape {shape}")
    return x.reshape(shape)


def _row_joint_state(m: dict[str, Any], _: int) -> dict[str, Any]:
    names = _names(m, "joint_names")
    return {
        "t": _number(m, "t"),
        "q": _sized(m, "position", (len(names),)),
        "qd": _sized(m, "velocity", (len(names),)),
        "joint_names": names,
    }


def _joint_positions(m: dict[str, Any], names: tuple[str, ...]) -> np.ndarray:
    """(K, 3) positions of ``m["positions"]``: objects ``{joint, x, y, z}`` of the joints that
    have one (the others NaN), or, in logs of earlier writers, a (K, 3) nested list."""
    items = m["positions"]
    if not (isinstance(items, list) and all(isinstance(i, dict) for i in items)):
        return _sized(m, "positions", (len(names), 3))  # a nested list
    index = {n: k for k, n in enumerate(names)}
    out = np.full((len(names), 3), np.nan)
    for item in items:
        k = index.get(item.get("joint"))  # type: ignore[arg-type]
        if k is None or not np.isnan(out[k, 0]):
            raise ValueError(
                f"field 'positions' names joint {item.get('joint')!r}, which is not one of "
                f"joint_names or comes twice"
            )
        out[k] = [_number(item, c) for c in "xyz"]
    return out


def _row_human(m: dict[str, Any], _: int) -> dict[str, Any]:
    names = _names(m, "joint_names")
    p = _joint_positions(m, names)
    return {"t": _number(m, "t"), "positions": p, "joint_names": names}


def _row_forecast(m: dict[str, Any], _: int) -> dict[str, Any]:
    actions, joints = _names(m, "action_names"), _names(m, "joint_names")
    a, k = len(actions), len(joints)
    mean = _sized(m, "mean", (a, -1, k, 3))
    return {
        "t": _number(m, "t"),
        "dt": _number(m, "dt"),
        "weights": _sized(m, "weights", (a,)),
        "mean": mean,
        "var": _sized(m, "var", mean.shape),
        "action_names": actions,
        "joint_names": joints,
    }


def _row_bound(m: dict[str, Any], _: int) -> dict[str, Any]:
    times = decode_array(m["times"])
    return {
        "t": _number(m, "t"),
        "times": times,
        "bound": _sized(m, "bound", times.shape),
        "confidence": _number(m, "confidence"),
        "max_bound": _number(m, "max_bound") if "max_bound" in m else math.nan,
    }


def _row_plan(m: dict[str, Any], _: int) -> dict[str, Any]:
    times = decode_array(m["times"])
    q = decode_array(m["q"])
    if q.size % max(times.shape[0], 1):
        raise ValueError(f"field 'q' has {q.size} values for {times.shape[0]} times")
    if not isinstance(m["feasible"], bool):
        raise ValueError(f"field 'feasible' must be true or false, got {m['feasible']!r}")
    return {
        "t": _number(m, "t"),
        "times": times,
        "q": q.reshape(times.shape[0], -1) if q.size else q.reshape(times.shape[0], 0),
        "feasible": m["feasible"],
        "wait_s": _number(m, "wait_s"),
        "solve_ms": _number(m, "solve_ms"),
    }


def _row_event(m: dict[str, Any], _: int, codec: str = VALUE_CODEC) -> dict[str, Any]:
    if not isinstance(m["kind"], str):
        raise ValueError(f"field 'kind' must be a string, got {m['kind']!r}")
    return {"t": _number(m, "t"), "kind": m["kind"], "detail": decode_value(m["detail"], codec)}


def _row_metrics(m: dict[str, Any], _: int, codec: str = VALUE_CODEC) -> dict[str, Any]:
    if not isinstance(m["metrics"], dict):
        raise ValueError(f"field 'metrics' must be an object, got {m['metrics']!r}")
    return {"t": _number(m, "t"), "metrics": decode_value(m["metrics"], codec)}


#: Decoders whose free-form values depend on the log's value codec (passed as ``codec``).
_CODEC_TOPICS = ("/task/events", "/episode/metrics")


def _row_scene(m: dict[str, Any], offset_ns: int) -> dict[str, Any]:
    by_id = {e["id"]: e for e in m["entities"]}
    t = _t_of_stamp(m["entities"][0]["timestamp"], offset_ns) if m["entities"] else math.nan
    empty = {"spheres": []}
    return {
        "t": t,
        "robot_spheres": _sphere_rows(by_id.get("robot", empty)),
        "human_spheres": _sphere_rows(by_id.get("human", empty)),
        "ellipsoids": _ellipsoid_rows(by_id.get("prediction", empty)),
    }


def _row_tf(m: dict[str, Any], offset_ns: int) -> dict[str, Any]:
    tr, r = m["translation"], m["rotation"]
    return {
        "t": _t_of_stamp(m["timestamp"], offset_ns),
        "parent_frame_id": m["parent_frame_id"],
        "child_frame_id": m["child_frame_id"],
        "translation": np.array([tr["x"], tr["y"], tr["z"]]),
        "rotation_xyzw": np.array([r["x"], r["y"], r["z"], r["w"]]),
    }


_ROW_DECODERS: dict[str, Callable[[dict[str, Any], int], dict[str, Any]]] = {
    "/tf": _row_tf,
    "/robot/joint_state": _row_joint_state,
    "/human/joints_true": _row_human,
    "/human/joints_tracked": _row_human,
    "/prediction/forecast": _row_forecast,
    "/planner/bound": _row_bound,
    "/planner/plan": _row_plan,
    "/task/events": _row_event,
    "/episode/metrics": _row_metrics,
    "/scene": _row_scene,
}


def _is_read(channel: Channel) -> bool:
    """Whether the messages of ``channel`` are decoded: those of an episode-log topic (which
    must then be JSON in an episode log) and JSON messages of any other topic (kept as dicts).
    In another program's file (no episode metadata record) our topic names are not ours:
    see :meth:`_Raw.drop_foreign_topics`."""
    return channel.topic in _ROW_DECODERS or channel.message_encoding == "json"


def _stack(arrays: list[np.ndarray]) -> np.ndarray:
    """Stack arrays of equal rank; ragged sizes are padded with NaN to the largest."""
    if not arrays:
        return np.zeros((0,))
    shapes = {a.shape for a in arrays}
    if len(shapes) == 1:
        return np.stack(arrays)
    ranks = {len(s) for s in shapes}
    if len(ranks) != 1:
        raise DataError(f"cannot stack arrays of different ranks: {sorted(shapes)}")
    full = tuple(max(s[i] for s in shapes) for i in range(ranks.pop()))
    out = np.full((len(arrays), *full), np.nan)
    for i, a in enumerate(arrays):
        out[(i, *(slice(0, n) for n in a.shape))] = a
    return out


@dataclass
class Episode:
    """One episode log, decoded.

    Attributes:
        path: the file read.
        metadata: the dict given to ``EpisodeWriter(metadata=...)`` (NaN and infinities
            included; ``None`` reads back as NaN, as in metrics).
        frames: topic -> DataFrame with one row per message in file order, a ``t`` column
            (simulation time [s]) and array-valued columns (e.g. ``/robot/joint_state`` has
            ``q`` and ``qd``, each a (J,) array per row).
        complete: whether every data record is there: False when the file was cut or
            damaged before the end of its data section (it is then read up to its last
            complete chunk), or its episode metadata record is missing. A file cut or damaged
            only in its summary section is complete (and read with a warning). An episode
            stopped by Ctrl-C or an error closes its file properly: that log is complete,
            and :attr:`interrupted` says the episode is not.
        foreign: whether the file is another program's MCAP file rather than an episode log:
            every data record is there but no ``iplanner.episode`` metadata record
            (:data:`EPISODE_METADATA_NAME`) is (``complete`` is then False: which episode it
            is, is unknown). A file cut before that record is not foreign but incomplete.
    """

    path: Path
    metadata: dict[str, Any]
    frames: dict[str, pd.DataFrame] = field(default_factory=dict)
    complete: bool = True
    foreign: bool = False

    def _frame(self, topic: str) -> pd.DataFrame:
        df = self.frames.get(topic)
        if df is None or len(df) == 0:
            raise DataError(f"{self.path}: no messages on {topic}")
        if "message" in df.columns:  # kept as dicts: the file has no episode metadata record
            raise DataError(
                f"{self.path}: the messages on {topic} are not decoded (no "
                f"{EPISODE_METADATA_NAME} metadata record: not an episode log, or a damaged "
                f"one); they are in frames[{topic!r}]['message']"
            )
        return df

    def _constant_names(self, topic: str, column: str) -> tuple[str, ...]:
        """The names in ``column`` (joint or action names) of the messages on ``topic``.

        Raises:
            DataError: when they change between messages (arrays of messages with other
                names must not be stacked: their columns are other joints), naming the
                channel and the first two name lists that differ.
        """
        df = self._frame(topic)
        names = df[column]
        first = names.iloc[0]
        for i, other in enumerate(names):
            if other != first:
                t = df["t"]
                raise DataError(
                    f"{self.path}: {column} changes between messages on {topic}: "
                    f"{list(first)} at t={t.iloc[0]:g} s, then {list(other)} at t={t.iloc[i]:g} s"
                )
        return first

    def _series(
        self, topic: str, column: str, dtype: torch.dtype, names: str | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(t (T,), the arrays of column stacked (T, ...))``.

        ``names``: the column of the names of the arrays' rows (joint names), which must be
        the same in every message (see :meth:`_constant_names`); None: not checked.
        """
        df = self._frame(topic)
        if names is not None:
            self._constant_names(topic, names)
        t = torch.as_tensor(df["t"].to_numpy(dtype=np.float64, copy=True), dtype=dtype)
        return t, torch.as_tensor(_stack(list(df[column])), dtype=dtype)

    def robot_q(self, dtype: torch.dtype = torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
        """``(t (T,) [s], q (T, J) [rad])`` from ``/robot/joint_state`` (float64 by default).

        Raises:
            DataError: when there are no messages, or the joint names change between them
                (also in :meth:`robot_qd`, :meth:`human_true` and :meth:`human_tracked`).
        """
        return self._series("/robot/joint_state", "q", dtype, names="joint_names")

    def robot_qd(self, dtype: torch.dtype = torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
        """``(t (T,) [s], qd (T, J) [rad/s])`` from ``/robot/joint_state``."""
        return self._series("/robot/joint_state", "qd", dtype, names="joint_names")

    def human_true(self, dtype: torch.dtype = torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
        """``(t (T,) [s], positions (T, K, 3) [m])`` of the ground-truth human joints."""
        return self._series("/human/joints_true", "positions", dtype, names="joint_names")

    def human_tracked(
        self, dtype: torch.dtype = torch.float64
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(t (T,) [s], positions (T, K, 3) [m])`` of the tracker output (NaN: dropout)."""
        return self._series("/human/joints_tracked", "positions", dtype, names="joint_names")

    def forecasts(self, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, Forecast]:
        """All forecasts as one :class:`Forecast` whose batch axis is time.

        Returns:
            ``(t (T,) [s], forecast)`` with ``forecast.weights`` (T, A) and ``forecast.mean``,
            ``forecast.var`` (T, A, n_f, K, 3); ``t`` is float64.

        Raises:
            DataError: when there are no forecasts, or actions, joints, dt or the horizon
                change over time.
        """
        df = self._frame("/prediction/forecast")
        actions = self._constant_names("/prediction/forecast", "action_names")
        joints = self._constant_names("/prediction/forecast", "joint_names")
        if df["dt"].nunique(dropna=False) != 1:
            raise DataError(f"{self.path}: dt changes between forecasts")
        if len({m.shape for m in df["mean"]}) != 1:
            raise DataError(f"{self.path}: the forecast horizon changes between forecasts")
        t = torch.as_tensor(df["t"].to_numpy(dtype=np.float64, copy=True))
        fc = Forecast(
            weights=torch.as_tensor(_stack(list(df["weights"])), dtype=dtype),
            mean=torch.as_tensor(_stack(list(df["mean"])), dtype=dtype),
            var=torch.as_tensor(_stack(list(df["var"])), dtype=dtype),
            dt=float(df["dt"].iloc[0]),
            joint_names=joints,
            action_names=actions,
        )
        return t, fc

    def bounds(
        self, dtype: torch.dtype = torch.float64
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(t (T,), times (T, W), bound (T, W), confidence (T,))`` (ragged W: NaN-padded)."""
        df = self._frame("/planner/bound")
        t, times = self._series("/planner/bound", "times", dtype)
        bound = torch.as_tensor(_stack(list(df["bound"])), dtype=dtype)
        conf = torch.as_tensor(df["confidence"].to_numpy(dtype=np.float64, copy=True), dtype=dtype)
        return t, times, bound, conf

    def scene_spheres(
        self, dtype: torch.dtype = torch.float64
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(t (T,), robot (T, S_r, 4), human (T, S_h, 4))`` sphere centres and radii [m].

        Each sphere is in the row it was given to ``EpisodeWriter.scene``; rows that had NaN
        or an infinity are NaN (as are rows past a message's own count when counts differ).
        """
        df = self._frame("/scene")
        t, robot = self._series("/scene", "robot_spheres", dtype)
        human = torch.as_tensor(_stack(list(df["human_spheres"])), dtype=dtype)
        return t, robot, human

    def events(self) -> list[dict[str, Any]]:
        """Task events in file order, each ``{"t": ..., "kind": ..., "detail": {...}}``."""
        df = self.frames.get("/task/events")
        return [] if df is None else df.to_dict("records")

    @property
    def interrupted(self) -> bool:
        """Whether the episode was stopped before its end (Ctrl-C, an exception): its
        writer, closed on the error, logged an ``interrupted`` task event. Such a file is
        whole (``complete`` can be True) but the episode is not: it has no metrics."""
        df = self.frames.get("/task/events")
        return (
            df is not None and "kind" in df.columns and bool((df["kind"] == "interrupted").any())
        )

    def metrics(self) -> dict[str, Any]:
        """The last ``/episode/metrics`` message's dict ({} when none was logged)."""
        df = self.frames.get("/episode/metrics")
        if df is None or len(df) == 0:
            return {}
        return dict(self._frame("/episode/metrics")["metrics"].iloc[-1])


@dataclass
class _Raw:
    """Records of a file before decoding."""

    messages: list[tuple[str, int, bytes]] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    #: channels skipped (see :func:`_is_read`): "topic (message encoding ...)" -> messages
    skipped: dict[str, int] = field(default_factory=dict)
    complete: bool = False
    problem: str = ""

    #: topic -> message encoding of the channels read
    encodings: dict[str, str] = field(default_factory=dict)

    def skip(self, channel: Channel) -> None:
        """Count a message of a channel that is not read."""
        key = f"{channel.topic} (message encoding {channel.message_encoding!r})"
        self.skipped[key] = self.skipped.get(key, 0) + 1

    def keep(self, channel: Channel, log_time: int, data: bytes) -> None:
        """Keep a message of a channel that is read."""
        self.messages.append((channel.topic, log_time, data))
        self.encodings[channel.topic] = channel.message_encoding

    def drop_foreign_topics(self) -> None:
        """In another program's file, a topic that shares an episode-log name (``/tf`` is
        common) is that program's: skipped unless JSON (then kept as dicts)."""
        kept = []
        for topic, log_time, data in self.messages:
            encoding = self.encodings.get(topic, "json")
            if topic in _ROW_DECODERS and encoding != "json":
                key = f"{topic} (message encoding {encoding!r})"
                self.skipped[key] = self.skipped.get(key, 0) + 1
            else:
                kept.append((topic, log_time, data))
        self.messages = kept


#: bytes of the footer record (opcode, length, summary_start, summary_offset_start, crc)
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4


def _check_summary_crc(f: Any) -> None:
    """Raise DataError when the footer's summary CRC does not match the summary section (the
    mcap reader does not check it, and a damaged index would drop or rename data silently).
    A CRC of 0 means none was written."""
    f.seek(0, 2)
    n = f.tell()
    if n < len(_MAGIC) * 2 + _FOOTER_SIZE:
        raise DataError("too short for a footer")
    f.seek(n - len(_MAGIC))
    if f.read(len(_MAGIC)) != _MAGIC:  # (a file cut short ends in the middle of a record)
        raise DataError("no closing magic bytes: the file ends before its footer")
    f.seek(n - len(_MAGIC) - _FOOTER_SIZE)
    footer = f.read(_FOOTER_SIZE)
    if footer[0] != 0x02:
        raise DataError("no footer record before the closing magic bytes")
    start = int.from_bytes(footer[9:17], "little")
    crc = int.from_bytes(footer[25:29], "little")
    if start == 0 or crc == 0:
        return
    if not len(_MAGIC) <= start <= n - len(_MAGIC) - _FOOTER_SIZE:
        raise DataError(f"the footer places the summary section at byte {start}, outside the file")
    f.seek(start)
    covered = f.read(n - len(_MAGIC) - 4 - start)
    if zlib.crc32(covered) != crc:
        raise DataError("summary section fails its checksum")


def _read_indexed(f: Any) -> _Raw:
    _check_summary_crc(f)
    f.seek(0)
    reader = make_reader(f, validate_crcs=True)
    summary = reader.get_summary()
    if summary is None:
        raise DataError("no summary section")
    raw = _Raw(complete=True)
    n_read = 0
    for _, channel, message in reader.iter_messages(log_time_order=False):
        n_read += 1
        if _is_read(channel):
            raw.keep(channel, message.log_time, message.data)
        else:
            raw.skip(channel)
    # a chunk whose checksum field was zeroed ("none written") and whose compression name was
    # damaged is taken as uncompressed by the mcap reader, and its messages vanish silently
    counted = summary.statistics.message_count if summary.statistics else None
    if counted is not None and counted != n_read:
        raise DataError(f"the chunks hold {n_read} messages, the summary counts {counted}")
    for m in reader.iter_metadata():
        raw.metadata[m.name] = dict(m.metadata)
    return raw


#: the chunk compressions of MCAP ("": none)
_COMPRESSIONS = ("", "zstd", "lz4")


def _stream_records(f: Any, size: int) -> Iterator[McapRecord]:
    """The records of a file in order, each chunk's records in its place. A chunk of another
    compression is a DataError: the mcap reader takes it as uncompressed, and one whose
    compression name and checksum field (0: none written) were damaged lost its messages
    silently."""
    for record in StreamReader(
        f, validate_crcs=True, emit_chunks=True, record_size_limit=max(size, 1)
    ).records:
        if isinstance(record, Chunk):
            if record.compression not in _COMPRESSIONS:
                raise DataError(f"a chunk has unknown compression {record.compression!r}")
            yield from breakup_chunk(record, validate_crc=True)
        else:
            yield record


def _error_text(err: BaseException) -> str:
    """``"Type: message"``. A MemoryError or OverflowError comes from the mcap library
    reading the bytes that a damaged length field declares ("byte string is too large", or
    no message at all): it says so."""
    text = str(err).strip()
    if isinstance(err, DataError) and text:  # our own words already
        return text
    if isinstance(err, EndOfFile | struct.error):  # the mcap library ran out of bytes
        return "the last record is cut short (the file ends inside it)"
    if isinstance(err, MemoryError | OverflowError):
        text = "a length field declares more bytes than can be read (damaged)" + (
            f" ({text})" if text else ""
        )
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def _read_stream(f: Any, size: int) -> _Raw:
    """Every record in file order, up to the first that does not read. The data section
    read in full (its end record and the footer reached) is complete unless the summary's
    statistics count other messages than were read: a chunk removed or repeated, whose own
    checksum holds, leaves the summary's (and its offsets) wrong but the stream readable."""
    raw = _Raw()
    channels: dict[int, Channel] = {}
    records = _stream_records(f, size)
    n_read, counted = 0, None
    while True:
        try:
            record = next(records)
        except StopIteration:
            break
        except Exception as err:  # truncated or damaged record: keep what came before it
            raw.problem = _error_text(err)
            break
        if isinstance(record, Statistics):
            counted = record.message_count
        if isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            n_read += 1
            ch = channels.get(record.channel_id)
            if ch is not None and _is_read(ch):
                raw.keep(ch, record.log_time, record.data)
            elif ch is not None:
                raw.skip(ch)
        elif isinstance(record, Metadata):
            raw.metadata[record.name] = dict(record.metadata)
        elif isinstance(record, DataEnd | Footer):  # every data record has been read
            raw.complete = True
    if raw.complete and counted is not None and counted != n_read:
        raw.complete = False
        mismatch = f"the chunks hold {n_read} messages, the summary counts {counted}"
        raw.problem = f"{raw.problem}; {mismatch}" if raw.problem else mismatch
    return raw


def read_episode(path: str | Path) -> Episode:
    """Read an episode log written by ``EpisodeWriter``.

    Args:
        path: the ``.mcap`` file.

    Returns:
        The decoded :class:`Episode`.

    Raises:
        DataError: when ``path`` is not a file path (str or os.PathLike), the file is missing
            or unreadable, is not MCAP, its metadata is not a JSON object (or its time offset
            not in [0, 2^64 - 1] ns), or a message cannot be decoded (not JSON or nested too
            deep, a field missing or of the wrong type, a number too large for a float, or an
            array whose size does not fit its joint or action names).

    Warns:
        DataWarning: when the file is truncated or damaged (a chunk or the summary failing its
            checksum, a chunk of unknown compression, fewer or more messages than the summary
            counts, a missing footer, an episode metadata record failing its checksum); the
            episode then holds the messages of every chunk before the damage (a prefix of what
            was written). A metadata record failing its checksum is dropped whole, its time
            offset too: the times taken from log times (``/scene``, ``/tf``, other tools'
            channels) then count from log time 0, which the warning says when the offset was
            not 0 (the episode commands write 0). A file cut within its first 8 bytes (empty
            included) is an empty, incomplete episode. A complete MCAP file with no episode
            metadata record is not an episode log (another program's): it is read, ``foreign``
            and incomplete, with a warning saying so. Also (one warning naming them) when
            channels are skipped: those of other tools whose messages are not JSON (protobuf,
            raw bytes); other tools' JSON channels are read into frames with one ``message``
            column.
    """
    path = path_argument(path, "of an .mcap episode log")
    if path.is_dir():
        raise DataError(
            f"{path}: is a folder; read_episode reads one .mcap file "
            "(eval.report.gather_results reads every log below a folder)"
        )
    if not path.is_file():
        raise DataError(f"{path}: no such episode log")
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(len(_MAGIC))
            if head != _MAGIC and not (len(head) < len(_MAGIC) and _MAGIC.startswith(head)):
                f.seek(0)
                if f.read(len(_LFS_POINTER)) == _LFS_POINTER:
                    raise DataError(
                        f"{path} is not an MCAP file (bad magic bytes); it is a Git LFS "
                        "pointer, the log never fetched: run `git lfs pull`"
                    )
                raise DataError(f"{path} is not an MCAP file (bad magic bytes)")
            if head != _MAGIC:  # cut within the opening magic bytes: nothing was written
                raw = _Raw(problem=f"{size} bytes, cut within the opening magic bytes")
            else:
                f.seek(0)
                try:
                    raw = _read_indexed(f)
                except Exception as err:  # no or damaged summary: read sequentially
                    f.seek(0)
                    raw = _read_stream(f, size)
                    first = _error_text(err)
                    raw.problem = (
                        f"{first}; read record by record: {raw.problem}" if raw.problem else first
                    )
    except OSError as err:
        raise DataError(f"{path}: cannot read the episode log: {err}") from err
    # the episode metadata record is written before any message: a file without it is
    # another program's, whose topics may share our names (/tf) but not our layouts
    ours = EPISODE_METADATA_NAME in raw.metadata
    if not ours:
        raw.drop_foreign_topics()
    meta_rec = raw.metadata.get(EPISODE_METADATA_NAME, {})
    # logs before the value codec was recorded wrote free-form values with codec "1"
    codec = meta_rec.get("value_codec", "1")
    if "crc32" in meta_rec and meta_rec["crc32"] != str(
        metadata_crc(
            meta_rec.get("json", ""),
            meta_rec.get("time_offset_ns", "0"),
            meta_rec.get("value_codec"),
        )
    ):
        damaged = "episode metadata fails its checksum (dropped)"
        if meta_rec.get("time_offset_ns", "0") != "0":  # which part was damaged is unknown
            damaged += (
                f"; its time offset ({reprlib.repr(meta_rec['time_offset_ns'])} ns) is not "
                "trusted either: times count from log time 0"
            )
        meta_rec = {}  # its values cannot be trusted
        # the best guess left: only writers of codec "2" record one
        codec = VALUE_CODEC if "value_codec" in raw.metadata[EPISODE_METADATA_NAME] else "1"
        raw.problem = "; ".join(p for p in (raw.problem, damaged) if p)
        raw.complete = False
    foreign = raw.complete and EPISODE_METADATA_NAME not in raw.metadata
    if foreign:  # every record read, none of them ours: another program's MCAP file
        raw.complete = False  # which episode it is is unknown: counted with the incomplete ones
        warnings.warn(
            f"{path}: not an iplanner episode log: a valid MCAP file with no "
            f"{EPISODE_METADATA_NAME} metadata record (written by another program?)"
            + (f"; also {raw.problem}" if raw.problem else "")
            + f"; read {len(raw.messages)} messages of its channels",
            DataWarning,
            stacklevel=2,
        )
    elif not raw.complete or raw.problem:
        warnings.warn(
            f"{path}: episode log is truncated or damaged ({raw.problem or 'no footer'}); "
            f"read {len(raw.messages)} messages from its complete chunks",
            DataWarning,
            stacklevel=2,
        )
    if raw.skipped:
        warnings.warn(
            f"{path}: skipped {sum(raw.skipped.values())} messages on channels that are not "
            f"episode-log topics and not JSON-encoded: {', '.join(sorted(raw.skipped))}",
            DataWarning,
            stacklevel=2,
        )
    try:
        metadata = json.loads(meta_rec["json"]) if "json" in meta_rec else {}
        offset_ns = int(meta_rec.get("time_offset_ns", "0"))
        if not 0 <= offset_ns <= _MAX_LOG_TIME_NS:
            raise ValueError(
                f"time_offset_ns {reprlib.repr(offset_ns)} is not in [0, 2^64 - 1] "
                "(an unsigned 64-bit log time)"
            )
        if not isinstance(metadata, dict):
            raise TypeError(f"expected a JSON object, got {type(metadata).__name__}")
        if codec not in VALUE_CODECS:
            raise ValueError(
                f"value codec {codec!r} is not one this version reads "
                f"({', '.join(VALUE_CODECS)}): written by a newer iplanner_torch?"
            )
        metadata = decode_value(metadata, codec)  # NaN, infinities and None as written
    except (ValueError, TypeError, RecursionError) as err:
        raise DataError(f"{path}: bad episode metadata record: {err}") from err
    decoders = {
        **_ROW_DECODERS,
        **{t: functools.partial(_ROW_DECODERS[t], codec=codec) for t in _CODEC_TOPICS},
    }
    rows: dict[str, list[dict[str, Any]]] = {}
    for topic, log_time, data in raw.messages:
        try:
            msg = loads(data)
            decoder = decoders.get(topic) if ours else None
            if decoder is None:
                row = {"t": (log_time - offset_ns) * 1e-9, "message": msg}
            else:
                row = decoder(msg, offset_ns)
        except (ValueError, KeyError, TypeError, IndexError, RecursionError, OverflowError) as err:
            # RecursionError: JSON nested deeper than the decoders' recursion goes;
            # OverflowError: an integer too large for a float (a time, an array value)
            raise DataError(f"{path}: cannot decode a message on {topic}: {err!r}") from err
        rows.setdefault(topic, []).append(row)
    frames = {topic: pd.DataFrame.from_records(r) for topic, r in rows.items()}
    return Episode(
        path=path, metadata=metadata, frames=frames, complete=raw.complete, foreign=foreign
    )
