"""``iplanner-experiment``: closed-loop human-robot experiments in MuJoCo (paper sec. 7).

Examples::

    iplanner-experiment                                # the main job: one scenario, 3 planners
    iplanner-experiment robot=fetch scenario=arrangement_2x2 'run.seeds=[0,1,2]'
    iplanner-experiment experiment=table_simulation    # paper table performance_simulation
    iplanner-experiment experiment=table_simulation run.jobs=2   # 2 episodes at once
    iplanner-experiment experiment=speed_response      # paper fig. speed_response
    iplanner-experiment 'run.planners=[itomp,iplanner_ni,iplanner_cv]'   # + constant velocity
    iplanner-experiment -m tracker.noise=0,0.02,0.05 human.speed=slow,medium,fast \\
        planner.confidence=0.9,0.95,0.99              # a sweep (one job per combination)
    iplanner-experiment -m hydra/launcher=joblib tracker.noise=0,0.02   # local processes
    iplanner-experiment experiment=table_simulation hydra.run.dir=outputs/table \\
        run.resume=true                                # go on with a run that stopped

Without ``experiment=...`` the run uses the ``scenario`` group at the confidence
``planner.confidence`` (which follows ``scenario.confidence`` unless set), the planners in
``run.planners`` and the seeds in ``run.seeds``. With it, the experiment file lists its own
scenarios, planners, seeds, speeds and noises; the ``sim`` and ``planner`` groups give the episode
settings it does not override. The ``planner`` group holds the settings (confidence, optimiser)
every planner of the run is built with, each as its kind (the default option's settings serve all
three planners of the main job), but for what its ``per_kind.<planner>`` entries set for one
planner (by default the I-Planners' warm starts; a ``planner.<key>`` of the command line serves
every planner); ``planner=<option>`` runs that planner alone. ``iplanner_cv`` plans on a
constant-velocity forecast (``run.cv``), ``oracle`` on the true future, ``blind`` as if nobody
were there: none of them needs a predictor. The learned I-Planner variants need predictors:
by default (``run.train_data=tasks``) each scenario's predictors learn from task
demonstrations of its arrangement and task order (``datasets/tasks_<...>``, generated when absent;
a blocking scenario's from the reaching set), kept in
``checkpoints/<dataset>/iplanner_{ni,no_ni}/``; missing ones (every scenario's) are trained on a
small budget (``run.train_trainer``) before any episode runs when ``run.train_if_missing`` is
true; an existing one is used as it is, but a command-line ``run.train_trainer``, ``seed`` or
``data.windows.*`` value it was not trained with is refused. Results: ``results.csv``,
``results.md``, plots, ``episodes/*.mcap`` and, unless ``run.timeline_plots=false``, one
timeline plot per log (``episodes/<episode>.png``, see
:mod:`iplanner_torch.eval.timeline`) in the run folder, with ``run_inputs.json`` (the
settings, code and predictors it began with). ``run.resume=true hydra.run.dir=<folder>``
(``hydra.sweep.dir`` for ``-m``) continues a run that stopped with the same settings: its
finished episodes are kept, the others run. ``run.jobs=N`` runs N episodes at once, each in a
worker process (:func:`~iplanner_torch.eval.experiment.episode_pool`): the same rows and logs
as one after the other, but for the wall-clock timings.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import sys
import time
from collections.abc import Iterator
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf, open_dict

from iplanner_torch.cli._common import (
    CONF_DIR,
    cfg_list,
    cfg_scalar,
    check_added_keys,
    check_root_keys,
    dump_config,
    friendly_errors,
    instantiate,
    overridden_fields,
    override_group,
    override_key,
    predictor_folder,
    print_help_if_asked,
    run_app,
    setting_changes,
)
from iplanner_torch.cli._common import (
    task_overrides as _task_overrides,
)
from iplanner_torch.files import json_text, whole_file
from iplanner_torch.types import resolve_device

#: predictor variant of a planner (see eval.episode.PLANNER_KINDS) -> conf/predictor option
VARIANT_OPTION = {"no_ni": "iplanner_no_ni", "ni": "iplanner_ni"}


#: Values of ``run.train_data``: each scenario's task demonstrations, or the ``data`` group.
TRAIN_DATA = ("tasks", "data")


def option_node(group: str, option: str, cfg: DictConfig) -> DictConfig:
    """The ``conf/<group>/<option>.yaml`` node, with ``${seed}`` and ``${paths.*}`` resolved
    against ``cfg``."""
    from iplanner_torch.errors import ConfigError

    path = Path(CONF_DIR) / group / f"{option}.yaml"
    if not path.exists():
        raise ConfigError(f"no config option {group}={option} ({path})")
    paths = OmegaConf.to_container(cfg.paths, resolve=True) if "paths" in cfg else {}
    root = OmegaConf.create(
        {"seed": cfg_scalar(cfg, "seed", int), "paths": paths, "node": OmegaConf.load(path)}
    )
    return root.node


def scenario_data_node(cfg: DictConfig, scenario: Any) -> DictConfig:
    """The dataset a scenario's predictors learn from.

    ``run.train_data=tasks`` (default): task demonstrations of the scenario's arrangement and
    task order (``conf/data/tasks.yaml``), so the progress states and next-action statistics
    are those of the task (paper sec. 4.1); a blocking scenario (fig. speed_response) learns
    from the reaching set; ``run.train_data=data``: the ``data`` group.
    """
    source = str(cfg.run.train_data)
    if source not in TRAIN_DATA:
        from iplanner_torch.errors import ConfigError

        raise ConfigError(f"run.train_data must be one of {TRAIN_DATA}, got {source!r}")
    if source == "data":
        return cfg.data
    if str(getattr(scenario, "kind", "delivery")) == "blocking":
        # the blocking arm movement is a reach: learn from the reaching set
        return option_node("data", "reaching", cfg)
    node = option_node("data", "tasks", cfg)
    node.generator.order = str(scenario.task_order)
    node.generator.arrangement = str(scenario.arrangement)
    order = str(scenario.task_order).replace(" ", "")
    slug = order.replace("->", "_then_").replace("(", "any").replace(")", "").replace(",", "-")
    slug = re.sub(r"[^0-9a-zA-Z_-]+", "", slug) or "x"
    node.path = str(Path(cfg.paths.datasets) / f"tasks_{scenario.arrangement}_{slug}")
    return node


def predictor_checkpoint(folder: Path, variant: str) -> Path:
    """The checkpoint of predictor ``variant`` in ``folder`` (:func:`predictor_folder`)."""
    return folder / VARIANT_OPTION[variant] / "predictor.ckpt"


def ensure_predictors(
    cfg: DictConfig, variants: list[str], data_node: DictConfig
) -> dict[str, str]:
    """Checkpoint path per predictor variant; trains the missing ones when allowed.

    Checkpoints live in ``<paths.checkpoints>/<dataset folder name>/<predictor option>/``.
    Missing ones are trained under :func:`training_lock`, so that parallel jobs train them once.
    """
    if not variants:  # no predicting planner: run.train_trainer is not read
        return {}
    trainer_node = option_node("trainer", str(cfg.run.train_trainer), cfg)
    given = {override_key(o) for o in _task_overrides()}
    windows_given = overridden_fields("data.windows")
    paths: dict[str, str] = {}
    folder = predictor_folder(cfg, data_node)
    missing = [v for v in variants if not predictor_checkpoint(folder, v).exists()]
    trains = bool(missing) and cfg_scalar(cfg.run, "train_if_missing", bool)
    with training_lock(folder) if trains else contextlib.nullcontext():
        for variant in variants:
            paths[variant] = _ensure_predictor(
                cfg, variant, data_node, folder, trainer_node, given, windows_given
            )
    return paths


@contextlib.contextmanager
def training_lock(folder: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``folder/.training.lock`` (created) while the predictors of
    one dataset are checked and, when missing, trained: the parallel jobs of a sweep that all
    lack them then train them once (the first job) and use them (the others, once it is
    done), instead of generating the same dataset and training the same checkpoints at the
    same time. A file system without ``flock`` (or Windows) gets no lock."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".training.lock", "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"waiting for another run training the predictors in {folder} ...", flush=True)
            fcntl.flock(handle, fcntl.LOCK_EX)
        except OSError:  # a file system without locks: go on without one
            yield
            return
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _ensure_predictor(
    cfg: DictConfig,
    variant: str,
    data_node: DictConfig,
    folder: Path,
    trainer_node: DictConfig,
    given: set[str],
    windows_given: Any,
) -> str:
    """The checkpoint of one variant (see :func:`ensure_predictors`), trained when missing."""
    from iplanner_torch.cli.train import train_from_config
    from iplanner_torch.errors import CheckpointError

    option = VARIANT_OPTION[variant]
    ckpt = predictor_checkpoint(folder, variant)
    out_dir = ckpt.parent
    if ckpt.is_dir():
        raise CheckpointError(f"{ckpt}: is a folder, not a checkpoint file")
    if not ckpt.exists():
        if not cfg_scalar(cfg.run, "train_if_missing", bool):
            raise CheckpointError(
                f"{ckpt}: no trained predictor; train it on {data_node.path} with "
                f"`{train_command(cfg, data_node, option, out_dir)}`, or leave "
                "run.train_if_missing=true to have this run train it"
            )
        print(
            f"training predictor {option} on {data_node.path} "
            f"(trainer={cfg.run.train_trainer}) ...",
            flush=True,
        )
        t0 = time.perf_counter()
        train_from_config(
            cfg,
            option_node("predictor", option, cfg),
            out_dir,
            trainer_node=trainer_node,
            data_node=data_node,
        )
        print(f"  trained in {time.perf_counter() - t0:.0f} s -> {ckpt}", flush=True)
    else:
        stale = checkpoint_differences(ckpt, data_node, windows_given)
        stale += training_differences(
            ckpt,
            trainer_node,
            seed=cfg_scalar(cfg, "seed", int) if "seed" in given else None,
            budget="run.train_trainer" in given,
        )
        if stale:
            from iplanner_torch.errors import ConfigError

            raise ConfigError(
                f"{ckpt} was trained with other settings than the command line gives: "
                f"{'; '.join(stale)} (checkpoint -> now). Delete {out_dir} to train it "
                "anew with them, or set paths.checkpoints=<another folder>"
            )
    return str(ckpt)


def train_command(
    cfg: DictConfig,
    data_node: DictConfig,
    option: str,
    out_dir: Path,
    *,
    trainer: str | None = None,
    overwrite: bool = False,
) -> str:
    """The ``iplanner-train`` command that trains predictor ``option`` into ``out_dir`` as
    this run would (:func:`_ensure_predictor`): on the dataset of ``data_node`` (its
    ``conf/data`` option and path; for task demonstrations also the task order and
    arrangement that generate it when missing), with ``trainer`` (default
    ``run.train_trainer``); ``overwrite`` adds ``train.overwrite=true`` (the command replaces
    the predictor there)."""
    from iplanner_torch.cli._common import _group_choice, override_word

    if data_node is cfg.data:  # run.train_data=data: the run's own data group option
        data_option = _group_choice("data") or "reaching"  # (None outside a Hydra run)
    else:
        data_option = "tasks" if "order" in data_node.get("generator", {}) else "reaching"
    words = [override_word("data", data_option), override_word("data.path", data_node.path)]
    if data_option == "tasks" and data_node is not cfg.data:
        gen = data_node.generator
        words += [
            override_word("data.generator.order", str(gen.order)),
            override_word("data.generator.arrangement", str(gen.arrangement)),
        ]
    words += [
        override_word("predictor", option),
        override_word("trainer", str(cfg.run.train_trainer) if trainer is None else trainer),
        override_word("train.out_dir", out_dir),
        *(["train.overwrite=true"] if overwrite else []),
    ]
    return " ".join(["iplanner-train", *words])


def checkpoint_differences(ckpt: Path, data_node: DictConfig, keys: set[str]) -> list[str]:
    """Where a trained predictor's window settings differ from ``data_node.windows``.

    Only ``keys`` are compared (the ``data.windows`` fields the command line sets), so a
    predictor trained otherwise on purpose (``iplanner-train`` into the folder the experiment
    reads) is used as it is. A file that does not read gives no differences here: loading it
    reports why.

    Returns:
        ``"n_prev: 15 -> 5"`` lines (checkpoint -> now); empty when they agree.
    """
    from dataclasses import asdict

    import torch

    from iplanner_torch.data.windows import WindowCfg

    if not keys:
        return []
    try:
        saved = dict(torch.load(ckpt, map_location="cpu", weights_only=True)["window_cfg"])
    except Exception:  # noqa: BLE001 - HumanMotionPredictor.load says what is wrong
        return []
    now = asdict(instantiate(data_node.windows, WindowCfg, name="data.windows"))
    return setting_changes(saved, now, keys)


def training_differences(
    ckpt: Path, trainer_node: DictConfig, *, seed: int | None, budget: bool
) -> list[str]:
    """Where a trained predictor's recorded training differs from what the command line asks.

    Read from the ``training_inputs.json`` beside ``ckpt``; a checkpoint without that record,
    or with one that records no trainer, gives no differences (it is used as it is, like one
    trained on purpose with ``iplanner-train`` into the experiment's folder). So does one whose
    record does not read, with a warning. A record of another training run than the
    checkpoint's (one started in the folder since and interrupted: its
    :func:`~iplanner_torch.eval.prediction.inputs_digest` differs from the one the checkpoint
    keeps) is not read: ``seed`` is then compared with the checkpoint's own predictor seed,
    and the budget goes unchecked, with a warning.

    Args:
        ckpt: the predictor checkpoint.
        trainer_node: the ``conf/trainer`` node of ``run.train_trainer``.
        seed: ``seed`` when the command line gives it (compared with the trainer's seed and
            the split's), else None.
        budget: whether the command line gives ``run.train_trainer`` (its ``max_epochs`` and
            ``max_steps`` are then compared).

    Returns:
        ``"trainer max_steps: 40 -> None"`` lines (checkpoint -> now); empty when they agree.

    Warns:
        DataWarning: when the record is there but does not read.
    """
    import warnings
    from dataclasses import asdict

    import torch

    from iplanner_torch.errors import CheckpointError, DataWarning
    from iplanner_torch.eval.prediction import inputs_digest, read_training_inputs
    from iplanner_torch.prediction.training import TrainerCfg

    if seed is None and not budget:
        return []
    try:
        record = read_training_inputs(ckpt)
    except CheckpointError as err:
        given = [k for k, v in (("seed", seed is not None), ("run.train_trainer", budget)) if v]
        warnings.warn(
            f"{err}: {ckpt} is used as it is, unchecked against the command line's "
            f"{' and '.join(given)}",
            DataWarning,
            stacklevel=2,
        )
        return []
    if record is None or not isinstance(record.get("trainer_cfg"), dict):
        return []
    try:
        saved = torch.load(ckpt, map_location="cpu", weights_only=True)
        own = str(saved.get("inputs_digest") or "")
        own_seed = saved["cfg"].get("seed")
    except Exception:  # noqa: BLE001 - HumanMotionPredictor.load says what is wrong
        own, own_seed = "", None
    if own and own != inputs_digest(record):
        warnings.warn(
            f"the training_inputs.json beside {ckpt} records another training run than the "
            "checkpoint's (one started in its folder since, and not finished): the "
            "checkpoint's trainer budget is unchecked",
            DataWarning,
            stacklevel=2,
        )
        if seed is not None and own_seed is not None and own_seed != seed:
            return [f"predictor seed: {own_seed!r} -> {seed!r}"]
        return []
    trainer = dict(record["trainer_cfg"])
    now = asdict(instantiate(trainer_node, TrainerCfg, name="trainer"))  # its seed is ${seed}
    keys = {"max_epochs", "max_steps"} if budget else set()
    if seed is not None:
        keys.add("seed")
    out = setting_changes(trainer, now, keys, prefix="trainer ")
    split = record.get("split")
    if seed is not None and isinstance(split, dict) and split.get("seed", seed) != seed:
        out.append(f"split seed: {split['seed']!r} -> {seed!r}")
    return out


def unused_overrides(overrides: list[str], train_data: str) -> list[str]:
    """The command-line overrides that ``iplanner-experiment`` would not read.

    Missing predictors are trained with their own ``conf/predictor/<variant>.yaml`` and the
    ``run.train_trainer`` option, so the ``predictor`` and ``trainer`` groups, and ``train`` and
    ``evaluate`` (the other commands' settings), are not read; the ``data`` group is read only
    with ``run.train_data=data``.

    Args:
        overrides: Hydra task overrides (``key=value``, ``+key=value``, ``group=option``).
        train_data: ``run.train_data`` (the value the overrides set, where they set it).
    """
    unread = {"predictor", "trainer", "train", "evaluate"}
    if train_data != "data":
        unread.add("data")
    return [o for o in overrides if override_group(o) in unread]


#: Sweep aliases (conf/config.yaml) -> the episode settings they feed (conf/sim/default.yaml).
ALIAS_PATHS = {
    "tracker.noise": "sim.tracker_noise",
    "tracker.dropout": "sim.tracker_dropout",
    "human.speed": "sim.human.speed",
}
#: run.* keys passed to EpisodeCfg as they are, under the same name, when the run group has
#: them (else EpisodeCfg's defaults): the task choice and the forecast's task conditioning
RUN_EPISODE_KEYS = (
    "task_crossing_radius",
    "mask_by_order",
    "rest_when_nothing_available",
    "reaction_s",
    "spread_tolerance",
    "cv",
)
#: run.* keys -> the EpisodeCfg fields they feed.
RUN_EPISODE_PATHS = {
    "run.max_duration_s": "max_duration_s",
    "run.stall_fallback_s": "stall_fallback_s",
    "run.scene_hz": "scene_hz",
    **{f"run.{key}": key for key in RUN_EPISODE_KEYS},
}


def replaced_overrides(overrides: list[str], exp_node: DictConfig | None) -> list[str]:
    """Command-line overrides that a value of the run replaces, each with what to set instead.

    Always: ``planner.kind`` and ``planner.predictor_variant`` (each episode sets them from
    the planners list), ``sim.human.mode`` (the scenario's kind) and ``planner.optimizer.seed``
    (the episode's seed). With ``experiment=...``: ``run.planners``, ``run.seeds`` and
    ``run.write_mcap`` (the experiment's own lists), the ``scenario`` group and
    ``planner.confidence`` (the experiment's scenarios), ``human.speed`` / ``tracker.noise``
    when the experiment lists speeds / noises, and any ``sim.*``, ``planner.*`` or
    ``run.*`` episode setting (or its sweep alias) that ``experiment.episode`` sets.

    Returns:
        ``"run.seeds=[5] (set experiment.seeds)"`` lines; empty when none is replaced.
    """
    out = []
    for override in overrides:
        key = override_key(override)
        head = key.split(".", 1)[0]
        instead = None
        if key in ("planner.kind", "planner.predictor_variant"):
            instead = "choose planners with run.planners, experiment.planners or planner=<option>"
        elif key == "sim.human.mode":
            instead = "the scenario's kind sets it: scenario.kind=tasks|blocking"
        elif key == "planner.optimizer.seed":
            instead = "each episode's seed replaces it: set run.seeds or experiment.seeds"
        elif exp_node is None or head in ("experiment", "hydra") or "/" in key:
            pass
        elif key in ("run.planners", "run.seeds", "run.write_mcap"):
            instead = f"set experiment.{key[4:]}"
        elif head == "scenario":
            instead = "the experiment's scenarios set it: edit experiment.scenarios"
        elif key == "planner.confidence":
            instead = "each of experiment.scenarios has its confidence"
        else:
            path = ALIAS_PATHS.get(key) or RUN_EPISODE_PATHS.get(key)
            if path is None and key.startswith("run.cv."):  # a field of EpisodeCfg.cv
                path = key[len("run.") :]
            path = path or (key if head in ("sim", "planner") else None)
            if path == "sim.human.speed" and exp_node.get("speeds"):
                instead = "set experiment.speeds"
            elif path == "sim.tracker_noise" and exp_node.get("noises"):
                instead = "set experiment.noises"
            elif (
                path is not None
                and exp_node.get("episode") is not None
                and OmegaConf.select(exp_node.episode, path) is not None
            ):
                instead = f"set experiment.episode.{path}"
        if instead:
            out.append(f"{override} ({instead})")
    return out


def choose_planner(cfg: DictConfig, overrides: list[str]) -> None:
    """Narrow the run to the planner the ``planner`` group option names (``planner=itomp``),
    so that ``-m planner=itomp,iplanner_ni`` runs one planner per job.

    Raises:
        ConfigError: when the command line also lists the planners, differently.
    """
    from iplanner_torch.errors import ConfigError

    chosen = [
        o.split("=", 1)[1]
        for o in overrides
        if not o.startswith("~") and override_key(o) == "planner"
    ]
    if not chosen:
        return
    option = chosen[-1]
    exp_node = cfg.get("experiment")
    key = "experiment.planners" if exp_node is not None else "run.planners"
    given = [o for o in overrides if override_key(o) == key]
    node = exp_node if exp_node is not None else cfg.run
    if given and cfg_list(node, "planners", str) != [option]:
        raise ConfigError(
            f"planner={option} runs the {option} planner alone, but {given[-1]} lists "
            "others: choose with one of them"
        )
    node.planners = [option]


def _leaf_keys(node: Any, prefix: str = "") -> list[str]:
    """The dotted keys of the values under a nested mapping (``{"a": {"b": 1}}`` -> ``a.b``)."""
    if not isinstance(node, (dict, DictConfig)):
        return [prefix] if prefix else []
    out = []
    for key in node:
        path = f"{prefix}.{key}" if prefix else str(key)
        value = node[key]
        out.extend(_leaf_keys(value, path) if isinstance(value, (dict, DictConfig)) else [path])
    return out


def drop_per_kind_keys(planner: DictConfig, keys: list[str]) -> None:
    """Remove the settings at ``keys`` (dotted, under ``planner``: ``replanner.fresh_fraction``)
    from every ``planner.per_kind`` entry, so that a value set for the whole run (on the
    command line or in ``experiment.episode.planner``) serves every planner of it, as asked,
    instead of being replaced by a planner's own default."""
    per_kind = planner.get("per_kind")
    if not isinstance(per_kind, DictConfig):
        return
    for key in keys:
        if key == "per_kind" or key.startswith("per_kind."):
            continue
        parent, _, leaf = key.rpartition(".")
        for name in list(per_kind):
            entry = per_kind[name]
            node = OmegaConf.select(entry, parent) if parent else entry
            if isinstance(node, DictConfig) and leaf in node:
                with open_dict(node):
                    node.pop(leaf)


def merged_episode_node(cfg: DictConfig, overrides: list[str] | None = None) -> DictConfig:
    """The ``EpisodeCfg`` node of this run: the scenario, sim and planner groups and the
    ``run.*`` episode keys, with ``experiment.episode`` (when an experiment is chosen) merged
    over them, so that an experiment file names only what it changes (e.g. one cost weight
    of ``planner``).

    A ``planner.*`` setting of the command line (``overrides``, default: this run's) or of
    ``experiment.episode.planner`` serves every planner of the run: it replaces that setting
    in the ``planner.per_kind`` entries (:func:`drop_per_kind_keys`), which set the rest."""
    node = OmegaConf.create(
        {
            "_target_": "iplanner_torch.eval.episode.EpisodeCfg",
            "scenario": OmegaConf.to_container(cfg.scenario, resolve=True),
            "sim": OmegaConf.to_container(cfg.sim, resolve=True),
            "planner": OmegaConf.to_container(cfg.planner, resolve=True),
            "max_duration_s": cfg_scalar(cfg.run, "max_duration_s", float),
            "stall_fallback_s": cfg.run.stall_fallback_s,
            "scene_hz": cfg_scalar(cfg.run, "scene_hz", float),
            "progress_bar": cfg_scalar(cfg, "progress", bool),
            **{key: cfg.run[key] for key in RUN_EPISODE_KEYS if key in cfg.run},
        }
    )
    given = [
        override_key(o).split(".", 1)[1]
        for o in (_task_overrides() if overrides is None else overrides)
        if not o.startswith("~") and override_key(o).startswith("planner.")
    ]
    exp_node = cfg.get("experiment")
    if exp_node is not None and exp_node.get("episode") is not None:
        node = OmegaConf.merge(node, exp_node.episode)
        given += _leaf_keys(exp_node.episode.get("planner"))
    drop_per_kind_keys(node.planner, given)
    return node


def _check_scenario_name(name: str) -> None:
    """Refuse a ``scenario=<option>`` whose name its file does not set (a new file without a
    ``name`` of its own: it took ScenarioCfg's default, or that of the file it starts from),
    unless the command line sets ``scenario.name``: the name labels the table, results.csv
    and the logs, and the episodes of another scenario would be filed under it. A name the
    file sets itself (``name: my_label``) is the user's label, and taken."""
    import yaml

    from iplanner_torch.cli._common import _group_choice
    from iplanner_torch.errors import ConfigError

    choice = _group_choice("scenario")
    if choice is None or choice == name:
        return
    if any(override_key(o) == "scenario.name" for o in _task_overrides()):
        return
    path = Path(CONF_DIR) / "scenario" / f"{choice}.yaml"
    try:
        own = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):  # another search path's file: the rule as it stands
        own = None
    if isinstance(own, dict) and own.get("name") == name:
        return
    raise ConfigError(
        f"scenario={choice}: its scenario is named {name!r}, a name its file does not set "
        f"(ScenarioCfg's default, or that of the file it starts from), which labels the "
        f"results; add 'name: <label>' (e.g. 'name: {choice}') to "
        f"conf/scenario/{choice}.yaml, or set scenario.name=<label>"
    )


def build_experiment(cfg: DictConfig, predictor_paths: dict[str, str]) -> Any:
    """The :class:`~iplanner_torch.eval.experiment.ExperimentCfg` this run describes."""
    from dataclasses import replace

    from iplanner_torch.errors import ConfigError
    from iplanner_torch.eval.episode import EpisodeCfg
    from iplanner_torch.eval.experiment import ExperimentCfg
    from iplanner_torch.planning.replanner import PlannerCfg
    from iplanner_torch.robot.model import RobotCfg
    from iplanner_torch.sim.env import SimCfg
    from iplanner_torch.sim.tasks import ScenarioCfg

    robot = instantiate(cfg.robot, RobotCfg, name="robot")
    # each group on its own first, so that a bad value is named with its group (a new file
    # of the group without '_target_' is told what to add)
    scenario = instantiate(cfg.scenario, ScenarioCfg, name="scenario")
    _check_scenario_name(scenario.name)
    instantiate(cfg.sim, SimCfg, name="sim")
    instantiate(cfg.planner, PlannerCfg, name="planner")
    if not cfg_scalar(cfg.run, "max_duration_s", float) > 0:
        raise ConfigError(f"run.max_duration_s: expected > 0 [s], got {cfg.run.max_duration_s}")

    episode_node = merged_episode_node(cfg)
    overridden = cfg.get("experiment") is not None and cfg.experiment.get("episode") is not None
    episode = instantiate(
        episode_node, EpisodeCfg, name="experiment.episode" if overridden else "run"
    )
    # "auto" keeps the closed loop on the CPU: at the planner's sizes (8 to 64 trajectories)
    # a replanning cycle on CUDA is bound by kernel launches, and the episodes ran at half
    # the CPU's speed on an H200 (experiments/bench/README.md); device=cuda asks for CUDA
    device = "cpu" if str(cfg.device) == "auto" else str(resolve_device(str(cfg.device)))
    exp_node = cfg.get("experiment")
    if exp_node is None:
        scenario = replace(
            episode.scenario, confidence=cfg_scalar(cfg.planner, "confidence", float)
        )
        try:
            return ExperimentCfg(
                name="main",
                robot=robot,
                device=device,
                scenarios=[scenario],
                planners=cfg_list(cfg.run, "planners", str),
                seeds=cfg_list(cfg.run, "seeds", int),
                predictor_paths=predictor_paths,
                episode=replace(episode, scenario=scenario),
                write_mcap=cfg_scalar(cfg.run, "write_mcap", bool),
            )
        except ConfigError as exc:  # "seeds: ..." is run.seeds here
            text = str(exc)
            field = text.split(":", 1)[0]
            raise ConfigError(f"run.{text}" if field in ("planners", "seeds") else text) from exc
    node = OmegaConf.to_container(exp_node, resolve=True)
    assert isinstance(node, dict)
    node.pop("episode", None)
    named = node.pop("robot", None)
    if named is not None and not isinstance(named, str):  # [] looked for conf/robot/[].yaml
        raise ConfigError(f"experiment.robot: expected a robot option name or null, got {named!r}")
    if named is not None and str(named) != robot.name:
        # experiment.robot=<name> is the robot group option <name> (as robot=<name>)
        chosen = [o for o in _task_overrides() if override_key(o) == "robot"]
        if chosen:
            raise ConfigError(
                f"experiment.robot={named!r} contradicts {chosen[0]}: choose the robot once "
                "(robot=<name>)"
            )
        robot = instantiate(option_node("robot", str(named), cfg), RobotCfg, name="robot")
    node["device"] = device
    node["predictor_paths"] = predictor_paths
    exp = instantiate(OmegaConf.create(node), ExperimentCfg, name="experiment")
    return replace(exp, robot=robot, episode=episode)


def check_run(cfg: DictConfig) -> tuple[Any, list[str], bool]:
    """The checks of a run's settings before anything runs: the overrides it does not read or
    that another setting would replace, the planners, every group's values and
    ``run.timeline_plots``. A sweep makes them for every job before the first one starts
    (:meth:`~iplanner_torch.cli.callbacks.GatherSweepResults.on_multirun_start`).

    Args:
        cfg: the run's composed config (without its ``hydra`` node); narrowed to the planner
            a ``planner=<option>`` override names (:func:`choose_planner`).

    Returns:
        The :class:`~iplanner_torch.eval.experiment.ExperimentCfg` (without predictor
        paths), the predictor variants its planners need, and whether to draw timeline plots.

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    from iplanner_torch.errors import ConfigError
    from iplanner_torch.eval.episode import CHECKPOINT_VARIANTS, PLANNER_KINDS

    overrides = _task_overrides()
    unused = unused_overrides(overrides, str(cfg.run.train_data))
    if unused:
        raise ConfigError(
            f"iplanner-experiment does not read {' '.join(unused)}: it trains a missing "
            "predictor with conf/predictor/<variant>.yaml, the run.train_trainer option and, "
            f"with run.train_data={cfg.run.train_data}, "
            + (
                "the data group"
                if str(cfg.run.train_data) == "data"
                else "each scenario's task demonstrations (the data group only with "
                "run.train_data=data)"
            )
            + "; train with other settings first (iplanner-train ... train.out_dir="
            "<paths.checkpoints>/<dataset folder>/<variant>), see the README"
        )
    replaced = replaced_overrides(overrides, cfg.get("experiment"))
    if replaced:
        raise ConfigError(
            "another setting of this run would replace "
            f"{'this override' if len(replaced) == 1 else 'these overrides'}: "
            f"{'; '.join(replaced)}"
        )
    choose_planner(cfg, overrides)
    exp_node = cfg.get("experiment")
    planners = (
        cfg_list(exp_node, "planners", str)
        if exp_node is not None
        else cfg_list(cfg.run, "planners", str)
    )
    unknown = [p for p in planners if p not in PLANNER_KINDS]
    if unknown:
        key = "experiment.planners" if exp_node is not None else "run.planners"
        raise ConfigError(
            f"{key}: unknown planners {unknown}; expected some of {sorted(PLANNER_KINDS)}"
        )
    variants = sorted({v for p in planners if (v := PLANNER_KINDS[p]) in CHECKPOINT_VARIANTS})
    experiment = build_experiment(cfg, {})
    if variants and str(cfg.run.train_data) == "data":
        check_train_data(cfg.data, experiment.episode.sim.tracker_fps)
    timeline_plots = cfg_scalar(cfg.run, "timeline_plots", bool)  # checked before any episode
    run_jobs(cfg)
    return experiment, variants, timeline_plots


def check_train_data(data_cfg: DictConfig, tracker_fps: float) -> None:
    """With ``run.train_data=data``, refuse a ``data`` group whose predictor the closed loop
    could not use, before anything is trained: one of a subset of the joints
    (``data.windows.joints``), one of the LEGO recording's arm joints, or one at a stated
    frame rate (``data.fps``) other than the tracker's. The trained predictor is checked
    again before the episodes (its rate and joints, whatever the data stated).

    Raises:
        ConfigError: naming the setting.
    """
    from iplanner_torch.cli._common import data_format, data_fps
    from iplanner_torch.data.skeleton import JOINT_NAMES
    from iplanner_torch.errors import ConfigError

    if data_format(data_cfg) == "lego_assembly":
        raise ConfigError(
            "run.train_data=data with a LEGO assembly recording (data.format=lego_assembly): "
            "its 6 arm joints are not the simulated person's "
            f"{len(JOINT_NAMES)} ({', '.join(JOINT_NAMES)}); train on the reaching or task "
            "demonstrations (run.train_data=tasks, the default)"
        )
    windows = data_cfg.get("windows", None)
    joints = windows.get("joints", None) if OmegaConf.is_config(windows) else None
    if joints is not None:
        joints = OmegaConf.to_container(joints) if OmegaConf.is_config(joints) else joints
        if not isinstance(joints, list) or [str(j) for j in joints] != list(JOINT_NAMES):
            raise ConfigError(
                f"data.windows.joints={joints}: the closed loop forecasts every joint of the "
                f"simulated person ({', '.join(JOINT_NAMES)}), so its predictor learns from "
                "all of them; leave data.windows.joints unset (null)"
            )
    fps = data_fps(data_cfg)
    if fps is not None and not math.isclose(fps, float(tracker_fps), rel_tol=1e-6):
        raise ConfigError(
            f"data.fps={fps:g}, but the tracker samples the person at sim.tracker_fps="
            f"{float(tracker_fps):g} Hz and the predictor must be trained at that rate"
        )


def run_jobs(cfg: DictConfig) -> int:
    """``run.jobs``: how many episodes of the run go at once, each in a process of its own.

    Raises:
        ConfigError: unless it is an integer >= 1.
    """
    from iplanner_torch.errors import ConfigError

    jobs = cfg_scalar(cfg.run, "jobs", int)
    if jobs < 1:
        raise ConfigError(f"run.jobs: expected an integer >= 1, got {jobs}")
    return jobs


def check_job(cfg: DictConfig) -> dict[str, tuple[Path, str]]:
    """What a sweep checks of each job before the first starts: the checks
    :func:`~iplanner_torch.cli._common.friendly_errors` makes of every command's config, then
    :func:`check_run`, and in a sweep resumed with ``run.resume=true`` the settings the job's
    folder began with (:func:`check_resumed_job`).

    Returns:
        For each folder of predictors the job reads, and trains when they are missing
        (``<paths.checkpoints>/<dataset folder>``), the folder with the training settings it
        asks for (``seed=0 run.train_trainer=fast``, and with ``run.train_data=data`` the
        ``data.windows`` fields its command line sets): jobs may share a folder with the same
        settings (the first trains, the others wait and use it), not with others (a sweep
        refuses them). Empty when no planner of the job predicts.

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    check_added_keys(cfg)
    check_root_keys(cfg)
    experiment, variants, _ = check_run(cfg)
    # each scenario's dataset (none to read without a predicting planner)
    scenarios = experiment.scenarios if variants else []
    nodes = {s.name: scenario_data_node(cfg, s) for s in scenarios}
    check_resumed_job(cfg, nodes, variants)
    if not variants:
        return {}
    folders = {name: predictor_folder(cfg, node) for name, node in nodes.items()}
    settings = f"seed={cfg_scalar(cfg, 'seed', int)} run.train_trainer={cfg.run.train_trainer}"
    if str(cfg.run.train_data) == "data":  # the window settings a checkpoint is compared on
        for field in sorted(overridden_fields("data.windows")):
            value = cfg.data.windows.get(field)
            value = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
            settings += f" data.windows.{field}={value}"
    return {f"predictors of {name}": (folder, settings) for name, folder in folders.items()}


#: the file in a run folder that records what the run began with, for ``run.resume``
RUN_INPUTS = "run_inputs.json"
#: settings a resumed run may give otherwise: none of them changes an episode
RESUME_FREE_KEYS = ("run.resume", "progress", "run.timeline_plots", "run.jobs")
#: the grid's lists, which a resumed run may extend: every episode the run finished must be
#: in the new grid (checked before any episode runs), and each episode is independent of the
#: others
RESUME_GRID_KEYS = (
    "run.seeds",
    "run.planners",
    "experiment.seeds",
    "experiment.planners",
    "experiment.speeds",
    "experiment.noises",
)


#: the .hydra/ record of the run a ``run.resume=true`` command names, read before Hydra
#: writes its own there (:func:`_refuse_used_run_dir`): put back when the resume is refused
_EARLIER_RECORD: dict[Path, bytes] = {}


def _put_back_record(out_dir: Path) -> None:
    """Restore the earlier run's ``.hydra/`` files that a refused resume's Hydra replaced."""
    for path, data in _EARLIER_RECORD.items():
        if path.parent.parent == out_dir.absolute():
            with contextlib.suppress(OSError):
                path.write_bytes(data)


def _flat_settings(node: Any, prefix: str = "") -> dict[str, Any]:
    """Nested settings as ``{"a.b": value}``: a list of scalars as it is, a list that holds
    mappings or lists by index (``{"a.scenarios[0].name": value}``)."""
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for key, value in node.items():
            out.update(_flat_settings(value, f"{prefix}{key}."))
        return out
    if isinstance(node, list) and any(isinstance(v, dict | list) for v in node):
        out = {f"{prefix[:-1]}[]": len(node)}
        for i, value in enumerate(node):
            out.update(_flat_settings(value, f"{prefix[:-1]}[{i}]."))
        return out
    return {prefix[:-1]: node}


def _code_commit() -> str | None:
    """The git commit of this package's source, or None outside a git checkout."""
    import subprocess

    try:
        res = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return res.stdout.strip() or None if res.returncode == 0 else None


def run_settings(cfg: DictConfig) -> dict[str, Any]:
    """A run's settings as :data:`RUN_INPUTS` records them: the composed config, flattened
    and resolved, without :data:`RESUME_FREE_KEYS`."""
    try:
        tree = OmegaConf.to_container(cfg, resolve=True)
    except Exception:  # noqa: BLE001 - a resolver only Hydra's app provides: as written
        tree = OmegaConf.to_container(cfg, resolve=False)
    return {k: v for k, v in _flat_settings(tree).items() if k not in RESUME_FREE_KEYS}


def run_inputs(cfg: DictConfig) -> dict[str, Any]:
    """What a run begins with: its settings (:func:`run_settings`) and the code (package
    version and git commit). Saved in the run folder as :data:`RUN_INPUTS`;
    ``run.resume=true`` compares them."""
    from iplanner_torch import __version__

    return {
        "settings": run_settings(cfg),
        "code": {"version": __version__, "commit": _code_commit()},
        "predictors": {},
    }


def _write_json(path: Path, value: Any) -> None:
    """``value`` as JSON at ``path``, whole or not at all."""
    with whole_file(path) as tmp:
        tmp.write_text(json.dumps(value, indent=1, sort_keys=True, default=str))


def _read_run_inputs(out_dir: Path) -> dict[str, Any]:
    from iplanner_torch.errors import ConfigError

    path = out_dir / RUN_INPUTS
    if not path.is_file():
        raise ConfigError(
            f"run.resume=true: {out_dir} holds no run to resume (no {RUN_INPUTS}); name the "
            "folder of the run to continue with hydra.run.dir=<folder> (hydra.sweep.dir for -m)"
        )
    try:
        try:
            inputs = json.loads(path.read_text(encoding="utf-8"))
        except RecursionError:  # "[" * 100000: the JSON decoder recursed too deep
            raise ValueError("JSON nested too deep") from None
        if not isinstance(inputs, dict) or not isinstance(inputs.get("settings"), dict):
            raise ValueError("no settings")
    except (ValueError, OSError) as exc:
        raise ConfigError(
            f"run.resume=true: {path} cannot be read ({exc}), so the run cannot be resumed; "
            "start a new run (another hydra.run.dir)"
        ) from exc
    inputs.setdefault("predictors", {})
    return inputs


def _as_json(value: Any) -> str:
    return json.dumps(value, default=str, sort_keys=True)


def _shown(value: Any) -> str:
    text = _as_json(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _refuse_other_settings(out_dir: Path, before: dict[str, Any], after: dict[str, Any]) -> None:
    """Raise a ConfigError naming the settings ``after`` has otherwise than ``before`` (the
    settings the run in ``out_dir`` began with), if any, but for a grid list
    (:data:`RESUME_GRID_KEYS`) that ``after`` extends (it holds every value of ``before``'s)."""
    from iplanner_torch.errors import ConfigError

    def extends(key: str) -> bool:
        old, new = before.get(key), after.get(key)
        return (
            key in RESUME_GRID_KEYS
            and isinstance(old, list)
            and isinstance(new, list)
            and len(old) > 0  # an empty list of speeds or noises: the episode's own one
            and all(_as_json(v) in {_as_json(w) for w in new} for v in old)
        )

    changed = [
        f"{k}: {_shown(before.get(k, '(unset)'))} -> {_shown(after.get(k, '(unset)'))}"
        for k in sorted(set(before) | set(after))
        if _as_json(before.get(k)) != _as_json(after.get(k)) and not extends(k)
    ]
    if changed:
        more = f" and {len(changed) - 4} more" if len(changed) > 4 else ""
        raise ConfigError(
            f"run.resume=true: the run in {out_dir} began with other settings "
            f"({'; '.join(changed[:4])}{more}); resume it with its own settings, or start a "
            "new run (another hydra.run.dir)"
        )


def check_resumed_job(
    cfg: DictConfig, data_nodes: dict[str, DictConfig], variants: list[str]
) -> None:
    """For a job of a sweep resumed with ``run.resume=true``, checked before the sweep's first
    job runs (before Hydra writes the job's record of this command in its folder's
    ``.hydra/``): refuse settings that differ from the ones the job's folder began with, and a
    predictor checkpoint of ``variants`` in each scenario's predictor folder (``data_nodes``,
    scenario name -> its dataset's node, :func:`scenario_data_node`;
    :func:`predictor_folder`) that differs from the one the job's episodes used
    (:func:`record_predictors`). A checkpoint the job used that is missing now is trained
    again here (:func:`ensure_predictors`) when the launcher runs the jobs on this machine
    (:func:`_jobs_run_here`), so that one that comes out otherwise is refused before any job
    runs; the same training gives the same file. With a cluster's launcher the job trains it
    on its node and compares it then (the training stays off the node that submits). A job
    folder without a run is not checked: the job starts afresh.

    Raises:
        ConfigError: as :func:`begin_run` and :func:`record_predictors`, and as
            :func:`ensure_predictors` for a missing checkpoint that may not be trained
            (``run.train_if_missing=false``).
    """
    from hydra.types import RunMode

    if not cfg_scalar(cfg.run, "resume", bool):
        return
    try:
        hc = HydraConfig.get()
        if hc.mode != RunMode.MULTIRUN:
            return
        folder = Path(str(hc.sweep.dir)) / str(hc.sweep.subdir)
    except Exception:  # noqa: BLE001 - no job folder to name: the job checks itself
        return
    if not (folder / RUN_INPUTS).exists():
        return
    earlier = _read_run_inputs(folder)
    _refuse_other_settings(folder, earlier["settings"], run_settings(cfg))
    for name, node in data_nodes.items():
        recorded = earlier["predictors"].get(name)
        if not recorded:
            continue
        folder = predictor_folder(cfg, node)
        paths = {v: str(predictor_checkpoint(folder, v)) for v in variants}
        missing = any(v in recorded and not Path(p).is_file() for v, p in paths.items())
        if missing and _jobs_run_here(hc):
            paths = ensure_predictors(cfg, variants, node)  # deleted since: trained again
        _refuse_changed_predictor(name, recorded, _digests(paths), paths)


def _jobs_run_here(hc: Any) -> bool:
    """Whether the sweep's launcher (``hc.launcher``, of the Hydra config) runs its jobs on
    this machine: Hydra's basic launcher, joblib's and Submitit's local one; not a cluster's
    (Submitit's SLURM launcher) nor one this project does not know."""
    from iplanner_torch.cli.callbacks import LOCAL_PARALLEL_LAUNCHERS

    target = str((hc.launcher or {}).get("_target_", ""))
    return target.endswith(("BasicLauncher", *LOCAL_PARALLEL_LAUNCHERS))


def begin_run(cfg: DictConfig, out_dir: Path, *, sweep_job: bool = False) -> bool:
    """Record a new run's inputs in its folder, or check a resumed one's against them.

    Without ``run.resume``, a folder that holds an earlier run's results is refused, and
    :data:`RUN_INPUTS` is written. With it, the folder must hold a run begun with the same
    settings (all but :data:`RESUME_FREE_KEYS`, and the grid's lists may grow,
    :data:`RESUME_GRID_KEYS`: :func:`extend_run`); a different code version is warned of. A job
    of a resumed sweep (``sweep_job``) whose folder holds no run (the sweep stopped before it
    began) starts as a new run. A refused resume puts back the earlier run's ``.hydra/``
    record, which Hydra replaced with this command's (:data:`_EARLIER_RECORD`).

    Returns:
        Whether the run resumes an earlier one.

    Raises:
        ConfigError: a used folder without ``run.resume``; with it, a folder without a run
            (but for a sweep's job), or one begun with other settings (the first differing
            keys named).

    Warns:
        ConfigWarning: when resuming with another package version or git commit.
    """
    from iplanner_torch.errors import ConfigError

    try:
        return _begin_run(cfg, out_dir, sweep_job)
    except ConfigError:
        _put_back_record(out_dir)
        raise


def _begin_run(cfg: DictConfig, out_dir: Path, sweep_job: bool) -> bool:
    """:func:`begin_run`, without putting the record back."""
    import warnings

    from iplanner_torch.errors import ConfigError, ConfigWarning

    now = run_inputs(cfg)
    resume = cfg_scalar(cfg.run, "resume", bool)
    if resume and sweep_job and not (out_dir / RUN_INPUTS).exists():
        resume = _used_run_dir(out_dir) is not None  # results but no record: refused below
    if not resume:
        message = _used_run_dir(out_dir)
        if message:
            raise ConfigError(message)
        _write_json(out_dir / RUN_INPUTS, now)
        return False
    earlier = _read_run_inputs(out_dir)
    _refuse_other_settings(out_dir, earlier["settings"], now["settings"])
    code_before, code_now = earlier.get("code") or {}, now["code"]
    if code_before != code_now:
        warnings.warn(
            f"run.resume=true: the run in {out_dir} began with other code (version "
            f"{code_before.get('version')}, commit {code_before.get('commit')}; now "
            f"{code_now['version']}, {code_now['commit']}): its kept and new episodes may "
            "differ for that reason alone",
            ConfigWarning,
            stacklevel=3,
        )
    return True


def scenario_dir(out_dir: Path, experiment: Any, scenario: Any) -> Path:
    """Where a run keeps one scenario's ``results.csv``: the run folder itself, or a folder
    per scenario when the experiment has several (its logs go to ``out_dir/episodes``)."""
    return out_dir if len(experiment.scenarios) == 1 else out_dir / scenario.name


def extend_run(cfg: DictConfig, out_dir: Path, experiment: Any) -> dict[str, int]:
    """For a resumed run: check that every episode the run finished is in the grid of
    ``experiment`` (the grid may have grown, :data:`RESUME_GRID_KEYS`), then record the
    settings it goes on with in :data:`RUN_INPUTS`, before any episode runs.

    Returns:
        Per scenario name, how many finished episodes the run keeps.

    Raises:
        ConfigError: naming episodes of the run that the grid leaves out
            (:func:`~iplanner_torch.eval.experiment.kept_episodes`).
        DataError: a ``results.csv`` that cannot be read.
    """
    from dataclasses import replace

    from iplanner_torch.errors import IPlannerError
    from iplanner_torch.eval.experiment import kept_episodes

    episodes = out_dir / "episodes"
    kept = {}
    try:
        for scenario in experiment.scenarios:
            one = replace(experiment, scenarios=[scenario])
            sub = scenario_dir(out_dir, experiment, scenario)
            kept[scenario.name] = len(kept_episodes(one, sub, episodes))
    except IPlannerError:  # refused, or a results.csv that does not read
        _put_back_record(out_dir)
        raise
    inputs = _read_run_inputs(out_dir)
    settings = run_settings(cfg)
    if inputs["settings"] != settings:  # a grid extended: the settings the run has now
        _write_json(out_dir / RUN_INPUTS, {**inputs, "settings": settings})
    return kept


def _checkpoint_bytes(paths: dict[str, str]) -> dict[str, bytes]:
    """The contents of each checkpoint file of ``paths`` (variant -> path) that exists, read
    once for its digest and its settings."""
    return {
        variant: Path(path).read_bytes()
        for variant, path in sorted(paths.items())
        if Path(path).is_file()
    }


def _digests(paths: dict[str, str], data: dict[str, bytes] | None = None) -> dict[str, str]:
    """SHA-256 of each checkpoint file of ``paths`` (variant -> path) that exists; ``data``:
    their contents when already read (:func:`_checkpoint_bytes`)."""
    import hashlib

    data = _checkpoint_bytes(paths) if data is None else data
    return {variant: hashlib.sha256(raw).hexdigest() for variant, raw in data.items()}


def _refuse_changed_predictor(
    scenario: str, recorded: dict[str, str] | None, digests: dict[str, str], paths: dict[str, str]
) -> None:
    """Raise a ConfigError naming the first checkpoint whose digest differs from the one
    ``recorded`` for it (a variant not recorded, or not present now, is not compared)."""
    from iplanner_torch.errors import ConfigError

    changed = [v for v in digests if (recorded or {}).get(v) not in (None, digests[v])]
    if changed:
        raise ConfigError(
            f"run.resume=true: the predictor {paths[changed[0]]} of scenario {scenario!r} is "
            "not the one the run began with (trained again since?); its kept episodes used "
            "the other, so start a new run (another hydra.run.dir)"
        )


def _checkpoint_settings(paths: dict[str, str], data: dict[str, bytes]) -> dict[str, Any]:
    """Variant -> ``{"path", "predictor"}``: each checkpoint's file and the predictor settings
    it was trained with (its ``cfg``, from ``data``, the files' contents), which can differ
    from the ``predictor`` config group that :data:`RUN_INPUTS` records with the run's
    settings (a variant trained on purpose into the folder the run reads). A file that is
    missing or does not read records its path alone."""
    import io

    import torch

    out: dict[str, Any] = {}
    for variant, path in sorted(paths.items()):
        entry: dict[str, Any] = {"path": str(path)}
        try:
            raw = io.BytesIO(data[variant])
            cfg = torch.load(raw, map_location="cpu", weights_only=True).get("cfg")
        except Exception:  # noqa: BLE001 - loading the predictor says what is wrong
            cfg = None
        if isinstance(cfg, dict):
            entry["predictor"] = cfg
        out[variant] = entry
    return out


def record_predictors(out_dir: Path, scenario: str, paths: dict[str, str]) -> None:
    """Record the checkpoints a scenario's episodes use (SHA-256 of each file, under
    ``predictors``; their paths and the settings they were trained with, under
    ``predictor_checkpoints``) in the run's :data:`RUN_INPUTS`; refuse checkpoints that
    differ from the ones recorded when the run began that scenario (trained again since: the
    kept episodes used the others).

    Raises:
        ConfigError: naming the checkpoint that changed.
    """
    from iplanner_torch.errors import ConfigError

    inputs = _read_run_inputs(out_dir)
    data = _checkpoint_bytes(paths)
    digests = _digests(paths, data)
    recorded = inputs["predictors"].get(scenario)
    try:
        _refuse_changed_predictor(scenario, recorded, digests, paths)
    except ConfigError:
        _put_back_record(out_dir)
        raise
    inputs["predictors"][scenario] = {**(recorded or {}), **digests}
    checkpoints = inputs.setdefault("predictor_checkpoints", {})
    checkpoints[scenario] = {**checkpoints.get(scenario, {}), **_checkpoint_settings(paths, data)}
    _write_json(out_dir / RUN_INPUTS, inputs)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
@friendly_errors
def _app(cfg: DictConfig) -> None:
    import warnings
    from dataclasses import replace

    import pandas as pd
    from hydra.types import RunMode
    from tqdm.auto import tqdm

    from iplanner_torch.eval.experiment import (
        episode_pool,
        finish_experiments,
        start_experiment,
        stop_pool,
    )
    from iplanner_torch.eval.report import (
        INTERRUPTED_DIR,
        comparison_key,
        comparison_table,  # the table iplanner-evaluate evaluate.mode=episode prints too
        gather_results,
        overrun_note,
        print_table,
        report_groups,
        write_sweep_report,
    )
    from iplanner_torch.planning.replanner import PlanningOverrunWarning

    # overruns are counted per episode (plan/overruns in results.csv); one line each would
    # drown the console
    warnings.simplefilter("ignore", PlanningOverrunWarning)
    t0 = time.perf_counter()
    hc = HydraConfig.get()
    out_dir = Path(hc.runtime.output_dir)
    progress = cfg_scalar(cfg, "progress", bool)
    resume = begin_run(cfg, out_dir, sweep_job=hc.mode == RunMode.MULTIRUN)
    (out_dir / "config_resolved.yaml").write_text(dump_config_safe(cfg))
    experiment, variants, timeline_plots = check_run(cfg)
    kept = extend_run(cfg, out_dir, experiment) if resume else {}
    n = len(experiment.scenarios) * len(experiment.planners) * len(experiment.seeds)
    n *= max(1, len(experiment.speeds)) * max(1, len(experiment.noises))
    print(f"experiment {experiment.name!r}: {n} episode(s)", flush=True)
    episodes = out_dir / "episodes"
    # every scenario's predictors before any episode: one trained while the workers run
    # episodes would share the cores with them and slow their wall-clock columns
    predictors = {}
    for scenario in experiment.scenarios:
        paths = ensure_predictors(cfg, variants, scenario_data_node(cfg, scenario))
        record_predictors(out_dir, scenario.name, paths)
        predictors[scenario.name] = paths
    # the whole run's episodes, with the time left (each episode has its own bar beneath)
    bar = tqdm(total=n, desc="episodes", unit="episode", disable=n < 2 or not progress)
    # the episodes left to run, each in a worker process of its own when run.jobs > 1
    jobs = min(run_jobs(cfg), n - sum(kept.values()))
    pool = episode_pool(jobs) if jobs > 1 else None
    if pool is not None:
        bar.write(f"{jobs} episodes at once, each in a process of its own (run.jobs)")
    runs = []
    try:
        for scenario in experiment.scenarios:
            paths = predictors[scenario.name]
            one = replace(experiment, scenarios=[scenario], predictor_paths=paths)
            sub = scenario_dir(out_dir, experiment, scenario)
            if resume:
                bar.write(
                    f"resuming: {kept[scenario.name]} finished episode(s) of scenario "
                    f"{scenario.name} kept"
                )
            # above the bar, which redraws; the workers take the episodes of every scenario
            # from one queue (none waits for a scenario's last episode)
            where = "running" if pool is None else "queued for the workers:"
            bar.write(f"{where} scenario {scenario.name} ...")
            sys.stdout.flush()
            runs.append(
                start_experiment(
                    one,
                    sub,
                    episodes_dir=episodes,
                    resume=resume,
                    on_done=bar.update,
                    executor=pool,
                )
            )
        frames = finish_experiments(runs)
    except BaseException:  # an episode failed, or an interrupt: nothing more starts
        if pool is not None:
            stop_pool(pool)
        raise
    bar.close()
    set_aside = sorted((out_dir / INTERRUPTED_DIR).glob("*.mcap"))
    if resume and set_aside:
        where = out_dir / INTERRUPTED_DIR
        print(f"{len(set_aside)} log(s) of unfinished episodes kept in {where}")
    df = pd.concat(frames, ignore_index=True)
    df = gather_results(df.to_dict("records"))
    # noise is plotted as a line over its values; swept speeds are categories the bar charts
    # already show
    sweep = "noise" if len(experiment.noises) > 1 else None
    written = write_sweep_report(df, out_dir, group_by=report_groups(df), sweep=sweep)
    table = comparison_table(df)
    (out_dir / "comparison.json").write_text(json_text(table.to_dict("records"), indent=2) + "\n")
    print()
    print_table(table)
    print()
    print(comparison_key(table))
    print()
    note = overrun_note(df)
    if note:
        print(note)
        print()
    mcaps = sorted((out_dir / "episodes").glob("*.mcap"))
    # every log, also in a resumed run: the figures share their axes (write_timelines)
    timelines = write_timelines(mcaps, progress, pool) if timeline_plots else []
    if pool is not None:
        pool.shutdown()
    print(f"results: {out_dir / 'results.md'} and {out_dir / 'results.csv'}")
    pngs = [p for p in written if str(p).endswith(".png")]
    print(f"plots:   {', '.join(str(p) for p in pngs) if pngs else '(none)'}")
    if mcaps:
        print(f"logs:    {len(mcaps)} MCAP episode log(s) in {out_dir / 'episodes'}")
        print(
            "         read one with iplanner_torch.recording.read_episode, or open it in Foxglove"
        )
    elif not experiment.write_mcap:
        key = "run" if cfg.get("experiment") is None else "experiment"
        print(f"logs:    none ({key}.write_mcap=false)")
    else:
        print(f"logs:    none in {out_dir / 'episodes'}")
    if timelines:
        print(
            f"         and {len(timelines)} timeline plot(s) beside them "
            "(<episode>.png: distance, collision bound, action probabilities, waits)"
        )
    print(f"done in {time.perf_counter() - t0:.0f} s")


def write_timelines(
    logs: list[Path], progress: bool = True, executor: Executor | None = None
) -> list[Path]:
    """Draw the timeline of each episode log beside it (``<log stem>.png``), the figures of a
    scenario with the same time, distance and arm-speed axes
    (:func:`~iplanner_torch.eval.timeline.shared_axes_by_scenario`), so that its planners
    side by side compare by eye.

    A figure already there (a resumed run's) is kept when its stamp
    (:class:`~iplanner_torch.eval.timeline.TimelineStamp`) says it was drawn from this very
    log (name, size and modification time) on the axes the scenario has now; its log is then
    not read either, the stamp holding the extremes the axes need. Every other figure is
    drawn. A log that cannot be drawn (cut short before its first messages, say) is named in
    a warning and left out; the others are drawn.

    Args:
        logs: the MCAP episode logs.
        progress: show a progress bar (for two logs or more).
        executor: reads the logs and draws the plots in its workers (the run's
            :func:`~iplanner_torch.eval.experiment.episode_pool`); None: here.

    Returns:
        The PNG paths beside the logs that have one now (drawn or kept), in the order of
        ``logs``.
    """
    import warnings

    from tqdm.auto import tqdm

    from iplanner_torch.errors import DataError, DataWarning
    from iplanner_torch.eval.timeline import (
        axes_by_scenario,
        episode_timeline,
        log_fingerprint,
        plot_episode_timeline,
        read_timeline_stamp,
        timeline_extremes,
        timeline_path,
    )

    bar = tqdm(total=2 * len(logs), desc="timeline plots", disable=not progress or len(logs) < 2)

    def collect(jobs: list | None, fn, *args) -> list:
        """Each job's result (a DataError in its place), in order; done here without jobs."""
        out = []
        for i in range(len(args[0])):
            try:
                out.append(fn(*(a[i] for a in args)) if jobs is None else jobs[i].result())
            except DataError as exc:
                out.append(exc)
            bar.update()
        return out

    # 1. each figure's stamp: one drawn from this very log gives its extremes unread
    pngs = [timeline_path(log) for log in logs]
    stamps = []
    for log, png in zip(logs, pngs):
        stamp = read_timeline_stamp(png)
        try:
            same = stamp is not None and stamp.source == log_fingerprint(log)
        except OSError:
            same = False
        stamps.append(stamp if same else None)
    # 2. the other logs' series (in the workers: reading a log is most of the work)
    unread = [log for log, st in zip(logs, stamps) if st is None]
    bar.update(len(logs) - len(unread))
    jobs = None if executor is None else [executor.submit(episode_timeline, p) for p in unread]
    read = iter(collect(jobs, episode_timeline, unread))
    items = [next(read) if st is None else st for st in stamps]  # Timeline, stamp or error
    # 3. the figures, on the axes of their scenario's episodes; kept where those did not move
    ok = [i for i, it in enumerate(items) if not isinstance(it, DataError)]
    extremes = [
        stamps[i].extremes if stamps[i] is not None else timeline_extremes(items[i]) for i in ok
    ]
    axes = dict(zip(ok, axes_by_scenario(extremes)))
    draw = [i for i in ok if stamps[i] is None or stamps[i].axes != axes[i]]
    bar.update(len(logs) - len(draw))
    # a log read above is drawn from its timeline; a kept one whose axes moved is read again
    # (plot_episode_timeline takes its path), in the workers too
    what = [items[i] if stamps[i] is None else logs[i] for i in draw]
    args = ([pngs[i] for i in draw], [axes[i] for i in draw], [logs[i] for i in draw])
    plots = (
        None
        if executor is None
        else [
            executor.submit(plot_episode_timeline, ep, png, ax, source=src)
            for ep, png, ax, src in zip(what, *args)
        ]
    )

    def plot(ep, png, ax, src):
        return plot_episode_timeline(ep, png, ax, source=src)

    results = dict(zip(draw, collect(plots, plot, what, *args)))
    bar.close()
    failed = [f"{logs[i].name} ({it})" for i, it in enumerate(items) if isinstance(it, DataError)]
    failed += [f"{logs[i].name} ({r})" for i, r in results.items() if isinstance(r, DataError)]
    written = [pngs[i] for i in ok if not isinstance(results.get(i), DataError)]
    if failed:
        warnings.warn(
            f"no timeline plot for {len(failed)} log(s): {'; '.join(failed)}",
            DataWarning,
            stacklevel=2,
        )
    return written


def experiment_config(*overrides: str) -> Any:
    """The :class:`~iplanner_torch.eval.experiment.ExperimentCfg` that ``iplanner-experiment
    <overrides>`` runs, for Python: the shipped planner, sim and scenario settings of
    ``conf/`` (the dataclasses' own defaults are the paper's and differ: e.g.
    ``OptimizerCfg()`` runs 40 and 10 iterations, ``conf/planner`` 25 and 16, with
    ``safe_hold`` and ``keep_start``), checked as the command checks them.

    Example::

        from iplanner_torch.cli import experiment_config
        from iplanner_torch.eval.episode import run_episode
        from iplanner_torch.robot.model import RobotModel

        exp = experiment_config("robot=fetch", "scenario=arrangement_2x2")
        res = run_episode(exp.episode, robot=RobotModel.from_cfg(exp.robot),
                          predictor=mine, planner_kind="iplanner_ni", writer_path=None,
                          seed=0)

    Args:
        overrides: command-line overrides, as typed (``"planner.optimizer.lr=0.001"``,
            ``"experiment=speed_response"``, ``"run.seeds=[0,1]"``).

    Returns:
        The run's grid (robot, scenarios, planners, seeds, speeds, noises) and its
        ``episode`` settings; ``predictor_paths`` is empty (the command fills it with the
        checkpoints it finds or trains; :func:`~iplanner_torch.eval.experiment.run_experiment`
        also takes predictor objects).

    Raises:
        ConfigError: for an override the command would refuse (an unknown key or option, a
            bad value), named as the command names it, or when called inside a Hydra app.
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from iplanner_torch.cli._common import check_composed_keys, composition_error_text
    from iplanner_torch.errors import ConfigError

    if not all(isinstance(o, str) for o in overrides):
        raise ConfigError(f"expected overrides as strings such as 'robot=fetch', got {overrides}")
    if GlobalHydra.instance().is_initialized():
        raise ConfigError("experiment_config composes conf/ itself: call it outside a Hydra app")
    hydra_config = HydraConfig.instance()
    try:
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            try:
                cfg = compose("config", overrides=list(overrides), return_hydra_config=True)
            except Exception as exc:  # noqa: BLE001 - Hydra's own, one line where it has one
                text = composition_error_text(exc)
                if text is None:
                    raise
                raise ConfigError(text) from None
            hydra_config.set_config(cfg)  # the overrides, as task_overrides reads them
            with open_dict(cfg):
                del cfg["hydra"]
            check_composed_keys(cfg)
            experiment, _, _ = check_run(cfg)
    finally:
        hydra_config.cfg = None
        GlobalHydra.instance().clear()
    return experiment


def dump_config_safe(cfg: DictConfig) -> str:
    """The resolved config, or the unresolved one where a resolver is not available."""
    try:
        return dump_config(cfg)
    except Exception:  # noqa: BLE001 - best effort for a log file
        return OmegaConf.to_yaml(cfg)


def main() -> None:
    """Console entry point."""
    # predictor, trainer, train and evaluate are the other commands' (refused here)
    groups = ("data", "experiment", "planner", "robot", "scenario", "sim")
    print_help_if_asked(__doc__ or "", sys.argv[1:], groups=groups)
    _refuse_used_run_dir(sys.argv[1:])
    run_app(_app)


def _used_run_dir(out_dir: Path) -> str | None:
    """The refusal for a run folder that holds an earlier run's results, or None."""
    earlier = [p for p in ("results.csv", "episodes") if (out_dir / p).exists()]
    if not earlier:
        return None
    return (
        f"{out_dir} already holds {' and '.join(earlier)} of an earlier run, which this "
        "run would replace; choose another hydra.run.dir (or delete them)"
    )


def _refuse_used_run_dir(argv: list[str]) -> None:
    """Exit 2 before Hydra starts when ``hydra.run.dir=<folder>`` on the command line names a
    folder with an earlier run's results: Hydra would first rewrite that run's ``.hydra/``
    files and add to its log. (A folder set in a config file is refused inside the run, after
    Hydra has done so.) A multirun (``-m``) is checked by its callback instead, before any
    job starts, against the results in the job folders of ``hydra.sweep.dir``
    (:meth:`~iplanner_torch.cli.callbacks.GatherSweepResults.on_multirun_start`)."""
    if any(a in ("-m", "--multirun", "-c", "--cfg") or a.startswith("--cfg=") for a in argv):
        return
    # (any value but false: a wrong one is named inside the run)
    if any(re.fullmatch(r"\+{0,2}run\.resume=(?!(false|False)$).*", a) for a in argv):
        # checked against the earlier run inside the run (begin_run), after Hydra has written
        # its record of this command in the folder's .hydra/: kept here to be put back if the
        # resume is refused
        for arg in argv:
            if arg.startswith("hydra.run.dir="):
                record = Path(arg.split("=", 1)[1].strip("'\"")).absolute() / ".hydra"
                _EARLIER_RECORD.update(
                    {f: f.read_bytes() for f in sorted(record.glob("*.yaml")) if f.is_file()}
                )
        return
    for arg in argv:
        if arg.startswith("hydra.run.dir="):
            value = arg.split("=", 1)[1].strip("'\"")
            message = None if "${" in value else _used_run_dir(Path(value).absolute())
            if message:
                print(f"error: ConfigError: {message}", file=sys.stderr)
                raise SystemExit(2)


if __name__ == "__main__":
    main()
