"""Reference probabilities that a Gaussian point lies in a ball (validation of the bounds).

With ``Sigma = U diag(s) U^T``, ``d = U^T (mu - c)`` and ``z ~ N(0, I)``,
``||X - c||^2 = sum_k s_k (z_k + d_k / sqrt(s_k))^2`` is a noncentral quadratic form in
normal variables, so ``P(||X - c|| <= R)`` is its CDF at ``R^2``. Three independent routes:

* **Ruben's series** (Ruben 1962; Farebrother 1984, AS 204): a mixture of central chi-square
  CDFs with positive weights when the scale ``beta`` is ``min s_k``. Vectorised over cases in
  numpy float64; its truncation error is bounded rigorously (the weights sum to 1 and the CDFs
  decrease with the degrees of freedom), so :func:`ruben_ball_probability` returns a bracket.
  It needs many terms when ``R^2 / min s`` is large (small sigma) or the covariance is very
  anisotropic: there use Imhof or Monte Carlo.
* **Imhof's integral** (Imhof 1961): ``P(Q > x) = 1/2 + (1/pi) int_0^inf sin(theta(u)) /
  (u rho(u)) du``, one ``scipy.integrate.quad`` per case; absolute accuracy about 1e-8.
* **Monte Carlo** with a standard error, seeded.

Inputs of any dtype are converted to float64 (the reference values are float64 whatever the
dtype of the bounds they check); empty batches give empty results.

Far cases: where the ball lies more than ``FAR_SIGMAS`` standard deviations (of the widest
direction) from the mean, ``P <= Phi(-FAR_SIGMAS)``, which is 0 in float64; Ruben's series
and Imhof's integral return exactly 0 there without evaluating (the series overflows and the
integral loses all accuracy for large noncentralities, returning up to 0.5 at 1e4 standard
deviations). Distances whose squares overflow float64 count as far.
"""

from __future__ import annotations

import math
import numbers
import warnings
from typing import Literal

import numpy as np
import torch
from scipy import integrate, special

from iplanner_torch.checks import integer
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.types import check_shape, non_finite_error

#: Ruben's series stops when the truncation bound is below ``RUBEN_RTOL * p + RUBEN_ATOL``.
RUBEN_RTOL = 1e-12
RUBEN_ATOL = 1e-300
#: Cases farther than this many standard deviations have probability below Phi(-40), about
#: 4e-350: 0 in float64.
FAR_SIGMAS = 40.0


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
    """Flatten to numpy float64: ``s (N, 3)`` eigenvalues, ``d2 (N, 3)``, ``x (N,) = R^2``.

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
    s, U = np.linalg.eigh(0.5 * (S + np.swapaxes(S, -1, -2)))
    # Negative eigenvalues beyond the rounding of the input's dtype: not a covariance.
    eps = torch.finfo(cov.dtype if cov.is_floating_point() else torch.float64).eps
    if s.size and not (s[:, 0] >= -(eps**0.5) * np.abs(s).max(1)).all():
        raise DataError(f"expected cov positive semidefinite, got eigenvalue {s[:, 0].min()}")
    s = np.maximum(s, 1e-300)
    with np.errstate(over="ignore", invalid="ignore"):  # overflowed distances are far cases
        d = np.einsum("nji,nj->ni", U, m - c)
        d2 = d * d
    return s, d2, r * r, tuple(batch)


def ruben_series(
    s: np.ndarray, d2: np.ndarray, x: np.ndarray, *, max_terms: int = 400
) -> tuple[np.ndarray, np.ndarray]:
    """Ruben's series for ``P(sum_k s_k (z_k + d_k/sqrt(s_k))^2 <= x)``, vectorised.

    Args:
        s: (N, 3) positive weights (variances) [m^2].
        d2: (N, 3) squared offsets ``d_k^2`` [m^2].
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
    lower, upper = _ruben_series(s, d2, x, max_terms)
    return torch.from_numpy(lower).view(batch), torch.from_numpy(upper).view(batch)


def imhof_cdf(s: np.ndarray, d2: np.ndarray, x: float) -> float:
    """Imhof's integral for ``P(sum_k s_k (z_k + delta_k)^2 <= x)`` of one case.

    Args:
        s: (3,) positive weights [m^2].
        d2: (3,) squared offsets ``d_k^2`` [m^2] (``delta_k^2 = d_k^2 / s_k``).
        x: threshold [m^2].

    Returns:
        The probability (absolute accuracy about 1e-8); exactly 0 beyond ``FAR_SIGMAS``
        standard deviations.

    Raises:
        ShapeError: when ``s`` and ``d2`` are not 1-D of one length.
        DataError: on NaN or Inf, non-positive ``s`` or ``x``, or negative ``d2``.
    """
    s = np.asarray(s, dtype=np.float64)
    d2 = np.asarray(d2, dtype=np.float64)
    if s.ndim != 1 or d2.shape != s.shape:
        raise ShapeError(f"expected s (n,) and d2 (n,), got {s.shape} and {d2.shape}")
    _check_series_args(s, d2, np.asarray(x, dtype=np.float64))
    if not x > 0:
        raise DataError(f"expected x > 0, got {x}")
    return _imhof_cdf(s, d2, float(x))


def _imhof_cdf(s: np.ndarray, d2: np.ndarray, x: float) -> float:
    """:func:`imhof_cdf` without the argument checks."""
    if _far(np.asarray(s), np.asarray(d2), np.asarray(x)):
        return 0.0  # below Phi(-FAR_SIGMAS); the integral loses all accuracy out there
    lam = np.asarray(s, dtype=np.float64) / x  # scale so the threshold is 1
    nc = np.asarray(d2, dtype=np.float64) / np.asarray(s, dtype=np.float64)

    def integrand(u: float) -> float:
        lu = lam * u
        den = 1.0 + lu * lu
        theta = 0.5 * np.sum(np.arctan(lu) + nc * lu / den) - 0.5 * u
        log_rho = 0.25 * np.sum(np.log(den)) + 0.5 * np.sum(nc * lu * lu / den)
        if u == 0.0:
            return 0.5 * float(np.sum(lam * (1.0 + nc)) - 1.0)
        return math.sin(theta) * math.exp(-log_rho) / u

    with warnings.catch_warnings():
        # quad reports slow convergence of the oscillating tail; the accuracy stated above
        # was checked against the noncentral chi-square CDF and Ruben's series.
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        val, _ = integrate.quad(integrand, 0.0, np.inf, limit=1000, epsabs=1e-11, epsrel=1e-9)
    return float(min(max(0.5 - val / math.pi, 0.0), 1.0))


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

    Args:
        center: (..., 3) ball centre [m].
        radius: (...) ball radius [m], > 0, or a float.
        mean: (..., 3) Gaussian mean [m].
        cov: (..., 3, 3) Gaussian covariance [m^2], symmetric positive (semi)definite.
        n: samples per case.
        seed: random seed (same seed, same numbers).
        chunk: samples drawn at once per case.

    Returns:
        ``(p (...), stderr (...))`` float64 CPU tensors, ``stderr = sqrt(p (1 - p) / n)``.

    Raises:
        ShapeError: as :func:`exact_ball_probability`.
        DataError: as :func:`exact_ball_probability`.
        ConfigError: when ``n`` or ``chunk`` is not a positive int.
    """
    integer("n", n, minimum=1)
    integer("chunk", chunk, minimum=1)
    s, d2, x, batch = _canonical(center, radius, mean, cov)
    rng = np.random.default_rng(seed)
    d = np.sqrt(d2)  # signs do not matter: the ball is symmetric in each eigen-direction
    hits = np.zeros(s.shape[0])
    done = 0
    while done < n:
        m = min(chunk, n - done)
        z = rng.standard_normal((m, s.shape[0], 3))
        y = d[None] + np.sqrt(s)[None] * z  # (m, N, 3) eigen-coordinates of X - c
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
        cov: (..., 3, 3) Gaussian covariance [m^2], symmetric positive (semi)definite.
        method: ``"imhof"`` (quad per case), ``"ruben"`` (upper end of the series bracket)
            or ``"mc"`` (estimate only; see :func:`mc_ball_probability` for its error).
        max_terms: Ruben's series terms.
        n_mc: Monte Carlo samples per case.
        seed: Monte Carlo seed.

    Returns:
        (...) float64 CPU tensor of probabilities.

    Raises:
        ShapeError: on wrong trailing dimensions, leading dimensions that do not broadcast,
            or a non-positive radius.
        DataError: on NaN or Inf in any argument, or a covariance with a negative eigenvalue.
        ConfigError: on an unknown method, or ``max_terms`` / ``n_mc`` not a positive int.
    """
    if method not in ("imhof", "ruben", "mc"):
        raise ConfigError(f"expected method in ('imhof', 'ruben', 'mc'), got {method!r}")
    if method == "ruben":
        return ruben_ball_probability(center, radius, mean, cov, max_terms=max_terms)[1]
    if method == "mc":
        return mc_ball_probability(center, radius, mean, cov, n=n_mc, seed=seed)[0]
    s, d2, x, batch = _canonical(center, radius, mean, cov)
    out = np.array([_imhof_cdf(s[i], d2[i], x[i]) for i in range(s.shape[0])])
    return torch.from_numpy(out).view(batch)
