"""EpisodeWriter: one MCAP log per closed-loop episode, replayable in Foxglove.

Every channel is JSON (``message_encoding="json"``, schema encoding ``"jsonschema"``), with the
schemas of :mod:`iplanner_torch.recording.schemas`, each one Foxglove's JSON-schema loader takes
(numbers finite, arrays flat and row-major, human joints as named objects: see there):

=========================  =========================  =========================================
topic                      schema                     written by
=========================  =========================  =========================================
``/tf``                    foxglove.FrameTransform    :meth:`EpisodeWriter.frame_transform`
``/robot/joint_state``     iplanner.RobotJointState   :meth:`EpisodeWriter.robot_state`
``/human/joints_true``     iplanner.HumanJoints       :meth:`EpisodeWriter.human_joints`
``/human/joints_tracked``  iplanner.HumanJoints       :meth:`EpisodeWriter.human_joints`
``/prediction/forecast``   iplanner.Forecast          :meth:`EpisodeWriter.forecast`
``/planner/bound``         iplanner.CollisionBound    :meth:`EpisodeWriter.collision_bound`
``/planner/plan``          iplanner.Plan              :meth:`EpisodeWriter.plan`
``/task/events``           iplanner.TaskEvent         :meth:`EpisodeWriter.task_event`
``/episode/metrics``       iplanner.EpisodeMetrics    :meth:`EpisodeWriter.metrics`
``/scene``                 foxglove.SceneUpdate       :meth:`EpisodeWriter.scene`
=========================  =========================  =========================================

Times: ``t`` is simulation time [s]; a message's log time is ``round(t * 1e9) + time_offset_ns``
nanoseconds, and every message of our own schemas also carries ``t`` itself. All geometry is
in the frame ``"world"`` (the table frame).

Checks: every argument is checked before anything of its message is written (shapes,
numbers, strings, bools; a ``ShapeError`` or ``DataError`` naming it), and the names of a
channel (its joint and action names) are fixed by its first message that is written: a
message with other names is refused, so the arrays of a channel always stack into one tensor
when read. A refused message fixes nothing. JSON has no NaN: a NaN or infinity in the robot
state, a plan or a bound is refused (the simulation and the planner give finite ones; the
forecast's values are checked as a :class:`Forecast` checks them), and a human joint with one
is left out of its message (a tracker dropout), read back as NaN.

Scene spheres: a sphere row with NaN or an infinity is not drawn (Foxglove has no NaN
sphere). When rows are left out, the entity's metadata says which rows its spheres are
(``sphere_count`` and ``sphere_rows``, see :mod:`~iplanner_torch.recording.reader`), so
:meth:`~iplanner_torch.recording.reader.Episode.scene_spheres` puts every row back in its slot,
NaN where one was left out.

Robustness: messages are grouped in small compressed chunks and the file is flushed whenever a
chunk is complete, so an episode killed midway leaves a file whose complete chunks
:func:`~iplanner_torch.recording.reader.read_episode` still reads (with a ``DataWarning``).
"""

from __future__ import annotations

import contextlib
import json
import math
import operator
import reprlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np
import torch
from mcap.writer import CompressionType, Writer
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from iplanner_torch.checks import integer, is_real, path_argument
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.interrupts import interrupts_deferred
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.recording.codec import (
    VALUE_CODEC,
    as_numpy,
    dumps,
    encode_value,
)
from iplanner_torch.recording.reader import (
    EPISODE_METADATA_NAME,
    SPHERE_COUNT_KEY,
    SPHERE_ROWS_KEY,
    Episode,
    metadata_crc,
    read_episode,
)
from iplanner_torch.recording.schemas import TOPIC_SCHEMAS, WORLD_FRAME
from iplanner_torch.types import check_shape

__all__ = ["EpisodeWriter", "SceneEllipsoid", "Episode", "read_episode", "ellipsoid_pose"]

#: RGBA of robot spheres, human spheres and predicted joint ellipsoids in ``/scene``.
ROBOT_RGBA = (1.0, 0.55, 0.1, 0.6)
HUMAN_RGBA = (0.2, 0.5, 1.0, 0.6)
ELLIPSOID_RGBA = (0.75, 0.2, 0.8, 0.25)

#: the largest log time an MCAP record holds (an unsigned 64-bit integer) [ns]
MAX_LOG_TIME_NS = 2**64 - 1

_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


@dataclass(frozen=True)
class SceneEllipsoid:
    """A predicted joint position drawn as an ellipsoid in ``/scene``.

    Attributes:
        mean: (3,) centre [m], world frame.
        cov: (3, 3) covariance [m^2]; drawn as its ``confidence`` ellipsoid (the writer's
            ``ellipsoid_confidence``). Give either ``cov`` or ``axes``.
        axes: (3,) semi-axis lengths [m] along x, y, z (axis-aligned ellipsoid).
        rgba: colour and opacity, each in [0, 1].
    """

    mean: Any
    cov: Any = None
    axes: Any = None
    rgba: tuple[float, float, float, float] = ELLIPSOID_RGBA


def ellipsoid_pose(
    cov: torch.Tensor | np.ndarray, confidence: float
) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes and orientation of the ``confidence`` ellipsoids of 3D Gaussians.

    The ellipsoid ``{x : (x - mu)^T cov^-1 (x - mu) <= chi2_3(confidence)}`` has semi-axes
    ``sqrt(chi2_3(confidence) * s_i)`` along the eigenvectors ``u_i`` of ``cov = U diag(s) U^T``.

    Args:
        cov: (..., 3, 3) symmetric positive semi-definite covariances [m^2].
        confidence: probability mass inside the ellipsoid, in (0, 1).

    Returns:
        ``(semi_axes (..., 3) [m], quaternion (..., 4) as x, y, z, w)``; the quaternion rotates
        the x, y, z axes onto the eigenvectors (a proper rotation: det U = +1).

    Raises:
        ConfigError: when ``confidence`` is not in (0, 1).
        ShapeError: when ``cov`` is not (..., 3, 3).
        DataError: when ``cov`` holds NaN or an infinity (or its eigendecomposition fails),
            is not symmetric, or has a negative eigenvalue, each beyond rounding (1e-6 of its
            largest entry).
    """
    if not 0.0 < confidence < 1.0:
        raise ConfigError(f"expected confidence in (0, 1), got {confidence}")
    return _ellipsoid_axes(as_numpy(cov), float(chi2.ppf(confidence, df=3)), check=True)


#: how far from symmetric and positive semi-definite (relative to the largest entry) a
#: covariance given to :func:`ellipsoid_pose` may be: rounding
_PSD_TOL = 1e-6


def _ellipsoid_axes(
    c: np.ndarray, k2: float, *, check: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes (..., 3) and quaternions (..., 4) of covariances c (..., 3, 3) at scale k2;
    ``check``: refuse covariances that are not symmetric positive semi-definite beyond
    rounding (the writer's own, moment-matched ones are clipped at 0 instead)."""
    if c.shape[-2:] != (3, 3):
        raise ShapeError(f"expected cov (..., 3, 3), got {c.shape}")
    if not np.isfinite(c).all():
        raise DataError("expected cov finite, got NaN or an infinity")
    batch = c.shape[:-2]
    c = c.reshape(-1, 3, 3)  # (E, 3, 3)
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            s, u = np.linalg.eigh(0.5 * (c + np.swapaxes(c, -1, -2)))
    except np.linalg.LinAlgError as err:
        raise DataError(f"cannot decompose cov (values too large?): {err}") from err
    if check and len(c):
        scale = np.abs(c).max(axis=(-1, -2))  # (E,)
        tol = _PSD_TOL * np.maximum(scale, np.finfo(np.float64).tiny)
        skew = np.abs(c - np.swapaxes(c, -1, -2)).max(axis=(-1, -2))
        if (skew > tol).any():
            i = int(np.argmax(skew > tol))
            raise DataError(
                f"expected cov symmetric, got one whose entries differ from their transposes' "
                f"by {skew[i]:.3g} (covariance {i} of the flattened batch)"
            )
        if (s[:, 0] < -tol).any():
            i = int(np.argmax(s[:, 0] < -tol))
            raise DataError(
                f"expected cov positive semi-definite, got an eigenvalue of {s[i, 0]:.3g} "
                f"(covariance {i} of the flattened batch)"
            )
    u[np.linalg.det(u) < 0, :, 2] *= -1.0  # proper rotations
    semi = np.sqrt(k2 * np.clip(s, 0.0, None))
    quat = Rotation.from_matrix(u).as_quat() if len(u) else np.zeros((0, 4))
    return semi.reshape(*batch, 3), quat.reshape(*batch, 4)


def _stamp_dict(ns: int) -> dict[str, int]:
    return {"sec": int(ns // 1_000_000_000), "nsec": int(ns % 1_000_000_000)}


def _xyz(v: Sequence[float]) -> dict[str, float]:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _rgba(c: Sequence[float]) -> dict[str, float]:
    return {"r": float(c[0]), "g": float(c[1]), "b": float(c[2]), "a": float(c[3])}


def _sphere(center: Sequence[float], size: Sequence[float], quat: Sequence[float], rgba) -> dict:
    return {
        "pose": {
            "position": _xyz(center),
            "orientation": {
                "x": float(quat[0]),
                "y": float(quat[1]),
                "z": float(quat[2]),
                "w": float(quat[3]),
            },
        },
        "size": _xyz(size),
        "color": _rgba(rgba),
    }


_IDENTITY_QUAT = (0.0, 0.0, 0.0, 1.0)


def _entity(
    ns: int,
    entity_id: str,
    kind: str,
    spheres: list[dict],
    metadata: Sequence[tuple[str, str]] = (),
) -> dict[str, Any]:
    return {
        "timestamp": _stamp_dict(ns),
        "frame_id": WORLD_FRAME,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [{"key": k, "value": v} for k, v in (("kind", kind), *metadata)],
        "arrows": [],
        "cubes": [],
        "spheres": spheres,
        "cylinders": [],
        "lines": [],
        "triangles": [],
        "texts": [],
        "models": [],
    }


#: numpy dtype kinds taken as numbers: bool, int, uint, float, and object (None -> NaN).
_NUMERIC_KINDS = "biufO"


def _numbers(name: str, x: Any, pretty: str) -> torch.Tensor:
    """``x`` as a tensor (float64 unless it is one already); a ShapeError naming ``name`` and
    its expected shape ``pretty`` when it is not numbers (strings, ragged nested lists)."""
    if isinstance(x, torch.Tensor):
        if x.is_complex():  # as_numpy would drop the imaginary parts
            raise ShapeError(f"expected {name} {pretty} of real numbers, got dtype {x.dtype}")
        return x
    try:
        a = np.asarray(x)
        if a.dtype.kind not in _NUMERIC_KINDS:
            raise TypeError(f"dtype {a.dtype}")
        return torch.as_tensor(a.astype(np.float64, copy=False))
    except (TypeError, ValueError, OverflowError) as err:  # OverflowError: an int past float
        raise ShapeError(f"expected {name} {pretty} of numbers, got {reprlib.repr(x)}") from err


def _as_tensor(name: str, x: Any, expected: Sequence[int | str]) -> np.ndarray:
    """Check the shape of a tensor / array argument and return it as a float64 numpy array.

    Raises:
        ShapeError: when its shape is not ``expected``, or it is not numbers (strings, nested
            lists of unequal lengths), naming the argument.
    """
    xt = _numbers(name, x, "(" + ", ".join(str(e) for e in expected) + ")")
    check_shape(name, xt, expected)
    return as_numpy(xt)


class EpisodeWriter:
    """Writes one closed-loop episode to an MCAP file (a context manager).

    Example::

        with EpisodeWriter(path, metadata={"scenario": "arrangements_1"}) as log:
            log.robot_state(t, q, qd, model.joint_names)
            log.metrics(t_end, {"eval/smoothness": 1.2})

    Args:
        path: output file (parent folders are created; an existing file is replaced).
        metadata: episode description (scenario, planner, seed, ...): any JSON-able dict; read
            back as ``Episode.metadata``. Written first, so it survives a truncated file.
        chunk_size: bytes of messages per chunk; a killed episode loses at most the last one.
        compression: chunk compression.
        ellipsoid_confidence: probability mass of the predicted joint ellipsoids in ``/scene``.
        time_offset_ns: added to every log time (e.g. the wall clock at the episode start),
            in [0, 2^64 - 1] (a log time is an unsigned 64-bit integer).

    Metadata, metrics and task event details read back as they were given: NaN and
    infinities as floats, ``None`` as ``None``, strings as strings (even ``"inf"``; see
    :mod:`~iplanner_torch.recording.codec`). Tensors and arrays in them read back as lists.
    Their keys must be strings, they may nest at most
    :data:`~iplanner_torch.recording.codec.MAX_VALUE_DEPTH` levels and hold no complex
    numbers.

    Raises:
        ConfigError: on a chunk size that is not an integer > 0, unknown compression, a
            confidence outside (0, 1) or a time offset that is not an integer in
            [0, 2^64 - 1].
        DataError: when ``metadata`` is not JSON-serialisable (as above), or ``path`` is not
            a path or cannot be written (a folder, below a file, no permission). The logging
            methods raise ``ShapeError`` on arrays of the wrong shape or not real numbers,
            and ``DataError`` on other arguments of the wrong type or value (a time that is
            not one or whose log time passes 2^64 - 1 ns, a number that is not one or not
            finite, a non-bool ``feasible``, names that are not a sequence of strings, frame
            ids or an event kind that are not strings, a transform with NaN or an infinity,
            metrics or details that are not a mapping or not JSON-serialisable as above,
            ellipsoid covariances, means or semi-axes with NaN or an infinity, colours outside
            [0, 1]) and on names that differ from the earlier ones of their channel; nothing
            of a refused message is written.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        metadata: Mapping[str, Any],
        chunk_size: int = 256 * 1024,
        compression: Literal["zstd", "lz4", "none"] = "zstd",
        ellipsoid_confidence: float = 0.95,
        time_offset_ns: int = 0,
    ) -> None:
        chunk_size = integer("chunk_size", chunk_size, minimum=1)
        if not isinstance(compression, str) or compression not in _COMPRESSION:
            raise ConfigError(f"expected compression in {sorted(_COMPRESSION)}, got {compression}")
        if not (is_real(ellipsoid_confidence) and 0.0 < ellipsoid_confidence < 1.0):
            raise ConfigError(
                f"expected ellipsoid_confidence in (0, 1), got {ellipsoid_confidence!r}"
            )
        time_offset_ns = integer("time_offset_ns", time_offset_ns, minimum=0)
        if time_offset_ns > MAX_LOG_TIME_NS:
            raise ConfigError(
                f"expected time_offset_ns in [0, 2^64 - 1] (an unsigned 64-bit log time), "
                f"got {time_offset_ns}"
            )
        self.path = path_argument(path, "for the episode log")
        try:
            meta_json = json.dumps(encode_value(dict(metadata)), allow_nan=False)
        except (TypeError, ValueError) as err:
            raise DataError(f"{self.path}: metadata is not JSON-serialisable: {err}") from err
        self._file = self._open()  # closed in close()
        self._chi2_scale = float(chi2.ppf(ellipsoid_confidence, df=3))
        self._offset_ns = int(time_offset_ns)
        self._writer = Writer(
            self._file, chunk_size=chunk_size, compression=_COMPRESSION[compression]
        )
        self._closed = False
        self._last_t = 0.0  # the last logged time [s] (an interruption is logged there)
        self._writer.start(profile="", library="iplanner_torch")
        self._writer.add_metadata(  # metadata records carry no checksum of their own
            EPISODE_METADATA_NAME,
            {
                "json": meta_json,
                "time_offset_ns": str(self._offset_ns),
                "value_codec": VALUE_CODEC,
                "crc32": str(metadata_crc(meta_json, str(self._offset_ns), VALUE_CODEC)),
            },
        )
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        # (topic, argument) -> the names of the channel's first message (see _checked_names)
        self._channel_names: dict[tuple[str, str], tuple[str, ...]] = {}
        schema_ids: dict[str, int] = {}
        for topic, schema in TOPIC_SCHEMAS.items():
            name = schema["title"]
            if name not in schema_ids:
                schema_ids[name] = self._writer.register_schema(
                    name=name, encoding="jsonschema", data=json.dumps(schema).encode()
                )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_ids[name]
            )
            self._sequence[topic] = 0
        self._file.flush()
        self.frame_transform(0.0, WORLD_FRAME, "table")

    # -- context manager ----------------------------------------------------------------------

    def __enter__(self) -> EpisodeWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close(exc)

    def close(self, error: BaseException | None = None) -> None:
        """Write the summary and footer and close the file (idempotent).

        Args:
            error: what stopped the episode early (an exception, Ctrl-C), or None. It is
                logged first as an ``interrupted`` task event at the last logged time, so a
                replay shows where and why the log ends; leaving a ``with`` block on an
                exception passes it.
        """
        if self._closed:
            return
        if error is not None:
            with contextlib.suppress(Exception):  # the log as it is still closes properly
                self.task_event(self._last_t, "interrupted", {"error": type(error).__name__})
        self._closed = True
        try:
            with interrupts_deferred():  # the summary and footer are written whole
                self._writer.finish()
        finally:
            self._file.close()

    def flush(self) -> None:
        """Close the chunk in progress and flush the file (e.g. at a task milestone)."""
        self._check_open()
        with interrupts_deferred():
            self._writer.flush()

    # -- plumbing -----------------------------------------------------------------------------

    def _open(self) -> Any:
        """The output file opened for writing, its folders created."""
        if self.path.is_dir():
            raise DataError(f"{self.path}: is a folder; EpisodeWriter writes one .mcap file")
        parent = self.path.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError) as err:  # a file where a folder goes
            what = "it is a file" if parent.exists() else "a folder above it is a file"
            raise DataError(
                f"{self.path}: cannot write the episode log: {parent} is not a folder ({what})"
            ) from err
        except OSError as err:
            raise DataError(f"{self.path}: cannot write the episode log: {err}") from err
        try:
            return open(self.path, "wb")
        except OSError as err:
            raise DataError(f"{self.path}: cannot write the episode log: {err}") from err

    def _check_open(self) -> None:
        if self._closed:
            raise DataError(f"{self.path}: episode log is already closed")

    def _log_time(self, t: float) -> int:
        try:
            if isinstance(t, str | bytes | bool | np.bool_):  # float() would take "1.5", True
                raise TypeError(type(t).__name__)
            t = float(t)
        except (TypeError, ValueError, OverflowError) as err:  # OverflowError: int past float
            raise DataError(
                f"{self.path}: expected a finite time t >= 0 s, got {reprlib.repr(t)}"
            ) from err
        if not math.isfinite(t) or t < 0.0:
            raise DataError(f"{self.path}: expected a finite time t >= 0 s, got {t}")
        scaled = t * 1e9  # inf for t beyond ~1.8e299 s: no integer log time
        ns = int(round(scaled)) + self._offset_ns if math.isfinite(scaled) else math.inf
        if ns > MAX_LOG_TIME_NS:
            raise DataError(
                f"{self.path}: time t = {t} s gives a log time beyond 2^64 - 1 ns (with "
                f"time_offset_ns = {self._offset_ns}); expected t <= "
                f"{(MAX_LOG_TIME_NS - self._offset_ns) * 1e-9:.6g} s"
            )
        self._last_t = t
        return ns

    def _write(
        self,
        topic: str,
        log_time: int,
        message: Mapping[str, Any],
        names: Mapping[str, tuple[str, ...]] | None = None,
    ) -> None:
        """Write ``message`` on ``topic``; then ``names`` (argument -> names, from
        :meth:`_checked_names`) become the channel's names where it has none yet."""
        self._check_open()
        try:
            data = dumps(message)
        except (TypeError, ValueError) as err:
            raise DataError(
                f"{self.path}: a {topic} message is not JSON-serialisable: {err}"
            ) from err
        before = self._file.tell()
        # one record is several writes into the chunk: a Ctrl-C between two of them would
        # leave a record whose length field covers the next one (the whole log unreadable)
        with interrupts_deferred():
            self._writer.add_message(
                channel_id=self._channels[topic],
                log_time=log_time,
                data=data,
                publish_time=log_time,
                sequence=self._sequence[topic],
            )
            self._sequence[topic] += 1
        for name, fixed in (names or {}).items():
            self._channel_names.setdefault((topic, name), fixed)
        if self._file.tell() != before:  # a chunk was completed: get it onto the disk
            self._file.flush()

    def _stamped(self, t: float) -> tuple[int, dict[str, Any]]:
        ns = self._log_time(t)
        return ns, {"timestamp": _stamp_dict(ns), "t": self._last_t}

    def _number(self, name: str, x: Any) -> float:
        """``x`` as a float; a DataError naming the argument when it is not a number (a
        string, a bool, None, an array, a complex number, an int too large for a float) or
        not finite (these fields are plain JSON numbers in their schemas)."""
        if not isinstance(x, str | bytes | bool | np.bool_ | complex | np.complexfloating):
            try:
                value = float(x)
            except (TypeError, ValueError, OverflowError):
                pass
            else:
                if math.isfinite(value):
                    return value
                raise DataError(f"{self.path}: expected {name} a finite number, got {value}")
        raise DataError(f"{self.path}: expected {name} a number, got {reprlib.repr(x)}")

    def _finite(self, name: str, x: np.ndarray) -> list[float]:
        """``x`` flattened (row-major) as a list of floats; a DataError naming the argument and
        its first entry that is NaN or infinite (these arrays are plain JSON numbers in their
        schemas, as Foxglove reads them)."""
        bad = ~np.isfinite(x)
        if bad.any():
            where = tuple(int(i) for i in np.argwhere(bad)[0])
            raise DataError(
                f"{self.path}: expected {name} finite, got {x[where]} at index "
                f"{where if len(where) != 1 else where[0]} ({int(bad.sum())} of {x.size} not "
                "finite)"
            )
        return x.ravel().tolist()

    def _string(self, name: str, x: Any) -> str:
        """``x`` when it is a string; a DataError naming the argument otherwise."""
        if isinstance(x, str):
            return x
        raise DataError(f"{self.path}: expected {name} a string, got {reprlib.repr(x)}")

    def _mapping(self, name: str, x: Any) -> dict[str, Any]:
        """``x`` as a dict when it is a mapping; a DataError naming the argument otherwise."""
        if isinstance(x, Mapping):
            return dict(x)
        raise DataError(
            f"{self.path}: expected {name} a mapping of name -> value, got {reprlib.repr(x)}"
        )

    def _flag(self, name: str, x: Any) -> bool:
        """``x`` as a bool: True or False (numpy's, or a one-element bool tensor, too)."""
        if isinstance(x, bool | np.bool_) or (
            isinstance(x, torch.Tensor) and x.dtype == torch.bool and x.numel() == 1
        ):
            return bool(x)
        raise DataError(f"{self.path}: expected {name} True or False, got {reprlib.repr(x)}")

    def _checked_names(
        self, topic: str, name: str, names: Sequence[str], n: int
    ) -> tuple[str, ...]:
        """The ``n`` names of argument ``name`` of a ``topic`` message.

        A channel's names are fixed by its first message that is written (a reader stacks
        its arrays, whose rows they name): :meth:`_write` stores them once the message is
        written, so a message refused for another argument fixes nothing. They are cached, so
        names equal to them cost one tuple comparison.

        Raises:
            ShapeError: when there are not ``n`` names.
            DataError: when they are not a sequence of strings (a single string included), or
                differ from the channel's names.
        """
        if isinstance(names, str | bytes) or not isinstance(names, Iterable):
            raise DataError(
                f"{self.path}: expected {name} a sequence of strings, got {reprlib.repr(names)}"
            )
        got = names if isinstance(names, tuple) else tuple(names)
        fixed = self._channel_names.get((topic, name))
        if got == fixed and len(got) == n:
            return fixed
        if len(got) != n:
            raise ShapeError(f"expected {n} {name}, got {len(got)}")
        if not all(isinstance(s, str) for s in got):
            raise DataError(f"{self.path}: expected {name} as strings, got {reprlib.repr(names)}")
        if fixed is not None:
            raise DataError(
                f"{self.path}: {name} changed on {topic}: {list(fixed)} before, {list(got)} now "
                "(a channel's names are fixed by its first message)"
            )
        return tuple(str(s) for s in got)

    # -- channels -----------------------------------------------------------------------------

    def frame_transform(
        self,
        t: float,
        parent: str,
        child: str,
        translation: Sequence[float] = (0.0, 0.0, 0.0),
        rotation_xyzw: Sequence[float] = _IDENTITY_QUAT,
    ) -> None:
        """Log a ``foxglove.FrameTransform`` on ``/tf`` (one from "world" to "table" at t=0).

        Args:
            t: simulation time [s].
            parent: parent frame id.
            child: child frame id.
            translation: (3,) child origin in the parent frame [m].
            rotation_xyzw: (4,) unit quaternion of the child frame in the parent frame.
        """
        parent = self._string("parent", parent)
        child = self._string("child", child)
        tr = _as_tensor("translation", translation, (3,))
        rot = _as_tensor("rotation_xyzw", rotation_xyzw, (4,))
        if not (np.isfinite(tr).all() and np.isfinite(rot).all()):  # plain numbers in Foxglove
            raise DataError(
                f"{self.path}: expected translation and rotation_xyzw finite, got "
                f"{tr.tolist()} and {rot.tolist()}"
            )
        ns = self._log_time(t)
        self._write(
            "/tf",
            ns,
            {
                "timestamp": _stamp_dict(ns),
                "parent_frame_id": parent,
                "child_frame_id": child,
                "translation": _xyz(tr),
                "rotation": dict(zip("xyzw", (float(v) for v in rot))),
            },
        )

    def robot_state(self, t: float, q: Any, qd: Any, joint_names: Sequence[str]) -> None:
        """Log the robot's joint state on ``/robot/joint_state``.

        Args:
            t: simulation time [s].
            q: (J,) joint positions [rad].
            qd: (J,) joint velocities [rad/s].
            joint_names: the J joint names (the same in every message).

        Raises:
            ShapeError: for shapes other than those above.
            DataError: for a NaN or infinite ``q`` or ``qd`` (JSON numbers carry neither).
        """
        q_np = _as_tensor("q", q, ("J",))
        qd_np = _as_tensor("qd", qd, (q_np.shape[0],))
        position, velocity = self._finite("q", q_np), self._finite("qd", qd_np)
        topic = "/robot/joint_state"
        names = self._checked_names(topic, "joint_names", joint_names, len(q_np))
        ns, msg = self._stamped(t)
        msg["joint_names"] = names
        msg["position"] = position
        msg["velocity"] = velocity
        self._write(topic, ns, msg, {"joint_names": names})

    def human_joints(
        self, t: float, true: Any | None, tracked: Any | None, joint_names: Sequence[str]
    ) -> None:
        """Log the true and the tracked human joints on ``/human/joints_true`` / ``_tracked``.

        Args:
            t: simulation time [s].
            true: (K, 3) ground-truth joint positions [m], or None to skip.
            tracked: (K, 3) tracker output [m], NaN where a joint dropped out, or None to skip.
            joint_names: the K joint names (the same in every message of a channel).

        A joint with a NaN or infinite coordinate is left out of its message's ``positions``
        (Foxglove then plots a gap) and reads back as NaN.
        """
        checked = []  # both messages are checked before either is written
        for topic, name, x in (
            ("/human/joints_true", "true", true),
            ("/human/joints_tracked", "tracked", tracked),
        ):
            if x is not None:
                p = _as_tensor(name, x, ("K", 3))
                names = self._checked_names(topic, "joint_names", joint_names, len(p))
                checked.append((topic, p, names))
        ns, base = self._stamped(t)
        for topic, p, names in checked:
            msg = dict(base)
            msg["joint_names"] = names
            msg["positions"] = [  # a joint not tracked (NaN) is left out: read back as NaN
                {"joint": n, "x": float(r[0]), "y": float(r[1]), "z": float(r[2])}
                for n, r in zip(names, p, strict=True)
                if np.isfinite(r).all()
            ]
            self._write(topic, ns, msg, {"joint_names": names})

    def forecast(
        self,
        t: float,
        weights: Any,
        mean: Any,
        var: Any,
        action_names: Sequence[str],
        dt: float,
        joint_names: Sequence[str] | None = None,
    ) -> None:
        """Log one forecast on ``/prediction/forecast``.

        Args:
            t: simulation time of the last observed frame [s].
            weights: (A,) action probabilities.
            mean: (A, n_f, K, 3) predicted joint positions [m].
            var: (A, n_f, K, 3) per-coordinate variances [m^2].
            action_names: the A action names (the same in every forecast).
            dt: seconds between predicted frames.
            joint_names: the K joint names (default ``joint_0`` ... ``joint_{K-1}``; the same
                in every forecast).

        Raises:
            ShapeError: for shapes other than those above, or no action, frame or joint.
            DataError: for values a :class:`Forecast` refuses (NaN or infinite, a mean
                coordinate beyond ``MAX_POSITION_M``, weights that are not probabilities),
                checked before anything is written: the reader builds one Forecast of all
                the messages, which one such message would have made unreadable.
        """
        w = _as_tensor("weights", weights, ("A",))
        m = _as_tensor("mean", mean, (w.shape[0], "n_f", "K", 3))
        v = _as_tensor("var", var, m.shape)
        if 0 in m.shape:  # the reader could not size its arrays: the whole log would be lost
            raise ShapeError(
                f"expected a forecast with at least one action, frame and joint, got mean "
                f"(A, n_f, K, 3) = {tuple(m.shape)}"
            )
        k = m.shape[2]
        names = joint_names if joint_names is not None else [f"joint_{i}" for i in range(k)]
        topic = "/prediction/forecast"
        actions = self._checked_names(topic, "action_names", action_names, w.shape[0])
        joints = self._checked_names(topic, "joint_names", names, k)
        dt = self._number("dt", dt)
        try:  # the reader's checks (:meth:`EpisodeLog.forecasts`), before the message is taken
            Forecast(
                weights=torch.from_numpy(w[None]),  # (1, A): float64, as the reader's
                mean=torch.from_numpy(m[None]),
                var=torch.from_numpy(v[None]),
                dt=dt,
                joint_names=joints,
                action_names=actions,
            )
        except (DataError, ShapeError) as err:
            raise DataError(f"{self.path}: forecast at t={t} not written: {err}") from None
        ns, msg = self._stamped(t)
        msg["dt"] = dt
        msg["action_names"] = actions
        msg["joint_names"] = joints
        msg["weights"] = self._finite("weights", w)  # finite: the Forecast above checked
        msg["mean"] = self._finite("mean", m)
        msg["var"] = self._finite("var", v)
        self._write(topic, ns, msg, {"action_names": actions, "joint_names": joints})

    def log_forecast(self, t: float, forecast: Forecast, index: int = 0) -> None:
        """Log item ``index`` of the batch of a :class:`Forecast` (see :meth:`forecast`)."""
        try:
            index = operator.index(index)  # ints, numpy and 0-d tensor integers; not 0.5
        except TypeError:
            index = None
        if index is None or not 0 <= index < forecast.batch_size:
            raise ShapeError(f"expected index in [0, {forecast.batch_size}), got {index!r}")
        self.forecast(
            t,
            forecast.weights[index],
            forecast.mean[index],
            forecast.var[index],
            forecast.action_names,
            forecast.dt,
            forecast.joint_names,
        )

    def collision_bound(self, t: float, times: Any, bound: Any, confidence: float) -> None:
        """Log the collision-probability bound along the plan on ``/planner/bound``.

        Args:
            t: simulation time [s].
            times: (W,) waypoint times [s].
            bound: (W,) upper bound of the collision probability at each waypoint.
            confidence: the confidence level (safe where bound <= 1 - confidence), in (0, 1).

        Raises:
            ShapeError: for shapes other than those above.
            DataError: for a ``confidence`` that is not a number in (0, 1), or a NaN or
                infinite entry of ``times`` or ``bound``.
        """
        tw = _as_tensor("times", times, ("W",))
        b = _as_tensor("bound", bound, (tw.shape[0],))
        confidence = self._number("confidence", confidence)
        if not 0.0 < confidence < 1.0:  # as the planner and ellipsoid_pose take it
            raise DataError(f"{self.path}: expected confidence in (0, 1), got {confidence}")
        times_list, bound_list = self._finite("times", tw), self._finite("bound", b)
        ns, msg = self._stamped(t)
        msg["times"] = times_list
        msg["bound"] = bound_list
        msg["confidence"] = confidence
        if b.size:  # left out without waypoints (read back as NaN)
            msg["max_bound"] = float(b.max())
        self._write("/planner/bound", ns, msg)

    def plan(
        self, t: float, times: Any, q: Any, feasible: bool, wait_s: float, solve_ms: float
    ) -> None:
        """Log the planner's chosen trajectory on ``/planner/plan``.

        Args:
            t: simulation time [s].
            times: (W,) waypoint times [s].
            q: (W, J) waypoint joint positions [rad].
            feasible: whether the plan met the bound (else the robot waits).
            wait_s: time the robot waits before executing [s].
            solve_ms: planner wall time [ms].

        Raises:
            ShapeError: for shapes other than those above.
            DataError: for a NaN or infinite entry of ``times`` or ``q``, or a ``wait_s`` or
                ``solve_ms`` that is not a finite number.
        """
        tw = _as_tensor("times", times, ("W",))
        qw = _as_tensor("q", q, (tw.shape[0], "J"))
        feasible = self._flag("feasible", feasible)
        wait_s = self._number("wait_s", wait_s)
        solve_ms = self._number("solve_ms", solve_ms)
        times_list, q_list = self._finite("times", tw), self._finite("q", qw)
        ns, msg = self._stamped(t)
        msg["times"] = times_list
        msg["q"] = q_list
        msg["feasible"] = feasible
        msg["wait_s"] = wait_s
        msg["solve_ms"] = solve_ms
        self._write("/planner/plan", ns, msg)

    def task_event(self, t: float, kind: str, detail: Mapping[str, Any] | None = None) -> None:
        """Log a task event on ``/task/events`` (``kind`` e.g. "action_start", "handover").

        Args:
            t: simulation time [s].
            kind: event name (a string).
            detail: JSON-able details (a mapping, or None for none); they read back as given
                (NaN, infinities and None included).
        """
        kind = self._string("kind", kind)
        detail = {} if detail is None else self._mapping("detail", detail)
        encoded = self._encoded("detail", detail)  # before the time is taken as logged
        ns, msg = self._stamped(t)
        msg["kind"] = kind
        msg["detail"] = encoded
        self._write("/task/events", ns, msg)

    def metrics(self, t: float, metrics: Mapping[str, Any]) -> None:
        """Log metric values on ``/episode/metrics`` (the last message is the episode's).

        Args:
            t: simulation time [s].
            metrics: name -> value (numbers, bools, strings; NaN and inf survive).
        """
        metrics = self._mapping("metrics", metrics)
        encoded = self._encoded("metrics", metrics)
        ns, msg = self._stamped(t)
        msg["metrics"] = encoded
        self._write("/episode/metrics", ns, msg)

    def _encoded(self, name: str, value: dict[str, Any]) -> Any:
        """``encode_value(value)``; a DataError naming ``name`` when it holds something JSON
        cannot carry (a numpy array of strings, an object)."""
        try:
            return encode_value(value)
        except (TypeError, ValueError) as err:
            raise DataError(
                f"{self.path}: {name} is not JSON-serialisable: {type(err).__name__}: {err}"
            ) from err

    def scene(
        self,
        t: float,
        robot_spheres: Any,
        human_spheres: Any,
        ellipsoids: Sequence[SceneEllipsoid | tuple] = (),
    ) -> None:
        """Log the 3D scene on ``/scene`` as a ``foxglove.SceneUpdate``.

        Three entities, each replacing the previous one of the same id: ``robot`` and ``human``
        (spheres) and ``prediction`` (one ellipsoid per predicted joint position: a sphere
        primitive scaled by the ellipsoid's axes and rotated onto the covariance's eigenvectors).

        Args:
            t: simulation time [s].
            robot_spheres: (S_r, 4) robot sphere centres and radii [x, y, z, r] [m].
            human_spheres: (S_h, 4) human sphere centres and radii [m]. A row of either with
                NaN or an infinity is not drawn; it reads back as a NaN row in its slot.
            ellipsoids: :class:`SceneEllipsoid` items, or tuples ``(mean, cov_or_axes)`` /
                ``(mean, cov_or_axes, rgba)``; a (3, 3) second item is a covariance, a (3,)
                one the semi-axes. Means, covariances and semi-axes must be finite, and the
                rgba 4 numbers in [0, 1].
        """
        rs = _as_tensor("robot_spheres", robot_spheres, ("S_r", 4))
        hs = _as_tensor("human_spheres", human_spheres, ("S_h", 4))
        for name, spheres in (("robot_spheres", rs), ("human_spheres", hs)):
            radii = np.asarray(spheres[:, 3])
            if (radii < 0).any():  # NaN rows are dropped below, not refused
                raise DataError(
                    f"{self.path}: expected {name} radii >= 0 [m], got "
                    f"{radii[radii < 0].tolist()} (rows {np.flatnonzero(radii < 0).tolist()})"
                )
        prims = self._ellipsoid_primitives(ellipsoids)
        ns = self._log_time(t)
        entities = []
        for entity_id, spheres, rgba in (("robot", rs, ROBOT_RGBA), ("human", hs, HUMAN_RGBA)):
            kept = np.isfinite(spheres).all(axis=1)  # (S,)
            drawn = [_sphere(s[:3], (2 * s[3],) * 3, _IDENTITY_QUAT, rgba) for s in spheres[kept]]
            slots: list[tuple[str, str]] = []
            if not kept.all():  # the rows drawn, so a reader puts each back in its slot
                rows = ",".join(str(i) for i in np.flatnonzero(kept))
                slots = [(SPHERE_COUNT_KEY, str(len(spheres))), (SPHERE_ROWS_KEY, rows)]
            entities.append(_entity(ns, entity_id, f"{entity_id}_spheres", drawn, slots))
        entities.append(_entity(ns, "prediction", "joint_ellipsoids", prims))
        self._write("/scene", ns, {"deletions": [], "entities": entities})

    def _color(self, rgba: Any) -> np.ndarray:
        """(4,) rgba of an ellipsoid: a ShapeError unless it is 4 numbers, a DataError unless
        each is in [0, 1]."""
        c = _as_tensor("ellipsoid rgba", rgba, (4,))
        if not ((c >= 0.0) & (c <= 1.0)).all():  # NaN fails too
            raise DataError(f"{self.path}: expected ellipsoid rgba in [0, 1], got {c.tolist()}")
        return c

    def _ellipsoid_primitives(self, items: Sequence[SceneEllipsoid | tuple]) -> list[dict]:
        """Sphere primitives of the ellipsoids (covariances decomposed in one batch)."""
        if not isinstance(items, Sequence):  # a bare SceneEllipsoid, None, ...
            raise ShapeError(
                f"expected ellipsoids a sequence of SceneEllipsoid or tuples, got "
                f"{reprlib.repr(items)}"
            )
        means, shapes, colors, is_cov = [], [], [], []
        for e in items:
            if isinstance(e, SceneEllipsoid):
                if (e.cov is None) == (e.axes is None):
                    raise ShapeError(
                        "expected exactly one of cov (3, 3) and axes (3,) per ellipsoid"
                    )
                second, rgba = (e.cov if e.cov is not None else e.axes), e.rgba
            else:
                if not isinstance(e, Sequence) or len(e) not in (2, 3):
                    got = f"{len(e)} items" if isinstance(e, Sequence) else reprlib.repr(e)
                    raise ShapeError(f"expected (mean, cov_or_axes[, rgba]), got {got}")
                second, rgba = e[1], (e[2] if len(e) == 3 else ELLIPSOID_RGBA)
            mean = e.mean if isinstance(e, SceneEllipsoid) else e[0]
            mean = as_numpy(_numbers("ellipsoid mean", mean, "(3)"))
            second = as_numpy(_numbers("ellipsoid cov_or_axes", second, "(3, 3) or (3)"))
            if mean.shape != (3,) or second.shape not in ((3, 3), (3,)):
                raise ShapeError(
                    f"expected ellipsoid mean (3,) and cov (3, 3) or axes (3,), "
                    f"got {mean.shape} and {second.shape}"
                )
            what = "cov" if second.shape == (3, 3) else "axes"
            if not (np.isfinite(mean).all() and np.isfinite(second).all()):
                raise DataError(
                    f"{self.path}: expected ellipsoid mean and {what} finite, got mean "
                    f"{mean.tolist()} and {what} {second.tolist()}"
                )
            if what == "axes" and (second < 0).any():
                raise DataError(
                    f"{self.path}: expected ellipsoid semi-axes >= 0 [m], got {second.tolist()}"
                )
            means.append(mean)
            shapes.append(second)
            colors.append(self._color(rgba))
            is_cov.append(second.shape == (3, 3))
        semi = np.zeros((len(items), 3))
        quat = np.tile(np.array(_IDENTITY_QUAT), (len(items), 1))
        cov_idx = [i for i, c in enumerate(is_cov) if c]
        if cov_idx:
            covs = np.stack([shapes[i] for i in cov_idx])  # (E_c, 3, 3)
            semi[cov_idx], quat[cov_idx] = _ellipsoid_axes(covs, self._chi2_scale)
        for i, c in enumerate(is_cov):
            if not c:
                semi[i] = shapes[i]
        return [_sphere(means[i], 2.0 * semi[i], quat[i], colors[i]) for i in range(len(items))]
