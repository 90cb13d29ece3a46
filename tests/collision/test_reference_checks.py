"""The ball probabilities and bounds against references computed here by other methods.

* Exact probability: direct cubature of the Gaussian density over the ball in spherical
  coordinates (Gauss-Legendre in radius and polar cosine, the periodic trapezoid rule in
  azimuth), in numpy; independent of Ruben's series, Imhof's integral and Monte Carlo.
* ``x_max``: scipy's SLSQP minimising the Mahalanobis distance over the ball; the bounds built
  from its point with scipy's normal CDF and multivariate normal density.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import optimize, stats

from iplanner_torch.collision import gaussian as G
from iplanner_torch.collision.exact import exact_ball_probability, ruben_ball_probability

F64 = torch.float64


def _random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    return q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]


def _cases(rng: np.random.Generator, n: int, *, sig_over_r: tuple[float, float]):
    """Random anisotropic ball / Gaussian pairs (numpy float64): c, R, mu, cov; the mean
    inside the ball in about a quarter of them, else up to 3 widest standard deviations out."""
    R = rng.uniform(0.05, 0.3, n)
    sig = R[:, None] * rng.uniform(*sig_over_r, (n, 3))  # (n, 3) standard deviations
    U = _random_rotations(rng, n)
    cov = np.einsum("nij,nj,nkj->nik", U, sig**2, U)
    inside = rng.random(n) < 0.25
    dist = np.where(inside, R * rng.uniform(0.0, 0.95, n), R + sig.max(1) * rng.uniform(0, 3, n))
    direction = rng.standard_normal((n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    c = rng.uniform(-1.0, 1.0, (n, 3))
    return c, R, c + direction * dist[:, None], cov


def ball_probability_cubature(
    c: np.ndarray, R: float, mu: np.ndarray, cov: np.ndarray, n_r: int = 48, n_p: int = 64
) -> float:
    """``P(||X - c|| <= R)`` for ``X ~ N(mu, cov)`` by a product rule over the ball."""
    x_r, w_r = np.polynomial.legendre.leggauss(n_r)
    r, w_r = 0.5 * R * (x_r + 1.0), 0.5 * R * w_r  # radius nodes on [0, R]
    ct, w_t = np.polynomial.legendre.leggauss(n_r)  # cos(theta) on [-1, 1]
    phi = 2.0 * math.pi * np.arange(n_p) / n_p
    st = np.sqrt(1.0 - ct**2)
    u = np.stack(
        [
            st[:, None] * np.cos(phi),
            st[:, None] * np.sin(phi),
            np.broadcast_to(ct[:, None], (n_r, n_p)),
        ],
        -1,
    )  # (n_t, n_p, 3) unit directions
    pts = c + r[:, None, None, None] * u[None]  # (n_r, n_t, n_p, 3)
    chol = np.linalg.cholesky(cov)
    z = np.linalg.solve(chol, (pts - mu).reshape(-1, 3).T)  # (3, n) whitened offsets
    norm = (2.0 * math.pi) ** 1.5 * np.prod(np.diag(chol))
    dens = (np.exp(-0.5 * (z * z).sum(0)) / norm).reshape(n_r, n_r, n_p)
    w = (w_r * r**2)[:, None, None] * w_t[None, :, None] * (2.0 * math.pi / n_p)
    return float((w * dens).sum())


def test_cubature_reproduces_the_noncentral_chi_square() -> None:
    """The reference itself, on isotropic cases where scipy's ncx2 is exact: good to 1e-11
    (the tolerance the comparisons below rely on, with margin)."""
    rng = np.random.default_rng(0)
    for _ in range(6):
        sigma, R = rng.uniform(0.05, 0.3), rng.uniform(0.05, 0.3)
        dist = rng.uniform(0.0, R + 3 * sigma)
        mu = np.array([dist, 0.0, 0.0])
        got = ball_probability_cubature(np.zeros(3), R, mu, sigma**2 * np.eye(3))
        want = stats.ncx2.cdf((R / sigma) ** 2, 3, (dist / sigma) ** 2)
        assert abs(got - want) <= 1e-11, (got, want)


def test_ruben_and_imhof_equal_cubature_for_anisotropic_covariances() -> None:
    """Full, anisotropic covariances (axis ratios up to 6) with sigma between 0.3 and 2 radii:
    the regime where the cubature is accurate to about 1e-12. Ruben's bracket must contain
    the cubature value (width 1e-12 allowed for the cubature's own error); Imhof's integral
    meets its stated accuracy ATOL = 1e-8."""
    rng = np.random.default_rng(1)
    c, R, mu, cov = _cases(rng, 12, sig_over_r=(0.3, 2.0))
    t = torch.from_numpy
    lower, upper = ruben_ball_probability(t(c), t(R), t(mu), t(cov), max_terms=600)
    imhof = exact_ball_probability(t(c), t(R), t(mu), t(cov), method="imhof").numpy()
    ref = np.array([ball_probability_cubature(c[i], R[i], mu[i], cov[i]) for i in range(12)])
    assert (ref > 1e-3).sum() >= 6 and ref.max() > 0.1  # not all in the far tail
    assert np.all(lower.numpy() <= ref + 1e-12) and np.all(ref <= upper.numpy() + 1e-12)
    np.testing.assert_allclose(imhof, ref, rtol=0, atol=1e-8)


@pytest.mark.parametrize("method", ["min", "volume", "halfspace"])
def test_bounds_are_never_below_the_cubature(method: str) -> None:
    """The bound (float64, Newton) is an upper bound on the exact probability; 1e-12 allows
    for the cubature's error only."""
    rng = np.random.default_rng(2)
    c, R, mu, cov = _cases(rng, 12, sig_over_r=(0.3, 2.0))
    ref = np.array([ball_probability_cubature(c[i], R[i], mu[i], cov[i]) for i in range(12)])
    t = torch.from_numpy
    bound = G.sphere_collision_bound(
        t(c), t(0.5 * R), t(mu), t(cov), t(0.5 * R), method=method
    ).numpy()
    assert np.all(bound >= ref - 1e-12), (bound - ref).min()


def _scipy_x_max(c: np.ndarray, R: float, mu: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The point of the ball ``||x - c|| <= R`` nearest to ``mu`` in Mahalanobis distance, by
    SLSQP in the ball's unit coordinates ``y = (x - c) / R``, the objective scaled to 1 at
    the start (the ball's point nearest to ``mu`` in Euclidean distance)."""
    prec = np.linalg.inv(cov)
    d = mu - c
    y0 = 0.999 * d / np.linalg.norm(d)
    scale = float((c + R * y0 - mu) @ prec @ (c + R * y0 - mu))
    res = optimize.minimize(
        lambda y: float((c + R * y - mu) @ prec @ (c + R * y - mu)) / scale,
        y0,
        jac=lambda y: 2.0 * R * prec @ (c + R * y - mu) / scale,
        constraints=[{"type": "ineq", "fun": lambda y: 1.0 - y @ y, "jac": lambda y: -2.0 * y}],
        method="SLSQP",
        options={"ftol": 1e-12, "maxiter": 1000},
    )
    return c + R * res.x


def test_x_max_and_both_bounds_equal_a_constrained_optimiser() -> None:
    """40 random anisotropic cases with the mean outside the ball (axis ratios up to 10).

    ``max_density_point`` equals SLSQP's minimiser to 1e-6 R (SLSQP stops near 1e-12 in the
    scaled objective, which leaves the point off along the sphere by about its square root)
    and is no worse than it; the halfspace and volume bounds equal ``Phi(-m)`` and
    ``(4/3) pi R^3 f(x_max)`` at SLSQP's point to rtol 1e-6 (the Mahalanobis distance is
    stationary along the sphere there, so the point's error enters to second order).
    """
    rng = np.random.default_rng(3)
    n = 40
    c, R, mu, cov = _cases(rng, 4 * n, sig_over_r=(0.1, 1.0))
    outside = np.linalg.norm(mu - c, axis=1) > R * 1.01
    c, R, mu, cov = c[outside][:n], R[outside][:n], mu[outside][:n], cov[outside][:n]
    assert len(R) == n
    t = torch.from_numpy
    x, lam = G.max_density_point(t(c), t(R), t(mu), t(cov))
    half = G.sphere_collision_bound(t(c), t(R / 2), t(mu), t(cov), t(R / 2), method="halfspace")
    vol = G.sphere_collision_bound(t(c), t(R / 2), t(mu), t(cov), t(R / 2), method="volume")
    assert bool((lam > 0).all())
    for i in range(n):
        ref = _scipy_x_max(c[i], R[i], mu[i], cov[i])
        ours = x[i].numpy()
        assert np.linalg.norm(ours - ref) <= 1e-6 * R[i], i
        # x_max lies in the ball and is no worse than the optimiser's point moved onto the
        # sphere (SLSQP meets the constraint only to about its ftol, outside or inside)
        prec = np.linalg.inv(cov[i])
        on_sphere = c[i] + R[i] * (ref - c[i]) / np.linalg.norm(ref - c[i])
        assert np.linalg.norm(ours - c[i]) <= R[i] * (1 + 1e-12)
        assert (ours - mu[i]) @ prec @ (ours - mu[i]) <= (
            (on_sphere - mu[i]) @ prec @ (on_sphere - mu[i])
        ) * (1 + 1e-12), i
        m = math.sqrt(float((ref - mu[i]) @ prec @ (ref - mu[i])))
        assert float(half[i]) == pytest.approx(stats.norm.sf(m), rel=1e-6)
        f = stats.multivariate_normal(mean=mu[i], cov=cov[i]).pdf(ref)
        want = min(4.0 / 3.0 * math.pi * R[i] ** 3 * f, 1.0)
        assert float(vol[i]) == pytest.approx(want, rel=1e-6)


def test_diagonal_bound_equals_the_full_bound_of_a_rotated_problem() -> None:
    """``sphere_collision_bound_diag`` (no eigendecomposition) against the full-covariance
    bound of the same problem rotated by a random rotation Q (the probability and both bounds
    are invariant: centre, mean and covariance all rotate). Tolerance: eigendecomposition
    rounding in float64."""
    rng = np.random.default_rng(4)
    n = 200
    c = rng.uniform(-0.5, 0.5, (n, 3))
    mu = c + rng.normal(size=(n, 3)) * 0.3
    var = (rng.uniform(0.02, 0.2, (n, 3))) ** 2
    R = rng.uniform(0.05, 0.3, n)
    Q = _random_rotations(rng, n)
    t = torch.from_numpy
    rot = lambda p: np.einsum("nij,nj->ni", Q, p)  # noqa: E731
    cov = np.einsum("nij,nj,nkj->nik", Q, var, Q)
    for method in ("min", "volume", "halfspace"):
        diag = G.sphere_collision_bound_diag(
            t(c), t(R / 2), t(mu), t(var), t(R / 2), method=method
        )
        full = G.sphere_collision_bound(
            t(rot(c)), t(R / 2), t(rot(mu)), t(cov), t(R / 2), method=method
        )
        torch.testing.assert_close(diag, full, rtol=1e-8, atol=1e-300)
