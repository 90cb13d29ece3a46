"""HumanMotionPredictor: mixture forecasts, fallbacks, NaN handling, checkpoints."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from iplanner_torch.data.windows import compute_features
from iplanner_torch.errors import (
    CheckpointError,
    ConfigError,
    DataError,
    DataWarning,
    ShapeError,
)
from iplanner_torch.prediction.predictor import (
    CHECKPOINT_VERSION,
    HumanMotionPredictor,
    content_digest,
    gp_inputs,
)

JOINTS = ("torso", "left_hand", "right_hand")


def test_prepare_computes_the_cached_tensors_on_one_thread(trained, monkeypatch) -> None:
    """Loading (and ``prepare``) computes every GP's cached tensors on one thread whatever
    torch's setting, and restores the setting: with the loading process's own count, the
    same checkpoint forecast differently under two threads and under one."""
    from iplanner_torch.prediction import svgp
    from iplanner_torch.types import torch_threads

    path, _ = trained
    seen = []
    original = svgp.SVGPRegressor._refresh_cache

    def spy(self):
        seen.append(torch.get_num_threads())
        return original(self)

    monkeypatch.setattr(svgp.SVGPRegressor, "_refresh_cache", spy)
    with torch_threads(2):
        pred = HumanMotionPredictor.load(path)
        assert torch.get_num_threads() == 2
    assert seen and set(seen) == {1}, seen
    assert len(seen) == len(pred.gps) + len(pred.pooled)


def test_forecast_is_gp_mean_plus_pose(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    fc = pred.predict(w.f_prev[:5], w.progress[:5])
    assert fc.weights.shape == (5, pred.num_actions)
    torch.testing.assert_close(fc.weights.sum(-1), torch.ones(5))
    # the weights are the classifier's p(c | F_prev, p) on standardised features
    x = (w.f_prev[:5] - pred.feat_mean) / pred.feat_std
    torch.testing.assert_close(fc.weights, pred.classifier.predict_proba(x, w.progress[:5]))
    for b in range(5):
        p, c = int(w.progress[b]), int(w.current[b])
        reg = pred.model_for(p, c)
        assert reg is not None
        m_ref, v_ref = reg.predict_gpytorch(gp_inputs(w.f_prev[b : b + 1], 3, "relative"))
        m_ref = m_ref.view(pred.n_future, 3, 3) + w.pose_now[b]
        torch.testing.assert_close(fc.mean[b, c], m_ref, atol=1e-4, rtol=1e-4)
        torch.testing.assert_close(
            fc.var[b, c], v_ref.view(pred.n_future, 3, 3), atol=1e-5, rtol=1e-3
        )


def test_gp_inputs_relative_to_the_current_pose() -> None:
    g = torch.Generator().manual_seed(0)
    f = torch.randn(4, 5, 18, generator=g)  # (B, n_p, D) with K = 2 joints, 3 kinds
    x = gp_inputs(f, 2, "relative").view(4, 5, 18)
    torch.testing.assert_close(x[:, -1], f[:, -1])  # current frame unchanged
    torch.testing.assert_close(x[:, :-1, :6], f[:, :-1, :6] - f[:, -1:, :6])
    torch.testing.assert_close(x[:, :, 6:], f[:, :, 6:])  # derivatives unchanged
    torch.testing.assert_close(gp_inputs(f, 2, "window"), f.reshape(4, -1))
    # a shifted person gives the same relative past, only the current pose moves
    shift = torch.zeros(18)
    shift[:6] = 0.3
    d = gp_inputs(f + shift, 2, "relative").view(4, 5, 18) - x
    assert float(d[:, :-1].abs().max()) < 1e-6 and float((d[:, -1, :6] - 0.3).abs().max()) < 1e-6


def test_batched_forecast_equals_single_window_forecasts(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    idx = torch.arange(0, len(w), max(1, len(w) // 12))  # several progress states
    fc = pred.predict(w.f_prev[idx], w.progress[idx])
    for j, i in enumerate(idx.tolist()):
        one = pred.predict(w.f_prev[i : i + 1], w.progress[i : i + 1])
        torch.testing.assert_close(fc.mean[j], one.mean[0], atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(fc.var[j], one.var[0], atol=1e-7, rtol=1e-5)


def test_unseen_progress_uses_pooled_gp_or_constant_velocity(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    # a valid state whose GPs are gone stands for one never seen in training
    state = max(p for p, _ in pred.gps)
    assert state > 0
    for key in [k for k in pred.gps if k[0] == state]:
        del pred.gps[key]
    pred.prepare()
    unseen = torch.full((2,), state, dtype=torch.int64)
    fc = pred.predict(w.f_prev[:2], unseen)
    assert pred.pooled  # the loop below checks something
    for a in range(pred.num_actions):
        reg = pred.pooled.get(a)
        if reg is not None:
            m, v = reg.predict_gpytorch(gp_inputs(w.f_prev[:2], 3))
            torch.testing.assert_close(
                fc.mean[:, a],
                m.view(2, pred.n_future, 3, 3) + w.pose_now[:2].unsqueeze(1),
                atol=1e-4,
                rtol=1e-4,
            )
            torch.testing.assert_close(
                fc.var[:, a], v.view(2, pred.n_future, 3, 3), atol=1e-5, rtol=1e-3
            )
    # no model at all: constant velocity with the documented variance
    pred.gps.clear()
    pred.pooled.clear()
    pred.prepare()
    fc = pred.predict(w.f_prev[:2], unseen)
    t = torch.arange(1, pred.n_future + 1) / pred.fps
    pos = w.f_prev[:2, :, :9].reshape(2, -1, 3, 3)
    vel = ((pos[:, -1] - pos[:, 0]) * pred.fps / (pos.shape[1] - 1)).unsqueeze(1)
    expect = w.pose_now[:2].unsqueeze(1) + vel * t.view(1, -1, 1, 1)
    for a in range(pred.num_actions):
        torch.testing.assert_close(fc.mean[:, a], expect)
    var_t = pred.cfg.fallback_sigma0**2 + (pred.cfg.fallback_sigma_rate * t) ** 2
    torch.testing.assert_close(fc.var[0, 0, :, 0, 0], var_t)


def test_progress_with_a_bit_of_no_progress_action_is_refused(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    free = next(a for a in range(62) if a not in pred.progress_actions)
    for bad in (1 << free, (1 << 62) | 1 << pred.progress_actions[0], -1):
        with pytest.raises(ConfigError, match="bits of progress actions only"):
            pred.predict(w.f_prev[:2], torch.full((2,), bad, dtype=torch.int64))


def test_predict_positions_refuses_inf_and_non_float_and_ignores_gradients(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    pos = w.f_prev[:2, :, :9].reshape(2, -1, 3, 3).clone()
    progress = w.progress[:2]
    ref = pred.predict_positions(pos, progress)
    got = pred.predict_positions(pos.clone().requires_grad_(True), progress)
    torch.testing.assert_close(got.mean, ref.mean)
    bad = pos.clone()
    bad[1, 2, 0, 1] = math.inf
    with pytest.raises(DataError, match="positions hold inf .*window 1, frame 2"):
        pred.predict_positions(bad, progress)
    for huge in (1e30, 1e39, -150.0):  # 1e39 is inf in float32: it used to read as a lost joint
        bad = pos.clone().double()
        bad[1, 3, 2, 0] = huge
        with pytest.raises(DataError, match=r"beyond 100 m \(first: window 1, frame 3"):
            pred.predict_positions(bad, progress)
    for dtype in (torch.int64, torch.bool):
        with pytest.raises(ShapeError, match="positions of a floating dtype"):
            pred.predict_positions(pos.to(dtype), progress)


def test_predict_positions_with_nan(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    g = torch.Generator().manual_seed(0)
    pos = w.f_prev[:3, :, :9].reshape(3, pred.n_prev, 3, 3).clone()
    pos = pos + 0.001 * torch.randn(pos.shape, generator=g)
    pos[0, 2, 1] = float("nan")  # one lost joint-frame
    fc = pred.predict_positions(pos, w.progress[:3])
    ref = pred.predict(
        compute_features(pos, pred.fps, pred.feature_kinds, joint_names=pred.joint_names),
        w.progress[:3],
    )
    assert bool(torch.isfinite(fc.mean).all())
    torch.testing.assert_close(fc.mean, ref.mean)
    # a joint lost in every frame takes the nearest observed joint along the bones
    pos[1, :, 2] = float("nan")
    fc = pred.predict_positions(pos, w.progress[:3])
    filled = pos.clone()
    filled[1, :, 2] = pos[1, :, pred.joint_names.index("torso")]  # the hand's nearest here
    ref = pred.predict(
        compute_features(filled, pred.fps, pred.feature_kinds, joint_names=pred.joint_names),
        w.progress[:3],
    )
    torch.testing.assert_close(fc.mean, ref.mean)
    pos[2] = float("nan")
    with pytest.raises(DataError, match="no joint is observed in any frame of window 2"):
        pred.predict_positions(pos, w.progress[:3])


def test_wrong_shapes_raise(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    with pytest.raises(ShapeError, match=r"expected f_prev \(B, 6, 27\)"):
        pred.predict(w.f_prev[0], w.progress[:1])
    with pytest.raises(ShapeError, match="expected progress"):
        pred.predict(w.f_prev[:2], w.progress[:3])
    with pytest.raises(ShapeError, match="expected positions"):
        pred.predict_positions(torch.zeros(1, 6, 4, 3), w.progress[:1])


def test_non_finite_windows_raise_naming_window_frame_and_feature(trained) -> None:
    """NaN in F_prev would give a NaN forecast (and a planner that sees no human)."""
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    assert pred.feature_names[:4] == (
        "torso position x",
        "torso position y",
        "torso position z",
        "left_hand position x",
    )
    assert pred.feature_names[9 + 7] == "right_hand velocity y"
    for bad in (float("nan"), float("inf")):
        f = w.f_prev[:3].clone()
        f[1, 4, 9 + 7] = bad
        with pytest.raises(
            DataError, match=r"f_prev is NaN/Inf at window 1, frame 4, 'right_hand velocity y'"
        ):
            pred.predict(f, w.progress[:3])
    # the raw-position entry point still imputes a lost joint-frame
    pos = w.f_prev[:1, :, :9].reshape(1, pred.n_prev, 3, 3).clone()
    pos[0, 4, 2] = float("nan")
    assert bool(torch.isfinite(pred.predict_positions(pos, w.progress[:1]).mean).all())


def test_empty_batch_and_bad_progress_raise(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    with pytest.raises(ShapeError, match="expected at least one window in f_prev"):
        pred.predict(w.f_prev[:0], w.progress[:0])
    with pytest.raises(ShapeError, match="expected at least one window in positions"):
        pred.predict_positions(torch.zeros(0, pred.n_prev, 3, 3), w.progress[:0])
    with pytest.raises(ShapeError, match="expected progress of an integer dtype"):
        pred.predict(w.f_prev[:2], w.progress[:2].float() + 0.5)
    with pytest.raises(
        ConfigError, match=r"expected progress bitmasks >= 0 .*, got -1 \(window 1\)"
    ):
        pred.predict(w.f_prev[:2], torch.tensor([0, -1]))
    # any integer dtype is taken as before
    fc = pred.predict(w.f_prev[:2], w.progress[:2].int())
    torch.testing.assert_close(fc.mean, pred.predict(w.f_prev[:2], w.progress[:2]).mean)


def test_action_weights_and_normalise_features_check_their_input(trained) -> None:
    """The public classifier entry points check windows and progress as predict does (a
    wrong feature count was torch's size-mismatch error, numpy input a TypeError, and
    progress out of range and an empty batch gave weights)."""
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    f, prog = w.f_prev[:2], w.progress[:2]
    weights = pred.action_weights(f, prog)
    assert weights.shape == (2, pred.num_actions)
    torch.testing.assert_close(weights, pred.predict(f, prog).weights)
    with pytest.raises(ShapeError, match="f_prev"):
        pred.action_weights(f[..., :5], prog)
    with pytest.raises(ShapeError, match="expected at least one window in f_prev"):
        pred.action_weights(f[:0], prog[:0])
    with pytest.raises(ConfigError, match=r"expected progress bitmasks >= 0 .*\(window 0\)"):
        pred.action_weights(f, torch.tensor([-5, 1]))
    bad = f.clone()
    bad[0, 1, 2] = float("nan")
    with pytest.raises(DataError, match="f_prev is NaN/Inf at window 0, frame 1"):
        pred.action_weights(bad, prog)
    with pytest.raises(ShapeError, match="f_prev"):
        pred.normalise_features(f.numpy())
    with pytest.raises(ShapeError, match="f_prev"):
        pred.normalise_features(f[:, :, :5])
    with pytest.raises(ShapeError, match=r"expected f_prev on cpu \(the predictor's\), got meta"):
        pred.normalise_features(f.to("meta"))
    torch.testing.assert_close(pred.normalise_features(f), (f - pred.feat_mean) / pred.feat_std)


def test_predict_refuses_non_float_windows_and_far_positions(trained) -> None:
    """As predict_positions: complex (the imaginary part used to be dropped with only torch's
    warning), integer and bool windows are refused, and so are positions beyond 100 m."""
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    f = w.f_prev[:2].clone()
    for dtype in (torch.complex64, torch.int64, torch.bool):
        with pytest.raises(ShapeError, match=f"expected f_prev of a floating dtype, got {dtype}"):
            pred.predict(f.to(dtype), w.progress[:2])
    far = f.clone()
    far[1, 2, 4] = 1e6  # 'left_hand position y'
    with pytest.raises(
        DataError,
        match=r"f_prev holds a position beyond 100 m \(first: window 1, frame 2, "
        r"'left_hand position y': 1e\+06\); positions are metres",
    ):
        pred.predict(far, w.progress[:2])
    # velocities and accelerations are not positions: large ones are taken as they are
    fast = f.clone()
    fast[0, 3, 9 + 4] = 1e3
    assert bool(torch.isfinite(pred.predict(fast, w.progress[:2]).mean).all())
    torch.testing.assert_close(
        pred.predict(f.double(), w.progress[:2]).mean, pred.predict(f, w.progress[:2]).mean
    )


def test_next_action_refuses_unknown_actions_and_bad_progress(trained) -> None:
    """next_action checks its arguments as predict checks progress (one shared check)."""
    path, _ = trained
    pred = HumanMotionPredictor.load(path)
    a_n = pred.num_actions
    assert a_n == 4 and pred.progress_actions == (1, 2)
    probs = pred.next_action(0b010, 0)
    assert probs.shape == (a_n,) and math.isclose(float(probs.sum()), 1.0, rel_tol=1e-6)
    # a numpy or 0-d tensor integer is an integer too
    torch.testing.assert_close(pred.next_action(np.int64(2), torch.tensor(0)), probs)
    for next_model in (pred.next_model, None):  # without a model the arguments are checked too
        pred.next_model = next_model
        for current in (-1, a_n, 99):
            with pytest.raises(
                ConfigError,
                match=rf"expected current an action index in \[0, 4\) \(idle, .*\), got {current}",
            ):
                pred.next_action(0, current)
        for progress in (-1, 1, 1 << 3, 1 << 40):  # bits 0 and 3 are no progress actions
            with pytest.raises(
                ConfigError,
                match=r"expected progress bitmasks >= 0 with bits of progress actions only "
                rf"\(bit a for action a in \[1, 2\]\), got {progress}$",
            ):
                pred.next_action(progress, 0)
        with pytest.raises(
            ShapeError, match="expected current of an integer dtype, got float 1.7"
        ):
            pred.next_action(0, 1.7)
        with pytest.raises(
            ShapeError, match="expected progress of an integer dtype, got float nan"
        ):
            pred.next_action(float("nan"), 0)
        with pytest.raises(ShapeError, match="expected progress of an integer dtype, got bool"):
            pred.next_action(True, 0)
        with pytest.raises(
            ShapeError, match="expected current of an integer dtype, got torch.float32"
        ):
            pred.next_action(0, torch.tensor(1.0))
        with pytest.raises(
            ShapeError, match=r"expected current a single integer, got shape \(2,\)"
        ):
            pred.next_action(0, torch.tensor([0, 1]))


def _rewrite(src: Path, dst: Path, *, digest: bool = True, **changes: object) -> Path:
    """A copy of checkpoint ``src`` with ``changes``; its digest recomputed (a file written
    that way), or with ``digest=False`` kept from ``src`` (a file damaged after writing)."""
    d = torch.load(src, map_location="cpu", weights_only=False)
    d.update(changes)
    if digest:
        d["digest"] = content_digest(d)
    torch.save(d, dst)
    return dst


def test_damaged_or_foreign_checkpoints_raise_checkpoint_errors(trained, tmp_path: Path) -> None:
    path, _ = trained
    assert torch.load(path, weights_only=False)["version"] == CHECKPOINT_VERSION
    old = _rewrite(path, tmp_path / "old.ckpt", version=CHECKPOINT_VERSION + 1)
    with pytest.raises(
        CheckpointError,
        match=rf"old.ckpt has format version {CHECKPOINT_VERSION + 1}; "
        rf"this code reads version {CHECKPOINT_VERSION}",
    ):
        HumanMotionPredictor.load(old)
    none = _rewrite(path, tmp_path / "none.ckpt", version=None)
    with pytest.raises(CheckpointError, match="format version None"):
        HumanMotionPredictor.load(none)
    for i, qualname in enumerate(
        ("nonexistent.mod:X", "iplanner_torch.prediction.ivm:Nope", "no_colon")
    ):
        bad = _rewrite(path, tmp_path / f"cls{i}.ckpt", classifier_class=qualname)
        with pytest.raises(CheckpointError, match=rf"cls{i}.ckpt: classifier_class '{qualname}'"):
            HumanMotionPredictor.load(bad)
    bad = _rewrite(path, tmp_path / "next.ckpt", next_model_class="math:pi")
    with pytest.raises(CheckpointError, match="next.ckpt: next_model_class 'math:pi'"):
        HumanMotionPredictor.load(bad)
    # parts that do not fit together: caught at load, not at the first forecast
    d = torch.load(path, weights_only=False)
    n_f = _rewrite(path, tmp_path / "nf.ckpt", n_future=d["n_future"] - 2)
    with pytest.raises(CheckpointError, match="nf.ckpt is inconsistent: its parts fail"):
        HumanMotionPredictor.load(n_f)
    half = _rewrite(path, tmp_path / "half.ckpt", classifier=None)
    with pytest.raises(CheckpointError, match="half.ckpt: classifier is None but"):
        HumanMotionPredictor.load(half)
    gone = torch.load(path, weights_only=False)
    del gone["classifier"], gone["joint_names"], gone["digest"]  # as an older file
    torch.save(gone, tmp_path / "gone.ckpt")
    with pytest.warns(DataWarning), pytest.raises(CheckpointError, match="gone.ckpt is incompl"):
        HumanMotionPredictor.load(tmp_path / "gone.ckpt", expect_joints=JOINTS)
    # a changed byte inside a tensor (torch reads it without complaint) breaks the digest
    d = torch.load(path, weights_only=False)
    assert d["digest"] == content_digest(d)
    rot = d["feat_mean"].clone()
    rot[0] += 1.0
    rotten = _rewrite(path, tmp_path / "rot.ckpt", digest=False, feat_mean=rot)
    with pytest.raises(CheckpointError, match="rot.ckpt is damaged: its contents do not match"):
        HumanMotionPredictor.load(rotten)
    # written before checkpoints carried a digest: loaded, unchecked, with a DataWarning
    older = torch.load(path, weights_only=False)
    del older["digest"]
    torch.save(older, tmp_path / "older.ckpt")
    with pytest.warns(DataWarning, match="older.ckpt has no content digest.*without the check"):
        loaded = HumanMotionPredictor.load(tmp_path / "older.ckpt")
    assert torch.equal(loaded.feat_mean, HumanMotionPredictor.load(path).feat_mean)
    # saved without a classifier (both fields None): uniform weights, as documented
    plain = _rewrite(path, tmp_path / "plain.ckpt", classifier=None, classifier_class=None)
    assert HumanMotionPredictor.load(plain).classifier is None
    with pytest.raises(CheckpointError, match="is a directory, not a checkpoint file"):
        HumanMotionPredictor.load(tmp_path)
    for bad in (None, 3, ["a.ckpt"]):  # Path() raised a bare TypeError
        with pytest.raises(CheckpointError, match=r"expected path a file path \(str or "
                           r"os.PathLike\) of a predictor checkpoint, got "):  # fmt: skip
            HumanMotionPredictor.load(bad)
    with pytest.raises(ConfigError, match="expected map_location a torch device.*'bogus'"):
        HumanMotionPredictor.load(path, map_location="bogus")
    # the meta device has no data: a setting error, not a damaged file
    with pytest.raises(ConfigError, match="map_location 'meta' holds no numbers"):
        HumanMotionPredictor.load(path, map_location="meta")
    with pytest.raises(ConfigError, match="map_location 'meta'"):
        HumanMotionPredictor.load(path, map_location=torch.device("meta"))


def test_checkpoint_fields_of_the_wrong_type_raise_checkpoint_errors(
    trained, tmp_path: Path
) -> None:
    path, _ = trained
    d = torch.load(path, weights_only=False)
    key = next(iter(d["gps"]))
    cases = {  # each raised the untyped error named
        "gps": (dict(gps=None), "is incomplete or malformed \\(AttributeError: "),
        "n_prev": (dict(n_prev=math.inf), "is incomplete or malformed \\(OverflowError: "),
        "window": (  # IndexError
            dict(gps={**d["gps"], key: {**d["gps"][key], "window": [1]}}),
            "is incomplete or malformed \\(IndexError: ",
        ),
        "version": (dict(version=torch.zeros(3)), "has format version tensor"),  # RuntimeError
        # a numpy array is no plain value: refused at loading (weights_only), unbuilt
        "kind": (
            dict(kind=np.array(["a", "b"])),
            "?: it holds objects other than tensors and plain",
        ),
    }
    for name, (changes, message) in cases.items():
        bad = _rewrite(path, tmp_path / f"{name}.ckpt", **changes)
        with pytest.raises(CheckpointError, match=f"{name}.ckpt {message}"):
            HumanMotionPredictor.load(bad)
    bad = _rewrite(path, tmp_path / "digest.ckpt", digest=False)  # ValueError
    torch.save({**torch.load(bad, weights_only=False), "digest": [0.0, 0.0, 0.0]}, bad)
    with pytest.raises(CheckpointError, match="digest.ckpt is damaged"):
        HumanMotionPredictor.load(bad)
    bad = _rewrite(path, tmp_path / "joints.ckpt", joint_names=None)  # TypeError
    with pytest.raises(CheckpointError, match="joints.ckpt is incomplete: no joint_names"):
        HumanMotionPredictor.load(bad, expect_joints=JOINTS)
    with pytest.raises(ConfigError, match="expected expect_joints a list or tuple.*got 5"):
        HumanMotionPredictor.load(path, expect_joints=5)  # TypeError
    with pytest.raises(ConfigError, match="expected expect_joints a list or tuple.*'torso'"):
        HumanMotionPredictor.load(path, expect_joints="torso")  # split into characters
    too_long = r"cannot look up this path \(File name too long\); expected the path of a ch"
    with pytest.raises(CheckpointError, match=too_long):
        HumanMotionPredictor.load(tmp_path / ("x" * 300 + ".ckpt"))  # OSError


def test_checkpoint_roundtrip_and_errors(trained, tmp_path: Path) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path, expect_joints=JOINTS)
    fc1 = pred.predict(w.f_prev[:4], w.progress[:4])
    p2 = pred.save(tmp_path / "again.ckpt")
    fc2 = HumanMotionPredictor.load(p2).predict(w.f_prev[:4], w.progress[:4])
    torch.testing.assert_close(fc1.mean, fc2.mean)
    torch.testing.assert_close(fc1.weights, fc2.weights)
    assert pred.fingerprint and len(pred.next_action(0, 0)) == pred.num_actions
    with pytest.raises(CheckpointError, match="trained on joints"):
        HumanMotionPredictor.load(path, expect_joints=("head",))
    bad = tmp_path / "truncated.ckpt"
    bad.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(CheckpointError, match=r"truncated.ckpt \(\w+: .*\): the file is cut "
                       "short, damaged or not a torch checkpoint; train it again"):  # fmt: skip
        HumanMotionPredictor.load(bad)
    with pytest.raises(CheckpointError, match="missing.ckpt does not exist"):
        HumanMotionPredictor.load(tmp_path / "missing.ckpt")


def test_the_same_predictor_saves_the_same_bytes(trained, tmp_path: Path) -> None:
    """A resumed run compares its checkpoints' SHA-256 with the ones it began with, so a
    predictor trained again alike must write the same file: the bytes may not depend on the
    file's name or on the temporary name it is written under."""
    path, _ = trained
    pred = HumanMotionPredictor.load(path)
    first = pred.save(tmp_path / "a" / "predictor.ckpt").read_bytes()
    again = pred.save(tmp_path / "a" / "predictor.ckpt").read_bytes()  # replaces the first
    other = pred.save(tmp_path / "b" / "other_name.ckpt").read_bytes()
    assert first == again == other


def test_runs_on_device(trained, device: torch.device) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path, map_location=device)
    fc = pred.predict(w.f_prev[:3].to(device), w.progress[:3].to(device))
    assert fc.mean.device.type == device.type
