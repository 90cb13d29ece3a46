"""Dimension glossary and small shape-checking helpers shared by the whole package.

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
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from iplanner_torch.errors import ShapeError


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


def default_device() -> torch.device:
    """The CUDA device when one is available, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")
