"""Upper bounds on the probability that a robot sphere meets a Gaussian human sphere (sec. 5).

A robot sphere (centre ``c``, radius ``r1``) and a human sphere (radius ``r2``) whose centre is
``X ~ N(mu, Sigma)`` (eq. center_distribution) intersect when ``||X - c|| <= R``, ``R = r1 + r2``
(eq. sphere_collision). That probability has no closed form; two upper bounds are computed from
the point ``x_max`` of the ball ``||x - c|| <= R`` where the density ``f`` is highest:

* **volume** (eq. approx_sphere_collision): ``P <= (4/3) pi R^3 f(x_max)``. The paper prints
  ``R^2``; a density has units m^-3, so a probability needs the ball's *volume*
  ``(4/3) pi R^3`` (with R^2 the bound is looser in metres and wrong in millimetres).
* **halfspace**: ``x_max`` minimises the Mahalanobis distance ``m`` from ``mu`` over the ball.
  In whitened coordinates ``z = Sigma^{-1/2} x`` the ball becomes a convex ellipsoid whose
  point nearest to the whitened mean is the whitened ``x_max``; the ellipsoid therefore lies in
  the half-space beyond the plane through that point orthogonal to the whitened
  ``x_max - mu``, whose standard-normal mass is ``Phi(-m)``. Hence ``P <= Phi(-m)`` when the
  mean lies outside the ball (the bound is 1 when it lies inside).
* **min** (default): ``min(volume, halfspace, 1)``. Every bound is clamped to ``[0, 1]``.

``x_max`` solves the secular equation. With ``Sigma = U diag(s) U^T`` and
``d = U^T (mu - c)``, the Lagrange condition gives ``y(lambda) = d / (1 + lambda s)`` (in the
eigenbasis, relative to ``c``) on the sphere ``||y|| = R``; the paper's
``x_max = (Sigma^-1 + lambda I)^-1 (Sigma^-1 mu + lambda c)`` is the same point. The default
solver is Newton on ``g(lambda) = 1/||y(lambda)|| - 1/R``; the paper's bisection is kept as the
reference (``solver="bisection"``). Why Newton is safe:

* ``q(lambda) = 1/||y(lambda)||`` is increasing and concave on ``lambda > -1/s_max`` (Moré and
  Sorensen 1983, the trust-region secular equation with the positive definite ``Sigma^-1``;
  checked numerically in the tests).
* ``lambda_lo = (||d||/R - 1)/s_max`` lies left of the root: since
  ``||y(lambda)|| >= ||d|| / (1 + lambda s_max)``, ``||y(lambda_lo)|| >= R``, i.e. ``g <= 0``;
  so does each ``(|d_k|/R - 1)/s_k``, and Newton starts from the largest of these.
* Newton on a concave increasing function from the left never overshoots: the tangent lies
  above the curve, so every iterate stays left of the root and increases monotonically.
* Stopping early is safe: the Mahalanobis distance of ``y(lambda)`` from ``d`` increases with
  ``lambda``, so an iterate left of the root gives a smaller ``m`` and both bounds a *larger*
  value. An unconverged Newton (or the lower end of a bisection bracket) is still an upper
  bound.

Only squares ``d_k^2`` enter: ``m^2 = lambda^2 sum_k s_k d_k^2 / (1 + lambda s_k)^2``.

Gradients: the Newton iterations run without autograd and one last Newton step is taken with
autograd on; at the fixed point its derivative equals the implicit-function derivative
``-g_theta / g_lambda``, so gradients with respect to the sphere centres are exact and cheap.

Pruning (``prune_sigma``): with ``gap = ||mu - c|| - R`` (the Euclidean distance from the mean
to the ball) and ``s_max`` the largest variance, ``m >= gap / sqrt(s_max)``. Pairs with
``gap > prune_sigma * sqrt(s_max)`` skip the solver and get ``Phi(-gap/sqrt(s_max))`` and
``(4/3) pi R^3 (2 pi)^-1.5 det(Sigma)^-0.5 exp(-gap^2 / (2 s_max))``, which are upper bounds on
the halfspace and volume bounds: pruning never lowers a bound; it raises the halfspace bound
of a pruned pair to at most ``Phi(-prune_sigma)`` (about 1e-9 for 6).

Inputs: every tensor is float32 or float64, all of one dtype and on one device (no
promotion); the radii may also be Python floats. Half precision is refused: ``eigh`` does not
take it, float16 flushes the variance floor to 0 and overflows squared distances beyond 256 m,
and neither has the precision the solver's tolerance needs. Empty batches give empty results;
an empty set of sphere pairs gives the bound 0 where it is maximised over
(:func:`trajectory_collision_bound`).

Far pairs: where the squared distance ``||mu - c||^2`` overflows the dtype (a distance beyond
about 1.3e154 m in float64, 1.8e19 m in float32) the solver would return NaN. Such a pair gets
the bounds of the Euclidean gap alone, ``m >= (sqrt(D) - R) / sqrt(s_max)`` with ``D`` a
quarter of the dtype's largest value (below every overflowed square), as for pruning: 0 in
practice, never below the pair's own bound, and without gradient (the gradient with respect
to the centres is NaN only where a coordinate of ``mu - c`` itself overflows).
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Callable
from typing import Literal

import torch

from iplanner_torch.checks import integer
from iplanner_torch.errors import (
    ConfigError,
    DataError,
    IPlannerError,
    NumericalWarning,
    ShapeError,
)
from iplanner_torch.types import check_shape, non_finite_error

Method = Literal["min", "volume", "halfspace"]
Solver = Literal["newton", "bisection"]

#: Newton iterations always run (vectorised, no data-dependent branching).
NEWTON_ITERS = 6
#: Extra Newton iterations allowed when the tolerance check fails after ``NEWTON_ITERS``.
NEWTON_MAX_EXTRA_ITERS = 40
#: Halvings of the bisection bracket (the paper's solver, kept as the reference).
BISECTION_ITERS = 60
#: Smallest variance used [m^2]; smaller eigenvalues are raised to it (1 micrometre std).
VAR_FLOOR = 1e-12
#: Smallest radius sum used [m]; smaller ones are raised to it (1 nanometre). The bounds grow
#: with the radius, so they stay upper bounds, and ``x_max`` moves by less than this. Far
#: smaller radii made NaN: the solver's squared terms (of order ``R^2``) underflow below
#: about 1e-19 m in float32 and 1e-154 m in float64; the floor keeps a wide margin.
RADIUS_FLOOR = 1e-9
#: Default pruning threshold in standard deviations (see the module docstring).
DEFAULT_PRUNE_SIGMA = 6.0

#: The dtypes the bounds compute in.
DTYPES = (torch.float32, torch.float64)

_LOG_2PI = math.log(2.0 * math.pi)
_LOG_4PI_3 = math.log(4.0 * math.pi / 3.0)
_METHODS = ("min", "volume", "halfspace")
_SOLVERS = ("newton", "bisection")


def _check_choices(method: str, solver: str) -> None:
    if method not in _METHODS:
        raise ConfigError(f"expected method in {_METHODS}, got {method!r}")
    if solver not in _SOLVERS:
        raise ConfigError(f"expected solver in {_SOLVERS}, got {solver!r}")


def _overflow_dist2(dtype: torch.dtype) -> float:
    """A lower bound [m^2] on a squared distance that overflowed in ``dtype``: a quarter of
    its largest value (the exact sum of the squares exceeds the largest value up to
    rounding)."""
    return torch.finfo(dtype).max / 4.0


def _tolerance(dtype: torch.dtype) -> float:
    """Relative residual ``|R/||y|| - 1|`` accepted by the Newton tolerance check."""
    return 64.0 * torch.finfo(dtype).eps


# The solver works component-first: d2 and s are (3, N), R and lambda are (N,), so that the
# sums over the 3 eigen-directions are plain additions of contiguous rows.


def _secular_residual(lam: torch.Tensor, d2: torch.Tensor, s: torch.Tensor, R: torch.Tensor):
    """Return ``g = 1/||y|| - 1/R`` and ``g' = dg/dlambda`` for ``y = d / (1 + lambda s)``."""
    if _differentiable(lam, d2, s, R):  # (the implicit-function step of the bounds)
        w = 1.0 / (1.0 + lam * s)  # (3, N)
        y2 = d2 * w * w  # (3, N) squared components of y
        q = torch.rsqrt(y2.sum(0))  # (N,) 1/||y||
        # (y2 q^2) (s w) q, as below
        return q - 1.0 / R, (y2 * (q * q) * (s * w)).sum(0) * q
    # without autograd, in place where a step makes a new tensor anyway (the same numbers as
    # above, with fewer allocations: the solver's steps run on about 100,000 pairs a call)
    w = torch.mul(lam, s).add_(1.0).reciprocal_()  # (3, N) 1 / (1 + lambda s)
    y2 = torch.mul(d2, w).mul_(w)  # (3, N) squared components of y
    q = y2.sum(0).rsqrt_()  # (N,) 1/||y||
    g = q - R.reciprocal()
    # (y2 q^2) (s w) q: the shares of ||y||^2 first, so that no product underflows before
    # the large q (up to 1/RADIUS_FLOOR) scales it back (y2 s w underflowed float32 far away)
    gp = y2.mul_(q * q).mul_(w.mul_(s)).sum(0).mul_(q)
    return g, gp


def _newton_step(
    lam: torch.Tensor, d2: torch.Tensor, s: torch.Tensor, R: torch.Tensor
) -> torch.Tensor:
    g, gp = _secular_residual(lam, d2, s, R)
    return lam - (g / gp if _differentiable(lam, d2, s, R) else g.div_(gp))


def _differentiable(*tensors: torch.Tensor) -> bool:
    """Whether autograd records operations on ``tensors`` here."""
    return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)


def _lambda_bracket(d2: torch.Tensor, s: torch.Tensor, R: torch.Tensor):
    """Return ``(lambda_lo, lambda_hi)`` bracketing the root (mean outside the ball)."""
    ratio = torch.sqrt(d2.sum(0)) / R - 1.0
    return ratio / s.amax(0), ratio / s.amin(0)


def _newton_start(d2: torch.Tensor, s: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """A start left of the root, at least ``lambda_lo``.

    ``||y(lambda)|| >= ||d|| / (1 + lambda s_max)`` and ``||y(lambda)|| >= |d_k| / (1 + lambda
    s_k)`` for each k, so ``lambda_lo`` and every ``(|d_k|/R - 1)/s_k`` lie left of the root;
    the largest is taken (it saves one or two iterations on anisotropic covariances).
    """
    lam_lo, _ = _lambda_bracket(d2, s, R)
    per_axis = ((torch.sqrt(d2) / R - 1.0) / s).amax(0)
    return torch.maximum(lam_lo, per_axis)


def _solve_newton(d2: torch.Tensor, s: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """Root of the secular equation by Newton from the left (no autograd).

    ``NEWTON_ITERS`` vectorised iterations, then a tolerance check; the pairs that have not
    converged (rare: strongly anisotropic covariances) are iterated further on their own.

    Args:
        d2: (3, N) squared eigen-coordinates of ``mu - c`` [m^2], all with ``||d|| > R``.
        s: (3, N) eigenvalues [m^2].
        R: (N,) radius sums [m].

    Returns:
        (N,) multipliers lambda [m^-2].
    """
    with torch.no_grad():
        d2, s, R = d2.detach(), s.detach(), R.detach()
        lam = _newton_start(d2, s, R)
        for _ in range(NEWTON_ITERS):
            lam = _newton_step(lam, d2, s, R)
        if lam.numel() == 0:
            return lam
        tol = _tolerance(d2.dtype)
        g, _ = _secular_residual(lam, d2, s, R)
        todo = ((g * R).abs() > tol).nonzero().squeeze(-1)  # (N_todo,)
        for _ in range(NEWTON_MAX_EXTRA_ITERS):
            if todo.numel() == 0:
                break
            args = (d2[:, todo], s[:, todo], R[todo])
            lam_t = _newton_step(lam[todo], *args)
            lam[todo] = lam_t
            g, _ = _secular_residual(lam_t, *args)
            todo = todo[(g * args[2]).abs() > tol]
        if todo.numel() > 0:
            warnings.warn(
                f"secular equation: Newton left {todo.numel()} pairs above relative residual "
                f"{tol:.1e} after {NEWTON_ITERS + NEWTON_MAX_EXTRA_ITERS} iterations; their "
                "iterates lie left of the root, so the bounds are still upper bounds",
                NumericalWarning,
                stacklevel=3,
            )
    return lam


def secular_multiplier(d: torch.Tensor, var: torch.Tensor, rad: torch.Tensor) -> torch.Tensor:
    """The multiplier of the closest point on a sphere to a Gaussian with diagonal covariance.

    ``lambda >= 0`` with ``||d / (1 + lambda var)|| = rad`` (:func:`_solve_newton`, the solver
    of :func:`sphere_collision_bound`, in the axes of the diagonal covariance), so that
    ``x_max - c = d / (1 + lambda var)``; 0 where the mean lies inside the ball. No autograd.

    Args:
        d: (..., 3) Gaussian mean minus ball centre [m].
        var: (..., 3) diagonal variances [m^2], > 0.
        rad: (...) ball radius [m], at least :data:`RADIUS_FLOOR` (broadcast to ``d``'s
            batch shape).

    Returns:
        (...) lambda [m^-2].

    Inputs are not checked (an inner loop of the planner's collision bound, fed checked
    obstacles): a variance that is not > 0 gives NaN, and ``d``, ``var``, ``rad`` must be
    tensors of one floating dtype; :func:`sphere_collision_bound` is the checked entry point.
    """
    with torch.no_grad():
        shape = d.shape[:-1]
        d2 = d.detach().square()
        rad = rad.detach().expand(shape)
        outside = d2.sum(-1) > rad.square()
        # an inside mean gets a stand-in outside its ball (its multiplier is 0 anyway), so that
        # every entry goes through one vectorised solve without a data-dependent shape
        stand_in = torch.zeros_like(d2)
        stand_in[..., 0] = (2.0 * rad).square()
        d2 = torch.where(outside.unsqueeze(-1), d2, stand_in)
        s = var.detach().expand(d2.shape)
        lam = _solve_newton(
            d2.reshape(-1, 3).T.contiguous(), s.reshape(-1, 3).T.contiguous(), rad.reshape(-1)
        )
        return torch.where(outside, lam.view(shape), torch.zeros_like(rad))


def _solve_bisection(d2: torch.Tensor, s: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """The paper's bisection on ``[lambda_lo, lambda_hi]``; returns the bracket's lower end.

    Args and returns as :func:`_solve_newton`.
    """
    with torch.no_grad():
        d2, s, R = d2.detach(), s.detach(), R.detach()
        lo, hi = _lambda_bracket(d2, s, R)
        for _ in range(BISECTION_ITERS):
            mid = 0.5 * (lo + hi)
            g, _ = _secular_residual(mid, d2, s, R)
            left = g < 0
            lo = torch.where(left, mid, lo)
            hi = torch.where(left, hi, mid)
    return lo


def _log_volume_factor(R: torch.Tensor, log_det: torch.Tensor) -> torch.Tensor:
    """``log((4/3) pi R^3 (2 pi)^-1.5 det(Sigma)^-0.5)``: the volume bound is this x e^(-m^2/2)."""
    return _LOG_4PI_3 + 3.0 * torch.log(R) - 1.5 * _LOG_2PI - 0.5 * log_det


def _combine(m2: torch.Tensor, log_vf: torch.Tensor, method: str) -> torch.Tensor:
    """``min`` / ``volume`` / ``halfspace`` bound from a squared Mahalanobis distance."""
    if method == "halfspace":
        return 0.5 * torch.erfc(torch.sqrt(m2) * (0.5**0.5))
    volume = torch.exp((log_vf - 0.5 * m2).clamp_max(0.0))
    if method == "volume":
        return volume
    return torch.minimum(volume, 0.5 * torch.erfc(torch.sqrt(m2) * (0.5**0.5)))


def _pair_bounds(
    d2: torch.Tensor,
    s: torch.Tensor,
    R: torch.Tensor,
    *,
    method: str,
    solver: str,
    prune_sigma: float | None,
) -> torch.Tensor:
    """Bound for every pair given squared eigen-coordinates ``d2`` and eigenvalues ``s``.

    Pairs whose ``d2.sum(0)`` overflows skip the solver and get the bounds of the gap
    ``sqrt(_overflow_dist2) - R`` (pruned: those of pruning); no gradient flows to their
    ``d2``.

    Args:
        d2: (3, ...) squared components of ``U^T (mu - c)`` [m^2] (component first).
        s: (3, ...) covariance eigenvalues (variances) [m^2], broadcastable to ``d2``.
        R: (...) sum of the two radii [m], broadcastable to ``d2[0]``.
        method: which bound.
        solver: secular-equation solver.
        prune_sigma: skip the solver beyond this many standard deviations (None: never).

    Returns:
        (...) bound in [0, 1], the broadcast shape of the three inputs.
    """
    s = s.clamp_min(VAR_FLOOR)
    R = R.clamp_min(RADIUS_FLOOR)
    log_det = torch.log(s).sum(0)  # (...) broadcastable, computed before expanding
    log_vf = _log_volume_factor(R, log_det)  # (...) broadcastable
    shape = torch.broadcast_shapes(d2.shape[1:], s.shape[1:], R.shape)
    dist2 = d2.sum(0)  # (...)
    # Overflowed squared distances (inf; NaN where a rotation met inf * 0) become a lower
    # bound on the true ones; nan_to_num passes no gradient to them.
    huge = ~torch.isfinite(dist2)  # (...)
    low2 = _overflow_dist2(d2.dtype)
    dist2 = dist2.nan_to_num(nan=low2, posinf=low2)
    outside = dist2 > R * R  # (shape)
    # Mean inside the ball: x_max = mu, m = 0, the half-space bound does not apply (1).
    if method == "halfspace":
        base = torch.ones(shape, dtype=d2.dtype, device=d2.device)
    else:
        base = torch.exp(log_vf.clamp_max(0.0)).expand(shape)
    active = outside & ~huge
    if prune_sigma is not None:
        # m >= gap / sqrt(s_max): pruned pairs get bounds that are never below their own.
        s_max = s.amax(0)
        gap = torch.sqrt(dist2) - R
        near = gap <= prune_sigma * torch.sqrt(s_max)
        far = outside & ~near
        if method == "volume":
            # the gap of far pairs only: sqrt's gradient at a mean on the centre would be NaN
            gap = torch.sqrt(torch.where(far, dist2, R * R)) - R
            far_val = torch.exp((log_vf - 0.5 * gap.clamp_min(0.0).square() / s_max).clamp_max(0))
        else:
            far_val = torch.full((), 0.5 * math.erfc(prune_sigma * 0.5**0.5), dtype=d2.dtype)
            far_val = far_val.to(d2.device)
        base = torch.where(far, far_val, base)
        active = active & near
    else:
        # Overflowed pairs: m >= gap / sqrt(s_max) as for pruning, with their common lower
        # bound on the distance, so on the shape of R and s only (no gradient: the bound of a
        # pair this far is constant to rounding).
        with torch.no_grad():
            gap = math.sqrt(low2) - R
            far_val = _combine(gap.square() / s.amax(0), log_vf, method)
        base = torch.where(outside & huge, far_val, base)
    idx = active.reshape(-1).nonzero().squeeze(1)  # (N_act,) flat indices of active pairs
    if idx.numel() == 0:
        # every bound is constant here; the empty sum keeps the result on d2's autograd graph
        # (zero gradient), so that backward() works as where some pairs are active
        if d2.requires_grad:
            return base.expand(shape) + d2.narrow(0, 0, 0).sum()
        return base.expand(shape)
    coords = torch.unravel_index(idx, shape)  # gather through broadcast strides, no copies
    d2_a = d2.expand((3,) + shape)[(slice(None),) + coords]  # (3, N_act)
    s_a = s.expand((3,) + shape)[(slice(None),) + coords]  # (3, N_act)
    R_a = R.expand(shape)[coords]  # (N_act,)
    if solver == "newton":
        lam = _solve_newton(d2_a, s_a, R_a)
        lam = _newton_step(lam, d2_a, s_a, R_a)  # differentiable (implicit-function) step
    else:
        lam = _solve_bisection(d2_a, s_a, R_a)
    # lam s overflows where a variance is many orders above the floor (inf / inf = NaN): capped,
    # w rounds to 1 there, as it should
    ls = (lam * s_a).clamp_max(0.5 * torch.finfo(s_a.dtype).max)  # (3, N_act)
    w = ls / (1.0 + ls)  # (3, N_act)
    m2 = (d2_a * w * w / s_a).sum(0)  # (N_act,) squared Mahalanobis distance of x_max
    vals = _combine(m2, log_vf.expand(shape)[coords], method)  # (N_act,)
    out = base.expand(shape).reshape(-1).index_put((idx,), vals.to(base.dtype))
    return out.view(shape)


# Input validation. Every public entry validates once, before any work, with at most one host
# sync for the finiteness and range checks (two for full covariances: the positive
# semidefiniteness check needs the eigenvalues); the solver internals assume valid input.

_Check = tuple[torch.Tensor, Callable[[], IPlannerError]]


def _check_prune_sigma(prune_sigma: float | None) -> None:
    """``prune_sigma`` must be None or > 0: at 0 or below every outside pair would get the
    useless halfspace bound ``Phi(-prune_sigma) >= 0.5``."""
    if prune_sigma is None:
        return
    if (
        isinstance(prune_sigma, bool)
        or not isinstance(prune_sigma, numbers.Real)
        or not prune_sigma > 0
    ):
        raise ConfigError(f"expected prune_sigma > 0 or None, got {prune_sigma!r}")


def _as_radius(name: str, radius: torch.Tensor | float, like: torch.Tensor) -> torch.Tensor:
    """A radius argument as a tensor; a Python real becomes a 0-dim tensor like ``like``."""
    if isinstance(radius, torch.Tensor):
        return radius
    if isinstance(radius, numbers.Real) and not isinstance(radius, bool):
        return torch.as_tensor(float(radius), dtype=like.dtype, device=like.device)
    kind = type(radius).__name__
    raise ShapeError(f"expected {name} to be a torch.Tensor or a float, got {kind}")


def _check_tensors(tensors: dict[str, torch.Tensor]) -> None:
    """Every tensor of a dtype in :data:`DTYPES`, of the first one's dtype and on its device
    (no promotion: mixed dtypes are refused, naming both)."""
    ref_name, ref = next(iter(tensors.items()))
    for name, t in tensors.items():
        if not isinstance(t, torch.Tensor):
            raise ShapeError(f"expected {name} to be a torch.Tensor, got {type(t).__name__}")
        if t.dtype not in DTYPES:
            raise ShapeError(
                f"expected {name} of a floating dtype (torch.float32 or torch.float64), "
                f"got {t.dtype}"
            )
        if t.device != ref.device:
            raise ShapeError(f"expected {name} on {ref.device} (as {ref_name}), got {t.device}")
        if t.dtype != ref.dtype:
            raise ShapeError(f"expected {name} {ref.dtype} (as {ref_name}), got {t.dtype}")


def _broadcast_batch(args: dict[str, tuple[torch.Tensor, int]]) -> torch.Size:
    """Broadcast shape of the leading dimensions; ``args`` maps name to (tensor, trailing
    event dimensions)."""
    try:
        return torch.broadcast_shapes(*(t.shape[: t.dim() - k] for t, k in args.values()))
    except RuntimeError:
        got = ", ".join(f"{name} {tuple(t.shape)}" for name, (t, _) in args.items())
        raise ShapeError(f"expected broadcastable leading dimensions, got {got}") from None


def _finite(name: str, x: torch.Tensor) -> _Check:
    return torch.isfinite(x).all(), lambda: non_finite_error(name, x)


def _nonnegative(name: str, x: torch.Tensor) -> _Check:
    return (x >= 0).all(), lambda: DataError(f"expected {name} >= 0, got min {float(x.min())}")


def _radius_sum_positive(R: torch.Tensor, name: str = "robot_radius + human_radius") -> _Check:
    return (R > 0).all(), lambda: ShapeError(f"expected {name} > 0 everywhere")


def _run_checks(checks: list[_Check]) -> None:
    """Raise the first failing check's error; one host sync for all of them."""
    ok = torch.stack([flag for flag, _ in checks]).tolist()
    for passed, (_, error) in zip(ok, checks):
        if not passed:
            raise error()


def _component_first(x: torch.Tensor, rank: int) -> torch.Tensor:
    """(..., 3) -> (3, ...), with singleton dimensions prepended to the batch so that it has
    ``rank`` dimensions (component-first tensors broadcast only when their ranks agree)."""
    x = x.movedim(-1, 0)  # (3, ...)
    return x.reshape((3,) + (1,) * (rank - x.dim() + 1) + x.shape[1:])  # (3, 1.., ...)


def _eigh_psd(cov: torch.Tensor, name: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Eigen-decomposition of the symmetrised ``cov`` (finite); :class:`DataError` when an
    eigenvalue is negative beyond rounding (``sqrt(eps)`` of the largest magnitude) or
    overflows the dtype.

    Entries near the dtype's limit make LAPACK fail or return NaN; such matrices are solved
    again scaled by a power of two each (exact), so only a covariance whose eigenvalues do
    not fit in the dtype is refused. Ordinary matrices take the unscaled path only.
    """
    # halves first: 0.5 a + 0.5 b cannot overflow where a + b could (same bits otherwise)
    sym = 0.5 * cov + 0.5 * cov.transpose(-1, -2)
    tol = torch.finfo(sym.dtype).eps ** 0.5
    try:
        s, U = torch.linalg.eigh(sym)  # (..., 3), (..., 3, 3)
    except RuntimeError:  # torch.linalg.LinAlgError: no convergence near the float limit
        finite = ok = False
    else:
        psd = (s[..., 0] >= -tol * s.abs().amax(-1)).all()  # eigenvalues ascend
        finite, ok = torch.stack((torch.isfinite(s).all(), psd)).tolist()  # one host sync
    if not finite:
        s, U = _eigh_scaled(sym, name)
        ok = bool((s[..., 0] >= -tol * s.abs().amax(-1)).all())
    if not ok:
        raise DataError(
            f"expected {name} positive semidefinite, got eigenvalue {float(s[..., 0].min())}"
        )
    return s, U


def _eigh_scaled(sym: torch.Tensor, name: str) -> tuple[torch.Tensor, torch.Tensor]:
    """``eigh`` of the symmetric (..., 3, 3) ``sym``, each matrix scaled by a power of two so
    that its largest entry is below 1 in magnitude (exact scaling); :class:`DataError` when an
    eigenvalue overflows the dtype."""
    _, expo = torch.frexp(sym.abs().amax(dim=(-1, -2)))  # (...): amax = f 2^expo, f in [0.5, 1)
    scale = torch.ldexp(torch.ones_like(sym[..., 0, 0]), -expo)  # (...) 2^-expo
    sn, U = torch.linalg.eigh(sym * scale[..., None, None])
    s = sn / scale[..., None]  # inf where an eigenvalue does not fit in the dtype
    if not bool(torch.isfinite(s).all()):
        raise DataError(
            f"expected {name} whose eigenvalues fit in {s.dtype}, got entries up to "
            f"{float(sym.abs().amax()):.3g}: its eigenvalues overflow"
        )
    return s, U


def _checked_pair_args(
    method: str,
    solver: str,
    prune_sigma: float | None,
    robot_center: torch.Tensor,
    robot_radius: torch.Tensor | float,
    mean: torch.Tensor,
    spread: tuple[str, torch.Tensor],
    human_radius: torch.Tensor | float,
) -> tuple[torch.Tensor, torch.Tensor, int, torch.Tensor]:
    """The input checks shared by the full (``("cov", (..., 3, 3))``) and diagonal
    (``("var", (..., 3))``, also >= 0) pair bounds: choices, ``prune_sigma``, shapes, dtypes,
    devices, broadcasting, finiteness and a positive radius sum.

    Returns:
        The radii as tensors, the broadcast batch rank and the radius sum ``R``.
    """
    name, value = spread
    full = name == "cov"
    _check_choices(method, solver)
    _check_prune_sigma(prune_sigma)
    check_shape("robot_center", robot_center, ("...", 3))
    check_shape("mean", mean, ("...", 3))
    check_shape(name, value, ("...", 3, 3) if full else ("...", 3))
    robot_r = _as_radius("robot_radius", robot_radius, robot_center)
    human_r = _as_radius("human_radius", human_radius, robot_center)
    args = {
        "robot_center": (robot_center, 1),
        "robot_radius": (robot_r, 0),
        "mean": (mean, 1),
        name: (value, 2 if full else 1),
        "human_radius": (human_r, 0),
    }
    _check_tensors({n: t for n, (t, _) in args.items()})
    rank = len(_broadcast_batch(args))
    R = robot_r + human_r
    checks = [_finite(n, t) for n, (t, _) in args.items()]
    if not full:
        checks.append(_nonnegative(name, value))
    _run_checks(checks + [_radius_sum_positive(R)])
    return robot_r, human_r, rank, R


def sphere_collision_bound(
    robot_center: torch.Tensor,
    robot_radius: torch.Tensor | float,
    mean: torch.Tensor,
    cov: torch.Tensor,
    human_radius: torch.Tensor | float,
    *,
    method: Method = "min",
    solver: Solver = "newton",
    prune_sigma: float | None = None,
) -> torch.Tensor:
    """Upper bound on P(robot sphere meets a human sphere with Gaussian centre) (sec. 5).

    Bounds ``P(||X - c|| <= r1 + r2)``, ``X ~ N(mean, cov)``, by eq. approx_sphere_collision
    with the ball's volume ``(4/3) pi R^3`` (the paper prints ``R^2``; see the module
    docstring), by the half-space bound ``Phi(-m)``, or by their minimum. Leading dimensions
    broadcast; an empty batch gives an empty result. Differentiable with respect to
    ``robot_center`` and ``mean``.

    A pair whose squared distance ``||mean - robot_center||^2`` overflows the dtype (a
    distance beyond about 1.3e154 m in float64, 1.8e19 m in float32) gets the bound of the
    Euclidean gap alone, 0 in practice, with no gradient (see the module docstring). A radius
    sum below :data:`RADIUS_FLOOR` (1 nm) is raised to it, which keeps the bound an upper
    bound.

    Args:
        robot_center: (..., 3) robot sphere centres [m], float32 or float64.
        robot_radius: (...) robot sphere radii [m], dtype and device of ``robot_center``, or
            a float.
        mean: (..., 3) mean of the human sphere centre [m], dtype and device of
            ``robot_center``.
        cov: (..., 3, 3) covariance of the human sphere centre [m^2], symmetric positive
            (semi)definite, dtype and device of ``robot_center``; eigenvalues below
            ``VAR_FLOOR`` are raised to it.
        human_radius: (...) human sphere radii [m], dtype and device of ``robot_center``, or
            a float.
        method: ``"min"`` (default), ``"volume"`` or ``"halfspace"``.
        solver: ``"newton"`` (default) or the paper's ``"bisection"`` (reference, no exact
            gradient through the multiplier).
        prune_sigma: skip the solver for pairs farther than this many standard deviations
            (> 0; cheap, never lower bound; None: never prune).

    Returns:
        (...) bound in [0, 1], dtype of the inputs.

    Raises:
        ShapeError: on wrong trailing dimensions, leading dimensions that do not broadcast,
            a dtype other than float32 and float64 (half precision and integers included),
            tensors of mixed devices or dtypes (no promotion: the message names both), or
            non-positive radius sums.
        DataError: on NaN or Inf in any argument, or a covariance with a negative eigenvalue.
        ConfigError: on an unknown method or solver, or ``prune_sigma <= 0``.
    """
    robot_radius, human_radius, rank, R = _checked_pair_args(
        method, solver, prune_sigma, robot_center, robot_radius, mean, ("cov", cov), human_radius
    )
    s, U = _eigh_psd(cov, "cov")  # (..., 3), (..., 3, 3)
    diff = mean - robot_center  # (..., 3)
    batch = torch.broadcast_shapes(U.shape[:-2], diff.shape[:-1])
    d = torch.einsum("...ji,...j->...i", U.expand(batch + (3, 3)), diff.expand(batch + (3,)))
    d2 = _component_first(d * d, rank)  # (3, ...)
    return _pair_bounds(
        d2, _component_first(s, rank), R, method=method, solver=solver, prune_sigma=prune_sigma
    )


def sphere_collision_bound_diag(
    robot_center: torch.Tensor,
    robot_radius: torch.Tensor | float,
    mean: torch.Tensor,
    var: torch.Tensor,
    human_radius: torch.Tensor | float,
    *,
    method: Method = "min",
    solver: Solver = "newton",
    prune_sigma: float | None = None,
) -> torch.Tensor:
    """:func:`sphere_collision_bound` for diagonal covariances (no eigendecomposition).

    Empty batches and far pairs as :func:`sphere_collision_bound`.

    Args:
        robot_center: (..., 3) robot sphere centres [m], float32 or float64.
        robot_radius: (...) robot sphere radii [m], dtype and device of ``robot_center``, or
            a float.
        mean: (..., 3) mean of the human sphere centre [m], dtype and device of
            ``robot_center``.
        var: (..., 3) per-axis variances of the human sphere centre [m^2], >= 0, dtype and
            device of ``robot_center``.
        human_radius: (...) human sphere radii [m], dtype and device of ``robot_center``, or
            a float.
        method: ``"min"`` (default), ``"volume"`` or ``"halfspace"``.
        solver: ``"newton"`` (default) or ``"bisection"`` (reference).
        prune_sigma: see :func:`sphere_collision_bound`.

    Returns:
        (...) bound in [0, 1].

    Raises:
        ShapeError: as :func:`sphere_collision_bound`.
        DataError: on NaN or Inf in any argument, or a negative variance.
        ConfigError: on an unknown method or solver, or ``prune_sigma <= 0``.
    """
    robot_radius, human_radius, rank, R = _checked_pair_args(
        method, solver, prune_sigma, robot_center, robot_radius, mean, ("var", var), human_radius
    )
    diff = mean - robot_center
    d2 = _component_first(diff * diff, rank)  # (3, ...)
    return _pair_bounds(
        d2, _component_first(var, rank), R, method=method, solver=solver, prune_sigma=prune_sigma
    )


def max_density_point(
    robot_center: torch.Tensor,
    radius: torch.Tensor | float,
    mean: torch.Tensor,
    cov: torch.Tensor,
    *,
    solver: Solver = "newton",
) -> tuple[torch.Tensor, torch.Tensor]:
    """``x_max``, the point of the ball ``||x - c|| <= radius`` with the highest density.

    An empty batch gives empty results. The squared distance ``||mean - robot_center||^2``
    must not overflow the dtype (a distance up to about 1.3e154 m in float64, 1.8e19 m in
    float32): beyond, the solver's squared distances overflow, and unlike the bounds (0 for
    such pairs) ``x_max`` has no cheap substitute.

    Args:
        robot_center: (..., 3) ball centre ``c`` [m], float32 or float64.
        radius: (...) ball radius ``R = r1 + r2`` [m], > 0 (below :data:`RADIUS_FLOOR`
            raised to it), dtype and device of ``robot_center``, or a float.
        mean: (..., 3) Gaussian mean [m], dtype and device of ``robot_center``.
        cov: (..., 3, 3) Gaussian covariance [m^2], symmetric positive (semi)definite, dtype
            and device of ``robot_center``.
        solver: ``"newton"`` or ``"bisection"``.

    Returns:
        ``(x_max (..., 3) [m], lambda (...) [m^-2])``; ``lambda = 0`` and ``x_max = mean`` when
        the mean lies inside the ball.

    Raises:
        ShapeError: on wrong trailing dimensions, leading dimensions that do not broadcast,
            a dtype other than float32 and float64, tensors of mixed devices or dtypes, or a
            non-positive radius.
        DataError: on NaN or Inf in any argument, a covariance with a negative eigenvalue,
            or a mean too far from the centre (see above).
        ConfigError: on an unknown solver.
    """
    _check_choices("min", solver)
    check_shape("robot_center", robot_center, ("...", 3))
    check_shape("mean", mean, ("...", 3))
    check_shape("cov", cov, ("...", 3, 3))
    radius = _as_radius("radius", radius, robot_center)
    args = {
        "robot_center": (robot_center, 1),
        "radius": (radius, 0),
        "mean": (mean, 1),
        "cov": (cov, 2),
    }
    _check_tensors({n: t for n, (t, _) in args.items()})
    _broadcast_batch(args)
    checks = [_finite(n, t) for n, (t, _) in args.items()]
    _run_checks(checks + [_radius_sum_positive(radius, "radius")])
    s, U = _eigh_psd(cov, "cov")
    s = s.clamp_min(VAR_FLOOR)
    diff = mean - robot_center
    batch = torch.broadcast_shapes(U.shape[:-2], diff.shape[:-1], radius.shape)
    U = U.expand(batch + (3, 3))
    s = s.expand(batch + (3,))
    d = torch.einsum("...ji,...j->...i", U, diff.expand(batch + (3,)))  # (..., 3)
    R = radius.expand(batch).clamp_min(RADIUS_FLOOR)
    dist2 = (d * d).sum(-1)  # (...)
    outside = dist2 > R * R
    in_range = torch.isfinite(dist2)
    any_outside, all_in_range = torch.stack([outside.any(), in_range.all()]).tolist()
    if not all_in_range:
        limit = math.sqrt(torch.finfo(d.dtype).max)
        raise DataError(
            f"expected ||mean - robot_center|| < {limit:.1e} m in {d.dtype} (its square "
            f"overflows beyond), got {int((~in_range).sum())} of {dist2.numel()} pairs farther"
        )
    lam = torch.zeros(batch, dtype=d.dtype, device=d.device)
    if any_outside:
        args = (d[outside].T ** 2, s[outside].T, R[outside])  # (3, N), (3, N), (N,)
        lam_a = _solve_newton(*args) if solver == "newton" else _solve_bisection(*args)
        lam = lam.masked_scatter(outside, lam_a)
    y = d / (1.0 + lam.unsqueeze(-1) * s)  # (..., 3) eigen-coordinates relative to c
    x = robot_center.expand(batch + (3,)) + torch.einsum("...ij,...j->...i", U, y)
    return x, lam


def _weights_per_waypoint(weights: torch.Tensor, W: int, A: int) -> torch.Tensor:
    if weights.dim() == 1:
        check_shape("weights", weights, (A,))
        return weights.expand(W, A)
    check_shape("weights", weights, (W, A))
    return weights


def pairwise_bound_matrix(
    robot_centers: torch.Tensor,
    robot_radii: torch.Tensor,
    human_mean: torch.Tensor,
    human_cov: torch.Tensor,
    human_radii: torch.Tensor,
    weights: torch.Tensor,
    *,
    method: Method = "min",
    prune_sigma: float | None = DEFAULT_PRUNE_SIGMA,
    max_pairs_per_chunk: int = 2_000_000,
) -> torch.Tensor:
    """Action-mixture bound for every robot/human sphere pair (eq. max_collision_probability).

    Entry ``[b, w, j, l]`` is ``sum_a weights[a] * bound(robot sphere j of trajectory b at
    waypoint w, human sphere l of action a at waypoint w)``.

    Every tensor has the dtype and device of ``robot_centers``. Any of B, W, S_r, S_h may be
    0 (the result is then empty); with A = 0 (no action) every entry is 0. Far pairs as
    :func:`sphere_collision_bound`.

    Args:
        robot_centers: (B, W, S_r, 3) robot sphere centres [m], float32 or float64.
        robot_radii: (S_r,) robot sphere radii [m].
        human_mean: (W, A, S_h, 3) mean human sphere centres per action [m].
        human_cov: (W, A, S_h, 3, 3) covariances [m^2], or (W, A, S_h, 3) per-axis variances
            [m^2] (diagonal covariances: no eigendecomposition).
        human_radii: (S_h,) human sphere radii [m].
        weights: (A,) or (W, A) action probabilities p(c | F, p): >= 0, summing to at most
            1 over A (up to rounding).
        method: ``"min"``, ``"volume"`` or ``"halfspace"``.
        prune_sigma: see :func:`sphere_collision_bound` (None: never prune).
        max_pairs_per_chunk: the batch is processed in chunks of at most this many pairs.

    Returns:
        (B, W, S_r, S_h) mixture bounds (may exceed 1 only by rounding; each term is <= 1).

    Raises:
        ShapeError: on inconsistent shapes, a dtype other than float32 and float64, tensors
            of mixed devices or dtypes (no promotion: the message names both), or
            non-positive radius sums.
        DataError: on NaN or Inf in any argument, negative variances, a covariance with a
            negative eigenvalue, or weights that are negative or sum to more than 1.
        ConfigError: on an unknown method, ``prune_sigma <= 0`` or a non-positive chunk size.
    """
    _check_choices(method, "newton")
    _check_prune_sigma(prune_sigma)
    integer("max_pairs_per_chunk", max_pairs_per_chunk, minimum=1)
    check_shape("robot_centers", robot_centers, ("B", "W", "S_r", 3))
    B, W, S_r, _ = robot_centers.shape
    check_shape("robot_radii", robot_radii, (S_r,))
    check_shape("human_mean", human_mean, (W, "A", "S_h", 3))
    _, A, S_h, _ = human_mean.shape
    check_shape("human_radii", human_radii, (S_h,))
    diagonal = isinstance(human_cov, torch.Tensor) and human_cov.dim() == 4
    if diagonal:
        check_shape("human_cov", human_cov, (W, A, S_h, 3))
    else:
        check_shape("human_cov", human_cov, (W, A, S_h, 3, 3))
    tensors = {
        "robot_centers": robot_centers,
        "robot_radii": robot_radii,
        "human_mean": human_mean,
        "human_cov": human_cov,
        "human_radii": human_radii,
        "weights": weights,
    }
    _check_tensors(tensors)
    w = _weights_per_waypoint(weights, W, A)  # (W, A)
    R = robot_radii[:, None, None] + human_radii[None, None, :]  # (S_r, 1, S_h)
    w_tol = 1.0 + torch.finfo(w.dtype).eps ** 0.5
    w_sum = w.sum(-1)  # (W,)
    checks = [_finite(n, t) for n, t in tensors.items()] + [
        _radius_sum_positive(R, "robot_radii + human_radii"),
        _nonnegative("weights", weights),
        (
            (w_sum <= w_tol).all(),
            lambda: DataError(f"expected weights summing to <= 1, got {float(w_sum.max())}"),
        ),
    ]
    if diagonal:
        checks.append(_nonnegative("human_cov", human_cov))
    _run_checks(checks)

    if diagonal:
        s = human_cov.movedim(-1, 0)  # (3, W, A, S_h)
        mu_e = human_mean.movedim(-1, 0)  # (3, W, A, S_h)
        U = None
    else:
        s, U = _eigh_psd(human_cov, "human_cov")
        s = s.movedim(-1, 0)  # (3, W, A, S_h) eigenvalues
        mu_e = torch.einsum("walji,walj->iwal", U, human_mean)  # (3, W, A, S_h) eigen-coords

    pairs_per_traj = W * S_r * A * S_h
    chunk = max(1, max_pairs_per_chunk // max(pairs_per_traj, 1))
    out = []
    for b0 in range(0, B, chunk):
        c = robot_centers[b0 : b0 + chunk]  # (b, W, S_r, 3)
        if U is None:
            c_e = c.movedim(-1, 0)[..., None, None]  # (3, b, W, S_r, 1, 1)
        else:
            c_e = torch.einsum("walji,bwrj->ibwral", U, c)  # (3, b, W, S_r, A, S_h)
        d = mu_e[:, None, :, None] - c_e  # (3, b, W, S_r, A, S_h)
        p = _pair_bounds(
            d * d,
            s[:, None, :, None],
            R,
            method=method,
            solver="newton",
            prune_sigma=prune_sigma,
        )  # (b, W, S_r, A, S_h)
        out.append(torch.einsum("bwral,wa->bwrl", p, w))
    if not out:  # B = 0
        return robot_centers.new_zeros((0, W, S_r, S_h))
    return torch.cat(out, dim=0)


def trajectory_collision_bound(
    robot_centers: torch.Tensor,
    robot_radii: torch.Tensor,
    human_mean: torch.Tensor,
    human_cov: torch.Tensor,
    human_radii: torch.Tensor,
    weights: torch.Tensor,
    *,
    method: Method = "min",
    reduce: Literal["max", "sum", "none"] = "max",
    prune_sigma: float | None = DEFAULT_PRUNE_SIGMA,
    max_pairs_per_chunk: int = 2_000_000,
) -> torch.Tensor:
    """Collision-probability bound per trajectory and waypoint (eq. max_collision_probability).

    ``max_{j, l} sum_a weights[a] * bound(robot sphere j, human sphere l of action a)``: the
    mixture over actions of the pair bounds, maximised over sphere pairs. With no sphere pair
    (S_r = 0 or S_h = 0) the bound is 0 (nothing can collide); B = 0 or W = 0 give an empty
    result. Inputs as :func:`pairwise_bound_matrix`.

    The paper's maximum (the planner's acceptance test by default) bounds each pair's
    probability of touching, not the probability that some pair touches, which can be
    larger: a robot sphere between two independently predicted hands is touched by one or
    the other more often than by either. ``reduce="sum"`` gives Boole's bound over the
    pairs, an upper bound on that probability too (pruned pairs keep their cheap bound, never
    a lower one); the planner's ``OptimizerCfg.bound_reduce="sum"`` plans with it.

    Args:
        robot_centers: (B, W, S_r, 3) robot sphere centres [m], float32 or float64.
        robot_radii: (S_r,) robot sphere radii [m].
        human_mean: (W, A, S_h, 3) mean human sphere centres per action [m].
        human_cov: (W, A, S_h, 3, 3) covariances [m^2] or (W, A, S_h, 3) variances [m^2].
        human_radii: (S_h,) human sphere radii [m].
        weights: (A,) or (W, A) action probabilities (>= 0, summing to at most 1).
        method: ``"min"``, ``"volume"`` or ``"halfspace"``.
        reduce: ``"max"`` (the paper's) or ``"sum"`` (over the pairs) -> (B, W); ``"none"``
            -> (B, W, S_r, S_h) as :func:`pairwise_bound_matrix`.
        prune_sigma: see :func:`sphere_collision_bound`.
        max_pairs_per_chunk: memory cap, see :func:`pairwise_bound_matrix`.

    Returns:
        (B, W) bounds in [0, 1] (or the pair matrix for ``reduce="none"``).

    Raises:
        ShapeError: on inconsistent shapes, dtypes or devices (see
            :func:`pairwise_bound_matrix`, which validates the inputs once).
        DataError: on non-finite or out-of-range inputs (see :func:`pairwise_bound_matrix`).
        ConfigError: on an unknown method or reduce, ``prune_sigma <= 0`` or a non-positive
            chunk size.
    """
    if reduce not in ("max", "sum", "none"):
        raise ConfigError(f"expected reduce in ('max', 'sum', 'none'), got {reduce!r}")
    pair = pairwise_bound_matrix(
        robot_centers,
        robot_radii,
        human_mean,
        human_cov,
        human_radii,
        weights,
        method=method,
        prune_sigma=prune_sigma,
        max_pairs_per_chunk=max_pairs_per_chunk,
    )
    if reduce == "none":
        return pair
    if pair.shape[2] == 0 or pair.shape[3] == 0:  # no sphere pair: the maximum of none is 0
        return pair.new_zeros(pair.shape[:2])
    if reduce == "sum":
        return pair.flatten(2).sum(-1).clamp(0.0, 1.0)
    return pair.flatten(2).amax(-1).clamp(0.0, 1.0)
