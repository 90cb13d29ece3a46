"""Input validation of Forecast: batch selection, far-away means, empty shapes, dtypes and
the masks of the task-state conditioning."""

from __future__ import annotations

import re

import pytest
import torch

from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.prediction.forecast import _SMALL_WEIGHTS, Forecast
from iplanner_torch.types import MAX_POSITION_M


def _forecast(b: int = 3, a: int = 3, dtype: torch.dtype = torch.float64, **tensors) -> Forecast:
    g = torch.Generator().manual_seed(b * 10 + a)
    weights = torch.softmax(torch.randn(b, a, generator=g, dtype=torch.float64), -1).to(dtype)
    mean = torch.randn(b, a, 4, 2, 3, generator=g, dtype=torch.float64).to(dtype)
    fields = {"weights": weights, "mean": mean, "var": torch.ones_like(mean)} | tensors
    return Forecast(
        **fields, dt=0.1, joint_names=("a", "b"), action_names=tuple(f"x{i}" for i in range(a))
    )


def test_select_counts_negative_ints_from_the_end() -> None:
    """-1 used to become slice(-1, 0): an empty forecast that the planner then failed on."""
    f = _forecast(b=3)
    for index, row in ((-1, 2), (-3, 0), (2, 2), (torch.tensor(-2), 1)):
        g = f.select(index)
        assert g.batch_size == 1
        for name in ("weights", "mean", "var"):
            assert torch.equal(getattr(g, name), getattr(f, name)[row : row + 1])
    # the other index kinds still work and keep the batch dimension
    assert f.select(slice(0, 2)).batch_size == 2
    assert torch.equal(f.select(torch.tensor([2, 0])).weights, f.weights[[2, 0]])
    assert f.select(torch.tensor([True, False, True])).batch_size == 2
    assert f.select([1]).batch_size == 1


@pytest.mark.parametrize("index", [3, 5, -4])
def test_select_refuses_an_int_out_of_range_naming_b(index: int) -> None:
    with pytest.raises(ShapeError, match=rf"expected index in \[-3, 3\) .* B = 3, got {index}"):
        _forecast(b=3).select(index)


@pytest.mark.parametrize(
    ("index", "message"),
    [
        (slice(3, 5), "select at least one row of the batch (B = 3)"),
        (torch.tensor([], dtype=torch.int64), "select at least one row of the batch (B = 3)"),
        (torch.tensor([0, 3]), "does not index the batch of a forecast of B = 3"),
        (True, "select at least one row of the batch (B = 3)"),
        ((0, slice(None)), "expected index of the batch dimension only"),
    ],
)
def test_select_refuses_indices_that_give_no_usable_batch(index: object, message: str) -> None:
    with pytest.raises(ShapeError, match=re.escape(message)):
        _forecast(b=3).select(index)  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [1e30, -101.0, MAX_POSITION_M + 1e-3])
def test_mean_beyond_max_position_is_refused(value: float) -> None:
    """A forecast 1e30 m away is finite, and the planner read it as "no human near"."""
    f = _forecast(b=2)
    mean = f.mean.clone()
    mean[1, 2, 3, 1, 0] = value
    with pytest.raises(
        DataError,
        match=re.escape(f"forecast mean is {value:g} m for joint 'b' (batch 1, action 'x2', ")
        + r"frame 3\), beyond 100 m",
    ):
        _forecast(b=2, mean=mean)
    mean[1, 2, 3, 1, 0] = MAX_POSITION_M  # the bound itself is taken
    _forecast(b=2, mean=mean)


def test_mean_beyond_max_position_is_refused_in_a_large_batch_too() -> None:
    b = _SMALL_WEIGHTS // 3 + 1  # weights checked with tensor operations
    f = _forecast(b=b)
    mean = f.mean.clone()
    mean[b - 1, 0, 0, 0, 2] = -1e6
    with pytest.raises(DataError, match=rf"mean is -1e\+06 m .*\(batch {b - 1}, action 'x0'"):
        _forecast(b=b, mean=mean)
    mean[b - 1, 0, 0, 0, 2] = float("nan")  # NaN is still named as such
    with pytest.raises(DataError, match="forecast mean is NaN/Inf for joint 'a'"):
        _forecast(b=b, mean=mean)


@pytest.mark.parametrize(("b", "a"), [(0, 3), (2, 0), (0, 0)])
def test_empty_batch_or_no_action_is_refused(b: int, a: int) -> None:
    """A = 0 passed the all-zero-weights guard (no row to test); B = 0 failed in the planner."""
    mean = torch.zeros(b, a, 4, 2, 3, dtype=torch.float64)
    weights = torch.zeros(b, a, dtype=torch.float64)
    with pytest.raises(ShapeError, match=rf"B >= 1 and A >= 1, got \({b}, {a}\)"):
        Forecast(
            weights=weights,
            mean=mean,
            var=torch.ones_like(mean),
            dt=0.1,
            joint_names=("a", "b"),
            action_names=tuple(f"x{i}" for i in range(a)),
        )


def test_mixed_or_non_floating_dtypes_are_refused() -> None:
    f = _forecast(b=2)
    with pytest.raises(ShapeError, match="one dtype on one device, got weights torch.float32"):
        _forecast(b=2, weights=f.weights.float())
    with pytest.raises(ShapeError, match="one dtype on one device, .*var torch.float32"):
        _forecast(b=2, var=f.var.float())
    with pytest.raises(
        ShapeError, match="expected forecast mean of a floating dtype, got torch.int64"
    ):
        _forecast(b=2, mean=f.mean.round().long())
    one_hot = torch.zeros(2, 3, dtype=torch.bool)
    one_hot[:, 0] = True
    with pytest.raises(
        ShapeError, match="expected forecast weights of a floating dtype, got torch.bool"
    ):
        _forecast(b=2, weights=one_hot)
    for dtype in (torch.float32, torch.float64):  # one floating dtype: fine
        assert _forecast(b=2, dtype=dtype).expected_mean().dtype == dtype


@pytest.mark.parametrize(
    ("keep", "message"),
    [
        (
            torch.tensor([1.0, 0.0, 1.0]),
            "expected keep a bool tensor (A,) or (B, A), got torch.float32",
        ),
        (
            torch.tensor([[1, 0, 1]] * 2),
            "expected keep a bool tensor (A,) or (B, A), got torch.int64",
        ),
        ([True, False, True], "expected keep to be a torch.Tensor, got list"),
    ],
)
def test_mask_actions_takes_bool_masks_only(keep: object, message: str) -> None:
    with pytest.raises(ShapeError, match=re.escape(message)):
        _forecast(b=2).mask_actions(keep)  # type: ignore[arg-type]


def test_hold_actions_takes_bool_masks_only() -> None:
    f = _forecast(b=2)
    with pytest.raises(
        ShapeError, match=re.escape("expected hold a bool tensor (A,), got torch.float32")
    ):
        f.hold_actions(torch.tensor([1.0, 0.0, 0.0]))
    with pytest.raises(ShapeError, match="expected hold to be a torch.Tensor, got list"):
        f.hold_actions([True, False, False])  # type: ignore[arg-type]
    held = f.hold_actions(torch.tensor([True, False, False]))
    assert torch.equal(held.mean[:, 0, -1], f.mean[:, 0, 0])


def test_dt_string_or_bool_is_refused_and_numbers_become_float() -> None:
    """dt="0.1" passed (float() takes it) and Forecast.times then raised a bare TypeError;
    dt=True passed as 1 s. A one-element tensor or numpy number is stored as a float."""
    f = _forecast()
    fields = {k: getattr(f, k) for k in ("weights", "mean", "var", "joint_names")}
    fields["action_names"] = f.action_names
    for bad in ("0.1", True):
        with pytest.raises(DataError, match="expected forecast dt a number > 0"):
            Forecast(**fields, dt=bad)
    g = Forecast(**fields, dt=torch.tensor([0.1]))
    assert type(g.dt) is float and g.times.shape == (4,)


def test_select_of_a_reversing_slice_and_to_an_unknown_device_are_typed_errors() -> None:
    """select(slice(None, None, -1)) raised a bare ValueError from tensor indexing;
    to("nope") and to(3) on a machine without an accelerator raised bare RuntimeErrors."""
    f = _forecast()
    with pytest.raises(ShapeError, match="does not index the batch"):
        f.select(slice(None, None, -1))
    for bad in ("nope", "meta"):
        with pytest.raises(ConfigError, match="device"):
            f.to(bad)
    assert f.to("cpu").mean.device.type == "cpu"


@pytest.mark.parametrize("field", ["joint_names", "action_names"])
@pytest.mark.parametrize("names", [None, "ab", 3])
def test_names_that_are_not_a_sequence_of_names_are_refused(field: str, names: object) -> None:
    """joint_names or action_names None (or a number) raised a bare TypeError from len(); one
    string of as many letters as joints passed, its letters taken as names."""
    f = _forecast(a=2)
    fields = {k: getattr(f, k) for k in ("weights", "mean", "var", "dt")}
    fields |= {"joint_names": f.joint_names, "action_names": f.action_names, field: names}
    with pytest.raises(ShapeError, match=f"expected forecast {field} a sequence of names"):
        Forecast(**fields)
    fields[field] = list("ab")  # a list is fine
    assert Forecast(**fields).joint_names is not None
