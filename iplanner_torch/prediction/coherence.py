"""Temporal coherence of actions: next-action histograms (paper sec. 4.1, eq. next_action).

From every labelled frame s of every demonstration, the tuple (progress state p_s, current action
c_s, next action n_s) is counted into a histogram ``h(n; p, c)``; the next action is the first
label after s that differs from c_s (frames whose next action is unknown, ``n < 0``, are
skipped). Then ``p(n | p, c) = h(n; p, c) / sum_k h(k; p, c)`` (eq. next_action).

Bit ``a`` of a progress bitmask ``p`` means action ``a`` has been completed. The *allowed* next
actions of (p, c) are those not completed in p and different from c (the next action differs
from the current one by definition).

* Seen pair (p, c): ``(h(n; p, c) + smoothing [n allowed]) / normaliser`` (additive smoothing on
  the allowed actions only; ``smoothing=0`` is the paper's plain normalised histogram).
* Unseen pair, seen p: the histogram marginalised over c, ``sum_c' h(n; p, c')``, with the count
  of ``n = c`` removed, smoothed the same way; if nothing is left, the next rule.
* Otherwise: uniform over the allowed actions (over all actions but c when none is allowed, and
  ``[1]`` when A = 1).

:meth:`NextActionModel.prob_given_progress` gives ``p(n | p) = sum_c h(n; p, c) / sum_{n, c}
h(n; p, c)`` (the empirical mixture over c), smoothed on the actions not completed in p, uniform
over those actions for an unseen p; the task planner uses it.
"""

from __future__ import annotations

import operator
from typing import Any

import torch
from torch import Tensor

from iplanner_torch.errors import CheckpointError, ConfigError, DataError, ShapeError
from iplanner_torch.types import check_shape

__all__ = ["NextActionModel"]


def _check_int(name: str, t: Tensor, n: int | None = None) -> None:
    check_shape(name, t, (n if n is not None else "B",))
    if t.dtype != torch.int64:
        raise ShapeError(f"expected {name} int64, got {t.dtype}")


def _pair(p: Any, c: Any, num_actions: int) -> tuple[int, int]:
    """``(p, c)`` as ints: a progress bitmask >= 0 and an action in [0, num_actions).

    Raises:
        ConfigError: for anything else (``int()`` used to truncate 0.5 to 0 and take -1 or 9).
    """
    out = []
    for name, v in (("progress", p), ("current action", c)):
        try:
            if isinstance(v, bool):
                raise TypeError
            out.append(operator.index(v))
        except TypeError:
            raise ConfigError(
                f"NextActionModel: expected the {name} an integer, got {v!r}"
            ) from None
    if out[0] < 0:
        raise ConfigError(f"NextActionModel: expected the progress bitmask >= 0, got {out[0]}")
    if not 0 <= out[1] < num_actions:
        raise ConfigError(
            f"NextActionModel: expected the current action in [0, {num_actions}), got {out[1]}"
        )
    return out[0], out[1]


class NextActionModel:
    """``p(n | p, c)`` from next-action histograms (eq. next_action).

    Attributes (after ``fit``):
        counts_: dict (progress, current) -> (A,) float64 counts h(n; p, c).
    """

    def __init__(self) -> None:
        self.num_actions = 0
        self.smoothing = 1.0
        self.counts_: dict[tuple[int, int], Tensor] = {}
        self._by_progress: dict[int, Tensor] = {}

    def fit(
        self,
        progress: Tensor,
        current: Tensor,
        next_action: Tensor,
        *,
        num_actions: int,
        smoothing: float = 1.0,
    ) -> NextActionModel:
        """Count the tuples.

        Args:
            progress: (N,) int64 progress bitmasks (bit a set: action a completed).
            current: (N,) int64 current action in [0, A).
            next_action: (N,) int64 next action in [0, A), or < 0 when unknown (skipped).
            num_actions: A.
            smoothing: additive count given to every allowed action of a seen pair (>= 0).

        Returns:
            self.

        Raises:
            ShapeError: on wrong shapes or dtypes. ConfigError: on bad A or smoothing.
            DataError: on labels out of range.
        """
        if num_actions < 1:
            raise ConfigError(f"expected num_actions >= 1, got {num_actions}")
        if not smoothing >= 0:
            raise ConfigError(f"expected smoothing >= 0, got {smoothing}")
        _check_int("progress", progress)
        n = progress.shape[0]
        _check_int("current", current, n)
        _check_int("next_action", next_action, n)
        keep = next_action >= 0
        p, c, nx = progress[keep].cpu(), current[keep].cpu(), next_action[keep].cpu()
        for name, t in (("current", c), ("next_action", nx)):
            if len(t) and (int(t.min()) < 0 or int(t.max()) >= num_actions):
                raise DataError(f"expected {name} in [0, {num_actions}), got values {t.unique()}")
        if len(p) and int(p.min()) < 0:
            raise DataError("expected progress bitmasks >= 0")
        self.num_actions = int(num_actions)
        self.smoothing = float(smoothing)
        self.counts_ = {}
        for pp, cc, nn in zip(p.tolist(), c.tolist(), nx.tolist()):
            h = self.counts_.setdefault(
                (pp, cc), torch.zeros(self.num_actions, dtype=torch.float64)
            )
            h[nn] += 1.0
        self._index()
        return self

    def _index(self) -> None:
        self._by_progress = {}
        for (p, _), h in self.counts_.items():
            if p in self._by_progress:
                self._by_progress[p] = self._by_progress[p] + h
            else:
                self._by_progress[p] = h.clone()

    def _not_completed(self, p: int) -> Tensor:
        """(A,) bool: actions whose bit is not set in p."""
        bits = torch.arange(self.num_actions)
        return ((p >> bits) & 1) == 0

    def _smoothed(self, h: Tensor, allowed: Tensor) -> Tensor | None:
        w = h + self.smoothing * allowed.double()
        total = float(w.sum())
        return w / total if total > 0 else None

    def next_action_prob(self, p: int, c: int) -> Tensor:
        """``p(n | p, c)`` for one pair (see the module docstring for the fallbacks).

        Args:
            p: progress bitmask.
            c: current action in [0, A).

        Returns:
            (A,) float64 probabilities summing to 1.

        Raises:
            CheckpointError: before fit.
            ConfigError: for a ``p`` or ``c`` that is not an integer (a bool or a float
                included), a negative ``p``, or a ``c`` outside [0, A).
        """
        if self.num_actions == 0:
            raise CheckpointError("NextActionModel is not fitted: call fit() or from_state_dict()")
        p, c = _pair(p, c, self.num_actions)
        a = self.num_actions
        others = torch.arange(a) != c
        allowed = self._not_completed(p) & others
        if (p, c) in self.counts_:
            out = self._smoothed(self.counts_[(p, c)], allowed)
            if out is not None:
                return out
        if p in self._by_progress:
            h = self._by_progress[p] * others.double()
            if float(h.sum()) > 0:
                out = self._smoothed(h, allowed)
                if out is not None:
                    return out
        if a == 1:
            return torch.ones(1, dtype=torch.float64)
        mask = allowed if bool(allowed.any()) else others
        return mask.double() / float(mask.sum())

    def prob(self, progress: Tensor, current: Tensor) -> Tensor:
        """``p(n | p, c)`` for a batch.

        Args:
            progress: (B,) int64 progress bitmasks.
            current: (B,) int64 current actions.

        Returns:
            (B, A) float64 probabilities (on progress's device), rows sum to 1.

        Raises:
            ShapeError: unless both are (B,) int64.
            ConfigError: as :meth:`next_action_prob`, naming the first bad row.
        """
        _check_int("progress", progress)
        _check_int("current", current, progress.shape[0])
        rows: dict[tuple[int, int], Tensor] = {}
        pairs = list(zip(progress.cpu().tolist(), current.cpu().tolist()))
        out = (
            torch.stack([rows.setdefault(k, self.next_action_prob(*k)) for k in pairs])
            if pairs
            else torch.zeros(0, self.num_actions, dtype=torch.float64)
        )
        return out.to(progress.device)

    def prob_given_progress(self, progress: Tensor) -> Tensor:
        """``p(n | p)`` marginalised over the current action (empirical mixture over c).

        Args:
            progress: (B,) int64 progress bitmasks.

        Returns:
            (B, A) float64 probabilities, rows sum to 1.
        """
        if self.num_actions == 0:
            raise CheckpointError("NextActionModel is not fitted: call fit() or from_state_dict()")
        _check_int("progress", progress)
        cache: dict[int, Tensor] = {}

        def one(p: int) -> Tensor:
            allowed = self._not_completed(p)
            if p in self._by_progress:
                out = self._smoothed(self._by_progress[p], allowed)
                if out is not None:
                    return out
            mask = (
                allowed if bool(allowed.any()) else torch.ones(self.num_actions, dtype=torch.bool)
            )
            return mask.double() / float(mask.sum())

        ps = progress.cpu().tolist()
        if not ps:
            return torch.zeros(0, self.num_actions, dtype=torch.float64, device=progress.device)
        out = torch.stack([cache.setdefault(p, one(p)) for p in ps])
        return out.to(progress.device)

    def state_dict(self) -> dict[str, Any]:
        """Counts as tensors: keys (K, 2) int64 (progress, current), counts (K, A) float64."""
        keys = sorted(self.counts_)
        return {
            "format": "next_action/1",
            "num_actions": self.num_actions,
            "smoothing": self.smoothing,
            "keys": torch.tensor(keys, dtype=torch.int64).view(-1, 2),
            "counts": (
                torch.stack([self.counts_[k] for k in keys])
                if keys
                else torch.zeros(0, self.num_actions, dtype=torch.float64)
            ),
        }

    @classmethod
    def from_state_dict(cls, d: dict[str, Any]) -> NextActionModel:
        """Rebuild from :meth:`state_dict`.

        Raises:
            CheckpointError: on a dict of another format.
        """
        if d.get("format") != "next_action/1":
            raise CheckpointError(
                "expected a next-action state dict (format next_action/1), "
                f"got {d.get('format')!r}"
            )
        obj = cls()
        obj.num_actions = int(d["num_actions"])
        obj.smoothing = float(d["smoothing"])
        obj.counts_ = {
            (int(k[0]), int(k[1])): h.double().clone()
            for k, h in zip(d["keys"].tolist(), d["counts"])
        }
        obj._index()
        return obj
