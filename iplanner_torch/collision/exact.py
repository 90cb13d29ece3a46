"""Reference probabilities that a Gaussian point lies in a ball (validation of the bounds).

With ``Sigma = U diag(s) U^T``, ``d = U^T (mu - c)`` and ``z ~ N(0, I)``,
``||X - c||^2 = sum_k s_k (z_k + d_k / sqrt(s_k))^2`` is a noncentral quadratic form in
normal variables, so ``P(||X - c|| <= R)`` is its CDF at ``R^2``. Three independent routes:

* **Ruben's series** (Ruben 1962; Farebrother 1984, AS 204): a mixture of central chi-square
  CDFs with positive weights when the scale ``beta`` is ``min s_k``. Vectorised over cases in
  numpy float64; its truncation error is bounded rigorously (the weights sum to 1 and the CDFs
  decrease with the degrees of freedom), so :func:`ruben_ball_probability` returns a bracket.
  It needs about ``||d||^2 / (2 min s)`` terms and more when ``R^2 / min s`` is large (small
  sigma) or the covariance is very anisotropic: there use Imhof or Monte Carlo.
  :func:`exact_ball_probability` warns (:class:`~iplanner_torch.errors.NumericalWarning`)
  when the bracket it returns the upper end of is wider than :data:`ATOL`.
* **Imhof's integral** (Imhof 1961): ``P(Q > x) = 1/2 + (1/pi) int_0^inf sin(theta(u)) /
  (u rho(u)) du``, one integration per case with absolute accuracy :data:`ATOL` (1e-8) on
  the probability, checked by an error estimate. The integrand oscillates with period about
  ``4 pi`` and decays only like ``u^-5/2`` beyond ``u ~ R^2 / min s``, so a plain adaptive
  quadrature over ``[0, inf)`` gives up unnoticed (it was off by 1e-4 at ``R / sigma = 20``
  and by 0.05 at 30, the mean at the centre).
  Instead: Gauss-Legendre panels of at most half a period of phase each (and at most the
  panel's distance to 0, for the algebraic factors) up to where the rest of the integral is
  bounded below 1e-12, or, where that is far out, up to where the phase of ``rho`` has
  settled, and QUADPACK's Fourier integral (QAWF) for the tail. The error estimate is the
  difference of a 20- and a 10-point rule per panel plus QAWF's estimate; a case whose
  estimate exceeds :data:`ATOL`, or that would need more than :data:`IMHOF_MAX_PANELS`
  panels (a variance below about ``1e-10 R^2`` with the mean off-centre along it; such a case
  takes seconds near that limit, a few milliseconds usually), warns
  (:class:`~iplanner_torch.errors.NumericalWarning`) and gives its estimate, or NaN when none
  could be made. Checked against the noncentral chi-square CDF for ``R / sigma`` from 1e-3
  to 3000 (error below 1e-13) and against Ruben's series for anisotropic covariances.
* **Monte Carlo** with a standard error, seeded.

Inputs of any dtype are converted to float64 (the reference values are float64 whatever the
dtype of the bounds they check); empty batches give empty results.

Degenerate covariances: an eigenvalue at most ``DEGENERATE_RTOL`` times the largest (or
negative within rounding) is a direction without randomness: its squared offset is subtracted
from ``R^2`` and the probability is that of the remaining directions; a zero covariance gives
the indicator of the mean lying inside or on the sphere. A covariance whose eigenvalues
overflow float64 is refused (:class:`~iplanner_torch.errors.DataError`).

Far cases: where the ball lies more than ``FAR_SIGMAS`` standard deviations (of the widest
direction) from the mean, ``P <= Phi(-FAR_SIGMAS)``, which is 0 in float64; Ruben's series
and Imhof's integral return exactly 0 there without evaluating (the series overflows and the
integral loses all accuracy for large noncentralities, returning up to 0.5 at 1e4 standard
deviations). Distances whose squares overflow float64 count as far. Likewise Imhof's integral
returns 0 where a variance exceeds ``1e300 R^2``: ``P <= sqrt(2 R^2 / (pi s))`` is below
1e-150 there.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Callable
from typing import Literal

import numpy as np
import torch
from scipy import integrate, special

from iplanner_torch.checks import integer
from iplanner_torch.checks import seed as check_seed
from iplanner_torch.errors import ConfigError, DataError, NumericalWarning, ShapeError
from iplanner_torch.types import check_shape, non_finite_error

#: Ruben's series stops when the truncation bound is below ``RUBEN_RTOL * p + RUBEN_ATOL``.
RUBEN_RTOL = 1e-12
RUBEN_ATOL = 1e-300
#: Cases farther than this many standard deviations have probability below Phi(-40), about
#: 4e-350: 0 in float64.
FAR_SIGMAS = 40.0
#: Absolute accuracy of :func:`exact_ball_probability` (Imhof's integral, and the bracket
#: width beyond which the Ruben route warns).
ATOL = 1e-8
#: Eigenvalues at most this times the largest are zero (float64 ``eigh`` rounding is a few
#: ``eps`` of the largest): those directions are deterministic.
DEGENERATE_RTOL = 16.0 * float(np.finfo(np.float64).eps)
#: The most Gauss-Legendre panels of one Imhof integral (20 + 10 nodes each).
IMHOF_MAX_PANELS = 250_000
#: Monte Carlo draws at most this many points (samples times cases) at once: 6 MiB per
#: (points, 3) float64 array, about 25 MiB in all.
MC_BLOCK = 2**18

# Imhof's integral: the neglected tail bound, and the phase rate of rho below which the
# QAWF tail starts (the slow factors then change little over one period of the carrier).
_IMHOF_TAIL_ATOL = 1e-12
_IMHOF_SLOW_PHASE = 0.05
_IMHOF_LU_MAX = 1e150  # lam * u beyond this: every term saturated
_GL_HI = np.polynomial.legendre.leggauss(20)
_GL_LO = np.polynomial.legendre.leggauss(10)
_PANEL_BLOCK = 4096  # panels evaluated at once


def _far(s: np.ndarray, d2: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Cases beyond ``FAR_SIGMAS``: ``(||d|| - sqrt(x)) / sqrt(max s)`` over the last axis.

    A squared distance that overflowed (inf, or NaN where a rotation met inf * 0) is far.

    Args:
        s: (..., n) variances [m^2]; d2: (..., n) squared offsets [m^2]; x: (...) ``R^2``.

    Returns:
        (...) bool.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        gap = np.sqrt(d2.sum(-1)) - np.sqrt(x)
        return ~(gap <= FAR_SIGMAS * np.sqrt(s.max(-1)))


def _check_finite(name: str, x: np.ndarray) -> None:
    if not np.isfinite(x).all():
        raise non_finite_error(name, x)


def _canonical(
    center: torch.Tensor, radius: torch.Tensor | float, mean: torch.Tensor, cov: torch.Tensor
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, ...]]:
    """Flatten to numpy float64: ``s (N, 3)`` eigenvalues (exactly 0 in deterministic
    directions, see ``DEGENERATE_RTOL``), ``d2 (N, 3)``, ``x (N,) = R^2``.

    Validates the arguments of the public functions (see :func:`exact_ball_probability`).
    """
    check_shape("center", center, ("...", 3))
    check_shape("mean", mean, ("...", 3))
    check_shape("cov", cov, ("...", 3, 3))
    if not isinstance(radius, (torch.Tensor, numbers.Real)) or isinstance(radius, bool):
        kind = type(radius).__name__
        raise ShapeError(f"expected radius to be a torch.Tensor or a float, got {kind}")
    if not isinstance(radius, torch.Tensor):
        radius = torch.tensor(float(radius), dtype=torch.float64)  # not float32 rounded
    try:
        batch = torch.broadcast_shapes(
            center.shape[:-1], radius.shape, mean.shape[:-1], cov.shape[:-2]
        )
    except RuntimeError:
        got = ", ".join(
            f"{n} {tuple(t.shape)}"
            for n, t in (("center", center), ("radius", radius), ("mean", mean), ("cov", cov))
        )
        raise ShapeError(f"expected broadcastable leading dimensions, got {got}") from None
    c = center.detach().double().cpu().expand(batch + (3,)).reshape(-1, 3).numpy()
    m = mean.detach().double().cpu().expand(batch + (3,)).reshape(-1, 3).numpy()
    S = cov.detach().double().cpu().expand(batch + (3, 3)).reshape(-1, 3, 3).numpy()
    r = radius.detach().double().cpu().expand(batch).reshape(-1).numpy()
    for name, x in (("center", c), ("radius", r), ("mean", m), ("cov", S)):
        _check_finite(name, x)
    if not (r > 0).all():
        raise ShapeError(f"expected radius > 0 everywhere, got min {r.min()}")
    s, U = _eigh_scaled(S)
    # Negative eigenvalues beyond the rounding of the input's dtype: not a covariance.
    eps = torch.finfo(cov.dtype if cov.is_floating_point() else torch.float64).eps
    if s.size and not (s[:, 0] >= -(eps**0.5) * np.abs(s).max(1)).all():
        raise DataError(f"expected cov positive semidefinite, got eigenvalue {s[:, 0].min()}")
    if s.size:
        s = np.where(s > DEGENERATE_RTOL * s.max(1, keepdims=True), s, 0.0)
    with np.errstate(over="ignore", invalid="ignore"):  # overflowed distances are far cases
        d = np.einsum("nji,nj->ni", U, m - c)
        d2 = d * d
    return s, d2, r * r, tuple(batch)


def _eigh_scaled(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``eigh`` of the symmetrised (N, 3, 3) ``S``, scaled by a power of two per case so that
    entries near the float64 limit neither overflow the symmetrisation nor stall LAPACK (the
    scaling is exact: finite results are those of the unscaled matrix).

    Raises:
        DataError: when an eigenvalue overflows float64.
    """
    if not S.size:
        return np.linalg.eigh(S)
    _, expo = np.frexp(np.abs(S).max(axis=(1, 2)))  # (N,) amax = f 2^expo, f in [0.5, 1)
    Sn = np.ldexp(S, -expo[:, None, None])  # entries below 1 in magnitude
    sn, U = np.linalg.eigh(0.5 * (Sn + np.swapaxes(Sn, -1, -2)))
    with np.errstate(over="ignore"):
        s = np.ldexp(sn, expo[:, None])
    if not np.isfinite(s).all():
        i = int(np.flatnonzero(~np.isfinite(s).all(1))[0])
        raise DataError(
            f"expected cov whose eigenvalues fit in float64, got cov {i} (flattened batch "
            f"index) with entries up to {np.abs(S[i]).max():.3g}: its eigenvalues overflow"
        )
    return s, U


def _split_deterministic(
    s: np.ndarray, d2: np.ndarray, x: np.ndarray
) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]]:
    """Take the directions without variance (``s_k = 0``) out of the quadratic form.

    Each adds the constant ``d2_k``, so ``P(Q <= x) = P(Q_rest <= x - sum d2_k)``.

    Args:
        s: (N, n) variances, exactly 0 in deterministic directions; d2: (N, n); x: (N,).

    Returns:
        ``p (N,)``: the probability of the cases decided without integration (all directions
        deterministic: the indicator of ``x_rest >= 0``; ``x_rest <= 0`` otherwise: 0), NaN
        elsewhere; and ``groups``: ``(index (G,), s (G, k), d2 (G, k), x_rest (G,))`` for the
        other cases with ``k`` random directions, ``k = 1 .. n``.
    """
    active = s > 0
    with np.errstate(invalid="ignore"):  # inf - inf: an overflowed distance, decided as 0
        x_rest = x - np.where(active, 0.0, d2).sum(1)
        positive = x_rest > 0
        inside = x_rest >= 0
    n_active = active.sum(1)
    p = np.full(s.shape[0], np.nan)
    p[n_active == 0] = inside[n_active == 0].astype(np.float64)
    p[(n_active > 0) & ~positive] = 0.0
    groups = []
    for k in range(1, s.shape[1] + 1):
        idx = np.flatnonzero((n_active == k) & positive)
        if idx.size:
            sel = active[idx]
            groups.append(
                (idx, s[idx][sel].reshape(-1, k), d2[idx][sel].reshape(-1, k), x_rest[idx])
            )
    return p, groups


def ruben_series(
    s: np.ndarray, d2: np.ndarray, x: np.ndarray, *, max_terms: int = 400
) -> tuple[np.ndarray, np.ndarray]:
    """Ruben's series for ``P(sum_k s_k (z_k + d_k/sqrt(s_k))^2 <= x)``, vectorised.

    Args:
        s: (N, n) positive weights (variances) [m^2].
        d2: (N, n) squared offsets ``d_k^2`` [m^2].
        x: (N,) threshold ``R^2`` [m^2].
        max_terms: the most series terms.

    Returns:
        ``(lower, upper)``, each (N,): the partial sum and the partial sum plus the rigorous
        truncation bound (up to float64 rounding); ``(0, 0)`` for cases beyond
        ``FAR_SIGMAS`` standard deviations (see the module docstring). ``N = 0`` gives
        empty arrays.

    Raises:
        ShapeError: on inconsistent shapes.
        DataError: on NaN or Inf, non-positive ``s``, or negative ``d2`` or ``x``.
        ConfigError: when ``max_terms`` is not a positive int.
    """
    integer("max_terms", max_terms, minimum=1)
    s, d2, x = np.asarray(s), np.asarray(d2), np.asarray(x)
    if s.ndim != 2 or d2.shape != s.shape or x.shape != s.shape[:1]:
        raise ShapeError(
            f"expected s (N, n), d2 (N, n), x (N,), got {s.shape}, {d2.shape}, {x.shape}"
        )
    _check_series_args(s, d2, x)
    return _ruben_series(s, d2, x, max_terms)


def _check_series_args(s: np.ndarray, d2: np.ndarray, x: np.ndarray) -> None:
    for name, a in (("s", s), ("d2", d2), ("x", x)):
        _check_finite(name, a)
    if not (s > 0).all():
        raise DataError(f"expected s > 0, got min {s.min()}")
    for name, a in (("d2", d2), ("x", x)):
        if not (a >= 0).all():
            raise DataError(f"expected {name} >= 0, got min {a.min()}")


def _ruben_series(
    s: np.ndarray, d2: np.ndarray, x: np.ndarray, max_terms: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ruben_series` without the argument checks."""
    far = _far(s, d2, x)
    if far.any():  # 0 to float64; the series would overflow
        lower, upper = np.zeros(s.shape[0]), np.zeros(s.shape[0])
        near = ~far
        if near.any():
            lower[near], upper[near] = _ruben_series(s[near], d2[near], x[near], max_terms)
        return lower, upper
    n_dim = s.shape[1]
    beta = s.min(axis=1, keepdims=True)  # (N, 1)
    gamma = 1.0 - beta / s  # (N, 3) in [0, 1)
    nc = d2 / s  # (N, 3) noncentralities delta_k^2
    log_a0 = -0.5 * nc.sum(1) + 0.5 * np.log(beta / s).sum(1)  # (N,)
    t = x / beta[:, 0]
    N = s.shape[0]
    K = max_terms
    # g[k] = sum_j gamma_j^k + k delta_j^2 (1 - gamma_j) gamma_j^(k-1), k >= 1.
    k = np.arange(K, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        gpow = gamma[:, :, None] ** k[None, None, :]  # (N, 3, K)
        gpow_m1 = np.concatenate([np.zeros((N, n_dim, 1)), gpow[:, :, :-1]], axis=2)
    g = (gpow + k * (nc * (1.0 - gamma))[:, :, None] * gpow_m1).sum(1)  # (N, K)
    a = np.zeros((N, K))
    a[:, 0] = 1.0
    log_scale = log_a0.copy()  # true a_k = a[:, k] * exp(log_scale)
    for kk in range(1, K):
        a[:, kk] = (g[:, kk:0:-1] * a[:, :kk]).sum(1) / (2.0 * kk)
        big = a[:, kk] > 1e250
        if big.any():
            a[big, : kk + 1] *= 1e-250
            log_scale[big] += 250.0 * math.log(10.0)
    dof = n_dim + 2.0 * np.arange(K + 1)
    F = special.gammainc(dof[None, :] / 2.0, t[:, None] / 2.0)  # (N, K + 1)
    scale = np.exp(log_scale)
    weights = a * scale[:, None]  # (N, K) true coefficients
    lower = (weights * F[:, :K]).sum(1)
    rest = np.clip(1.0 - weights.sum(1), 0.0, 1.0)
    upper = lower + rest * F[:, K] + 1e-15 * lower
    return lower, np.minimum(upper, 1.0)


def ruben_ball_probability(
    center: torch.Tensor,
    radius: torch.Tensor | float,
    mean: torch.Tensor,
    cov: torch.Tensor,
    *,
    max_terms: int = 400,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Bracket ``(lower, upper)`` of ``P(||X - c|| <= radius)`` by Ruben's series (float64).

    Deterministic directions (zero eigenvalues of ``cov``) are taken out first (see the
    module docstring); a zero ``cov`` gives the indicator, as ``(p, p)``.

    Args:
        center: (..., 3) ball centre [m].
        radius: (...) ball radius [m], > 0, or a float.
        mean: (..., 3) Gaussian mean [m].
        cov: (..., 3, 3) Gaussian covariance [m^2], symmetric positive (semi)definite.
        max_terms: series terms.

    Returns:
        ``(lower (...), upper (...))`` float64 CPU tensors; the exact value lies between them.

    Raises:
        ShapeError: as :func:`exact_ball_probability`.
        DataError: as :func:`exact_ball_probability`.
        ConfigError: when ``max_terms`` is not a positive int.
    """
    integer("max_terms", max_terms, minimum=1)
    s, d2, x, batch = _canonical(center, radius, mean, cov)
    lower, upper = _ruben_bracket(s, d2, x, max_terms)
    return torch.from_numpy(lower).view(batch), torch.from_numpy(upper).view(batch)


def _ruben_bracket(
    s: np.ndarray, d2: np.ndarray, x: np.ndarray, max_terms: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_ruben_series` for canonical cases that may have deterministic directions."""
    p, groups = _split_deterministic(s, d2, x)
    lower, upper = p.copy(), p.copy()
    for idx, s_g, d2_g, x_g in groups:
        lower[idx], upper[idx] = _ruben_series(s_g, d2_g, x_g, max_terms)
    return lower, upper


def imhof_cdf(s: np.ndarray, d2: np.ndarray, x: float) -> float:
    """Imhof's integral for ``P(sum_k s_k (z_k + delta_k)^2 <= x)`` of one case.

    Args:
        s: (n,) positive weights [m^2].
        d2: (n,) squared offsets ``d_k^2`` [m^2] (``delta_k^2 = d_k^2 / s_k``).
        x: threshold [m^2].

    Returns:
        The probability with absolute accuracy :data:`ATOL` (see the module docstring);
        exactly 0 beyond ``FAR_SIGMAS`` standard deviations.

    Raises:
        ShapeError: when ``s`` and ``d2`` are not 1-D of one length.
        DataError: on NaN or Inf, non-positive ``s`` or ``x``, or negative ``d2``.

    Warns:
        NumericalWarning: when the integral's error estimate exceeds :data:`ATOL` (the value
            is that estimate's, or NaN when none could be made).
    """
    s = np.asarray(s, dtype=np.float64)
    d2 = np.asarray(d2, dtype=np.float64)
    if s.ndim != 1 or d2.shape != s.shape:
        raise ShapeError(f"expected s (n,) and d2 (n,), got {s.shape} and {d2.shape}")
    _check_series_args(s, d2, np.asarray(x, dtype=np.float64))
    if not x > 0:
        raise DataError(f"expected x > 0, got {x}")
    p, err = _imhof_cdf(s, d2, float(x))
    _warn_inaccurate(np.array([err]))
    return p


def _warn_inaccurate(err: np.ndarray) -> None:
    """NumericalWarning when an Imhof error estimate (N,) exceeds ATOL (or is NaN)."""
    bad = ~(err <= ATOL)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        warnings.warn(
            f"Imhof's integral missed its absolute accuracy {ATOL:g} in {int(bad.sum())} of "
            f"{err.size} cases (first: flattened index {i}, error estimate {err[i]:.3g}; "
            "NaN where no value could be made): use method='mc' for these",
            NumericalWarning,
            stacklevel=3,
        )


def _imhof_terms(lam: np.ndarray, nc: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, ...]:
    """``phi(u) = sum_k arctan(lam_k u) + nc_k lam_k u / (1 + lam_k^2 u^2)`` and the envelope
    ``1 / (u rho(u))`` of Imhof's integrand (``theta = (phi - u) / 2``).

    Args:
        lam: (n,) ``s / x``; nc: (n,) ``d2 / s``; u: (m,) > 0.

    Returns:
        ``(phi (m,), envelope (m,))``.
    """
    lu = np.minimum(lam[:, None] * u[None, :], _IMHOF_LU_MAX)  # (n, m)
    q = lu * lu
    den = 1.0 + q
    phi = (np.arctan(lu) + nc[:, None] * lu / den).sum(0)
    log_rho = 0.25 * np.log1p(q).sum(0) + 0.5 * (nc[:, None] * (q / den)).sum(0)
    return phi, np.exp(-log_rho) / u


def _first_log_u(pred: Callable[[float], bool]) -> float:
    """The smallest ``u`` in ``[e^-700, e^700]`` with ``pred(u)`` (``pred`` monotone: False
    then True), to a relative 1e-10, by bisection on ``log u``."""
    lo, hi = -700.0, 700.0
    while hi - lo > 1e-10:
        mid = 0.5 * (lo + hi)
        if pred(math.exp(mid)):
            hi = mid
        else:
            lo = mid
    return math.exp(hi)


def _imhof_cdf(s: np.ndarray, d2: np.ndarray, x: float) -> tuple[float, float]:
    """:func:`imhof_cdf` without the argument checks; returns ``(p, error estimate)``."""
    if _far(s, d2, np.asarray(x)):
        return 0.0, 0.0  # below Phi(-FAR_SIGMAS); the integral loses all accuracy out there
    if not s.max() <= 1e300 * x:
        return 0.0, 0.0  # P <= sqrt(2 x / (pi s_max)) < 1e-150; lam would overflow
    lam = s / x  # (n,) scaled so that the threshold is 1
    nc = d2 / s  # (n,) noncentralities
    n = s.size
    log_half_det = 0.5 * float(np.log(lam).sum())
    lu_cap = _IMHOF_LU_MAX

    def phase_rate(u: float) -> float:  # bounds |phi'(v)| for v >= u
        lu = np.minimum(lam * u, lu_cap)
        return float((lam * (1.0 + nc) / (1.0 + lu * lu)).sum())

    def log_tail(u: float) -> float:  # log of a bound on int_u^inf |integrand|
        lu = np.minimum(lam * u, lu_cap)
        g = 0.5 * float((nc * (lu * lu / (1.0 + lu * lu))).sum())
        return math.log(2.0 / n) - log_half_det - 0.5 * n * math.log(u) - g

    slow = 0.0
    if phase_rate(0.0) > _IMHOF_SLOW_PHASE:
        slow = _first_log_u(lambda u: phase_rate(u) <= _IMHOF_SLOW_PHASE)
    slow = max(slow, 4.0 * math.pi)  # QAWF starts one period away from the 1/u at 0
    cut = _first_log_u(lambda u: log_tail(u) <= math.log(_IMHOF_TAIL_ATOL))
    qawf = cut > slow
    end = slow if qawf else cut

    # Panels: at most pi of phase each (the clock counts half-periods of the fastest phase
    # bound), and no wider than their distance from 0 beyond 1 / (4 max lam).
    def clock(u: np.ndarray) -> np.ndarray:
        at = np.arctan(np.minimum(lam[:, None] * u[None, :], lu_cap))  # (n, m)
        return (u + ((1.0 + nc)[:, None] * at).sum(0)) / (2.0 * math.pi)

    n_clock = math.ceil(float(clock(np.array([end]))[0]))
    if n_clock > IMHOF_MAX_PANELS:
        return math.nan, math.inf
    k = np.arange(1.0, n_clock)  # clock(u_k) = k, by bisection
    lo, hi = np.zeros(k.size), np.full(k.size, end)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        above = clock(mid) >= k
        hi, lo = np.where(above, mid, hi), np.where(above, lo, mid)
    first = min(float(hi[0]) if hi.size else end, 0.25 / float(lam.max()))
    n_geo = max(0, math.ceil(math.log2(end / first)))
    geo = first * 2.0 ** np.arange(n_geo)
    edges = np.unique(np.concatenate([[0.0], hi, geo[geo < end], [end]]))
    val, err = 0.0, 0.0
    n_panels = edges.size - 1
    for j in range(0, n_panels, _PANEL_BLOCK):
        j_end = min(j + _PANEL_BLOCK, n_panels)
        a, b = edges[j:j_end], edges[j + 1 : j_end + 1]  # (P,) panel ends
        hi_rule = _panel_sums(lam, nc, a, b, *_GL_HI)
        lo_rule = _panel_sums(lam, nc, a, b, *_GL_LO)
        val += float(hi_rule.sum())
        err += float(np.abs(hi_rule - lo_rule).sum())
    if qawf:  # sin(theta) = sin(phi/2) cos(u/2) - cos(phi/2) sin(u/2)

        def slow_sin(u: float) -> float:
            phi, env = _imhof_terms(lam, nc, np.array([u]))
            return math.sin(0.5 * phi[0]) * env[0]

        def slow_cos(u: float) -> float:
            phi, env = _imhof_terms(lam, nc, np.array([u]))
            return math.cos(0.5 * phi[0]) * env[0]

        kw = {"epsabs": 0.1 * _IMHOF_TAIL_ATOL, "limlst": 200, "limit": 200}
        with warnings.catch_warnings():
            warnings.simplefilter("error", integrate.IntegrationWarning)
            try:
                v1, e1 = integrate.quad(slow_sin, end, np.inf, weight="cos", wvar=0.5, **kw)
                v2, e2 = integrate.quad(slow_cos, end, np.inf, weight="sin", wvar=0.5, **kw)
            except integrate.IntegrationWarning:
                return math.nan, math.inf
        val += v1 - v2
        err += e1 + e2
    else:
        err += _IMHOF_TAIL_ATOL
    p = 0.5 - val / math.pi
    return float(min(max(p, 0.0), 1.0)), err / math.pi


def _panel_sums(
    lam: np.ndarray, nc: np.ndarray, a: np.ndarray, b: np.ndarray, t: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """Gauss-Legendre (nodes ``t``, weights ``w`` on [-1, 1]) integrals of Imhof's integrand
    ``sin((phi(u) - u) / 2) / (u rho(u))`` over the panels ``[a_i, b_i]``; (P,)."""
    half = 0.5 * (b - a)  # (P,)
    u = half[:, None] * t[None, :] + (0.5 * (a + b))[:, None]  # (P, q)
    phi, env = _imhof_terms(lam, nc, u.ravel())
    f = (np.sin(0.5 * (phi - u.ravel())) * env).reshape(u.shape)  # (P, q)
    return (f @ w) * half


def mc_ball_probability(
    center: torch.Tensor,
    radius: torch.Tensor | float,
    mean: torch.Tensor,
    cov: torch.Tensor,
    *,
    n: int,
    seed: int,
    chunk: int = 1_000_000,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Monte Carlo estimate of ``P(||X - c|| <= radius)`` with its standard error (float64).

    Samples are drawn in blocks of at most ``chunk`` per case and :data:`MC_BLOCK` points in
    all, so memory stays bounded however many cases there are (the block size does not change
    the numbers drawn).

    Args:
        center: (..., 3) ball centre [m].
        radius: (...) ball radius [m], > 0, or a float.
        mean: (..., 3) Gaussian mean [m].
        cov: (..., 3, 3) Gaussian covariance [m^2], symmetric positive (semi)definite.
        n: samples per case.
        seed: random seed, an integer in [0, 2^32 - 1] (same seed, same numbers).
        chunk: the most samples drawn at once per case.

    Returns:
        ``(p (...), stderr (...))`` float64 CPU tensors, ``stderr = sqrt(p (1 - p) / n)``.

    Raises:
        ShapeError: as :func:`exact_ball_probability`.
        DataError: as :func:`exact_ball_probability`.
        ConfigError: when ``n`` or ``chunk`` is not a positive int, or ``seed`` is not an
            integer in [0, 2^32 - 1].
    """
    integer("n", n, minimum=1)
    integer("chunk", chunk, minimum=1)
    check_seed(seed)
    s, d2, x, batch = _canonical(center, radius, mean, cov)
    rng = np.random.default_rng(seed)
    d = np.sqrt(d2)  # signs do not matter: the ball is symmetric in each eigen-direction
    N = s.shape[0]
    hits = np.zeros(N)
    step = min(chunk, max(1, MC_BLOCK // max(N, 1)))
    done = 0
    while done < n:
        m = min(step, n - done)
        z = rng.standard_normal((m, N, 3))
        y = d[None] + np.sqrt(s)[None] * z  # (m, N, 3) eigen-coordinates of X - c
        with np.errstate(over="ignore"):  # an overflowed square is outside
            hits += ((y * y).sum(-1) <= x[None]).sum(0)
        done += m
    p = hits / n
    se = np.sqrt(p * (1.0 - p) / n)
    return torch.from_numpy(p).view(batch), torch.from_numpy(se).view(batch)


def exact_ball_probability(
    center: torch.Tensor,
    radius: torch.Tensor | float,
    mean: torch.Tensor,
    cov: torch.Tensor,
    *,
    method: Literal["imhof", "ruben", "mc"] = "imhof",
    max_terms: int = 400,
    n_mc: int = 1_000_000,
    seed: int = 0,
) -> torch.Tensor:
    """``P(||X - c|| <= radius)`` for ``X ~ N(mean, cov)``, float64 (reference values).

    Args:
        center: (..., 3) ball centre [m].
        radius: (...) ball radius [m], > 0, or a float.
        mean: (..., 3) Gaussian mean [m].
        cov: (..., 3, 3) Gaussian covariance [m^2], symmetric positive semidefinite; zero
            eigenvalues are deterministic directions (a zero ``cov`` gives 1 where the mean
            is inside or on the sphere, else 0).
        method: ``"imhof"`` (one integration per case, absolute accuracy :data:`ATOL`),
            ``"ruben"`` (upper end of the series bracket) or ``"mc"`` (estimate only; see
            :func:`mc_ball_probability` for its error).
        max_terms: Ruben's series terms.
        n_mc: Monte Carlo samples per case.
        seed: Monte Carlo seed.

    Returns:
        (...) float64 CPU tensor of probabilities.

    Raises:
        ShapeError: on wrong trailing dimensions, leading dimensions that do not broadcast,
            or a non-positive radius.
        DataError: on NaN or Inf in any argument, a covariance with a negative eigenvalue, or
            one whose eigenvalues overflow float64.
        ConfigError: on an unknown method, ``max_terms`` / ``n_mc`` not a positive int, or
            ``seed`` not an integer in [0, 2^32 - 1].

    Warns:
        NumericalWarning: where Imhof's integral misses :data:`ATOL` (see the module
            docstring), or where Ruben's bracket is wider than :data:`ATOL` (raise
            ``max_terms``, or use Imhof).
    """
    if method not in ("imhof", "ruben", "mc"):
        raise ConfigError(f"expected method in ('imhof', 'ruben', 'mc'), got {method!r}")
    if method == "mc":
        return mc_ball_probability(center, radius, mean, cov, n=n_mc, seed=seed)[0]
    integer("max_terms", max_terms, minimum=1)
    s, d2, x, batch = _canonical(center, radius, mean, cov)
    if method == "ruben":
        lower, upper = _ruben_bracket(s, d2, x, max_terms)
        width = upper - lower
        if (width > ATOL).any():
            i = int(np.argmax(width))
            warnings.warn(
                f"Ruben's series did not close to {ATOL:g} with max_terms={max_terms} in "
                f"{int((width > ATOL).sum())} of {width.size} cases (widest: flattened index "
                f"{i}, bracket [{lower[i]:.6g}, {upper[i]:.6g}]); the upper ends are "
                "returned: raise max_terms or use method='imhof'",
                NumericalWarning,
                stacklevel=2,
            )
        return torch.from_numpy(upper).view(batch)
    p, groups = _split_deterministic(s, d2, x)
    err = np.zeros(p.shape)
    for idx, s_g, d2_g, x_g in groups:
        for i, s_i, d2_i, x_i in zip(idx, s_g, d2_g, x_g):
            p[i], err[i] = _imhof_cdf(s_i, d2_i, float(x_i))
    _warn_inaccurate(err)
    return torch.from_numpy(p).view(batch)
