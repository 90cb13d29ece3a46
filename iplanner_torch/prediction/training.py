"""Lightning training of the whole predictor: classifier, next-action model and every GP.

* :class:`SVGPModule` trains one :class:`SVGPRegressor` with Adam on its collapsed ELBO
  (Titsias's bound; q in closed form, see :mod:`iplanner_torch.prediction.svgp`), logging
  ``train/elbo``; at the end q is set from all points and ``val/nll``, ``val/rmse`` are logged
  on the validation windows of its group. NIGP rounds are successive (warm-started) fits.
* :class:`IVMModule` lets Lightning drive the IVM's greedy fit: the greedy import loop runs
  inside the single training step of a single epoch (the IVM is not a gradient method), and
  the loss after each import step is logged as ``train/ivm_loss`` (step = import count).
* :func:`train_predictor` trains everything, writes a Lightning ``.ckpt`` per sub-model
  (``classifier.ckpt``, ``gp_p{p}_c{c}.ckpt``, ``gp_pooled_c{c}.ckpt``) and the combined
  ``predictor.ckpt`` (loadable by :meth:`HumanMotionPredictor.load`), with CSV and TensorBoard
  logs under ``out_dir``, and ``training_inputs.json``: what the sub-models were trained on
  (data fingerprint, actions, joints, predictor, window and trainer settings, and the
  demonstration split when the caller gives it, which evaluation reads to score the same
  held-out demonstrations). ``resume=True`` reuses sub-model checkpoints already written, after
  checking that record; each sub-model checkpoint keeps the record's
  :func:`~iplanner_torch.eval.prediction.inputs_digest` and a digest of its model, so one of
  another run (an interrupted one in the same folder) is trained anew and a changed file is
  refused. ``predictor.ckpt`` keeps the digest too, so a record rewritten by a later,
  unfinished run is not taken for its own.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import lightning as L
import torch
from torch.utils.data import DataLoader, TensorDataset
from tqdm.auto import tqdm

from iplanner_torch import checks
from iplanner_torch.data.windows import WindowSet, compute_features
from iplanner_torch.errors import (
    CheckpointError,
    ConfigError,
    DataError,
    DataWarning,
    checkpoint_load_error,
)
from iplanner_torch.eval.prediction import (
    INPUTS_FILE,
    RESUME_RECORD_KEYS,
    RESUME_SPLIT_FIELDS,
    RESUME_TRAINER_FIELDS,
    SplitRecord,
    flat_settings,
    inputs_digest,
    read_training_inputs,
)
from iplanner_torch.prediction.predictor import (
    HumanMotionPredictor,
    PredictorCfg,
    content_digest,
    dataset_fingerprint,
    gp_inputs,
)
from iplanner_torch.prediction.svgp import SVGPCfg, SVGPRegressor
from iplanner_torch.types import torch_threads

__all__ = [
    "IVMModule",
    "PredictorCfg",
    "SVGPCfg",
    "SVGPModule",
    "SplitRecord",
    "TrainerCfg",
    "input_noise_map",
    "train_predictor",
]


@dataclass(frozen=True, kw_only=True)
class TrainerCfg:
    """Lightning settings shared by every sub-model's training."""

    # cap on the GP epochs (None: SVGPCfg.epochs); the step cap SVGPCfg.max_steps also holds.
    max_epochs: int | None = None
    # cap on the optimiser steps of every GP fit (None: only SVGPCfg's caps).
    max_steps: int | None = None
    # Lightning accelerator: auto picks CUDA when present.
    accelerator: Literal["auto", "cpu", "gpu", "cuda"] = "auto"
    # devices per sub-model fit.
    devices: int = 1
    # logging interval [steps].
    log_every_n_steps: int = 10
    # seed of the global random state (torch, numpy, Python) at every fit (Lightning
    # seed_everything). The built-in models draw only from generators seeded by the
    # predictor's own seed (the root ``seed`` sets both), so this one alone changes none of
    # their numbers; it matters to code that reads the global state, e.g. a custom model.
    seed: int = 0
    # write TensorBoard logs beside the CSV logs.
    tensorboard: bool = True
    # torch CPU threads while training (restored after). The CPU sums are split across the
    # threads, so the thread count changes the fitted numbers in their last digits, which the
    # closed loop can amplify: a fixed count gives the same predictor for the same seed
    # whatever torch's own setting (core count, OMP_NUM_THREADS). None: torch's setting.
    num_threads: int | None = 2

    def __post_init__(self) -> None:
        # every number is checked for its range (NaN and infinities included): a bad value
        # fails here, before a training folder is touched
        checks.optional(checks.integer, "max_epochs", self.max_epochs, minimum=0)
        checks.optional(checks.integer, "max_steps", self.max_steps, minimum=0)
        if self.accelerator not in ("auto", "cpu", "gpu", "cuda"):
            raise ConfigError(
                f"accelerator must be auto, cpu, gpu or cuda, got {self.accelerator!r}"
            )
        checks.integer("devices", self.devices, minimum=1)
        checks.integer("log_every_n_steps", self.log_every_n_steps, minimum=1)
        # Lightning's seed_everything takes numpy's seeds only, 0 .. 2^32 - 1
        checks.seed(self.seed)
        checks.optional(checks.integer, "num_threads", self.num_threads, minimum=1)

    def cap_steps(self, steps: int) -> int:
        """``steps`` capped by :attr:`max_steps`."""
        return steps if self.max_steps is None else min(steps, self.max_steps)


class SVGPModule(L.LightningModule):
    """Trains one SVGP (eq. GPRlearning) on its collapsed ELBO (Titsias's bound).

    Each training step is one Adam step on the bound over a seeded subset of at most
    ``batch_size`` points (all points when N is smaller), logged as ``train/elbo``; at the end
    q is set in closed form from all points, the noise floor is calibrated on the validation
    windows of the group (:meth:`SVGPRegressor.calibrate`) and ``val/nll``, ``val/rmse`` are
    logged on them.

    Args:
        reg: the regressor (initialised with :meth:`SVGPRegressor.from_data`).
        x: (N, D_in) raw training inputs.
        y: (N, C) raw training outputs.
        extra: (N,) extra observation noise ``e_i`` (normalised units).
        steps: optimiser steps of this fit.
        x_val: (N_v, D_in) validation inputs, or None.
        y_val: (N_v, C) validation outputs, or None.
        calibrate: raise the noise floor on the validation windows at the end
            (:meth:`SVGPRegressor.calibrate`, when ``cfg.calibrate_floor``).
        inputs_digest: the training run's :func:`inputs_digest`, written into the checkpoint.
        round_index: the training round (0, then the noisy-input refits), whose minibatches
            are drawn (:meth:`SVGPRegressor.batch_indices`).
    """

    def __init__(
        self,
        reg: SVGPRegressor,
        x: torch.Tensor,
        y: torch.Tensor,
        extra: torch.Tensor,
        steps: int,
        x_val: torch.Tensor | None = None,
        y_val: torch.Tensor | None = None,
        calibrate: bool = True,
        inputs_digest: str = "",
        round_index: int = 0,
    ) -> None:
        super().__init__()
        self.reg = reg
        self.steps = int(steps)
        self.round_index = int(round_index)
        self.calibrate = bool(calibrate)
        self.inputs_digest = inputs_digest
        self.register_buffer("x", x, persistent=False)
        self.register_buffer("y", y, persistent=False)
        self.register_buffer("extra", extra, persistent=False)
        self.register_buffer("x_val", x_val, persistent=False)
        self.register_buffer("y_val", y_val, persistent=False)
        self.val_metrics: dict[str, float] = {}
        self._xn: torch.Tensor | None = None
        self._yn: torch.Tensor | None = None

    def on_train_start(self) -> None:
        self.reg.train()
        self._xn = self.reg.normalise_x(self.x)
        self._yn = self.reg.normalise_y(self.y)

    def train_dataloader(self) -> DataLoader:
        idx = self.reg.batch_indices(
            self.x.shape[0], max(self.steps, 1), torch.device("cpu"), self.round_index
        )
        return DataLoader(_IndexBatches(idx), batch_size=None, shuffle=False)

    def training_step(self, batch: torch.Tensor, batch_idx: int) -> torch.Tensor:
        idx = batch.to(self.x.device)
        loss = self.reg.elbo_loss(self._xn[idx], self._yn[idx], self.extra[idx], self.x.shape[0])
        self.log("train/elbo", -loss, prog_bar=True, on_step=True, on_epoch=False)
        return loss

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.Adam(self.reg.trainable_parameters(), lr=self.reg.cfg.lr)

    def on_train_end(self) -> None:
        self.reg.eval()
        self.reg.finalise(self.x, self.y, self.extra)
        self._xn = self._yn = None
        cfg = self.reg.cfg
        if (
            self.calibrate
            and cfg.calibrate_floor
            and self.x_val is not None
            and self.x_val.shape[0] >= cfg.calibrate_min_windows
        ):
            self.reg.calibrate(self.x_val, self.y_val, self.x, self.y, self.extra)
        if self.x_val is not None and self.x_val.shape[0]:
            mean, var = self.reg.predict(self.x_val)
            nll = 0.5 * (torch.log(2 * math.pi * var) + (self.y_val - mean) ** 2 / var)
            self.val_metrics = {
                "val/nll": float(nll.mean()),
                "val/rmse": float((self.y_val - mean).pow(2).mean().sqrt()),
            }
            for lg in self.loggers:
                lg.log_metrics(self.val_metrics, step=self.global_step)

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["svgp"] = self.reg.to_checkpoint()
        _stamp(checkpoint, "svgp", self.inputs_digest)


class _IndexBatches(torch.utils.data.Dataset):
    """A dataset whose items are precomputed index batches (one per optimiser step)."""

    def __init__(self, batches: list[torch.Tensor]) -> None:
        self.batches = batches

    def __len__(self) -> int:
        return len(self.batches)

    def __getitem__(self, i: int) -> torch.Tensor:
        return self.batches[i]


class IVMModule(L.LightningModule):
    """Lightning wrapper of the action classifier's greedy IVM fit (eq. IVMclassifier).

    The whole greedy import loop runs in the single training step of a single epoch; the loss
    history (one value per import step) is logged as ``train/ivm_loss``.

    Args:
        classifier: an unfitted ``ActionClassifier``.
        x: (N, n_p, D) normalised windows.
        progress: (N,) int64 progress bitmasks.
        current: (N,) int64 current actions.
        fit_kwargs: keyword arguments of ``classifier.fit`` (num_actions, kernel_factory, ...).
        inputs_digest: the training run's :func:`inputs_digest`, written into the checkpoint.
    """

    def __init__(
        self,
        classifier: Any,
        x: torch.Tensor,
        progress: torch.Tensor,
        current: torch.Tensor,
        fit_kwargs: dict[str, Any],
        inputs_digest: str = "",
    ) -> None:
        super().__init__()
        self.inputs_digest = inputs_digest
        self.automatic_optimization = False
        self.classifier = classifier
        self.data = (x, progress, current)
        self.fit_kwargs = fit_kwargs
        self.dummy = torch.nn.Parameter(torch.zeros(()))  # Lightning needs a parameter

    def train_dataloader(self) -> DataLoader:
        return DataLoader(TensorDataset(torch.zeros(1)), batch_size=1)

    def training_step(self, batch: Any, batch_idx: int) -> None:
        x, p, c = (t.to(self.device) for t in self.data)
        self.classifier.fit(x, p, c, **self.fit_kwargs)
        for step, loss in enumerate(_loss_history(self.classifier)):
            for lg in self.loggers:
                lg.log_metrics({"train/ivm_loss": float(loss)}, step=step)

    def configure_optimizers(self) -> torch.optim.Optimizer:
        # never stepped (the IVM is fitted greedily); returned to keep Lightning quiet
        return torch.optim.SGD([self.dummy], lr=0.0)

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["classifier"] = self.classifier.state_dict()
        _stamp(checkpoint, "classifier", self.inputs_digest)


def _loss_history(classifier: Any) -> list[float]:
    hist = getattr(classifier, "loss_history_", None)
    if hist is None:
        models = getattr(classifier, "models_", None) or getattr(classifier, "ivms_", None) or {}
        vals = models.values() if isinstance(models, dict) else models
        hist = [v for m in vals for v in getattr(m, "loss_history_", [])]
    return [float(v) for v in hist]


# ------------------------------------------------------------------------------ orchestration
def _trainer(
    tcfg: TrainerCfg,
    out_dir: Path,
    name: str,
    max_steps: int,
    progress: bool,
    max_epochs: int = -1,
) -> L.Trainer:
    import shutil

    from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger

    # the sub-model is trained anew: the logs of the one it replaces go first (TensorBoard
    # added this run's events beside the earlier run's in version_0, so the curves ran back
    # to step 0 and on again; the CSV logger replaced its file with a warning per sub-model)
    for root in (out_dir / "logs", out_dir / "tb"):
        shutil.rmtree(root / name / "version_0", ignore_errors=True)
    loggers: list[Any] = [CSVLogger(out_dir / "logs", name=name, version=0)]
    if tcfg.tensorboard:
        loggers.append(TensorBoardLogger(out_dir / "tb", name=name, version=0))
    return L.Trainer(
        max_steps=max_steps,
        max_epochs=max_epochs,
        accelerator=tcfg.accelerator,
        devices=tcfg.devices,
        logger=loggers,
        enable_checkpointing=False,
        enable_model_summary=False,
        enable_progress_bar=progress,
        log_every_n_steps=tcfg.log_every_n_steps,
        num_sanity_val_steps=0,
        limit_val_batches=0,
    )


def _quiet() -> None:
    warnings.filterwarnings("ignore", ".*does not have many workers.*")
    warnings.filterwarnings("ignore", ".*`configure_optimizers` returned `None`.*")
    warnings.filterwarnings("ignore", ".*GPU available but not used.*")
    warnings.filterwarnings("ignore", ".*Number of training batches.*")
    warnings.filterwarnings("ignore", ".*LeafSpec.*")
    warnings.filterwarnings("ignore", ".*in eval mode at the start of training.*")
    import logging

    for name in ("lightning.pytorch", "lightning.fabric", "lightning"):
        logging.getLogger(name).setLevel(logging.ERROR)


def _stamp(checkpoint: dict[str, Any], key: str, digest: str) -> None:
    """Write into a sub-model checkpoint the :func:`inputs_digest` of the run that trained it
    and ``model_digest``, the content digest of its model (``checkpoint[key]``) and of that:
    torch reads a changed byte inside a tensor without complaint, and a resumed run would
    build its predictor on it."""
    checkpoint["inputs_digest"] = digest
    checkpoint["model_digest"] = content_digest({key: checkpoint[key], "inputs_digest": digest})


def _resume(ckpt: Path, key: str, build: Any, digest: str) -> Any:
    """``build(torch.load(ckpt))`` for a sub-model checkpoint written by this run's inputs.

    A file that cannot be read or built, or whose model does not match its ``model_digest``
    (:func:`_stamp`), is a CheckpointError naming it and the way out (the sub-model is
    retrained without it). A file stamped with another run's :func:`inputs_digest` (a
    training run started in the folder since and interrupted before it came to this
    sub-model) gives None with a DataWarning: the caller trains the sub-model anew. A file
    written before the stamps is used as it is, unchecked, with a DataWarning.
    """
    try:
        d = torch.load(ckpt, map_location="cpu", weights_only=True)
        if not isinstance(d, dict) or key not in d:
            raise KeyError(key)
        if "model_digest" in d and d["model_digest"] != content_digest(
            {key: d[key], "inputs_digest": d.get("inputs_digest")}
        ):
            raise CheckpointError(
                "its contents do not match the digest written with them (the file is damaged)"
            )
        if d.get("inputs_digest", digest) != digest:
            warnings.warn(
                f"{ckpt} was trained by another training run (other data or settings) than "
                "this one: trained anew",
                DataWarning,
                stacklevel=3,
            )
            return None
        if "model_digest" not in d:  # both stamps came in together: an older file has neither
            warnings.warn(
                f"{ckpt} carries no digests (written before checkpoints were stamped): "
                "resumed from as it is, without the checks that it is undamaged and from this "
                "training run's data and settings; delete it to retrain that sub-model",
                DataWarning,
                stacklevel=3,
            )
        return build(d)
    except Exception as err:  # noqa: BLE001 - a broken file is an error the user must see
        # our own CheckpointError says what is wrong already; another error is named by type
        why = str(err) if isinstance(err, CheckpointError) else checkpoint_load_error(err)[1]
        raise CheckpointError(
            f"cannot resume from {ckpt}: {why}; delete the file to retrain that sub-model, or "
            "run with train.resume=false"
        ) from err


def train_svgp(
    x: torch.Tensor,
    y: torch.Tensor,
    *,
    cfg: SVGPCfg,
    tcfg: TrainerCfg,
    out_dir: Path,
    name: str,
    window: tuple[int, int] | None = None,
    x_val: torch.Tensor | None = None,
    y_val: torch.Tensor | None = None,
    progress: bool = True,
    resume: bool = False,
    noise_map: torch.Tensor | None = None,
    inputs_digest: str = "",
) -> SVGPRegressor:
    """Train one SVGP with Lightning (NIGP rounds included) and write ``<name>.ckpt``.

    Args:
        x: (N, D_in) raw inputs.
        y: (N, C) raw outputs.
        cfg: GP settings.
        tcfg: Lightning settings.
        out_dir: where the checkpoint and the logs go.
        name: sub-model name (file stem, logger name).
        window: (n_p, D) for the time-series kernels.
        x_val: (N_v, D_in) validation inputs, or None.
        y_val: (N_v, C) validation outputs, or None.
        progress: progress bars.
        resume: reuse ``<name>.ckpt`` when it exists.
        noise_map: (D_in, D_src) Jacobian of the inputs with respect to the noisy values
            (:func:`input_noise_map`) for nigp; None: each input column noisy on its own.
        inputs_digest: the training run's :func:`inputs_digest`, written into the checkpoint;
            with ``resume``, a checkpoint stamped with another is trained anew.

    Returns:
        The trained regressor (on the CPU).
    """
    ckpt = out_dir / f"{name}.ckpt"
    if resume and ckpt.is_file():
        reg = _resume(
            ckpt, "svgp", lambda d: SVGPRegressor.from_checkpoint(d["svgp"]), inputs_digest
        )
        if reg is not None:
            return reg
    L.seed_everything(tcfg.seed, verbose=False)
    reg = SVGPRegressor.from_data(cfg, x, y, window=window)
    n = x.shape[0]
    rounds = cfg.nigp_iterations + 1 if cfg.noisy_input == "nigp" else 1
    nigp = cfg.noisy_input == "nigp"
    extra = torch.zeros(n, dtype=x.dtype) if nigp else reg.extra_train_noise(x)
    trainer = None
    for r in range(rounds):
        if r > 0:
            reg.to(x.device)
            extra = reg.extra_train_noise(x, noise_map)
        steps = tcfg.cap_steps(
            cfg.steps_for(n, tcfg.max_epochs) if r == 0 else cfg.nigp_refit_steps
        )
        # the floor is calibrated once, after the last round
        module = SVGPModule(
            reg, x, y, extra, steps, x_val, y_val,
            calibrate=r == rounds - 1, inputs_digest=inputs_digest, round_index=r,
        )  # fmt: skip
        if steps > 0:
            trainer = _trainer(
                tcfg, out_dir, name if rounds == 1 else f"{name}_r{r}", steps, progress
            )
            trainer.fit(module)
        else:
            module.on_train_end()
    if trainer is not None:
        trainer.save_checkpoint(ckpt)
    else:
        d = {"svgp": reg.to_checkpoint()}
        _stamp(d, "svgp", inputs_digest)
        torch.save(d, ckpt)
    reg.to("cpu")
    reg._cache = None
    return reg


def _as_train_val(data: Any) -> tuple[WindowSet, WindowSet | None]:
    if isinstance(data, WindowSet):
        return data, None
    if isinstance(data, tuple | list) and len(data) == 2:
        return data[0], data[1]
    if hasattr(data, "train_windows"):
        if getattr(data, "train_windows", None) is None:
            data.setup("fit")
        return data.train_windows, data.val_windows
    raise DataError(
        f"expected a WindowSet, (train, val) WindowSets or a DataModule, got {type(data).__name__}"
    )


def input_noise_map(
    n_p: int, joint_names: Sequence[str], fps: float, kinds: Sequence[str], gp_input: str
) -> torch.Tensor:
    """(n_p D, n_p K 3) Jacobian of a window's GP inputs with respect to its observed joint
    positions, float64: the features (positions, and velocities and accelerations as finite
    differences of them, :func:`iplanner_torch.data.windows.compute_features`) and the GP
    input (:func:`iplanner_torch.prediction.predictor.gp_inputs`) are linear in the positions,
    so position noise ``sigma^2 I`` is ``sigma^2 A A^T`` on the GP inputs (NIGP). Column
    ``i`` is the GP input of a window whose positions are zero but for coordinate ``i``."""
    k = len(joint_names)
    basis = torch.eye(n_p * k * 3, dtype=torch.float64).reshape(-1, n_p, k, 3)
    f_prev = compute_features(basis, fps, kinds, joint_names=joint_names)  # (n_p K 3, n_p, D)
    return gp_inputs(f_prev, k, gp_input).T.contiguous()  # (n_p D, n_p K 3)


def _gp_xy(w: WindowSet, gp_input: str) -> tuple[torch.Tensor, torch.Tensor]:
    """GP inputs (N, n_p D) and future positions relative to the pose (N, n_f K 3)."""
    n = len(w)
    x = gp_inputs(w.f_prev.float(), len(w.joint_names), gp_input)  # (N, n_p * D)
    y = (w.xi_next - w.pose_now.unsqueeze(1)).reshape(n, -1).float()  # (N, n_f * K * 3)
    return x, y


def _subsample(idx: torch.Tensor, n_max: int, seed: int) -> torch.Tensor:
    if idx.numel() <= n_max:
        return idx
    g = torch.Generator().manual_seed(seed)
    return idx[torch.randperm(idx.numel(), generator=g)[:n_max]].sort().values


def _classifier_kernel_factory(cfg: PredictorCfg) -> Any:
    """A callable ``windows (N, n_p, D) -> kernel`` with the median bandwidth rule."""
    from iplanner_torch.prediction import dtw

    def factory(x: torch.Tensor) -> Any:
        bw = cfg.classifier_bandwidth
        if cfg.classifier_kernel == "rbf":
            if bw is None:
                flat = x.reshape(x.shape[0], -1)
                bw = float(torch.cdist(flat[:256], flat[:256]).median().clamp_min(1e-6))
            return dtw.RBFKernel(bw)
        if bw is None:
            med = dtw.median_dtw(x, 256, cfg.seed)
            bw = med if cfg.classifier_kernel == "dtw" else dtw.gak_sigma(med, x.shape[1])
        if cfg.classifier_kernel == "dtw":
            return dtw.DTWKernel(bw)
        return dtw.GlobalAlignmentKernel(bw)

    return factory


def _check_accelerator(tcfg: TrainerCfg) -> None:
    """Check that ``tcfg.accelerator`` and ``tcfg.devices`` exist on this machine.

    Lightning finds out only when its first trainer starts, after the training folder has
    been written to (``training_inputs.json``, earlier logs replaced), and then raises its own
    ``MisconfigurationException``.

    Raises:
        ConfigError: for ``cuda`` without CUDA, ``gpu`` without CUDA or MPS, or more
            ``devices`` than CUDA devices where training runs on CUDA.
    """
    cuda = torch.cuda.is_available()
    if tcfg.accelerator == "cuda" and not cuda:
        raise ConfigError(
            "trainer.accelerator=cuda but CUDA is not available here; use "
            "trainer.accelerator=cpu or auto"
        )
    if tcfg.accelerator == "gpu" and not (cuda or torch.backends.mps.is_available()):
        raise ConfigError(
            "trainer.accelerator=gpu but no GPU (CUDA or MPS) is available here; use "
            "trainer.accelerator=cpu or auto"
        )
    on_cuda = tcfg.accelerator == "cuda" or (tcfg.accelerator in ("gpu", "auto") and cuda)
    if on_cuda and tcfg.devices > torch.cuda.device_count():
        raise ConfigError(
            f"trainer.devices={tcfg.devices} but this machine has "
            f"{torch.cuda.device_count()} CUDA device(s)"
        )


def train_predictor(
    data: Any,
    *,
    predictor_cfg: PredictorCfg,
    trainer_cfg: TrainerCfg,
    out_dir: str | Path,
    progress: bool = True,
    resume: bool = False,
    split: SplitRecord | None = None,
    overwrite: bool = False,
) -> Path:
    """Train the classifier, the next-action model and all GPs; write ``predictor.ckpt``.

    Args:
        data: training windows: a WindowSet, a (train, val) pair of WindowSets (val may be
            None), or a DataModule with ``train_windows`` / ``val_windows``.
        predictor_cfg: predictor settings.
        trainer_cfg: Lightning settings, and the torch thread count while training
            (:attr:`TrainerCfg.num_threads`; torch's count is restored after).
        out_dir: folder for checkpoints (``*.ckpt``) and logs (``logs/`` CSV, ``tb/``).
        progress: progress bars.
        resume: skip sub-models whose checkpoint already exists in ``out_dir``, after
            checking that ``out_dir / training_inputs.json`` records the same training data
            (fingerprint), actions, joints and settings (predictor, window, trainer, split).
        split: how the demonstrations behind ``data`` were split, recorded in
            ``training_inputs.json`` so that evaluation scores the ones held out
            (:func:`iplanner_torch.eval.prediction.recorded_split`); None: not recorded.
        overwrite: replace a ``predictor.ckpt`` in ``out_dir`` trained on other inputs.
            Without it (and without ``resume``) such a folder is refused before anything is
            written: only a predictor of the same recorded inputs (data fingerprint, actions,
            joints, predictor, window, trainer and split settings, as a resume compares
            them), which the same seed trains anew to the same numbers, is replaced.

    Returns:
        The path of ``predictor.ckpt``.

    Raises:
        ConfigError: when ``trainer_cfg.accelerator`` (or its ``devices``) is not available
            on this machine; checked before anything is written to ``out_dir``.
        DataError: for empty data.
        CheckpointError: (``resume``) when the folder's sub-models were trained on other
            inputs, or a reused sub-model cannot be read; (neither ``resume`` nor
            ``overwrite``) when the folder holds a predictor trained on other inputs, or one
            whose training record is missing or unreadable; or when the assembled predictor
            fails on its own training windows (a sub-model of another shape). An existing
            ``predictor.ckpt`` is then left as it was.
    """
    _check_accelerator(trainer_cfg)
    with torch_threads(trainer_cfg.num_threads):
        return _train_predictor(
            data,
            predictor_cfg=predictor_cfg,
            trainer_cfg=trainer_cfg,
            out_dir=out_dir,
            progress=progress,
            resume=resume,
            split=split,
            overwrite=overwrite,
        )


def _train_predictor(
    data: Any,
    *,
    predictor_cfg: PredictorCfg,
    trainer_cfg: TrainerCfg,
    out_dir: str | Path,
    progress: bool,
    resume: bool,
    split: SplitRecord | None,
    overwrite: bool,
) -> Path:
    """:func:`train_predictor` on the thread count it set."""
    _quiet()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    train, val = _as_train_val(data)
    if len(train) == 0:
        raise DataError("no training windows")
    cfg = predictor_cfg
    n_p, d = train.f_prev.shape[1], train.f_prev.shape[2]
    feat_mean = train.f_prev.reshape(-1, d).mean(0)
    feat_std = train.f_prev.reshape(-1, d).std(0).clamp_min(1e-6)
    progress_actions = train.cfg.progress_indices(train.action_names)
    fingerprint = dataset_fingerprint(train.f_prev, train.xi_next, train.current)
    digest = _record_inputs(
        out_dir, fingerprint, train, cfg, trainer_cfg, split, resume, overwrite
    )

    groups: dict[tuple[int, int], torch.Tensor] = {}
    for p in torch.unique(train.progress).tolist():
        for c in torch.unique(train.current[train.progress == p]).tolist():
            idx = torch.nonzero((train.progress == p) & (train.current == c))[:, 0]
            groups[(int(p), int(c))] = idx
    jobs = [(pc, idx) for pc, idx in sorted(groups.items()) if idx.numel() >= cfg.min_group_size]
    fitted = {pc for pc, _ in jobs}
    pooled_jobs: list[tuple[int, torch.Tensor]] = []
    aliases: dict[int, tuple[int, int]] = {}  # action -> its one group's GP, reused as pooled
    for c in torch.unique(train.current).tolist():
        own = [pc for pc in groups if pc[1] == c]
        if len(own) == 1 and own[0] in fitted:
            aliases[c] = own[0]
            continue
        idx = torch.nonzero(train.current == c)[:, 0]
        if idx.numel() >= cfg.min_group_size:
            pooled_jobs.append((c, idx))
    # one bar over the sub-models (the classifier and every GP) instead of one per model
    bar = tqdm(
        total=1 + len(jobs) + len(pooled_jobs),
        desc=f"training {out_dir.name}",
        unit="model",
        disable=not progress,
    )
    bar.set_postfix_str("classifier")
    classifier = _train_classifier(
        train, cfg, trainer_cfg, out_dir, feat_mean, feat_std, resume, digest
    )
    bar.update()
    next_model = _train_next_action(train, cfg)

    x_all, y_all = _gp_xy(train, cfg.gp_input)
    noise_map = (
        input_noise_map(n_p, train.joint_names, train.fps, train.cfg.feature_kinds, cfg.gp_input)
        if cfg.svgp.noisy_input == "nigp"
        else None
    )
    xv_all, yv_all = _gp_xy(val, cfg.gp_input) if val is not None and len(val) else (None, None)

    def val_rows(p: int | None, c: int) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        if xv_all is None:
            return None, None
        m = val.current == c
        if p is not None:
            m &= val.progress == p
        return xv_all[m], yv_all[m]

    def fit(idx: torch.Tensor, p: int | None, c: int, name: str) -> SVGPRegressor:
        """One GP on (a subsample of) the training rows ``idx``, validated on (p, c)."""
        idx = _subsample(idx, cfg.max_gp_points, cfg.seed)
        xv, yv = val_rows(p, c)
        bar.set_postfix_str(name)
        reg = train_svgp(
            x_all[idx],
            y_all[idx],
            cfg=cfg.svgp,
            tcfg=trainer_cfg,
            out_dir=out_dir,
            name=name,
            window=(n_p, d),
            x_val=xv,
            y_val=yv,
            progress=False,
            resume=resume,
            noise_map=noise_map,
            inputs_digest=digest,
        )
        bar.update()
        return reg

    gps: dict[tuple[int, int], SVGPRegressor] = {}
    for (p, c), idx in jobs:
        gps[(p, c)] = fit(idx, p, c, f"gp_p{p}_c{c}")
    own_pooled = {c: fit(idx, None, c, f"gp_pooled_c{c}") for c, idx in pooled_jobs}
    bar.close()
    pooled: dict[int, SVGPRegressor] = {}
    for c in torch.unique(train.current).tolist():  # in action order, as the predictor keeps it
        if c in aliases:
            pooled[c] = gps[aliases[c]]
        elif c in own_pooled:
            pooled[c] = own_pooled[c]

    predictor = HumanMotionPredictor(
        cfg=cfg,
        joint_names=train.joint_names,
        action_names=train.action_names,
        fps=train.fps,
        n_prev=n_p,
        n_future=train.xi_next.shape[1],
        feature_kinds=train.cfg.feature_kinds,
        progress_actions=progress_actions,
        feat_mean=feat_mean,
        feat_std=feat_std,
        classifier=classifier,
        next_model=next_model,
        gps=gps,
        pooled=pooled,
        fingerprint=fingerprint,
        window_cfg=asdict(train.cfg),
        inputs_digest=digest,
    )
    try:  # the assembled predictor must pass load's check before it replaces a file
        predictor.predict(train.f_prev[:4], train.progress[:4])
        predictor.prepare()._self_check()  # every GP, the classifier, the next-action model
    except Exception as err:  # noqa: BLE001 - reported with the way out
        raise CheckpointError(
            f"the predictor assembled from the sub-models in {out_dir} fails on its own "
            f"training windows ({type(err).__name__}: {err}); {out_dir / 'predictor.ckpt'} "
            "is left as it was. Delete the sub-model checkpoints (*.ckpt) or run with "
            "train.resume=false"
        ) from err
    return predictor.save(out_dir / "predictor.ckpt")


def _record_inputs(
    out_dir: Path,
    fingerprint: str,
    train: WindowSet,
    cfg: PredictorCfg,
    tcfg: TrainerCfg,
    split: SplitRecord | None,
    resume: bool,
    overwrite: bool = False,
) -> str:
    """Write ``out_dir / INPUTS_FILE`` (training data fingerprint, action names, predictor,
    window and trainer settings, and the split when given). With ``resume``, first compare it
    with the file already there: sub-models trained on other data or settings must not be mixed
    into this predictor. The trainer settings (:data:`RESUME_TRAINER_FIELDS`) and the split
    (seed, fractions) are compared only where the file records them (it did not always).
    Without ``resume`` or ``overwrite``, a ``predictor.ckpt`` already in ``out_dir`` is kept
    unless its record shows the same inputs (:func:`train_predictor`).

    Returns:
        The record's :func:`inputs_digest`.

    Raises:
        CheckpointError: (``resume``) when the recorded inputs differ, naming what differs;
            (neither) when a predictor of other inputs, or of no readable record, is there.
    """
    inputs = json.loads(
        json.dumps(
            {
                "fingerprint": fingerprint,
                "action_names": list(train.action_names),
                "joint_names": list(train.joint_names),
                "fps": float(train.fps),
                "predictor_cfg": asdict(cfg),
                "window_cfg": asdict(train.cfg),
                "trainer_cfg": asdict(tcfg),
                **({} if split is None else {"split": asdict(split)}),
            },
            default=str,
        )
    )
    path = out_dir / INPUTS_FILE
    if not resume and not overwrite:
        _refuse_replacing(out_dir, inputs)
    try:
        before = read_training_inputs(out_dir) if resume else None
    except CheckpointError as err:
        raise CheckpointError(
            f"cannot resume in {out_dir}: {err}; run with train.resume=false"
        ) from None
    if before is not None:
        changed = _record_differences(before, inputs)
        if changed:
            values = " (recorded -> now)" if any("->" in c for c in changed) else ""
            raise CheckpointError(
                f"cannot resume in {out_dir}: its sub-models were trained with other "
                f"{', '.join(changed)} than this run's{values}; choose another train.out_dir "
                "or run with train.resume=false"
            )
    elif resume and any(out_dir.glob("*.ckpt")):
        warnings.warn(
            f"{out_dir} has no {INPUTS_FILE} (written since this check exists): the reused "
            "sub-models cannot be checked against this run's data and settings",
            DataWarning,
            stacklevel=3,
        )
    path.write_text(json.dumps(inputs, indent=2) + "\n", encoding="utf-8")
    return inputs_digest(inputs)


def _record_differences(before: dict[str, Any], inputs: dict[str, Any]) -> list[str]:
    """What differs between two training records, in words (:func:`_record_change`): the
    parts of :data:`RESUME_RECORD_KEYS`, and the trainer and split fields where both records
    hold them."""
    changed = [
        _record_change(k, before.get(k), inputs[k])
        for k in RESUME_RECORD_KEYS
        if before.get(k) != inputs[k]
    ]
    if "fps" in before and before["fps"] != inputs.get("fps"):  # recorded since it is
        changed.append(f"frame rate ({before['fps']!r} -> {inputs.get('fps')!r} fps)")
    for key, fields in (
        ("trainer_cfg", RESUME_TRAINER_FIELDS),
        ("split", RESUME_SPLIT_FIELDS),
    ):
        was, now = before.get(key), inputs.get(key)
        if not isinstance(was, dict) or now is None:  # not recorded then, or not given now
            continue
        differ = [f"{f} {was.get(f)!r} -> {now[f]!r}" for f in fields if was.get(f) != now[f]]
        if differ:
            changed.append(f"{_RECORD_NAMES[key]} ({', '.join(differ)})")
    return changed


def _refuse_replacing(out_dir: Path, inputs: dict[str, Any]) -> None:
    """CheckpointError when ``out_dir`` holds a ``predictor.ckpt`` that this training would
    replace and its record does not show the same inputs (``inputs``): a predictor of other
    data, joints or settings would be lost without a word."""
    if not (out_dir / "predictor.ckpt").is_file():
        return
    way_out = (
        "choose another train.out_dir, or add train.overwrite=true to replace it "
        "(its sub-model checkpoints and logs too)"
    )
    try:
        before = read_training_inputs(out_dir)
    except CheckpointError as err:
        raise CheckpointError(
            f"{out_dir} holds a predictor.ckpt whose training record cannot be read ({err}), "
            f"so this run cannot tell whether it would replace it by the same; {way_out}"
        ) from None
    if before is None:
        raise CheckpointError(
            f"{out_dir} holds a predictor.ckpt without {INPUTS_FILE}, so this run cannot tell "
            f"whether it would replace it by the same; {way_out}"
        )
    changed = _record_differences(before, inputs)
    if changed:
        values = " (recorded -> now)" if any("->" in c for c in changed) else ""
        raise CheckpointError(
            f"{out_dir} holds a predictor trained with other {', '.join(changed)} than this "
            f"run's{values}; {way_out}"
        )


#: how a resume refusal names the parts of a training record
_RECORD_NAMES = {
    "fingerprint": "training data",
    "action_names": "actions",
    "joint_names": "joints",
    "predictor_cfg": "predictor settings",
    "window_cfg": "window settings (data.windows)",
    "trainer_cfg": "trainer settings",
    "split": "split",
}


def _record_change(key: str, was: Any, now: Any) -> str:
    """What differs in part ``key`` of a training record, in words: ``training data (other
    demonstrations, or other windows of them)``, ``joints [...] -> [...]``, ``predictor
    settings (svgp.num_inducing 16 -> 8)``."""
    name = _RECORD_NAMES.get(key, key)
    if key == "fingerprint":
        return f"{name} (other demonstrations, or other windows of them)"
    if isinstance(was, dict) and isinstance(now, dict):
        a, b = flat_settings(was), flat_settings(now)
        keys = [k for k in dict.fromkeys([*a, *b]) if a.get(k) != b.get(k)]
        shown = [f"{k} {a.get(k)!r} -> {b.get(k)!r}" for k in keys[:4]]
        more = f", and {len(keys) - 4} more" if len(keys) > 4 else ""
        return f"{name} ({', '.join(shown)}{more})"
    return f"{name} ({was!r} -> {now!r})"


def _train_classifier(
    train: WindowSet,
    cfg: PredictorCfg,
    tcfg: TrainerCfg,
    out_dir: Path,
    feat_mean: torch.Tensor,
    feat_std: torch.Tensor,
    resume: bool,
    digest: str = "",
) -> Any:
    """Fit the action classifier with Lightning (None when the IVM module is unavailable);
    its own progress bar is off (the caller's bar counts it as one sub-model)."""
    try:
        from iplanner_torch.prediction.ivm import ActionClassifier
    except ImportError:
        warnings.warn("prediction.ivm is unavailable: uniform action weights", stacklevel=2)
        return None
    ckpt = out_dir / "classifier.ckpt"
    if resume and ckpt.is_file():
        clf = _resume(
            ckpt, "classifier", lambda d: ActionClassifier.from_state_dict(d["classifier"]), digest
        )
        if clf is not None:
            return clf
    L.seed_everything(tcfg.seed, verbose=False)
    idx = _subsample(torch.arange(len(train)), cfg.classifier_max_train, cfg.seed)
    x = (train.f_prev[idx] - feat_mean) / feat_std
    fit_kwargs = {
        "num_actions": len(train.action_names),
        "kernel_factory": _classifier_kernel_factory(cfg),
        "ivm_kwargs": {
            "lam": cfg.ivm_lam,
            "max_import": cfg.ivm_max_import,
            "tol": cfg.ivm_tol,
            "candidates": cfg.ivm_candidates,
            "newton_steps": cfg.ivm_newton_steps,
            "seed": cfg.seed,
        },
    }
    # the classifier sees the hands' positions and velocities (what separates reaches early);
    # the windows are still passed whole and the columns are picked inside the classifier
    from iplanner_torch.prediction.ivm import feature_columns

    kinds = [k for k in ("position", "velocity") if k in train.cfg.feature_kinds]
    hands = [j for j in ("left_hand", "right_hand") if j in train.joint_names]
    index = (
        feature_columns(train.joint_names, train.cfg.feature_kinds, hands, kinds)
        if hands and kinds
        else None
    )
    clf = ActionClassifier(feature_index=index)
    module = IVMModule(
        clf, x, train.progress[idx], train.current[idx], fit_kwargs, inputs_digest=digest
    )
    # manual optimisation never steps an optimiser, so the budget is one epoch, not one step
    trainer = _trainer(tcfg, out_dir, "classifier", -1, False, max_epochs=1)
    trainer.fit(module)
    trainer.save_checkpoint(ckpt)
    return clf


def _train_next_action(train: WindowSet, cfg: PredictorCfg) -> Any:
    """Fit the next-action histograms (None when the coherence module is unavailable)."""
    try:
        from iplanner_torch.prediction.coherence import NextActionModel
    except ImportError:
        warnings.warn("prediction.coherence is unavailable: uniform next actions", stacklevel=2)
        return None
    return NextActionModel().fit(
        train.progress,
        train.current,
        train.next_action,
        num_actions=len(train.action_names),
        smoothing=cfg.coherence_smoothing,
    )
