"""The predictor's output: a mixture over actions of Gaussian future joint positions.

Paper eq. motion_prediction: p(xi_next | F, p) = sum_c p(c | F, p) p(xi_next | F, p, c).
"""

from __future__ import annotations

import copy
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from iplanner_torch import checks
from iplanner_torch.errors import DataError, ShapeError
from iplanner_torch.types import MAX_POSITION_M, check_shape, resolve_device

#: how far a row of forecast weights may sum from 1 (float32 rounding of A probabilities)
WEIGHT_SUM_TOL = 1e-3
#: weights of at most this many entries (on the CPU) are checked in Python, not with tensors
_SMALL_WEIGHTS = 256


@dataclass(kw_only=True)
class Forecast:
    """Per-action Gaussian forecasts of the next ``n_f`` frames and the action weights.

    Attributes:
        weights: (B, A) p(c = a | F_prev, p): >= 0, rows sum to 1 (within
            :data:`WEIGHT_SUM_TOL`); B >= 1 and A >= 1. ``weights``, ``mean`` and ``var`` share
            one floating dtype and one device.
        mean: (B, A, n_f, K, 3) predicted joint positions [m], world (table) frame, each
            coordinate within +-:data:`~iplanner_torch.types.MAX_POSITION_M`.
        var: (B, A, n_f, K, 3) per-coordinate variances [m^2] (independent output channels).
            Negative entries (rounding in a GP's predictive variance) are not rejected here:
            the planner floors them (:func:`~iplanner_torch.planning.costs.forecast_to_obstacle`
            keeps sphere-centre variances >= 1e-10).
        dt: seconds between consecutive predicted frames (1 / fps), finite and > 0; a real
            number (numpy scalars and one-element tensors are converted to float).
        joint_names: the K joint names.
        action_names: the A action names.

    Raises:
        ShapeError: when ``weights``, ``mean`` or ``var`` has the wrong shape (B = 0 or A = 0
            included), is not of a floating dtype, or they differ in dtype or device, or
            ``joint_names`` or ``action_names`` is not a sequence of names (None, one string)
            or ``action_names`` does not name A actions.
        DataError: when ``weights``, ``mean`` or ``var`` holds NaN or inf (naming the field
            and, for ``mean`` and ``var``, the joint), a coordinate of ``mean`` lies beyond
            :data:`~iplanner_torch.types.MAX_POSITION_M`, a row of ``weights`` is not
            probabilities (all 0 would hide the person), or ``dt`` is not a finite number > 0
            (a string or a bool included).
            A non-finite or far-away forecast must never reach the planner, whose collision
            bound would read it as "no human".
    """

    weights: torch.Tensor
    mean: torch.Tensor
    var: torch.Tensor
    dt: float
    joint_names: tuple[str, ...]
    action_names: tuple[str, ...]

    def __post_init__(self) -> None:
        for field_name in ("joint_names", "action_names"):
            names = getattr(self, field_name)
            if isinstance(names, str | bytes) or not isinstance(names, Sequence):
                raise ShapeError(
                    f"expected forecast {field_name} a sequence of names, got "
                    f"{type(names).__name__} {names!r}"
                )
        check_shape("weights", self.weights, ("B", "A"))
        b, a = self.weights.shape
        if b < 1 or a < 1:
            raise ShapeError(
                f"expected forecast weights (B, A) with B >= 1 and A >= 1, got {(b, a)}: a "
                "forecast needs a batch row and an action"
            )
        check_shape("mean", self.mean, (b, a, "n_f", len(self.joint_names), 3))
        check_shape("var", self.var, tuple(self.mean.shape))
        self._check_dtypes()
        if len(self.action_names) != a:
            raise ShapeError(
                f"expected {a} action names (weights (B, A) = {tuple(self.weights.shape)}), "
                f"got {len(self.action_names)}: {tuple(self.action_names)}"
            )
        try:
            if isinstance(self.dt, (str, bytes, bool)):  # float() takes them: "0.1", True
                raise TypeError(type(self.dt).__name__)
            dt = float(self.dt)
        except (TypeError, ValueError) as err:
            raise DataError(f"expected forecast dt a number > 0 [s], got {self.dt!r}") from err
        if not (math.isfinite(dt) and dt > 0.0):
            raise DataError(f"expected forecast dt a finite number > 0 [s], got {self.dt!r}")
        self.dt = dt  # a float, whatever number type (numpy, one-element tensor) it came as
        # weights that are not probabilities: negative, or rows not summing to 1 (NaN is left
        # to the finiteness check)
        w = self.weights
        if w.device.type == "cpu" and w.numel() <= _SMALL_WEIGHTS:
            # a planning cycle's forecast: a few numbers, checked in Python (one tolist) at a
            # fraction of the cost of a chain of tiny tensor operations
            rows = w.tolist()
            bad = any(min(r) < 0 or abs(sum(r) - 1) > WEIGHT_SUM_TOL for r in rows)
            if bad or not self._values_ok(None):
                self._raise_invalid()
            return
        # a batch: a flag that joins the one host sync of the value check
        invalid = (w < 0).any() | ((w.sum(-1) - 1).abs() > WEIGHT_SUM_TOL).any()
        if not self._values_ok(invalid):
            self._raise_invalid()

    def _check_dtypes(self) -> None:
        """ShapeError unless ``weights``, ``mean`` and ``var`` share one floating dtype and one
        device (integer or bool tensors, or a float32 / float64 mix, would fail later, in
        :meth:`expected_mean` or the planner, with a raw RuntimeError)."""
        fields = {"weights": self.weights, "mean": self.mean, "var": self.var}
        for name, t in fields.items():
            if not t.is_floating_point():
                raise ShapeError(f"expected forecast {name} of a floating dtype, got {t.dtype}")
        if (
            len({t.dtype for t in fields.values()}) > 1
            or len({t.device for t in fields.values()}) > 1
        ):
            got = ", ".join(f"{n} {t.dtype}/{t.device}" for n, t in fields.items())
            raise ShapeError(
                f"expected forecast weights, mean and var of one dtype on one device, got {got}"
            )

    def _values_ok(self, invalid: torch.Tensor | None) -> bool:
        """Whether ``weights``, ``mean`` and ``var`` are finite, every coordinate of ``mean``
        lies within +-:data:`MAX_POSITION_M` and ``invalid`` (a bool flag of other failed
        checks, or None) is not set: one host synchronisation (one ``tolist``).

        ``mean``'s extremes carry a NaN or an infinity into the range test, the sums of
        ``weights`` and ``var`` into the finiteness test. False may be a false alarm (a sum
        that overflowed): :meth:`_raise_invalid` then tells.
        """
        m = self.mean
        zero = m.new_zeros(())
        parts = [*torch.aminmax(m)] if m.numel() else [zero, zero]  # n_f = 0: nothing to test
        parts += [self.weights.sum(), self.var.sum()]
        if invalid is not None:
            parts.append(invalid.to(m.dtype))
        lo, hi, s_w, s_v, *flag = torch.stack(parts).tolist()  # the one host sync
        near = -MAX_POSITION_M <= lo and hi <= MAX_POSITION_M  # False on NaN
        return near and math.isfinite(s_w) and math.isfinite(s_v) and not any(flag)

    def _raise_invalid(self) -> None:
        """Raise :class:`DataError` naming the first field and entry that is NaN or inf, the
        first coordinate of ``mean`` beyond :data:`MAX_POSITION_M`, or the first row of
        weights that are not probabilities; return when there is none (a false alarm of
        :meth:`_values_ok`)."""
        bad_w = ~torch.isfinite(self.weights)
        if bool(bad_w.any()):
            b, a = (int(i) for i in bad_w.nonzero()[0])
            raise DataError(
                f"forecast weights is NaN/Inf for action {self._action(a)!r} (batch {b})"
            )
        for name in ("mean", "var"):
            bad = ~torch.isfinite(getattr(self, name))
            if bool(bad.any()):
                b, a, f, k, _ = (int(i) for i in bad.nonzero()[0])
                raise DataError(
                    f"forecast {name} is NaN/Inf for joint {self.joint_names[k]!r} "
                    f"(batch {b}, action {self._action(a)!r}, frame {f})"
                )
        far = self.mean.abs() > MAX_POSITION_M
        if bool(far.any()):
            b, a, f, k, c = (int(i) for i in far.nonzero()[0])
            raise DataError(
                f"forecast mean is {float(self.mean[b, a, f, k, c]):g} m for joint "
                f"{self.joint_names[k]!r} (batch {b}, action {self._action(a)!r}, frame {f}), "
                f"beyond {MAX_POSITION_M:g} m; positions are metres in the world frame: check "
                "the units"
            )
        w = self.weights
        rows = ((w < 0).any(-1) | ((w.sum(-1) - 1).abs() > WEIGHT_SUM_TOL)).nonzero()
        if len(rows):
            b = int(rows[0, 0])
            raise DataError(
                f"forecast weights of batch {b} are not probabilities: "
                f"{[round(float(x), 6) for x in w[b]]} (sum {float(w[b].sum()):g}); expected "
                "weights >= 0 summing to 1 over the actions (a forecast with every weight 0 "
                "would hide the person from the planner)"
            )

    def _derive(self, **fields: torch.Tensor) -> Forecast:
        """A copy with some tensors replaced, without the checks of ``__post_init__``.

        Only for the methods below, whose new tensors are built from this (checked)
        forecast's own: subsets, a move to another device, held frames, or weights
        renormalised by a positive sum. They keep the shapes and stay finite, so checking
        them again would cost a host sync per copy and planning cycle for nothing.
        """
        new = copy.copy(self)
        for name, value in fields.items():
            object.__setattr__(new, name, value)
        return new

    def _action(self, a: int) -> str:
        """The name of action ``a`` (its index when the names do not cover it)."""
        return self.action_names[a] if a < len(self.action_names) else str(a)

    @property
    def batch_size(self) -> int:
        """B."""
        return int(self.weights.shape[0])

    @property
    def horizon(self) -> int:
        """n_f, the number of predicted frames."""
        return int(self.mean.shape[2])

    @property
    def times(self) -> torch.Tensor:
        """(n_f,) seconds after the last observed frame at which each predicted frame lies."""
        return self.dt * torch.arange(
            1, self.horizon + 1, dtype=self.mean.dtype, device=self.mean.device
        )

    def joint_cov(self) -> torch.Tensor:
        """(B, A, n_f, K, 3, 3) diagonal covariances built from ``var``."""
        return torch.diag_embed(self.var)

    def expected_mean(self) -> torch.Tensor:
        """(B, n_f, K, 3) the mixture's mean: sum over actions of weight x mean."""
        return torch.einsum("ba,bafkc->bfkc", self.weights, self.mean)

    def to(self, device: torch.device | str) -> Forecast:
        """A copy on ``device`` (``"cpu"``, ``"cuda"``, ``"cuda:<index>"`` or ``"auto"``).

        Raises:
            ConfigError: for a device that :func:`~iplanner_torch.types.resolve_device`
                refuses (an unknown name, CUDA where there is none, another device type).
        """
        device = resolve_device(device)
        return self._derive(
            weights=self.weights.to(device),
            mean=self.mean.to(device),
            var=self.var.to(device),
        )

    def mask_actions(self, keep: torch.Tensor) -> Forecast:
        """The forecast with some actions ruled out and the weights renormalised.

        Task-state conditioning: an action whose precondition does not hold (e.g. taking a
        block that is not on its delivery spot) gets weight 0. A batch row where every action
        with weight would be ruled out keeps its weights unchanged (the predictor's belief is
        then all there is).

        Args:
            keep: (A,) or (B, A) bool, True for the actions still possible.

        Returns:
            A forecast with the same means and variances and new weights (B, A).

        Raises:
            ShapeError: when ``keep`` is not a bool tensor (A,) or (B, A).
        """
        b, a = self.weights.shape
        if not isinstance(keep, torch.Tensor) or keep.dim() == 1:
            check_shape("keep", keep, (a,))
        else:
            check_shape("keep", keep, (b, a))
        _check_bool("keep", keep, "(A,) or (B, A)")
        keep = keep.expand(b, a)  # (B, A)
        w = torch.where(keep.to(self.weights.device), self.weights, 0.0)
        total = w.sum(-1, keepdim=True)  # (B, 1)
        ok = total > 0.0
        w = torch.where(ok, w / torch.where(ok, total, 1.0), self.weights)
        return self._derive(weights=w)

    def hold_actions(self, hold: torch.Tensor) -> Forecast:
        """The forecast with some actions' motion held at their first predicted frame.

        Task-state conditioning of a rest: the spread of an ``idle`` forecast learned from
        demonstrations is mostly the chance that a reach starts within the horizon. When no
        reach is possible (no block is there to take), the idle person is
        predicted to stay where the first frame puts them, with that frame's variance, over
        the whole horizon.

        Args:
            hold: (A,) bool, True for the actions to hold.

        Returns:
            A forecast with the same weights; for the held actions, mean and var of every
            frame equal those of frame 0.

        Raises:
            ShapeError: when ``hold`` is not a bool tensor (A,).
        """
        check_shape("hold", hold, (int(self.weights.shape[1]),))
        _check_bool("hold", hold, "(A,)")
        h = hold.to(self.mean.device).view(1, -1, 1, 1, 1)
        mean = torch.where(h, self.mean[:, :, :1].expand_as(self.mean), self.mean)
        var = torch.where(h, self.var[:, :, :1].expand_as(self.var), self.var)
        return self._derive(mean=mean, var=var)

    def scale_var(self, factor: float) -> Forecast:
        """The forecast with every variance multiplied by ``factor`` (standard deviations by
        its square root); weights and means unchanged.

        Raises:
            DataError: when ``factor`` is not a finite number > 0.
        """
        f = checks.positive("factor", factor, error=DataError)
        return self._derive(var=self.var * f)

    def delay_actions(self, frames: torch.Tensor) -> Forecast:
        """The forecast with some actions' motion starting later.

        Task-state conditioning of a reaction time: a person who rests cannot start a reach
        for a block sooner than a reaction time after it landed, so that action's predicted
        motion is shifted later by the frames left until then, the person held at the first
        predicted frame meanwhile.

        Args:
            frames: (A,) integer delays >= 0 [frames]; 0 leaves an action as it is, a delay of
                ``n_f`` or more holds it at its first frame over the whole horizon (as
                :meth:`hold_actions`).

        Returns:
            A forecast with the same weights; for action ``a``, frame ``k`` of mean and var is
            frame ``max(0, k - frames[a])`` of this one.

        Raises:
            ShapeError: when ``frames`` is not an integer tensor (A,).
            DataError: when a delay is negative.
        """
        check_shape("frames", frames, (int(self.weights.shape[1]),))
        if not _is_integer(frames):
            raise ShapeError(f"expected frames an integer tensor (A,), got {frames.dtype}")
        if bool((frames < 0).any()):
            raise DataError(f"expected frames >= 0, got {frames.tolist()}")
        n = self.horizon
        k = torch.arange(n, device=self.mean.device)
        idx = (k.view(1, n) - frames.to(self.mean.device).view(-1, 1)).clamp(min=0)  # (A, n_f)
        g = idx.view(1, -1, n, 1, 1).expand_as(self.mean)
        return self._derive(mean=self.mean.gather(2, g), var=self.var.gather(2, g))

    def select(self, index: int | slice | torch.Tensor | list[int]) -> Forecast:
        """The forecast for a subset of the batch (keeps the batch dimension).

        Args:
            index: which batch rows: an int (negative counts from the end, as in Python: -1 is
                the last row; a 0-d integer tensor counts as one), a slice, or what indexes a
                tensor's first dimension (an index tensor or list, a (B,) bool mask).

        Returns:
            A forecast of the selected rows, B' >= 1 of them.

        Raises:
            ShapeError: for an int outside [-B, B), an index that selects no row, one that
                does not index the batch dimension alone (a bool, None, a tuple), an index
                tensor or list out of range, or a slice with a step below 1.
        """
        b = self.batch_size
        if isinstance(index, torch.Tensor) and index.dim() == 0 and _is_integer(index):
            index = int(index)
        if isinstance(index, numbers.Integral) and not isinstance(index, bool):
            i = int(index)
            if not -b <= i < b:
                raise ShapeError(
                    f"expected index in [-{b}, {b}) for a forecast of B = {b}, got {i}"
                )
            i %= b
            idx: Any = slice(i, i + 1)
        elif isinstance(index, tuple):  # would index the action or frame dimension too
            raise ShapeError(f"expected index of the batch dimension only, got {index!r}")
        else:
            idx = index
        try:
            weights = self.weights[idx]  # (B', A)
        except (IndexError, TypeError, ValueError, RuntimeError) as err:  # ValueError: step < 1
            raise ShapeError(
                f"index {index!r} does not index the batch of a forecast of B = {b}: {err}"
            ) from err
        if weights.dim() != 2 or weights.shape[0] == 0:
            raise ShapeError(
                f"expected index to select at least one row of the batch (B = {b}), got "
                f"{index!r}, which selects weights {tuple(weights.shape)}"
            )
        return self._derive(weights=weights, mean=self.mean[idx], var=self.var[idx])


def _is_integer(t: torch.Tensor) -> bool:
    """Whether ``t`` has an integer dtype (not floating, complex or bool)."""
    return not (t.is_floating_point() or t.is_complex() or t.dtype == torch.bool)


def _check_bool(name: str, mask: torch.Tensor, shape: str) -> None:
    """ShapeError unless ``mask`` is a bool tensor (a float or int mask would be read as
    weights or indices, not as True / False)."""
    if mask.dtype != torch.bool:
        raise ShapeError(f"expected {name} a bool tensor {shape}, got {mask.dtype}")
