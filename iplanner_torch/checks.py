"""Scalar value checks shared by the whole package.

Configs (``__post_init__``) and public functions check their number arguments with these:

- :func:`finite`, :func:`positive`, :func:`non_negative`: a real number (not a bool);
- :func:`is_real`: the test they use, for fields whose range is checked by hand;
- :func:`finite_tuple`: a sequence of a given number of finite reals;
- :func:`integer`, :func:`seed`: an integer (not a bool), optionally bounded below;
- :func:`flag`: ``True`` or ``False``;
- :func:`finite_time`: anything with a float value (also numpy numbers and one-element
  tensors), as :func:`math.isfinite` takes it; anything else is ``error`` too;
- :func:`optional`: any of the above for a field that may also be None;
- :func:`real_array`: an array-like of real numbers (not bool, complex, text or ragged);
- :func:`field_kind`, :func:`fits_kind`: the scalar kind a dataclass field takes (bool, int,
  float or str, a ``Literal``, ``| None``) and whether a value is of it, for settings given by
  name (the command line's config check and ``PlannerCfg.per_kind``).

Each check raises ``error`` (:class:`~iplanner_torch.errors.ConfigError` unless the caller
passes another exception type, e.g. :class:`~iplanner_torch.errors.DataError` for input data)
naming the argument and the value, and returns the value converted (a float, an int, ...)
without changing it: callers may keep what they were given. The tensor checks
(:func:`~iplanner_torch.types.check_shape`, :func:`~iplanner_torch.types.check_finite`) live
in :mod:`iplanner_torch.types`.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import reprlib
import types
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np

from iplanner_torch.errors import ConfigError, DataError, ShapeError

_T = TypeVar("_T")


def is_real(value: object) -> bool:
    """Whether ``value`` is a real number and not a bool (NaN and infinities are real: range
    checks refuse them where they must)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def finite(name: str, value: object, *, error: type[Exception] = ConfigError) -> float:
    """``value`` as a float; ``error`` unless it is a finite real number (not a bool)."""
    if not is_real(value) or not math.isfinite(float(value)):  # type: ignore[arg-type]
        raise error(f"expected {name} a finite number, got {value!r}")
    return float(value)  # type: ignore[arg-type]


def positive(name: str, value: object, *, error: type[Exception] = ConfigError) -> float:
    """``value`` as a float; ``error`` unless it is a real number (not a bool), finite and > 0."""
    if not is_real(value) or not 0.0 < float(value) < math.inf:  # type: ignore[arg-type]
        raise error(f"expected {name} > 0 and finite, got {value!r}")
    return float(value)  # type: ignore[arg-type]


def non_negative(name: str, value: object, *, error: type[Exception] = ConfigError) -> float:
    """``value`` as a float; ``error`` unless it is a real number (not a bool), finite and
    >= 0."""
    if not is_real(value) or not 0.0 <= float(value) < math.inf:  # type: ignore[arg-type]
        raise error(f"expected {name} >= 0 and finite, got {value!r}")
    return float(value)  # type: ignore[arg-type]


def finite_tuple(
    name: str, value: object, n: int, *, error: type[Exception] = ConfigError
) -> tuple[float, ...]:
    """``value`` as ``n`` floats; ``error`` unless it is a sequence of ``n`` finite real
    numbers (not bools).

    Lists and OmegaConf list nodes are accepted as well as tuples.
    """
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        raise error(f"expected {name} a sequence of {n} finite numbers, got {value!r}")
    items = tuple(value)  # type: ignore[arg-type]
    ok = len(items) == n and all(is_real(v) and math.isfinite(float(v)) for v in items)
    if not ok:
        raise error(f"expected {name} a sequence of {n} finite numbers, got {value!r}")
    return tuple(float(v) for v in items)  # type: ignore[arg-type]


def integer(
    name: str,
    value: object,
    *,
    minimum: int | None = None,
    error: type[Exception] = ConfigError,
) -> int:
    """``value`` as an int; ``error`` unless it is an integer (not a bool) and, when
    ``minimum`` is given, >= ``minimum``."""
    if (
        isinstance(value, (bool, np.bool_))
        or not isinstance(value, numbers.Integral)
        or (minimum is not None and int(value) < minimum)
    ):
        bound = "" if minimum is None else f" >= {minimum}"
        raise error(f"expected {name} an integer{bound}, got {value!r}")
    return int(value)


def flag(name: str, value: object, *, error: type[Exception] = ConfigError) -> bool:
    """``value`` as a bool; ``error`` unless it is ``True`` or ``False`` (also numpy's)."""
    if not isinstance(value, (bool, np.bool_)):
        raise error(f"expected {name} True or False, got {value!r}")
    return bool(value)


#: the largest seed: one 32-bit word. The random streams are numpy generators seeded by
#: lists such as ``[seed, salt]`` and ``[seed, salt, k]``; numpy splits a larger int into
#: several 32-bit words, so seed ``7 + 2**32`` with ``[seed, 0, 3]`` would draw the very
#: numbers of seed 7 with ``[seed, 1, 0, 3]``. Lightning's seed_everything takes no more.
MAX_SEED = 2**32 - 1


def seed(value: object, *, error: type[Exception] = ConfigError, name: str = "seed") -> int:
    """A random seed as an int; ``error`` unless it is an integer in [0, :data:`MAX_SEED`]
    (numpy's generators refuse negative seeds; a larger one would share another seed's
    streams, see :data:`MAX_SEED`)."""
    out = integer(name, value, minimum=0, error=error)
    if out > MAX_SEED:
        raise error(f"expected {name} an integer <= {MAX_SEED} (2^32 - 1), got {value!r}")
    return out


def finite_time(name: str, value: Any, *, error: type[Exception] = ConfigError) -> float:
    """``value`` as a float time [s]; ``error`` when it is NaN, infinite or not a number.

    Anything :func:`math.isfinite` takes is accepted: Python and numpy numbers, one-element
    tensors. Unlike :func:`finite` this does not ask for a :class:`numbers.Real`, since times
    often come out of tensors.

    Raises:
        error: when ``value`` is NaN or infinite, or has no float value (e.g. a string,
            ``None``, or an integer beyond float range).
    """
    try:
        ok = math.isfinite(value)
    except (TypeError, ValueError, OverflowError) as err:  # OverflowError: an int > 1e308
        raise error(f"expected {name} a finite time [s], got {reprlib.repr(value)}") from err
    if not ok:
        raise error(f"expected {name} a finite time [s], got {value!r}")
    return float(value)


def short_repr(value: Any, limit: int = 60) -> str:
    """``repr(value)``, shortened to ``limit`` characters (ending in ``...``) for messages."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def path_argument(
    value: object,
    purpose: str,
    *,
    kind: str = "file path",
    name: str = "path",
    error: type[Exception] = DataError,
) -> Path:
    """``value`` as a :class:`~pathlib.Path`; ``error`` unless it is a str or os.PathLike
    (``Path()`` raises a bare TypeError for None, a number, a list ...).

    The message reads ``"expected path a file path (str or os.PathLike) <purpose>, got
    NoneType None"``; ``kind`` replaces "file path" (e.g. "file or folder path").
    """
    if not (isinstance(value, str) or hasattr(value, "__fspath__")):
        raise error(
            f"expected {name} a {kind} (str or os.PathLike) {purpose}, got "
            f"{type(value).__name__} {reprlib.repr(value)}"
        )
    return Path(value)  # type: ignore[arg-type]


def is_dir(
    path: Path, expected: str, *, what: str = "", error: type[Exception] = DataError
) -> bool:
    """``path.is_dir()``, with ``error`` naming ``path`` where the system refuses to look it up
    at all (a name too long: a file's text passed as its path), where pathlib raises the
    OSError instead of answering False.

    The message reads ``"<what> '<path>': cannot look up this path (File name too long);
    expected <expected>"``, the path shortened to 60 characters.
    """
    try:
        return path.is_dir()
    except OSError as exc:
        shown = short_repr(str(path))
        raise error(
            f"{what + ' ' if what else ''}{shown}: cannot look up this path ({exc.strerror}); "
            f"expected {expected}"
        ) from exc


def optional(check: Callable[..., _T], name: str, value: object, **kwargs: Any) -> _T | None:
    """``check(name, value, **kwargs)`` for a field that may also be None (returned as is).

    Example: ``optional(finite, "budget_s", cfg.budget_s)``.
    """
    if value is None:
        return None
    return check(name, value, **kwargs)


def real_array(name: str, value: object) -> np.ndarray:
    """``value`` (an array, a tensor or nested sequences) as a numpy array of integers or
    floats, its dtype kept.

    Raises:
        ShapeError: for ragged nested sequences and for anything but real numbers (bool,
            complex, strings, None inside).
    """
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()  # type: ignore[union-attr]
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as err:  # ragged nested sequences
        raise ShapeError(
            f"expected {name} an array of real numbers, got a ragged sequence"
        ) from err
    if arr.dtype.kind not in "iuf":
        raise ShapeError(f"expected {name} an array of real numbers, got dtype {arr.dtype}")
    return arr


def increasing_times(name: str, times: np.ndarray) -> np.ndarray:
    """``times`` (a 1-D numpy array [s]), checked finite and strictly increasing.

    Raises:
        DataError: naming ``name``, for a NaN or infinite time or one not after the last.
    """
    if not (np.isfinite(times).all() and (np.diff(times) > 0).all()):
        raise DataError(f"expected {name} finite and strictly increasing, got {times}")
    return times


#: The scalar types :func:`field_kind` reports.
SCALAR_TYPES: tuple[type, ...] = (bool, int, float, str)


@dataclasses.dataclass(frozen=True)
class FieldKind:
    """What one dataclass field takes (:func:`field_kind`).

    Attributes:
        base: bool, int, float or str; for a ``Literal``, the type all its choices share
            (``object`` when they mix types).
        nullable: whether the field may be None (``X | None``; a field judged by its default,
            its annotation not resolving, may be None).
        choices: the values of a ``Literal`` field, else None.
    """

    base: type
    nullable: bool
    choices: tuple[Any, ...] | None = None


def field_kind(cls: type, name: str) -> FieldKind | None:
    """The scalar kind of the field ``name`` of the dataclass ``cls``, or None when it holds
    anything else (a dataclass, a list, a union of several types) or is not a field.

    The field is ``X``, ``X | None``, ``Literal[...]`` or ``Literal[...] | None`` with ``X``
    one of :data:`SCALAR_TYPES`. A field whose annotation does not resolve is judged by its
    default (a scalar default: that type, nullable).
    """
    fields = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
    if name not in fields:
        return None
    try:
        hint = typing.get_type_hints(cls).get(name)
    except Exception:  # an annotation that does not resolve: fall back to the default
        hint = None
    if hint is None:
        default = fields[name].default
        if default is not dataclasses.MISSING and type(default) in SCALAR_TYPES:
            return FieldKind(type(default), True)
        return None
    union = typing.get_origin(hint) in (typing.Union, types.UnionType)
    args = [a for a in typing.get_args(hint) if a is not type(None)] if union else [hint]
    nullable = union and len(args) < len(typing.get_args(hint))
    if len(args) != 1:
        return None
    base = args[0]
    if typing.get_origin(base) is Literal:
        choices = typing.get_args(base)
        kinds = {type(c) for c in choices}
        return FieldKind(kinds.pop() if len(kinds) == 1 else object, nullable, choices)
    if base in SCALAR_TYPES:
        return FieldKind(base, nullable)
    return None


def fits_kind(value: object, base: type) -> bool:
    """Whether ``value`` is a ``base`` (:data:`SCALAR_TYPES`): a bool is no int or float, an
    int is a float; any other ``base`` by ``isinstance``."""
    if base is bool:
        return isinstance(value, bool)
    if base is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if base is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return isinstance(value, base)
