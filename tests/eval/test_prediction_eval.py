"""Prediction metrics (paper sec. 7.1) against brute force and exact probabilities."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from scipy.stats import chi2

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.windows import WindowCfg, build_windows
from iplanner_torch.errors import DataWarning, ShapeError
from iplanner_torch.eval.prediction import (
    evaluate_prediction,
    modified_hausdorff,
    short_horizon,
    window_metrics,
)
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
    m = window_metrics(fc, truth, torch.zeros(2000, dtype=torch.int64), truth[:, 0])
    for q in (90, 95, 99):
        share = float(m[f"inside{q}"].float().mean())
        assert abs(share - q / 100) < 0.01, (q, share)
    # a point exactly at the 95 % radius along one axis is inside 95 % but not 90 %
    r = math.sqrt(chi2.ppf(0.95, 3)) * 0.999
    one = _forecast(1)
    t = one.mean[:, 0].clone()
    t[..., 0] += r * one.var[:, 0, ..., 0].sqrt()
    m1 = window_metrics(one, t, torch.zeros(1, dtype=torch.int64), t[:, 0])
    assert bool(m1["inside95"].all()) and not bool(m1["inside90"].any())


def test_regression_precision_accuracy_and_classification() -> None:
    fc = _forecast(3)
    offset = 0.1
    truth = fc.expected_mean() + offset  # every coordinate off by 0.1
    current = torch.tensor([0, 1, 0])
    now = torch.zeros(3, 3, 3)  # (B, K, 3): every joint at the origin now
    m = window_metrics(fc, truth, current, now)
    n_f, k = 15, 3
    expect_prec = n_f * k * 3 * offset**2 * fc.dt
    torch.testing.assert_close(m["reg_precision"], torch.full((3,), expect_prec))
    # two actions: the mixture variance per coordinate is w1 v1 + w2 v2 + w1 w2 (m1 - m2)^2
    w1, w2 = 0.9, 0.1
    v1, v2 = fc.var[:, 0].double(), fc.var[:, 1].double()
    d = (fc.mean[:, 0] - fc.mean[:, 1]).double()
    var_mix = w1 * v1 + w2 * v2 + w1 * w2 * d**2
    expect_acc = (var_mix.prod(-1).sum((-1, -2)) * fc.dt).float()
    torch.testing.assert_close(m["reg_accuracy"], expect_acc, rtol=1e-4, atol=1e-9)
    certain = Forecast(
        weights=torch.tensor([[1.0, 0.0]]).expand(3, 2),
        mean=fc.mean,
        var=fc.var,
        dt=fc.dt,
        joint_names=JOINTS,
        action_names=("a", "b"),
    )
    m_certain = window_metrics(certain, truth, current, now)  # one action: its own variance
    torch.testing.assert_close(
        m_certain["reg_accuracy"], fc.var[:, 0].prod(-1).sum((-1, -2)) * fc.dt
    )
    assert m["correct"].tolist() == [True, False, True]
    for b in range(3):  # moving hand = the hand that gets farther from where it is now
        disp = [float(truth[b, :, j].norm(dim=-1).max()) for j in (1, 2)]
        j = (1, 2)[disp.index(max(disp))]
        assert float(m["hand_motion"][b]) == pytest.approx(max(disp), rel=1e-6)
        ref = _mhd_brute(fc.expected_mean()[b, :, j], truth[b, :, j])
        assert math.isclose(float(m["mhd_1s"][b]), ref, rel_tol=1e-5)
        assert ref <= offset * math.sqrt(3) + 1e-6


def _out_and_back(b: int = 1) -> tuple[Forecast, torch.Tensor, torch.Tensor]:
    """One second at 15 fps: the right hand goes 15 cm out and comes back, the left drifts
    2 cm away; a forecast 1 cm off both. Returns the forecast, the truth (B, 15, 3, 3) and the
    current pose (B, 3, 3)."""
    n_f, dt = 15, 1 / 15
    s = torch.arange(1, n_f + 1, dtype=torch.float64) * dt  # (n_f,)
    now = torch.tensor([[0.0, 0.0, 1.0], [0.5, 0.3, 1.0], [0.5, -0.3, 1.0]], dtype=torch.float64)
    truth = now.expand(b, n_f, 3, 3).clone()  # (B, n_f, K, 3)
    truth[:, :, 1, 1] += 0.02 * s  # left hand: 2 cm in the second
    truth[:, :, 2, 0] += 0.15 * torch.sin(torch.pi * s)  # right hand: out and back
    mean = truth[:, None].expand(b, 2, n_f, 3, 3).clone()  # (B, A, n_f, K, 3)
    mean[..., 0] += 0.01
    fc = Forecast(
        weights=torch.tensor([[0.5, 0.5]], dtype=torch.float64).expand(b, 2),
        mean=mean,
        var=torch.full_like(mean, 1e-4),
        dt=dt,
        joint_names=JOINTS,
        action_names=("a", "b"),
    )
    return fc, truth, now.expand(b, 3, 3).clone()


def test_the_moving_hand_is_the_one_that_gets_farthest_from_where_it_is_now() -> None:
    """A hand that goes out and comes back within the second moves, though it ends where it
    started: its motion is its largest distance from the current pose (as the closed-loop
    eval/mhd measures it), not the distance between the first and last future frames."""
    fc, truth, now = _out_and_back()
    m = window_metrics(fc, truth, torch.zeros(1, dtype=torch.int64), now)
    right = truth[0, :, 2] - now[0, 2]  # (n_f, 3)
    assert float(m["hand_motion"][0]) == pytest.approx(float(right.norm(dim=-1).max()))
    assert float(m["hand_motion"][0]) > 0.14
    ref = _mhd_brute(fc.expected_mean()[0, :, 2], truth[0, :, 2])
    assert float(m["mhd_1s"][0]) == pytest.approx(ref, rel=1e-9)
    with pytest.raises(ShapeError, match=r"expected pose_now \(1, 3, 3\)"):
        window_metrics(fc, truth, torch.zeros(1, dtype=torch.int64), now[:, :2])


def test_evaluate_prediction_measures_hand_motion_from_the_windows_current_pose() -> None:
    """evaluate_prediction counts a window as moving by the distance from the window's
    current pose (pose_now): a hand 6 cm from it in every future frame moves."""
    predictor = _HoldPredictor(15.0, ("reach_0", "reach_1"))
    demo = _still_demo()
    positions = demo.positions.copy()
    positions[10:, 2, 0] += 0.06  # the right hand steps 6 cm at frame 10 and stays there
    demo = Demonstration(
        positions=positions,
        labels=demo.labels,
        fps=demo.fps,
        joint_names=JOINTS,
        action_names=demo.action_names,
    )
    windows = build_windows([demo], WindowCfg(n_prev=4, n_future=3, feature_kinds=("position",)))
    res, frame = evaluate_prediction(predictor, windows, return_frame=True)
    stepped = frame["frame_index"] == 9  # current frame 9: every future frame is 6 cm off
    assert frame.loc[stepped, "hand_motion"].item() == pytest.approx(0.06, rel=1e-5)
    assert res["mhd_1s_moving"] == pytest.approx(float(frame.loc[frame["hand_motion"] > 0.05,
                                                 "mhd_1s"].mean()))  # fmt: skip


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


class _HoldPredictor:
    """Predicts the last observed pose, held still, for the first of its actions; carries the
    frame rate and action names a checkpoint stores."""

    n_prev, n_future = 4, 3
    joint_names = JOINTS
    feature_kinds = ("position",)
    window_cfg: dict = {}

    def __init__(self, fps: float, action_names: tuple[str, ...]) -> None:
        self.fps = fps
        self.action_names = action_names

    def predict(self, f_prev: torch.Tensor, progress: torch.Tensor) -> Forecast:
        b, k, a = f_prev.shape[0], len(JOINTS), len(self.action_names)
        pose = f_prev[:, -1, : 3 * k].reshape(b, 1, 1, k, 3)  # (B, 1, 1, K, 3)
        mean = pose.expand(b, a, self.n_future, k, 3).clone()  # (B, A, n_f, K, 3)
        weights = torch.zeros(b, a)
        weights[:, 0] = 1.0
        return Forecast(
            weights=weights,
            mean=mean,
            var=torch.full_like(mean, 1e-4),
            dt=1.0 / self.fps,
            joint_names=JOINTS,
            action_names=self.action_names,
        )


def _still_demo(
    fps: float = 15.0, actions: tuple[str, ...] = ("reach_0", "reach_1"), frames: int = 20
):
    """A person standing still for ``frames`` frames while doing action 0."""
    pose = np.array([[0.0, 0.0, 1.0], [0.3, 0.2, 1.0], [0.3, -0.2, 1.0]])
    return Demonstration(
        positions=np.repeat(pose[None], frames, axis=0),
        labels=np.zeros(frames),
        fps=fps,
        joint_names=JOINTS,
        action_names=actions,
    )


def test_matching_data_evaluates_without_warning() -> None:
    predictor = _HoldPredictor(15.0, ("reach_0", "reach_1"))
    predictor.n_future = 15  # a 1 s horizon: no warning about a shorter one
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = evaluate_prediction(predictor, [_still_demo()])
    assert res["n_windows"] == 20 - 4 - 15 + 1
    assert res["class_accuracy"] == 1.0 and res["reg_precision"] == pytest.approx(0.0, abs=1e-12)


def test_a_horizon_shorter_than_a_second_is_said_to_shorten_mhd_1s() -> None:
    """A 30 Hz recording cut with the 15 Hz defaults (n_future 15) forecasts 0.5 s: mhd_1s
    was then the MHD over 0.5 s under its 1 s name, without a word."""
    predictor = _HoldPredictor(30.0, ("reach_0", "reach_1"))
    predictor.n_future = 15
    match = (r"forecasts 15 frames at 30 Hz, 0\.5 s: mhd_1s, mhd_1s_moving and the 'moving' "
             r"test cover those 0\.5 s, not 1 s; .* data\.windows\.n_future=30")  # fmt: skip
    with pytest.warns(DataWarning, match=match):
        res = evaluate_prediction(predictor, [_still_demo(fps=30.0, frames=40)])
    assert res["n_windows"] == 40 - 4 - 15 + 1
    assert short_horizon(predictor) == pytest.approx(0.5)
    predictor.n_future = 30
    assert short_horizon(predictor) is None


def test_frame_rate_mismatch_warns_and_still_evaluates() -> None:
    """A 30 fps checkpoint on 15 fps data: a DataWarning naming both rates."""
    predictor = _HoldPredictor(30.0, ("reach_0", "reach_1"))
    with pytest.warns(DataWarning, match="data is at 15 fps but the predictor was trained at 30"):
        res = evaluate_prediction(predictor, [_still_demo()])
    assert res["n_windows"] == 14 and res["reg_precision"] == pytest.approx(0.0, abs=1e-12)


def test_action_name_mismatch_warns_on_demonstrations_and_windows() -> None:
    """A checkpoint of unlabelled motion on the reaching set: the class metrics mean nothing."""
    predictor = _HoldPredictor(15.0, ("unlabelled",))
    demo = _still_demo()
    match = r"data has 2 actions \(reach_0, reach_1\) but the predictor was trained on 1 action"
    with pytest.warns(DataWarning, match=match) as rec:
        evaluate_prediction(predictor, [demo])
    assert not any("fps" in str(r.message) for r in rec)  # the frame rates agree
    windows = build_windows([demo], WindowCfg(n_prev=4, n_future=3, feature_kinds=("position",)))
    with pytest.warns(DataWarning, match="class_\\* metrics compare unrelated labels"):
        res = evaluate_prediction(predictor, windows)
    assert res["n_windows"] == len(windows)


def test_action_mismatch_drops_progress_bits_the_predictor_has_no_state_for() -> None:
    """Data whose actions outnumber the predictor's: the progress bit of its action 2 has no
    state in a predictor whose progress actions are (1,), and its predict() refuses such a
    bit; evaluation drops it (said in the warning) instead of failing on the bitmask."""
    seen: list[torch.Tensor] = []

    class Strict(_HoldPredictor):
        progress_actions = (1,)

        def predict(self, f_prev: torch.Tensor, progress: torch.Tensor) -> Forecast:
            assert not bool((progress & ~0b10).any()), "a bit of no progress action"
            seen.append(progress)
            return super().predict(f_prev, progress)

    demo = _still_demo(actions=("idle", "reach_0", "reach_1"))
    demo = Demonstration(
        positions=demo.positions,
        labels=np.array([2] * 6 + [1] * 6 + [0] * 8),  # reach_1, then reach_0 done
        fps=demo.fps,
        joint_names=JOINTS,
        action_names=demo.action_names,
    )
    with pytest.warns(DataWarning, match=r"bits of actions the predictor has no progress "
                      r"state for are dropped"):  # fmt: skip
        res = evaluate_prediction(Strict(15.0, ("idle", "take_0")), [demo])
    got = torch.cat(seen)
    assert res["n_windows"] == len(got) == 14
    windows = build_windows([demo], WindowCfg(n_prev=4, n_future=3, feature_kinds=("position",)))
    assert set(windows.progress.tolist()) == {0, 0b100, 0b110}  # the data's own bits
    assert torch.equal(got, windows.progress & 0b10)


def test_training_inputs_record_reads_or_is_refused_by_name(tmp_path) -> None:
    """One reader of training_inputs.json: None without it, the record beside a checkpoint or
    in a folder, a CheckpointError naming the file when it is no JSON object; the recorded
    split then falls back to seed and data.split with a warning."""
    import json

    from iplanner_torch.errors import CheckpointError
    from iplanner_torch.eval.prediction import (
        INPUTS_FILE,
        SplitRecord,
        read_training_inputs,
        recorded_split,
    )

    ckpt = tmp_path / "predictor.ckpt"
    assert read_training_inputs(tmp_path) is None and recorded_split(ckpt, "abc") is None
    split = {"seed": 2, "fractions": [0.6, 0.2, 0.2], "held_out": ["d1"]}
    (tmp_path / INPUTS_FILE).write_text(json.dumps({"fingerprint": "abc", "split": split}))
    assert read_training_inputs(ckpt) == read_training_inputs(tmp_path)
    assert recorded_split(ckpt, "abc") == SplitRecord(
        seed=2, fractions=(0.6, 0.2, 0.2), held_out=("d1",)
    )
    assert recorded_split(ckpt, "other") is None  # the folder was trained anew since
    bad = {"fingerprint": "abc", "split": dict(split, fractions=[0.5, 0.5, 0.5])}
    for text, why in (
        ("\xff", "JSONDecodeError"),
        ("[" * 100000, "JSON nested too deep"),  # a raw RecursionError before
        ("null", "expected a JSON object, got NoneType"),
        (json.dumps(bad), r"ConfigError: fractions: expected 3 non-negative shares"),
        (json.dumps({"fingerprint": "abc", "split": {"fractions": [1, 0, 0]}}), "KeyError"),
        # numpy refused a negative seed with a raw traceback in iplanner-evaluate; true, 1.7
        # and "1" were read as 1, a held_out string as its letters
        (json.dumps(bad | {"split": dict(split, seed=-5)}), "ValueError: split seed -5"),
        (json.dumps(bad | {"split": dict(split, seed=True)}), "ValueError: split seed True"),
        (json.dumps(bad | {"split": dict(split, seed=1.7)}), "ValueError: split seed 1.7"),
        (json.dumps(bad | {"split": dict(split, seed="1")}), "ValueError: split seed '1'"),
        (json.dumps(bad | {"split": dict(split, held_out="d1")}), "TypeError: split held_out"),
        (json.dumps(bad | {"split": dict(split, held_out=[1])}), "TypeError: split held_out"),
        (json.dumps(bad | {"split": dict(split, fractions="0.6")}), "TypeError: split fractions"),
        (json.dumps(bad | {"split": [2]}), "TypeError: split is list"),
    ):
        (tmp_path / INPUTS_FILE).write_text(text)
        if "fingerprint" not in text:
            with pytest.raises(CheckpointError, match=f"{INPUTS_FILE} is unreadable \\({why}"):
                read_training_inputs(ckpt)
        with pytest.warns(DataWarning, match=f"cannot read the held-out split of .*{why}"):
            assert recorded_split(ckpt, "abc") is None


def test_recorded_split_takes_only_the_record_of_the_checkpoints_training(tmp_path) -> None:
    """A checkpoint keeps the inputs_digest of its record: another run's record beside it (a
    retrain started since and interrupted, which wrote its record at its start) is refused, or
    passed over with a warning when the split is given; with the same fingerprint it was read
    as the checkpoint's, so evaluation scored a split that held out other demonstrations."""
    import json

    from iplanner_torch.errors import CheckpointError
    from iplanner_torch.eval.prediction import (
        INPUTS_FILE,
        SplitRecord,
        inputs_digest,
        recorded_split,
    )

    ckpt = tmp_path / "predictor.ckpt"
    own = {"fingerprint": "abc", "split": {"seed": 1, "fractions": [0.6, 0.2, 0.2]}}
    later = {"fingerprint": "abc", "split": {"seed": 0, "fractions": [0.6, 0.2, 0.2]}}
    digest = inputs_digest(own)
    (tmp_path / INPUTS_FILE).write_text(json.dumps(own))
    assert recorded_split(ckpt, "abc", digest) == SplitRecord(seed=1, fractions=(0.6, 0.2, 0.2))
    (tmp_path / INPUTS_FILE).write_text(json.dumps(later))
    assert recorded_split(ckpt, "abc").seed == 0  # a checkpoint without a digest: as before
    with pytest.raises(
        CheckpointError,
        match=rf"{INPUTS_FILE} is not the record of .*"
        r"predictor.ckpt \(it records the split seed=0 data.split=\[0.6,0.2,0.2\]\).*retrain",
    ):
        recorded_split(ckpt, "abc", digest)
    with pytest.warns(DataWarning, match="was interrupted before.*drawn from seed"):
        assert recorded_split(ckpt, "abc", digest, split_given=True) is None
    # a checkpoint copied beside another predictor's record: the settings that differ are named
    other = {**later, "predictor_cfg": {"svgp": {"noisy_input": "none", "num_inducing": 8}}}
    (tmp_path / INPUTS_FILE).write_text(json.dumps(other))
    own_cfg = {"svgp": {"noisy_input": "simple", "num_inducing": 8}}
    with pytest.raises(CheckpointError, match=r"predictor settings: svgp.noisy_input 'none' "
                       r"\(record\) / 'simple'\. Either a training"):  # fmt: skip
        recorded_split(ckpt, "abc", digest, predictor_cfg=own_cfg)


def test_a_constant_velocity_forecast_of_linear_motion_scores_zero_error_and_no_class() -> None:
    """Joints moving in straight lines at constant speed: the constant-velocity forecast is
    exact (MHD and regression error 0), and without an action model the class metrics are
    NaN rather than a score of labels it does not have."""
    from iplanner_torch.prediction.constant_velocity import (
        ConstantVelocityCfg,
        ConstantVelocityPredictor,
    )

    fps, frames = 15.0, 40
    t = np.arange(frames)[:, None, None] / fps
    pose = np.array([[0.0, 0.0, 1.0], [0.3, 0.2, 1.0], [0.3, -0.2, 1.0]])
    velocity = np.array([[0.0, 0.0, 0.0], [0.2, -0.1, 0.05], [-0.3, 0.0, 0.1]])
    demo = Demonstration(
        positions=pose[None] + velocity[None] * t,
        labels=np.zeros(frames),
        fps=fps,
        joint_names=JOINTS,
        action_names=("reach_0", "reach_1"),
    )
    cv = ConstantVelocityPredictor(
        ConstantVelocityCfg(n_prev=4, fit_frames=4, n_future=15), fps=fps, joint_names=JOINTS
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no action-name mismatch warned of
        res = evaluate_prediction(cv, [demo])
    assert res["n_windows"] == frames - 4 - 15 + 1
    assert res["mhd_1s"] == pytest.approx(0.0, abs=1e-6)
    assert res["reg_precision"] == pytest.approx(0.0, abs=1e-9)
    assert res["mhd_1s_moving"] == pytest.approx(0.0, abs=1e-6)  # the right hand moves 32 cm
    for key in ("class_precision", "class_accuracy", "class_confident", "n_confident"):
        assert math.isnan(res[key]), key
    assert res["coverage95"] == 1.0  # every true position at its predicted mean


def test_a_top_probability_of_exactly_one_half_is_not_confident() -> None:
    """``class_precision`` counts windows whose top probability *exceeds* 0.5: a forecast
    split 0.5 / 0.5 is not confident, one of 0.6 is."""
    from iplanner_torch.data.reaching import ReachingCfg, reaching_demonstrations
    from iplanner_torch.eval.prediction import evaluate_prediction

    demos = reaching_demonstrations(ReachingCfg(n_targets=2), 0, 0)[:1]
    windows = build_windows(demos, WindowCfg(n_prev=5, n_future=15, stride=4))
    a = len(windows.action_names)

    class Split:
        fps, n_future, progress_actions = windows.fps, 15, None
        action_names = windows.action_names

        def predict(self, f_prev: torch.Tensor, progress: torch.Tensor) -> Forecast:
            b = f_prev.shape[0]
            w = torch.zeros(b, a)
            w[:, :2] = torch.tensor([0.5, 0.5])
            w[::2, :2] = torch.tensor([0.6, 0.4])
            mean = torch.zeros(b, a, 15, windows.xi_next.shape[2], 3)
            var = torch.full_like(mean, 0.01)
            names = {"joint_names": windows.joint_names, "action_names": self.action_names}
            return Forecast(weights=w, mean=mean, var=var, dt=1 / 15, **names)

    got = evaluate_prediction(Split(), windows)
    assert got["n_confident"] == (len(windows) + 1) // 2 and len(windows) > 2


def test_window_metrics_refuses_labels_that_would_be_broadcast_or_are_not_indices() -> None:
    """A (1,) ``current`` for two windows was broadcast: every window scored against its one
    label, with no error; a float one was taken; a float64 ``xi_true`` was refused with the
    names of an internal function's arguments."""
    fc = _forecast(2)
    truth = fc.mean[:, 0].clone()
    now = truth[:, 0]
    with pytest.raises(ShapeError, match="current"):
        window_metrics(fc, truth, torch.tensor([1]), now)
    with pytest.raises(ShapeError, match="current"):
        window_metrics(fc, truth, torch.tensor([1.0, 0.0]), now)
    with pytest.raises(ShapeError, match="xi_true of the forecast's dtype"):
        window_metrics(fc, truth.double(), torch.tensor([1, 0]), now)
    m = window_metrics(fc, truth, torch.tensor([0, -1]), now)  # -1: no label, not correct
    assert m["correct"].tolist() == [True, False]
