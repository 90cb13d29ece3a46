"""Closed-loop and prediction metrics against analytic values and brute-force references."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.integrate import quad
from scipy.spatial.distance import cdist

from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.eval.metrics import (
    METRIC_KEYS,
    classification_precision,
    closest_distance,
    efficiency,
    episode_metrics,
    jerkiness,
    joint_accelerations,
    modified_hausdorff,
    modified_hausdorff_batch,
    prediction_mhd,
    regression_accuracy,
    regression_precision,
    smoothness,
)


def _nonuniform_grid(n: int, t_end: float, seed: int = 0) -> np.ndarray:
    g = np.random.default_rng(seed)
    steps = g.uniform(0.5, 1.5, size=n - 1)
    return np.concatenate([[0.0], np.cumsum(steps) / steps.sum() * t_end])


def test_smoothness_of_a_quadratic_is_its_squared_acceleration() -> None:
    t = _nonuniform_grid(60, 3.0)
    a = np.array([0.5, -1.2, 2.0])
    q = a * t[:, None] ** 2 + np.array([0.1, 0.3, -0.2]) * t[:, None] + 1.0
    assert smoothness(t, q) == pytest.approx(((2 * a) ** 2).sum(), rel=1e-9)
    assert jerkiness(t, q) == pytest.approx(((2 * a) ** 2).sum(), rel=1e-9)


def test_smoothness_matches_the_integral_of_a_smooth_motion() -> None:
    """q = sin(w t): (1/T) int_0^T (w^2 sin(w t))^2 dt by scipy quadrature."""
    w, t_end = 2.0, 3.0
    t = _nonuniform_grid(3000, t_end, seed=1)
    q = np.sin(w * t)[:, None]
    ref = quad(lambda s: (w**2 * math.sin(w * s)) ** 2, 0.0, t_end)[0] / t_end
    assert smoothness(t, q) == pytest.approx(ref, rel=2e-3)
    assert jerkiness(t, q) == pytest.approx(w**4, rel=2e-3)  # max of (w^2 sin)^2


def test_jerkiness_of_a_piecewise_quadratic_is_the_larger_acceleration() -> None:
    """C1 motion whose acceleration jumps from a1 to a2 at t_s (every joint at once)."""
    t = _nonuniform_grid(80, 2.0, seed=2)
    t_s = 1.013
    a1, a2 = np.array([1.0, -0.5]), np.array([-3.0, 2.0])
    v_s, p_s = 2 * a1 * t_s, a1 * t_s**2
    tt = t[:, None]
    q = np.where(tt < t_s, a1 * tt**2, p_s + v_s * (tt - t_s) + a2 * (tt - t_s) ** 2)
    expected = max(((2 * a1) ** 2).sum(), ((2 * a2) ** 2).sum())
    assert jerkiness(t, q) == pytest.approx(expected, rel=1e-9)
    # Smoothness: the time-weighted mean of the two, up to the one or two straddling samples.
    frac = t_s / t[-1]
    mean = frac * ((2 * a1) ** 2).sum() + (1 - frac) * ((2 * a2) ** 2).sum()
    assert smoothness(t, q) == pytest.approx(mean, rel=0.05)


def test_joint_accelerations_weights_cover_the_time_span() -> None:
    t = _nonuniform_grid(10, 1.7)
    qdd, w = joint_accelerations(t, np.zeros((10, 2)))
    assert qdd.shape == (8, 2) and float(w.sum()) == pytest.approx(1.7)


def test_trajectory_metrics_reject_bad_input() -> None:
    with pytest.raises(ShapeError, match=r"expected q \(10, J\)"):
        smoothness(np.arange(10.0), np.zeros((9, 2)))
    with pytest.raises(ShapeError, match="at least 3 time samples"):
        jerkiness(np.arange(2.0), np.zeros((2, 2)))
    with pytest.raises(DataError, match="strictly increasing"):
        smoothness(np.array([0.0, 1.0, 1.0, 2.0]), np.zeros((4, 1)))


@pytest.mark.parametrize("metric", [smoothness, jerkiness, joint_accelerations])
def test_trajectory_metrics_reject_a_nan_row_naming_it(metric) -> None:
    t = np.linspace(0.0, 1.0, 12)
    q = np.zeros((12, 3))
    q[7, 1] = np.nan
    q[9, 0] = np.inf
    with pytest.raises(DataError, match=r"NaN or inf in 2 rows, first \[7, 9\] \(t = 0\.636 s\)"):
        metric(t, q)
    with pytest.raises(DataError, match="strictly increasing"):
        metric(np.array([0.0, np.nan, 1.0, 2.0]), np.zeros((4, 1)))


def test_closest_distance_matches_a_brute_force_loop() -> None:
    g = np.random.default_rng(3)
    n_t, s_r, s_h = 12, 5, 7
    rc = g.normal(size=(n_t, s_r, 3))
    hc = g.normal(size=(n_t, s_h, 3)) + 1.0
    rr, hr = g.uniform(0.05, 0.2, s_r), g.uniform(0.05, 0.2, s_h)
    hc[4, 2] = np.nan  # an untracked joint is ignored
    ref = np.full(n_t, np.inf)
    for t in range(n_t):
        for i in range(s_r):
            for j in range(s_h):
                if np.isnan(hc[t, j]).any():
                    continue
                d = math.dist(rc[t, i], hc[t, j]) - rr[i] - hr[j]
                ref[t] = min(ref[t], d)
    overall, per_step = closest_distance(rc, rr, hc, hr)
    np.testing.assert_allclose(per_step.numpy(), ref, rtol=1e-12)
    assert overall == pytest.approx(ref.min())


def test_closest_distance_is_negative_on_penetration() -> None:
    rc = torch.tensor([[[0.0, 0.0, 0.0]]])
    hc = torch.tensor([[[0.3, 0.0, 0.0]]])
    d, _ = closest_distance(rc, torch.tensor([0.2]), hc, torch.tensor([0.15]))
    assert d == pytest.approx(-0.05)
    with pytest.raises(ShapeError, match="expected human_radii"):
        closest_distance(rc, torch.tensor([0.2]), hc, torch.tensor([0.1, 0.2]))


def test_closest_distance_on_device(device: torch.device) -> None:
    rc = torch.randn(4, 3, 3, device=device)
    hc = torch.randn(4, 2, 3, device=device)
    r = torch.full((3,), 0.1, device=device)
    h = torch.full((2,), 0.1, device=device)
    d, per = closest_distance(rc, r, hc, h)
    assert per.device.type == device.type
    ref = (torch.cdist(rc.double(), hc.double()) - 0.2).amin(dim=(1, 2)).min()
    assert d == pytest.approx(float(ref), rel=1e-6)


def test_modified_hausdorff_by_hand() -> None:
    a = np.array([[0.0, 0.0, 0.0]])
    b = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    # A->B: mean of min = 1; B->A: mean(5, 1) = 3; MHD = max = 3.
    assert modified_hausdorff(a, b) == pytest.approx(3.0)
    assert modified_hausdorff(b, a) == pytest.approx(3.0)
    assert modified_hausdorff(a, a) == 0.0


def test_modified_hausdorff_matches_brute_force_on_random_sets() -> None:
    g = np.random.default_rng(4)
    for n, m in [(5, 9), (30, 2), (17, 17)]:
        a, b = g.normal(size=(n, 3)), g.normal(size=(m, 3))
        d = cdist(a, b)
        ref = max(d.min(axis=1).mean(), d.min(axis=0).mean())
        assert modified_hausdorff(torch.from_numpy(a), b) == pytest.approx(ref, rel=1e-12)


def test_prediction_mhd_checks_shapes() -> None:
    p = np.zeros((15, 3))
    assert prediction_mhd(p, p + np.array([0.0, 0.0, 0.1])) == pytest.approx(0.1)
    with pytest.raises(ShapeError, match=r"expected true \(15, 3\)"):
        prediction_mhd(p, np.zeros((14, 3)))


def test_efficiency() -> None:
    assert efficiency(30.0, 20.0) == pytest.approx(1.5)
    with pytest.raises(DataError, match="positive task times"):
        efficiency(30.0, 0.0)


def test_regression_precision_against_a_loop() -> None:
    g = np.random.default_rng(5)
    pred, true = g.normal(size=(2, 6, 10, 3)), g.normal(size=(2, 6, 10, 3))
    dt = 1 / 15
    ref = [
        sum(np.sum((pred[b, f, k] - true[b, f, k]) ** 2) * dt for f in range(6) for k in range(10))
        for b in range(2)
    ]
    np.testing.assert_allclose(regression_precision(pred, true, dt).numpy(), ref, rtol=1e-12)
    # A constant offset c on every coordinate: T * K * 3 c^2 with T = n_f dt.
    c = 0.02
    val = regression_precision(true[0], true[0] + c, dt)
    assert val.shape == () and float(val) == pytest.approx(6 * dt * 10 * 3 * c**2)


def test_regression_accuracy_is_rotation_invariant() -> None:
    g = np.random.default_rng(6)
    var = g.uniform(1e-3, 1e-2, size=(4, 5, 3))  # (n_f, K, 3)
    rot = np.linalg.qr(g.normal(size=(3, 3)))[0]
    cov = rot @ (var[..., :, None] * np.eye(3)) @ rot.T  # (n_f, K, 3, 3), same determinants
    dt = 0.1
    ref = float(np.prod(var, axis=-1).sum() * dt)
    assert float(regression_accuracy(var, dt)) == pytest.approx(ref, rel=1e-12)
    assert float(regression_accuracy(cov, dt, full_cov=True)) == pytest.approx(ref, rel=1e-9)
    with pytest.raises(DataError, match="dt > 0"):
        regression_accuracy(var, 0.0)


def test_classification_precision_counts_confident_frames_only() -> None:
    probs = np.array([[0.9, 0.1], [0.4, 0.6], [0.5, 0.5], [0.2, 0.8]])
    labels = np.array([0, 0, 1, 1])
    # Frames 0, 1, 3 are counted (top > 0.5); 0 and 3 are right.
    frac, n = classification_precision(probs, labels)
    assert n == 3 and frac == pytest.approx(2 / 3)
    frac, n = classification_precision(probs, labels, threshold=0.95)
    assert n == 0 and math.isnan(frac)


def test_episode_metrics_keys() -> None:
    t = np.linspace(0.0, 1.0, 11)
    q = t[:, None] ** 2 * np.ones((1, 2))
    rc = np.zeros((3, 1, 3))
    hc = np.ones((3, 1, 3))
    out = episode_metrics(
        t=t,
        q=q,
        robot_centers=rc,
        robot_radii=[0.1],
        human_centers=hc,
        human_radii=[0.1],
        t_human_alone=12.0,
        t_with_robot=8.0,
    )
    assert set(out) == set(METRIC_KEYS)
    assert out["eval/smoothness"] == pytest.approx(8.0)
    assert out["eval/min_distance"] == pytest.approx(math.sqrt(3) - 0.2)
    assert out["eval/contact"] == 0.0 and out["eval/efficiency"] == pytest.approx(1.5)
    assert math.isnan(out["eval/mhd"])


def test_episode_metrics_of_fewer_than_three_samples_have_nan_smoothness() -> None:
    """Two samples hold no interior sample to take an acceleration at: the smoothness and
    jerkiness are NaN, the other metrics are computed as usual."""
    for n in (0, 1, 2):
        t = np.arange(n, dtype=float) * 0.04
        out = episode_metrics(
            t=t,
            q=np.zeros((n, 2)),
            robot_centers=np.zeros((n, 1, 3)),
            robot_radii=[0.1],
            human_centers=np.ones((n, 1, 3)),
            human_radii=[0.1],
        )
        assert math.isnan(out["eval/smoothness"]) and math.isnan(out["eval/jerkiness"])
        if n:
            assert out["eval/min_distance"] == pytest.approx(math.sqrt(3) - 0.2)
    with pytest.raises(ShapeError, match=r"expected q \(2, J\)"):
        episode_metrics(
            t=np.array([0.0, 0.04]), q=np.zeros((3, 2)), robot_centers=np.zeros((2, 1, 3)),
            robot_radii=[0.1], human_centers=np.ones((2, 1, 3)), human_radii=[0.1],
        )  # fmt: skip


def test_modified_hausdorff_batch_checks_its_shapes() -> None:
    """It had no checks: a wrong rank returned a result, other sizes failed in torch.cdist."""
    a, b = torch.zeros(2, 5, 3), torch.zeros(2, 4, 3)
    with pytest.raises(ShapeError, match=r"expected a \(B, N, 3\), got \(10, 3\)"):
        modified_hausdorff_batch(a.reshape(10, 3), b)
    with pytest.raises(ShapeError, match=r"expected b \(2, M, 3\)"):
        modified_hausdorff_batch(a, torch.zeros(2, 4, 2))
    with pytest.raises(ShapeError, match="non-empty point sets"):
        modified_hausdorff_batch(a, b[:, :0])
    with pytest.raises(ShapeError, match="one floating dtype on one device"):
        modified_hausdorff_batch(a, b.double())
    assert modified_hausdorff_batch(a, b).tolist() == [0.0, 0.0]


def test_modified_hausdorff_of_identical_paths_is_exactly_zero() -> None:
    """More than 25 points: the distances are still taken directly (the matrix-product
    expansion left about 2e-4 m between a float32 path and itself)."""
    g = torch.Generator().manual_seed(0)
    a = 1.0 + 0.3 * torch.randn(4, 30, 3, generator=g)  # (B, 30, 3) float32, about 1 m
    assert modified_hausdorff_batch(a, a.clone()).tolist() == [0.0] * 4
    assert modified_hausdorff(a[0].double() + 1000.0, a[0].double() + 1000.0) == 0.0
    # a small offset is measured as such, not lost in the cancellation
    shifted = modified_hausdorff(a[0].double() + 1000.0, a[0].double() + 1000.0 + 1e-4)
    assert shifted == pytest.approx(math.sqrt(3) * 1e-4, rel=1e-6)


def test_a_nan_point_gives_a_nan_distance() -> None:
    a = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [1.0, 0.0, 0.0]])
    b = np.array([[0.0, 0.0, 0.1], [1.0, 0.0, 0.1], [2.0, 0.0, 0.0]])
    assert math.isnan(modified_hausdorff(a, b)) and math.isnan(modified_hausdorff(b, a))
    assert math.isnan(prediction_mhd(a, b)) and math.isnan(prediction_mhd(b, a))


@pytest.mark.parametrize(
    "bad",
    [
        "abc",  # text: a raw numpy ValueError
        [[0.0, 0.0, 0.0], [1.0, 0.0]],  # ragged: a raw numpy ValueError
        [[True, False, True]],  # bools are not positions
        torch.zeros(1, 3, dtype=torch.complex64),
    ],
)
def test_inputs_that_are_not_real_arrays_raise_shape_error(bad) -> None:
    with pytest.raises(ShapeError, match="expected a an array of real numbers"):
        modified_hausdorff(bad, np.zeros((2, 3)))


@pytest.mark.parametrize("alone", ["a", torch.tensor([30.0, 20.0]), None, True])
def test_efficiency_of_a_non_number_raises_data_error(alone) -> None:
    """'a' and a two-element tensor raised raw TypeError / RuntimeError."""
    with pytest.raises(DataError, match="expected positive task times"):
        efficiency(alone, 1.0)
    with pytest.raises(DataError, match="expected positive task times"):
        efficiency(1.0, alone)
    # numpy scalars and one-element tensors are numbers
    assert efficiency(np.float32(3.0), torch.tensor([2.0])) == pytest.approx(1.5)


@pytest.mark.parametrize("dt", [math.nan, math.inf, "0.1", 0.0])
def test_regression_metrics_refuse_a_dt_that_is_not_positive_and_finite(dt) -> None:
    """dt = NaN returned NaN (while dt <= 0 raised)."""
    x = np.zeros((2, 1, 3))
    with pytest.raises(DataError, match="expected dt > 0 and finite"):
        regression_precision(x, x, dt)
    with pytest.raises(DataError, match="expected dt > 0 and finite"):
        regression_accuracy(x, dt)


def test_classification_precision_refuses_nan_rows_and_bad_labels() -> None:
    """A NaN frame was dropped silently; a label A or -1 was counted as wrong."""
    probs = np.array([[0.9, 0.1], [np.nan, 0.6], [0.2, 0.8]])
    with pytest.raises(DataError, match=r"expected finite probs, got NaN or inf in 1 frames"):
        classification_precision(probs, [0, 0, 1])
    probs = np.array([[0.9, 0.1], [0.4, 0.6], [0.2, 0.8]])
    for labels in ([0, 2, 1], [0, -1, 1], [0, 0.5, 1]):
        with pytest.raises(DataError, match=r"expected labels integers in \[0, 2\)"):
            classification_precision(probs, labels)
    assert classification_precision(probs, torch.tensor([0, 1, 1])) == (1.0, 3)


def test_closest_distance_refuses_an_infinite_centre() -> None:
    """An infinite centre was reported as 1.8e308 m away."""
    rc = np.zeros((2, 1, 3))
    hc = np.ones((2, 1, 3))
    hc[1, 0, 0] = math.inf
    with pytest.raises(DataError, match="expected finite .*human_centers, got an infinite"):
        closest_distance(rc, [0.1], hc, [0.1])
    with pytest.raises(DataError, match="expected finite robot_radii"):
        closest_distance(rc, [math.nan], np.ones((2, 1, 3)), [0.1])
    hc[1, 0, 0] = math.nan  # NaN (untracked) is still ignored
    overall, per_step = closest_distance(rc, [0.1], hc, [0.1])
    assert overall == pytest.approx(math.sqrt(3) - 0.2) and math.isnan(per_step[1])


@pytest.mark.parametrize(
    "t", [[-math.inf, 0.5, 1.0, 1.5], [0.0, 0.5, 1.0, math.inf]], ids=["-inf", "inf"]
)
def test_trajectory_metrics_refuse_infinite_times(t) -> None:
    """An infinite first or last time passed as increasing: smoothness was NaN."""
    q = np.zeros((4, 2))
    for metric in (smoothness, jerkiness, joint_accelerations):
        with pytest.raises(DataError, match="strictly increasing finite times"):
            metric(t, q)


def test_efficiency_of_an_infinite_time_raises_data_error() -> None:
    """An infinite task time gave an efficiency of inf or 0."""
    for alone, team in ((math.inf, 1.0), (1.0, math.inf)):
        with pytest.raises(DataError, match="expected positive task times"):
            efficiency(alone, team)


@pytest.mark.parametrize("threshold", ["0.5", None, [0.5], math.nan, True])
def test_classification_precision_refuses_a_threshold_that_is_not_a_number(threshold) -> None:
    """A string, None or a list raised a bare TypeError; NaN counted no frame silently."""
    probs, labels = np.array([[0.9, 0.1], [0.2, 0.8]]), np.array([0, 1])
    with pytest.raises(ConfigError, match="expected threshold a finite number"):
        classification_precision(probs, labels, threshold)
    assert classification_precision(probs, labels, torch.tensor(0.5)) == (1.0, 2)


@pytest.mark.parametrize("name", ["mhd", "prediction_ms"])
def test_episode_metrics_refuse_an_mhd_or_time_that_is_not_a_number(name: str) -> None:
    """A string or a two-element tensor raised a bare ValueError from float()."""
    t = np.linspace(0.0, 1.0, 5)
    args = dict(
        t=t,
        q=np.zeros((5, 2)),
        robot_centers=np.zeros((5, 1, 3)),
        robot_radii=[0.1],
        human_centers=np.ones((5, 1, 3)),
        human_radii=[0.1],
    )
    for bad in ("x", torch.tensor([1.0, 2.0])):
        with pytest.raises(DataError, match=f"expected {name} a number or None"):
            episode_metrics(**args, **{name: bad})
    key = f"eval/{name}"
    assert episode_metrics(**args, **{name: np.float32(2.0)})[key] == 2.0
    assert math.isnan(episode_metrics(**args, **{name: math.nan})[key])


def test_spheres_that_just_touch_count_as_a_contact() -> None:
    """``eval/contact`` is ``min_distance <= 0``: two spheres of radius 0.5 m with centres
    1 m apart (exactly representable) touch, at distance 0; 1 mm further apart they do not."""
    t = torch.tensor([0.0, 0.1, 0.2], dtype=torch.float64)
    q = torch.zeros(3, 2, dtype=torch.float64)
    radii = torch.tensor([0.5], dtype=torch.float64)
    robot = torch.zeros(3, 1, 3, dtype=torch.float64)
    for gap, contact in ((1.0, 1.0), (1.001, 0.0)):
        human = torch.tensor([gap, 0.0, 0.0], dtype=torch.float64).expand(3, 1, 3)
        m = episode_metrics(
            t=t, q=q, robot_centers=robot, robot_radii=radii, human_centers=human,
            human_radii=radii,
        )  # fmt: skip
        assert m["eval/contact"] == contact, (gap, m["eval/min_distance"])
    assert m["eval/min_distance"] == pytest.approx(0.001)


def test_closest_distance_refuses_negative_radii() -> None:
    """A negative radius was taken: the distance came out larger than the spheres' (1.73 m
    for touching spheres), hiding the contact."""
    rc, hc = torch.zeros(2, 1, 3), torch.ones(2, 1, 3)
    with pytest.raises(DataError, match=r"expected robot_radii >= 0 \[m\]"):
        closest_distance(rc, -torch.ones(1), hc, torch.ones(1))
    with pytest.raises(DataError, match="human_radii >= 0"):
        closest_distance(rc, torch.ones(1), hc, torch.tensor([-0.1]))
