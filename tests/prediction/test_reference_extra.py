"""More prediction numerics against references computed here by other methods.

* ``SVGPRegressor.calibrate``: the floor against scipy's bounded scalar minimum of the
  documented negative validation log-likelihood ``sum_i (log(b_i + f) + r_i / (b_i + f)) / 2``
  (located first on a logarithmic grid), with ``r_i`` the channel mean of the squared
  normalised residuals and ``b_i`` the predictive variance without the floor.
* ``SVGPCfg.steps_for``: hand-computed step counts.
* ``HumanMotionPredictor``'s constant-velocity fallback: the extrapolation of exactly linear
  (and quadratic) motion and the documented variance, by hand.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy import optimize

from iplanner_torch.prediction.predictor import HumanMotionPredictor, PredictorCfg
from iplanner_torch.prediction.svgp import SVGPCfg, SVGPRegressor

pytestmark = pytest.mark.usefixtures("one_thread")

F64 = torch.float64


# ------------------------------------------------------------------------------ calibrate


def _toy(n: int, noise: float, gen: torch.Generator, span: float = 3.0):
    x = (torch.rand(n, 1, generator=gen, dtype=F64) * 2 - 1) * span
    f = torch.cat([torch.sin(1.5 * x), 0.3 * x], -1)  # (n, 2): channels of different spread
    return x, f + noise * torch.randn(n, 2, generator=gen, dtype=F64)


@pytest.fixture(scope="module")
def fitted() -> tuple[torch.Tensor, ...]:
    """Training data (noise 0.01) and validation data 8x noisier, float64."""
    gen = torch.Generator().manual_seed(5)
    x, y = _toy(120, 0.01, gen)
    xv, yv = _toy(80, 0.08, gen, span=2.5)
    return x, y, xv, yv


def _regressor(noisy_input: str, x: torch.Tensor, y: torch.Tensor) -> SVGPRegressor:
    cfg = SVGPCfg(num_inducing=15, noisy_input=noisy_input, epochs=20, max_steps=40)
    reg = SVGPRegressor.from_data(cfg, x, y)
    reg.fit(x, y)
    return reg


def _terms(reg: SVGPRegressor, xv: torch.Tensor, yv: torch.Tensor) -> tuple[np.ndarray, ...]:
    """(b_i, r_i) of the documented objective from the regressor's predictions: the
    normalised predictive variance less the floor, and the channel mean of the squared
    normalised residuals."""
    mean, var = reg.predict(xv)
    ys = reg.y_std
    floor = float(reg.likelihood.floor.detach())
    b = (var / ys**2).mean(-1) - floor
    r = ((yv - mean) / ys).pow(2).mean(-1)
    return b.numpy(), r.numpy()


def _neg_loglik(f: float, b: np.ndarray, r: np.ndarray) -> float:
    t = b + f
    return float(0.5 * np.sum(np.log(t) + r / t))


def _best_floor(b: np.ndarray, r: np.ndarray, lo: float) -> float:
    """The maximiser over ``f >= lo`` of the validation log-likelihood: the best point of a
    logarithmic grid up to ``1e4 lo``, refined by scipy's bounded Brent search between its
    neighbours (``lo`` itself when the grid's best is ``lo``)."""
    grid = lo * np.logspace(0.0, 4.0, 801)
    vals = np.array([_neg_loglik(f, b, r) for f in grid])
    i = int(np.argmin(vals))
    assert i < len(grid) - 1, "the maximiser lies beyond the grid"
    if i == 0:
        return lo
    res = optimize.minimize_scalar(
        _neg_loglik,
        bounds=(grid[i - 1], grid[i + 1]),
        args=(b, r),
        method="bounded",
        options={"xatol": 1e-14 * grid[i]},
    )
    assert res.success
    return float(res.x)


@pytest.mark.parametrize("noisy_input", ["none", "simple"])
def test_calibrate_raises_the_floor_to_scipys_maximiser(fitted, noisy_input: str) -> None:
    """One round: the returned (and set) floor is the maximiser of ``sum_i -(log(b_i + f) +
    r_i / (b_i + f)) / 2`` over ``f`` at or above the fitted floor, found by scipy (rtol 1e-7),
    where ``b_i`` includes the input-noise term ``e_test`` (non-zero for ``simple``). The
    validation noise is 8x the training noise, so the floor is raised well above the fitted one.
    Catches residuals not normalised by ``y_std``, a sum instead of a mean over channels, the
    floor counted twice in ``b_i``, ``e_test`` left out, or a wrong sign in the derivative."""
    x, y, xv, yv = fitted
    reg = _regressor(noisy_input, x, y)
    if noisy_input == "simple":
        assert float(reg.test_extra_noise) > 0  # b_i holds a non-zero e_test
    floor0 = float(reg.likelihood.floor.detach())
    b, r = _terms(reg, xv, yv)
    want = _best_floor(b, r, floor0)
    assert want > 3 * floor0  # the case where the floor is raised
    got = reg.calibrate(xv, yv, x, y, reg.extra_train_noise(x), rounds=1)
    assert got == pytest.approx(want, rel=1e-7)
    assert float(reg.likelihood.floor.detach()) == pytest.approx(want, rel=1e-7)


def _few_points_very_noisy_validation() -> tuple[torch.Tensor, ...]:
    """20 training points (noise 0.01) and validation windows at the same inputs, 10 draws
    each with noise 1: the floor jumps by 3 orders of magnitude in the first round, and the q
    refitted with it shrinks the mean enough that the second round raises it again."""
    gen = torch.Generator().manual_seed(0)
    x = torch.linspace(-3.0, 3.0, 20, dtype=F64).unsqueeze(-1)
    y = torch.cat([torch.sin(1.5 * x), 0.3 * x], -1)
    y = y + 0.01 * torch.randn(20, 2, generator=gen, dtype=F64)
    xv = x.repeat(10, 1)
    yv = y.repeat(10, 1) + torch.randn(200, 2, generator=gen, dtype=F64)
    return x, y, xv, yv


@pytest.mark.parametrize("case", ["raised again", "kept"])
def test_calibrate_second_round_maximises_with_the_refitted_q(fitted, case: str) -> None:
    """``rounds = 2`` is one round, q recomputed with the new floor, then a second round on
    the new predictions: the result equals scipy's maximiser for the predictions after one
    round, at or above the first round's floor (rtol 1e-7). In the "raised again" case that
    maximiser is about 2.5 % above the first round's floor; in the "kept" case (the validation set
    of the other calibration tests) it is 4 % below, and the floor stays (a round never lowers
    it). Catches a calibration that stops after one round, a second round on the first
    round's residuals and variances (q not recomputed between rounds), or a second round
    that lowers the floor."""
    if case == "raised again":
        x, y, xv, yv = _few_points_very_noisy_validation()
        cfg = SVGPCfg(num_inducing=20, noisy_input="none", epochs=60, max_steps=60)
        regs = [SVGPRegressor.from_data(cfg, x, y) for _ in range(2)]
        for reg in regs:
            reg.fit(x, y)
    else:
        x, y, xv, yv = fitted
        regs = [_regressor("none", x, y) for _ in range(2)]
    reg_one, reg_two = regs
    extra = reg_one.extra_train_noise(x)
    first = reg_one.calibrate(xv, yv, x, y, extra, rounds=1)
    b, r = _terms(reg_one, xv, yv)
    want = _best_floor(b, r, first)
    unconstrained = _best_floor(b, r, 1e-3 * first)
    if case == "raised again":
        assert unconstrained > 1.01 * first
    else:
        assert unconstrained < 0.99 * first
    got = reg_two.calibrate(xv, yv, x, y, extra, rounds=2)
    assert got == pytest.approx(want, rel=1e-7)


def test_calibrate_never_lowers_the_floor(fitted) -> None:
    """Validation values without noise (the true function at the training inputs): the
    log-likelihood decreases above the fitted floor (checked here on scipy's side), so the
    floor is returned unchanged, bit for bit. Catches a calibration that lowers the floor to
    the validation optimum."""
    x, y, _, _ = fitted
    reg = _regressor("none", x, y)
    floor0 = float(reg.likelihood.floor.detach())
    xv = x[:60]
    yv = torch.cat([torch.sin(1.5 * xv), 0.3 * xv], -1)
    b, r = _terms(reg, xv, yv)
    assert _best_floor(b, r, floor0) == floor0
    # the unconstrained maximiser is below the fitted floor
    res = optimize.minimize_scalar(
        _neg_loglik, bounds=(1e-12, floor0), args=(b, r), method="bounded"
    )
    assert res.x < 0.99 * floor0
    got = reg.calibrate(xv, yv, x, y, reg.extra_train_noise(x), rounds=1)
    assert got == floor0


# ------------------------------------------------------------------------------ steps_for


@pytest.mark.parametrize(
    ("n", "max_epochs", "want"),
    [
        (1000, None, 30),  # one batch of 1000 per epoch, 30 epochs
        (5000, None, 150),  # ceil(5000 / 1024) = 5 batches, 150 steps = max_steps
        (10_000, None, 150),  # 10 x 30 = 300, capped at max_steps
        (5000, 2, 10),  # max_epochs caps the epochs: 2 x 5
        (1000, 100, 30),  # max_epochs above epochs: epochs stays 30
        (1025, None, 60),  # 2 batches per epoch (ceil(1025 / 1024))
        (1, None, 30),  # one point: one batch per epoch
        (0, None, 0),  # no point: ceil(0 / 1) = 0 batches, no step
        (5000, 0, 0),  # no epoch: no step
    ],
)
def test_steps_for_hand_values(n: int, max_epochs: int | None, want: int) -> None:
    """``min(epochs' * ceil(n / min(batch_size, max(n, 1))), max_steps)``, with ``epochs' =
    min(epochs, max_epochs)``, by hand for batch_size 1024, epochs 30, max_steps 150; n = 0
    gives 0 steps (the batch size is floored at 1, no division by 0). Catches floor division
    (1025 -> 30), a missing max_steps cap, max_epochs replacing epochs instead of capping it,
    or a ZeroDivisionError at n = 0."""
    cfg = SVGPCfg(batch_size=1024, epochs=30, max_steps=150)
    assert cfg.steps_for(n, max_epochs) == want


# ------------------------------------------------------------------ constant-velocity fallback

FPS = 10.0
N_PREV, N_FUTURE = 5, 6
JOINTS = ("torso", "left_hand", "right_hand")
SIGMA0, SIGMA_RATE = 0.2, 0.5


def _gp_free_predictor() -> HumanMotionPredictor:
    """A predictor without any GP (no state's own, no pooled): every forecast is the
    constant-velocity fallback; no classifier, so the weights are uniform."""
    d = 3 * len(JOINTS) * 3
    return HumanMotionPredictor(
        cfg=PredictorCfg(fallback_sigma0=SIGMA0, fallback_sigma_rate=SIGMA_RATE),
        joint_names=JOINTS,
        action_names=("reach", "place"),
        fps=FPS,
        n_prev=N_PREV,
        n_future=N_FUTURE,
        feature_kinds=("position", "velocity", "acceleration"),
        progress_actions=(0, 1),
        feat_mean=torch.zeros(d),
        feat_std=torch.ones(d),
    ).prepare()


def test_fallback_mean_extrapolates_linear_motion() -> None:
    """Windows of exactly linear motion ``p0 + v i / fps`` (frames i = 0..n_p - 1): the mean
    ``k`` frames ahead is ``p_now + v k / fps`` for k = 1..n_f for every action (float32:
    atol 1e-5), ``p_now = p0 + v (n_p - 1) / fps``; also for a progress state never seen.
    Catches a velocity not scaled by fps, divided by n_p instead of n_p - 1, times starting at
    k = 0, or a forecast anchored at the first frame instead of the current one."""
    pred = _gp_free_predictor()
    p0 = torch.tensor(
        [
            [[0.1, 0.2, 0.9], [0.3, -0.2, 1.1], [0.3, 0.4, 1.0]],
            [[-0.5, 0.0, 1.0], [0.0, 0.5, 0.8], [-0.2, 0.1, 1.2]],
        ],
        dtype=F64,
    )  # (B, K, 3)
    v = torch.tensor(
        [
            [[0.0, 0.0, 0.0], [0.4, -0.3, 0.1], [-0.6, 0.2, 0.0]],
            [[0.2, 0.2, -0.1], [1.0, 0.0, 0.5], [0.0, -0.8, 0.3]],
        ],
        dtype=F64,
    )  # [m/s]
    i = torch.arange(N_PREV, dtype=F64).view(1, -1, 1, 1)
    positions = p0.unsqueeze(1) + v.unsqueeze(1) * i / FPS  # (B, n_p, K, 3)
    for state in (0, 3):
        fc = pred.predict_positions(positions.float(), torch.full((2,), state))
        assert fc.mean.shape == (2, 2, N_FUTURE, len(JOINTS), 3)
        for k in range(1, N_FUTURE + 1):
            expect = p0 + v * (N_PREV - 1 + k) / FPS  # (B, K, 3)
            for a in range(2):
                np.testing.assert_allclose(
                    fc.mean[:, a, k - 1].double().numpy(), expect.numpy(), rtol=0, atol=1e-5
                )
        np.testing.assert_allclose(fc.weights.numpy(), 0.5)


def test_fallback_mean_uses_the_windows_mean_velocity() -> None:
    """Quadratic motion ``p(t) = v t + a t^2 / 2`` over the window (t = i / fps): the
    documented velocity is the window's mean ``(p_last - p_first) / ((n_p - 1) / fps) = v + a
    T / 2`` (T = 0.4 s), not the current one ``v + a T``; the mean k frames ahead is
    ``p(T) + (v + a T / 2) k / fps`` (float32: atol 1e-5). Catches the last frame's velocity
    feature (or a last-step difference) used instead of the window's mean."""
    pred = _gp_free_predictor()
    vel = torch.tensor([0.5, -0.2, 0.1], dtype=F64)
    acc = torch.tensor([2.0, 1.0, -3.0], dtype=F64)
    t = torch.arange(N_PREV, dtype=F64) / FPS
    traj = vel * t[:, None] + 0.5 * acc * t[:, None] ** 2  # (n_p, 3)
    positions = traj[None, :, None, :].expand(1, N_PREV, len(JOINTS), 3) + torch.tensor(
        [0.0, 0.0, 1.0], dtype=F64
    )
    big_t = (N_PREV - 1) / FPS
    v_mean = vel + acc * big_t / 2  # (0.9, 0.0, -0.5)
    fc = pred.predict_positions(positions.float(), torch.zeros(1, dtype=torch.int64))
    p_now = positions[0, -1]  # (K, 3)
    for k in range(1, N_FUTURE + 1):
        expect = p_now + v_mean * k / FPS
        np.testing.assert_allclose(
            fc.mean[0, 1, k - 1].double().numpy(), expect.numpy(), rtol=0, atol=1e-5
        )


def test_fallback_variance_hand_values() -> None:
    """``fallback_sigma0^2 + (fallback_sigma_rate t)^2`` per coordinate, t = k / fps: with
    sigma0 = 0.2 m, rate 0.5 m/s and fps 10, k = 1 gives 0.04 + 0.0025 = 0.0425 m^2 and
    k = 3 gives 0.04 + 0.0225 = 0.0625 m^2 (sd 0.25 m), k = 6 gives 0.04 + 0.09 = 0.13, the
    same for every action, joint and coordinate (float32: rtol 1e-6). Catches sigma0 and the
    rate swapped, a variance linear in t, or t counted from k = 0."""
    pred = _gp_free_predictor()
    positions = torch.zeros(1, N_PREV, len(JOINTS), 3)
    positions[..., 2] = 1.0
    fc = pred.predict_positions(positions, torch.zeros(1, dtype=torch.int64))
    for k, want in ((1, 0.0425), (3, 0.0625), (6, 0.13)):
        np.testing.assert_allclose(fc.var[0, :, k - 1].numpy(), want, rtol=1e-6)
