"""``iplanner-evaluate``: evaluate trained predictors and study episode logs.

Modes (``evaluate.mode``)::

    iplanner-evaluate                                   # prediction: held-out metrics
    iplanner-evaluate evaluate.checkpoint=checkpoints/reaching/iplanner_no_ni/predictor.ckpt
    iplanner-evaluate evaluate.mode=noise_sweep         # fig. result_prediction (NI vs no NI)
    iplanner-evaluate evaluate.mode=episode evaluate.logs=outputs/experiment/<run>/episodes
    iplanner-evaluate evaluate.mode=episode evaluate.logs=outputs/experiment/<run>/results.csv
    iplanner-evaluate evaluate.mode=episode \\
        'evaluate.logs=[<runA>/results.csv,<runB>/results.csv]' \\
        'evaluate.labels=[held,spread]' evaluate.baseline=itomp@spread

``prediction`` evaluates one checkpoint on the held-out demonstrations of ``data`` (the same
split by demonstration as training); ``noise_sweep`` re-noises the held-out clean motion at
each ``evaluate.noises`` level and replays it at each ``evaluate.speeds`` speed, for each
predictor in ``evaluate.compare`` (trained when missing), and writes CSV, PNG plots and a
README; ``episode`` summarises MCAP episode logs, or the episode rows of a results CSV (an
experiment's ``results.csv``, or rows gathered from several runs), with one row per episode, a
summary table and plots, and prints the table ``iplanner-experiment`` prints
(:func:`~iplanner_torch.eval.report.comparison_table`: episode counts, then the paper's metrics
in cm and ms); an episode whose log was cut before its metrics counts in ``contact_unknown``,
not as contact-free nor as a contact. ``evaluate.logs`` may list several sources: with
``evaluate.labels`` each source's planners are renamed ``<planner>@<label>``, so two runs of
one planner (with and without an option) stay apart, and ``evaluate.baseline`` names the
planner that ``results.md`` compares the others with, seed by seed.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from iplanner_torch.cli._common import (
    CONF_DIR,
    cfg_list,
    cfg_scalar,
    friendly_errors,
    load_dataset,
    print_help_if_asked,
    repo_path,
)
from iplanner_torch.errors import CheckpointError, ConfigError, DataError

MODES = ("prediction", "noise_sweep", "episode")


def _out_dir(cfg: DictConfig) -> Path:
    """The folder the tables and plots go to, created now so that a bad path fails before the
    evaluation runs rather than after it."""
    if cfg.evaluate.out_dir:
        path = repo_path(cfg.evaluate.out_dir)
    else:
        path = Path(HydraConfig.get().runtime.output_dir)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"evaluate.out_dir={path} is a file; give a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"evaluate.out_dir={path}: cannot create it ({exc})") from None
    return path


def _checkpoint(path: Path, cfg: DictConfig) -> Path:
    """``path`` when it is a file; otherwise a CheckpointError that says what it is and, when
    missing, the training command for this dataset and predictor."""
    if path.is_dir():
        raise CheckpointError(f"{path}: is a folder, not a checkpoint file (predictor.ckpt)")
    if not path.exists():
        predictor = HydraConfig.get().runtime.choices.get("predictor", "iplanner_ni")
        raise CheckpointError(
            f"{path}: no checkpoint; train one with `iplanner-train data.path={cfg.data.path} "
            f"predictor={predictor} train.out_dir={path.parent}`"
        )
    return path


def _check_joints(cfg: DictConfig, predictor: Any, ckpt: Path) -> None:
    """Refuse a ``data.windows.joints`` selection that leaves out a joint of the checkpoint.

    Evaluation forecasts the joints the predictor was trained on, so the held-out data must
    keep them all; a narrower selection used to fail later as "unknown joint names" for the
    joints it had dropped.
    """
    selected = cfg.data.windows.get("joints", None) if "windows" in cfg.data else None
    if not selected:
        return
    selected = [str(j) for j in selected]
    dropped = [j for j in predictor.joint_names if j not in selected]
    if dropped:
        raise ConfigError(
            f"data.windows.joints={selected} leaves out {dropped}, which {ckpt} was trained "
            f"on (its joints: {list(predictor.joint_names)}); evaluation forecasts the "
            "checkpoint's joints: leave data.windows.joints out, or evaluate a checkpoint "
            "trained with that selection"
        )


def _held_out(cfg: DictConfig) -> list:
    from iplanner_torch.data.windows import split_by_demonstration

    demos = load_dataset(
        cfg.data, generate_if_missing=False, progress=cfg_scalar(cfg, "progress", bool)
    )
    fractions = tuple(float(f) for f in cfg.data.get("split", (0.8, 0.1, 0.1)))
    _, _, test = split_by_demonstration(demos, fractions, cfg_scalar(cfg, "seed", int))
    if not test:
        raise ConfigError(f"data.split={list(fractions)} leaves no held-out demonstrations")
    return test


def _prediction(cfg: DictConfig) -> None:
    from iplanner_torch.eval.prediction import evaluate_prediction
    from iplanner_torch.prediction.predictor import HumanMotionPredictor

    ckpt = _checkpoint(repo_path(cfg.evaluate.checkpoint), cfg)
    out = _out_dir(cfg) / "prediction_metrics.json"
    predictor = HumanMotionPredictor.load(ckpt)
    _check_joints(cfg, predictor, ckpt)
    metrics = evaluate_prediction(predictor, _held_out(cfg))
    out.write_text(json.dumps(metrics, indent=2, default=float))
    print(f"{ckpt} on held-out demonstrations of {cfg.data.path}:")
    for key, value in metrics.items():
        print(f"  {key:28s} {value:.4g}" if isinstance(value, float) else f"  {key:28s} {value}")
    print(f"wrote {out}")


def _noise_sweep(cfg: DictConfig) -> None:
    from iplanner_torch.cli.experiment import option_node
    from iplanner_torch.cli.train import train_from_config
    from iplanner_torch.eval.prediction_sweep import prediction_vs_noise, write_noise_report
    from iplanner_torch.prediction.predictor import HumanMotionPredictor

    report_dir = _out_dir(cfg)
    predictors = {}
    for option in cfg.evaluate.compare:
        out_dir = repo_path(Path(cfg.paths.checkpoints) / Path(cfg.data.path).name / str(option))
        ckpt = out_dir / "predictor.ckpt"
        if not ckpt.exists():
            print(f"training missing predictor {option} ...", flush=True)
            train_from_config(
                cfg,
                option_node("predictor", str(option), cfg),
                out_dir,
                trainer_node=cfg.trainer,
            )
        predictors[str(option)] = HumanMotionPredictor.load(ckpt)
        _check_joints(cfg, predictors[str(option)], ckpt)
    df = prediction_vs_noise(
        predictors,
        _held_out(cfg),
        noises=cfg_list(cfg.evaluate, "noises", float),
        speeds=[str(s) for s in cfg.evaluate.speeds],
        seed=cfg_scalar(cfg, "seed", int),
        progress=cfg_scalar(cfg, "progress", bool),
    )
    command = "iplanner-evaluate " + " ".join(HydraConfig.get().overrides.task)
    written = write_noise_report(df, report_dir, command=command)
    print(df.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    print("wrote " + ", ".join(str(p) for p in written))


def _episode_rows(path: Path) -> Any:
    """The episode rows of one source of ``evaluate.logs`` (an .mcap file, a folder of them or
    a results .csv), refused with a clear error when it holds none."""
    from iplanner_torch.eval.report import gather_results

    if path.is_dir() and not any(path.rglob("*.mcap")):
        raise ConfigError(f"{path}: no .mcap episode logs found")
    df = gather_results(path)  # a folder: every log below it, in numbered order
    if path.suffix == ".csv" and df.empty:
        raise DataError(f"{path}: no episode rows; nothing to report")
    if path.suffix == ".csv" and "planner" not in df.columns:
        raise DataError(f"{path}: no 'planner' column; is this an episode results file?")
    if "planner" not in df.columns or df["planner"].isna().all():
        raise DataError(
            f"{path}: none of the {len(df)} episode log(s) could be read as far as its "
            "metadata (each is truncated or damaged near its start); nothing to report"
        )
    return df


def _episode(cfg: DictConfig) -> None:
    import pandas as pd
    from omegaconf import ListConfig

    from iplanner_torch.cli.callbacks import episode_report, sweep_overrides
    from iplanner_torch.eval.report import comparison_table, incomplete_logs_note, print_table

    logs = cfg.evaluate.logs
    if not logs:
        raise ConfigError(
            "evaluate.mode=episode needs evaluate.logs=<an .mcap file, a folder of them or a "
            "results .csv>, or a list of them"
        )
    several = isinstance(logs, (list, tuple, ListConfig))
    sources = (
        cfg_list(cfg.evaluate, "logs", str) if several else [cfg_scalar(cfg.evaluate, "logs", str)]
    )
    paths = [repo_path(x) for x in sources]
    labels: list[str] | None = None
    if cfg.evaluate.get("labels") is not None:
        labels = cfg_list(cfg.evaluate, "labels", str)
        if len(labels) != len(paths) or len(set(labels)) != len(labels) or "" in labels:
            raise ConfigError(
                f"evaluate.labels: expected {len(paths)} different, non-empty labels, one per "
                f"source of evaluate.logs, got {labels}"
            )
    baseline = cfg.evaluate.get("baseline")
    out_dir = _out_dir(cfg)
    frames, swept = [], []
    for i, path in enumerate(paths):
        df = _episode_rows(path)
        if path.is_dir():  # a multirun folder: the overrides its jobs differ in
            df, keys = sweep_overrides(df, path)
            swept += [k for k in keys if k not in swept]
        if labels is not None:  # keep the runs apart: itomp@held, itomp@spread, ...
            named = df["planner"].notna()  # a log cut before its metadata has none
            df = df.assign(planner=df["planner"].where(~named, df["planner"] + "@" + labels[i]))
        frames.append(df)
    df = pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]
    if baseline is None:
        baseline = "itomp"
    else:
        baseline = cfg_scalar(cfg.evaluate, "baseline", str)
        if not (df["planner"] == baseline).any():
            names = sorted(str(x) for x in df["planner"].dropna().unique())
            raise ConfigError(
                f"evaluate.baseline={baseline!r}: no episodes of that planner; the planners "
                f"are {names}"
            )
    written = episode_report(df, out_dir, baseline=baseline, split_by=swept)
    print_table(comparison_table(df))  # the columns and units of iplanner-experiment's table
    note = incomplete_logs_note(df)
    if note:
        print(note)
    print(f"{len(df)} episode(s); wrote " + ", ".join(str(p) for p in written))


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
@friendly_errors
def _app(cfg: DictConfig) -> None:
    mode = str(cfg.evaluate.mode)
    if mode not in MODES:
        raise ConfigError(f"evaluate.mode must be one of {MODES}, got {mode!r}")
    {"prediction": _prediction, "noise_sweep": _noise_sweep, "episode": _episode}[mode](cfg)


def main() -> None:
    """Console entry point."""
    print_help_if_asked(__doc__ or "", sys.argv[1:])
    _app()


if __name__ == "__main__":
    main()
