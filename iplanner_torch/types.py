"""Dimension glossary, the tensor checks and the device resolution shared by the whole
package.

Dimension letters used in every docstring:

====  ==========================================================================
B     batch (windows, trajectories, or parallel optimiser starts)
T     time frames of a recording
A     human actions (classes of the action classifier)
W     waypoints of a robot trajectory
K     tracked human joints (10 for the OpenNI upper body)
J     robot joints
S     spheres (S_r on the robot, S_h on the human)
N     training points
M     inducing points of a sparse GP / import vectors of an IVM
D     features per frame (positions, velocities, accelerations: 9 K)
n_p   frames in the observed window F_prev
n_f   frames in the predicted future xi_next
====  ==========================================================================

Units are SI: metres, seconds, radians. Tensors are float32 unless a docstring says otherwise.

The tensor checks: :func:`check_shape` (ShapeError), :func:`all_finite`, :func:`check_finite`
and :func:`non_finite_error` (DataError). Scalar checks live in :mod:`iplanner_torch.checks`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence

import numpy as np
import torch

from iplanner_torch.errors import ConfigError, DataError, ShapeError

MAX_POSITION_M = 100.0
"""Largest joint coordinate [m] that demonstration files and forecasts take.

A person beside a robot is metres from the world origin: a coordinate beyond 100 m means other
units (a recording in millimetres, say) or a corrupted sample. Such values used to train and
forecast: a forecast 1e30 m away is finite, so the planner read it as "no human near".
"""


def check_shape(name: str, x: torch.Tensor, expected: Sequence[int | str | None]) -> None:
    """Check ``x.shape`` against ``expected`` and raise :class:`ShapeError` when it differs.

    Args:
        name: the argument's name, used in the message.
        x: the tensor to check.
        expected: one entry per dimension: an int must match exactly; a str or None matches
            any size (a str names the dimension in the message, e.g. ``"B"``). A leading
            ``"..."`` matches any number of leading dimensions.

    Raises:
        ShapeError: when the rank or a fixed size differs, naming expected and got.
    """
    if not isinstance(x, torch.Tensor):
        raise ShapeError(f"expected {name} to be a torch.Tensor, got {type(x).__name__}")
    exp = list(expected)
    shape = tuple(x.shape)
    pretty = "(" + ", ".join(str(e) for e in exp) + ")"
    if exp and exp[0] == "...":
        tail = exp[1:]
        if len(shape) < len(tail):
            raise ShapeError(f"expected {name} {pretty}, got {shape}")
        shape_tail = shape[len(shape) - len(tail) :]
        exp_cmp = tail
    else:
        if len(shape) != len(exp):
            raise ShapeError(f"expected {name} {pretty}, got {shape}")
        shape_tail = shape
        exp_cmp = exp
    for got, want in zip(shape_tail, exp_cmp):
        if isinstance(want, int) and got != want:
            raise ShapeError(f"expected {name} {pretty}, got {shape}")


def check_device(reference: str, x: torch.Tensor, **others: torch.Tensor | None) -> None:
    """Raise :class:`ShapeError` unless every tensor of ``others`` is on ``x``'s device (no
    host synchronisation: for the hot paths too). ``reference`` names ``x`` in the message:
    ``expected q_min on cpu (where q is), got cuda:0``. None entries are skipped."""
    dev = x.device
    for name, t in others.items():
        if t is not None and t.device != dev:
            raise ShapeError(f"expected {name} on {dev} (where {reference} is), got {t.device}")


def all_finite(*xs: torch.Tensor) -> bool:
    """Whether every entry of every tensor in ``xs`` is finite; one host synchronisation.

    The sum of a tensor is finite only if all its entries are (IEEE arithmetic carries a NaN
    or an infinity into every sum that includes it), and summing is many times cheaper than
    ``isfinite(x).all()``, which builds a boolean tensor. So the sums are tested first; only
    when one is not finite (a NaN or inf entry, or a sum that overflowed) are the entries
    tested one by one. Integer and boolean tensors are always finite.

    Args:
        xs: (...) tensors on one device, of any shapes and dtypes.
    """
    floats = [x for x in xs if (x.is_floating_point() or x.is_complex()) and x.numel() > 0]
    if not floats:
        return True
    dev = floats[0].device
    sums = torch.stack([x.sum().abs().to(dev, torch.float32) for x in floats])  # (n,)
    if bool(torch.isfinite(sums).all()):
        return True
    return all(bool(torch.isfinite(x).all()) for x in floats)


def check_finite(
    name: str,
    x: torch.Tensor,
    dims: Sequence[str | Sequence[str]] | None = None,
    *,
    hint: str | None = None,
) -> None:
    """Raise :class:`DataError` when ``x`` holds NaN or inf, naming the first such entry.

    One host synchronisation when ``x`` is finite (:func:`all_finite`); the message is built
    only on failure.

    Args:
        name: the argument's name, used in the message.
        x: (...) the tensor to check.
        dims: how to name the index along each leading dimension of ``x``: a str names the
            dimension (``"window"`` gives ``window 3``), a sequence of str names each of its
            entries (e.g. the D feature columns); dimensions beyond ``dims`` are left out
            (``("window", "frame")`` for (B, T, D) names the frame). None gives the raw index.
        hint: appended to the message (what to do about it), e.g.
            ``"impute lost frames first"``.

    Raises:
        DataError: when an entry of ``x`` is NaN or inf.
    """
    if all_finite(x):
        return
    idx = [int(i) for i in (~torch.isfinite(x)).nonzero()[0]]
    if dims is None:
        where = f"index {tuple(idx)}"
    else:
        parts = []
        for i, dim in zip(idx, dims):
            parts.append(f"{dim} {i}" if isinstance(dim, str) else repr(dim[i]))
        where = ", ".join(parts)
    raise DataError(f"{name} is NaN/Inf at {where}" + (f": {hint}" if hint else ""))


def non_finite_error(name: str, x: torch.Tensor | np.ndarray) -> DataError:
    """The :class:`DataError` for an ``x`` found to hold NaN or inf, counting them.

    For checks that test finiteness together with other conditions in one host
    synchronisation and build the message only when one fails.

    Args:
        name: the argument's name, used in the message.
        x: (...) the tensor (or numpy array) that failed the check.
    """
    t = torch.as_tensor(x)
    n_nan, n_inf = int(torch.isnan(t).sum()), int(torch.isinf(t).sum())
    return DataError(
        f"expected finite {name}, got {n_nan} NaN and {n_inf} Inf among {t.numel()} values"
    )


def default_device() -> torch.device:
    """The CUDA device when one is available, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def resolve_device(device: torch.device | str) -> torch.device:
    """The usable torch device ``device`` names; ``"auto"`` is :func:`default_device`.

    The project runs on ``cpu`` and ``cuda``; other types are refused (``meta`` holds no
    numbers, ``mps`` and the rest are untested here).

    Raises:
        ConfigError: for a name torch does not know, a device type other than those two, a
            CUDA device when CUDA is not available, or a CUDA index beyond the devices present.
    """
    if isinstance(device, str) and device == "auto":
        return default_device()
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ConfigError(f"unknown device {device!r}: {exc}") from exc
    if dev.type not in ("cpu", "cuda"):
        raise ConfigError(
            f"device {str(dev)!r} is not one this project runs on: use 'cpu', 'cuda', "
            "'cuda:<index>' or 'auto'"
        )
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(f"device {str(dev)!r} requested but CUDA is not available")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(
                f"device {str(dev)!r} requested but only {torch.cuda.device_count()} CUDA "
                f"device(s) exist"
            )
    return dev


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run the block on ``n`` torch CPU threads (None: torch's setting as it is), restoring
    torch's count after it. The count splits the CPU sums, so it fixes their last digits."""
    threads = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
