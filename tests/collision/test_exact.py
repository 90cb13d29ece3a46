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
from iplanner_torch.errors import ConfigError, DataError, NumericalWarning, ShapeError

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


def _isotropic_grid(ratios: np.ndarray, fractions: np.ndarray):
    """Isotropic cases (sigma = 1 cm) over R / sigma x offset / R, with the ncx2 reference."""
    sigma = 0.01
    R, frac = (a.ravel() for a in np.meshgrid(ratios * sigma, fractions, indexing="ij"))
    dist = R * frac
    n = R.size
    mu = torch.zeros(n, 3, dtype=F64)
    mu[:, 0] = torch.from_numpy(dist)
    cov = torch.eye(3, dtype=F64).expand(n, 3, 3) * sigma**2
    x, nc = (R / sigma) ** 2, (dist / sigma) ** 2
    ref = np.where(nc > 0, stats.ncx2.cdf(x, 3, np.maximum(nc, 1e-300)), stats.chi2.cdf(x, 3))
    return torch.zeros(n, 3, dtype=F64), torch.from_numpy(R), mu, cov, ref


def test_imhof_meets_its_accuracy_for_small_sigma() -> None:
    """R / sigma up to 50, offsets inside and outside: Imhof's integral was off by 1.1e-4 at
    R / sigma = 20 with the mean at the centre (plain quad over [0, inf) gave up unnoticed)."""
    ratios = np.array([0.1, 0.5, 2.0, 8.0, 20.0, 21.0, 22.0, 50.0])
    c, R, mu, cov, ref = _isotropic_grid(ratios, np.array([0.0, 0.5, 0.95, 1.05, 1.5]))
    got = exact_ball_probability(c, R, mu, cov)
    assert np.abs(got.numpy() - ref).max() <= 1e-10
    # the audit's case: sigma = 1 cm, R = 0.2 m, the mean at the centre
    z = torch.zeros(1, 3, dtype=F64)
    p = exact_ball_probability(z, 0.2, z, torch.eye(3, dtype=F64)[None] * 1e-4)
    assert abs(p.item() - stats.chi2.cdf(400.0, 3)) <= 1e-12


@pytest.mark.slow
def test_imhof_and_ruben_match_noncentral_chi_square_on_a_grid() -> None:
    """60 x 9 isotropic cases, R / sigma from 0.1 to 50 (worst error about 3e-14)."""
    ratios = np.concatenate([np.geomspace(0.1, 50.0, 60), [20.0, 21.0, 22.0]])
    fractions = np.array([0.0, 0.3, 0.7, 0.95, 1.0, 1.05, 1.3, 2.0, 4.0])
    c, R, mu, cov, ref = _isotropic_grid(ratios, fractions)
    imhof = exact_ball_probability(c, R, mu, cov)
    assert np.abs(imhof.numpy() - ref).max() <= 1e-12
    lower, upper = ruben_ball_probability(c, R, mu, cov, max_terms=3000)
    assert (upper - lower).max() <= 1e-12
    assert np.abs(upper.numpy() - ref).max() <= 1e-12


def test_imhof_small_sigma_anisotropic_matches_ruben_and_mc() -> None:
    """Anisotropic, small sigma, the mean inside: P near 1, where Monte Carlo is sharp."""
    gen = torch.Generator().manual_seed(11)
    n = 4
    q, _ = torch.linalg.qr(torch.randn(n, 3, 3, generator=gen, dtype=F64))
    sig = torch.tensor([[0.01, 0.02, 0.05], [0.008, 0.01, 0.012], [0.01, 0.03, 0.1], [0.02] * 3])
    cov = q @ torch.diag_embed(sig.double() ** 2) @ q.transpose(-1, -2)
    mu = torch.tensor([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.02, 0.0], [0.1, 0.1, 0.0]])
    c, mu = torch.zeros(n, 3, dtype=F64), mu.double()
    imhof = exact_ball_probability(c, 0.2, mu, cov)
    lower, upper = ruben_ball_probability(c, 0.2, mu, cov, max_terms=2000)
    assert torch.all(upper - lower <= 1e-12)
    assert torch.all((imhof - upper).abs() <= 1e-10), (imhof - upper).abs().max()
    p, se = mc_ball_probability(c, 0.2, mu, cov, n=200_000, seed=12)
    assert torch.all((p - imhof).abs() <= 5 * se + 1e-5)


def test_zero_covariance_is_the_indicator() -> None:
    """cov = 0: the point is the mean; Imhof gave 0.73 inside, Ruben NaN."""
    c = torch.zeros(4, 3, dtype=F64)
    mu = torch.tensor(
        [[0.1, 0.05, 0.0], [0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.25, 0.0]], dtype=F64
    )
    cov = torch.zeros(4, 3, 3, dtype=F64)
    for method in ("imhof", "ruben", "mc"):
        p = exact_ball_probability(c, 0.2, mu, cov, method=method, n_mc=100)
        assert p.tolist() == [1.0, 1.0, 1.0, 0.0], method  # inside, centre, on, outside
    lower, upper = ruben_ball_probability(c, 0.2, mu, cov)
    assert torch.equal(lower, upper) and upper.tolist() == [1.0, 1.0, 1.0, 0.0]


@pytest.mark.parametrize("method", ["imhof", "ruben"])
def test_rank_deficient_covariance_reduces_to_the_random_directions(method: str) -> None:
    """No variance along z: the z offset comes off R^2, the rest is a 2-D (or 1-D)
    noncentral chi-square (Ruben's series had a scale of 1e-300 and returned 1)."""
    s = 0.05**2
    mu = torch.tensor([[0.03, 0.04, 0.1], [0.0, 0.1, 0.12], [0.2, 0.0, 0.15]], dtype=F64)
    R2 = 0.2**2
    cov2 = torch.diag(torch.tensor([s, s, 0.0], dtype=F64)).expand(3, 3, 3)
    p2 = exact_ball_probability(torch.zeros(3, 3, dtype=F64), 0.2, mu, cov2, method=method)
    ref2 = stats.ncx2.cdf((R2 - mu[:, 2] ** 2) / s, 2, (mu[:, 0] ** 2 + mu[:, 1] ** 2) / s)
    np.testing.assert_allclose(p2.numpy(), ref2, rtol=0, atol=1e-10)
    cov1 = torch.diag(torch.tensor([s, 0.0, 0.0], dtype=F64)).expand(3, 3, 3)
    p1 = exact_ball_probability(torch.zeros(3, 3, dtype=F64), 0.2, mu, cov1, method=method)
    rest = np.sqrt(R2 - mu[:, 1] ** 2 - mu[:, 2] ** 2).numpy()
    x0 = mu[:, 0].numpy()
    ref1 = stats.norm.cdf((rest - x0) / 0.05) - stats.norm.cdf((-rest - x0) / 0.05)
    np.testing.assert_allclose(p1.numpy(), ref1, rtol=0, atol=1e-10)


def test_huge_covariances() -> None:
    """Entries near the float64 limit: eigenvalues that overflow are refused by name (a raw
    LinAlgError, or 'eigenvalue nan' blaming positive semidefiniteness, before); a huge but
    representable covariance gives P about 0 (Imhof gave 0.5)."""
    z = torch.zeros(3, dtype=F64)
    for cov in (torch.full((3, 3), 1.7e308, dtype=F64), torch.full((3, 3), 1e308, dtype=F64)):
        with pytest.raises(DataError, match="eigenvalues overflow"):
            exact_ball_probability(z, 0.2, z, cov)
    diag = torch.eye(3, dtype=F64) * 1.7e308
    f32 = torch.full((3, 3), 3e38)  # rank one, eigenvalue 9e38
    for cov in (diag, f32):
        for method in ("imhof", "ruben", "mc"):
            p = exact_ball_probability(z.to(cov.dtype), 0.2, z.to(cov.dtype), cov, method=method)
            assert 0.0 <= p.item() <= 1e-8, method


@pytest.mark.parametrize("seed", [-1, 1.5, "a", True, 2**32])
def test_mc_seed_is_checked(seed: object) -> None:
    c, R, mu, cov, _ = _isotropic(2, 13)
    with pytest.raises(ConfigError, match="expected seed an integer"):
        mc_ball_probability(c, R, mu, cov, n=10, seed=seed)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected seed an integer"):
        exact_ball_probability(c, R, mu, cov, method="mc", n_mc=10, seed=seed)  # type: ignore[arg-type]


def test_mc_memory_is_bounded_by_cases_times_chunk() -> None:
    """2000 cases x 2000 samples used to be drawn at once (96 MB for the normals alone; 200
    cases with the default n_mc needed 4.5 GiB); blocks keep below MC_BLOCK points."""
    import tracemalloc

    c, R, mu, cov, _ = _isotropic(2000, 14)
    a = mc_ball_probability(c[:3], R[:3], mu[:3], cov[:3], n=2000, seed=1)
    tracemalloc.start()
    try:
        p, _ = mc_ball_probability(c, R, mu, cov, n=2000, seed=1)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 40e6, peak
    assert torch.all((p >= 0) & (p <= 1))
    assert torch.equal(a[0], mc_ball_probability(c[:3], R[:3], mu[:3], cov[:3], n=2000, seed=1)[0])


def test_ruben_warns_when_its_bracket_is_open() -> None:
    """A large noncentrality needs more terms than max_terms: the upper end of the open
    bracket was returned silently (1 where the truth is 3e-28)."""
    c, R, mu, cov, ref = _isotropic_grid(np.array([36.0]), np.array([1.3]))
    with pytest.warns(NumericalWarning, match="Ruben's series did not close"):
        p = exact_ball_probability(c, R, mu, cov, method="ruben")
    assert p.item() == 1.0 and ref[0] < 1e-20
    got = exact_ball_probability(c, R, mu, cov, method="ruben", max_terms=3000)
    assert abs(got.item() - ref[0]) <= 1e-12


def test_imhof_warns_where_it_cannot_meet_its_accuracy() -> None:
    """A variance 1e-13 of the largest with the mean off-centre along it would need about
    1e12 panels: NaN and a warning, not a wrong number."""
    cov = torch.diag(torch.tensor([1.0, 1.0, 1e-13], dtype=F64))
    mu = torch.tensor([0.2, 0.1, 0.5], dtype=F64)
    with pytest.warns(NumericalWarning, match="missed its absolute accuracy"):
        p = exact_ball_probability(torch.zeros(3, dtype=F64), 1.0, mu, cov)
    assert math.isnan(p.item())
    with pytest.warns(NumericalWarning, match="missed its absolute accuracy"):
        imhof_cdf(np.array([1.0, 1.0, 1e-13]), np.array([0.04, 0.01, 0.25]), 1.0)
