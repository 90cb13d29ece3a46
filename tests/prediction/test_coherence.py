"""Next-action histograms (eq. next_action) on a hand-made label sequence."""

from __future__ import annotations

import pytest
import torch

from iplanner_torch.errors import CheckpointError, ConfigError, DataError, ShapeError
from iplanner_torch.prediction.coherence import NextActionModel


def _tuples():
    """(progress, current, next) per frame of three demonstrations with A = 4.

    demo 1 labels 0 0 1 2 2, demo 2 labels 0 2 1, demo 3 labels 0 0 3; progress is the bitmask
    of actions completed before the frame, next the first different later label (-1: none).
    """
    rows = [
        (0b000, 0, 1), (0b000, 0, 1), (0b001, 1, 2), (0b011, 2, -1), (0b011, 2, -1),
        (0b000, 0, 2), (0b001, 2, 1), (0b101, 1, -1),
        (0b000, 0, 3), (0b000, 0, 3), (0b001, 3, -1),
    ]  # fmt: skip
    p, c, n = (torch.tensor(col, dtype=torch.int64) for col in zip(*rows))
    return p, c, n


def _fit(smoothing: float) -> NextActionModel:
    p, c, n = _tuples()
    return NextActionModel().fit(p, c, n, num_actions=4, smoothing=smoothing)


def _t(*v: float) -> torch.Tensor:
    return torch.tensor(v, dtype=torch.float64)


def test_exact_counts_without_smoothing():
    m = _fit(0.0)
    assert torch.equal(m.counts_[(0, 0)], _t(0, 2, 1, 2))
    torch.testing.assert_close(m.next_action_prob(0, 0), _t(0, 2 / 5, 1 / 5, 2 / 5))
    torch.testing.assert_close(m.next_action_prob(1, 1), _t(0, 0, 1, 0))
    torch.testing.assert_close(m.next_action_prob(1, 2), _t(0, 1, 0, 0))
    assert (0b011, 2) not in m.counts_  # next action unknown: not counted


def test_smoothing_only_on_allowed_actions():
    m = _fit(1.0)
    # p = 0, c = 0: allowed {1, 2, 3}
    torch.testing.assert_close(m.next_action_prob(0, 0), _t(0, 3 / 8, 2 / 8, 3 / 8))
    # p = 0b001, c = 1: allowed {2, 3}
    torch.testing.assert_close(m.next_action_prob(1, 1), _t(0, 0, 2 / 3, 1 / 3))
    # p = 0b001, c = 2: allowed {1, 3}
    torch.testing.assert_close(m.next_action_prob(1, 2), _t(0, 2 / 3, 0, 1 / 3))


@pytest.mark.parametrize("smoothing,want", [(0.0, (0, 0.5, 0.5, 0)), (1.0, (0, 0.5, 0.5, 0))])
def test_unseen_pair_uses_marginal_over_current(smoothing, want):
    m = _fit(smoothing)
    # (0b001, 3) unseen; p seen with counts n=2 (c=1) and n=1 (c=2); allowed {1, 2}
    torch.testing.assert_close(m.next_action_prob(1, 3), _t(*want))


def test_unseen_progress_is_uniform_over_allowed():
    m = _fit(1.0)
    torch.testing.assert_close(m.next_action_prob(0b011, 2), _t(0, 0, 0, 1))
    torch.testing.assert_close(m.next_action_prob(0b1111, 0), _t(0, 1 / 3, 1 / 3, 1 / 3))
    torch.testing.assert_close(m.next_action_prob(0b0100, 1), _t(0.5, 0, 0, 0.5))


def test_batched_prob_and_progress_marginal():
    m = _fit(1.0)
    p = torch.tensor([0, 1, 1, 0b011, 0b1111, 0b0110])
    c = torch.tensor([0, 1, 3, 2, 0, 1])
    probs = m.prob(p, c)
    assert probs.shape == (6, 4)
    torch.testing.assert_close(probs.sum(-1), torch.ones(6, dtype=torch.float64))
    for row, (pp, cc) in enumerate(zip(p.tolist(), c.tolist())):
        torch.testing.assert_close(probs[row], m.next_action_prob(pp, cc))
    marg = m.prob_given_progress(torch.tensor([0, 1, 0b0110]))
    torch.testing.assert_close(marg[0], _t(1, 3, 2, 3) / 9)
    torch.testing.assert_close(marg[1], _t(0, 2, 2, 1) / 5)
    torch.testing.assert_close(marg[2], _t(0.5, 0, 0, 0.5))
    plain = _fit(0.0).prob_given_progress(torch.tensor([0]))
    torch.testing.assert_close(plain[0], _t(0, 0.4, 0.2, 0.4))


def test_state_dict_round_trip_and_errors():
    m = _fit(0.5)
    again = NextActionModel.from_state_dict(m.state_dict())
    p = torch.tensor([0, 1, 1, 5, 0b011])
    c = torch.tensor([0, 1, 3, 0, 2])
    assert torch.equal(again.prob(p, c), m.prob(p, c))
    assert torch.equal(again.prob_given_progress(p), m.prob_given_progress(p))
    with pytest.raises(CheckpointError, match="next_action/1"):
        NextActionModel.from_state_dict({"format": "ivm/1"})
    with pytest.raises(CheckpointError, match="not fitted"):
        NextActionModel().next_action_prob(0, 0)
    pp, cc, nn = _tuples()
    with pytest.raises(ShapeError, match=r"expected current \(11\), got \(10,\)"):
        NextActionModel().fit(pp, cc[:10], nn, num_actions=4)
    with pytest.raises(DataError, match=r"next_action in \[0, 3\)"):
        NextActionModel().fit(pp, cc, nn, num_actions=3)
    with pytest.raises(ConfigError, match="smoothing >= 0"):
        NextActionModel().fit(pp, cc, nn, num_actions=4, smoothing=-1.0)


@pytest.mark.parametrize(
    ("p", "c", "message"),
    [
        (0, 9, r"current action in \[0, 4\), got 9"),
        (0, -1, r"current action in \[0, 4\), got -1"),
        (-2, 0, r"progress bitmask >= 0, got -2"),
        (0.5, 0, r"progress an integer, got 0.5"),
        (0, 1.0, r"current action an integer, got 1.0"),
        (True, 0, r"progress an integer, got True"),
    ],
)
def test_out_of_range_pairs_are_refused(p, c, message):
    """They gave a plausible distribution (int() truncated 0.5, and -1 or 9 picked no row)."""
    m = _fit(0.5)
    with pytest.raises(ConfigError, match=f"^NextActionModel: expected the {message}$"):
        m.next_action_prob(p, c)
    if isinstance(p, int) and isinstance(c, int) and not isinstance(p, bool):
        with pytest.raises(ConfigError, match=message):
            m.prob(torch.tensor([0, p]), torch.tensor([0, c]))


def test_integer_kinds_are_taken() -> None:
    """numpy and 0-d torch integers are integers (operator.index)."""
    import numpy as np

    m = _fit(0.5)
    want = m.next_action_prob(1, 3)
    assert torch.equal(m.next_action_prob(np.int64(1), torch.tensor(3)), want)
