"""The shared scalar checks (iplanner_torch.checks) and tensor checks (iplanner_torch.types)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import pytest
import torch

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.types import all_finite, check_finite, non_finite_error


@pytest.mark.parametrize(
    ("check", "good", "bad"),
    [
        (checks.finite, [0, -2.5, np.float32(1.5), np.int64(3)], [math.nan, True, "1", None]),
        (checks.positive, [1e-9, 3, np.float64(2.0)], [0, -1, math.inf, math.nan, True]),
        (checks.non_negative, [0, 0.0, 7], [-1e-9, math.inf, math.nan, False]),
    ],
)  # fmt: skip
def test_real_checks_accept_and_refuse(check, good, bad) -> None:
    for value in good:
        out = check("x", value)
        assert isinstance(out, float) and out == float(value)
    for value in bad:
        with pytest.raises(ConfigError, match=r"expected x .*got"):
            check("x", value)
        with pytest.raises(DataError):  # the caller picks the exception type
            check("x", value, error=DataError)


def test_finite_tuple_integer_flag_seed() -> None:
    assert checks.finite_tuple("p", [1, 2.5], 2) == (1.0, 2.5)
    for value in ((1.0,), (1.0, math.nan), "ab", 3, (True, 1.0)):
        with pytest.raises(ConfigError, match="expected p a sequence of 2 finite numbers"):
            checks.finite_tuple("p", value, 2)
    assert checks.integer("n", np.int64(4), minimum=1) == 4 and checks.integer("n", -3) == -3
    for value in (0, 1.0, True, "2"):
        with pytest.raises(ConfigError, match="expected n an integer >= 1"):
            checks.integer("n", value, minimum=1)
    assert checks.flag("f", np.bool_(True)) is True
    with pytest.raises(ConfigError, match="expected f True or False, got 1"):
        checks.flag("f", 1)
    assert checks.seed(0) == 0
    with pytest.raises(ConfigError, match="expected seed an integer >= 0, got -1"):
        checks.seed(-1)


def test_finite_time_and_optional() -> None:
    assert checks.finite_time("t", torch.tensor(1.5)) == 1.5
    assert checks.finite_time("t", np.float32(0.25)) == 0.25
    with pytest.raises(DataError, match=r"expected t a finite time \[s\], got nan"):
        checks.finite_time("t", math.nan, error=DataError)
    for bad in ("soon", None, [1.0], 10**400):  # 10**400: beyond float range
        with pytest.raises(ConfigError, match="expected t a finite time"):
            checks.finite_time("t", bad)
    with pytest.raises(DataError, match="expected t a finite time"):
        checks.finite_time("t", "soon", error=DataError)
    assert checks.optional(checks.positive, "b", None) is None
    assert checks.optional(checks.positive, "b", 2) == 2.0
    with pytest.raises(ConfigError, match="expected b > 0"):
        checks.optional(checks.positive, "b", 0)


def test_check_finite_names_the_first_bad_entry() -> None:
    x = torch.zeros(3, 4, 2)
    check_finite("x", x)  # finite: no error
    x[1, 2, 1] = math.inf
    x[2, 0, 0] = math.nan
    with pytest.raises(DataError, match=r"^x is NaN/Inf at index \(1, 2, 1\)$"):
        check_finite("x", x)
    with pytest.raises(DataError, match=r"^x is NaN/Inf at window 1, frame 2: fill gaps$"):
        check_finite("x", x, ("window", "frame"), hint="fill gaps")
    with pytest.raises(DataError, match=r"^x is NaN/Inf at window 1, frame 2, 'b'$"):
        check_finite("x", x, ("window", "frame", ("a", "b")))


def test_non_finite_error_counts_for_tensors_and_arrays() -> None:
    x = np.array([1.0, np.nan, np.inf, -np.inf])
    for value in (x, torch.from_numpy(x)):
        err = non_finite_error("cov", value)
        assert isinstance(err, DataError)
        assert str(err) == "expected finite cov, got 1 NaN and 2 Inf among 4 values"


@pytest.mark.parametrize("dtype", [torch.float16, torch.float32, torch.float64, torch.complex64])
@pytest.mark.parametrize("n", [1, 7, 1000, 40_001])
def test_all_finite_finds_one_bad_entry_anywhere(dtype: torch.dtype, n: int) -> None:
    g = torch.Generator().manual_seed(n)
    x = torch.randn(n, generator=g).to(dtype)
    assert all_finite(x) and all_finite(x, x[: n // 2], torch.zeros(3, dtype=torch.int64))
    positions = torch.randint(0, n, (5,), generator=g).tolist() + [0, n - 1]
    for i in positions:
        for bad in (math.nan, math.inf, -math.inf):
            y = x.clone()
            y[i] = bad
            assert not all_finite(y), (i, bad)
            assert not all_finite(x, y)  # any tensor of several
    y = x.clone()
    y[0], y[-1] = math.inf, -math.inf  # the sum is NaN, not inf
    assert not all_finite(y)


def test_all_finite_is_exact_when_a_sum_overflows() -> None:
    big = torch.full((4,), 60000.0, dtype=torch.float16)  # finite entries, the sum overflows
    assert math.isinf(float(big.sum())) and all_finite(big)
    huge = torch.full((3,), 3e38)  # float32 sums overflow too
    assert all_finite(huge, big)
    assert all_finite() and all_finite(torch.empty(0)) and all_finite(torch.ones(2, 2).bool())
    with pytest.raises(DataError, match=r"^x is NaN/Inf at index \(1,\)$"):
        check_finite("x", torch.tensor([3e38, math.nan, 3e38]))
    check_finite("x", huge)  # no false alarm


def test_path_argument() -> None:
    assert checks.path_argument("a/b.mcap", "of a log") == Path("a/b.mcap")
    assert checks.path_argument(Path("c"), "of a log") == Path("c")
    for bad in (None, 3, ["a"]):
        with pytest.raises(
            DataError, match=r"expected path a file path \(str or os.PathLike\) of"
        ):
            checks.path_argument(bad, "of a log")
    with pytest.raises(ConfigError, match="expected out a folder path .* for plots, got NoneType"):
        checks.path_argument(None, "for plots", kind="folder path", name="out", error=ConfigError)


def test_is_dir_answers_and_names_a_path_the_system_cannot_look_up(tmp_path) -> None:
    from iplanner_torch.checks import is_dir
    from iplanner_torch.errors import CheckpointError

    assert is_dir(tmp_path, "a folder") and not is_dir(tmp_path / "missing", "a folder")
    with pytest.raises(DataError, match=r"^'.{56}\.\.\.: cannot look up this path \(File name "
                       r"too long\); expected a folder$"):  # fmt: skip
        is_dir(tmp_path / ("x" * 300), "a folder")
    with pytest.raises(CheckpointError, match=r"^predictor checkpoint '.*; expected a file$"):
        long_path = tmp_path / ("x" * 300)
        is_dir(long_path, "a file", what="predictor checkpoint", error=CheckpointError)


@dataclass
class _Settings:
    flag: bool = False
    count: int = 1
    rate: float | None = None
    name: str = "a"
    mode: Literal["x", "y"] = "x"
    maybe: Literal["x", "y"] | None = None
    level: Literal[1, 2] = 1
    mixed: Literal[1, "a"] = 1
    both: int | float = 1
    items: list[int] = field(default_factory=list)


def test_field_kind_reads_each_annotation_form() -> None:
    Settings = _Settings
    kind = checks.field_kind
    assert kind(Settings, "flag") == checks.FieldKind(bool, False)
    assert kind(Settings, "count") == checks.FieldKind(int, False)
    assert kind(Settings, "rate") == checks.FieldKind(float, True)
    assert kind(Settings, "name") == checks.FieldKind(str, False)
    assert kind(Settings, "mode") == checks.FieldKind(str, False, ("x", "y"))
    assert kind(Settings, "maybe") == checks.FieldKind(str, True, ("x", "y"))
    assert kind(Settings, "level") == checks.FieldKind(int, False, (1, 2))
    assert kind(Settings, "mixed") == checks.FieldKind(object, False, (1, "a"))
    assert kind(Settings, "both") is None and kind(Settings, "items") is None
    assert kind(Settings, "absent") is None and kind(int, "real") is None


def test_field_kind_judges_an_unresolvable_annotation_by_its_default() -> None:
    @dataclass
    class Settings:
        speed: NoSuchType = 2.5  # type: ignore[name-defined] # noqa: F821
        table: NoSuchType = None  # type: ignore[name-defined] # noqa: F821

    assert checks.field_kind(Settings, "speed") == checks.FieldKind(float, True)
    assert checks.field_kind(Settings, "table") is None


@pytest.mark.parametrize(
    ("base", "good", "bad"),
    [
        (bool, [True, False], [0, 1, "true", None]),
        (int, [0, -3], [True, 1.0, "1", None]),
        (float, [0, 1.5, np.float64(2.0), math.inf], [True, "1.5", None]),
        (str, ["", "a"], [1, None, b"a"]),
    ],
)  # fmt: skip
def test_fits_kind_keeps_bools_apart_from_numbers(base, good, bad) -> None:
    assert all(checks.fits_kind(v, base) for v in good)
    assert not any(checks.fits_kind(v, base) for v in bad)
