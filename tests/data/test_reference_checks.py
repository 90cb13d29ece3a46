"""Window features and imputation against numpy re-computations.

* Velocities and accelerations of :func:`compute_features`: ``np.gradient`` with
  ``edge_order=2`` (central differences inside, second-order one-sided at both ends), on
  random trajectories, edges included.
* :func:`impute_nan`: ``np.interp`` of every joint coordinate over its observed frames (it
  holds the first and last observations beyond them), on random gaps.
"""

from __future__ import annotations

import numpy as np
import torch

from iplanner_torch.data.windows import compute_features, impute_nan

FPS = 15.0


def test_derivative_features_equal_numpy_gradients() -> None:
    """Random (B, T, K, 3) positions: the velocity and acceleration blocks equal
    ``np.gradient`` applied once and twice along time (float64: rtol 1e-12)."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=(3, 12, 4, 3))
    f = compute_features(torch.from_numpy(x), FPS).numpy()  # (3, 12, 36)
    v = np.gradient(x, 1.0 / FPS, axis=1, edge_order=2)
    a = np.gradient(v, 1.0 / FPS, axis=1, edge_order=2)
    np.testing.assert_allclose(f[..., :12], x.reshape(3, 12, 12), rtol=0, atol=0)
    np.testing.assert_allclose(f[..., 12:24], v.reshape(3, 12, 12), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(f[..., 24:], a.reshape(3, 12, 12), rtol=1e-12, atol=1e-10)
    # the kinds select and order the blocks
    only_acc = compute_features(torch.from_numpy(x), FPS, ("position", "acceleration")).numpy()
    np.testing.assert_allclose(only_acc[..., 12:], a.reshape(3, 12, 12), rtol=1e-12, atol=1e-10)


def test_imputation_equals_numpy_interpolation_over_random_gaps() -> None:
    """Random losses of whole joints (a NaN in any coordinate loses the joint), leading,
    inner and trailing gaps: each imputed coordinate equals ``np.interp`` over the joint's
    observed frames; observed frames are unchanged (float64: atol 1e-12)."""
    rng = np.random.default_rng(1)
    t_len, k = 40, 5
    x = rng.normal(size=(t_len, k, 3)).cumsum(axis=0)
    lost = rng.random((t_len, k)) < 0.3
    lost[:3, 0] = True  # a leading gap
    lost[-4:, 1] = True  # a trailing gap
    lost[0, 2] = lost[-1, 2] = False
    xn = x.copy()
    coord = rng.integers(0, 3, size=(t_len, k))
    rows, cols = np.nonzero(lost)
    xn[rows, cols, coord[rows, cols]] = np.nan  # one coordinate is enough
    got = impute_nan(torch.from_numpy(xn)).numpy()
    frames = np.arange(t_len)
    for j in range(k):
        seen = ~lost[:, j]
        for c in range(3):
            want = np.interp(frames, frames[seen], x[seen, j, c])
            np.testing.assert_allclose(got[:, j, c], want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got[~lost], x[~lost])
