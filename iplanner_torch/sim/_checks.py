"""Value checks shared by the ``__post_init__`` of the simulation configs.

Each check raises :class:`~iplanner_torch.errors.ConfigError` naming the field and the value,
and leaves the value itself unchanged (configs keep what they were given).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from iplanner_torch.errors import ConfigError


def _is_real(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def finite(name: str, value: object) -> float:
    """``value`` as a float; ConfigError unless it is a finite real number (not a bool)."""
    if not _is_real(value) or not math.isfinite(float(value)):  # type: ignore[arg-type]
        raise ConfigError(f"expected {name} a finite number, got {value!r}")
    return float(value)  # type: ignore[arg-type]


def positive(name: str, value: object) -> float:
    """``value`` as a float; ConfigError unless it is finite and > 0."""
    if not _is_real(value) or not 0.0 < float(value) < math.inf:  # type: ignore[arg-type]
        raise ConfigError(f"expected {name} > 0 and finite, got {value!r}")
    return float(value)  # type: ignore[arg-type]


def non_negative(name: str, value: object) -> float:
    """``value`` as a float; ConfigError unless it is finite and >= 0."""
    if not _is_real(value) or not 0.0 <= float(value) < math.inf:  # type: ignore[arg-type]
        raise ConfigError(f"expected {name} >= 0 and finite, got {value!r}")
    return float(value)  # type: ignore[arg-type]


def finite_tuple(name: str, value: object, n: int) -> tuple[float, ...]:
    """``value`` as ``n`` floats; ConfigError unless it is a sequence of ``n`` finite numbers.

    Lists and OmegaConf list nodes are accepted as well as tuples.
    """
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
        raise ConfigError(f"expected {name} a sequence of {n} finite numbers, got {value!r}")
    items = tuple(value)  # type: ignore[arg-type]
    ok = len(items) == n and all(_is_real(v) and math.isfinite(float(v)) for v in items)
    if not ok:
        raise ConfigError(f"expected {name} a sequence of {n} finite numbers, got {value!r}")
    return tuple(float(v) for v in items)  # type: ignore[arg-type]


def integer(name: str, value: object, *, minimum: int) -> int:
    """``value`` as an int; ConfigError unless it is an integer (not a bool) >= ``minimum``."""
    if (
        isinstance(value, (bool, np.bool_))
        or not isinstance(value, numbers.Integral)
        or int(value) < minimum
    ):
        raise ConfigError(f"expected {name} an integer >= {minimum}, got {value!r}")
    return int(value)


def flag(name: str, value: object) -> bool:
    """``value`` as a bool; ConfigError unless it is ``True`` or ``False``."""
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"expected {name} True or False, got {value!r}")
    return bool(value)


def seed(value: object) -> int:
    """A random seed as an int; ConfigError unless it is a non-negative integer (numpy's
    generators refuse negative seeds)."""
    return integer("seed", value, minimum=0)
