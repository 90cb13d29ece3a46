"""Task-state conditioning of forecasts (Forecast.mask_actions, the episode's action_mask) and
the validation of a Forecast's values."""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pytest
import torch

from iplanner_torch.errors import DataError, ShapeError
from iplanner_torch.eval.episode import action_mask, reaction_delays, rest_hold
from iplanner_torch.prediction.forecast import Forecast


def _forecast(weights: list[list[float]]) -> Forecast:
    w = torch.tensor(weights, dtype=torch.float64)
    b, a = w.shape
    mean = torch.randn(b, a, 4, 2, 3, dtype=torch.float64)
    return Forecast(
        weights=w,
        mean=mean,
        var=torch.ones_like(mean),
        dt=0.1,
        joint_names=("a", "b"),
        action_names=tuple(f"x{i}" for i in range(a)),
    )


def test_mask_renormalises_the_kept_weights_and_keeps_the_gaussians() -> None:
    f = _forecast([[0.5, 0.3, 0.2], [0.0, 0.0, 1.0]])
    g = f.mask_actions(torch.tensor([True, False, True]))
    assert torch.allclose(
        g.weights[0], torch.tensor([0.5 / 0.7, 0.0, 0.2 / 0.7], dtype=g.weights.dtype)
    )
    assert torch.equal(g.weights[1], f.weights[1])
    assert g.mean is f.mean and g.var is f.var
    # a row whose every weighted action is ruled out keeps its belief
    h = f.mask_actions(torch.tensor([[True, True, False], [True, True, False]]))
    assert torch.equal(h.weights[1], f.weights[1])
    expected = torch.tensor([0.625, 0.375, 0.0], dtype=h.weights.dtype)
    assert torch.allclose(h.weights[0], expected)
    with pytest.raises(ShapeError):
        f.mask_actions(torch.tensor([True, False]))


def test_action_mask_rules_out_takes_of_blocks_not_on_their_spot() -> None:
    names = ("idle", "take_0", "take_1", "reach_3", "Take_2")
    keep = action_mask(names, available={1, 2})
    assert keep.tolist() == [True, False, True, False, True]
    assert action_mask(names, available=set()).tolist() == [True, False, False, False, False]


def test_hold_actions_freezes_only_the_held_actions_at_frame_zero() -> None:
    f = _forecast([[0.5, 0.3, 0.2]])
    f.var = torch.rand_like(f.mean) + 0.1
    g = f.hold_actions(torch.tensor([True, False, False]))
    for k in range(f.horizon):
        assert torch.equal(g.mean[:, 0, k], f.mean[:, 0, 0])
        assert torch.equal(g.var[:, 0, k], f.var[:, 0, 0])
    assert torch.equal(g.mean[:, 1:], f.mean[:, 1:])
    assert torch.equal(g.var[:, 1:], f.var[:, 1:])
    assert torch.equal(g.weights, f.weights)
    with pytest.raises(ShapeError):
        f.hold_actions(torch.tensor([True, False]))


def test_rest_hold_only_when_no_take_is_possible() -> None:
    names = ("idle", "reach_0", "reach_1", "return")
    none_left = action_mask(names, available=set())
    assert rest_hold(names, none_left).tolist() == [True, False, False, False]
    one_left = action_mask(names, available={1})
    assert not rest_hold(names, one_left).any()
    # a predictor without take actions: nothing is known about availability, nothing is held
    assert not rest_hold(("idle", "wave"), torch.tensor([True, True])).any()


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_forecast_is_rejected_naming_field_and_joint(bad: float) -> None:
    """A NaN forecast must never reach the planner: its collision bound reads it as no human."""
    f = _forecast([[0.5, 0.3, 0.2]])
    var = f.var.clone()
    var[0, 1, 2, 1, 0] = bad
    with pytest.raises(DataError, match=r"forecast var is NaN/Inf for joint 'b' .*'x1'.*frame 2"):
        replace(f, var=var)
    mean = f.mean.clone()
    mean[0, 2, 3, 0, 2] = bad
    with pytest.raises(DataError, match="forecast mean is NaN/Inf for joint 'a'"):
        replace(f, mean=mean)
    weights = f.weights.clone()
    weights[0, 0] = bad
    with pytest.raises(DataError, match="forecast weights is NaN/Inf for action 'x0'"):
        replace(f, weights=weights)
    with pytest.raises(DataError, match="dt"):
        replace(f, dt=bad)
    # shapes are still checked first
    with pytest.raises(ShapeError, match="expected var"):
        replace(f, var=var[:, :, :2])


@pytest.mark.parametrize("dt", [0.0, -0.1, "fast", None])
def test_forecast_dt_must_be_a_positive_number(dt: object) -> None:
    f = _forecast([[1.0]])
    with pytest.raises(DataError, match="expected forecast dt a"):
        replace(f, dt=dt)


def test_action_names_must_name_every_action() -> None:
    f = _forecast([[0.5, 0.5]])
    with pytest.raises(ShapeError, match=r"expected 2 action names .* got 1: \('x0',\)"):
        replace(f, action_names=("x0",))


def test_negative_variances_are_kept_and_every_derived_forecast_still_builds() -> None:
    f = _forecast([[0.5, 0.3, 0.2], [0.2, 0.2, 0.6]])
    f.var = -0.01 * torch.ones_like(f.mean)  # documented: floored by the planner, not rejected
    g = replace(f, var=f.var.clone())
    assert float(g.var.max()) < 0.0
    assert replace(g, dt=np.float64(1 / 15)).horizon == 4
    derived = [
        g.mask_actions(torch.tensor([True, False, True])),
        g.mask_actions(torch.tensor([[False, False, False], [True, True, False]])),
        g.hold_actions(torch.tensor([True, False, False])),
        g.select(1),
        g.select(slice(0, 2)),
        g.to("cpu"),
    ]
    # derived copies skip __post_init__; building each anew runs every check on it
    for d in derived:
        assert isinstance(d, Forecast) and d is not g
        rebuilt = replace(d)
        for name in ("weights", "mean", "var"):
            assert torch.equal(getattr(rebuilt, name), getattr(d, name))
    assert [d.batch_size for d in derived] == [2, 2, 2, 1, 2, 2]
    assert torch.equal(g.weights, replace(f, var=f.var).weights)  # g itself is unchanged


@pytest.mark.parametrize(
    ("weights", "shown"),
    [
        ([[0.5, 0.5], [0.0, 0.0]], "batch 1 are not probabilities: [0.0, 0.0] (sum 0)"),
        ([[1.0, 1.0]], "batch 0 are not probabilities: [1.0, 1.0] (sum 2)"),
        ([[1.5, -0.5]], "batch 0 are not probabilities: [1.5, -0.5] (sum 1)"),
        ([[0.9, 0.09]], "batch 0 are not probabilities: [0.9, 0.09] (sum 0.99)"),
    ],
)
def test_weights_that_are_not_probabilities_are_refused(
    weights: list[list[float]], shown: str
) -> None:
    """All-zero weights would make the collision bound 0 (the person unseen by the planner),
    so weights must be >= 0 and sum to 1; float rounding is tolerated."""
    with pytest.raises(DataError, match=re.escape(f"forecast weights of {shown}; expected")):
        _forecast(weights)
    _forecast([[0.5, 0.5 + 1e-4], [1.0, 0.0]])  # rounding within WEIGHT_SUM_TOL


def test_weights_of_a_large_batch_are_checked_with_tensors_alike() -> None:
    """Above _SMALL_WEIGHTS entries the weights are checked with tensor operations (one host
    sync): the same refusal, and float rounding tolerated."""
    from iplanner_torch.prediction.forecast import _SMALL_WEIGHTS

    rows = [[0.25, 0.25, 0.25, 0.25 + 1e-4]] * (_SMALL_WEIGHTS // 4 + 1)
    _forecast(rows)
    with pytest.raises(DataError, match=re.escape("weights of batch 5 are not probabilities")):
        _forecast(rows[:5] + [[0.0, 0.0, 0.0, 0.0]] + rows[6:])
    with pytest.raises(DataError, match=re.escape("weights is NaN/Inf for action 'x1' (batch 2)")):
        _forecast(rows[:2] + [[0.5, math.nan, 0.25, 0.25]] + rows[3:])


def test_delay_actions_shifts_each_actions_frames_later() -> None:
    """Frame k of a delayed action is frame max(0, k - d) of the forecast (a loop over the
    frames); a delay of 0 keeps the action, one of n_f or more holds it as hold_actions."""
    f = _forecast([[0.5, 0.3, 0.2], [0.2, 0.2, 0.6]])
    delays = [0, 2, 9]
    g = f.delay_actions(torch.tensor(delays))
    assert torch.equal(g.weights, f.weights)
    for a, d in enumerate(delays):
        for k in range(f.horizon):
            src = max(0, k - d)
            assert torch.equal(g.mean[:, a, k], f.mean[:, a, src])
            assert torch.equal(g.var[:, a, k], f.var[:, a, src])
    held = f.hold_actions(torch.tensor([False, False, True]))
    assert torch.equal(g.mean[:, 2], held.mean[:, 2]) and torch.equal(g.var[:, 2], held.var[:, 2])


@pytest.mark.parametrize(
    ("frames", "error", "message"),
    [
        (torch.tensor([0.0, 1.0, 2.0]), ShapeError, "integer tensor"),
        (torch.tensor([True, False, True]), ShapeError, "integer tensor"),
        (torch.tensor([0, 1]), ShapeError, "frames"),
        (torch.tensor([0, -1, 2]), DataError, "expected frames >= 0"),
    ],
)
def test_delay_actions_refuses_bad_delays(frames, error, message) -> None:
    with pytest.raises(error, match=message):
        _forecast([[0.5, 0.3, 0.2]]).delay_actions(frames)


def test_reaction_delays_count_the_whole_frames_left_of_the_reaction() -> None:
    """take_1 landed 0.05 s before the observation: 0.25 s of a 0.3 s reaction are left, two
    whole frames of 0.1 s; take_2 landed long ago; take_3 is not available; idle is delayed
    by the least delay of the available takes."""
    names = ("idle", "take_1", "take_2", "take_3")
    landed = {1: 9.95, 2: 5.0, 3: 9.99}
    assert reaction_delays(names, {1}, landed, 10.0, 0.3, 0.1).tolist() == [2, 2, 0, 0]
    assert reaction_delays(names, {1, 2}, landed, 10.0, 0.3, 0.1).tolist() == [0, 2, 0, 0]
    # a block with no landing time (there from the start, or in the hand) is not delayed
    assert reaction_delays(names, {1, 3}, {1: 9.95}, 10.0, 0.3, 0.1).tolist() == [0, 2, 0, 0]
    # exactly 0.3 s left: three frames (not two after rounding), none once the time is up
    assert reaction_delays(names, {1}, {1: 10.0}, 10.0, 0.3, 0.1).tolist() == [3, 3, 0, 0]
    assert reaction_delays(names, {1}, {1: 9.7}, 10.0, 0.3, 0.1).tolist() == [0, 0, 0, 0]
    assert reaction_delays(names, set(), landed, 10.0, 0.3, 0.1).tolist() == [0, 0, 0, 0]
    assert reaction_delays(("reach_1",), {1}, landed, 10.0, 0.0, 0.1).tolist() == [0]


def test_hands_still_reads_tracker_noise_as_rest_and_a_reach_as_motion() -> None:
    from iplanner_torch.data.skeleton import JOINT_NAMES
    from iplanner_torch.eval.episode import HAND_JOINTS, hands_still

    rng = np.random.default_rng(0)
    rest = np.zeros((20, len(JOINT_NAMES), 3))
    noisy = rest + rng.normal(0.0, 0.01, rest.shape)  # 1 cm tracker noise
    assert hands_still(noisy, 4, 0.03)
    moving = noisy.copy()
    moving[:, HAND_JOINTS, 0] += np.linspace(0.0, 0.6, 20)[:, None]  # 0.45 m/s at 15 Hz
    assert not hands_still(moving, 4, 0.03)
    dropped = rest.copy()
    dropped[-1, HAND_JOINTS[0]] = np.nan
    assert not hands_still(dropped, 4, 0.03)
    assert not hands_still(rest[:1], 4, 0.03)
