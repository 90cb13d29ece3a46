"""Reference ball probabilities agree with each other and with the noncentral chi-square."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

from iplanner_torch.collision.exact import (
    exact_ball_probability,
    imhof_cdf,
    mc_ball_probability,
    ruben_ball_probability,
    ruben_series,
)
from iplanner_torch.errors import ConfigError, DataError, ShapeError

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
    with pytest.raises(ConfigError, match="expected n an integer >= 1"):
        mc_ball_probability(c, R, mu, cov, n=0, seed=0)


@pytest.mark.parametrize("method", ["imhof", "ruben", "mc"])
@pytest.mark.parametrize("name", ["center", "radius", "mean", "cov"])
def test_non_finite_input_raises_data_error(name: str, method: str) -> None:
    c, R, mu, cov, _ = _isotropic(2, 7)
    args = {"center": c, "radius": R, "mean": mu, "cov": cov}
    args[name] = args[name].clone()
    args[name][1] = math.nan
    with pytest.raises(DataError, match=f"expected finite {name}, got"):
        exact_ball_probability(**args, method=method, n_mc=100)


def test_bad_shapes_and_ranges() -> None:
    c, R, mu, cov, _ = _isotropic(4, 8)
    with pytest.raises(ShapeError, match=r"center \(4, 3\).*mean \(5, 3\)"):
        ruben_ball_probability(c, R, torch.zeros(5, 3, dtype=F64), cov)
    with pytest.raises(ShapeError, match="expected radius > 0"):
        exact_ball_probability(c, -R, mu, cov, method="ruben")
    with pytest.raises(ShapeError, match="expected radius > 0"):
        exact_ball_probability(c, 0.0 * R, mu, cov)  # Imhof returned NaN at radius 0
    with pytest.raises(DataError, match="expected cov positive semidefinite"):
        exact_ball_probability(c, R, mu, -cov, method="ruben")
    # a float radius is accepted and equals the tensor one
    one = exact_ball_probability(c[0], 0.2, mu[0], cov[0], method="ruben")
    assert one == exact_ball_probability(
        c[0], torch.tensor(0.2, dtype=F64), mu[0], cov[0], method="ruben"
    )


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"max_terms": 0}, "expected max_terms an integer >= 1"),
        ({"n": 1.5}, "expected n an integer >= 1"),
        ({"chunk": -1}, "expected chunk an integer >= 1"),
        ({"chunk": 0}, "expected chunk an integer >= 1"),  # used to loop forever
    ],
)
def test_non_positive_counts_raise_config_error(kwargs: dict, pattern: str) -> None:
    c, R, mu, cov, _ = _isotropic(2, 9)
    if "max_terms" in kwargs:
        with pytest.raises(ConfigError, match=pattern):
            ruben_ball_probability(c, R, mu, cov, **kwargs)
        with pytest.raises(ConfigError, match=pattern):
            ruben_series(np.ones((2, 3)), np.ones((2, 3)), np.ones(2), **kwargs)
    else:
        with pytest.raises(ConfigError, match=pattern):
            mc_ball_probability(c, R, mu, cov, **{"n": 100, "seed": 0, **kwargs})


def test_series_and_imhof_arguments_are_checked() -> None:
    s, d2, x = np.full((2, 3), 0.01), np.full((2, 3), 0.04), np.full(2, 0.09)
    with pytest.raises(ShapeError, match=r"expected s \(N, n\), d2 \(N, n\), x \(N,\)"):
        ruben_series(s, d2[:1], x)
    with pytest.raises(DataError, match="expected s > 0"):
        ruben_series(0.0 * s, d2, x)
    with pytest.raises(DataError, match="expected finite d2"):
        ruben_series(s, np.full((2, 3), np.nan), x)
    with pytest.raises(DataError, match="expected x > 0"):
        imhof_cdf(s[0], d2[0], 0.0)
    with pytest.raises(ShapeError, match=r"expected s \(n,\) and d2 \(n,\)"):
        imhof_cdf(s, d2, 0.09)
    assert imhof_cdf(s[0], d2[0], 0.09) == pytest.approx(float(ruben_series(s, d2, x)[1][0]))


@pytest.mark.parametrize("far", [1e3, 1e4, 1e20, 1e100, 1e155, 1e300])
def test_far_cases_are_zero(far: float) -> None:
    """Beyond FAR_SIGMAS standard deviations the probability is 0 in float64: Imhof's
    integral returned up to 0.5 from about 1e4 standard deviations and failed with a
    ValueError (math domain error) beyond 1e154 m; Ruben's series returned NaN beyond about
    1e100 standard deviations."""
    c = torch.zeros(2, 3, dtype=F64)
    mu = torch.tensor([[0.3, 0.0, 0.0], [far, 0.0, 0.0]], dtype=F64)
    cov = torch.eye(3, dtype=F64) * 0.01
    near = exact_ball_probability(c[:1], 0.1, mu[:1], cov, method="ruben")
    for method in ("imhof", "ruben", "mc"):
        p = exact_ball_probability(c, 0.1, mu, cov, method=method, n_mc=1000)
        assert p[1] == 0.0, method
    lower, upper = ruben_ball_probability(c, 0.1, mu, cov)
    assert lower[1] == 0.0 and upper[1] == 0.0
    assert upper[0] == near[0]  # the near case keeps its value
    d2 = np.array([min(far, 1e100) ** 2, 0.0, 0.0])  # finite: imhof_cdf checks it
    assert imhof_cdf(np.full(3, 0.01), d2, 0.01) == 0.0
    assert ruben_series(np.full((1, 3), 0.01), d2[None], np.full(1, 0.01))[1][0] == 0.0


def test_far_float32_input_is_zero_and_empty_batches_are_empty() -> None:
    """A float32 mean 1e20 m away (converted to float64) gave 0.5 by Imhof's integral."""
    p = exact_ball_probability(
        torch.zeros(1, 3), 0.1, torch.tensor([[1e20, 0.0, 0.0]]), torch.eye(3) * 0.01
    )
    assert p.dtype == F64 and p.item() == 0.0
    empty = torch.zeros(0, 3, dtype=F64)
    for method in ("imhof", "ruben", "mc"):
        got = exact_ball_probability(empty, 0.1, empty, torch.eye(3, dtype=F64), method=method)
        assert got.shape == (0,)
