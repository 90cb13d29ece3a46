"""NaN-safe JSON encoding of arrays and metric values."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from iplanner_torch.errors import DataError
from iplanner_torch.recording.codec import (
    decode_array,
    decode_value,
    dumps,
    encode_array,
    encode_value,
    loads,
)


def test_arrays_round_trip_with_nan_and_inf() -> None:
    x = np.random.default_rng(0).normal(size=(4, 3, 2))
    x[0, 1, 1] = np.nan
    x[2, 0, 0] = np.inf
    x[3, 2, 1] = -np.inf
    enc = encode_array(torch.from_numpy(x))
    text = json.dumps(enc, allow_nan=False)  # valid JSON: no NaN / Infinity tokens
    assert "NaN" not in text and "Infinity" not in text and "null" in text
    np.testing.assert_array_equal(decode_array(json.loads(text)), x)


def test_float32_values_come_back_exactly() -> None:
    x = torch.randn(100, dtype=torch.float32)
    back = decode_array(loads(dumps({"v": encode_array(x)}))["v"])
    assert np.array_equal(back.astype(np.float32), x.numpy())


def test_encode_value_makes_nested_dicts_json_safe() -> None:
    v = {"a": math.nan, "b": [1.0, math.inf], "c": {"d": np.float32(2.5), "e": np.int64(3)}}
    enc = encode_value(v)
    assert enc == {"a": "nan", "b": [1.0, "inf"], "c": {"d": 2.5, "e": 3}}
    with pytest.raises(ValueError, match="Out of range float"):
        dumps({"x": math.nan})  # raw NaN is refused, never written


@pytest.mark.parametrize(
    ("value", "written"),
    [
        (None, None),
        (math.nan, "nan"),
        (-math.inf, "-inf"),
        ("inf", "~inf"),
        ("nan", "~nan"),
        ("~", "~~"),
        ("~inf", "~~inf"),
        ("infinite", "infinite"),
        ("", ""),
        ([None, "x", np.float64(math.nan)], [None, "x", "nan"]),
        (np.array([[math.nan, 2.0]]), [["nan", 2.0]]),
    ],
)
def test_free_form_values_are_written_apart_and_read_back(value: object, written: object) -> None:
    """Value codec "2": what is written for each case, and that decoding gives it back."""
    assert loads(dumps({"v": encode_value(value)}))["v"] == written
    back = decode_value(written)
    expected = value.tolist() if isinstance(value, np.ndarray) else value
    assert json.dumps(back) == json.dumps(expected)  # NaN as the token NaN: equal as text


def test_codec_1_reads_null_and_inf_strings_as_floats() -> None:
    """Logs written before the codec was recorded: null was NaN and "inf" the infinity."""
    back = decode_value({"a": None, "b": ["inf", "-inf"], "c": "~x"}, "1")
    assert math.isnan(back["a"]) and back["b"] == [math.inf, -math.inf] and back["c"] == "~x"
    with pytest.raises(ValueError, match="unknown value codec '3'"):
        decode_value({}, "3")


@pytest.mark.parametrize("value", [[[1.0, 2.0], [3.0]], "abc", {"a": 1}, ["1", "x"]])
def test_decode_array_names_a_value_that_is_no_array(value) -> None:
    """numpy's ValueError or TypeError became a DataError naming the value."""
    with pytest.raises(DataError, match=r"^not an array of numbers as encode_array writes them"):
        decode_array(value)
