"""Reference ball probabilities agree with each other and with the noncentral chi-square."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import stats

from iplanner_torch.collision.exact import (
    exact_ball_probability,
    mc_ball_probability,
    ruben_ball_probability,
)
from iplanner_torch.errors import ConfigError

F64 = torch.float64


def _isotropic(n: int, seed: int):
    rng = np.random.default_rng(seed)
    sigma = rng.uniform(0.03, 0.3, n)
    R = rng.uniform(0.05, 0.3, n)
    dist = rng.uniform(0.0, 1.0, n)
    c = np.zeros((n, 3))
    mu = np.stack([dist, np.zeros(n), np.zeros(n)], 1)
    cov = np.eye(3) * sigma[:, None, None] ** 2
    ref = stats.ncx2.cdf((R / sigma) ** 2, 3, (dist / sigma) ** 2)
    t = torch.from_numpy
    return t(c), t(R), t(mu), t(cov), ref


def test_ruben_matches_noncentral_chi_square() -> None:
    c, R, mu, cov, ref = _isotropic(500, 0)
    lower, upper = ruben_ball_probability(c, R, mu, cov, max_terms=300)
    keep = ref > 1e-280
    np.testing.assert_allclose(upper.numpy()[keep], ref[keep], rtol=1e-8)
    assert torch.all(lower <= upper)


def test_imhof_matches_noncentral_chi_square() -> None:
    c, R, mu, cov, ref = _isotropic(8, 1)
    got = exact_ball_probability(c, R, mu, cov, method="imhof")
    np.testing.assert_allclose(got.numpy(), ref, rtol=1e-5, atol=1e-8)


def test_anisotropic_ruben_imhof_and_mc_agree() -> None:
    gen = torch.Generator().manual_seed(2)
    n = 6
    c = torch.zeros(n, 3, dtype=F64)
    mu = torch.rand(n, 3, generator=gen, dtype=F64) * 0.3
    A = torch.randn(n, 3, 3, generator=gen, dtype=F64) * 0.1
    cov = A @ A.transpose(-1, -2) + 0.005 * torch.eye(3, dtype=F64)
    R = torch.full((n,), 0.15, dtype=F64)
    ruben = exact_ball_probability(c, R, mu, cov, method="ruben", max_terms=600)
    imhof = exact_ball_probability(c, R, mu, cov, method="imhof")
    p, se = mc_ball_probability(c, R, mu, cov, n=400_000, seed=3)
    np.testing.assert_allclose(imhof.numpy(), ruben.numpy(), rtol=1e-5, atol=1e-8)
    assert torch.all((p - ruben).abs() <= 5 * se + 1e-12)


def test_mc_is_seeded() -> None:
    c, R, mu, cov, _ = _isotropic(3, 4)
    a = mc_ball_probability(c, R, mu, cov, n=1000, seed=5)
    b = mc_ball_probability(c, R, mu, cov, n=1000, seed=5)
    assert torch.equal(a[0], b[0])


def test_errors() -> None:
    c, R, mu, cov, _ = _isotropic(2, 6)
    with pytest.raises(ConfigError, match="expected method"):
        exact_ball_probability(c, R, mu, cov, method="quad")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected n > 0"):
        mc_ball_probability(c, R, mu, cov, n=0, seed=0)
