"""ConstantVelocityPredictor against numpy's least-squares line and the textbook prediction
interval, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.prediction.constant_velocity import (
    ACTION,
    ConstantVelocityCfg,
    ConstantVelocityPredictor,
)

K = len(JOINT_NAMES)
FPS = 15.0


def _window(seed: int, b: int = 2, n_p: int = 15) -> torch.Tensor:
    gen = np.random.default_rng(seed)
    p0 = gen.uniform(-0.5, 0.5, size=(b, 1, K, 3))
    v = gen.uniform(-1.0, 1.0, size=(b, 1, K, 3))
    t = (np.arange(n_p) - (n_p - 1)).reshape(1, n_p, 1, 1) / FPS
    noise = 0.01 * gen.standard_normal((b, n_p, K, 3))
    return torch.as_tensor(p0 + v * t + noise, dtype=torch.float64)


def test_mean_and_spread_are_numpy_s_line_fit_and_prediction_interval() -> None:
    cfg = ConstantVelocityCfg(fit_frames=6, n_future=10, min_std=1e-4, spread_mps=0.05)
    pred = ConstantVelocityPredictor(cfg, fps=FPS)
    x = _window(0)
    x[1, -2, 3] = float("nan")  # a lost frame: left out of that joint's fit
    fc = pred.predict_positions(x, torch.zeros(2, dtype=torch.int64))
    assert fc.weights.shape == (2, 1) and fc.action_names == (ACTION,)
    assert fc.mean.shape == (2, 1, 10, K, 3) and fc.dt == pytest.approx(1 / FPS)
    ahead = np.arange(1, 11) / FPS
    for b, k, c in [(0, 0, 0), (0, 7, 2), (1, 3, 1), (1, 3, 0), (1, K - 1, 2)]:
        t = (np.arange(6) - 5) / FPS
        y = x[b, -6:, k, c].numpy()
        keep = np.isfinite(y)
        t, y = t[keep], y[keep]
        slope, icpt = np.polyfit(t, y, 1)
        np.testing.assert_allclose(fc.mean[b, 0, :, k, c].numpy(), icpt + slope * ahead, atol=1e-9)
        n = len(t)
        s2 = np.sum((y - icpt - slope * t) ** 2) / (n - 2)
        se2 = s2 * (1 / n + (ahead - t.mean()) ** 2 / np.sum((t - t.mean()) ** 2))
        np.testing.assert_allclose(
            fc.var[b, 0, :, k, c].numpy(), se2 + (0.05 * ahead) ** 2, rtol=1e-9
        )


def test_exact_linear_motion_is_extrapolated_exactly() -> None:
    t = (torch.arange(15, dtype=torch.float64) - 14) / FPS
    v = torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64)
    p0 = torch.tensor([0.5, 0.1, 0.9], dtype=torch.float64)
    x = (p0 + t[:, None] * v).unsqueeze(1).expand(15, K, 3).unsqueeze(0)  # (1, 15, K, 3)
    pred = ConstantVelocityPredictor(ConstantVelocityCfg(n_future=30), fps=FPS)
    fc = pred.predict_positions(x, torch.zeros(1, dtype=torch.int64))
    want = p0 + 2.0 * v  # 30 frames at 15 Hz: 2 s ahead
    torch.testing.assert_close(fc.mean[0, 0, -1], want.expand(K, 3), atol=1e-12, rtol=0)
    # no residual: the least spread, growing with the time ahead
    assert bool((fc.var[0, 0, 1:] > fc.var[0, 0, :-1]).all())
    assert float(fc.var[0, 0, 0].min()) >= 0.01**2 * 0.2


def test_a_joint_seen_once_is_held_and_a_joint_never_seen_is_refused() -> None:
    pred = ConstantVelocityPredictor(fps=FPS)
    x = _window(1, b=1)
    x[0, :, 4] = float("nan")
    x[0, 2, 4] = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)  # before the fitted frames
    fc = pred.predict_positions(x, torch.zeros(1, dtype=torch.int64))
    torch.testing.assert_close(
        fc.mean[0, 0, :, 4], torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64).expand(15, 3)
    )
    ahead = torch.arange(1, 16, dtype=torch.float64) / FPS
    torch.testing.assert_close(fc.var[0, 0, :, 4, 0], 0.01**2 + (0.1 * ahead) ** 2)
    x[0, 2, 4] = float("nan")
    with pytest.raises(DataError, match=f"joint '{JOINT_NAMES[4]}' is lost in every frame"):
        pred.predict_positions(x, torch.zeros(1, dtype=torch.int64))


def test_bad_input_is_refused() -> None:
    pred = ConstantVelocityPredictor(fps=FPS)
    zero = torch.zeros(1, dtype=torch.int64)
    with pytest.raises(ShapeError, match="positions"):
        pred.predict_positions(torch.zeros(1, 14, K, 3), zero)
    x = _window(2, b=1)
    x[0, -1, 0, 0] = float("inf")
    with pytest.raises(DataError, match="inf"):
        pred.predict_positions(x, zero)
    with pytest.raises(ConfigError, match="fit_frames"):
        ConstantVelocityCfg(fit_frames=1)
    with pytest.raises(ConfigError, match="n_prev"):
        ConstantVelocityCfg(fit_frames=6, n_prev=5)
    with pytest.raises(ConfigError, match="fps"):
        ConstantVelocityPredictor(fps=0.0)
