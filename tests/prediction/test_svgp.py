"""Sparse variational GP with the noisy-input correction (eq. GPRlearning, sec. 6.1)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from iplanner_torch.errors import ConfigError, ShapeError
from iplanner_torch.prediction.svgp import SVGPCfg, SVGPRegressor


@pytest.fixture(autouse=True)
def _one_thread():
    """One intra-op thread: these small problems run fastest (and fairest) that way."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


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
    assert 0.85 <= float(inside) <= 1.0


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
    ls, os_ = float(kern.base_kernel.lengthscale), float(kern.outputscale)
    floor = float(reg.likelihood.floor)
    for c in range(2):
        ys = reg.y_std[c]
        extra = cfg.simple_extra_var / ys**2 if noisy_input == "simple" else 0.0
        noise = torch.full((x.shape[0],), floor + float(extra), dtype=torch.float64)
        m_ref, v_ref = _exact_gp(
            reg.normalise_x(x),
            reg.normalise_y(y)[:, c : c + 1],
            reg.normalise_x(xs),
            ls,
            os_,
            noise,
        )
        m_ref = m_ref[:, 0] * ys + reg.y_mean[c]
        test_extra = cfg.simple_extra_var if noisy_input == "simple" else 0.0
        v_ref = (v_ref + floor) * ys**2 + test_extra
        torch.testing.assert_close(mean[:, c], m_ref, atol=2e-4, rtol=1e-3)
        torch.testing.assert_close(var[:, c], v_ref, atol=2e-5, rtol=1e-2)


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
    term = 0.02**2 * (1 + 2.0**2)
    diff = out["simple"] - out["none"]
    # the test-point term is added exactly; the larger training noise also widens the latent
    # posterior slightly, so the increase is at least the term and not much more
    assert bool((diff >= term * 0.999).all())
    assert float(diff.median()) < 3 * term


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
    extra = reg.nigp_extra_noise(x[interior])  # (n, 1) [output units^2]
    expected = 0.03**2 * a**2
    rel = (extra / expected - 1).abs()
    assert float(rel.median()) < 0.05
    assert float(rel.max()) < 0.25
    torch.testing.assert_close(
        reg.extra_test_var, torch.tensor([expected], dtype=torch.float64), rtol=0.25, atol=0.0
    )


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


def test_runs_on_device(device: torch.device) -> None:
    x, y, _ = _toy(50, 8)
    x, y = x.to(device), y.to(device)
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=10, epochs=2), x, y)
    reg.fit(x, y)
    mean, var = reg.predict(x[:5])
    assert mean.device.type == device.type and bool((var > 0).all())


def test_time_series_kernel_gak() -> None:
    dtw = pytest.importorskip("iplanner_torch.prediction.dtw")
    assert hasattr(dtw, "GlobalAlignmentKernel")
    g = torch.Generator().manual_seed(9)
    w = torch.randn(60, 5, 3, generator=g).cumsum(1) * 0.1  # (N, n_p, D) windows
    y = w[:, -1, :] + 0.1 * (w[:, -1, :] - w[:, -2, :])
    cfg = SVGPCfg(num_inducing=20, kernel="gak", noisy_input="simple", epochs=3)
    reg = SVGPRegressor.from_data(cfg, w.reshape(60, -1), y, window=(5, 3))
    reg.fit(w.reshape(60, -1), y)
    m1, v1 = reg.predict(w[:8].reshape(8, -1))
    m2, v2 = reg.predict_gpytorch(w[:8].reshape(8, -1))
    torch.testing.assert_close(m1, m2, atol=1e-4, rtol=1e-3)
    assert bool((v1 > 0).all())


def test_errors() -> None:
    with pytest.raises(ConfigError, match="num_inducing"):
        SVGPCfg(num_inducing=0)
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
