"""HumanMotionPredictor and its classifier: devices checked before anything moves, inputs
that overflow inside named as the caller's argument, and a kernel that is not one refused
when the classifier is made."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from iplanner_torch.errors import CheckpointError, ConfigError, DataError
from iplanner_torch.prediction.dtw import RBFKernel
from iplanner_torch.prediction.ivm import ActionClassifier, IVMClassifier
from iplanner_torch.prediction.predictor import HumanMotionPredictor

JOINTS = ("torso", "left_hand", "right_hand")
#: the feature columns of the K = 3 joints: positions 0..8, velocities 9..17, accelerations
VELOCITIES = slice(9, 18)


def _bad_devices() -> list[object]:
    bad: list[object] = ["foo", "meta", torch.device("meta"), "mps", "cuda:99"]
    if not torch.cuda.is_available():
        bad += ["cuda", torch.device("cuda"), "cuda:0"]
    return bad


@pytest.mark.parametrize("device", _bad_devices(), ids=str)
def test_to_refuses_a_device_before_moving_anything(trained, device: object) -> None:
    """``.to("cuda")`` on a CPU build was torch's AssertionError, ``.to("foo")`` its
    RuntimeError, and ``.to("meta")`` emptied the predictor's weights without a word."""
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    before = pred.predict(w.f_prev[:3], w.progress[:3])
    with pytest.raises(ConfigError, match="device"):
        pred.to(device)  # type: ignore[arg-type]
    assert pred.device == torch.device("cpu")
    assert all(r.device.type == "cpu" for r in [pred.feat_mean, pred.feat_std])
    after = pred.predict(w.f_prev[:3], w.progress[:3])  # every part still in place
    torch.testing.assert_close(after.mean, before.mean, atol=0, rtol=0)
    torch.testing.assert_close(after.weights, before.weights, atol=0, rtol=0)
    # the classifier's own .to checks alike, before anything moves
    classifier = pred.classifier
    assert isinstance(classifier, ActionClassifier)
    ivm = next(m for m in classifier.models_.values() if isinstance(m, IVMClassifier))
    for obj in (classifier, ivm):
        with pytest.raises(ConfigError, match="device"):
            obj.to(device)  # type: ignore[arg-type]
    assert ivm.import_vectors_.device.type == "cpu" and ivm.weights_.device.type == "cpu"
    torch.testing.assert_close(
        pred.predict(w.f_prev[:3], w.progress[:3]).weights, before.weights, atol=0, rtol=0
    )


def test_to_takes_the_devices_the_project_runs_on(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    for device in ("cpu", torch.device("cpu"), "auto"):
        assert pred.to(device) is pred
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert pred.device.type == expected  # "auto": CUDA where there is one
    pred.to("cpu")
    assert bool(torch.isfinite(pred.predict(w.f_prev[:2], w.progress[:2]).mean).all())


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is available here")
def test_load_to_cuda_without_cuda_is_a_config_error(trained) -> None:
    path, _ = trained
    with pytest.raises(
        ConfigError, match=r"cannot move predictor checkpoint .* to map_location 'cuda': device"
    ):
        HumanMotionPredictor.load(path, map_location="cuda")


def test_finite_windows_that_overflow_inside_name_f_prev_not_internals(trained) -> None:
    """Velocities around 3e38 are finite, but overflow float32 when normalised for the
    classifier: the message said ``x is NaN/Inf ...: impute lost frames first``."""
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    f, progress = w.f_prev[:3].clone(), w.progress[:3]
    f[:, :, VELOCITIES] = 3e38
    assert bool(torch.isfinite(f).all())
    message = (
        r"^f_prev holds values too large for the predictor: finite as given, they overflow "
        r"to inf in its float32 arithmetic \(overflow; largest: window 0, frame 0, "
        r"'torso velocity x': 3e\+38\); .*check the units$"
    )
    with pytest.raises(DataError, match=message) as err:
        pred.predict(f, progress)
    assert "x is NaN" not in str(err.value) and "impute" not in str(err.value)
    with pytest.raises(DataError, match=message):
        pred.action_weights(f, progress)


def _patch_gps(monkeypatch: pytest.MonkeyPatch, change) -> None:
    """Every GP's (and GP bank's) predictive mean passed through ``change(mean, x)``."""
    from iplanner_torch.prediction.svgp import SVGPBank, SVGPRegressor

    for cls in (SVGPBank, SVGPRegressor):

        def predict(self, x, *args, _real=cls.predict, **kwargs):
            mean, var = _real(self, x, *args, **kwargs)
            return change(mean, x), var

        monkeypatch.setattr(cls, "predict", predict)


def test_a_forecast_that_overflows_names_f_prev_not_the_forecast(trained, monkeypatch) -> None:
    """A forecast made non-finite by windows this large is their overflow (``f_prev``), not
    ``forecast mean is NaN/Inf``; one made non-finite from ordinary windows (a broken model)
    keeps Forecast's own message."""
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    pred.classifier = None
    f, progress = w.f_prev[:3].clone(), w.progress[:3]
    big = f.clone()
    big[:, :, VELOCITIES] = 3e38

    def squares(mean: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        # the inputs' squares, as a float32 kernel takes them: inf * 0 is NaN for these
        extra = x.abs().amax(-1) ** 2 * 0.0
        return mean + extra.view(-1, *([1] * (mean.dim() - 1)))

    _patch_gps(monkeypatch, squares)
    assert bool(torch.isfinite(pred.predict(f, progress).mean).all())  # ordinary windows
    with pytest.raises(
        DataError,
        match=r"^f_prev holds values too large for the predictor: .*\(overflow; largest: "
        r"window 0, frame 0, 'torso velocity x': 3e\+38\)",
    ):
        pred.predict(big, progress)
    monkeypatch.undo()
    _patch_gps(monkeypatch, lambda mean, x: mean * float("nan"))  # broken on any input
    with pytest.raises(DataError, match=r"^forecast mean is NaN/Inf"):
        pred.predict(f, progress)


def test_float64_windows_beyond_float32_are_an_overflow(trained) -> None:
    """A finite float64 value beyond float32's range became inf on conversion, and was
    reported as NaN/Inf in f_prev; NaN and far positions as given keep their messages."""
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    f, progress = w.f_prev[:2].double(), w.progress[:2]
    big = f.clone()
    big[1, 2, 10] = 1e300  # 'torso velocity y'
    with pytest.raises(
        DataError,
        match=r"^f_prev holds values too large for the predictor: .*\(overflow; largest: "
        r"window 1, frame 2, 'torso velocity y': 1e\+300\)",
    ):
        pred.predict(big, progress)
    far = f.clone()
    far[0, 1, 4] = 1e300  # 'left_hand position y'
    with pytest.raises(DataError, match=r"f_prev holds a position beyond 100 m .*1e\+300"):
        pred.predict(far, progress)
    nan = big.clone()
    nan[0, 3, 11] = float("nan")
    with pytest.raises(DataError, match=r"f_prev is NaN/Inf at window 0, frame 3"):
        pred.predict(nan, progress)
    torch.testing.assert_close(
        pred.predict(f, progress).mean, pred.predict(f.float(), progress).mean
    )


def test_positions_whose_features_overflow_name_positions(trained) -> None:
    path, w = trained
    pred = HumanMotionPredictor.load(path)
    positions = w.f_prev[:2, :, :9].reshape(2, pred.n_prev, 3, 3).clone()
    pred.fps = 1e30  # accelerations (m/s^2) of ordinary motion overflow at this rate
    with pytest.raises(
        DataError,
        match=r"^positions holds values too large for the predictor: finite as given, the "
        r"features computed from them overflow to inf .*\(overflow; largest: ",
    ):
        pred.predict_positions(positions, w.progress[:2])


@pytest.mark.parametrize("kernel", [None, "rbf", 3.0])
def test_a_kernel_that_is_not_callable_is_refused_when_made(kernel: object) -> None:
    """``IVMClassifier(None, ...)`` was made, and failed only in fit with ``TypeError:
    'NoneType' object is not callable``."""
    with pytest.raises(ConfigError, match=rf"^expected kernel a callable .*got {kernel!r}$"):
        IVMClassifier(kernel, num_classes=2)  # type: ignore[arg-type]
    IVMClassifier(RBFKernel(1.0), num_classes=2)  # a kernel is taken


def test_a_state_dict_with_a_kernel_that_is_not_callable_is_a_checkpoint_error(trained) -> None:
    path, _ = trained
    pred = HumanMotionPredictor.load(path)
    ivm = next(m for m in pred.classifier.models_.values() if isinstance(m, IVMClassifier))
    with pytest.raises(CheckpointError, match="invalid IVM state dict: expected kernel"):
        IVMClassifier.from_state_dict(ivm.state_dict(), kernel="rbf")  # type: ignore[arg-type]


class _RunsCode:
    """Pickles to a call of ``marker.write_text``: loading it with unpickling runs code."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "ran"))


def test_a_checkpoint_that_would_run_code_is_refused_without_running_it(tmp_path: Path) -> None:
    """HumanMotionPredictor.load reads tensors and plain values only (weights_only): a file
    holding a pickled object ran it before any check (a file from anywhere could run any
    code); now it is a CheckpointError and the object is never built."""
    marker = tmp_path / "ran.txt"
    path = tmp_path / "predictor.ckpt"
    torch.save({"kind": "HumanMotionPredictor", "version": 1, "x": _RunsCode(marker)}, path)
    refused = r"holds objects other than tensors and plain values, which are not loaded"
    with pytest.raises(CheckpointError, match=refused):
        HumanMotionPredictor.load(path)
    assert not marker.exists()
