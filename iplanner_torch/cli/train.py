"""``iplanner-train``: train a human motion predictor (IVM + sparse GPs + next-action model).

Examples::

    iplanner-train                                   # predictor=iplanner_ni on datasets/reaching
    iplanner-train predictor=iplanner_no_ni trainer=fast
    iplanner-train train.resume=true                 # skip sub-models already trained
    iplanner-train data=lego 'data.windows.joints=[right_hand]' train.out_dir=ck/lego_right
    # a sweep: one predictor per job, each in its own folder (ck/0, ck/1, ck/2)
    iplanner-train -m predictor.svgp.num_inducing=8,16,32 'train.out_dir=ck/${hydra:job.num}'

Writes ``<train.out_dir>/predictor.ckpt`` (default ``checkpoints/<dataset>/<predictor>/``), the
sub-models' Lightning checkpoints, CSV / TensorBoard logs and ``training_inputs.json`` (what
they were trained on: data, predictor, window and trainer settings, and the split by
demonstration, ``seed`` and ``data.split``, with the names of the held-out demonstrations,
which ``iplanner-evaluate`` scores; a resume on other data or settings is refused, and so is
a folder whose predictor was trained on other inputs unless ``train.overwrite=true``), then
prints held-out metrics. It reads ``data``, ``predictor``, ``trainer``, ``train``, ``seed``,
``paths`` and ``progress``; any other override (``device``: training runs on
``trainer.accelerator``) is refused. A missing or empty dataset folder is generated only when
it is the data option's own (``datasets/reaching``) or lies under ``paths.datasets``; a folder
given with ``data.path=<folder>`` elsewhere is read, never generated (``iplanner-data
generate`` writes one). A sweep (``-m``) checks every job before the first runs, refuses jobs
that would train into one ``train.out_dir``, and ends with ``summary/results.csv``, ``.md`` and
``metrics.png``: each job's held-out metrics beside the settings the jobs differ in.
"""

from __future__ import annotations

import json
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from iplanner_torch.cli._common import (
    CONF_DIR,
    cfg_scalar,
    check_added_keys,
    check_root_keys,
    config_split,
    data_settings,
    dataset_generator,
    friendly_errors,
    instantiate,
    load_dataset,
    overridden_fields,
    print_help_if_asked,
    refuse_unread_overrides,
    repo_path,
    run_app,
    write_job_record,
)
from iplanner_torch.errors import ConfigError, DataError, DataWarning
from iplanner_torch.files import json_text, whole_file


def train_from_config(
    cfg: DictConfig,
    predictor_node: DictConfig,
    out_dir: Path,
    *,
    trainer_node: DictConfig,
    data_node: DictConfig | None = None,
) -> tuple[Path, dict]:
    """Train one predictor as the config says; returns (checkpoint path, held-out metrics).

    Args:
        cfg: the root config (seed, progress, train.resume).
        predictor_node: a ``conf/predictor`` node.
        out_dir: where ``predictor.ckpt``, sub-model checkpoints and logs go.
        trainer_node: a ``conf/trainer`` node.
        data_node: a ``conf/data`` node (default ``cfg.data``); generated when absent or
            empty, unless the command line gives its folder (``data.path=...``) outside
            ``paths.datasets``.
    """
    data_node = cfg.data if data_node is None else data_node
    from iplanner_torch.data.windows import build_windows, split_by_demonstration
    from iplanner_torch.eval.prediction import evaluate_prediction
    from iplanner_torch.prediction.predictor import HumanMotionPredictor
    from iplanner_torch.prediction.training import train_predictor

    predictor_cfg, trainer_cfg, window_cfg, drawn = check_training(
        cfg, predictor_node, trainer_node, data_node
    )
    demos = load_dataset(
        data_node, generate_if_missing=True, progress=cfg_scalar(cfg, "progress", bool)
    )
    train, val, test = split_by_demonstration(demos, drawn.fractions, drawn.seed)
    if not train:
        raise DataError(
            f"data.split={list(drawn.fractions)} leaves none of the {len(demos)} "
            "demonstrations to train on; give the train share (the first) more"
        )
    # recorded beside the checkpoint: iplanner-evaluate scores the same held-out demonstrations
    split = replace(drawn, held_out=tuple(d.name for d in test))
    train_w = build_windows(train, window_cfg)
    if len(train_w) == 0:
        longest = max(d.num_frames for d in train)
        labelled = max(int((d.labels >= 0).sum()) for d in train)
        raise DataError(
            f"the {len(train)} training demonstrations give no training windows: a window "
            f"needs data.windows.n_prev + n_future = "
            f"{window_cfg.n_prev + window_cfg.n_future} frames, the n_prev-th of them labelled, "
            f"and the longest demonstration has {longest} frames ({labelled} labelled); "
            "lower data.windows.n_prev or n_future"
        )
    val_w = build_windows(val, window_cfg) if val else None
    horizon_s = window_cfg.n_future / float(train_w.fps)
    if horizon_s < 1.0 - 1e-6:  # said before the training, not after it (as evaluation does)
        warnings.warn(
            f"data.windows.n_future={window_cfg.n_future} at {train_w.fps:g} fps forecasts "
            f"{horizon_s:.2g} s: the held-out mhd_1s, mhd_1s_moving and the 'moving' test "
            f"will cover those {horizon_s:.2g} s, not 1 s; for 1 s set "
            f"data.windows.n_future={math.ceil(train_w.fps - 1e-9)} (and n_prev to match)",
            DataWarning,
            stacklevel=2,
        )
    resume = cfg_scalar(cfg.train, "resume", bool)
    # a resumed folder's earlier runs trained part (or all) of the predictor: their time
    # (what the last of them recorded) counts in this one's
    before = _recorded_seconds(out_dir / "heldout_metrics.json") if resume else 0.0
    t0 = time.perf_counter()
    ckpt = train_predictor(
        (train_w, val_w),
        predictor_cfg=predictor_cfg,
        trainer_cfg=trainer_cfg,
        out_dir=out_dir,
        progress=cfg_scalar(cfg, "progress", bool),
        resume=resume,
        split=split,
        overwrite=cfg_scalar(cfg.train, "overwrite", bool),
    )
    seconds = time.perf_counter() - t0 + before
    metrics: dict = {"train_seconds": seconds, "train_windows": len(train_w)}
    if test:
        predictor = HumanMotionPredictor.load(ckpt)
        with warnings.catch_warnings():  # the short horizon was named before the training
            warnings.filterwarnings("ignore", message="the predictor forecasts .* frames at")
            metrics.update(evaluate_prediction(predictor, test))
    else:
        warnings.warn(
            f"data.split={list(drawn.fractions)} holds out none of the {len(demos)} "
            "demonstrations (each group of one target or first action is cut by rounding), so "
            "there are no held-out metrics; use more demonstrations or a larger test fraction",
            DataWarning,
            stacklevel=2,
        )
    with whole_file(out_dir / "heldout_metrics.json") as tmp:
        tmp.write_text(json_text(metrics, indent=2) + "\n")
    return ckpt, metrics


def _recorded_seconds(path: Path) -> float:
    """``train_seconds`` of an earlier run's ``heldout_metrics.json``, or 0 when there is
    none (a run interrupted before it wrote the file) or it does not read as one."""
    try:
        value = json.loads(path.read_text(encoding="utf-8")).get("train_seconds", 0.0)
    except (OSError, ValueError, RecursionError, AttributeError):
        return 0.0
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    return float(value) if ok and math.isfinite(value) and value >= 0 else 0.0


def check_training(
    cfg: DictConfig,
    predictor_node: DictConfig,
    trainer_node: DictConfig,
    data_node: DictConfig,
) -> tuple[Any, Any, Any, Any]:
    """The settings of one training, checked before any data is read or generated (a sweep
    checks every job's before the first one starts: :func:`check_job`).

    Args:
        cfg: the root config (``seed``, ``progress``, ``train.resume``).
        predictor_node, trainer_node, data_node: as :func:`train_from_config` takes them.

    Returns:
        ``(predictor settings, trainer settings, window settings, split)``: a
        :class:`~iplanner_torch.prediction.predictor.PredictorCfg`, a
        :class:`~iplanner_torch.prediction.training.TrainerCfg`, a
        :class:`~iplanner_torch.data.windows.WindowCfg` and the
        :class:`~iplanner_torch.eval.prediction.SplitRecord` that ``seed`` and ``data.split``
        draw.

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    from iplanner_torch.data.windows import WindowCfg
    from iplanner_torch.prediction.predictor import PredictorCfg
    from iplanner_torch.prediction.training import TrainerCfg

    predictor_cfg = instantiate(predictor_node, PredictorCfg)
    trainer_cfg = instantiate(trainer_node, TrainerCfg)
    window_cfg = instantiate(data_node.windows, WindowCfg)
    drawn = config_split(cfg, data_node)
    data_settings(data_node)  # what load_dataset checks first, before it reads or generates
    if data_node.get("generator") is not None:  # used when the folder is missing
        dataset_generator(data_node, name="data.generator")
    cfg_scalar(cfg, "progress", bool)
    cfg_scalar(cfg.train, "resume", bool)
    cfg_scalar(cfg.train, "overwrite", bool)
    return predictor_cfg, trainer_cfg, window_cfg, drawn


def check_job(cfg: DictConfig) -> dict[str, Path]:
    """What a sweep checks of each ``iplanner-train`` job before the first starts: the checks
    the job makes before it trains (:func:`check_training` and the overrides it refuses).

    Returns:
        ``{"train.out_dir": folder}``: where the job writes its predictor, outside its job
        folder (a sweep refuses two jobs that would write the same).

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    check_added_keys(cfg)
    _refuse_unread(cfg)
    check_root_keys(cfg)
    _refuse_unread_svgp_fields(cfg)
    check_training(cfg, cfg.predictor, cfg.trainer, cfg.data)
    return {"train.out_dir": repo_path(cfg.train.out_dir)}


def _refuse_unread_svgp_fields(cfg: DictConfig) -> None:
    """Refuse a command-line ``predictor.svgp`` field that the chosen ``noisy_input`` does not
    read (:data:`~iplanner_torch.prediction.svgp.UNREAD_BY_NOISY_INPUT`):
    ``predictor.svgp.nigp_iterations=4`` with ``noisy_input=simple`` would change nothing."""
    from dataclasses import fields

    from iplanner_torch.errors import ConfigWarning
    from iplanner_torch.prediction.svgp import UNREAD_BY_NOISY_INPUT, SVGPCfg

    svgp = cfg.predictor.get("svgp")
    if not isinstance(svgp, DictConfig):  # not a predictor config: instantiating it says so
        return
    mode = str(svgp.get("noisy_input", "simple"))
    not_read = set(UNREAD_BY_NOISY_INPUT.get(mode, ()))
    which = (
        "nigp_iterations and nigp_refit_steps are read with noisy_input=nigp, "
        "input_noise_sigma with simple or nigp, velocity_limit with simple"
    )
    unread = sorted(overridden_fields("predictor.svgp") & not_read)
    if unread:
        keys = ", ".join(f"predictor.svgp.{k}" for k in unread)
        raise ConfigError(
            f"{keys}: not read with predictor.svgp.noisy_input={mode} ({which}); set "
            "predictor.svgp.noisy_input too, or leave them out"
        )
    # a predictor option file (a variant) that sets them to other than the defaults: the
    # shipped files list them at their defaults, for a switch of noisy_input
    defaults = {f.name: f.default for f in fields(SVGPCfg)}
    changed = [k for k in sorted(not_read) if k in svgp and svgp[k] != defaults.get(k)]
    if changed:
        keys = ", ".join(f"svgp.{k}: {svgp[k]}" for k in changed)
        warnings.warn(
            f"the predictor option sets {keys}, which noisy_input={mode} does not read "
            f"({which}): they change nothing",
            ConfigWarning,
            stacklevel=2,
        )


def _refuse_unread(cfg: DictConfig) -> None:
    """Refuse the overrides iplanner-train does not read (before their values are checked)."""
    refuse_unread_overrides(
        "iplanner-train",
        ("data", "predictor", "trainer", "train", "seed", "paths"),
        "it reads data, predictor, trainer, train, seed, paths and progress; it trains on "
        "trainer.accelerator (device is where iplanner-evaluate and iplanner-experiment run "
        "the predictors), evaluate.* belongs to iplanner-evaluate, and the closed-loop "
        "settings (robot, scenario, planner, sim, run, tracker, human) to iplanner-experiment",
    )


def _kept_when_interrupted(cfg: DictConfig) -> str:
    """What an interrupted training keeps, for its ``interrupted: ...`` line: the sub-models
    finished before the signal (a fit that was cut writes nothing), which ``train.resume=true``
    reuses."""
    out_dir = repo_path(cfg.train.out_dir)
    return (
        f"what was written before is kept in {out_dir} (training_inputs.json and the "
        "sub-models trained before the signal, as *.ckpt); run the same command with "
        "train.resume=true to go on from them"
    )


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
@friendly_errors(before=_refuse_unread, kept=_kept_when_interrupted)
def _app(cfg: DictConfig) -> None:
    _refuse_unread_svgp_fields(cfg)
    out_dir = repo_path(cfg.train.out_dir)
    ckpt, metrics = train_from_config(cfg, cfg.predictor, out_dir, trainer_node=cfg.trainer)
    # a copy in the run's own folder, which a sweep gathers into its summary
    write_job_record("heldout_metrics.json", {"checkpoint": str(ckpt), **metrics})
    print(f"predictor checkpoint: {ckpt}")
    print(f"logs: {out_dir / 'logs'}")
    print(f"run folder: {HydraConfig.get().runtime.output_dir} (train.log, .hydra/ config)")
    from iplanner_torch.eval.prediction import metric_line

    for key, value in metrics.items():
        print(metric_line(key, value))


def main() -> None:
    """Console entry point."""
    print_help_if_asked(
        __doc__ or "",
        sys.argv[1:],
        groups=("data", "predictor", "trainer"),
        root_keys="seed=<int>, progress=true|false (training runs on trainer.accelerator)",
    )
    run_app(_app)


if __name__ == "__main__":
    main()
