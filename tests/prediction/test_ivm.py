"""Import Vector Machine: learning on synthetic windows, greedy selection, fallbacks, I/O."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch
from scipy.optimize import minimize

from iplanner_torch.data.windows import compute_features
from iplanner_torch.errors import CheckpointError, ConfigError, DataError, ShapeError
from iplanner_torch.prediction.dtw import (
    DTWKernel,
    GlobalAlignmentKernel,
    RBFKernel,
    gak_sigma,
    median_dtw,
)
from iplanner_torch.prediction.ivm import ActionClassifier, IVMClassifier, feature_columns

pytestmark = pytest.mark.usefixtures("one_thread")


def sine_windows(n: int, seed: int, classes=(0, 1, 2), t: int = 12, d: int = 3):
    """Noisy sine windows whose frequency is set by the class, random phase."""
    g = torch.Generator().manual_seed(seed)
    cls = torch.tensor(classes)
    y = cls[torch.randint(0, len(classes), (n,), generator=g)]
    time = torch.linspace(0.0, 1.0, t)
    freq = 1.0 + y.double()
    phase = 2 * math.pi * torch.rand(n, generator=g, dtype=torch.float64)
    base = torch.sin(2 * math.pi * freq[:, None] * time[None] + phase[:, None])  # (n, t)
    x = base[:, :, None] + 0.25 * torch.randn(n, t, d, generator=g, dtype=torch.float64)
    return x.float(), y


@pytest.fixture(scope="module")
def data():
    return sine_windows(150, 0), sine_windows(150, 1)


def test_dtw_ivm_learns_and_loss_is_monotone(data):
    (x, y), (xt, yt) = data
    kernel = DTWKernel(median_dtw(x, 300, seed=0))
    ivm = IVMClassifier(kernel, num_classes=4, max_import=25, seed=0).fit(x, y)
    assert (ivm.predict(x) == y).float().mean() >= 0.95
    assert (ivm.predict(xt) == yt).float().mean() >= 0.90
    h = np.array(ivm.loss_history_)
    assert len(h) >= 3 and np.all(np.diff(h) <= 1e-9)
    assert h[-1] < 0.5 * h[0]
    prob = ivm.predict_proba(xt)
    assert prob.shape == (150, 4) and prob.dtype == torch.float32
    torch.testing.assert_close(prob.sum(-1), torch.ones(150), atol=1e-6, rtol=0)
    assert (prob[:, 3] == 0).all()  # class 3 never seen: fixed -inf logit
    assert torch.isinf(ivm.decision_function(xt[:2])[:, 3]).all()
    assert len(ivm.import_index_) <= 25


def test_gak_and_rbf_kernels_learn(data):
    (x, y), (xt, yt) = data
    for kernel in (GlobalAlignmentKernel(2.0), RBFKernel(3.0)):
        ivm = IVMClassifier(kernel, num_classes=3, max_import=20).fit(x, y)
        assert (ivm.predict(xt) == yt).float().mean() >= 0.90, kernel


def test_gak_learns_with_its_automatic_bandwidth(data):
    """Training's GAK bandwidth (``classifier_bandwidth`` unset) follows Cuturi's rule,
    median DTW / sqrt(T); sqrt(median DTW / T), the rule before, classified 87 % of these."""
    from iplanner_torch.prediction.predictor import PredictorCfg
    from iplanner_torch.prediction.training import _classifier_kernel_factory

    (x, y), (xt, yt) = data
    kernel = _classifier_kernel_factory(PredictorCfg(classifier_kernel="gak", seed=0))(x)
    med = median_dtw(x, 256, 0)
    assert isinstance(kernel, GlobalAlignmentKernel)
    assert kernel.sigma == pytest.approx(med / math.sqrt(x.shape[1]))
    ivm = IVMClassifier(kernel, num_classes=3, max_import=20).fit(x, y)
    assert (ivm.predict(xt) == yt).float().mean() >= 0.97


def test_gak_sigma_rule() -> None:
    assert gak_sigma(12.0, 9) == pytest.approx(4.0)
    assert gak_sigma(0.0, 5) == 1e-3  # all windows alike: a floor, not 0
    with pytest.raises(ConfigError, match="length"):
        gak_sigma(1.0, 0)
    with pytest.raises(ConfigError, match="median_distance"):
        gak_sigma(float("nan"), 4)


def test_same_seed_same_model(data):
    (x, y), _ = data
    kern = RBFKernel(3.0)
    a = IVMClassifier(kern, num_classes=3, max_import=8, candidates=20, seed=3).fit(x, y)
    b = IVMClassifier(kern, num_classes=3, max_import=8, candidates=20, seed=3).fit(x, y)
    assert torch.equal(a.import_index_, b.import_index_)
    torch.testing.assert_close(a.weights_, b.weights_, atol=0, rtol=0)


def test_first_import_is_brute_force_argmin():
    x, y = sine_windows(14, 5, classes=(0, 1), t=6, d=2)
    kernel = RBFKernel(2.0)
    lam = 0.05
    ivm = IVMClassifier(
        kernel, num_classes=2, lam=lam, max_import=1, candidates=None, newton_steps=300
    ).fit(x, y)
    kmat = kernel(x, x).double().numpy()
    onehot = np.eye(2)[y.numpy()]
    shift = 1e-8

    def h(theta: np.ndarray, j: int) -> float:
        b, v = theta[:2], theta[2:]
        f = b[None, :] + kmat[:, j : j + 1] * v[None, :]  # (N, 2)
        lse = np.logaddexp(f[:, 0], f[:, 1])
        nll = -(onehot * (f - lse[:, None])).sum()
        return nll + 0.5 * lam * (kmat[j, j] + shift) * float(v @ v)

    best = [minimize(h, np.zeros(4), args=(j,), method="BFGS", tol=1e-12).fun for j in range(14)]
    assert int(ivm.import_index_[0]) == int(np.argmin(best))
    gap = sorted(best)[1] - sorted(best)[0]
    assert gap > 1e-3  # the test problem has a unique winner
    assert abs(ivm.loss_history_[1] - min(best)) < 1e-6 * abs(min(best))


@pytest.mark.parametrize("kind", ["rbf", "dtw"])
def test_final_fit_is_the_exact_kernel_logistic_regression_on_its_imports(kind: str) -> None:
    """On the import vectors it chose, the IVM's final H and probabilities are scipy's minimum
    of the documented objective: softmax NLL + lam / 2 sum_c a_c^T (K_SS + s I) a_c, with s
    the jitter plus, for the indefinite DTW kernel, the shift to the smallest eigenvalue."""
    from iplanner_torch.prediction import ivm as ivm_module

    x, y = sine_windows(40, 8, classes=(0, 1, 2), t=6, d=2)
    # a wide DTW kernel: its Gram on these 40 windows is indefinite (smallest eigenvalue -0.05)
    kernel = RBFKernel(2.0) if kind == "rbf" else DTWKernel(4 * median_dtw(x, 200, seed=0))
    lam = 0.05
    ivm = IVMClassifier(
        kernel, num_classes=3, lam=lam, max_import=4, tol=0.0, candidates=None, newton_steps=200
    ).fit(x, y)
    sel = ivm.import_index_.tolist()
    assert len(sel) == 4
    kmat = kernel(x, x).double().numpy()
    kmat = 0.5 * (kmat + kmat.T)
    eig_min = float(np.linalg.eigvalsh(kmat)[0])
    shift = ivm_module._JITTER * float(np.abs(np.diag(kmat)).mean())
    if kind == "dtw":
        assert eig_min < -0.01  # the shift is exercised
        shift += -eig_min * (1.0 + 1e-6)
    k_ns = kmat[:, sel]  # (N, 4)
    pen = kmat[np.ix_(sel, sel)] + shift * np.eye(4)
    onehot = np.eye(3)[y.numpy()]

    def h(theta: np.ndarray) -> float:
        b, a = theta[:3], theta[3:].reshape(4, 3)
        f = b[None] + k_ns @ a  # (N, 3)
        lse = np.log(np.exp(f - f.max(1, keepdims=True)).sum(1)) + f.max(1)
        return float(-(onehot * (f - lse[:, None])).sum() + 0.5 * lam * np.trace(a.T @ pen @ a))

    best = minimize(h, np.zeros(15), method="BFGS", options={"gtol": 1e-10, "maxiter": 5000})
    assert ivm.loss_history_[-1] == pytest.approx(best.fun, rel=1e-8)
    b, a = best.x[:3], best.x[3:].reshape(4, 3)
    xt, _ = sine_windows(7, 9, classes=(0, 1, 2), t=6, d=2)
    f = b[None] + kernel(xt, x[sel]).double().numpy() @ a
    p_ref = np.exp(f - f.max(1, keepdims=True))
    p_ref /= p_ref.sum(1, keepdims=True)
    np.testing.assert_allclose(ivm.predict_proba(xt).double().numpy(), p_ref, atol=2e-6)


def test_state_dict_round_trip(data):
    (x, y), (xt, _) = data
    ivm = IVMClassifier(DTWKernel(4.0, band=3), num_classes=3, max_import=6).fit(x, y)
    again = IVMClassifier.from_state_dict(ivm.state_dict())  # kernel rebuilt by name
    assert torch.equal(again.predict_proba(xt), ivm.predict_proba(xt))
    custom = IVMClassifier.from_state_dict(ivm.state_dict(), DTWKernel(4.0, band=3))
    assert torch.equal(custom.predict_proba(xt), ivm.predict_proba(xt))
    with pytest.raises(CheckpointError, match="format ivm/1"):
        IVMClassifier.from_state_dict({"format": "other"})


def test_single_class_and_errors():
    x, _ = sine_windows(10, 2)
    ivm = IVMClassifier(RBFKernel(1.0), num_classes=3).fit(x, torch.full((10,), 2))
    prob = ivm.predict_proba(x)
    assert torch.equal(prob, torch.tensor([0.0, 0.0, 1.0]).expand(10, 3))
    with pytest.raises(ShapeError, match=r"expected y \(10\), got \(9,\)"):
        ivm.fit(x, torch.zeros(9, dtype=torch.int64))
    with pytest.raises(ShapeError, match=r"expected x \(N, T, D\)"):
        ivm.predict_proba(x[0])
    with pytest.raises(DataError, match=r"expected y in \[0, 3\)"):
        ivm.fit(x, torch.full((10,), 3))
    with pytest.raises(ShapeError, match="int64"):
        ivm.fit(x, torch.zeros(10))
    with pytest.raises(ConfigError, match="lam > 0"):
        IVMClassifier(RBFKernel(1.0), num_classes=3, lam=0.0)
    for value in (math.nan, math.inf):  # nan <= 0 is False: these used to pass
        with pytest.raises(ConfigError, match=f"expected lam > 0 and finite, got {value}"):
            IVMClassifier(RBFKernel(1.0), num_classes=3, lam=value)
        with pytest.raises(ConfigError, match=f"expected tol >= 0 and finite, got {value}"):
            IVMClassifier(RBFKernel(1.0), num_classes=3, tol=value)
    with pytest.raises(CheckpointError, match="not fitted"):
        IVMClassifier(RBFKernel(1.0), num_classes=3).predict_proba(x)


def _state_data():
    """Progress 1: actions {0, 1} (frequencies 1, 2); progress 3: action 2 only."""
    x01, y01 = sine_windows(80, 10, classes=(0, 1))
    x2, y2 = sine_windows(20, 11, classes=(2,))
    x = torch.cat([x01, x2])
    cur = torch.cat([y01, y2])
    prog = torch.cat([torch.full((80,), 1), torch.full((20,), 3)])
    return x, prog, cur


def test_action_classifier_states_and_fallbacks():
    x, prog, cur = _state_data()
    calls = []

    def factory(xs):
        calls.append(len(xs))
        return RBFKernel(3.0)

    clf = ActionClassifier().fit(
        x, prog, cur, num_actions=3, kernel_factory=factory, ivm_kwargs={"max_import": 10}
    )
    assert sorted(calls) == [80, 100]  # state 1 and the global one; state 3 needs no kernel
    # single-action state: exactly 1
    p3 = clf.predict_proba(x[80:], torch.full((20,), 3))
    assert torch.equal(p3, torch.tensor([0.0, 0.0, 1.0]).expand(20, 3))
    # seen state 1 learns its two actions
    p1 = clf.predict_proba(x[:80], prog[:80])
    assert (p1.argmax(-1) == cur[:80]).float().mean() >= 0.95
    assert (p1[:, 2] == 0).all()
    # unseen 0b111: related seen states 1 (distance 2) and 3 (distance 1) -> 3
    assert clf.resolve(7) == 3
    # unseen 0b010: subset of 3 (distance 1), unrelated to 1 -> 3; 0b100: none -> global
    assert clf.resolve(2) == 3
    assert clf.resolve(4) == -1
    # a mixed batch is grouped by state and equals the per-state calls
    progress = torch.tensor([1, 3, 7, 4, 1])
    batch = clf.predict_proba(x[[0, 85, 1, 2, 3]], progress)
    torch.testing.assert_close(batch[2], clf.models_[3].predict_proba(x[[1]])[0])
    torch.testing.assert_close(batch[3], clf.models_[-1].predict_proba(x[[2]])[0])
    torch.testing.assert_close(batch.sum(-1), torch.ones(5), atol=1e-6, rtol=0)
    # round trip
    again = ActionClassifier.from_state_dict(clf.state_dict())
    assert torch.equal(again.predict_proba(x[[0, 85, 1, 2, 3]], progress), batch)
    with pytest.raises(ShapeError, match=r"expected progress \(5\)"):
        clf.predict_proba(x[:5], progress[:4])


def test_action_classifier_tie_prefers_subset_and_no_global():
    x, prog, cur = _state_data()
    prog = torch.where(prog == 3, torch.tensor(6), torch.tensor(3))  # seen: 3 (0b011), 6 (0b110)
    clf = ActionClassifier().fit(
        x,
        prog,
        cur,
        num_actions=3,
        kernel_factory=lambda: RBFKernel(3.0),
        ivm_kwargs={"max_import": 4},
        fit_global=False,
    )
    assert clf.resolve(2) == 3  # 0b010: subset of both at distance 1 -> smaller q
    assert clf.resolve(7) == 3  # 0b111: both subsets at distance 1 -> smaller q
    assert clf.resolve(8) == -1
    uniform = clf.predict_proba(x[:2], torch.tensor([8, 8]))
    torch.testing.assert_close(uniform, torch.full((2, 3), 1 / 3))


def test_feature_columns_pick_the_blocks_of_compute_features():
    names = ("head", "left_hand", "right_hand")
    kinds = ("position", "velocity", "acceleration")
    t = torch.linspace(0.0, 1.0, 9, dtype=torch.float64)
    pos = torch.stack(
        [torch.stack([t * (k + 1), t**2 * (k + 2), -t * (k + 3)], -1) for k in range(3)], 1
    )  # (T, K, 3), a different trajectory per joint
    feats = compute_features(pos, fps=8.0, kinds=kinds)  # (T, 27)
    vel = torch.gradient(pos, spacing=1.0 / 8.0, dim=0, edge_order=2)[0]
    cols = feature_columns(names, kinds, ("right_hand", "left_hand"), ("velocity", "position"))
    want = torch.cat([vel[:, 2], vel[:, 1], pos[:, 2], pos[:, 1]], -1)  # (T, 12)
    torch.testing.assert_close(feats[:, cols], want, atol=1e-12, rtol=0)
    assert feature_columns(names, kinds) == [3, 4, 5, 6, 7, 8, 12, 13, 14, 15, 16, 17]
    with pytest.raises(ConfigError, match="no joints or feature kinds.*'left_elbow'"):
        feature_columns(names, kinds, ("left_elbow",))
    with pytest.raises(ConfigError, match="no joints or feature kinds.*'jerk'"):
        feature_columns(names, kinds, kinds=("jerk",))


def test_action_classifier_feature_index_equals_selected_input():
    x, prog, cur = _state_data()
    g = torch.Generator().manual_seed(12)
    noise = torch.randn(x.shape[0], x.shape[1], 4, generator=g)
    full = torch.cat([noise[..., :2], x, noise[..., 2:]], -1)  # (N, T, 7): columns 2..4 signal
    kw = {"num_actions": 3, "kernel_factory": lambda: RBFKernel(3.0)}
    kw["ivm_kwargs"] = {"max_import": 6}
    sel = ActionClassifier(feature_index=[2, 3, 4]).fit(full, prog, cur, **kw)
    ref = ActionClassifier().fit(x, prog, cur, **kw)
    progress = torch.tensor([1, 3, 1, 4])
    rows = [0, 85, 7, 3]
    want = ref.predict_proba(x[rows], progress)
    assert torch.equal(sel.predict_proba(full[rows], progress), want)
    again = ActionClassifier.from_state_dict(sel.state_dict())
    assert again.feature_index == [2, 3, 4]
    assert torch.equal(again.predict_proba(full[rows], progress), want)
    with pytest.raises(ShapeError, match=r"more than 4 features, got \(4, 12, 3\)"):
        sel.predict_proba(x[rows], progress)
    with pytest.raises(ConfigError, match="non-negative columns"):
        ActionClassifier(feature_index=[-1, 2])


def _fitted_classifier():
    x, prog, cur = _state_data()
    clf = ActionClassifier().fit(
        x,
        prog,
        cur,
        num_actions=3,
        kernel_factory=lambda xs: DTWKernel(median_dtw(xs, 100, seed=0)),
        ivm_kwargs={"max_import": 6},
    )
    return clf, x[[0, 85, 1, 2]], torch.tensor([1, 3, 7, 4])


def test_to_keeps_predictions_on_cpu():
    clf, x, progress = _fitted_classifier()
    before = clf.predict_proba(x, progress)
    assert clf.to("cpu") is clf
    assert torch.equal(clf.predict_proba(x, progress), before)
    assert clf.models_[1].weights_.dtype == torch.float64


@pytest.mark.gpu
def test_to_cuda_matches_cpu():
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    clf, x, progress = _fitted_classifier()
    want = clf.predict_proba(x, progress)
    clf.to("cuda")
    ivm = clf.models_[1]
    assert ivm.import_vectors_.is_cuda and ivm.weights_.is_cuda and ivm.classes_.is_cuda
    got = clf.predict_proba(x.cuda(), progress.cuda())
    assert got.is_cuda
    torch.testing.assert_close(got.cpu(), want, atol=1e-5, rtol=1e-5)
    state = ActionClassifier.from_state_dict(clf.state_dict())  # a CUDA model saves CPU tensors
    assert not state.models_[1].weights_.is_cuda
    torch.testing.assert_close(state.predict_proba(x, progress), want, atol=1e-6, rtol=0)


def test_windows_of_another_width_name_the_trained_one(data):
    (x, y), _ = data
    ivm = IVMClassifier(GlobalAlignmentKernel(2.0), num_classes=3, max_import=4).fit(x, y)
    d = x.shape[-1]
    with pytest.raises(ShapeError, match=rf"expected x \(B, T, {d}\) as the classifier was"):
        ivm.predict_proba(torch.zeros(2, x.shape[1], d + 1, dtype=x.dtype))


@pytest.mark.parametrize(
    ("setting", "value"),
    [
        ("num_classes", "2"),
        ("num_classes", 2.5),
        ("max_import", math.nan),
        ("max_import", 4.0),
        ("candidates", 1.5),
        ("newton_steps", "3"),
        ("seed", None),
    ],
)
def test_integer_settings_are_refused_unless_integers(setting: str, value: object) -> None:
    """num_classes="2" and max_import=nan used to raise raw errors, 2.5 became 2."""
    kwargs: dict[str, object] = {"num_classes": 3, setting: value}
    with pytest.raises(ConfigError, match=re.escape(f"expected {setting} an integer")):
        IVMClassifier(RBFKernel(1.0), **kwargs)  # type: ignore[arg-type]


def test_rbf_ivm_names_the_callers_windows_and_takes_an_empty_batch(data):
    """The RBF kernel compares windows of equal T: another T used to be reported against the
    stored import vectors (its x2); an empty batch used to fail in max() of nothing."""
    (x, y), _ = data
    ivm = IVMClassifier(RBFKernel(3.0), num_classes=4, max_import=4).fit(x, y)
    t, d = x.shape[1], x.shape[2]
    with pytest.raises(
        ShapeError, match=rf"expected x \(B, {t}, {d}\) as the classifier was trained on, got "
    ):
        ivm.predict_proba(x[:5, :6])
    empty = ivm.predict_proba(x[:0])
    assert empty.shape == (0, 4) and empty.dtype == x.dtype


def test_ivm_checkpoint_errors_name_what_is_missing(data):
    (x, y), _ = data
    good = IVMClassifier(RBFKernel(3.0), num_classes=3, max_import=3).fit(x, y).state_dict()
    with pytest.raises(CheckpointError, match="expected an IVM state dict .*got a NoneType"):
        IVMClassifier.from_state_dict(None)  # type: ignore[arg-type]
    with pytest.raises(CheckpointError, match="expected an IVM state dict .*got a list"):
        IVMClassifier.from_state_dict([good])  # type: ignore[arg-type]
    for field in ("weights", "classes", "import_vectors"):
        with pytest.raises(
            CheckpointError, match=f"entry '{field}' is not a tensor, got NoneType"
        ):
            IVMClassifier.from_state_dict(good | {field: None})
    broken = {k: v for k, v in good.items() if k != "kernel_hparams"}
    with pytest.raises(CheckpointError, match=r"missing \['kernel_hparams'\]"):
        IVMClassifier.from_state_dict(broken)
    with pytest.raises(CheckpointError, match=r"needs the arguments \['lengthscale'\]"):
        IVMClassifier.from_state_dict(good | {"kernel_hparams": {}})
    with pytest.raises(CheckpointError, match="tensors do not fit together"):
        IVMClassifier.from_state_dict(good | {"weights": good["weights"][:2]})
    with pytest.raises(CheckpointError, match="expected num_classes an integer >= 1"):
        IVMClassifier.from_state_dict(good | {"num_classes": "3"})


def test_action_classifier_checkpoint_errors_name_what_is_missing():
    x, prog, cur = _state_data()
    clf = ActionClassifier().fit(
        x, prog, cur, num_actions=3, kernel_factory=lambda: RBFKernel(3.0),
        ivm_kwargs={"max_import": 3},
    )  # fmt: skip
    good = clf.state_dict()
    with pytest.raises(CheckpointError, match=r"missing \['num_actions'\]"):
        ActionClassifier.from_state_dict({k: v for k, v in good.items() if k != "num_actions"})
    with pytest.raises(CheckpointError, match="action classifier state dict, got a NoneType"):
        ActionClassifier.from_state_dict(None)  # type: ignore[arg-type]
    single = {"format": "single/1", "num_actions": 3}
    with pytest.raises(CheckpointError, match=r"single-action model 3: missing \['action'\]"):
        ActionClassifier.from_state_dict(good | {"models": good["models"] | {3: single}})
    # a checkpoint written before num_features was saved: D is read off the import vectors
    old = {k: v for k, v in good.items() if k != "num_features"}
    assert ActionClassifier.from_state_dict(old).num_features == x.shape[2]


def test_action_classifier_checks_progress_and_windows_of_every_state():
    """Float progress used to be truncated (2.5 -> 2) and NaN progress raised a raw
    ValueError; a single-action state answered 1 for NaN windows or windows of another D."""
    x, prog, cur = _state_data()
    clf = ActionClassifier().fit(
        x, prog, cur, num_actions=3, kernel_factory=lambda: RBFKernel(3.0),
        ivm_kwargs={"max_import": 3},
    )  # fmt: skip
    assert clf.num_features == x.shape[2]
    for progress in (torch.tensor([1.0, 2.5]), torch.tensor([math.nan, 3.0])):
        with pytest.raises(ShapeError, match="progress .* integer dtype .*got torch.float32"):
            clf.predict_proba(x[:2], progress)
    with pytest.raises(ShapeError, match="integer dtype .*got torch.bool"):
        clf.predict_proba(x[:2], torch.tensor([True, True]))
    state3 = torch.tensor([3, 3])  # a single-action state
    bad = x[80:82].clone()
    bad[1, 4, 2] = math.nan
    with pytest.raises(DataError, match="x is NaN/Inf at window 1, frame 4"):
        clf.predict_proba(bad, state3)
    wide = torch.zeros(2, x.shape[1], x.shape[2] + 2)
    with pytest.raises(ShapeError, match=r"expected x \(B, T, 3\) as the classifier was trained"):
        clf.predict_proba(wide, state3)
    # int32 bitmasks and the round trip keep working
    want = clf.predict_proba(x[[0, 85]], torch.tensor([1, 3]))
    assert torch.equal(
        clf.predict_proba(x[[0, 85]], torch.tensor([1, 3], dtype=torch.int32)), want
    )
    again = ActionClassifier.from_state_dict(clf.state_dict())
    assert again.num_features == x.shape[2]
    with pytest.raises(DataError, match="x is NaN/Inf at window 1"):
        again.predict_proba(bad, state3)
