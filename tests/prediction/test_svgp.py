"""Sparse variational GP with the noisy-input correction (eq. GPRlearning, sec. 6.1)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from iplanner_torch.errors import CheckpointError, ConfigError, ShapeError
from iplanner_torch.prediction.svgp import SVGPBank, SVGPCfg, SVGPRegressor
from iplanner_torch.prediction.training import TrainerCfg, train_svgp

pytestmark = pytest.mark.usefixtures("one_thread")


def _toy(n: int, seed: int, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(n, 1, generator=g, dtype=dtype) * 6 - 3
    f = torch.cat([torch.sin(1.5 * x), 0.3 * x**2], -1)  # (n, 2)
    y = f + 0.05 * torch.randn(n, 2, generator=g, dtype=dtype)
    return x, y, f


def _exact_gp(x, y, xs, lengthscale, outputscale, noise):
    """Closed-form GP posterior (RBF kernel), the independent reference."""

    def k(a, b):
        return outputscale * torch.exp(-0.5 * torch.cdist(a, b).pow(2) / lengthscale**2)

    kxx = k(x, x) + torch.diag(noise)
    ksx = k(xs, x)
    sol = torch.linalg.solve(kxx, y)
    mean = ksx @ sol
    var = outputscale - (ksx * torch.linalg.solve(kxx, ksx.T).T).sum(-1)
    return mean, var


def test_learns_known_function_with_calibrated_intervals() -> None:
    x, y, _ = _toy(300, 0)
    cfg = SVGPCfg(
        num_inducing=30, noisy_input="none", epochs=100, max_steps=120, lr=0.05, batch_size=128
    )
    reg = SVGPRegressor.from_data(cfg, x, y)
    reg.fit(x, y)
    xt, yt, ft = _toy(400, 1)
    xt = xt.clamp(-2.8, 2.8)
    ft = torch.cat([torch.sin(1.5 * xt), 0.3 * xt**2], -1)
    yt = ft + 0.05 * torch.randn_like(ft)
    mean, var = reg.predict(xt)
    rmse = float((mean - ft).pow(2).mean().sqrt())
    assert rmse < 0.04
    inside = ((mean - yt).abs() <= 1.96 * var.sqrt()).float().mean()
    # 95 % intervals hold about 95 % of 800 noisy values (binomial sd 0.8 %): neither too
    # narrow nor too wide; their width is the noise's (0.05) plus a little posterior
    assert 0.92 <= float(inside) <= 0.985
    assert 0.05 <= float(var.mean().sqrt()) <= 0.06


def test_every_parameter_gets_a_gradient() -> None:
    x, y, _ = _toy(64, 2)
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=8, noisy_input="simple"), x, y)
    extra = reg.extra_train_noise(x)
    loss = reg.elbo_loss(reg.normalise_x(x), reg.normalise_y(y), extra, x.shape[0])
    loss.backward()
    for name, p in reg.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name


@pytest.mark.parametrize("noisy_input", ["none", "simple"])
def test_full_rank_svgp_equals_exact_gp(noisy_input: str) -> None:
    x, y, _ = _toy(40, 3, torch.float64)
    cfg = SVGPCfg(
        num_inducing=40,
        noisy_input=noisy_input,
        learn_inducing=False,
        epochs=0,
        input_noise_sigma=0.05,
        velocity_limit=1.5,
    )
    reg = SVGPRegressor.from_data(cfg, x, y)
    reg.set_inducing(reg.normalise_x(x))
    reg.fit(x, y)  # epochs = 0: q(v) set to its optimum for the fixed hyperparameters
    xs = torch.linspace(-3.5, 3.5, 30, dtype=torch.float64).unsqueeze(-1)
    mean, var = reg.predict(xs)
    kern = reg.model.covar_module
    ls, os_ = float(kern.base_kernel.lengthscale.detach()), float(kern.outputscale.detach())
    floor = float(reg.likelihood.floor.detach())
    # the paper's term over the mean output variance, shared by the channels (normalised)
    extra = cfg.simple_extra_var / float(reg.y_std.pow(2).mean()) if noisy_input == "simple" else 0
    noise = torch.full((x.shape[0],), floor + extra, dtype=torch.float64)
    for c in range(2):
        ys = reg.y_std[c]
        m_ref, v_ref = _exact_gp(
            reg.normalise_x(x),
            reg.normalise_y(y)[:, c : c + 1],
            reg.normalise_x(xs),
            ls,
            os_,
            noise,
        )
        m_ref = m_ref[:, 0] * ys + reg.y_mean[c]
        v_ref = (v_ref + floor + extra) * ys**2
        torch.testing.assert_close(mean[:, c], m_ref, atol=2e-4, rtol=1e-3)
        torch.testing.assert_close(var[:, c], v_ref, atol=2e-5, rtol=1e-2)


def test_collapsed_bound_with_z_equal_x_is_the_exact_marginal_likelihood() -> None:
    x, y, _ = _toy(30, 10, torch.float64)
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=30, noisy_input="none"), x, y)
    reg.set_inducing(reg.normalise_x(x))
    xn, yn = reg.normalise_x(x), reg.normalise_y(y)
    extra = torch.linspace(0.0, 0.05, 30, dtype=torch.float64)  # heteroscedastic noise
    with torch.no_grad():
        loss = float(reg.elbo_loss(xn, yn, extra, 30))
        kern = reg.model.covar_module
        k = kern(xn).to_dense() + reg.jitter * torch.eye(30, dtype=torch.float64)
        cov = k + torch.diag(reg.likelihood.floor + extra)
        dist = torch.distributions.MultivariateNormal(torch.zeros(30, dtype=torch.float64), cov)
        exact = float(sum(dist.log_prob(yn[:, c]) for c in range(2)))
    # Titsias's bound is tight when Z = X (up to the jitter on K_ZZ)
    assert math.isclose(-loss * 60, exact, rel_tol=2e-3, abs_tol=1e-2)


def test_simple_correction_adds_paper_term_to_predictive_variance() -> None:
    x, y, _ = _toy(60, 4, torch.float64)
    out = {}
    for ni in ("none", "simple"):
        cfg = SVGPCfg(
            num_inducing=20, noisy_input=ni, epochs=0, input_noise_sigma=0.02, velocity_limit=2.0
        )
        reg = SVGPRegressor.from_data(cfg, x, y)
        reg.fit(x, y)
        out[ni] = reg.predict(x)[1]
    # channel c gets sigma^2 (1 + v^2) std_c^2 / mean(std^2) [m^2]: the paper's term on average
    term = 0.02**2 * (1 + 2.0**2) * reg.y_std.pow(2) / reg.y_std.pow(2).mean()
    diff = out["simple"] - out["none"]
    # the test-point term is added exactly; the larger training noise also widens the latent
    # posterior slightly, so the increase is at least the term and not much more
    assert bool((diff >= term * 0.999).all())
    assert bool((diff.median(0).values < 3 * term).all())
    torch.testing.assert_close(diff.mean(0).mean(), (term.mean()).expand(()), rtol=0.5, atol=0)


def test_nigp_noise_of_linear_function_is_sigma2_a2() -> None:
    g = torch.Generator().manual_seed(5)
    a = 2.5
    x = torch.rand(200, 1, generator=g, dtype=torch.float64) * 4 - 2
    y = a * x + 0.01 * torch.randn(200, 1, generator=g, dtype=torch.float64)
    cfg = SVGPCfg(
        num_inducing=30,
        noisy_input="nigp",
        input_noise_sigma=0.03,
        epochs=100,
        max_steps=80,
        lr=0.05,
        nigp_iterations=1,
    )
    reg = SVGPRegressor.from_data(cfg, x, y)
    reg.fit(x, y)
    interior = x[:, 0].abs() < 1.5
    ys2 = reg.y_std[0] ** 2
    extra = reg.extra_train_noise(x[interior]) * ys2  # (n,) [output units^2]
    expected = 0.03**2 * a**2
    rel = (extra / expected - 1).abs()
    assert float(rel.median()) < 0.05
    assert float(rel.max()) < 0.25
    assert math.isclose(float(reg.test_extra_noise * ys2), expected, rel_tol=0.25)


def test_each_training_round_draws_minibatches_of_its_own() -> None:
    """The noisy-input refits (rounds 1, ...) do not replay round 0's minibatches, and the
    first minibatches are not the subset that set the bandwidth and the inducing points
    (one stream each): with 60 points in batches of 16, ``fit`` asks for rounds 0 and 1 and
    gets different subsets; the same round gives the same subsets again."""
    x, y, _ = _toy(60, 9)
    cfg = SVGPCfg(num_inducing=8, noisy_input="nigp", nigp_iterations=1, batch_size=16,
                  epochs=1, max_steps=4, nigp_refit_steps=4, seed=2)  # fmt: skip
    reg = SVGPRegressor.from_data(cfg, x, y)
    asked: list[tuple[int, list[torch.Tensor]]] = []
    draw = reg.batch_indices

    def recording(n, steps, device, round_index=0):
        out = draw(n, steps, device, round_index)
        asked.append((round_index, out))
        return out

    reg.batch_indices = recording  # type: ignore[method-assign]
    reg.fit(x, y)
    assert [r for r, _ in asked] == [0, 1]
    (_, first), (_, second) = asked
    assert all(len(b) == 16 and len(set(b.tolist())) == 16 for b in first + second)
    assert not any(torch.equal(a, b) for a, b in zip(first, second))
    assert all(torch.equal(a, b) for a, b in zip(first, draw(60, 4, torch.device("cpu"), 0)))
    # from_data's stream: a permutation of the 60 points for the bandwidth, one for the
    # inducing points; no minibatch is the start of either
    g = torch.Generator().manual_seed(cfg.seed)
    used = [torch.randperm(60, generator=g)[:16] for _ in range(2)]
    assert not any(torch.equal(a, b) for a in first + second for b in used)


def test_lightning_rounds_draw_minibatches_of_their_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The Lightning path (``train_svgp``, what ``iplanner-train`` runs) asks each round for
    its own minibatches, as ``fit`` does."""
    x, y, _ = _toy(60, 9)
    cfg = SVGPCfg(num_inducing=8, noisy_input="nigp", nigp_iterations=2, batch_size=16,
                  epochs=1, max_steps=4, nigp_refit_steps=2, seed=2)  # fmt: skip
    rounds: list[int] = []
    draw = SVGPRegressor.batch_indices

    def recording(self, n, steps, device, round_index=0):
        rounds.append(round_index)
        return draw(self, n, steps, device, round_index)

    monkeypatch.setattr(SVGPRegressor, "batch_indices", recording)
    tcfg = TrainerCfg(accelerator="cpu", tensorboard=False)
    train_svgp(x, y, cfg=cfg, tcfg=tcfg, out_dir=tmp_path, name="g", progress=False)
    assert rounds == [0, 1, 2]


def test_nigp_closed_form_gradient_matches_autograd() -> None:
    g = torch.Generator().manual_seed(11)
    x = torch.randn(80, 5, generator=g, dtype=torch.float64) * torch.tensor(
        [1.0, 2.0, 0.5, 3.0, 1.0], dtype=torch.float64
    )
    y = torch.cat([x[:, :2].sum(-1, keepdim=True).sin(), x[:, 2:].pow(2)], -1)  # (80, 4)
    reg = SVGPRegressor.from_data(
        SVGPCfg(num_inducing=15, noisy_input="none", ard=True, max_steps=20), x, y
    )
    reg.fit(x, y)
    xs = torch.randn(12, 5, generator=g, dtype=torch.float64)
    closed = reg.mean_grad_sq(xs)
    reg.refresh_cache()
    torch.testing.assert_close(
        closed, reg._mean_grad_sq_autograd(xs, 8, None), rtol=1e-8, atol=1e-10
    )
    a_map = torch.randn(5, 3, generator=g, dtype=torch.float64)  # (D_in, D_src)
    torch.testing.assert_close(
        reg.mean_grad_sq(xs, noise_map=a_map),
        reg._mean_grad_sq_autograd(xs, 8, a_map),
        rtol=1e-8,
        atol=1e-10,
    )
    eye = torch.eye(5, dtype=torch.float64)
    torch.testing.assert_close(reg.mean_grad_sq(xs, noise_map=eye), closed, rtol=1e-10, atol=0)
    with pytest.raises(ShapeError, match="noise_map"):
        reg.mean_grad_sq(xs, noise_map=a_map.T)


def test_nigp_noise_map_carries_correlated_input_noise() -> None:
    """Inputs x = A s of sources s with independent noise sigma: a linear function w . x gets
    output noise sigma^2 ||A^T w||^2 (here 7.25 sigma^2), not sigma^2 ||w||^2 (3.25 sigma^2)
    as if every input column were noisy on its own."""
    g = torch.Generator().manual_seed(6)
    a_map = torch.tensor([[1.0, 0.0], [1.0, -1.0]], dtype=torch.float64)  # x1 = s1, x2 = s1 - s2
    src = torch.rand(300, 2, generator=g, dtype=torch.float64) * 4 - 2
    x = src @ a_map.T  # (N, 2)
    w = torch.tensor([1.5, 1.0], dtype=torch.float64)
    y = (x @ w).unsqueeze(-1) + 0.01 * torch.randn(300, 1, generator=g, dtype=torch.float64)
    cfg = SVGPCfg(
        num_inducing=30, noisy_input="nigp", input_noise_sigma=0.03, max_steps=80, epochs=100
    )
    reg = SVGPRegressor.from_data(cfg, x, y)
    reg.fit(x, y, noise_map=a_map)
    interior = (src.abs() < 1.5).all(-1)
    ys2 = reg.y_std[0] ** 2
    extra = reg.extra_train_noise(x[interior], a_map) * ys2  # (n,) [output units^2]
    expected = 0.03**2 * float((a_map.T @ w).pow(2).sum())  # 7.25 sigma^2
    rel = (extra / expected - 1).abs()
    assert float(rel.median()) < 0.05
    alone = reg.extra_train_noise(x[interior]) * ys2  # the identity map
    assert float((alone / (0.03**2 * float(w.pow(2).sum())) - 1).abs().median()) < 0.05


@pytest.mark.parametrize("kernel", ["gak", "dtw"])
def test_nigp_is_refused_for_the_time_series_kernels(kernel: str) -> None:
    with pytest.raises(ConfigError, match=f"noisy_input nigp needs .* kernel {kernel}"):
        SVGPCfg(kernel=kernel, noisy_input="nigp")


def test_calibration_raises_floor_to_the_validation_noise() -> None:
    g = torch.Generator().manual_seed(12)
    x = torch.rand(300, 1, generator=g) * 6 - 3
    y = torch.sin(1.5 * x) + 0.01 * torch.randn(300, 1, generator=g)
    xv = torch.rand(400, 1, generator=g) * 5 - 2.5
    yv = torch.sin(1.5 * xv) + 0.1 * torch.randn(400, 1, generator=g)  # 10x noisier
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=30, noisy_input="none"), x, y)
    reg.fit(x, y)
    before = float(reg.likelihood.floor.detach())
    reg.calibrate(xv, yv, x, y, reg.extra_train_noise(x))
    _, var = reg.predict(xv)
    assert float(reg.likelihood.floor.detach()) > 5 * before
    # the predictive variance now matches the validation noise (0.1^2)
    assert 0.7 * 0.01 < float(var.mean()) < 1.4 * 0.01
    again = reg.calibrate(x, y, x, y, reg.extra_train_noise(x))  # never lowered
    assert again == pytest.approx(float(reg.likelihood.floor.detach()))


def test_bank_equals_each_regressor() -> None:
    g = torch.Generator().manual_seed(13)
    regs = []
    for i, (n, m, kernel) in enumerate([(40, 12, "rbf"), (25, 25, "rbf"), (60, 8, "rbf")]):
        x = torch.randn(n, 3, generator=g) * (1 + i)
        y = torch.cat([x.sin(), x.cos()], -1)  # (n, 6)
        reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=m, kernel=kernel, max_steps=5), x, y)
        reg.fit(x, y)
        regs.append(reg)
    bank = SVGPBank([regs[0], regs[1], regs[2], regs[0]])
    xs = torch.randn(7, 3, generator=g)
    mean, var = bank.predict(xs, chunk=3)
    assert mean.shape == (7, 4, 6)
    for i, reg in enumerate([regs[0], regs[1], regs[2], regs[0]]):
        m1, v1 = reg.predict(xs)
        torch.testing.assert_close(mean[:, i], m1, atol=1e-5, rtol=1e-4)
        torch.testing.assert_close(var[:, i], v1, atol=1e-6, rtol=1e-4)
    x = torch.randn(30, 3, generator=g)
    mat = SVGPRegressor.from_data(SVGPCfg(num_inducing=10, kernel="matern", max_steps=3), x, x)
    mat.fit(x, x)
    m2, v2 = SVGPBank([mat]).predict(xs)
    torch.testing.assert_close(m2[:, 0], mat.predict(xs)[0], atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(v2[:, 0], mat.predict(xs)[1], atol=1e-6, rtol=1e-4)
    with pytest.raises(ConfigError, match="one of rbf or matern"):
        SVGPBank([regs[0], mat])
    narrow = SVGPRegressor.from_data(SVGPCfg(num_inducing=5, epochs=0), x, x)
    narrow.fit(x, x)
    with pytest.raises(ConfigError, match="equal input_dim and num_channels"):
        SVGPBank([regs[0], narrow])
    with pytest.raises(ConfigError, match="at least one"):
        SVGPBank([])


def test_fast_path_matches_gpytorch_prediction() -> None:
    g = torch.Generator().manual_seed(6)
    x = torch.randn(150, 4, generator=g)
    y = torch.cat([x.sum(-1, keepdim=True).sin(), x[:, :2].prod(-1, keepdim=True), x[:, 3:]], -1)
    for ni in ("simple", "nigp"):
        cfg = SVGPCfg(
            num_inducing=25, noisy_input=ni, epochs=5, max_steps=30, nigp_iterations=1, ard=True
        )
        reg = SVGPRegressor.from_data(cfg, x, y)
        reg.fit(x, y)
        xs = torch.randn(40, 4, generator=g)
        m1, v1 = reg.predict(xs)
        m2, v2 = reg.predict_gpytorch(xs)
        torch.testing.assert_close(m1, m2, atol=1e-4, rtol=1e-3)
        torch.testing.assert_close(v1, v2, atol=1e-4, rtol=2e-3)


def test_same_seed_same_numbers_and_checkpoint_roundtrip() -> None:
    x, y, _ = _toy(80, 7)
    cfg = SVGPCfg(num_inducing=10, epochs=3, seed=3)
    r1 = SVGPRegressor.from_data(cfg, x, y)
    r1.fit(x, y)
    r2 = SVGPRegressor.from_data(cfg, x, y)
    r2.fit(x, y)
    xs = torch.linspace(-2, 2, 7).unsqueeze(-1)
    torch.testing.assert_close(r1.predict(xs), r2.predict(xs), rtol=0, atol=0)
    r3 = SVGPRegressor.from_checkpoint(r1.to_checkpoint())
    torch.testing.assert_close(r3.predict(xs), r1.predict(xs))
    old = {**r1.to_checkpoint(), "format": 1}
    with pytest.raises(CheckpointError, match="retrain"):
        SVGPRegressor.from_checkpoint(old)


def test_runs_on_device(device: torch.device) -> None:
    x, y, _ = _toy(50, 8)
    x, y = x.to(device), y.to(device)
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=10, epochs=2), x, y)
    reg.fit(x, y)
    mean, var = reg.predict(x[:5])
    assert mean.device.type == device.type and bool((var > 0).all())


def _series_gram(a: torch.Tensor, b: torch.Tensor, kind: str, bandwidth: float) -> torch.Tensor:
    """(N1, T, D), (N2, T, D) -> (N1, N2): the DTW kernel exp(-DTW / gamma), or the
    normalised global alignment kernel, by textbook recursions one pair at a time."""

    def dp(x, y, local, combine, start):
        r = [
            [start if i == j == 0 else None for j in range(len(y) + 1)] for i in range(len(x) + 1)
        ]
        for i in range(1, len(x) + 1):
            for j in range(1, len(y) + 1):
                prev = [v for v in (r[i - 1][j], r[i][j - 1], r[i - 1][j - 1]) if v is not None]
                r[i][j] = local(x[i - 1], y[j - 1], combine(prev))
        return r[-1][-1]

    def dtw(x, y):
        return dp(x, y, lambda u, v, p: math.dist(u, v) + p, min, 0.0)

    def gak(x, y):
        def local(u, v, p):
            e = math.exp(-(math.dist(u, v) ** 2) / (2 * bandwidth**2))
            return e / (2.0 - e) * p

        return dp(x, y, local, sum, 1.0)

    a, b = a.tolist(), b.tolist()
    if kind == "dtw":
        return torch.tensor([[math.exp(-dtw(x, y) / bandwidth) for y in b] for x in a])
    return torch.tensor([[gak(x, y) / math.sqrt(gak(x, x) * gak(y, y)) for y in b] for x in a])


@pytest.mark.parametrize("kind", ["gak", "dtw"])
def test_full_rank_series_kernel_svgp_equals_exact_gp(kind: str) -> None:
    """With Z = X and q(v) at its optimum, the SVGP on a time-series kernel (its fast path
    and GPyTorch's) is the exact GP on that kernel's Gram, computed here pair by pair."""
    g = torch.Generator().manual_seed(9)
    n, t, d = 24, 4, 2
    w = torch.randn(n + 6, t, d, generator=g, dtype=torch.float64).cumsum(1) * 0.3
    y = torch.stack([w[:, -1, 0] + 0.5 * w[:, -1, 1], torch.sin(w[:, -1, 1])], -1)
    x = w.reshape(n + 6, -1)
    cfg = SVGPCfg(num_inducing=n, kernel=kind, noisy_input="none", learn_inducing=False, epochs=0)
    reg = SVGPRegressor.from_data(cfg, x[:n], y[:n], window=(t, d))
    reg.set_inducing(reg.normalise_x(x[:n]))
    reg.fit(x[:n], y[:n])
    mean, var = reg.predict(x[n:])
    m2, v2 = reg.predict_gpytorch(x[n:])
    kern = reg.model.covar_module
    os_, floor = float(kern.outputscale.detach()), float(reg.likelihood.floor.detach())
    xn = reg.normalise_x(x).reshape(n + 6, t, d)
    bandwidth = reg.bandwidth
    k_xx = os_ * _series_gram(xn[:n], xn[:n], kind, bandwidth).double()
    k_sx = os_ * _series_gram(xn[n:], xn[:n], kind, bandwidth).double()
    k_xx = k_xx + floor * torch.eye(n, dtype=torch.float64)
    m_ref = k_sx @ torch.linalg.solve(k_xx, reg.normalise_y(y[:n]))
    v_ref = os_ - (k_sx * torch.linalg.solve(k_xx, k_sx.T).T).sum(-1) + floor
    m_ref = m_ref * reg.y_std + reg.y_mean
    v_ref = v_ref.unsqueeze(-1) * reg.y_std**2
    torch.testing.assert_close(mean, m_ref, atol=2e-4, rtol=1e-3)
    torch.testing.assert_close(var, v_ref, atol=2e-5, rtol=1e-2)
    torch.testing.assert_close(m2, m_ref, atol=2e-4, rtol=1e-3)
    torch.testing.assert_close(v2, v_ref, atol=2e-5, rtol=1e-2)


def test_errors() -> None:
    with pytest.raises(ConfigError, match="num_inducing"):
        SVGPCfg(num_inducing=0)
    with pytest.raises(ConfigError, match=r"num_inducing <= 8192 \(MAX_INDUCING\), got 100000"):
        SVGPCfg(num_inducing=100_000)
    assert SVGPCfg(num_inducing=8192).num_inducing == 8192
    with pytest.raises(ConfigError, match="noisy_input"):
        SVGPCfg(noisy_input="bogus")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="kernel"):
        replace(SVGPCfg(), kernel="poly")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="window"):
        SVGPRegressor(SVGPCfg(kernel="gak"), input_dim=6, num_channels=2, num_inducing=3)
    x, y, _ = _toy(20, 0)
    with pytest.raises(ShapeError, match=r"expected y \(20, C\)"):
        SVGPRegressor.from_data(SVGPCfg(), x, y[:5])
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=5, epochs=1), x, y)
    with pytest.raises(ShapeError, match=r"expected x \(B, 1\), got \(3, 2\)"):
        reg.predict(torch.zeros(3, 2))
    assert math.isclose(SVGPCfg(input_noise_sigma=0.1, velocity_limit=1.0).simple_extra_var, 0.02)
    with pytest.raises(ConfigError, match="batch_size"):
        SVGPCfg(batch_size=1)
    with pytest.raises(ConfigError, match="nigp_refit_steps"):
        SVGPCfg(nigp_refit_steps=-1)


def test_inputs_of_another_dtype_are_refused() -> None:
    x, y, _ = _toy(40, 3)  # float32
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=8, max_steps=2), x, y)
    with pytest.raises(ShapeError, match=r"expected x torch.float32 \(the regressor's\)"):
        reg.predict(x.double())
    # the reference path and other devices: raw RuntimeErrors from deep inside GPyTorch
    with pytest.raises(ShapeError, match=r"expected x torch.float32 \(the regressor's\)"):
        reg.predict_gpytorch(x.double())
    with pytest.raises(ShapeError, match=r"expected x \(B, 1\)"):
        reg.predict_gpytorch(x[:, None])
    for predict in (reg.predict, reg.predict_gpytorch):
        with pytest.raises(ShapeError, match=r"expected x on cpu \(the regressor's\), got meta"):
            predict(x.to("meta"))
    with pytest.raises(ShapeError, match="expected y torch.float32"):
        reg.fit(x, y.double())
    with pytest.raises(ShapeError, match="one floating dtype"):
        SVGPRegressor.from_data(SVGPCfg(num_inducing=8), x, y.round().long())
    with pytest.raises(ShapeError, match="one floating dtype"):
        SVGPRegressor.from_data(SVGPCfg(num_inducing=8), x.round().long(), y.round().long())


def test_fast_path_tensors_on_a_given_thread_count() -> None:
    """The forecast's cached tensors come out of a Cholesky factor and a triangular solve
    whose last bits depend on torch's CPU thread count; ``refresh_cache(threads=1)`` computes
    them on one thread whatever the setting (the predictor's ``prepare`` does), so the same
    predictor loaded with two threads (``iplanner-experiment``) or one (a joblib sweep job)
    forecasts alike. M = 256: large enough that two threads split the factor's sums."""
    from iplanner_torch.types import torch_threads

    x, y, _ = _toy(300, 3, torch.float64)
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=256, noisy_input="none"), x, y)
    z = reg.model.variational_strategy.inducing_points.detach()
    kzz = reg.model.covar_module(z).to_dense().detach()
    factors = []
    for threads in (2, 1):
        with torch_threads(threads):
            factors.append(torch.linalg.cholesky(kzz + 1e-6 * torch.eye(256, dtype=kzz.dtype)))
    if torch.equal(*factors):  # one core, or a library that does not split this factor
        pytest.skip("this machine's Cholesky factor does not depend on the thread count")
    caches = []
    for threads in (2, 1):
        with torch_threads(threads):
            reg.refresh_cache(threads=1)
            assert torch.get_num_threads() == threads  # restored after
        caches.append({k: v.clone() for k, v in reg._cache.items()})
    for key, value in caches[0].items():
        assert torch.equal(value, caches[1][key]), key
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match="threads"):
            reg.refresh_cache(threads=bad)
