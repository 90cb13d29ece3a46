"""Prediction numerics against references computed here by other methods.

* DTW and the global alignment kernel: every warping path enumerated (a minimum and a sum
  over explicit paths, not a dynamic programme); the RBF kernel: scipy's ``cdist``.
* IVM: the second import vector against scipy's minimum of the documented objective for
  each candidate, the first import's coefficients held fixed.
* SVGP: the sparse (M < N) predictive mean and variance against Titsias's closed form in
  unwhitened numpy linear algebra, the collapsed bound against ``log N(y | 0, Q + Lam) -
  tr(Lam^-1 (K - Q)) / 2`` with scipy's multivariate normal, the NIGP gradient term against
  central finite differences of the predictive mean.
* Forecast mixtures: Monte Carlo samples of the action mixture.
* Next-action histograms: plain-Python counting of random tuples.
"""

from __future__ import annotations

import math
from collections import Counter
from functools import cache

import numpy as np
import pytest
import torch
from scipy import optimize, stats
from scipy.spatial.distance import cdist

from iplanner_torch.eval.prediction import window_metrics
from iplanner_torch.prediction import ivm as ivm_module
from iplanner_torch.prediction.coherence import NextActionModel
from iplanner_torch.prediction.dtw import (
    RBFKernel,
    dtw_distance,
    dtw_paired,
    gak_log,
    gak_log_paired,
    median_dtw,
)
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.prediction.ivm import IVMClassifier
from iplanner_torch.prediction.svgp import SVGPCfg, SVGPRegressor

pytestmark = pytest.mark.usefixtures("one_thread")

F64 = torch.float64


# ------------------------------------------------------------------------------------ DTW


@cache
def _paths(t1: int, t2: int) -> tuple[tuple[tuple[int, int], ...], ...]:
    """Every warping path from (0, 0) to (t1 - 1, t2 - 1), steps (1, 0), (0, 1), (1, 1)."""
    if t1 == 1 and t2 == 1:
        return (((0, 0),),)
    out = []
    for di, dj in ((1, 0), (0, 1), (1, 1)):
        if t1 - di >= 1 and t2 - dj >= 1:
            out += [p + ((t1 - 1, t2 - 1),) for p in _paths(t1 - di, t2 - dj)]
    return tuple(out)


def _in_band(i: int, j: int, t1: int, t2: int, band: int | None) -> bool:
    """The documented Sakoe-Chiba rule: ``|i - j r| <= max(band, max(1, r) / 2)``."""
    if band is None or t1 == 1 or t2 == 1:
        return True
    r = (t1 - 1) / (t2 - 1)
    return abs(i - j * r) <= max(band, max(1.0, r) / 2) + 1e-9


def _admissible(t1: int, t2: int, band: int | None) -> list[tuple[tuple[int, int], ...]]:
    return [p for p in _paths(t1, t2) if all(_in_band(i, j, t1, t2, band) for i, j in p)]


def test_path_enumeration_counts_delannoy_numbers() -> None:
    """The reference's own check: D(m, n) paths (1, 3, 13, 63, 321 on the diagonal)."""
    assert [len(_paths(n, n)) for n in range(1, 6)] == [1, 3, 13, 63, 321]
    assert len(_paths(3, 5)) == 41


@pytest.mark.parametrize("band", [None, 0, 1])
@pytest.mark.parametrize(("t1", "t2"), [(5, 5), (4, 6), (6, 3), (1, 4)])
def test_dtw_is_the_cheapest_warping_path(t1: int, t2: int, band: int | None) -> None:
    """DTW = min over admissible paths of the summed frame distances (squared variant: the
    square root of the min of summed squared distances). Float64: rtol 1e-12."""
    g = torch.Generator().manual_seed(t1 * 10 + t2)
    x = torch.randn(3, t1, 2, generator=g, dtype=F64)
    y = torch.randn(4, t2, 2, generator=g, dtype=F64)
    paths = _admissible(t1, t2, band)
    assert paths
    for squared in (False, True):
        got = dtw_distance(x, y, band=band, squared=squared).numpy()
        for a in range(3):
            for b in range(4):
                d = cdist(x[a].numpy(), y[b].numpy())
                cost = d**2 if squared else d
                best = min(sum(cost[i, j] for i, j in p) for p in paths)
                want = math.sqrt(best) if squared else best
                assert got[a, b] == pytest.approx(want, rel=1e-12), (a, b, squared)
    paired = dtw_paired(x[:3], y[:3], band=band).numpy()
    np.testing.assert_allclose(paired, np.diag(dtw_distance(x, y[:3], band=band).numpy()))


def test_next_action_of_an_unseen_pair_by_hand() -> None:
    """(p=0, c=0) -> 1 five times, (0, 1) -> 2 five times; the unseen pair (0, 2) takes the
    histogram of p = 0 summed over c, [0, 5, 5], without its count of n = c = 2, [0, 5, 0],
    plus the smoothing 1 on the allowed actions 0 and 1: [1, 6, 0] / 7. (Keeping the count of
    n = c gave 5/12 to "the next action is the current one", impossible by definition.)"""
    five = torch.zeros(5, dtype=torch.int64)
    model = NextActionModel().fit(
        torch.cat([five, five]),
        torch.cat([five, five + 1]),
        torch.cat([five + 1, five + 2]),
        num_actions=3,
    )
    got = model.next_action_prob(0, 2)
    torch.testing.assert_close(got, torch.tensor([1 / 7, 6 / 7, 0.0], dtype=torch.float64))


def test_median_dtw_of_two_windows_is_their_brute_force_distance() -> None:
    """With two windows every pair drawn is the one distinct pair, so the median is their DTW
    distance (the cheapest warping path); pairing a window with itself (distance 0) would drag
    it towards 0."""
    g = torch.Generator().manual_seed(5)
    x = torch.randn(2, 5, 2, generator=g, dtype=F64)
    d = cdist(x[0].numpy(), x[1].numpy())
    want = min(sum(d[i, j] for i, j in p) for p in _admissible(5, 5, None))
    assert median_dtw(x, 501, seed=3) == pytest.approx(want, rel=1e-12)


def test_dtw_of_a_set_with_itself_in_small_tiles_equals_a_copy() -> None:
    """``dtw_distance(x, x)`` takes the symmetric path (one triangle, mirrored); tiles of a few
    cells must still fill the whole matrix: the same numbers as ``dtw_distance(x, x.clone())``,
    and every entry the brute-force cheapest path."""
    g = torch.Generator().manual_seed(6)
    x = torch.randn(10, 4, 2, generator=g, dtype=F64)
    same = dtw_distance(x, x, max_cells=128)
    torch.testing.assert_close(same, dtw_distance(x, x.clone(), max_cells=128), rtol=1e-12, atol=0)
    paths = _admissible(4, 4, None)
    for a, b in ((0, 9), (9, 0), (3, 7)):
        d = cdist(x[a].numpy(), x[b].numpy())
        assert float(same[a, b]) == pytest.approx(min(sum(d[i, j] for i, j in p) for p in paths))


@pytest.mark.parametrize("band", [None, 0, 1])
@pytest.mark.parametrize(("t1", "t2"), [(5, 5), (4, 6), (6, 3)])
def test_gak_is_the_sum_over_warping_paths(t1: int, t2: int, band: int | None) -> None:
    """Cuturi's kernel = sum over admissible paths of the product of the local kernels
    ``kappa = e^-u / (2 - e^-u)``, ``u = ||a - b||^2 / (2 sigma^2)``. Float64: rtol 1e-10
    (a log-sum-exp over a few hundred terms)."""
    g = torch.Generator().manual_seed(100 + t1 * 10 + t2)
    x = torch.randn(3, t1, 2, generator=g, dtype=F64)
    y = torch.randn(2, t2, 2, generator=g, dtype=F64)
    sigma = 1.1
    paths = _admissible(t1, t2, band)
    got = gak_log(x, y, sigma=sigma, band=band).numpy()
    for a in range(3):
        for b in range(2):
            u = cdist(x[a].numpy(), y[b].numpy()) ** 2 / (2 * sigma**2)
            kappa = np.exp(-u) / (2.0 - np.exp(-u))
            total = sum(math.prod(kappa[i, j] for i, j in p) for p in paths)
            assert got[a, b] == pytest.approx(math.log(total), rel=1e-10), (a, b)
    np.testing.assert_allclose(
        gak_log_paired(x[:2], y, sigma=sigma, band=band).numpy(),
        np.diag(got[:2]),
        rtol=1e-12,
    )


def test_rbf_kernel_equals_scipy_distances_of_flattened_windows() -> None:
    """``exp(-||x - y||^2 / (2 l^2))`` on flattened windows, distances by scipy (float64:
    rtol 1e-12; float32: 1e-5 for the rounding of the inputs and of the matrix product)."""
    g = torch.Generator().manual_seed(7)
    x = 3.0 + torch.randn(6, 5, 4, generator=g, dtype=F64)
    y = 3.0 + torch.randn(4, 5, 4, generator=g, dtype=F64)
    ls = 2.5
    want = np.exp(-cdist(x.flatten(1).numpy(), y.flatten(1).numpy(), "sqeuclidean") / (2 * ls**2))
    np.testing.assert_allclose(RBFKernel(ls)(x, y).numpy(), want, rtol=1e-12, atol=0)
    np.testing.assert_allclose(RBFKernel(ls)(x.float(), y.float()).numpy(), want, rtol=1e-5)


# ------------------------------------------------------------------------------------ IVM


def _windows(n: int, seed: int, classes: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    y = torch.randint(0, classes, (n,), generator=g)
    time = torch.linspace(0.0, 1.0, 6, dtype=F64)
    phase = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    base = torch.sin(2 * math.pi * (1.0 + y.double())[:, None] * time + phase[:, None])
    x = base[:, :, None] + 0.3 * torch.randn(n, 6, 2, generator=g, dtype=F64)
    return x, y


def test_second_import_is_the_candidate_of_least_conditional_loss() -> None:
    """The documented greedy step after the first import: each candidate l is scored by the
    minimum over (bias, v_l) of H with the first import's coefficients held fixed, and the
    least is imported. Reference: scipy's BFGS minimum of that H per candidate, the fixed
    coefficients taken from a one-import fit refitted to convergence (its refit is the same
    bound-Newton fit as the two-import run's, 300 steps: converged to far below the gap
    between the best and second-best candidate checked below)."""
    x, y = _windows(18, 1)
    kernel = RBFKernel(2.0)
    lam = 0.05
    kw = dict(num_classes=3, lam=lam, tol=0.0, candidates=None, newton_steps=300)
    one = IVMClassifier(kernel, max_import=1, **kw).fit(x, y)
    two = IVMClassifier(kernel, max_import=2, **kw).fit(x, y)
    j1 = int(one.import_index_[0])
    assert int(two.import_index_[0]) == j1
    a1 = one.weights_[1].numpy()  # (C,) coefficients of the first import
    kmat = kernel(x, x).numpy()
    shift = ivm_module._JITTER * float(np.abs(np.diag(kmat)).mean())
    onehot = np.eye(3)[y.numpy()]

    def h(theta: np.ndarray, l: int) -> float:
        b, v = theta[:3], theta[3:]
        f = b[None] + kmat[:, j1 : j1 + 1] * a1[None] + kmat[:, l : l + 1] * v[None]
        lse = np.log(np.exp(f - f.max(1, keepdims=True)).sum(1)) + f.max(1)
        nll = -(onehot * (f - lse[:, None])).sum()
        pen = (kmat[j1, j1] + shift) * a1 @ a1 + 2 * kmat[j1, l] * a1 @ v
        pen += (kmat[l, l] + shift) * v @ v
        return float(nll + 0.5 * lam * pen)

    scores = {}
    for l in range(18):
        if l == j1:
            continue
        res = optimize.minimize(h, np.zeros(6), args=(l,), method="BFGS", options={"gtol": 1e-9})
        scores[l] = res.fun
    ranked = sorted(scores, key=scores.get)
    assert scores[ranked[1]] - scores[ranked[0]] > 1e-3  # a clear winner
    assert int(two.import_index_[1]) == ranked[0]
    # the refit over both coefficients only lowers H below the winner's conditional minimum
    assert two.loss_history_[2] <= scores[ranked[0]] + 1e-9


# ----------------------------------------------------------------------------------- SVGP


def _svgp(kernel: str = "rbf", seed: int = 0) -> tuple[SVGPRegressor, torch.Tensor, torch.Tensor]:
    """A trained sparse GP (N = 60, M = 12, D_in = 2, C = 3, ARD) in float64."""
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(60, 2, generator=g, dtype=F64) * 4 - 2
    f = torch.stack([torch.sin(2 * x[:, 0]), x[:, 0] * x[:, 1], torch.cos(x[:, 1])], -1)
    y = f + 0.05 * torch.randn(60, 3, generator=g, dtype=F64)
    cfg = SVGPCfg(num_inducing=12, kernel=kernel, ard=True, noisy_input="simple", max_steps=25)
    reg = SVGPRegressor.from_data(cfg, x, y)
    reg.fit(x, y)
    return reg, x, y


def _rbf_gram(reg: SVGPRegressor, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The regressor's ARD RBF kernel in numpy on normalised inputs (its hyperparameters)."""
    ls = reg.model.covar_module.base_kernel.lengthscale.detach().numpy().reshape(-1)
    os_ = float(reg.model.covar_module.outputscale.detach())
    return os_ * np.exp(-0.5 * cdist(a / ls, b / ls, "sqeuclidean"))


def test_sparse_prediction_equals_titsias_closed_form() -> None:
    """M = 12 < N = 60 inducing inputs, heteroscedastic training noise ``floor + e_i``:
    ``Sigma = (K_ZZ + K_ZX Lam^-1 K_XZ)^-1``, mean ``K_*Z Sigma K_ZX Lam^-1 y``, variance
    ``k_** - K_*Z (K_ZZ^-1 - Sigma) K_Z* + floor + mean(e)`` (the test input's noise term),
    unwhitened, with the same jitter on K_ZZ. Float64 throughout: rtol 1e-7 for the
    different factorisations (K_ZZ's condition number is about 3e3 here; without the jitter
    the reference moves by about 5e-5)."""
    reg, x, y = _svgp()
    extra = torch.linspace(0.0, 0.05, 60, dtype=F64)
    reg.finalise(x, y, extra)
    xs = torch.rand(25, 2, generator=torch.Generator().manual_seed(9), dtype=F64) * 5 - 2.5
    mean, var = reg.predict(xs)

    xm, xsd = reg.x_mean.numpy(), reg.x_std.numpy()
    ym, ysd = reg.y_mean.numpy(), reg.y_std.numpy()
    xn, xsn = (x.numpy() - xm) / xsd, (xs.numpy() - xm) / xsd
    yn = (y.numpy() - ym) / ysd
    z = reg.model.variational_strategy.inducing_points.detach().numpy()
    floor = float(reg.likelihood.floor.detach())
    lam = floor + extra.numpy()
    kzz = _rbf_gram(reg, z, z) + reg.jitter * np.eye(12)
    kzx, ksz = _rbf_gram(reg, z, xn), _rbf_gram(reg, xsn, z)
    sigma = np.linalg.inv(kzz + (kzx / lam) @ kzx.T)
    m_ref = ksz @ sigma @ (kzx / lam) @ yn
    os_ = float(reg.model.covar_module.outputscale.detach())
    v_f = os_ - np.einsum("bi,ij,bj->b", ksz, np.linalg.inv(kzz) - sigma, ksz)
    v_ref = (v_f + floor + extra.numpy().mean())[:, None] * ysd**2
    np.testing.assert_allclose(mean.numpy(), m_ref * ysd + ym, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(var.numpy(), v_ref, rtol=1e-7, atol=1e-12)
    # GPyTorch's own variational strategy gives the same, except that it adds its jitter to
    # the prior variance k_** as well
    m2, v2 = reg.predict_gpytorch(xs)
    np.testing.assert_allclose(m2.numpy(), m_ref * ysd + ym, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(v2.numpy(), v_ref + reg.jitter * ysd**2, rtol=1e-7, atol=1e-12)


def test_collapsed_bound_with_fewer_inducing_inputs_equals_its_formula() -> None:
    """Titsias's bound for M = 12 < N = 60 with heteroscedastic noise, summed over C = 3
    channels, per datum and channel: ``-(sum_c log N(y_c | 0, Q + Lam) - C tr(Lam^-1 (K -
    Q)) / 2) / (N C)`` with ``Q = K_XZ (K_ZZ + jitter)^-1 K_ZX``. rtol 1e-7: the bound adds
    1e-8 to ``I + Psi Psi^T`` before factorising it, which moves it by about 1e-8 relative
    (1e-14 with that jitter put into the reference as well)."""
    reg, x, y = _svgp(seed=1)
    xn, yn = reg.normalise_x(x), reg.normalise_y(y)
    extra = torch.linspace(0.01, 0.08, 60, dtype=F64)
    with torch.no_grad():
        loss = float(reg.elbo_loss(xn, yn, extra, 60))
    z = reg.model.variational_strategy.inducing_points.detach().numpy()
    kzz = _rbf_gram(reg, z, z) + reg.jitter * np.eye(12)
    kzx = _rbf_gram(reg, z, xn.numpy())
    q = kzx.T @ np.linalg.solve(kzz, kzx)
    lam = float(reg.likelihood.floor.detach()) + extra.numpy()
    os_ = float(reg.model.covar_module.outputscale.detach())
    logp = sum(
        stats.multivariate_normal(np.zeros(60), q + np.diag(lam)).logpdf(yn[:, c].numpy())
        for c in range(3)
    )
    trace = ((os_ - np.diag(q)) / lam).sum()
    want = -(logp - 3 * 0.5 * trace) / (60 * 3)
    assert loss == pytest.approx(want, rel=1e-7)


def _fd_grad_sq(reg: SVGPRegressor, x: torch.Tensor, a_map: torch.Tensor | None) -> np.ndarray:
    """``sum_c ||A^T d g_c / d x||^2`` of the normalised predictive means by central
    differences of :meth:`SVGPRegressor.predict` (step 1e-5 of the raw inputs)."""
    h = 1e-5
    n, d = x.shape
    grads = np.zeros((n, reg.num_channels, d))
    for k in range(d):
        step = torch.zeros(d, dtype=F64)
        step[k] = h
        up = (reg.predict(x + step)[0] - reg.y_mean) / reg.y_std
        down = (reg.predict(x - step)[0] - reg.y_mean) / reg.y_std
        grads[:, :, k] = ((up - down) / (2 * h)).numpy()
    if a_map is not None:
        grads = grads @ a_map.numpy()
    return (grads**2).sum(axis=(1, 2))


@pytest.mark.parametrize("kernel", ["rbf", "matern"])
def test_nigp_gradient_term_equals_finite_differences(kernel: str) -> None:
    """``mean_grad_sq`` (closed form for rbf, autograd for matern) and the NIGP noise
    ``e_i = sigma^2 sum_c ||A^T grad g_c||^2 / C`` against central differences of the
    predictive mean, with and without an input map A. Central differences of step 1e-5 are
    good to about 1e-9 relative here (truncation h^2 g''' and rounding eps / h): rtol 1e-6."""
    reg, _, _ = _svgp(kernel, seed=2)
    xs = torch.rand(10, 2, generator=torch.Generator().manual_seed(3), dtype=F64) * 3 - 1.5
    a_map = torch.tensor([[1.0, 0.5, 0.0], [-0.3, 1.0, 2.0]], dtype=F64)  # (D_in, D_src)
    for amap in (None, a_map):
        want = _fd_grad_sq(reg, xs, amap)
        np.testing.assert_allclose(
            reg.mean_grad_sq(xs, noise_map=amap).numpy(), want, rtol=1e-6, atol=0
        )
    nigp = SVGPRegressor.from_checkpoint(
        {**reg.to_checkpoint(), "cfg": {**reg.to_checkpoint()["cfg"], "noisy_input": "nigp"}}
    )
    sigma = nigp.cfg.input_noise_sigma
    np.testing.assert_allclose(
        nigp.extra_train_noise(xs, a_map).numpy(),
        sigma**2 * _fd_grad_sq(reg, xs, a_map) / 3,
        rtol=1e-6,
    )


# ----------------------------------------------------------------------- forecast mixtures


def test_mixture_mean_and_moment_matched_variance_equal_monte_carlo() -> None:
    """Samples of the mixture (an action drawn by its weight, then the Gaussian of that
    action) against ``Forecast.expected_mean`` and the moment-matched variance inside
    ``window_metrics``' regression accuracy (one frame, one joint: the accuracy is then the
    product of the three variances times dt). Tolerances: 5 standard errors of the sample
    mean; 3 % for the product of three sample variances (each about 0.4 % standard error
    with 400 000 samples of these mixtures)."""
    rng = np.random.default_rng(0)
    w = np.array([[0.6, 0.3, 0.1]])
    mean = rng.normal(size=(1, 3, 1, 1, 3)) * 0.2
    var = rng.uniform(0.005, 0.03, size=(1, 3, 1, 1, 3))
    fc = Forecast(
        weights=torch.from_numpy(w),
        mean=torch.from_numpy(mean),
        var=torch.from_numpy(var),
        dt=0.1,
        joint_names=("hand",),
        action_names=("a", "b", "c"),
    )
    n = 400_000
    a = rng.choice(3, size=n, p=w[0])
    samples = mean[0, a, 0, 0] + np.sqrt(var[0, a, 0, 0]) * rng.standard_normal((n, 3))
    m_mc, se = samples.mean(0), samples.std(0) / math.sqrt(n)
    got = fc.expected_mean()[0, 0, 0].numpy()
    assert np.all(np.abs(got - m_mc) <= 5 * se), (got, m_mc, se)
    truth = torch.zeros(1, 1, 1, 3, dtype=F64)
    acc = window_metrics(fc, truth, torch.zeros(1, dtype=torch.int64), truth[:, 0])
    want = float(np.prod(samples.var(0)) * 0.1)
    assert float(acc["reg_accuracy"][0]) == pytest.approx(want, rel=0.03)


# ----------------------------------------------------------------------- next-action model


def test_next_action_probabilities_equal_plain_counting() -> None:
    """Random (progress, current, next) tuples, A = 5: the model's ``p(n | p, c)`` of every
    seen pair and ``p(n | p)`` of every seen progress state against counts kept in Python
    Counters, smoothed on the allowed actions as eq. next_action and the module say.
    Exact up to float64 division: rtol 1e-12."""
    rng = np.random.default_rng(4)
    a_n, n, smoothing = 5, 400, 0.5
    p = rng.choice([0, 0b00010, 0b00110, 0b10110], size=n)
    c = rng.integers(0, a_n, n)
    nx = (c + rng.integers(1, a_n, n)) % a_n  # never the current action
    nx[rng.random(n) < 0.1] = -1  # unknown next action: not counted
    model = NextActionModel().fit(
        torch.from_numpy(p), torch.from_numpy(c), torch.from_numpy(nx), num_actions=a_n,
        smoothing=smoothing,
    )  # fmt: skip
    pair_counts: dict[tuple[int, int], Counter] = {}
    state_counts: dict[int, Counter] = {}
    for pp, cc, nn in zip(p.tolist(), c.tolist(), nx.tolist()):
        if nn < 0:
            continue
        pair_counts.setdefault((pp, cc), Counter())[nn] += 1
        state_counts.setdefault(pp, Counter())[nn] += 1
    for (pp, cc), cnt in pair_counts.items():
        allowed = [k != cc and not (pp >> k) & 1 for k in range(a_n)]
        raw = [cnt[k] + smoothing * allowed[k] for k in range(a_n)]
        want = np.array(raw) / sum(raw)
        np.testing.assert_allclose(model.next_action_prob(pp, cc).numpy(), want, rtol=1e-12)
    states = sorted(state_counts)
    got = model.prob_given_progress(torch.tensor(states)).numpy()
    for row, pp in enumerate(states):
        raw = [state_counts[pp][k] + smoothing * (not (pp >> k) & 1) for k in range(a_n)]
        np.testing.assert_allclose(got[row], np.array(raw) / sum(raw), rtol=1e-12)
