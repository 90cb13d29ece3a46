"""The human motion predictor (paper eq. motion_prediction).

``p(xi_next | F, p) = sum_c p(c | F, p) p(xi_next | F, p, c)``: the action classifier gives the
weights ``p(c | F, p)``; one sparse variational GP per (progress state p, current action c)
gives the Gaussian future positions; the next-action model gives ``p(n | p, c)``.

GP inputs are the observed windows ``F_prev`` flattened (``n_p * D``, normalised inside each
GP), by default with every frame's positions taken relative to the current pose
(:func:`gp_inputs`); all actions' GPs of a progress state are stacked once (at load) into an
:class:`~iplanner_torch.prediction.svgp.SVGPBank`, so a forecast is a few batched matmuls.
GP outputs are the future positions *relative to the current pose* (ARCHITECTURE 4.10),
the pose is added back at prediction, so a forecast lies in the world (table) frame.

Fallbacks for a (p, c) without its own GP, in order:

1. the GP of action c pooled over all progress states;
2. a constant-velocity extrapolation with the window's mean velocity
   ``(p_last - p_first) / ((n_p - 1) / fps)`` (robust to tracker noise), with the large variance
   ``fallback_sigma0^2 + (fallback_sigma_rate * t)^2`` per coordinate (t seconds ahead): a
   conservative forecast for collision checking.
"""

from __future__ import annotations

import hashlib
import importlib
import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch

from iplanner_torch import checks
from iplanner_torch.errors import (
    CheckpointError,
    ConfigError,
    DataError,
    DataWarning,
    ShapeError,
    checkpoint_load_error,
)
from iplanner_torch.files import whole_file
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.prediction.svgp import SVGPBank, SVGPCfg, SVGPRegressor
from iplanner_torch.types import (
    MAX_POSITION_M,
    all_finite,
    check_finite,
    check_shape,
    resolve_device,
)

CHECKPOINT_VERSION = 1
#: the GP input kinds of :func:`gp_inputs` (``PredictorCfg.gp_input``)
GP_INPUTS = ("window", "relative")
#: the magnitude from which finite windows can overflow float32 inside the predictor (their
#: squares, which the kernels take, do): a NaN or inf that appears inside from windows this
#: large is reported as their overflow (sqrt of float32's largest value, about 1.8e19)
_OVERFLOW_FROM = math.sqrt(torch.finfo(torch.float32).max)


@dataclass(frozen=True, kw_only=True)
class PredictorCfg:
    """Settings of the whole predictor: classifier, GPs, next-action model, fallbacks."""

    # settings of every per-(p, c) GP (eq. GPRlearning) and its noisy-input correction.
    svgp: SVGPCfg = field(default_factory=SVGPCfg)
    # kernel of the action classifier (eq. IVMclassifier): the paper uses DTW.
    classifier_kernel: Literal["dtw", "gak", "rbf"] = "dtw"
    # classifier kernel bandwidth (DTW gamma, GAK sigma, RBF lengthscale); None = median rule.
    classifier_bandwidth: float | None = None
    # IVM regularisation lambda.
    ivm_lam: float = 0.03
    # IVM maximum number of import vectors.
    ivm_max_import: int = 60
    # IVM stopping tolerance on the relative loss change.
    ivm_tol: float = 1e-3
    # IVM candidate import vectors tried per greedy step.
    ivm_candidates: int = 64
    # IVM Newton steps per candidate evaluation.
    ivm_newton_steps: int = 3
    # training windows given to the classifier at most (random subset, seeded).
    classifier_max_train: int = 1500
    # additive smoothing of the next-action histograms (eq. next_action).
    coherence_smoothing: float = 1.0
    # a (p, c) group needs at least this many windows for its own GP.
    min_group_size: int = 20
    # training windows per GP at most (random subset, seeded).
    max_gp_points: int = 3000
    # GP inputs: "window" = the flattened features; "relative" = the same with each frame's
    # positions taken relative to the current pose (the current pose itself kept absolute).
    gp_input: Literal["window", "relative"] = "relative"
    # fallback forecast: standard deviation at t = 0 [m].
    fallback_sigma0: float = 0.1
    # fallback forecast: growth of the standard deviation [m/s].
    fallback_sigma_rate: float = 1.0
    # seed of subsampling.
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.svgp, dict):
            object.__setattr__(self, "svgp", SVGPCfg(**self.svgp))
        if not isinstance(self.svgp, SVGPCfg):
            raise ConfigError(f"expected svgp an SVGPCfg, got {type(self.svgp).__name__}")
        if self.classifier_kernel not in ("dtw", "gak", "rbf"):
            raise ConfigError(
                f"classifier_kernel must be dtw, gak or rbf, got {self.classifier_kernel!r}"
            )
        # every number is checked for its range and, for floats, for NaN and infinities
        # (``nan <= 0`` is False): a bad value fails here, before a training folder is touched
        checks.optional(checks.positive, "classifier_bandwidth", self.classifier_bandwidth)
        checks.positive("ivm_lam", self.ivm_lam)
        checks.integer("ivm_max_import", self.ivm_max_import, minimum=1)
        checks.non_negative("ivm_tol", self.ivm_tol)
        checks.integer("ivm_candidates", self.ivm_candidates, minimum=1)
        checks.integer("ivm_newton_steps", self.ivm_newton_steps, minimum=1)
        checks.integer("classifier_max_train", self.classifier_max_train, minimum=2)
        checks.non_negative("coherence_smoothing", self.coherence_smoothing)
        checks.integer("min_group_size", self.min_group_size, minimum=2)
        checks.integer("max_gp_points", self.max_gp_points, minimum=2)
        if self.gp_input not in GP_INPUTS:
            raise ConfigError(f"gp_input must be window or relative, got {self.gp_input!r}")
        checks.positive("fallback_sigma0", self.fallback_sigma0)
        checks.non_negative("fallback_sigma_rate", self.fallback_sigma_rate)
        checks.seed(self.seed)

    def to_dict(self) -> dict[str, Any]:
        """Plain-dict form (saved in checkpoints)."""
        return asdict(self)


def _check_floating(name: str, x: torch.Tensor) -> None:
    """ShapeError unless ``x`` has a real floating dtype (not integer, bool or complex)."""
    if not x.is_floating_point():
        raise ShapeError(f"expected {name} of a floating dtype, got {x.dtype}")


def _check_integer(name: str, x: torch.Tensor) -> None:
    """ShapeError unless ``x`` has an integer dtype (not floating, complex or bool)."""
    if x.is_floating_point() or x.is_complex() or x.dtype == torch.bool:
        raise ShapeError(f"expected {name} of an integer dtype, got {x.dtype}")


def _integer_scalar(name: str, value: Any) -> torch.Tensor:
    """``value`` (a Python or numpy integer, or a one-element integer tensor) as a 0-d int64
    CPU tensor.

    Raises:
        ShapeError: for anything else (a float, NaN, a bool, a tensor of other size or dtype).
    """
    if isinstance(value, torch.Tensor):
        if value.numel() != 1:
            raise ShapeError(f"expected {name} a single integer, got shape {tuple(value.shape)}")
        _check_integer(name, value)
        return value.detach().cpu().reshape(()).to(torch.int64)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ShapeError(
            f"expected {name} of an integer dtype, got {type(value).__name__} {value!r}"
        )
    if not -(2**63) <= int(value) < 2**63:
        raise ShapeError(f"expected {name} an int64, got {value!r}")
    return torch.tensor(int(value), dtype=torch.int64)


def _far_error(what: str, where: str, hint: str = "") -> DataError:
    """The DataError for a position beyond :data:`MAX_POSITION_M` (``where``: its first)."""
    return DataError(
        f"{what} beyond {MAX_POSITION_M:g} m (first: {where}); positions are metres in the "
        f"world frame: check the units{hint}"
    )


def gp_inputs(f_prev: torch.Tensor, num_joints: int, kind: str = "relative") -> torch.Tensor:
    """The GP input of each window (eq. GPRlearning), flattened.

    Args:
        f_prev: (B, n_p, D) window features, positions [m] first (3 K columns).
        num_joints: K.
        kind: "window" (features as they are) or "relative" (every frame's positions minus
            the current, last frame's; the current pose stays absolute).

    Returns:
        (B, n_p * D) inputs.

    Raises:
        ConfigError: for a ``kind`` other than "window" or "relative" (a misspelt one gave
            "window"'s inputs), or ``num_joints`` not an integer >= 1.
        ShapeError: when ``f_prev`` is not (B, n_p, D) with D >= 3 K.
    """
    if kind not in GP_INPUTS:
        raise ConfigError(f"expected kind one of {GP_INPUTS}, got {kind!r}")
    checks.integer("num_joints", num_joints, minimum=1)
    check_shape("f_prev", f_prev, ("B", "n_p", "D"))
    if f_prev.shape[-1] < 3 * num_joints:
        raise ShapeError(
            f"expected f_prev (B, n_p, D) with D >= 3 K = {3 * num_joints} position columns "
            f"first, got D = {f_prev.shape[-1]}"
        )
    b = f_prev.shape[0]
    if kind == "relative":
        k3 = 3 * num_joints
        pos = f_prev[:, :, :k3]  # (B, n_p, 3K)
        rel = torch.cat([pos[:, :-1] - pos[:, -1:], pos[:, -1:]], 1)  # (B, n_p, 3K)
        f_prev = torch.cat([rel, f_prev[:, :, k3:]], -1)  # (B, n_p, D)
    return f_prev.reshape(b, -1)


def content_digest(d: dict[str, Any]) -> str:
    """SHA-256 of a checkpoint dict's contents (every key and value, tensors by dtype, shape
    and bytes), without its own ``digest`` entry: :meth:`HumanMotionPredictor.save` stores
    it and :meth:`HumanMotionPredictor.load` checks it, so that a changed byte inside a
    tensor (which torch reads without complaint) is caught."""
    h = hashlib.sha256()

    def feed(v: Any) -> None:
        if isinstance(v, dict):
            h.update(b"{")
            for k in sorted(v, key=repr):
                h.update(repr(k).encode())
                feed(v[k])
            h.update(b"}")
        elif isinstance(v, list | tuple):
            h.update(b"(" if isinstance(v, tuple) else b"[")
            for e in v:
                feed(e)
            h.update(b")")
        elif isinstance(v, torch.Tensor):
            t = v.detach().cpu().contiguous().reshape(-1)
            h.update(f"T{t.dtype}{tuple(v.shape)}".encode())
            h.update(t.view(torch.uint8).numpy().tobytes())
        elif v is None or isinstance(v, bool | int | float | str):
            h.update(f"{type(v).__name__}:{v!r}".encode())
        else:
            h.update(f"{type(v).__module__}.{type(v).__qualname__}".encode())

    feed({k: v for k, v in d.items() if k != "digest"})
    return h.hexdigest()


def dataset_fingerprint(*tensors: torch.Tensor) -> str:
    """A short hash of the training tensors (shapes and a sample of values)."""
    h = hashlib.sha256()
    for t in tensors:
        t = t.detach().cpu().contiguous()
        h.update(str(tuple(t.shape)).encode())
        flat = t.reshape(-1)
        step = max(1, flat.numel() // 4096)
        h.update(flat[::step].double().numpy().tobytes())
    return h.hexdigest()[:16]


class HumanMotionPredictor:
    """Action-weighted mixture of per-action Gaussian forecasts (eq. motion_prediction).

    Args:
        cfg: predictor settings.
        joint_names: the K joint names (order of the K axis).
        action_names: the A action names.
        fps: frame rate of the windows [Hz].
        n_prev: n_p, observed frames per window.
        n_future: n_f, predicted frames.
        feature_kinds: feature blocks per frame ("position" first).
        progress_actions: indices of the actions that count for the progress state.
        feat_mean: (D,) feature means of the training windows (classifier normalisation).
        feat_std: (D,) feature standard deviations.
        classifier: object with ``predict_proba(x (B, n_p, D), progress (B,)) -> (B, A)`` on
            normalised features, or None for uniform weights.
        next_model: object with ``prob(progress (B,), current (B,)) -> (B, A)``, or None.
        gps: GP per (progress bitmask, action).
        pooled: GP per action pooled over progress states.
        fingerprint: hash of the training data.
        window_cfg: the data's window settings, kept for reference (a dict).
        inputs_digest: :func:`~iplanner_torch.eval.prediction.inputs_digest` of the training
            record (``training_inputs.json``) of the run that trained it; "" when unknown.
    """

    def __init__(
        self,
        *,
        cfg: PredictorCfg,
        joint_names: tuple[str, ...],
        action_names: tuple[str, ...],
        fps: float,
        n_prev: int,
        n_future: int,
        feature_kinds: tuple[str, ...],
        progress_actions: tuple[int, ...],
        feat_mean: torch.Tensor,
        feat_std: torch.Tensor,
        classifier: Any = None,
        next_model: Any = None,
        gps: dict[tuple[int, int], SVGPRegressor] | None = None,
        pooled: dict[int, SVGPRegressor] | None = None,
        fingerprint: str = "",
        window_cfg: dict[str, Any] | None = None,
        inputs_digest: str = "",
    ) -> None:
        self.cfg = cfg
        self.joint_names = tuple(joint_names)
        self.action_names = tuple(action_names)
        self.fps = float(fps)
        self.n_prev = int(n_prev)
        self.n_future = int(n_future)
        self.feature_kinds = tuple(feature_kinds)
        self.progress_actions = tuple(int(a) for a in progress_actions)
        self.feat_mean = feat_mean.float()
        self.feat_std = feat_std.float()
        self.classifier = classifier
        self.next_model = next_model
        self.gps = dict(gps or {})
        self.pooled = dict(pooled or {})
        self.fingerprint = fingerprint
        self.window_cfg = dict(window_cfg or {})
        self.inputs_digest = str(inputs_digest)
        # progress state -> (bank of its actions' GPs or None, the actions that have a GP)
        self._banks: dict[int, tuple[SVGPBank | None, list[int]]] = {}
        k = len(self.joint_names)
        d = 3 * k * len(self.feature_kinds)
        check_shape("feat_mean", self.feat_mean, (d,))
        check_shape("feat_std", self.feat_std, (d,))

    # ------------------------------------------------------------------------------ sizes
    @property
    def num_joints(self) -> int:
        """K."""
        return len(self.joint_names)

    @property
    def num_actions(self) -> int:
        """A."""
        return len(self.action_names)

    @property
    def num_features(self) -> int:
        """D = 3 K x number of feature kinds."""
        return 3 * self.num_joints * len(self.feature_kinds)

    @property
    def feature_names(self) -> tuple[str, ...]:
        """The D feature columns' names, ``"<joint> <kind> <x|y|z>"`` (the layout of
        :func:`data.windows.compute_features`: kind-major, then joint, then coordinate)."""
        return tuple(
            f"{joint} {kind} {axis}"
            for kind in self.feature_kinds
            for joint in self.joint_names
            for axis in "xyz"
        )

    @property
    def device(self) -> torch.device:
        """Where the model's tensors live."""
        return self.feat_mean.device

    def to(self, device: torch.device | str) -> HumanMotionPredictor:
        """Move every tensor (GPs, normalisation, classifier when it can) to ``device``
        (``"cpu"``, ``"cuda"``, ``"cuda:<index>"`` or ``"auto"``).

        Raises:
            ConfigError: for a device that :func:`~iplanner_torch.types.resolve_device`
                refuses (an unknown name, CUDA where there is none, ``meta``, which holds no
                numbers, or another device type), before anything is moved.
        """
        device = resolve_device(device)
        self.feat_mean = self.feat_mean.to(device)
        self.feat_std = self.feat_std.to(device)
        for reg in list(self.gps.values()) + list(self.pooled.values()):
            reg.to(device)
            reg._cache = None
        for obj in (self.classifier, self.next_model):
            if obj is not None and hasattr(obj, "to"):
                obj.to(device)
        self._banks = {}
        return self

    def prepare(self) -> HumanMotionPredictor:
        """(Re)compute every GP's fast-path tensors and the per-progress-state banks.

        Call after changing ``gps`` or ``pooled`` in place. The tensors are computed on one
        CPU thread, whatever torch's setting: the thread count fixes their last bits, and
        every forecast reads them. Loaded under two threads (``iplanner-experiment``) and
        under one (a ``hydra/launcher=joblib`` job, whose workers get ``OMP_NUM_THREADS=1``),
        the same checkpoint gave forecasts that differed in the last float32 bit, and so
        episodes of the same seed that differed.
        """
        self._banks = {}
        for reg in list(self.gps.values()) + list(self.pooled.values()):
            reg.refresh_cache(threads=1)
        for p in sorted({p for p, _ in self.gps}):
            self._bank(p)
        return self

    def _bank(self, progress: int) -> tuple[SVGPBank | None, list[int]]:
        """The stacked GPs of every action at ``progress`` (None when they cannot stack)."""
        hit = self._banks.get(progress)
        if hit is not None:
            return hit
        regs = [self.model_for(progress, a) for a in range(self.num_actions)]
        have = [a for a, r in enumerate(regs) if r is not None]
        kernels = {regs[a].cfg.kernel for a in have}
        bank = None
        if have and len(kernels) == 1 and kernels <= {"rbf", "matern"}:
            bank = SVGPBank([regs[a] for a in have])
        self._banks[progress] = (bank, have)
        return bank, have

    # -------------------------------------------------------------------------- inference
    def normalise_features(self, f_prev: torch.Tensor) -> torch.Tensor:
        """(B, n_p, D) features -> normalised features (classifier input).

        Raises:
            ShapeError: unless ``f_prev`` is a floating (B, n_p, D) tensor on the predictor's
                device.
        """
        check_shape("f_prev", f_prev, ("B", self.n_prev, self.num_features))
        _check_floating("f_prev", f_prev)
        if f_prev.device != self.feat_mean.device:
            raise ShapeError(
                f"expected f_prev on {self.feat_mean.device} (the predictor's), got "
                f"{f_prev.device}"
            )
        return self._normalise(f_prev)

    def _normalise(self, f_prev: torch.Tensor) -> torch.Tensor:
        """:meth:`normalise_features` without the checks."""
        return (f_prev - self.feat_mean) / self.feat_std

    def model_for(self, progress: int, action: int) -> SVGPRegressor | None:
        """The GP used for (p, c): its own, else the pooled one of c, else None (fallback)."""
        reg = self.gps.get((int(progress), int(action)))
        return reg if reg is not None else self.pooled.get(int(action))

    def action_weights(self, f_prev: torch.Tensor, progress: torch.Tensor) -> torch.Tensor:
        """(B, A) p(c | F_prev, p) (eq. IVMclassifier) of (B, n_p, D) windows at progress
        states (B,) long; uniform without a classifier.

        Raises:
            ShapeError: as :meth:`predict`, for shapes, dtypes and an empty batch.
            ConfigError: as :meth:`predict`, for progress states out of range.
            DataError: as :meth:`predict`, for windows that are not finite, or finite ones so
                large that the classifier's input overflows.
        """
        f_prev, progress = self._checked_windows(f_prev, progress, positions_checked=False)
        return self._action_weights(f_prev, progress)

    def _action_weights(
        self, f_prev: torch.Tensor, progress: torch.Tensor, name: str = "f_prev"
    ) -> torch.Tensor:
        """:meth:`action_weights` of checked windows (``name``: the argument they came from,
        for messages)."""
        b = f_prev.shape[0]
        if self.classifier is None:
            return torch.full(
                (b, self.num_actions),
                1.0 / self.num_actions,
                dtype=f_prev.dtype,
                device=f_prev.device,
            )
        x = self._normalise(f_prev)
        if not hasattr(self.classifier, "to"):  # a CPU-only classifier: evaluate it there
            x, progress = x.cpu(), progress.cpu()
        try:
            w = self.classifier.predict_proba(x, progress)
        except DataError:  # the windows are finite: x is not when their scaling overflowed
            overflow = None if all_finite(x) else self._overflow_error(name, f_prev)
            if overflow is None:
                raise
            raise overflow from None
        return w.to(f_prev)

    def _overflow_error(self, name: str, f_prev: torch.Tensor) -> DataError | None:
        """The DataError for windows ``f_prev`` (B, n_p, D) that are finite as the caller gave
        them (``name``: the argument, as the public method calls it) but overflow to inf in
        the predictor's float32 arithmetic, naming the entry of largest magnitude; None when
        no finite entry reaches :data:`_OVERFLOW_FROM` (a NaN or inf of another cause)."""
        size = torch.where(torch.isfinite(f_prev), f_prev.abs(), 0).to(torch.float64)
        if not float(size.max()) >= _OVERFLOW_FROM:
            return None
        b_i, t_i, d_i = (size == size.max()).nonzero()[0].tolist()
        what = "the features computed from them overflow" if name != "f_prev" else "they overflow"
        return DataError(
            f"{name} holds values too large for the predictor: finite as given, {what} to inf "
            f"in its float32 arithmetic (overflow; largest: window {b_i}, frame {t_i}, "
            f"{self.feature_names[d_i]!r}: {float(f_prev[b_i, t_i, d_i]):g}); positions are "
            "metres, velocities m/s and accelerations m/s^2: check the units"
        )

    def _fallback(self, f_prev: torch.Tensor, pose: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Constant-velocity mean (B, n_f, K, 3) and the large fallback variance."""
        k = self.num_joints
        t = (
            torch.arange(1, self.n_future + 1, dtype=f_prev.dtype, device=f_prev.device) / self.fps
        )  # (n_f,)
        pos = f_prev[:, :, : 3 * k].reshape(f_prev.shape[0], -1, k, 3)  # (B, n_p, K, 3)
        # mean velocity over the window: far less noisy than the last frame's derivative
        vel = ((pos[:, -1] - pos[:, 0]) * self.fps / (pos.shape[1] - 1)).unsqueeze(1)
        mean = pose.unsqueeze(1) + vel * t.view(1, -1, 1, 1)
        sd = self.cfg.fallback_sigma0**2 + (self.cfg.fallback_sigma_rate * t) ** 2
        var = sd.view(1, -1, 1, 1).expand(mean.shape).clone()
        return mean, var

    def _check_progress(self, progress: torch.Tensor) -> torch.Tensor:
        """``progress`` ((B,) or 0-d) as int64 on its device, checked (:meth:`predict`).

        Raises:
            ShapeError: when it is not of an integer dtype.
            ConfigError: for a negative bitmask or one with a bit of no progress action.
        """
        _check_integer("progress", progress)
        progress = progress.to(torch.int64)
        mask = sum(1 << a for a in self.progress_actions)  # the bits that stand for an action
        stray = (progress < 0) | ((progress & ~mask) != 0)
        if bool(stray.any()):
            i = int(stray.reshape(-1).nonzero()[0, 0])
            where = f" (window {i})" if progress.dim() == 1 else ""
            raise ConfigError(
                f"expected progress bitmasks >= 0 with bits of progress actions only (bit a "
                f"for action a in {list(self.progress_actions)}), got "
                f"{int(progress.reshape(-1)[i])}{where}"
            )
        return progress

    def _check_window_values(self, f_prev: torch.Tensor, *, check_range: bool = True) -> None:
        """DataError when ``f_prev`` (B, n_p, D) holds NaN or inf, or (``check_range``) a
        position beyond :data:`MAX_POSITION_M`; one host synchronisation when it is fine (the
        names of the message are built only on failure)."""
        if not check_range:
            if not all_finite(f_prev):
                check_finite("f_prev", f_prev, ("window", "frame", self.feature_names))
            return
        k3 = 3 * self.num_joints
        lo, hi = torch.aminmax(f_prev[:, :, :k3].contiguous())  # NaN propagates
        stats = torch.stack([lo, hi, f_prev.sum()]).tolist()  # (3,): one sync
        near = -MAX_POSITION_M <= stats[0] and stats[1] <= MAX_POSITION_M  # False on NaN
        if near and math.isfinite(stats[2]):  # a NaN or inf makes the sum NaN or inf
            return
        check_finite("f_prev", f_prev, ("window", "frame", self.feature_names))
        if not near:
            b_i, t_i, d_i = (f_prev[:, :, :k3].abs() > MAX_POSITION_M).nonzero()[0].tolist()
            raise _far_error(
                "f_prev holds a position",
                f"window {b_i}, frame {t_i}, {self.feature_names[d_i]!r}: "
                f"{float(f_prev[b_i, t_i, d_i]):g}",
            )

    def predict(self, f_prev: torch.Tensor, progress: torch.Tensor) -> Forecast:
        """Forecast the next n_f frames for a batch of windows (eq. motion_prediction).

        Args:
            f_prev: (B, n_p, D) features of the observed frames (positions [m], velocities
                [m/s], accelerations [m/s^2], as :func:`data.windows.compute_features`), B >= 1,
                finite (lost joints imputed: :meth:`predict_positions` does that).
            progress: (B,) integer (int64) progress-state bitmasks, >= 0, with bit ``a`` set
                only for an action ``a`` of ``progress_actions`` (a state without its own GP
                uses the fallbacks of the module docstring). Gradients are not tracked.

        Returns:
            The Forecast: weights (B, A), mean/var (B, A, n_f, K, 3) in the world frame,
            float32 on the predictor's device whatever the inputs' floating dtype (the
            models' own).

        Raises:
            ShapeError: for wrong shapes, no window (B = 0), an ``f_prev`` that is not of a
                floating dtype (integer, bool or complex), or a ``progress`` that is not of an
                integer dtype.
            ConfigError: for a negative ``progress`` or one with a bit of no progress action.
            DataError: when ``f_prev`` holds NaN or inf (naming window, frame and feature), or
                a position beyond :data:`MAX_POSITION_M`, or values finite but so large that
                they overflow float32 inside the predictor (``f_prev holds values too large
                for the predictor: ... (overflow; largest: ...)``).
        """
        return self._predict(f_prev, progress, positions_checked=False)

    def _checked_windows(
        self,
        f_prev: torch.Tensor,
        progress: torch.Tensor,
        *,
        positions_checked: bool,
        name: str = "f_prev",
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``f_prev`` (B, n_p, D) as float32 and ``progress`` (B,) on the predictor's device,
        checked as :meth:`predict` checks them (``positions_checked``: only finiteness, of
        features computed from the argument ``name``). Windows finite as given that are not
        in float32 (float64 beyond its range) are refused as an overflow."""
        check_shape("f_prev", f_prev, ("B", self.n_prev, self.num_features))
        if f_prev.shape[0] == 0:
            raise ShapeError(
                f"expected at least one window in f_prev (B >= 1, {self.n_prev}, "
                f"{self.num_features}), got {tuple(f_prev.shape)}"
            )
        _check_floating("f_prev", f_prev)
        check_shape("progress", progress, (f_prev.shape[0],))
        given = f_prev.detach()
        f_prev = given.to(self.device, torch.float32)
        progress = self._check_progress(progress.to(self.device))
        try:
            self._check_window_values(f_prev, check_range=not positions_checked)
        except DataError:
            if not positions_checked:
                if not all_finite(given):  # NaN or inf as given: that message stands
                    raise
                # finite as given: a far position is named as such, else it is an overflow
                self._check_window_values(given.to(self.device), check_range=True)
            overflow = self._overflow_error(name, given.to(self.device))
            if overflow is None:
                raise
            raise overflow from None
        return f_prev, progress

    def _predict(
        self,
        f_prev: torch.Tensor,
        progress: torch.Tensor,
        *,
        positions_checked: bool,
        name: str = "f_prev",
    ) -> Forecast:
        """:meth:`predict`; ``positions_checked``: the caller has already refused positions
        beyond :data:`MAX_POSITION_M` (:meth:`predict_positions`), so only finiteness is
        checked here; ``name``: the caller's argument, for messages."""
        f_prev, progress = self._checked_windows(
            f_prev, progress, positions_checked=positions_checked, name=name
        )
        b, k, a_n = f_prev.shape[0], self.num_joints, self.num_actions
        pose = f_prev[:, -1, : 3 * k].reshape(b, k, 3)  # (B, K, 3) current pose
        x = gp_inputs(f_prev, k, self.cfg.gp_input)  # (B, n_p * D)
        weights = self._action_weights(f_prev, progress, name)
        uniq = torch.unique(progress).tolist()
        banks = {p: self._bank(int(p)) for p in uniq}
        if all(len(have) == a_n for _, have in banks.values()):
            mean = torch.empty(b, a_n, self.n_future, k, 3, dtype=f_prev.dtype, device=self.device)
            var = torch.empty_like(mean)
        else:
            mean, var = self._fallback(f_prev, pose)  # (B, n_f, K, 3) each
            mean = mean.unsqueeze(1).repeat(1, a_n, 1, 1, 1)  # (B, A, n_f, K, 3)
            var = var.unsqueeze(1).repeat(1, a_n, 1, 1, 1)
        for p in uniq:
            rows = slice(None) if len(uniq) == 1 else (progress == p).nonzero()[:, 0]
            xr, pr = x[rows], pose[rows]
            bank, have = banks[p]
            nb = xr.shape[0]
            if bank is not None:
                m, v = bank.predict(xr)  # (b, G, n_f K 3) each
                m = m.view(nb, len(have), self.n_future, k, 3) + pr.view(nb, 1, 1, k, 3)
                v = v.view(nb, len(have), self.n_future, k, 3)
                if len(have) == a_n:
                    mean[rows], var[rows] = m, v
                else:
                    cols = torch.tensor(have, device=self.device)
                    if isinstance(rows, slice):
                        mean[:, cols], var[:, cols] = m, v
                    else:
                        mean[rows.unsqueeze(-1), cols], var[rows.unsqueeze(-1), cols] = m, v
                continue
            for a in have:
                m, v = self.model_for(p, a).predict(xr)  # (b, n_f K 3) each
                mean[rows, a] = m.view(nb, self.n_future, k, 3) + pr.unsqueeze(1)
                var[rows, a] = v.view(nb, self.n_future, k, 3)
        try:
            return Forecast(
                weights=weights,
                mean=mean,
                var=var,
                dt=1.0 / self.fps,
                joint_names=self.joint_names,
                action_names=self.action_names,
            )
        except DataError:  # the windows are finite: a non-finite forecast may be an overflow
            finite = all_finite(weights, mean, var)
            overflow = None if finite else self._overflow_error(name, f_prev)
            if overflow is None:
                raise
            raise overflow from None

    def predict_positions(self, positions: torch.Tensor, progress: torch.Tensor) -> Forecast:
        """Forecast from raw tracked positions (features computed here).

        NaN joints are imputed by :func:`data.windows.compute_features` (linear interpolation
        in time, edge hold; a joint lost in the whole window takes a connected joint's
        trajectory, else any observed joint's). A window with no observed joint at all raises,
        never a silent NaN forecast.

        Args:
            positions: (B, n_p, K, 3) tracked joint positions [m], NaN where lost.
            progress: (B,) int64 progress-state bitmasks.

        Returns:
            As :meth:`predict`.

        Raises:
            ShapeError: for wrong shapes (as :meth:`predict`) or a dtype that is not floating.
            ConfigError: as :meth:`predict`.
            DataError: when every joint is NaN in every frame of a window, or on inf or a
                coordinate beyond :data:`MAX_POSITION_M`; naming ``positions`` when the
                features computed from them overflow (as :meth:`predict`).
        """
        from iplanner_torch.data.windows import compute_features

        check_shape("positions", positions, ("B", self.n_prev, self.num_joints, 3))
        if positions.shape[0] == 0:
            raise ShapeError(
                f"expected at least one window in positions (B >= 1, {self.n_prev}, "
                f"{self.num_joints}, 3), got {tuple(positions.shape)}"
            )
        _check_floating("positions", positions)
        positions = positions.detach()
        seen = torch.isfinite(positions).all(-1).any(1).any(1)  # (B,) any joint observed
        huge = positions.abs() > MAX_POSITION_M  # inf included, NaN not
        all_seen, no_huge = torch.stack([seen.all(), ~huge.any()]).tolist()
        if not no_huge:
            b_i, t_i, k_i = huge.any(-1).nonzero()[0].tolist()
            value = positions[b_i, t_i, k_i]
            if bool(torch.isinf(value).any()):
                raise DataError(
                    f"positions hold inf (first: window {b_i}, frame {t_i}, joint "
                    f"{self.joint_names[k_i]!r}); mark a lost joint with NaN"
                )
            raise _far_error(
                "positions hold a coordinate",
                f"window {b_i}, frame {t_i}, joint {self.joint_names[k_i]!r}: {value.tolist()}",
                ", or mark a bad sample lost with NaN",
            )
        if not all_seen:
            bi = int((~seen).nonzero()[0])
            raise DataError(f"no joint is observed in any frame of window {bi}: cannot forecast")
        f = compute_features(
            positions.to(self.device, torch.float32),
            self.fps,
            self.feature_kinds,
            joint_names=self.joint_names,
        )
        return self._predict(f, progress, positions_checked=True, name="positions")

    def next_action(self, progress: int, current: int) -> torch.Tensor:
        """(A,) p(n | p, c) (eq. next_action); uniform without a next-action model.

        Args:
            progress: p, the progress-state bitmask: an integer >= 0 with bit ``a`` set only
                for an action ``a`` of ``progress_actions``, as :meth:`predict` takes it.
            current: c, the current action: an index into ``action_names``, in [0, A). There
                is no "unknown" value: the model is fitted on labelled frames only (windows
                whose current frame is unlabelled are left out of training), so a caller that
                does not know c picks the action it stands for (the closed loop passes idle).

        Returns:
            (A,) probabilities of the next action (on the CPU), summing to 1.

        Raises:
            ShapeError: when ``progress`` or ``current`` is not an integer (a float, NaN, a
                bool, a tensor of more than one element), as :meth:`predict` for ``progress``.
            ConfigError: for a ``progress`` that :meth:`predict` refuses (negative, or with a
                bit of no progress action), or a ``current`` outside [0, A).
        """
        p = self._check_progress(_integer_scalar("progress", progress))
        c = _integer_scalar("current", current)
        if not 0 <= int(c) < self.num_actions:
            raise ConfigError(
                f"expected current an action index in [0, {self.num_actions}) "
                f"({', '.join(self.action_names)}), got {int(c)}"
            )
        if self.next_model is None:
            return torch.full((self.num_actions,), 1.0 / self.num_actions)
        return self.next_model.prob(p.view(1), c.view(1))[0]

    # -------------------------------------------------------------------------- storing
    def to_checkpoint(self) -> dict[str, Any]:
        """Everything needed to rebuild the predictor."""

        def state(obj: Any) -> Any:
            return None if obj is None else obj.state_dict()

        return {
            "version": CHECKPOINT_VERSION,
            "kind": "HumanMotionPredictor",
            "cfg": self.cfg.to_dict(),
            "joint_names": self.joint_names,
            "action_names": self.action_names,
            "fps": self.fps,
            "n_prev": self.n_prev,
            "n_future": self.n_future,
            "feature_kinds": self.feature_kinds,
            "progress_actions": self.progress_actions,
            "feat_mean": self.feat_mean.cpu(),
            "feat_std": self.feat_std.cpu(),
            "classifier": state(self.classifier),
            "classifier_class": None
            if self.classifier is None
            else type(self.classifier).__module__ + ":" + type(self.classifier).__qualname__,
            "next_model": state(self.next_model),
            "next_model_class": None
            if self.next_model is None
            else type(self.next_model).__module__ + ":" + type(self.next_model).__qualname__,
            "gps": {f"{p}:{c}": reg.to_checkpoint() for (p, c), reg in self.gps.items()},
            "pooled": {
                str(c): (self._alias(reg) or reg.to_checkpoint()) for c, reg in self.pooled.items()
            },
            "fingerprint": self.fingerprint,
            "window_cfg": self.window_cfg,
            "inputs_digest": self.inputs_digest,
        }

    def _alias(self, reg: SVGPRegressor) -> str | None:
        for (p, c), r in self.gps.items():
            if r is reg:
                return f"{p}:{c}"
        return None

    def save(self, path: str | Path) -> Path:
        """Write the predictor to ``path`` (a torch file, conventionally ``predictor.ckpt``)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        d = self.to_checkpoint()
        d["digest"] = content_digest(d)  # checked by load: torch does not check its zip CRCs
        # an earlier checkpoint stays whole until this one is; written through a file object,
        # the archive's inner folder is named "archive", not after the temporary file, so the
        # same predictor gives the same bytes (a resumed run compares checkpoint digests)
        with whole_file(path) as tmp, tmp.open("wb") as f:
            torch.save(d, f)
        return path

    @classmethod
    def load(
        cls,
        path: str | Path,
        map_location: torch.device | str | None = None,
        *,
        expect_joints: tuple[str, ...] | list[str] | None = None,
    ) -> HumanMotionPredictor:
        """Rebuild a predictor from a checkpoint alone.

        Args:
            path: the file written by :meth:`save` (or by ``train_predictor``).
            map_location: device for every tensor (default: CPU).
            expect_joints: when given, the joint names the caller needs.

        Raises:
            CheckpointError: for a missing, corrupt or truncated file (naming it), a directory,
                a path the system cannot look up (a name too long), a checkpoint of another
                format version than ``CHECKPOINT_VERSION``, a sub-model class that cannot be
                imported, a field missing or of the wrong type, or a checkpoint of another joint
                set than ``expect_joints``; for a ``path`` that is not a str or os.PathLike
                (None, a number).
            ConfigError: when ``map_location`` is not a device, is ``meta`` (no data), or is
                one this machine lacks; when ``expect_joints`` is not a list or tuple.
        """
        path = checks.path_argument(path, "of a predictor checkpoint", error=CheckpointError)
        if map_location is not None:
            try:
                device = torch.device(map_location)
            except (RuntimeError, TypeError, ValueError) as err:
                raise ConfigError(
                    f"expected map_location a torch device (e.g. 'cpu', 'cuda:0'), got "
                    f"{map_location!r}"
                ) from err
            if device.type == "meta":
                raise ConfigError(
                    "map_location 'meta' holds no numbers, and a predictor needs its weights "
                    "to forecast: load it on a real device (e.g. 'cpu', 'cuda:0')"
                )
        if expect_joints is not None and (
            isinstance(expect_joints, str) or not isinstance(expect_joints, Sequence)
        ):
            raise ConfigError(
                f"expected expect_joints a list or tuple of joint names, got {expect_joints!r}"
            )
        if checks.is_dir(
            path,
            "the path of a checkpoint file",
            what="predictor checkpoint",
            error=CheckpointError,
        ):
            raise CheckpointError(
                f"predictor checkpoint {path} is a directory, not a checkpoint file (a training "
                "run writes <out_dir>/predictor.ckpt)"
            )
        if not path.is_file():
            raise CheckpointError(f"predictor checkpoint {path} does not exist")
        try:
            # weights_only: tensors and plain containers only; a pickled object (which could
            # run code while it loads) is refused. Every checkpoint this project writes is
            # of that kind.
            d = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as err:  # noqa: BLE001 - any unpickling failure means corrupt
            pickled, why = checkpoint_load_error(err)
            if pickled:
                raise CheckpointError(
                    f"cannot read predictor checkpoint {path}: {why}; it is no checkpoint "
                    "this project wrote: train it again"
                ) from None
            raise CheckpointError(
                f"cannot read predictor checkpoint {path} ({why}): the "
                "file is cut short, damaged or not a torch checkpoint; train it again"
            ) from err
        if not isinstance(d, dict) or not _equals(d.get("kind"), "HumanMotionPredictor"):
            raise CheckpointError(f"{path} is not a HumanMotionPredictor checkpoint")
        version = d.get("version")
        if not _equals(version, CHECKPOINT_VERSION):
            raise CheckpointError(
                f"predictor checkpoint {path} has format version {version!r}; this code reads "
                f"version {CHECKPOINT_VERSION} (retrain, or load it with the matching code)"
            )
        if "digest" not in d:
            warnings.warn(
                f"predictor checkpoint {path} has no content digest (written before "
                "checkpoints carried one): loaded without the check for damage; save it again "
                "or retrain to add one",
                DataWarning,
                stacklevel=2,
            )
        elif not _equals(d["digest"], content_digest(d)):
            raise CheckpointError(
                f"predictor checkpoint {path} is damaged: its contents do not match the "
                "digest written with them (retrain, or restore the file)"
            )
        if expect_joints is not None and not isinstance(d.get("joint_names"), tuple | list):
            raise CheckpointError(
                f"predictor checkpoint {path} is incomplete: no joint_names (a list of names), "
                f"got {type(d.get('joint_names')).__name__}"
            )
        if expect_joints is not None and tuple(expect_joints) != tuple(d["joint_names"]):
            raise CheckpointError(
                f"{path} was trained on joints {tuple(d['joint_names'])}, expected "
                f"{tuple(expect_joints)}"
            )
        try:
            pred = cls._from_dict(d)
        except CheckpointError as err:
            raise CheckpointError(f"predictor checkpoint {path}: {err}") from err
        except Exception as err:  # noqa: BLE001 - a missing key, a value of the wrong type
            raise CheckpointError(
                f"predictor checkpoint {path} is incomplete or malformed "
                f"({type(err).__name__}: {err})"
            ) from err
        if map_location is not None:
            try:
                pred.to(map_location)
            except (ConfigError, RuntimeError, AssertionError) as err:  # no CUDA here
                raise ConfigError(
                    f"cannot move predictor checkpoint {path} to map_location "
                    f"{map_location!r}: {err}"
                ) from err
        try:
            return pred.prepare()._self_check()
        except Exception as err:  # noqa: BLE001 - any failure here means an inconsistent file
            raise CheckpointError(
                f"predictor checkpoint {path} is inconsistent: its parts fail on a test window "
                f"({type(err).__name__}: {err})"
            ) from err

    def _self_check(self) -> HumanMotionPredictor:
        """Run every part once: a forecast of the mean window at every progress state with
        GPs (so every GP, the classifier and the fallbacks) and the next-action model; the
        output shapes are checked by :class:`Forecast`. Returns self."""
        states = sorted({p for p, _ in self.gps} | {0})
        f = self.feat_mean.to(self.device, torch.float32).expand(len(states), self.n_prev, -1)
        self.predict(f, torch.tensor(states, dtype=torch.int64))
        probs = self.next_action(states[-1], 0)
        if tuple(probs.shape) != (self.num_actions,):
            raise ShapeError(
                f"next-action model gives {tuple(probs.shape)} for A = {self.num_actions}"
            )
        return self

    @classmethod
    def _from_dict(cls, d: dict[str, Any]) -> HumanMotionPredictor:
        cfg_d = dict(d["cfg"])
        cfg_d["svgp"] = SVGPCfg(**cfg_d["svgp"])
        cfg = PredictorCfg(**cfg_d)
        gps = {}
        for key, sd in d["gps"].items():
            p, c = (int(v) for v in key.split(":"))
            gps[(p, c)] = SVGPRegressor.from_checkpoint(sd)
        pooled = {}
        for key, sd in d["pooled"].items():
            if isinstance(sd, str):
                p, c = (int(v) for v in sd.split(":"))
                pooled[int(key)] = gps[(p, c)]
            else:
                pooled[int(key)] = SVGPRegressor.from_checkpoint(sd)
        return cls(
            cfg=cfg,
            joint_names=tuple(d["joint_names"]),
            action_names=tuple(d["action_names"]),
            fps=d["fps"],
            n_prev=d["n_prev"],
            n_future=d["n_future"],
            feature_kinds=tuple(d["feature_kinds"]),
            progress_actions=tuple(d["progress_actions"]),
            feat_mean=d["feat_mean"],
            feat_std=d["feat_std"],
            classifier=_rebuild(d, "classifier"),
            next_model=_rebuild(d, "next_model"),
            gps=gps,
            pooled=pooled,
            fingerprint=d.get("fingerprint", ""),
            window_cfg=d.get("window_cfg"),
            inputs_digest=d.get("inputs_digest", ""),
        )


def _equals(value: Any, expected: str | int) -> bool:
    """``value == expected`` for a checkpoint field of any type: a tensor or an array (whose
    ``==`` has no single truth value) is never equal."""
    return isinstance(value, str | int | float) and value == expected


def _rebuild(d: dict[str, Any], name: str) -> Any:
    """Rebuild the sub-model ``name`` of checkpoint dict ``d`` from its ``<name>_class``
    (``module:Class``) and its ``state_dict`` (``d[name]``) via ``from_state_dict``.

    Raises:
        CheckpointError: when ``<name>_class`` is not ``module:Class`` of an importable class
            with a ``from_state_dict`` (naming the field; the caller adds the file).
    """
    field_name = f"{name}_class"
    qualname, state = d[field_name], d[name]  # KeyError: an incomplete checkpoint
    if qualname is None and state is None:  # saved without this part
        return None
    if qualname is None or state is None:
        missing = field_name if qualname is None else name
        raise CheckpointError(f"{missing} is None but {name!r} is not saved as absent")
    mod_name, sep, cls_name = str(qualname).partition(":")
    try:
        if not sep or not mod_name or not cls_name:
            raise ValueError("expected 'module:Class'")
        obj_cls: Any = importlib.import_module(mod_name)
        for part in cls_name.split("."):
            obj_cls = getattr(obj_cls, part)
        from_state_dict = obj_cls.from_state_dict
    except (ImportError, AttributeError, ValueError) as err:
        raise CheckpointError(
            f"{field_name} {qualname!r} names no loadable class ({type(err).__name__}: {err})"
        ) from err
    return from_state_dict(state)
