"""The probabilistic collision bound: never below the exact probability, solver agreement,
gradients, and the mixture / maximum over sphere pairs."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch
from scipy import special

from iplanner_torch.collision import gaussian as G
from iplanner_torch.collision.exact import ruben_series
from iplanner_torch.errors import ConfigError, DataError, ShapeError

F64 = torch.float64


def _random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    return q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]


def _cases(rng: np.random.Generator, n: int, *, sig_over_r, var_ratio, far_sigmas=8.0):
    """Random ball / Gaussian pairs: returns c, R, mu, cov (numpy float64) and s, d2."""
    R = rng.uniform(0.05, 0.4, n)
    sig_min = R * np.exp(rng.uniform(*np.log(sig_over_r), n))
    ratios = np.exp(rng.uniform(0.0, 0.5 * math.log(var_ratio), (n, 3)))
    ratios[np.arange(n), rng.integers(0, 3, n)] = 1.0
    s = (sig_min[:, None] * ratios) ** 2  # (n, 3) eigenvalues
    U = _random_rotations(rng, n)
    cov = np.einsum("nij,nj,nkj->nik", U, s, U)
    inside = rng.random(n) < 0.25
    dist = np.where(
        inside,
        R * rng.uniform(0.0, 0.999, n),
        R + np.sqrt(s.max(1)) * rng.uniform(0.0, far_sigmas, n),
    )
    direction = rng.standard_normal((n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    c = rng.uniform(-1.0, 1.0, (n, 3))
    mu = c + direction * dist[:, None]
    d = np.einsum("nji,nj->ni", U, mu - c)
    return c, R, mu, cov, s, d * d


def _bounds(c, R, mu, cov, method: str) -> np.ndarray:
    t = lambda a: torch.from_numpy(a)  # noqa: E731
    r1 = t(0.6 * R)
    return G.sphere_collision_bound(t(c), r1, t(mu), t(cov), t(R) - r1, method=method).numpy()


@pytest.mark.parametrize("method", ["min", "volume", "halfspace"])
def test_bound_never_below_exact_10000_cases(method: str) -> None:
    rng = np.random.default_rng(1)
    c, R, mu, cov, s, d2 = _cases(rng, 10_000, sig_over_r=(0.25, 4.0), var_ratio=4.0)
    lower, upper = ruben_series(s, d2, R * R, max_terms=120)
    # The series bracket is tight here (rigorous truncation bound): the reference is exact.
    assert np.all(upper - lower <= 1e-10 * upper + 1e-300)
    bound = _bounds(c, R, mu, cov, method)
    assert np.all(bound >= upper * (1.0 - 1e-9)), (bound / upper).min()
    assert np.all(bound <= 1.0) and np.all(bound >= 0.0)
    if method == "min":
        exact = upper[upper >= 1e-6]
        assert np.median(bound[upper >= 1e-6] / exact) < 3.0


def test_bound_never_below_exact_small_sigma_anisotropic() -> None:
    """Small sigma and strong anisotropy: Ruben needs many terms; where the series bracket
    does not close, Monte Carlo with a 5-sigma margin is the reference."""
    rng = np.random.default_rng(2)
    c, R, mu, cov, s, d2 = _cases(rng, 300, sig_over_r=(0.03, 0.3), var_ratio=100.0)
    lower, upper = ruben_series(s, d2, R * R, max_terms=1500)
    bound = _bounds(c, R, mu, cov, "min")
    closed = upper - lower <= 1e-8 * upper + 1e-300
    assert closed.mean() > 0.8
    assert np.all(bound[closed] >= upper[closed] * (1.0 - 1e-9))
    open_ = np.flatnonzero(~closed)
    if open_.size:
        from iplanner_torch.collision.exact import mc_ball_probability

        t = torch.from_numpy
        p, se = mc_ball_probability(
            t(c[open_]), t(R[open_]), t(mu[open_]), t(cov[open_]), n=200_000, seed=3
        )
        assert np.all(bound[open_] >= p.numpy() - 5.0 * se.numpy() - 1e-12)


def test_isotropic_bound_matches_closed_form() -> None:
    """Isotropic: x_max lies on the line to the mean, m = (||mu - c|| - R)/sigma."""
    c = torch.zeros(4, 3, dtype=F64)
    dist = torch.tensor([0.3, 0.5, 0.8, 1.2], dtype=F64)
    mu = torch.stack([dist, torch.zeros(4, dtype=F64), torch.zeros(4, dtype=F64)], -1)
    sigma, R = 0.1, torch.full((4,), 0.2, dtype=F64)
    cov = torch.eye(3, dtype=F64).expand(4, 3, 3) * sigma**2
    m = (dist - R) / sigma
    half = 0.5 * special.erfc(m.numpy() / math.sqrt(2))
    vol = 4 / 3 * math.pi * 0.2**3 * (2 * math.pi * sigma**2) ** -1.5 * np.exp(-0.5 * m**2)
    got_h = G.sphere_collision_bound(c, R / 2, mu, cov, R / 2, method="halfspace")
    got_v = G.sphere_collision_bound(c, R / 2, mu, cov, R / 2, method="volume")
    np.testing.assert_allclose(got_h.numpy(), half, rtol=1e-10)
    np.testing.assert_allclose(got_v.numpy(), np.minimum(vol.numpy(), 1.0), rtol=1e-10)


def test_secular_function_concave_and_start_left_of_root() -> None:
    rng = np.random.default_rng(4)
    _, R, _, _, s, d2 = _cases(rng, 2000, sig_over_r=(0.01, 3.0), var_ratio=1e4)
    outside = d2.sum(1) > R**2
    d2_t = torch.from_numpy(d2[outside].T.copy())
    s_t = torch.from_numpy(s[outside].T.copy())
    R_t = torch.from_numpy(R[outside])
    start = G._newton_start(d2_t, s_t, R_t)
    g0, _ = G._secular_residual(start, d2_t, s_t, R_t)
    assert torch.all(g0 <= 1e-12)
    root = G._solve_bisection(d2_t, s_t, R_t)
    h = 1e-3 * root + 1e-6
    lam = torch.stack([root - h, root, root + h])  # (3, N)
    q = torch.stack([G._secular_residual(lam[i], d2_t, s_t, R_t)[0] for i in range(3)])
    assert torch.all(q[0] - 2 * q[1] + q[2] <= 1e-12 * q[1].abs().clamp_min(1.0))


def test_newton_equals_bisection() -> None:
    rng = np.random.default_rng(5)
    c, R, mu, cov, _, _ = _cases(rng, 5000, sig_over_r=(0.005, 5.0), var_ratio=1e4)
    t = torch.from_numpy
    x_n, lam_n = G.max_density_point(t(c), t(R), t(mu), t(cov), solver="newton")
    x_b, lam_b = G.max_density_point(t(c), t(R), t(mu), t(cov), solver="bisection")
    assert torch.allclose(lam_n, lam_b, rtol=1e-6, atol=0.0)
    assert (x_n - x_b).norm(dim=-1).max() <= 1e-6 * float(R.max())
    outside = lam_n > 0
    assert torch.allclose((x_n - t(c)).norm(dim=-1)[outside], t(R)[outside], rtol=1e-8)
    for method in ("min", "volume", "halfspace"):
        r1 = t(R) / 2
        b_n = G.sphere_collision_bound(t(c), r1, t(mu), t(cov), r1, method=method)
        b_b = G.sphere_collision_bound(
            t(c), r1, t(mu), t(cov), r1, method=method, solver="bisection"
        )
        assert torch.allclose(b_n, b_b, rtol=1e-6, atol=1e-300)


def test_x_max_maximises_density_over_the_ball() -> None:
    """Brute force: no point sampled in the ball has a higher density than x_max."""
    gen = torch.Generator().manual_seed(6)
    c = torch.zeros(3, dtype=F64)
    mu = torch.tensor([0.4, -0.1, 0.2], dtype=F64)
    A = torch.randn(3, 3, generator=gen, dtype=F64) * 0.1
    cov = A @ A.T + 1e-3 * torch.eye(3, dtype=F64)
    R = torch.tensor(0.15, dtype=F64)
    x, _ = G.max_density_point(c, R, mu, cov)
    pts = torch.randn(200_000, 3, generator=gen, dtype=F64)
    pts = pts / pts.norm(dim=-1, keepdim=True) * R * torch.rand(200_000, 1, generator=gen)
    P = torch.linalg.inv(cov)
    maha = lambda p: torch.einsum("ni,ij,nj->n", p - mu, P, p - mu)  # noqa: E731
    assert maha(x[None]).item() <= maha(pts).min().item() + 1e-12


@pytest.mark.parametrize("method", ["min", "volume", "halfspace"])
@pytest.mark.parametrize("diag", [False, True])
def test_gradients_match_finite_differences(method: str, diag: bool) -> None:
    gen = torch.Generator().manual_seed(7)
    n = 6
    c = (torch.rand(n, 3, generator=gen, dtype=F64) * 0.1).requires_grad_(True)
    mu = torch.tensor([0.25, 0.05, 0.0], dtype=F64) + 0.02 * torch.randn(n, 3, generator=gen)
    var = (0.04 + 0.06 * torch.rand(n, 3, generator=gen, dtype=F64)) ** 2
    r1 = torch.full((n,), 0.06, dtype=F64)
    r2 = torch.full((n,), 0.05, dtype=F64)
    if diag:
        f = lambda cc: G.sphere_collision_bound_diag(cc, r1, mu, var, r2, method=method)  # noqa: E731
    else:
        Q = torch.linalg.qr(torch.randn(n, 3, 3, generator=gen, dtype=F64))[0]
        cov = Q @ torch.diag_embed(var) @ Q.transpose(-1, -2)
        f = lambda cc: G.sphere_collision_bound(cc, r1, mu, cov, r2, method=method)  # noqa: E731
    assert bool((f(c) < 1).all()) and bool((f(c) > 1e-8).all())
    assert torch.autograd.gradcheck(f, (c,), eps=1e-7, atol=1e-6, rtol=1e-4)


def _problem(gen: torch.Generator, B=3, W=4, S_r=5, A=3, S_h=4, dtype=F64):
    rc = torch.rand(B, W, S_r, 3, generator=gen, dtype=dtype) * 0.6
    rr = 0.03 + 0.05 * torch.rand(S_r, generator=gen, dtype=dtype)
    hm = torch.rand(W, A, S_h, 3, generator=gen, dtype=dtype) * 0.6
    hv = (0.02 + 0.1 * torch.rand(W, A, S_h, 3, generator=gen, dtype=dtype)) ** 2
    hr = 0.03 + 0.05 * torch.rand(S_h, generator=gen, dtype=dtype)
    w = torch.softmax(torch.randn(W, A, generator=gen, dtype=dtype), -1)
    return rc, rr, hm, hv, hr, w


@pytest.mark.parametrize("diag", [True, False])
def test_trajectory_bound_equals_brute_force_loop(diag: bool) -> None:
    gen = torch.Generator().manual_seed(8)
    rc, rr, hm, hv, hr, w = _problem(gen)
    B, W, S_r, _ = rc.shape
    _, A, S_h, _ = hm.shape
    Q = torch.linalg.qr(torch.randn(W, A, S_h, 3, 3, generator=gen, dtype=F64))[0]
    cov = Q @ torch.diag_embed(hv) @ Q.transpose(-1, -2)
    h_cov = hv if diag else cov
    got = G.trajectory_collision_bound(rc, rr, hm, h_cov, hr, w, prune_sigma=None)
    pair = G.pairwise_bound_matrix(rc, rr, hm, h_cov, hr, w, prune_sigma=None)
    want = torch.zeros(B, W, dtype=F64)
    want_pair = torch.zeros(B, W, S_r, S_h, dtype=F64)
    for b in range(B):
        for i in range(W):
            for j in range(S_r):
                for l in range(S_h):
                    total = 0.0
                    for a in range(A):
                        p = G.sphere_collision_bound(
                            rc[b, i, j],
                            rr[j],
                            hm[i, a, l],
                            cov[i, a, l] if not diag else torch.diag(hv[i, a, l]),
                            hr[l],
                            solver="bisection",
                        )
                        total += float(w[i, a]) * float(p)
                    want_pair[b, i, j, l] = total
                    want[b, i] = max(float(want[b, i]), total)
    torch.testing.assert_close(pair, want_pair, rtol=1e-6, atol=1e-12)
    torch.testing.assert_close(got, want.clamp(0, 1), rtol=1e-6, atol=1e-12)
    total = G.trajectory_collision_bound(rc, rr, hm, h_cov, hr, w, reduce="sum", prune_sigma=None)
    torch.testing.assert_close(total, want_pair.sum((2, 3)).clamp(0, 1), rtol=1e-6, atol=1e-12)


def test_the_pair_maximum_is_no_bound_on_touching_any_pair_and_the_sum_is() -> None:
    """A robot sphere between two hands predicted independently, 12 cm either side (1 cm std):
    Monte Carlo over both hands at once is the reference. The paper's maximum over pairs is
    below the probability that one hand or the other touches; Boole's sum is above it."""
    rc = torch.zeros(1, 1, 1, 3, dtype=F64)  # (B, W, S_r, 3)
    rr = torch.tensor([0.05], dtype=F64)
    hm = torch.tensor([[[[0.12, 0.0, 0.0], [-0.12, 0.0, 0.0]]]], dtype=F64)  # (W, A, S_h, 3)
    hv = torch.full((1, 1, 2, 3), 0.01**2, dtype=F64)
    hr = torch.tensor([0.05, 0.05], dtype=F64)
    w = torch.ones(1, dtype=F64)
    n = 400_000
    hands = hm[0, 0] + 0.01 * torch.randn(n, 2, 3, generator=torch.Generator().manual_seed(5))
    touched = (hands.norm(dim=-1) < 0.1).any(-1).to(F64)  # (n,)
    p_any = float(touched.mean())
    se = math.sqrt(p_any * (1 - p_any) / n)
    paper = float(G.trajectory_collision_bound(rc, rr, hm, hv, hr, w, prune_sigma=None))
    union = float(G.trajectory_collision_bound(rc, rr, hm, hv, hr, w, reduce="sum"))
    assert paper < p_any - 5 * se, (paper, p_any)
    assert union >= p_any - 5 * se, (union, p_any)
    assert union == pytest.approx(2 * paper, rel=1e-6)  # the two pairs are mirror images


def test_batched_equals_looped_and_chunking() -> None:
    gen = torch.Generator().manual_seed(9)
    rc, rr, hm, hv, hr, w = _problem(gen, B=7)
    full = G.trajectory_collision_bound(rc, rr, hm, hv, hr, w[0])
    chunked = G.trajectory_collision_bound(rc, rr, hm, hv, hr, w[0], max_pairs_per_chunk=100)
    looped = torch.cat(
        [G.trajectory_collision_bound(rc[b : b + 1], rr, hm, hv, hr, w[0]) for b in range(7)]
    )
    # equal to the last bit on some CPUs, not on all: vectorised kernels may take other paths
    # for other tensor sizes, so a chunk may round an element differently (on one machine a
    # 2e-16 relative difference in one of 28 elements)
    torch.testing.assert_close(full, chunked, rtol=1e-12, atol=0)
    torch.testing.assert_close(full, looped, rtol=1e-12, atol=0)


@pytest.mark.parametrize("method", ["min", "volume", "halfspace"])
def test_pruning_never_lowers_the_bound(method: str) -> None:
    gen = torch.Generator().manual_seed(10)
    rc, rr, hm, hv, hr, w = _problem(gen, B=4, W=3, S_r=6, A=2, S_h=8)
    hv = hv * 0.05  # small variances: many pairs beyond 3 sigma
    exact = G.pairwise_bound_matrix(rc, rr, hm, hv, hr, w, method=method, prune_sigma=None)
    pruned = G.pairwise_bound_matrix(rc, rr, hm, hv, hr, w, method=method, prune_sigma=3.0)
    assert not torch.equal(exact, pruned)  # some pairs were pruned
    assert torch.all(pruned >= exact * (1 - 1e-12))
    if method != "volume":
        assert torch.all(pruned - exact <= 0.5 * math.erfc(3.0 / math.sqrt(2)) + 1e-15)


def test_trajectory_gradient_matches_finite_differences() -> None:
    gen = torch.Generator().manual_seed(11)
    rc, rr, hm, hv, hr, w = _problem(gen, B=1, W=2, S_r=2, A=2, S_h=2)
    rc = rc.requires_grad_(True)
    f = lambda x: G.pairwise_bound_matrix(x, rr, hm, hv, hr, w).sum()  # noqa: E731
    assert torch.autograd.gradcheck(f, (rc,), eps=1e-7, atol=1e-6, rtol=1e-4)


def test_float32_matches_float64(device: torch.device) -> None:
    gen = torch.Generator().manual_seed(12)
    prob = _problem(gen, B=4, W=5, S_r=8, A=3, S_h=6)
    want = G.trajectory_collision_bound(*prob)
    got = G.trajectory_collision_bound(*(x.to(device, torch.float32) for x in prob))
    assert got.device.type == device.type and got.dtype == torch.float32
    torch.testing.assert_close(got.cpu().double(), want, rtol=1e-3, atol=1e-6)


def test_seeded_inputs_give_identical_outputs() -> None:
    a = G.trajectory_collision_bound(*_problem(torch.Generator().manual_seed(13)))
    b = G.trajectory_collision_bound(*_problem(torch.Generator().manual_seed(13)))
    assert torch.equal(a, b)


def test_errors() -> None:
    gen = torch.Generator().manual_seed(14)
    rc, rr, hm, hv, hr, w = _problem(gen)
    with pytest.raises(ShapeError, match=r"expected human_mean \(4, A, S_h, 3\)"):
        G.trajectory_collision_bound(rc, rr, hm[:2], hv, hr, w)
    with pytest.raises(ShapeError, match="expected robot_radii"):
        G.trajectory_collision_bound(rc, rr[:2], hm, hv, hr, w)
    with pytest.raises(ShapeError, match="expected weights"):
        G.trajectory_collision_bound(rc, rr, hm, hv, hr, w[:, :2])
    with pytest.raises(ConfigError, match="expected method"):
        G.trajectory_collision_bound(rc, rr, hm, hv, hr, w, method="area")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected reduce"):
        G.trajectory_collision_bound(rc, rr, hm, hv, hr, w, reduce="mean")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected solver"):
        G.sphere_collision_bound_diag(rc, rr[0], rc, rc, rr[0], solver="golden")  # type: ignore[arg-type]
    with pytest.raises(ShapeError, match=r"expected cov \(\.\.\., 3, 3\)"):
        G.sphere_collision_bound(rc, rr[0], rc, rc, rr[0])
    with pytest.raises(ShapeError, match="radius"):
        G.sphere_collision_bound_diag(rc[0, 0, 0], -rr[0], rc[0, 0, 0], hv[0, 0, 0], rr[0] * 0)


def _pair(n: int = 4) -> dict[str, torch.Tensor]:
    """Valid arguments of sphere_collision_bound for n pairs (float64)."""
    gen = torch.Generator().manual_seed(15)
    return {
        "robot_center": torch.rand(n, 3, generator=gen, dtype=F64) * 0.1,
        "robot_radius": torch.full((n,), 0.06, dtype=F64),
        "mean": torch.tensor([0.3, 0.0, 0.0], dtype=F64).expand(n, 3).clone(),
        "cov": torch.eye(3, dtype=F64).expand(n, 3, 3) * 0.05**2,
        "human_radius": torch.full((n,), 0.05, dtype=F64),
    }


def _diag(args: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The same pairs as arguments of sphere_collision_bound_diag (cov -> its diagonal)."""
    out = {k: v for k, v in args.items() if k != "cov"}
    out["var"] = torch.diagonal(args["cov"], dim1=-2, dim2=-1)
    return out


@pytest.mark.parametrize("bad", [math.nan, math.inf])
@pytest.mark.parametrize("name", ["robot_center", "robot_radius", "mean", "cov", "human_radius"])
def test_non_finite_input_raises_data_error(name: str, bad: float) -> None:
    args = _pair()
    args[name] = args[name].clone()
    args[name][1] = bad
    with pytest.raises(DataError, match=f"expected finite {name}, got"):
        G.sphere_collision_bound(**args)
    diag_name = "var" if name == "cov" else name
    with pytest.raises(DataError, match=f"expected finite {diag_name}, got"):
        G.sphere_collision_bound_diag(**_diag(args))
    if name in ("robot_center", "mean", "cov"):
        R = args["robot_radius"] + args["human_radius"]
        with pytest.raises(DataError, match=f"expected finite {name}, got"):
            G.max_density_point(args["robot_center"], R, args["mean"], args["cov"])


def test_covariances_nan_and_inf_identity() -> None:
    """NaN, inf and identity covariances: eigh used to fail with an untyped LinAlgError."""
    args = _pair(1)
    for cov in (torch.full((3, 3), math.nan, dtype=F64), math.inf * torch.eye(3, dtype=F64)):
        with pytest.raises(DataError, match="expected finite cov, got"):
            G.sphere_collision_bound(**{**args, "cov": cov})


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_covariances_near_the_float_limit(dtype: torch.dtype) -> None:
    """Entries near the dtype's limit made eigh fail (raw LinAlgError) or return NaN ("got
    eigenvalue nan"). A huge but representable variance now gives a bound near 0; eigenvalues
    beyond the dtype are refused as overflowing."""
    big = torch.finfo(dtype).max / 1.05  # eigenvalue fits; 3 x it does not
    z = torch.zeros(3, dtype=dtype)
    huge = torch.diag(torch.full((3,), big, dtype=dtype))
    p = G.sphere_collision_bound(z, 0.1, z, huge, 0.1)
    assert torch.isfinite(p) and 0.0 <= float(p) < 1e-6
    with pytest.raises(DataError, match="eigenvalues overflow"):
        G.sphere_collision_bound(z, 0.1, z, torch.full((3, 3), big, dtype=dtype), 0.1)
    # not a covariance at all: named as such, not as NaN
    bad = torch.eye(3, dtype=dtype)
    bad[0, 1] = bad[1, 0] = big
    with pytest.raises(DataError, match="positive semidefinite, got eigenvalue -"):
        G.sphere_collision_bound(z, 0.1, z, bad, 0.1)


def test_indefinite_covariance_or_negative_variance_raises_data_error() -> None:
    args = _pair()
    with pytest.raises(DataError, match="expected cov positive semidefinite"):
        G.sphere_collision_bound(**{**args, "cov": -args["cov"]})
    with pytest.raises(DataError, match="expected cov positive semidefinite"):
        G.max_density_point(args["robot_center"], 0.1, args["mean"], -args["cov"])
    with pytest.raises(DataError, match="expected var >= 0"):
        G.sphere_collision_bound_diag(**{**_diag(args), "var": -_diag(args)["var"]})
    # rounding-level negative eigenvalues of a singular covariance are accepted
    flat = torch.diag(torch.tensor([0.01, 0.01, 0.0], dtype=F64))
    Q = torch.linalg.qr(torch.randn(3, 3, dtype=F64))[0]
    b = G.sphere_collision_bound(**{**args, "cov": Q @ flat @ Q.T})
    assert bool(((b >= 0) & (b <= 1)).all())


def test_mismatched_leading_dimensions_raise_shape_error() -> None:
    args = _pair(4)
    args["mean"] = torch.zeros(5, 3, dtype=F64)
    pattern = (
        r"expected broadcastable leading dimensions, got robot_center \(4, 3\).*mean \(5, 3\)"
    )
    with pytest.raises(ShapeError, match=pattern):
        G.sphere_collision_bound(**args)
    with pytest.raises(ShapeError, match=pattern):
        G.sphere_collision_bound_diag(**_diag(args))
    with pytest.raises(ShapeError, match=r"robot_center \(4, 3\).*mean \(5, 3\)"):
        G.max_density_point(args["robot_center"], 0.1, args["mean"], args["cov"][0])
    ok = _pair(4)
    with pytest.raises(ShapeError, match=r"radius \(2,\)"):
        G.max_density_point(ok["robot_center"], torch.ones(2, dtype=F64), ok["mean"], ok["cov"])


def test_dtype_and_device_are_checked() -> None:
    args = _pair()
    with pytest.raises(ShapeError, match="expected mean torch.float64 \\(as robot_center\\)"):
        G.sphere_collision_bound(**{**args, "mean": args["mean"].float()})
    with pytest.raises(ShapeError, match="expected robot_center of a floating dtype"):
        G.sphere_collision_bound(**{**args, "robot_center": torch.zeros(4, 3, dtype=torch.long)})
    with pytest.raises(ShapeError, match="expected cov on cpu"):
        G.sphere_collision_bound(**{**args, "cov": args["cov"].to("meta")})


def test_float_radius_is_accepted() -> None:
    args = _pair()
    c, m, cov = args["robot_center"], args["mean"], args["cov"]
    x_f, lam_f = G.max_density_point(c, 0.2, m, cov)
    x_t, lam_t = G.max_density_point(c, torch.tensor(0.2, dtype=F64), m, cov)
    assert torch.equal(x_f, x_t) and torch.equal(lam_f, lam_t)
    b_f = G.sphere_collision_bound(c, 0.06, m, cov, 0.05)
    b_t = G.sphere_collision_bound(
        c, torch.tensor(0.06, dtype=F64), m, cov, torch.tensor(0.05, dtype=F64)
    )
    assert torch.equal(b_f, b_t)
    b_d = G.sphere_collision_bound_diag(c, 0.06, m, torch.full((3,), 0.05**2, dtype=F64), 0.05)
    torch.testing.assert_close(b_d, b_f)
    with pytest.raises(ShapeError, match="expected radius > 0"):
        G.max_density_point(c, 0.0, m, cov)
    with pytest.raises(ShapeError, match="expected radius to be a torch.Tensor or a float"):
        G.max_density_point(c, "0.2", m, cov)  # type: ignore[arg-type]


@pytest.mark.parametrize("prune_sigma", [-1.0, 0.0, math.nan])
def test_non_positive_prune_sigma_raises_config_error(prune_sigma: float) -> None:
    args = _pair()
    with pytest.raises(ConfigError, match="expected prune_sigma > 0 or None"):
        G.sphere_collision_bound(**args, prune_sigma=prune_sigma)
    with pytest.raises(ConfigError, match="expected prune_sigma > 0 or None"):
        G.sphere_collision_bound_diag(**_diag(args), prune_sigma=prune_sigma)
    rc, rr, hm, hv, hr, w = _problem(torch.Generator().manual_seed(16))
    with pytest.raises(ConfigError, match="expected prune_sigma > 0 or None"):
        G.trajectory_collision_bound(rc, rr, hm, hv, hr, w, prune_sigma=prune_sigma)


@pytest.mark.parametrize("diag", [True, False])
@pytest.mark.parametrize(
    "name", ["robot_centers", "robot_radii", "human_mean", "human_cov", "human_radii", "weights"]
)
def test_trajectory_bound_non_finite_input_raises_data_error(name: str, diag: bool) -> None:
    rc, rr, hm, hv, hr, w = _problem(torch.Generator().manual_seed(17))
    cov = hv if diag else torch.diag_embed(hv)
    args = dict(
        robot_centers=rc, robot_radii=rr, human_mean=hm, human_cov=cov, human_radii=hr, weights=w
    )
    args[name] = args[name].clone()
    args[name].view(-1)[0] = math.nan
    with pytest.raises(DataError, match=f"expected finite {name}, got 1 NaN"):
        G.trajectory_collision_bound(**args)
    with pytest.raises(DataError, match=f"expected finite {name}, got 1 NaN"):
        G.pairwise_bound_matrix(**args)


def test_trajectory_bound_out_of_range_inputs() -> None:
    rc, rr, hm, hv, hr, w = _problem(torch.Generator().manual_seed(18))
    with pytest.raises(DataError, match="expected weights >= 0"):
        G.trajectory_collision_bound(rc, rr, hm, hv, hr, w - 0.5)
    with pytest.raises(DataError, match="expected weights summing to <= 1"):
        G.trajectory_collision_bound(rc, rr, hm, hv, hr, 2.0 * w)
    with pytest.raises(DataError, match="expected human_cov >= 0"):
        G.trajectory_collision_bound(rc, rr, hm, -hv, hr, w)
    with pytest.raises(DataError, match="expected human_cov positive semidefinite"):
        G.trajectory_collision_bound(rc, rr, hm, -torch.diag_embed(hv), hr, w)
    with pytest.raises(ShapeError, match=r"expected robot_radii \+ human_radii > 0"):
        G.trajectory_collision_bound(rc, -rr, hm, hv, 0.0 * hr, w)
    with pytest.raises(ShapeError, match="expected human_mean torch.float64"):
        G.trajectory_collision_bound(rc, rr, hm.float(), hv, hr, w)
    with pytest.raises(ConfigError, match="expected max_pairs_per_chunk an integer >= 1"):
        G.trajectory_collision_bound(rc, rr, hm, hv, hr, w, max_pairs_per_chunk=1.5)  # type: ignore[arg-type]
    with pytest.raises(ShapeError, match="expected human_cov to be a torch.Tensor"):
        G.trajectory_collision_bound(rc, rr, hm, hv.tolist(), hr, w)  # type: ignore[arg-type]
    # weights of dropped actions (sum < 1) are fine
    b = G.trajectory_collision_bound(rc, rr, hm, hv, hr, 0.5 * w)
    assert bool(((b >= 0) & (b <= 1)).all())


def test_shared_covariance_and_radius_broadcast() -> None:
    """A (3, 3) covariance, (3,) variances or (S,) radii broadcast against batched centres
    (the component-first solver used to fail on arguments of lower rank)."""
    args = _pair(4)
    want = G.sphere_collision_bound(**args)
    got = G.sphere_collision_bound(**{**args, "cov": args["cov"][0]})
    torch.testing.assert_close(got, want, rtol=0, atol=0)
    got_d = G.sphere_collision_bound_diag(**{**_diag(args), "var": _diag(args)["var"][0]})
    torch.testing.assert_close(got_d, want, rtol=1e-12, atol=0)
    # one centre and mean against four radii
    radii = torch.tensor([0.02, 0.05, 0.1, 0.2], dtype=F64)
    c, m, cov = args["robot_center"][0], args["mean"][0], args["cov"][0]
    loop = torch.stack([G.sphere_collision_bound(c, r, m, cov, 0.05) for r in radii])
    torch.testing.assert_close(G.sphere_collision_bound(c, radii, m, cov, 0.05), loop)
    torch.testing.assert_close(
        G.sphere_collision_bound_diag(c, radii, m, torch.diagonal(cov), 0.05), loop
    )


def _traj_args(gen: torch.Generator, diag: bool, dtype=F64, **sizes) -> dict[str, torch.Tensor]:
    """Arguments of trajectory_collision_bound by name, with diagonal or full covariances."""
    rc, rr, hm, hv, hr, w = _problem(gen, dtype=dtype, **sizes)
    return dict(
        robot_centers=rc,
        robot_radii=rr,
        human_mean=hm,
        human_cov=hv if diag else torch.diag_embed(hv),
        human_radii=hr,
        weights=w,
    )


@pytest.mark.parametrize("diag", [True, False])
def test_empty_batch_gives_empty_results(diag: bool) -> None:
    """B = 0 used to fail in torch.cat; every entry point returns an empty tensor."""
    args = _traj_args(torch.Generator().manual_seed(20), diag, B=0)
    pair = G.pairwise_bound_matrix(**args)
    assert pair.shape == (0, 4, 5, 4) and pair.dtype == F64
    assert G.trajectory_collision_bound(**args).shape == (0, 4)
    assert G.trajectory_collision_bound(**args, reduce="none").shape == (0, 4, 5, 4)
    assert G.trajectory_collision_bound(**args, prune_sigma=None).shape == (0, 4)
    empty = torch.zeros(0, 3, dtype=F64)
    cov = torch.eye(3, dtype=F64) * 0.01
    assert G.sphere_collision_bound(empty, 0.05, empty, cov, 0.05).shape == (0,)
    assert G.sphere_collision_bound_diag(empty, 0.05, empty, torch.diagonal(cov), 0.05).shape == (
        0,
    )
    x, lam = G.max_density_point(empty, 0.1, empty, cov)
    assert x.shape == (0, 3) and lam.shape == (0,)


@pytest.mark.parametrize("diag", [True, False])
@pytest.mark.parametrize("sizes", [{"S_r": 0}, {"S_h": 0}])
def test_no_sphere_pair_gives_zero_bound(diag: bool, sizes: dict[str, int]) -> None:
    """No robot or no human sphere: nothing can collide, the bound is 0 (the maximum over no
    pair used to fail in amax)."""
    args = _traj_args(torch.Generator().manual_seed(21), diag, **sizes)
    B, W, S_r, _ = args["robot_centers"].shape
    S_h = args["human_mean"].shape[2]
    got = G.trajectory_collision_bound(**args)
    assert got.shape == (B, W) and got.dtype == F64
    assert torch.equal(got, torch.zeros(B, W, dtype=F64))
    pair = G.trajectory_collision_bound(**args, reduce="none", prune_sigma=None)
    assert pair.shape == (B, W, S_r, S_h)
    assert torch.equal(pair, torch.zeros_like(pair))


@pytest.mark.parametrize("diag", [True, False])
def test_no_waypoint_or_no_action(diag: bool) -> None:
    """No waypoint: an empty (B, 0); no action (A = 0, empty weights): 0 everywhere."""
    gen = torch.Generator().manual_seed(25)
    assert G.trajectory_collision_bound(**_traj_args(gen, diag, W=0)).shape == (3, 0)
    got = G.trajectory_collision_bound(**_traj_args(gen, diag, A=0))
    assert torch.equal(got, torch.zeros(3, 4, dtype=F64))


@pytest.mark.parametrize(
    "name", ["robot_radius", "human_radius", "radius", "robot_radii", "human_radii", "weights"]
)
def test_mixed_dtypes_raise_shape_error_naming_both(name: str) -> None:
    """A float64 radius or weight with float32 centres used to be promoted in one entry point
    and a raw RuntimeError in others; every entry point now refuses it by name."""
    pattern = rf"expected {name} torch\.float32 \(as robot_centers?\), got torch\.float64"
    if name in ("robot_radii", "human_radii", "weights"):
        for diag in (True, False):
            args = _traj_args(torch.Generator().manual_seed(22), diag, dtype=torch.float32)
            args[name] = args[name].double()
            with pytest.raises(ShapeError, match=pattern):
                G.pairwise_bound_matrix(**args)
            with pytest.raises(ShapeError, match=pattern):
                G.trajectory_collision_bound(**args)
        return
    args = {k: v.float() for k, v in _pair().items()}
    R = args["robot_radius"] + args["human_radius"]
    if name == "radius":
        with pytest.raises(ShapeError, match=pattern):
            G.max_density_point(args["robot_center"], R.double(), args["mean"], args["cov"])
        return
    args[name] = args[name].double()
    with pytest.raises(ShapeError, match=pattern):
        G.sphere_collision_bound(**args)
    with pytest.raises(ShapeError, match=pattern):
        G.sphere_collision_bound_diag(**_diag(args))
    # Python floats are converted to the dtype of the centres
    b = G.sphere_collision_bound(**{**args, name: 0.05})
    assert b.dtype == torch.float32


@pytest.mark.parametrize(
    "dtype", [torch.float16, torch.bfloat16, torch.int64, torch.int32, torch.bool]
)
def test_unsupported_dtypes_raise_shape_error(dtype: torch.dtype) -> None:
    """Half precision used to fail inside eigh (NotImplementedError) or, with variances,
    compute in half precision (float16 floors no variance: 1e-12 underflows); every entry
    point names the two supported dtypes."""
    pattern = r"expected robot_centers? of a floating dtype \(torch\.float32 or torch\.float64\)"
    args = {k: v.to(dtype) for k, v in _pair().items()}
    with pytest.raises(ShapeError, match=pattern):
        G.sphere_collision_bound(**args)
    with pytest.raises(ShapeError, match=pattern):
        G.sphere_collision_bound_diag(**_diag(args))
    with pytest.raises(ShapeError, match=pattern):
        G.max_density_point(args["robot_center"], 0.1, args["mean"], args["cov"])
    targs = {
        k: v.to(dtype) for k, v in _traj_args(torch.Generator().manual_seed(23), True).items()
    }
    with pytest.raises(ShapeError, match=pattern):
        G.trajectory_collision_bound(**targs)
    with pytest.raises(ShapeError, match=pattern):
        G.pairwise_bound_matrix(**targs)
    # one half-precision argument among float64 ones is named
    with pytest.raises(ShapeError, match=r"expected cov of a floating dtype"):
        G.sphere_collision_bound(**{**_pair(), "cov": _pair()["cov"].to(dtype)})


@pytest.mark.parametrize("method", ["min", "volume", "halfspace"])
@pytest.mark.parametrize("prune_sigma", [None, 6.0])
@pytest.mark.parametrize(("dtype", "far"), [(torch.float32, 1e20), (torch.float64, 1e155)])
def test_far_means_give_zero_not_nan(
    method: str, prune_sigma: float | None, dtype: torch.dtype, far: float
) -> None:
    """A mean so far that its squared distance overflows used to give NaN without pruning;
    the bound of such a pair is that of its Euclidean gap: 0 (the pruned bound with
    pruning), with finite gradients, and its neighbours keep their bounds."""
    args = {k: v.to(dtype) for k, v in _pair(3).items()}
    near = G.sphere_collision_bound(**args, method=method, prune_sigma=prune_sigma)
    mean = args["mean"].clone()
    mean[1, 0] = far
    mean[2] = -far
    mean.requires_grad_(True)
    center = args["robot_center"].clone().requires_grad_(True)
    kw = dict(method=method, prune_sigma=prune_sigma)
    pruned = 0.5 * math.erfc(6.0 / math.sqrt(2.0)) if method != "volume" else 0.0
    want = 0.0 if prune_sigma is None else pruned
    for fn, spread in (
        (G.sphere_collision_bound, args["cov"]),
        (G.sphere_collision_bound_diag, _diag(args)["var"]),
    ):
        for solver in ("newton", "bisection"):
            b = fn(
                center,
                args["robot_radius"],
                mean,
                spread,
                args["human_radius"],
                solver=solver,
                **kw,
            )
            assert torch.isfinite(b).all()
            assert b[0] == near[0]
            torch.testing.assert_close(
                b[1:], torch.full((2,), want, dtype=dtype), rtol=1e-6, atol=0
            )
            b.sum().backward()
            assert torch.isfinite(mean.grad).all() and torch.isfinite(center.grad).all()
            mean.grad = center.grad = None
    gen = torch.Generator().manual_seed(24)
    for diag in (True, False):
        targs = _traj_args(gen, diag, dtype=dtype)
        targs["human_mean"] = targs["human_mean"].clone()
        targs["human_mean"][:, 0] = far  # every human sphere of action 0 far away
        got = G.trajectory_collision_bound(**targs, **kw)
        assert torch.isfinite(got).all() and bool(((got >= 0) & (got <= 1)).all())
        targs["weights"] = torch.zeros_like(targs["weights"])
        targs["weights"][:, 0] = 1.0  # only the far action
        only_far = G.trajectory_collision_bound(**targs, **kw)
        torch.testing.assert_close(only_far, torch.full_like(only_far, want), rtol=1e-6, atol=0)


@pytest.mark.parametrize(
    ("dtype", "limit"), [(torch.float32, "1.8e+19"), (torch.float64, "1.3e+154")]
)
def test_max_density_point_refuses_overflowing_distances(dtype: torch.dtype, limit: str) -> None:
    """x_max of a mean whose squared distance overflows used to be NaN."""
    args = {k: v.to(dtype) for k, v in _pair(2).items()}
    mean = args["mean"].clone()
    mean[1, 0] = 1e20 if dtype == torch.float32 else 1e155
    limit_m = re.escape(f"{limit} m in {dtype}")
    pattern = rf"expected \|\|mean - robot_center\|\| < {limit_m}.*got 1 of 2 pairs"
    with pytest.raises(DataError, match=pattern):
        G.max_density_point(args["robot_center"], 0.1, mean, args["cov"])
    # just inside the limit x_max is finite, on the sphere, towards the mean
    mean[1, 0] = 0.5 * float(limit)
    x, lam = G.max_density_point(args["robot_center"], 0.1, mean, args["cov"])
    assert torch.isfinite(x).all() and torch.isfinite(lam).all()
    r = torch.linalg.vector_norm(x[1] - args["robot_center"][1])
    torch.testing.assert_close(r, torch.tensor(0.1, dtype=dtype))


def test_volume_bound_gradient_is_finite_with_the_mean_on_the_centre() -> None:
    """With pruning, a mean exactly on the robot sphere's centre gave NaN gradients (the
    far-pair gap's square root at 0, multiplied by a zero weight)."""
    args = _pair(2)
    mean = args["robot_center"].clone().requires_grad_(True)
    b = G.sphere_collision_bound(**{**args, "mean": mean}, method="volume", prune_sigma=6.0)
    b.sum().backward()
    assert torch.isfinite(mean.grad).all()


@pytest.mark.parametrize(("dtype", "big"), [(torch.float32, 1e38), (torch.float64, 1e307)])
@pytest.mark.parametrize("full", [False, True])
def test_huge_variance_beside_a_floored_one_gives_the_bound_not_nan(
    dtype: torch.dtype, big: float, full: bool
) -> None:
    """A variance so far above another one raised to VAR_FLOOR that ``lambda s`` overflowed
    gave NaN (inf / inf); along that direction the person is anywhere, so the half-space
    bound is that of the other two: the distance to the disc of the ball at z = 0.1."""
    var = torch.tensor([[0.01, big, 0.0]], dtype=dtype)
    spread = torch.diag_embed(var) if full else var
    fn = G.sphere_collision_bound if full else G.sphere_collision_bound_diag
    center = torch.zeros(1, 3, dtype=dtype, requires_grad=True)
    mean = torch.tensor([[0.5, 0.2, 0.1]], dtype=dtype)
    m = (0.5 - math.sqrt(0.2**2 - 0.1**2)) / 0.1
    for method in ("halfspace", "min"):
        b = fn(center, 0.1, mean, spread, 0.1, method=method)
        assert torch.isfinite(b).all()
        if method == "halfspace":
            assert float(b.detach()) == pytest.approx(
                0.5 * math.erfc(m / math.sqrt(2.0)), rel=1e-3
            )
        b.sum().backward()
        assert torch.isfinite(center.grad).all()
        center.grad = None


def test_backward_works_when_every_bound_is_constant() -> None:
    """With every mean inside its ball (or every pair pruned) the bounds did not depend on
    the centres and backward() raised a bare RuntimeError ("does not require grad"); the
    gradient is now zero."""
    center = torch.zeros(2, 3, dtype=F64, requires_grad=True)
    mean = torch.zeros(2, 3, dtype=F64)
    for method in ("min", "volume", "halfspace"):
        cov = 0.01 * torch.eye(3, dtype=F64)
        b = G.sphere_collision_bound(center, 0.1, mean, cov, 0.1, method=method)
        b.sum().backward()
        assert center.grad is not None and not center.grad.any()
        center.grad = None
        far = torch.full((2, 3), 100.0, dtype=F64)
        var = torch.full((2, 3), 0.01, dtype=F64)
        b = G.sphere_collision_bound_diag(
            center, 0.1, far, var, 0.1, method=method, prune_sigma=6.0
        )
        b.sum().backward()
        assert center.grad is not None and torch.isfinite(center.grad).all()
        center.grad = None


@pytest.mark.parametrize(
    ("dtype", "radius"),
    [(torch.float32, 1e-12), (torch.float32, 1e-30), (torch.float64, 1e-30),
     (torch.float64, 1e-200)],
)  # fmt: skip
def test_near_zero_radii_give_the_floor_radius_bound_not_nan(
    dtype: torch.dtype, radius: float
) -> None:
    """Radius sums below ``RADIUS_FLOOR`` are raised to it; they made NaN (float64 below about
    1e-154 m, float32 below about 1e-19 m) where the solver's squares underflowed. The bound
    at the floor stays above the probability of the tiny ball, about its volume times the
    density at its centre."""
    c = torch.zeros(3, dtype=dtype)
    mean = torch.tensor([0.3, 0.1, 0.0], dtype=dtype)
    cov = torch.diag(torch.tensor([1e-2, 2e-2, 5e-3], dtype=dtype))
    half = G.RADIUS_FLOOR / 2
    for method in ("min", "volume", "halfspace"):
        b = G.sphere_collision_bound(c, radius, mean, cov, radius, method=method)
        at_floor = G.sphere_collision_bound(c, half, mean, cov, half, method=method)
        assert torch.isfinite(b) and 0.0 <= float(b) <= 1.0, (method, b)
        assert float(b) == float(at_floor), method
    bound = G.sphere_collision_bound(c, radius, mean, cov, radius)
    diag = G.sphere_collision_bound_diag(c, radius, mean, torch.diagonal(cov), radius)
    assert float(diag) == pytest.approx(float(bound), rel=1e-5)
    m, S = mean.double(), cov.double()
    density = math.exp(-0.5 * float(m @ torch.linalg.solve(S, m))) / math.sqrt(
        (2 * math.pi) ** 3 * float(torch.det(S))
    )
    p_ball = 4 / 3 * math.pi * G.RADIUS_FLOOR**3 * density  # the density varies by < 1e-6
    assert float(bound) >= p_ball * (1 - 1e-4)
    x, lam = G.max_density_point(c, torch.tensor(2 * radius, dtype=dtype), mean, cov)
    assert torch.isfinite(x).all() and torch.isfinite(lam)
    assert float(torch.linalg.norm(x.double())) == pytest.approx(G.RADIUS_FLOOR, rel=1e-4)


def test_far_pairs_with_tiny_radius_and_variance_are_finite_in_float32() -> None:
    """A mean 1e9 m away with variance 1e-12 m^2 and a radius sum at or near the floor: the
    secular equation's derivative (a product of y^2, s and w) underflowed float32 to 0 and
    made NaN."""
    c = torch.zeros(3)
    mean = torch.tensor([1e9, 3e8, 0.0])
    cov = torch.diag(torch.tensor([1e-12, 2e-12, 5e-13]))
    for method in ("min", "halfspace"):
        b = G.sphere_collision_bound(c, 1e-10, mean, cov, 1e-10, method=method)
        assert float(b) == 0.0, method
    x, _ = G.max_density_point(c, torch.tensor(2e-9), mean, cov)
    assert torch.isfinite(x).all()
    direction = (mean / torch.linalg.norm(mean)).double()
    assert float(torch.linalg.norm(x.double())) == pytest.approx(2e-9, rel=1e-3)
    assert float(x.double() @ direction) > 0.0
