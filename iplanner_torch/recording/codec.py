"""JSON encoding of numeric arrays and free-form values for MCAP messages, lossless for NaN
and infinities.

JSON has no NaN or infinity.

- Numeric arrays and numeric fields (:func:`encode_array`): a NaN is written as ``null`` and
  an infinity as the string ``"inf"`` or ``"-inf"``; :func:`decode_array` maps them back.
- Free-form values (the episode metadata, metrics and event details; :func:`encode_value`,
  value codec ``"2"``): a NaN is written as the string ``"nan"``, an infinity as ``"inf"`` or
  ``"-inf"``, ``None`` as ``null``, and a string that would read as one of them (``"nan"``,
  ``"inf"``, ``"-inf"``) or that starts with ``~`` gets a ``~`` in front. So
  :func:`decode_value` gives back every value as it was: ``None`` stays ``None`` and the
  string ``"inf"`` stays a string. Mappings need string keys (JSON's object keys are strings:
  ``{1: "a"}`` would read back as ``{"1": "a"}``), values may nest at most
  :data:`MAX_VALUE_DEPTH` levels (a structure that holds itself never ends), and complex
  numbers are refused (a float has no imaginary part): :func:`encode_value` raises on them.

Logs written before the value codec was recorded (value codec ``"1"``) wrote a free-form NaN
as ``null`` and strings as they were; :func:`decode_value` with ``codec="1"`` reads them as
then: ``null`` and the strings ``"inf"`` / ``"-inf"`` as floats.

Finite numbers are written with Python's shortest round-trip ``repr`` of the float64 value, so
float32 and float64 inputs come back bit-identical (as float64).
"""

from __future__ import annotations

import json
import math
import reprlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

from iplanner_torch.errors import DataError


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
    """The float64 array of a value written by :func:`encode_array` (None -> NaN).

    Raises:
        DataError: for a value that is not such an array (ragged lists, text other than
            ``"inf"`` / ``"-inf"``, a dict): numpy's ValueError or TypeError, named.
    """
    try:
        return np.array(value, dtype=np.float64)
    except (ValueError, TypeError) as err:
        raise DataError(
            f"not an array of numbers as encode_array writes them ({err}): {reprlib.repr(value)}"
        ) from None


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


#: The value codec :func:`encode_value` writes (see the module docstring); episode logs record
#: it beside their metadata.
VALUE_CODEC = "2"
#: The value codecs :func:`decode_value` reads.
VALUE_CODECS = ("1", "2")

#: Free-form strings that would read as a number, so they are written with ``~`` in front.
_NUMBER_WORDS = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def _free_scalar(x: Any) -> Any:
    """One free-form scalar as :func:`encode_value` writes it."""
    if isinstance(x, str):
        return "~" + x if x in _NUMBER_WORDS or x.startswith("~") else x
    if isinstance(x, float) and math.isnan(x):
        return "nan"
    return encode_scalar(x)  # bool, None, int, finite float, +-inf


#: How deep free-form values may nest (mappings and lists in one another): a reader decodes
#: them recursively, so a deeper value could be written but not read back.
MAX_VALUE_DEPTH = 100


def encode_value(x: Any, _depth: int = 0) -> Any:
    """Recursively make dicts, lists, tensors and numbers JSON-safe, losslessly (value codec
    ``"2"`` of the module docstring: NaN as ``"nan"``, ``None`` as ``null``, strings that
    would read as numbers escaped with ``~``).

    Raises:
        TypeError: on a mapping key that is not a string, or a complex number or array.
        ValueError: on values nested deeper than :data:`MAX_VALUE_DEPTH` (or holding
            themselves).
    """
    if _depth > MAX_VALUE_DEPTH:
        raise ValueError(
            f"nested deeper than {MAX_VALUE_DEPTH} levels (or a value that holds itself)"
        )
    if isinstance(x, Mapping):
        bad = [k for k in x if not isinstance(k, str)]
        if bad:
            raise TypeError(f"keys must be strings (JSON object keys), got {bad[0]!r}")
        return {k: encode_value(v, _depth + 1) for k, v in x.items()}
    if isinstance(x, torch.Tensor | np.ndarray):
        if x.dtype == torch.bool or (isinstance(x, np.ndarray) and x.dtype == np.bool_):
            return as_numpy(x, dtype=bool).tolist()
        if x.is_complex() if isinstance(x, torch.Tensor) else np.iscomplexobj(x):
            raise TypeError(f"complex values are not real numbers: dtype {x.dtype}")
        a = as_numpy(x)
        if np.isfinite(a).all():
            return a.tolist()
        return np.vectorize(_free_scalar, otypes=[object])(a.astype(object)).tolist()
    if isinstance(x, Sequence) and not isinstance(x, str | bytes):
        return [encode_value(v, _depth + 1) for v in x]
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return _free_scalar(float(x))
    return _free_scalar(x)


def decode_value(x: Any, codec: str = VALUE_CODEC) -> Any:
    """Recursive inverse of :func:`encode_value` (``codec="2"``), or the reading of a log
    written before the value codec was recorded (``codec="1"``: ``null`` and the strings
    ``"inf"`` / ``"-inf"`` as floats, other strings as they are).

    Raises:
        ValueError: on a codec other than those in :data:`VALUE_CODECS`.
    """
    if codec not in VALUE_CODECS:
        raise ValueError(f"unknown value codec {codec!r}, expected one of {VALUE_CODECS}")
    return _decode(x, codec == "1")


def _decode(x: Any, legacy: bool) -> Any:
    if isinstance(x, dict):
        return {k: _decode(v, legacy) for k, v in x.items()}
    if isinstance(x, list):
        return [_decode(v, legacy) for v in x]
    if legacy:
        return decode_scalar(x)
    if isinstance(x, str):
        if x in _NUMBER_WORDS:
            return _NUMBER_WORDS[x]
        return x[1:] if x.startswith("~") else x
    return x


def decode_scalar(x: Any) -> Any:
    """Inverse of :func:`encode_scalar`: ``null`` -> NaN, ``"inf"`` / ``"-inf"`` -> floats,
    others unchanged (the numeric fields of a message, and free-form values of codec "1")."""
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
