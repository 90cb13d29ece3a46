"""Evaluation metrics of paper sec. 7: robot trajectory quality, safety and prediction quality.

Closed loop (sec. 7.2): smoothness (eq. smoothness), jerkiness (eq. jerkiness), the closest
human-robot distance, efficiency, and the modified Hausdorff distance (MHD, Dubuisson and Jain
1994) between the predicted and the true motion of the moving hand. Prediction (sec. 7.1):
classification precision, regression precision and regression accuracy.

Inputs may be tensors, numpy arrays or nested lists of real numbers (anything else, e.g. text,
bools or ragged lists, is a :class:`~iplanner_torch.errors.ShapeError`); everything is
computed in float64. Functions returning ``float`` reduce a whole episode; the prediction
integrals keep leading batch dimensions.

Metric names used in episode logs and reports (``stage/name``) are in :data:`METRIC_KEYS`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from iplanner_torch.checks import is_real, positive, real_array
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.types import check_shape

__all__ = [
    "METRIC_KEYS",
    "joint_accelerations",
    "smoothness",
    "jerkiness",
    "closest_distance",
    "modified_hausdorff",
    "modified_hausdorff_batch",
    "prediction_mhd",
    "efficiency",
    "regression_precision",
    "regression_accuracy",
    "classification_precision",
    "episode_metrics",
]

#: Keys of the closed-loop metrics dict (what ``EpisodeWriter.metrics`` logs per episode).
METRIC_KEYS: dict[str, str] = {
    "eval/smoothness": "(1/T) int sum_i qdd_i^2 dt [rad^2/s^4] (NaN below 3 samples)",
    "eval/jerkiness": "max_t sum_i qdd_i^2 [rad^2/s^4] (NaN below 3 samples)",
    "eval/min_distance": "closest human-robot surface distance [m] (< 0: penetration)",
    "eval/contact": "1.0 when min_distance <= 0 at some time, else 0.0",
    "eval/efficiency": "task time of the human alone / task time with the robot",
    "eval/mhd": "mean MHD of the predicted vs true moving-hand path [m]",
    "eval/prediction_ms": "mean wall time of one prediction [ms]",
}


def _f64(name: str, x: Any, expected: tuple) -> torch.Tensor:
    """``x`` as a float64 tensor (on its own device), its shape checked; ShapeError for
    anything but real numbers (bools, complex, text, ragged lists)."""
    if isinstance(x, torch.Tensor):
        if x.dtype == torch.bool or x.is_complex():
            raise ShapeError(f"expected {name} an array of real numbers, got dtype {x.dtype}")
        xt = x
    else:
        xt = torch.as_tensor(real_array(name, x).astype(np.float64))
    check_shape(name, xt, expected)
    return xt.to(torch.float64)


def _check_dt(dt: Any) -> float:
    """``dt`` as a float; DataError unless it is a finite real number > 0 (NaN gave NaN)."""
    return positive("dt", dt, error=DataError)


def _real_scalar(value: Any) -> float:
    """``value`` (a real number, a numpy scalar, a one-element real tensor or array) as a
    float; NaN for anything else (text, bools, several elements)."""
    if isinstance(value, torch.Tensor | np.ndarray):
        arr = value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else value
        return float(arr.reshape(())) if arr.size == 1 and arr.dtype.kind in "iuf" else math.nan
    return float(value) if is_real(value) else math.nan


def _is_nan(value: Any) -> bool:
    """Whether ``value`` is a NaN number (also a numpy NaN or a one-element NaN tensor)."""
    try:
        return math.isnan(value)
    except (TypeError, ValueError):
        return False


def _check_time(t: torch.Tensor, min_len: int) -> None:
    if t.shape[0] < min_len:
        raise ShapeError(f"expected at least {min_len} time samples, got t {tuple(t.shape)}")
    if not bool(torch.all(torch.diff(t) > 0) & torch.isfinite(t).all()):
        raise DataError("expected strictly increasing finite times t")


def joint_accelerations(t: Any, q: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Second derivatives of ``q`` on a possibly non-uniform time grid.

    The three-point formula at each interior sample i, with ``h0 = t_i - t_{i-1}`` and
    ``h1 = t_{i+1} - t_i``::

        qdd_i = 2 ((q_{i+1} - q_i) / h1 - (q_i - q_{i-1}) / h0) / (h0 + h1)

    is exact for quadratics (it is the second derivative of the interpolating parabola).

    Args:
        t: (T,) sample times [s], strictly increasing, T >= 3.
        q: (T, J) joint positions [rad], finite (the robot's measured or planned joints have
            no NaN rows, unlike tracked human joints).

    Returns:
        ``(qdd (T-2, J) [rad/s^2], weights (T-2,) [s])``: accelerations at the interior samples
        and the length of time each one stands for (its half-intervals on both sides; the first
        and last also cover the end intervals), summing to ``t[-1] - t[0]``.

    Raises:
        ShapeError: for mismatched shapes or T < 3.
        DataError: for times that are not strictly increasing (or NaN or infinite), or a NaN
            or infinite joint position (naming the rows).
    """
    tt = _f64("t", t, ("T",))
    qq = _f64("q", q, (tt.shape[0], "J")).to(tt.device)
    _check_time(tt, 3)
    bad = ~torch.isfinite(qq).all(dim=-1)  # (T,)
    if bool(bad.any()):
        rows = bad.nonzero().flatten().tolist()
        raise DataError(
            f"expected finite joint positions q, got NaN or inf in {len(rows)} rows, first "
            f"{rows[:5]} (t = {tt[rows[0]].item():.3f} s)"
        )
    h = torch.diff(tt)  # (T-1,)
    slope = torch.diff(qq, dim=0) / h[:, None]  # (T-1, J)
    qdd = 2.0 * (slope[1:] - slope[:-1]) / (h[1:] + h[:-1])[:, None]  # (T-2, J)
    w = 0.5 * (h[1:] + h[:-1])
    w[0] = w[0] + 0.5 * h[0]
    w[-1] = w[-1] + 0.5 * h[-1]
    return qdd, w


def smoothness(t: Any, q: Any) -> float:
    """Paper eq. smoothness: ``(1/T) int_0^T sum_i qdd_i(t)^2 dt`` [rad^2/s^4].

    ``qdd`` comes from :func:`joint_accelerations`; the integral gives each interior sample's
    ``sum_i qdd_i^2`` the time it stands for, so a constant acceleration ``a`` gives exactly
    ``sum_i a_i^2``.

    Args:
        t: (T,) sample times [s], strictly increasing, T >= 3.
        q: (T, J) joint positions [rad], finite.

    Raises:
        DataError: as :func:`joint_accelerations` (a NaN row is an error, not a NaN result).
    """
    qdd, w = joint_accelerations(t, q)
    total = float(w.sum())
    return float((qdd.square().sum(-1) * w).sum()) / total


def jerkiness(t: Any, q: Any) -> float:
    """Paper eq. jerkiness: ``max_t sum_i qdd_i(t)^2`` [rad^2/s^4] over the interior samples.

    Args:
        t: (T,) sample times [s], strictly increasing, T >= 3.
        q: (T, J) joint positions [rad], finite.

    Raises:
        DataError: as :func:`joint_accelerations`.
    """
    qdd, _ = joint_accelerations(t, q)
    return float(qdd.square().sum(-1).max())


def closest_distance(
    robot_centers: Any, robot_radii: Any, human_centers: Any, human_radii: Any
) -> tuple[float, torch.Tensor]:
    """Closest surface-to-surface distance between robot and human spheres over time.

    Sphere pairs with a NaN centre (e.g. an untracked joint) are ignored; a time step where
    every pair is NaN gets NaN and does not count for the minimum.

    Args:
        robot_centers: (T, S_r, 3) robot sphere centres [m].
        robot_radii: (S_r,) robot sphere radii [m].
        human_centers: (T, S_h, 3) human sphere centres [m].
        human_radii: (S_h,) human sphere radii [m].

    Returns:
        ``(min over time [m], per-step minimum (T,) [m])``; negative values mean penetration.

    Raises:
        ShapeError: for mismatched shapes or anything but real numbers.
        DataError: for an infinite centre coordinate (it was reported as 1.8e308 m) or a
            radius that is not finite or is negative.
    """
    rc = _f64("robot_centers", robot_centers, ("T", "S_r", 3))
    n_t, s_r = rc.shape[:2]
    rr = _f64("robot_radii", robot_radii, (s_r,)).to(rc.device)
    hc = _f64("human_centers", human_centers, (n_t, "S_h", 3)).to(rc.device)
    hr = _f64("human_radii", human_radii, (hc.shape[1],)).to(rc.device)
    for name, x in (("robot_centers", rc), ("human_centers", hc)):
        if bool(torch.isinf(x).any()):
            raise DataError(f"expected finite (or NaN: untracked) {name}, got an infinite one")
    for name, x in (("robot_radii", rr), ("human_radii", hr)):
        if not bool(torch.isfinite(x).all()):
            raise DataError(f"expected finite {name}, got {x.tolist()}")
        if bool((x < 0).any()):  # a negative radius inflated the distance, hiding a contact
            raise DataError(f"expected {name} >= 0 [m], got {x.tolist()}")
    diff = rc[:, :, None, :] - hc[:, None, :, :]  # (T, S_r, S_h, 3)
    gap = diff.norm(dim=-1) - rr[None, :, None] - hr[None, None, :]  # (T, S_r, S_h)
    gap = torch.nan_to_num(gap, nan=math.inf, posinf=math.inf).flatten(1)  # (T, S_r*S_h)
    per_step = (
        gap.min(dim=1).values
        if gap.shape[1]
        else torch.full((n_t,), math.inf, dtype=rc.dtype, device=rc.device)
    )
    per_step = torch.where(torch.isinf(per_step), torch.nan, per_step)
    finite = per_step[~torch.isnan(per_step)]
    overall = float(finite.min()) if finite.numel() else math.nan
    return overall, per_step


def modified_hausdorff(a: Any, b: Any) -> float:
    """Modified Hausdorff distance (Dubuisson and Jain 1994) between two point sets.

    ``MHD(A, B) = max(mean_{x in A} min_{y in B} |x - y|, mean_{y in B} min_{x in A} |x - y|)``.

    Args:
        a: (N, 3) points [m] (N >= 1).
        b: (M, 3) points [m] (M >= 1).

    Returns:
        The distance [m]; NaN when a point of either set has a NaN coordinate (a NaN is
        carried through, not an error).

    Raises:
        ShapeError: for an empty set or points that are not 3-D.
    """
    pa = _f64("a", a, ("N", 3))
    pb = _f64("b", b, ("M", 3)).to(pa.device)
    if pa.shape[0] == 0 or pb.shape[0] == 0:
        raise ShapeError(
            f"expected non-empty point sets, got a {tuple(pa.shape)}, b {tuple(pb.shape)}"
        )
    return float(modified_hausdorff_batch(pa[None], pb[None])[0])


def modified_hausdorff_batch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """:func:`modified_hausdorff` for a batch of point-set pairs.

    Distances are taken between the points themselves in the inputs' dtype, so identical
    sets give exactly 0 in float32 as in float64. Shapes, dtypes and devices are checked
    (no host synchronisation); the values are not (a hot path).

    Args:
        a: (B, N, 3) points [m], N >= 1, of a floating dtype.
        b: (B, M, 3) points [m], M >= 1, of ``a``'s dtype and device.

    Returns:
        (B,) ``max(mean_i min_j |a_i - b_j|, mean_j min_i |a_i - b_j|)`` [m]; NaN for a pair
        in which a point has a NaN coordinate.

    Raises:
        ShapeError: for other shapes, an empty point set, or dtypes or devices that differ.
    """
    check_shape("a", a, ("B", "N", 3))
    check_shape("b", b, (a.shape[0], "M", 3))
    if a.shape[1] == 0 or b.shape[1] == 0:
        raise ShapeError(
            f"expected non-empty point sets, got a {tuple(a.shape)}, b {tuple(b.shape)}"
        )
    if not a.is_floating_point() or a.dtype != b.dtype or a.device != b.device:
        raise ShapeError(
            f"expected a and b of one floating dtype on one device, got {a.dtype} on {a.device} "
            f"and {b.dtype} on {b.device}"
        )
    # the direct difference, not the matrix-product expansion (which cancels to ~1e-4 m in
    # float32): identical paths give exactly 0
    d = torch.cdist(a, b, compute_mode="donot_use_mm_for_euclid_dist")  # (B, N, M)
    return torch.maximum(d.min(dim=-1).values.mean(-1), d.min(dim=-2).values.mean(-1))


def prediction_mhd(pred_mean: Any, true: Any) -> float:
    """MHD between a predicted mean path and the true path of one joint (paper sec. 7.2).

    Args:
        pred_mean: (n_f, 3) predicted positions [m] of the moving hand over the horizon.
        true: (n_f, 3) its true positions at the same times [m].

    Returns:
        The distance [m] (:func:`modified_hausdorff`); NaN when a frame of either path has a
        NaN coordinate.

    Raises:
        ShapeError: for paths of other shapes or of different lengths.
    """
    p = _f64("pred_mean", pred_mean, ("n_f", 3))
    _f64("true", true, (p.shape[0], 3))
    return modified_hausdorff(p, true)


def efficiency(t_human_alone: float, t_with_robot: float) -> float:
    """Task time of the human alone divided by the task time with the robot (> 1: helps).

    Args:
        t_human_alone: completion time of all subtasks by the human alone [s].
        t_with_robot: completion time of the human-robot team [s].

    Raises:
        DataError: unless both are finite numbers > 0 (real numbers, numpy scalars or
            one-element tensors).
    """
    alone, team = _real_scalar(t_human_alone), _real_scalar(t_with_robot)
    if not (0 < alone < math.inf and 0 < team < math.inf):
        raise DataError(
            f"expected positive task times, got alone={t_human_alone!r}, "
            f"with robot={t_with_robot!r}"
        )
    return alone / team


def regression_precision(pred_mean: Any, true: Any, dt: float) -> torch.Tensor:
    """Paper sec. 7.1 regression precision: ``int_0^T sum_i |p_pred,i - p_true,i|^2 dt``.

    The predicted frames lie at ``dt, 2 dt, ..., n_f dt``; the integral is the right Riemann
    sum over them (each frame stands for the ``dt`` before it), so ``T = n_f dt``.

    Args:
        pred_mean: (..., n_f, K, 3) predicted mean joint positions [m].
        true: (..., n_f, K, 3) true joint positions [m].
        dt: seconds between predicted frames, finite and > 0.

    Returns:
        (...) [m^2 s], float64 (a 0-d tensor without batch dimensions); NaN or inf where a
        position behind that entry is (carried through, not an error).

    Raises:
        ShapeError: for mismatched shapes or anything but real numbers.
        DataError: for a ``dt`` that is not a finite number > 0.
    """
    p = _f64("pred_mean", pred_mean, ("...", "n_f", "K", 3))
    y = _f64("true", true, tuple(p.shape)).to(p.device)
    dt = _check_dt(dt)
    return (p - y).square().sum(dim=(-1, -2, -3)) * dt


def regression_accuracy(var: Any, dt: float, *, full_cov: bool = False) -> torch.Tensor:
    """Paper sec. 7.1 regression accuracy: ``int_0^T sum_i det K_i(t) dt`` (lower is better).

    Args:
        var: (..., n_f, K, 3) per-coordinate variances [m^2] (``det`` = their product), or
            with ``full_cov`` (..., n_f, K, 3, 3) covariances.
        dt: seconds between predicted frames, finite and > 0 (right Riemann sum, as
            :func:`regression_precision`).
        full_cov: whether ``var`` holds full 3x3 covariances.

    Returns:
        (...) [m^6 s], float64; NaN or inf where a variance behind that entry is (carried
        through, not an error).

    Raises:
        ShapeError: for a wrong shape or anything but real numbers.
        DataError: for a ``dt`` that is not a finite number > 0.
    """
    dt = _check_dt(dt)
    if full_cov:
        c = _f64("cov", var, ("...", "n_f", "K", 3, 3))
        det = torch.linalg.det(c)  # (..., n_f, K)
    else:
        v = _f64("var", var, ("...", "n_f", "K", 3))
        det = v.prod(dim=-1)  # (..., n_f, K)
    return det.sum(dim=(-1, -2)) * dt


def classification_precision(probs: Any, labels: Any, threshold: float = 0.5) -> tuple[float, int]:
    """Paper sec. 7.1 classification precision on frames whose top probability > threshold.

    Args:
        probs: (T, A) action probabilities per frame, finite.
        labels: (T,) true action index per frame, integers in [0, A).
        threshold: frames whose largest probability is not above it are not counted; a
            finite number (or a one-element tensor).

    Returns:
        ``(fraction of counted frames whose arg-max is the label, number of counted frames)``;
        the fraction is NaN when no frame is counted.

    Raises:
        ShapeError: for mismatched shapes or anything but real numbers.
        DataError: for a NaN or infinite probability (such frames were dropped silently), or
            a label that is not an integer in [0, A).
        ConfigError: for a ``threshold`` that is not a finite number.
    """
    if not math.isfinite(_real_scalar(threshold)):
        raise ConfigError(f"expected threshold a finite number, got {threshold!r}")
    threshold = _real_scalar(threshold)
    p = _f64("probs", probs, ("T", "A"))
    lab = _f64("labels", labels, (p.shape[0],)).to(p.device)
    bad = ~torch.isfinite(p).all(dim=1)  # (T,)
    if bool(bad.any()):
        rows = bad.nonzero().flatten().tolist()
        raise DataError(
            f"expected finite probs, got NaN or inf in {len(rows)} frames, first {rows[:5]}"
        )
    n_a = p.shape[1]
    bad = (lab != lab.round()) | (lab < 0) | (lab >= n_a) | torch.isnan(lab)
    if bool(bad.any()):
        i = int(bad.nonzero()[0])
        raise DataError(
            f"expected labels integers in [0, {n_a}), got {lab[i].item()!r} at frame {i}"
        )
    if p.shape[0] == 0:  # no frame: nothing counted (max over no action would raise)
        return math.nan, 0
    if n_a == 0:
        raise DataError("expected probs over at least one action, got (T, 0)")
    top, arg = p.max(dim=1)
    keep = top > threshold
    n = int(keep.sum())
    if n == 0:
        return math.nan, 0
    correct = (arg[keep] == lab.to(arg.device)[keep]).sum()
    return float(correct) / n, n


def episode_metrics(
    *,
    t: Any,
    q: Any,
    robot_centers: Any,
    robot_radii: Any,
    human_centers: Any,
    human_radii: Any,
    t_human_alone: float | None = None,
    t_with_robot: float | None = None,
    mhd: float | None = None,
    prediction_ms: float | None = None,
) -> dict[str, float]:
    """The closed-loop metrics of one episode, keyed as in :data:`METRIC_KEYS`.

    An episode with fewer than 3 robot samples (shorter than two sampling periods) has no
    joint acceleration: its smoothness and jerkiness are NaN.

    Args:
        t: (T,) robot sample times [s].
        q: (T, J) robot joint positions [rad].
        robot_centers: (T_c, S_r, 3) robot sphere centres [m] (T_c may differ from T).
        robot_radii: (S_r,) [m].
        human_centers: (T_c, S_h, 3) true human sphere centres at the same times [m].
        human_radii: (S_h,) [m].
        t_human_alone: task time of the human alone [s] (efficiency is NaN without it).
        t_with_robot: task time with the robot [s].
        mhd: mean prediction MHD over the episode [m], if predictions were made.
        prediction_ms: mean prediction time [ms], if predictions were made.

    Raises:
        ShapeError: for mismatched shapes.
        DataError: as :func:`smoothness` (from 3 samples on), or for an ``mhd`` or
            ``prediction_ms`` that is not a number (a real number, a numpy scalar or a
            one-element tensor; NaN passes).
    """
    for name, value in (("mhd", mhd), ("prediction_ms", prediction_ms)):
        if value is not None and math.isnan(_real_scalar(value)) and not _is_nan(value):
            raise DataError(f"expected {name} a number or None, got {value!r}")
    n_t = _f64("t", t, ("T",)).shape[0]
    _f64("q", q, (n_t, "J"))
    short = n_t < 3  # no interior sample: no acceleration
    dmin, _ = closest_distance(robot_centers, robot_radii, human_centers, human_radii)
    eff = (
        efficiency(t_human_alone, t_with_robot)
        if t_human_alone is not None and t_with_robot is not None
        else math.nan
    )
    return {
        "eval/smoothness": math.nan if short else smoothness(t, q),
        "eval/jerkiness": math.nan if short else jerkiness(t, q),
        "eval/min_distance": dmin,
        "eval/contact": float(dmin <= 0.0) if not math.isnan(dmin) else math.nan,
        "eval/efficiency": eff,
        "eval/mhd": math.nan if mhd is None else _real_scalar(mhd),
        "eval/prediction_ms": math.nan if prediction_ms is None else _real_scalar(prediction_ms),
    }
