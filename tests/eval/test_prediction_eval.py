"""Prediction metrics (paper sec. 7.1) against brute force and exact probabilities."""

from __future__ import annotations

import math

import pytest
import torch
from scipy.stats import chi2

from iplanner_torch.eval.prediction import evaluate_prediction, modified_hausdorff, window_metrics
from iplanner_torch.prediction.forecast import Forecast

JOINTS = ("torso", "left_hand", "right_hand")


def _mhd_brute(a: torch.Tensor, b: torch.Tensor) -> float:
    def directed(p, q):
        return sum(min(math.dist(x, y) for y in q.tolist()) for x in p.tolist()) / len(p)

    return max(directed(a, b), directed(b, a))


def test_modified_hausdorff_matches_brute_force() -> None:
    g = torch.Generator().manual_seed(0)
    a = torch.randn(4, 7, 3, generator=g, dtype=torch.float64)
    b = torch.randn(4, 5, 3, generator=g, dtype=torch.float64)
    got = modified_hausdorff(a, b)
    for i in range(4):
        assert math.isclose(float(got[i]), _mhd_brute(a[i], b[i]), rel_tol=1e-9)


def _forecast(b: int, n_f: int = 15, seed: int = 0) -> Forecast:
    g = torch.Generator().manual_seed(seed)
    a = 2
    weights = torch.tensor([[0.9, 0.1]]).expand(b, a).clone()
    mean = torch.randn(b, a, n_f, 3, 3, generator=g, dtype=torch.float64).float()
    var = 0.01 + 0.05 * torch.rand(b, a, n_f, 3, 3, generator=g)
    return Forecast(
        weights=weights, mean=mean, var=var, dt=1 / 15, joint_names=JOINTS, action_names=("a", "b")
    )


def test_coverage_matches_chi_square_levels_on_gaussian_samples() -> None:
    fc = _forecast(2000)
    g = torch.Generator().manual_seed(1)
    truth = fc.mean[:, 0] + fc.var[:, 0].sqrt() * torch.randn(fc.mean[:, 0].shape, generator=g)
    m = window_metrics(fc, truth, torch.zeros(2000, dtype=torch.int64))
    for q in (90, 95, 99):
        share = float(m[f"inside{q}"].float().mean())
        assert abs(share - q / 100) < 0.01, (q, share)
    # a point exactly at the 95 % radius along one axis is inside 95 % but not 90 %
    r = math.sqrt(chi2.ppf(0.95, 3)) * 0.999
    one = _forecast(1)
    t = one.mean[:, 0].clone()
    t[..., 0] += r * one.var[:, 0, ..., 0].sqrt()
    m1 = window_metrics(one, t, torch.zeros(1, dtype=torch.int64))
    assert bool(m1["inside95"].all()) and not bool(m1["inside90"].any())


def test_regression_precision_accuracy_and_classification() -> None:
    fc = _forecast(3)
    offset = 0.1
    truth = fc.expected_mean() + offset  # every coordinate off by 0.1
    current = torch.tensor([0, 1, 0])
    m = window_metrics(fc, truth, current)
    n_f, k = 15, 3
    expect_prec = n_f * k * 3 * offset**2 * fc.dt
    torch.testing.assert_close(m["reg_precision"], torch.full((3,), expect_prec))
    second = (fc.weights[:, :, None, None, None] * (fc.var + fc.mean**2)).sum(1)
    var_mix = second - fc.expected_mean() ** 2
    torch.testing.assert_close(m["reg_accuracy"], var_mix.prod(-1).sum((-1, -2)) * fc.dt)
    assert m["correct"].tolist() == [True, False, True]
    for b in range(3):  # moving hand = the hand with the larger true displacement over 1 s
        disp = [float((truth[b, -1, j] - truth[b, 0, j]).norm()) for j in (1, 2)]
        j = (1, 2)[disp.index(max(disp))]
        ref = _mhd_brute(fc.expected_mean()[b, :, j], truth[b, :, j])
        assert math.isclose(float(m["mhd_1s"][b]), ref, rel_tol=1e-5)
        assert ref <= offset * math.sqrt(3) + 1e-6


@pytest.mark.slow
def test_evaluate_prediction_on_held_out_demos(tmp_path) -> None:
    from iplanner_torch.data.reaching import ReachingCfg, reaching_demonstrations
    from iplanner_torch.data.windows import WindowCfg, build_windows, split_by_demonstration
    from iplanner_torch.prediction.predictor import HumanMotionPredictor, PredictorCfg
    from iplanner_torch.prediction.svgp import SVGPCfg
    from iplanner_torch.prediction.training import TrainerCfg, train_predictor

    rc = ReachingCfg(n_targets=2, reaches_per_target=8)
    demos = [d for t in range(2) for r in range(8) for d in reaching_demonstrations(rc, t, r)]
    train, _, test = split_by_demonstration(demos, (0.75, 0.0, 0.25))
    wc = WindowCfg(n_prev=8, n_future=15, stride=1, joints=JOINTS)
    cfg = PredictorCfg(
        svgp=SVGPCfg(num_inducing=40, epochs=20, max_steps=100),
        classifier_kernel="rbf",
        min_group_size=10,
    )
    path = train_predictor(
        build_windows(train, wc),
        predictor_cfg=cfg,
        trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False),
        out_dir=tmp_path,
        progress=False,
    )
    res, frame = evaluate_prediction(HumanMotionPredictor.load(path), test, return_frame=True)
    # sanity levels for this small training set (chance precision is 1/4)
    assert res["class_precision"] > 0.5
    assert res["mhd_1s"] < 0.1
    assert 0.7 < res["coverage95"] <= 1.0
    assert len(frame) == res["n_windows"]
