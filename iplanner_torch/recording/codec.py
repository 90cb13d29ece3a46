"""JSON encoding of numeric arrays for MCAP messages, lossless for NaN and infinities.

JSON has no NaN or infinity. In every message of an episode log a NaN number is written as
``null`` and an infinity as the string ``"inf"`` or ``"-inf"``; :func:`decode_array` maps them
back. Finite numbers are written with Python's shortest round-trip ``repr`` of the float64
value, so float32 and float64 inputs come back bit-identical (as float64).

The price, in the free-form dicts (episode metadata, metrics, event details): a value that
was itself the string ``"inf"`` or ``"-inf"``, or ``None``, reads back as the float
infinity or NaN. Store such text under another spelling (``"infinite"``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch


def as_numpy(x: Any, dtype: type = np.float64) -> np.ndarray:
    """A float64 (or ``dtype``) numpy copy of a tensor, array, sequence or scalar."""
    if isinstance(x, torch.Tensor):
        return x.detach().to("cpu", torch.float64).numpy().astype(dtype, copy=False)
    return np.asarray(x, dtype=dtype)


def encode_array(x: Any) -> Any:
    """A nested list of numbers for JSON, with NaN as None and +-inf as "inf" / "-inf".

    Args:
        x: tensor, array or nested sequence of numbers, any shape (a 0-d input gives a scalar).

    Returns:
        Nested Python lists (or one scalar) that ``json.dumps(..., allow_nan=False)`` accepts.
    """
    a = as_numpy(x)
    if np.isfinite(a).all():
        return a.tolist()
    obj = a.astype(object)
    obj[np.isnan(a)] = None
    obj[np.isposinf(a)] = "inf"
    obj[np.isneginf(a)] = "-inf"
    return obj.tolist()


def decode_array(value: Any) -> np.ndarray:
    """The float64 array of a value written by :func:`encode_array` (None -> NaN)."""
    return np.array(value, dtype=np.float64)


def encode_scalar(x: Any) -> Any:
    """A JSON-safe scalar: float NaN -> None, +-inf -> "inf" / "-inf"; others unchanged."""
    if isinstance(x, torch.Tensor | np.ndarray | np.generic):
        x = x.item() if getattr(x, "ndim", 0) == 0 else encode_array(x)
        if isinstance(x, list):
            return x
    if isinstance(x, bool) or x is None or isinstance(x, str | int):
        return x
    if isinstance(x, float):
        if math.isnan(x):
            return None
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        return x
    return x


def encode_value(x: Any) -> Any:
    """Recursively make dicts, lists, tensors and numbers JSON-safe (see module docstring)."""
    if isinstance(x, Mapping):
        return {str(k): encode_value(v) for k, v in x.items()}
    if isinstance(x, torch.Tensor | np.ndarray):
        if x.dtype == torch.bool or (isinstance(x, np.ndarray) and x.dtype == np.bool_):
            return as_numpy(x, dtype=bool).tolist()
        return encode_array(x)
    if isinstance(x, Sequence) and not isinstance(x, str | bytes):
        return [encode_value(v) for v in x]
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return encode_scalar(float(x))
    return encode_scalar(x)


def decode_scalar(x: Any) -> Any:
    """Inverse of :func:`encode_scalar` for values of a metrics or detail dict."""
    if x is None:
        return math.nan
    if x == "inf":
        return math.inf
    if x == "-inf":
        return -math.inf
    return x


def dumps(message: Mapping[str, Any]) -> bytes:
    """UTF-8 JSON bytes of an already JSON-safe message (raises ValueError on NaN)."""
    return json.dumps(message, allow_nan=False, separators=(",", ":")).encode("utf-8")


def loads(data: bytes) -> dict[str, Any]:
    """The message dict of UTF-8 JSON bytes."""
    return json.loads(data.decode("utf-8"))
