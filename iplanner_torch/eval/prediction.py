"""Evaluation of the human motion predictor on held-out data (sec. 7.1, fig. result_prediction).

Metrics, per held-out window (averaged over windows unless stated):

* ``class_precision``: among windows whose top action probability exceeds 0.5, the share whose
  top action is the true current action (``class_confident`` is that share of windows);
  ``class_accuracy``: that share among all windows. With one action (a recording labelled
  as one, such as the LEGO trials) both are 1 by construction.
* ``reg_precision``: ``int_0^T sum_i ||p_pred,i(t) - p_true,i(t)||^2 dt`` [m^2 s] with the
  mixture mean (sum over actions of weight x mean), rectangle rule on the n_f frames.
* ``reg_accuracy``: ``int_0^T sum_i det K_i(t) dt`` [m^6 s] with ``K_i`` the diagonal covariance
  of the moment-matched mixture (per coordinate ``sum_a w_a (var_a + mean_a^2) - mean^2``).
* ``mhd_1s``: modified Hausdorff distance (Dubuisson and Jain 1994) between the predicted mean
  trajectory and the true trajectory of the moving hand over the first second [m] (over the
  whole forecast when it is shorter, with a warning: :func:`short_horizon`); the moving
  hand is the joint named ``*hand*`` (else any joint) with the largest true displacement in that
  second: the largest distance of its true future positions from its position at the current
  frame (the window's last observed frame, ``WindowSet.pose_now``), as the closed-loop
  ``eval/mhd`` measures it. ``mhd_1s_moving`` averages only windows in which that displacement
  (``hand_motion``) exceeds 5 cm.
* ``coverage90/95/99``: share of held-out future joint positions inside the 90/95/99 %
  ellipsoids of the *top action's* Gaussian (diagonal covariance; squared Mahalanobis distance
  against the chi-square quantile with 3 degrees of freedom).

The held-out demonstrations are those the predictor's training left out: training records its
split (:class:`SplitRecord`) in ``training_inputs.json`` beside the checkpoint
(:func:`recorded_split`), and :func:`held_out_demonstrations` draws the same split again.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from scipy.stats import chi2

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.windows import (
    WindowCfg,
    WindowSet,
    build_windows,
    check_split_fractions,
    split_by_demonstration,
)
from iplanner_torch.errors import (
    CheckpointError,
    ConfigError,
    DataError,
    DataWarning,
    ShapeError,
)
from iplanner_torch.eval.metrics import modified_hausdorff_batch as modified_hausdorff
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import check_shape

COVERAGE_LEVELS = (0.90, 0.95, 0.99)

#: the file beside a trained ``predictor.ckpt`` that records what its sub-models were trained
#: on (written by :func:`iplanner_torch.prediction.training.train_predictor`; defined here so
#: that reading it does not load Lightning)
INPUTS_FILE = "training_inputs.json"

#: the trainer settings that shape the fitted sub-models (accelerator, devices, num_threads,
#: log_every_n_steps and tensorboard change where they are computed and what is logged, not
#: what is fitted, save for float rounding)
RESUME_TRAINER_FIELDS = ("max_epochs", "max_steps", "seed")
#: the parts of an :data:`INPUTS_FILE` record that decide what the sub-models are, compared
#: whole (the trainer's :data:`RESUME_TRAINER_FIELDS` and the split's
#: :data:`RESUME_SPLIT_FIELDS` decide them too)
RESUME_RECORD_KEYS = ("fingerprint", "action_names", "joint_names", "predictor_cfg", "window_cfg")
RESUME_SPLIT_FIELDS = ("seed", "fractions")


def inputs_digest(record: dict[str, Any]) -> str:
    """SHA-256 of what in a training record decides the trained model: the data fingerprint,
    action and joint names, predictor and window settings, the trainer's
    :data:`RESUME_TRAINER_FIELDS` and the split's seed and fractions.

    ``train_predictor`` writes it into every sub-model checkpoint and into ``predictor.ckpt``,
    so that a sub-model or a record of another training run in the same folder (one started
    there since, say, and interrupted) is told apart from this run's.

    Args:
        record: the :data:`INPUTS_FILE` record (as ``json.loads`` reads it).
    """
    import hashlib

    trainer = record.get("trainer_cfg")
    split = record.get("split")
    key = {
        **{k: record.get(k) for k in RESUME_RECORD_KEYS},
        "trainer_cfg": {f: trainer.get(f) for f in RESUME_TRAINER_FIELDS}
        if isinstance(trainer, dict)
        else None,
        "split": {f: split.get(f) for f in RESUME_SPLIT_FIELDS}
        if isinstance(split, dict)
        else None,
    }
    text = json.dumps(key, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True, kw_only=True)
class SplitRecord:
    """How a training run split its demonstrations (:func:`split_by_demonstration`), recorded
    with its checkpoint so that evaluation scores the demonstrations training held out."""

    # shuffling seed of split_by_demonstration.
    seed: int
    # (train, val, test) shares of the demonstrations.
    fractions: tuple[float, float, float]
    # names of the test (held-out) demonstrations; empty: not recorded.
    held_out: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "fractions", check_split_fractions(self.fractions))
        object.__setattr__(self, "held_out", tuple(str(n) for n in self.held_out))

    def describe(self) -> str:
        """``seed=1 data.split=[0.6,0.2,0.2]``: the command-line settings that draw this split."""
        return f"seed={self.seed} data.split=[{','.join(f'{f:g}' for f in self.fractions)}]"


def read_training_inputs(folder: str | Path) -> dict[str, Any] | None:
    """The :data:`INPUTS_FILE` record in a training folder (or beside a checkpoint in it).

    Args:
        folder: the training folder, or a checkpoint file in it.

    Returns:
        The record, or None when the folder has none.

    Raises:
        CheckpointError: naming the file, when it does not read as a JSON object.
    """
    folder = Path(folder)
    path = (folder.parent if folder.suffix == ".ckpt" else folder) / INPUTS_FILE
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise CheckpointError(f"{path} is unreadable ({type(err).__name__}: {err})") from None
    except RecursionError:  # "[" * 100000: the JSON decoder recursed too deep
        raise CheckpointError(f"{path} is unreadable (JSON nested too deep)") from None
    if not isinstance(record, dict):
        raise CheckpointError(
            f"{path} is unreadable (expected a JSON object, got {type(record).__name__})"
        )
    return record


def recorded_split(
    ckpt: str | Path,
    fingerprint: str,
    digest: str = "",
    *,
    split_given: bool = False,
    predictor_cfg: dict[str, Any] | None = None,
) -> SplitRecord | None:
    """The split recorded in :data:`INPUTS_FILE` beside ``ckpt``, when that file records the
    training of this checkpoint: its :func:`inputs_digest` is the one the checkpoint keeps
    (``digest``), or, for a checkpoint that keeps none, it names the same training data
    (``fingerprint``).

    A record of another training run (one started in the checkpoint's folder since, and
    interrupted before it wrote its own ``predictor.ckpt``) does not say which
    demonstrations this checkpoint held out, and the split ``seed`` and ``data.split`` draw
    may include some it was trained on; it is refused, unless the caller says the split is
    given explicitly (``split_given``: the command line sets it).

    Args:
        ckpt: a ``predictor.ckpt``.
        fingerprint: the checkpoint's ``HumanMotionPredictor.fingerprint``.
        digest: the checkpoint's ``HumanMotionPredictor.inputs_digest`` ("" when it keeps
            none: trained before checkpoints kept it).
        split_given: the split to fall back on is given explicitly (``seed`` on the command
            line), so a record of another run is passed over with a warning.
        predictor_cfg: the checkpoint's predictor settings (``asdict(predictor.cfg)``), to
            name those a record of another run differs in; None: not named.

    Returns:
        The record, or None when there is none for this checkpoint: trained before the split
        was recorded, copied away from its training folder, or (without ``digest``) the
        folder was trained anew since on other data.

    Raises:
        CheckpointError: when the record beside ``ckpt`` belongs to another training run than
            the checkpoint's and ``split_given`` is false.

    Warns:
        DataWarning: when the file is there but cannot be read, or (``split_given``) when it
            belongs to another training run.
    """
    if not fingerprint and not digest:
        return None
    try:
        inputs = read_training_inputs(ckpt)
    except CheckpointError as err:
        _unreadable_split(ckpt, err)
        return None
    if inputs is None:
        return None
    if digest and inputs_digest(inputs) != digest:
        _other_run(ckpt, inputs, split_given, predictor_cfg)
        return None
    if not digest and inputs.get("fingerprint") != fingerprint:
        return None
    try:
        return _split_of(inputs)
    except (ConfigError, ValueError, TypeError, KeyError, AttributeError) as err:
        _unreadable_split(ckpt, err)
        return None


def _split_of(inputs: dict[str, Any]) -> SplitRecord | None:
    """The split an :data:`INPUTS_FILE` record keeps (None when it keeps none).

    Raises:
        ConfigError, ValueError, TypeError, KeyError: what is wrong with it.
    """
    split = inputs.get("split")
    if split is None:
        return None
    if not isinstance(split, dict):
        raise TypeError(f"split is {type(split).__name__}, not an object")
    seed, held_out = split["seed"], split.get("held_out", [])
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"split seed {seed!r} is not a non-negative integer")
    if not isinstance(held_out, list) or not all(isinstance(n, str) for n in held_out):
        raise TypeError(f"split held_out {held_out!r} is not a list of names")
    if not isinstance(split["fractions"], list):
        raise TypeError(f"split fractions {split['fractions']!r} is not a list")
    return SplitRecord(seed=seed, fractions=tuple(split["fractions"]), held_out=held_out)


def _unreadable_split(ckpt: str | Path, err: Exception) -> None:
    """Warn that the split recorded beside ``ckpt`` cannot be read (:func:`recorded_split`)."""
    warnings.warn(
        f"cannot read the held-out split of {ckpt} ({type(err).__name__}: {err}); the "
        "split is drawn from seed and data.split",
        DataWarning,
        stacklevel=3,
    )


def flat_settings(value: Any, prefix: str = "") -> dict[str, Any]:
    """Nested settings (a dict of dicts) as dotted keys: ``{"svgp.noisy_input": "simple",
    "seed": 0, ...}``; an empty dict gives no key."""
    if not isinstance(value, dict):
        return {prefix: value}
    out: dict[str, Any] = {}
    for k, v in value.items():
        out.update(flat_settings(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def _other_run(
    ckpt: str | Path,
    inputs: dict[str, Any],
    split_given: bool,
    predictor_cfg: dict[str, Any] | None = None,
) -> None:
    """Refuse (or, with ``split_given``, warn about) the :data:`INPUTS_FILE` record beside
    ``ckpt`` that another training run than the checkpoint's wrote (:func:`recorded_split`),
    naming the predictor settings it differs in when ``predictor_cfg`` is given."""
    path = Path(ckpt).parent / INPUTS_FILE
    split = inputs.get("split")
    try:
        drawn = SplitRecord(seed=split["seed"], fractions=tuple(split["fractions"])).describe()
        records = f" (it records the split {drawn})"
    except Exception:  # noqa: BLE001 - what it records is only named when it reads
        records = ""
    differ = ""
    if predictor_cfg is not None and isinstance(inputs.get("predictor_cfg"), dict):
        rec = flat_settings(inputs["predictor_cfg"])
        own = flat_settings(json.loads(json.dumps(predictor_cfg, default=str)))
        keys = [k for k in dict.fromkeys([*rec, *own]) if rec.get(k) != own.get(k)]
        if keys:
            shown = ", ".join(f"{k} {rec.get(k)!r} (record) / {own.get(k)!r}" for k in keys[:4])
            differ = f"; predictor settings: {shown}{', ...' if len(keys) > 4 else ''}"
    text = (
        f"{path} is not the record of {ckpt}{records}: its inputs differ from those the "
        f"checkpoint was trained under{differ}. Either a training started in this folder "
        "after the checkpoint was written and was interrupted before it wrote its own, or the "
        "checkpoint was copied here from another folder; so the record does not say which "
        "demonstrations the checkpoint held out"
    )
    if split_given:
        warnings.warn(
            f"{text}; the held-out split is drawn from seed and data.split as the command line "
            "gives them, unchecked against the checkpoint's training",
            DataWarning,
            stacklevel=3,
        )
        return
    raise CheckpointError(
        f"{text}, and the split seed and data.split draw may include demonstrations it was "
        f"trained on; retrain it (iplanner-train ... train.out_dir={Path(ckpt).parent} "
        "train.overwrite=true), or "
        "pass the seed and data.split it was trained with (seed=<int> data.split=[...]) to "
        "score the demonstrations they hold out"
    )


#: the unit of each metric :func:`evaluate_prediction` returns (and of the training's own),
#: printed beside its value
METRIC_UNITS: dict[str, str] = {
    "n_windows": "windows",
    "n_confident": "windows",
    "class_confident": "share",
    "class_precision": "share",
    "class_accuracy": "share",
    "reg_precision": "m^2 s",
    "reg_accuracy": "m^6 s",
    "mhd_1s": "m",
    "mhd_1s_moving": "m",
    **{f"coverage{round(q * 100)}": "share" for q in COVERAGE_LEVELS},
    "train_seconds": "s",
    "train_windows": "windows",
}


def metric_line(key: str, value: Any) -> str:
    """``  mhd_1s                       0.03275 m``: a metric as the commands print it, with
    its unit (:data:`METRIC_UNITS`) when it has one."""
    text = f"{value:.4g}" if isinstance(value, float) else str(value)
    unit = METRIC_UNITS.get(key, "")
    return f"  {key:28s} {text}{f' {unit}' if unit else ''}"


def held_out_demonstrations(
    demos: Sequence[Demonstration], split: SplitRecord
) -> list[Demonstration]:
    """The test demonstrations of ``split`` among ``demos`` (drawn again with its seed and
    fractions).

    Args:
        demos: the dataset's demonstrations.
        split: how training split them.

    Returns:
        The held-out demonstrations, in the input order.

    Warns:
        DataWarning: when the split records the names of its held-out demonstrations and the
            ones drawn now are others: ``demos`` is not the dataset the predictor was trained
            on (or it was generated anew), so the metrics may include training demonstrations.
    """
    _, _, test = split_by_demonstration(demos, split.fractions, split.seed)
    names = sorted(d.name for d in test)
    if split.held_out and names != sorted(split.held_out):
        unknown = sorted(set(names) - set(split.held_out))
        warnings.warn(
            f"{split.describe()} holds out {len(test)} demonstration(s) of this data, "
            f"{len(unknown)} of them not among the {len(split.held_out)} the predictor's "
            f"training held out{f' (e.g. {unknown[:3]})' if unknown else ''}: this is not the "
            "dataset it was trained on, or it was generated anew; the metrics may include "
            "demonstrations it was trained on, or leave out some it was not",
            DataWarning,
            stacklevel=2,
        )
    return test


def window_metrics(
    fc: Forecast, xi_true: torch.Tensor, current: torch.Tensor, pose_now: torch.Tensor
) -> dict[str, Any]:
    """Per-window metrics of one batch of forecasts (see the module docstring).

    Args:
        fc: the forecasts (B windows).
        xi_true: (B, n_f, K, 3) true future positions [m].
        current: (B,) int64 true current actions.
        pose_now: (B, K, 3) positions at the current frame, the last observed one [m]
            (``WindowSet.pose_now``); the hands' displacements are measured from it.

    Returns:
        Dict of (B,) tensors: top_prob, correct, reg_precision, reg_accuracy, mhd_1s,
        hand_motion (the moving hand's largest distance from ``pose_now`` within the first
        second [m]) and ``inside{90,95,99}`` (B, n_f, K) bool.

    Raises:
        ShapeError: when ``fc`` is not a Forecast, ``xi_true`` is not (B, n_f, K, 3) of the
            forecast's dtype, ``pose_now`` not (B, K, 3), or ``current`` not a (B,) integer
            tensor (a (1,) one was broadcast: every window scored against its one label; a
            label no action of the forecast has, such as -1, scores as not correct).
    """
    if not isinstance(fc, Forecast):
        raise ShapeError(f"expected fc a Forecast, got {type(fc).__name__}")
    check_shape("xi_true", xi_true, tuple(fc.mean.shape[:1]) + tuple(fc.mean.shape[2:]))
    if xi_true.dtype != fc.mean.dtype:
        raise ShapeError(
            f"expected xi_true of the forecast's dtype {fc.mean.dtype}, got {xi_true.dtype}"
        )
    check_shape("pose_now", pose_now, (xi_true.shape[0], xi_true.shape[2], 3))
    check_shape("current", current, (xi_true.shape[0],))
    if current.is_floating_point() or current.is_complex() or current.dtype == torch.bool:
        raise ShapeError(f"expected current (B,) integer action indices, got {current.dtype}")
    w = fc.weights  # (B, A)
    mean = fc.expected_mean()  # (B, n_f, K, 3)
    second = torch.einsum("ba,bafkc->bfkc", w, fc.var + fc.mean**2)
    var_mix = (second - mean**2).clamp_min(0.0)
    dt = fc.dt
    err2 = (mean - xi_true).pow(2).sum(-1).sum(-1)  # (B, n_f)
    top_p, top = w.max(-1)
    out: dict[str, Any] = {
        "top_prob": top_p,
        "correct": top == current.to(top.device),
        "reg_precision": err2.sum(-1) * dt,
        "reg_accuracy": var_mix.prod(-1).sum(-1).sum(-1) * dt,
    }
    n1 = max(1, min(fc.horizon, int(round(1.0 / dt))))
    hands = [i for i, n in enumerate(fc.joint_names) if "hand" in n] or list(
        range(len(fc.joint_names))
    )
    true_h = xi_true[:, :n1, hands]  # (B, n1, H, 3)
    now_h = pose_now.to(xi_true)[:, hands]  # (B, H, 3)
    disp = (true_h - now_h[:, None]).norm(dim=-1).amax(1)  # (B, H)
    hmax, which = disp.max(-1)
    j = torch.tensor(hands, device=which.device)[which]  # (B,)
    b_idx = torch.arange(xi_true.shape[0], device=which.device)
    pred_traj = mean[:, :n1].permute(0, 2, 1, 3)[b_idx, j]  # (B, n1, 3)
    true_traj = xi_true[:, :n1].permute(0, 2, 1, 3)[b_idx, j]  # (B, n1, 3)
    out["mhd_1s"] = modified_hausdorff(pred_traj, true_traj)
    out["hand_motion"] = hmax
    m_top = fc.mean[b_idx, top]  # (B, n_f, K, 3)
    v_top = fc.var[b_idx, top].clamp_min(1e-12)
    d2 = ((xi_true - m_top) ** 2 / v_top).sum(-1)  # (B, n_f, K)
    for q in COVERAGE_LEVELS:
        out[f"inside{round(q * 100)}"] = d2 <= float(chi2.ppf(q, 3))
    return out


def _names(names: Sequence[str], shown: int = 4) -> str:
    head = ", ".join(names[:shown]) + (", ..." if len(names) > shown else "")
    return f"{len(names)} action{'' if len(names) == 1 else 's'} ({head})"


def short_horizon(predictor: Any) -> float | None:
    """The predictor's forecast horizon ``n_future / fps`` [s] when it is shorter than the
    1 s that ``mhd_1s`` names (the metric then covers the shorter horizon), else None."""
    n_future, fps = getattr(predictor, "n_future", None), getattr(predictor, "fps", None)
    if n_future is None or not fps:
        return None
    horizon = float(n_future) / float(fps)
    return horizon if horizon < 1.0 - 1e-6 else None


def check_data_matches(predictor: Any, fps: float, action_names: Sequence[str]) -> None:
    """Warn when data differs in frame rate or actions from what ``predictor`` was trained on.

    Args:
        predictor: a :class:`HumanMotionPredictor` (its ``fps`` and ``action_names``, stored
            in the checkpoint).
        fps: the data's frame rate [Hz].
        action_names: the data's A action names.

    Warns:
        DataWarning: when the frame rates differ (the predicted frames are ``1 / fps`` of the
            checkpoint apart, the true ones ``1 / fps`` of the data, so the position metrics
            compare different instants), or when the action names differ (the class metrics
            then compare labels of unrelated action sets and the progress states stand for
            other actions).
    """
    p_fps = getattr(predictor, "fps", None)
    if p_fps is not None and not math.isclose(float(p_fps), float(fps), rel_tol=1e-6):
        warnings.warn(
            f"the data is at {float(fps):g} fps but the predictor was trained at "
            f"{float(p_fps):g} fps: its frames are 1/{float(p_fps):g} s apart and the data's "
            f"1/{float(fps):g} s, so predicted and true positions are compared at different "
            "times",
            DataWarning,
            stacklevel=3,
        )
    p_actions = tuple(getattr(predictor, "action_names", ()) or ())
    if p_actions and p_actions != tuple(action_names):
        warnings.warn(
            f"the data has {_names(tuple(action_names))} but the predictor was trained on "
            f"{_names(p_actions)}: the class_* metrics compare unrelated labels and the "
            "progress states stand for other actions (bits of actions the predictor has no "
            "progress state for are dropped); only the position metrics compare like with "
            "like",
            DataWarning,
            stacklevel=3,
        )


def evaluate_prediction(
    predictor: Any,
    data: WindowSet | Sequence[Demonstration],
    *,
    batch_size: int = 512,
    moving_threshold: float = 0.05,
    return_frame: bool = False,
) -> dict[str, float] | tuple[dict, Any]:
    """Evaluate a predictor on held-out windows or demonstrations (paper fig. result_prediction).

    Args:
        predictor: a :class:`HumanMotionPredictor`, or a forecaster with its ``predict``,
            window settings and ``fps`` but no actions (``action_names`` empty, e.g.
            :class:`~iplanner_torch.prediction.constant_velocity.ConstantVelocityPredictor`):
            its class metrics are NaN.
        data: held-out windows, or demonstrations (cut with the predictor's window settings).
        batch_size: windows per forward pass.
        moving_threshold: the moving hand's largest distance from its current position
            within 1 s (``hand_motion``) above which a window counts as moving [m].
        return_frame: also return a pandas DataFrame with one row per window.

    Returns:
        Dict of averaged metrics (see the module docstring) plus ``n_windows``,
        ``n_confident``; with ``return_frame`` a (dict, DataFrame) pair.

    Raises:
        DataError: when there are no windows.

    Warns:
        DataWarning: when the data's frame rate or action names differ from the predictor's
            (:func:`check_data_matches`). A mismatch warns rather than raises: the positions
            can still be compared (e.g. to see how a predictor carries over to other motion),
            but the numbers are not the predictor's held-out accuracy.
    """
    if isinstance(data, WindowSet):
        check_data_matches(predictor, data.fps, data.action_names)
        windows = data
    else:
        demos = list(data)
        if demos:  # build_windows checks that the demonstrations agree with the first one
            check_data_matches(predictor, demos[0].fps, demos[0].action_names)
        wc = dict(predictor.window_cfg) if predictor.window_cfg else {}
        wc.update(
            n_prev=predictor.n_prev,
            n_future=predictor.n_future,
            joints=predictor.joint_names,
            feature_kinds=predictor.feature_kinds,
        )
        windows = build_windows(demos, WindowCfg(**wc))
    if len(windows) == 0:
        raise DataError("no held-out windows to evaluate")
    horizon_s = short_horizon(predictor)
    if horizon_s is not None:
        fps = float(predictor.fps)
        warnings.warn(
            f"the predictor forecasts {predictor.n_future} frames at {fps:g} Hz, "
            f"{horizon_s:.2g} s: mhd_1s, mhd_1s_moving and the 'moving' test cover those "
            f"{horizon_s:.2g} s, not 1 s; for a 1 s horizon train with "
            f"data.windows.n_future={math.ceil(fps - 1e-9)} (and n_prev to match)",
            DataWarning,
            stacklevel=2,
        )
    progress = windows.progress
    p_actions = tuple(getattr(predictor, "action_names", ()) or ())
    p_progress = getattr(predictor, "progress_actions", None)
    if p_actions and p_actions != tuple(windows.action_names) and p_progress is not None:
        # warned (other actions): the data's progress bits name its own actions; keep those
        # the predictor has a progress state for, as predict() refuses any other bit
        progress = progress & sum(1 << a for a in p_progress)
    parts: dict[str, list[torch.Tensor]] = {}
    with torch.no_grad():
        for s in range(0, len(windows), batch_size):
            sl = slice(s, s + batch_size)
            fc = predictor.predict(windows.f_prev[sl], progress[sl])
            m = window_metrics(
                fc, windows.xi_next[sl].to(fc.mean), windows.current[sl], windows.pose_now[sl]
            )
            for k, v in m.items():
                parts.setdefault(k, []).append(v.cpu())
    cat = {k: torch.cat(v) for k, v in parts.items()}
    conf = cat["top_prob"] > 0.5
    moving = cat["hand_motion"] > moving_threshold
    res = {
        "n_windows": float(len(windows)),
        "n_confident": float(conf.sum()),
        "class_confident": float(conf.float().mean()),
        "class_precision": float(cat["correct"][conf].float().mean())
        if conf.any()
        else float("nan"),
        "class_accuracy": float(cat["correct"].float().mean()),
        "reg_precision": float(cat["reg_precision"].mean()),
        "reg_accuracy": float(cat["reg_accuracy"].mean()),
        "mhd_1s": float(cat["mhd_1s"].mean()),
        "mhd_1s_moving": float(cat["mhd_1s"][moving].mean()) if moving.any() else float("nan"),
    }
    for q in COVERAGE_LEVELS:
        res[f"coverage{round(q * 100)}"] = float(cat[f"inside{round(q * 100)}"].float().mean())
    if not p_actions:  # no action model (a constant-velocity forecast): no class to score
        for key in ("n_confident", "class_confident", "class_precision", "class_accuracy"):
            res[key] = math.nan
    if not return_frame:
        return res
    import pandas as pd

    frame = pd.DataFrame(
        {
            "demo_index": windows.demo_index.numpy(),
            "frame_index": windows.frame_index.numpy(),
            "current": windows.current.numpy(),
            "top_prob": cat["top_prob"].numpy(),
            "correct": cat["correct"].numpy(),
            "reg_precision": cat["reg_precision"].numpy(),
            "reg_accuracy": cat["reg_accuracy"].numpy(),
            "mhd_1s": cat["mhd_1s"].numpy(),
            "hand_motion": cat["hand_motion"].numpy(),
        }
    )
    return res, frame
