"""``iplanner-evaluate``: evaluate trained predictors and study episode logs.

Modes (``evaluate.mode``)::

    iplanner-evaluate                                   # prediction: held-out metrics
    iplanner-evaluate evaluate.checkpoint=checkpoints/reaching/iplanner_no_ni/predictor.ckpt
    iplanner-evaluate evaluate.mode=noise_sweep         # fig. result_prediction (NI, no NI, CV)
    iplanner-evaluate evaluate.mode=episode evaluate.logs=outputs/experiment/<run>/episodes
    iplanner-evaluate evaluate.mode=episode evaluate.logs=outputs/experiment/<run>/results.csv
    iplanner-evaluate evaluate.mode=episode \\
        'evaluate.logs=[<runA>/results.csv,<runB>/results.csv]' \\
        'evaluate.labels=[held,spread]' evaluate.baseline=itomp@spread

``prediction`` evaluates one checkpoint on the held-out demonstrations of ``data``: those of
the split by demonstration its training recorded in ``training_inputs.json`` beside it (its
``seed`` and ``data.split``; a different ``seed`` or ``data.split`` on the command line is
refused), or, for a checkpoint trained before that record, the split ``seed`` and
``data.split`` draw now. The checkpoint defines the windows (``data.windows.n_prev``,
``n_future``, ``stride``, ``feature_kinds``, ``progress_actions``; a different value on the
command line is refused) and the predictor runs on ``device``. ``noise_sweep`` re-noises the
held-out clean motion at each ``evaluate.noises`` level and replays it at each
``evaluate.speeds`` speed, for each predictor in ``evaluate.compare``, read from
``<paths.checkpoints>/<data folder>/<option>/predictor.ckpt`` (trained with
``conf/predictor/<option>.yaml`` and ``trainer`` when missing; ``evaluate.checkpoint``,
``train.out_dir`` and ``predictor`` are not read, and refused; an existing checkpoint whose
predictor settings differ from its option's in what tells the options apart, e.g.
``svgp.noisy_input``, is refused); the entry ``constant_velocity`` is the constant-velocity
forecast of ``run.cv`` (no checkpoint; on the first checkpoint's windows, its class metrics
NaN), the baseline. It writes CSV, PNG plots and a README; ``episode``
summarises MCAP episode logs, or the episode rows of a results CSV (an experiment's
``results.csv``, or rows gathered from several runs; in a run or multirun folder, a run made
with ``run.write_mcap=false`` is read from its ``results.csv``), with one row per episode, a
summary table and plots, and prints the table ``iplanner-experiment`` prints
(:func:`~iplanner_torch.eval.report.comparison_table`: episode counts, then the paper's metrics
in cm and ms); an episode whose log was cut before its metrics counts in ``contact_unknown``,
not as contact-free nor as a contact. In a folder, an ``.mcap`` file that is not a readable
episode log (not MCAP, e.g. a Git LFS pointer never fetched, or another program's MCAP file)
is left out, named in one ``DataWarning``; one given by its path is refused. The settings a
multirun's jobs differ in (its overrides, e.g. ``planner.itomp_spread_mps``) are kept apart in
the summary, read from the jobs' ``.hydra/overrides.yaml`` for a folder and from the dotted
override columns of a sweep's ``summary/results.csv``. ``evaluate.logs`` may list several
sources: with ``evaluate.labels`` each source's planners are renamed ``<planner>@<label>``, so
two runs of one planner (with and without an option) stay apart, and ``evaluate.baseline``
names the planner that ``results.md`` compares the others with, seed by seed. Without labels,
episodes that repeat another's settings (a run given twice, or reached twice below one folder)
are counted as more episodes, with a ``DataWarning``.

Each mode refuses the overrides it does not read (:data:`MODE_READS`): ``prediction`` the
``trainer`` group and ``predictor.*`` keys (the checkpoint defines them), ``episode``
everything but ``evaluate.logs``, ``labels``, ``baseline`` and ``out_dir``, and every mode the
closed-loop groups of ``iplanner-experiment``. A given ``evaluate.out_dir`` that already
holds the files the mode writes (:data:`MODE_WRITES`: an earlier report) is refused before
anything is evaluated, rather than written over.
"""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from iplanner_torch.cli._common import (
    CONF_DIR,
    _group_choice,
    cfg_list,
    cfg_scalar,
    check_added_keys,
    check_root_keys,
    config_split,
    data_format,
    data_fps,
    differing_settings,
    friendly_errors,
    instantiate,
    load_dataset,
    overridden_fields,
    override_group,
    override_key,
    override_word,
    predictor_folder,
    print_help_if_asked,
    refuse_unread_overrides,
    repo_path,
    run_app,
    setting_changes,
    shell_command,
)
from iplanner_torch.cli._common import (
    task_overrides as _task_overrides,
)
from iplanner_torch.errors import CheckpointError, ConfigError, DataError
from iplanner_torch.files import json_text

if TYPE_CHECKING:
    from iplanner_torch.eval.prediction import SplitRecord

MODES = ("prediction", "noise_sweep", "episode")

#: ``data.windows`` fields a checkpoint defines at evaluation (``joints``: :func:`_check_joints`)
CHECKPOINT_WINDOW_KEYS = ("n_prev", "n_future", "stride", "feature_kinds", "progress_actions")


def _given() -> dict[str, str]:
    """The keys this run's command line sets, each with its override as typed
    (``{"seed": "seed=1", "predictor": "predictor=iplanner_no_ni"}``)."""
    return {override_key(o): o for o in _task_overrides()}


#: the files each mode writes into its folder (glob patterns): a given ``evaluate.out_dir``
#: that holds one of them is refused, not written over
MODE_WRITES = {
    "prediction": ("prediction_metrics.json",),
    "noise_sweep": ("prediction_vs_noise.csv", "prediction_vs_noise.png", "README.md"),
    "episode": ("results.csv", "results.md", "compare_*.png", "paired_*.png", "sweep_*.png"),
}


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


def _refuse_earlier(path: Path, mode: str) -> Path:
    """``path``, the report folder of ``mode``, when it holds none of the files that mode
    writes (:data:`MODE_WRITES`).

    Raises:
        ConfigError: naming the files of an earlier report there, which this one would
            replace.
    """
    earlier = sorted({q.name for pattern in MODE_WRITES[mode] for q in path.glob(pattern)})
    if earlier:
        raise ConfigError(
            f"evaluate.out_dir={path} already holds {', '.join(earlier)} of an earlier report, "
            "which this one would replace; choose another evaluate.out_dir (or leave it unset: "
            "a new run folder), or move those files away"
        )
    return path


def _checkpoint(path: Path, cfg: DictConfig) -> Path:
    """``path`` when it is a file; otherwise a CheckpointError that says what it is and, when
    missing, the training command for this dataset and predictor."""
    if path.is_dir():
        raise CheckpointError(f"{path}: is a folder, not a checkpoint file (predictor.ckpt)")
    if not path.exists():
        predictor = HydraConfig.get().runtime.choices.get("predictor", "iplanner_ni")
        # iplanner-train writes <train.out_dir>/predictor.ckpt
        out_dir = path.parent if path.name == "predictor.ckpt" else path.with_suffix("")
        train = shell_command("iplanner-train", f"predictor={predictor}")
        train += f" {override_word('data', _group_choice('data') or 'reaching')}"
        train += f" {override_word('data.path', cfg.data.path)}"
        train += f" {override_word('train.out_dir', out_dir)}"
        use = ""
        if out_dir != path.parent:
            checkpoint = override_word("evaluate.checkpoint", out_dir / "predictor.ckpt")
            use = f", then run with {checkpoint}"
        raise CheckpointError(
            f"{path}: no such checkpoint file; train one with `{train}` (it writes "
            f"{out_dir / 'predictor.ckpt'}){use}"
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


def _check_windows(cfg: DictConfig, predictor: Any, ckpt: Path) -> None:
    """Refuse a command-line ``data.windows`` value (:data:`CHECKPOINT_WINDOW_KEYS`) other than
    the checkpoint's: evaluation cuts the held-out windows with the checkpoint's settings, so
    ``data.windows.n_prev=10`` on a checkpoint trained with 15 would otherwise be ignored."""
    from omegaconf import OmegaConf

    saved_cfg = dict(predictor.window_cfg or {})
    saved = {
        "n_prev": predictor.n_prev,
        "n_future": predictor.n_future,
        "stride": saved_cfg.get("stride", 1),  # evaluate_prediction's default when absent
        "feature_kinds": predictor.feature_kinds,
    }
    if "progress_actions" in saved_cfg:
        saved["progress_actions"] = saved_cfg["progress_actions"]

    def plain(value: Any) -> Any:
        if OmegaConf.is_config(value):
            value = OmegaConf.to_container(value)
        return list(value) if isinstance(value, (list, tuple)) else value

    keys = overridden_fields("data.windows", _task_overrides()) & set(CHECKPOINT_WINDOW_KEYS)
    now = {key: plain(cfg.data.windows[key]) for key in keys}
    found = differing_settings(saved, now, keys)
    differ = [
        f"data.windows.{key}={plain(value)} (checkpoint: {plain(old)})"
        for key, old, value in sorted(found, key=lambda d: CHECKPOINT_WINDOW_KEYS.index(d[0]))
    ]
    if differ:
        raise ConfigError(
            f"{'; '.join(differ)}: {ckpt} was trained with other window settings, and "
            "evaluation cuts the held-out windows with the checkpoint's; leave "
            f"{'it' if len(differ) == 1 else 'them'} out, or evaluate a checkpoint trained "
            "with them (iplanner-train ... data.windows.<key>=<value>)"
        )


def _evaluation_split(
    cfg: DictConfig,
    recorded: dict[Path, SplitRecord | None],
    to_train: list[Path],
    *,
    seed_draws_noise: bool = False,
) -> SplitRecord:
    """The split whose held-out demonstrations are scored: the one the checkpoints' training
    recorded, else (checkpoints from before the record) the one ``seed`` and ``data.split``
    draw, which the checkpoints ``to_train`` will be trained on.

    Args:
        cfg: the root config.
        recorded: checkpoint -> its :func:`~iplanner_torch.eval.prediction.recorded_split`
            (None when it has none).
        to_train: checkpoints still to train (with ``seed`` and ``data.split``).
        seed_draws_noise: ``seed`` also draws something else (the noise sweep's noise), so a
            ``seed`` other than the recorded split's is not refused: the recorded split is
            scored and ``seed`` draws only the rest.

    Raises:
        ConfigError: when the checkpoints were trained on different splits, when the command
            line sets ``seed`` or ``data.split`` otherwise than the recorded split, or when a
            checkpoint to train would be trained on another split than the recorded one.
    """
    from iplanner_torch.eval.prediction import INPUTS_FILE

    config = config_split(cfg)
    found = {ckpt: rec for ckpt, rec in recorded.items() if rec is not None}
    if len({(r.seed, r.fractions) for r in found.values()}) > 1:
        listed = "; ".join(f"{ckpt}: {rec.describe()}" for ckpt, rec in found.items())
        raise ConfigError(
            f"the compared checkpoints were trained on different splits ({listed}), so they "
            "held out different demonstrations; retrain them on one split (delete their "
            "folders and pass seed and data.split)"
        )
    if not found:
        return config
    ckpt, rec = next(iter(found.items()))
    where = f"{ckpt} was trained on the split {rec.describe()} (recorded in "
    where += f"{ckpt.parent / INPUTS_FILE})"
    given = _given()
    differ = [
        given[key]
        for key, same in (
            ("seed", config.seed == rec.seed or (seed_draws_noise and not to_train)),
            ("data.split", config.fractions == rec.fractions),
        )
        if key in given and not same
    ]
    if differ:
        raise ConfigError(
            f"{' '.join(differ)}: {where}, and evaluation scores the demonstrations that split "
            f"held out; leave {' and '.join(d.split('=', 1)[0] for d in differ)} out, or "
            f"evaluate a checkpoint trained with {' '.join(differ)}"
        )
    if to_train and (config.seed, config.fractions) != (rec.seed, rec.fractions):
        missing = ", ".join(str(c) for c in to_train)
        raise ConfigError(
            f"{where}, but the missing {missing} would be trained on {config.describe()} and "
            f"hold out other demonstrations; pass {rec.describe()} to train "
            f"{'it' if len(to_train) == 1 else 'them'} on the same split"
        )
    return rec


def _held_out(
    cfg: DictConfig, split: SplitRecord, source: str, *, recorded: bool, generate: bool = False
) -> list:
    """The demonstrations of ``data`` that ``split`` holds out (announced with ``source``,
    where the split comes from; ``recorded``: by the checkpoints' training).

    Raises:
        ConfigError: when the split holds none out.
        DataError: (``recorded``) when none of the demonstrations the training held out is
            in ``data``: the checkpoint was trained on other data, and its "held-out"
            metrics here would be those of demonstrations it may never have been split from.
    """
    from iplanner_torch.errors import DataError
    from iplanner_torch.eval.prediction import held_out_demonstrations

    demos = load_dataset(
        cfg.data, generate_if_missing=generate, progress=cfg_scalar(cfg, "progress", bool)
    )
    if recorded and split.held_out and not set(split.held_out) & {d.name for d in demos}:
        shown = ", ".join(sorted(split.held_out)[:3])
        raise DataError(
            f"none of the {len(split.held_out)} demonstration(s) the checkpoint's training held "
            f"out ({shown}{', ...' if len(split.held_out) > 3 else ''}) is among the "
            f"{len(demos)} of {cfg.data.path}: it was trained on other data; give that data "
            "(data=<option> data.path=<folder>, as its training was given)"
        )
    test = held_out_demonstrations(demos, split)
    if not test:
        raise ConfigError(
            f"{split.describe()} ({source}) leaves no held-out demonstrations of the "
            f"{len(demos)} in {cfg.data.path}: "
            + ("retrain with" if recorded else "give")
            + " a larger test share, e.g. data.split=[0.6,0.2,0.2]"
        )
    print(f"held-out split: {split.describe()} ({source}): {len(test)} demonstration(s)")
    return test


def _recorded_split(ckpt: Path, predictor: Any) -> SplitRecord | None:
    """The split ``ckpt``'s training recorded beside it
    (:func:`~iplanner_torch.eval.prediction.recorded_split`): a record of another training run
    (one started in its folder since, and interrupted) is refused, unless the command line
    gives ``seed``, which then draws the split (with a warning)."""
    from dataclasses import asdict, is_dataclass

    from iplanner_torch.eval.prediction import recorded_split

    return recorded_split(
        ckpt,
        predictor.fingerprint,
        getattr(predictor, "inputs_digest", ""),
        split_given="seed" in _given(),
        predictor_cfg=asdict(predictor.cfg)
        if is_dataclass(getattr(predictor, "cfg", None))
        else None,
    )


def _split_source(recorded: SplitRecord | None, ckpts: list[Path]) -> str:
    """Where the split comes from, for messages (``ckpts``: the evaluated checkpoints)."""
    from iplanner_torch.eval.prediction import INPUTS_FILE

    if recorded is not None:
        return f"recorded in {INPUTS_FILE} by the training"
    if not ckpts:  # only the constant-velocity baseline: nothing was trained
        return "from seed and data.split: no checkpoint is compared"
    if any((ckpt.parent / INPUTS_FILE).is_file() for ckpt in ckpts):
        return (
            f"from seed and data.split: the {INPUTS_FILE} beside the checkpoint does not record "
            "its training's split"
        )
    return f"from seed and data.split: no {INPUTS_FILE} beside the checkpoint records its split"


def _check_data_settings(cfg: DictConfig) -> None:
    """``data.format``, ``data.fps`` and ``data.split`` (with ``seed``), checked: ConfigError
    naming the key, so that a bad one is named before any checkpoint loads."""
    data_format(cfg.data)
    data_fps(cfg.data)
    config_split(cfg)


def _device(cfg: DictConfig) -> Any:
    """The torch device ``device`` names (``auto``: CUDA when present)."""
    from iplanner_torch.types import resolve_device

    return resolve_device(str(cfg.get("device", "cpu")))


def _prediction(cfg: DictConfig) -> None:
    from iplanner_torch.eval.prediction import evaluate_prediction, metric_line
    from iplanner_torch.prediction.predictor import HumanMotionPredictor

    _refuse_unread("prediction")
    ckpt = _checkpoint(repo_path(cfg.evaluate.checkpoint), cfg)
    out = _refuse_earlier(_out_dir(cfg), "prediction") / "prediction_metrics.json"
    _check_data_settings(cfg)  # before the checkpoint loads
    predictor = HumanMotionPredictor.load(ckpt, map_location=_device(cfg))
    _check_joints(cfg, predictor, ckpt)
    _check_windows(cfg, predictor, ckpt)
    record = _recorded_split(ckpt, predictor)
    split = _evaluation_split(cfg, {ckpt: record}, [])
    held_out = _held_out(cfg, split, _split_source(record, [ckpt]), recorded=record is not None)
    metrics = evaluate_prediction(predictor, held_out)
    out.write_text(json_text(metrics, indent=2) + "\n")
    print(f"{ckpt} on held-out demonstrations of {cfg.data.path}:")
    for key, value in metrics.items():
        print(metric_line(key, value))
    print(f"wrote {out}")


def _refuse_unread_sweep_overrides(cfg: DictConfig) -> None:
    """Refuse command-line keys ``noise_sweep`` does not read: ``evaluate.checkpoint``,
    ``train.out_dir`` and the ``predictor`` group and its keys (its checkpoints come from
    ``paths.checkpoints`` and ``evaluate.compare``)."""
    unread = [
        override
        for key, override in _given().items()
        if key in ("evaluate.checkpoint", "train.out_dir")
        or override_group(override) == "predictor"
    ]
    if unread:
        folder = Path(str(cfg.paths.checkpoints)) / Path(str(cfg.data.path)).name
        raise ConfigError(
            f"evaluate.mode=noise_sweep does not read {' '.join(unread)}: it compares "
            f"<paths.checkpoints>/<data folder>/<option>/predictor.ckpt for each option of "
            f"evaluate.compare (here {folder}/{{{','.join(_learned(cfg.evaluate.compare))}"
            "}), training a missing one with conf/predictor/<option>.yaml; choose them with "
            "evaluate.compare and paths.checkpoints, or score one checkpoint with "
            "evaluate.mode=prediction evaluate.checkpoint=<file>"
        )


def _learned(compare: Any) -> list[str]:
    """The options of ``evaluate.compare`` read from checkpoints (all but
    :data:`CV_OPTION`)."""
    return [str(o) for o in compare if str(o) != CV_OPTION]


def _flat_settings(value: Any) -> dict[str, Any]:
    """:func:`~iplanner_torch.eval.prediction.flat_settings` (imported when used)."""
    from iplanner_torch.eval.prediction import flat_settings

    return flat_settings(value)


def _follows_seed(node: DictConfig) -> set[str]:
    """The dotted keys of a ``conf/predictor`` node whose value is ``${seed}`` (the command
    line's ``seed``)."""
    from omegaconf import OmegaConf

    raw = OmegaConf.to_container(node, resolve=False)
    return {k for k, v in _flat_settings(raw).items() if v == "${seed}"}


def _option_settings(cfg: DictConfig, options: list[str]) -> dict[str, dict[str, Any]]:
    """Option -> the predictor settings of ``conf/predictor/<option>.yaml`` (dotted keys), for
    ``options`` and every other option of the group that builds (those that do not are left
    out; an option of ``options`` that does not build is refused).

    Raises:
        ConfigError: when an option of ``options`` does not build a predictor config.
    """
    from dataclasses import asdict

    from iplanner_torch.cli.experiment import option_node
    from iplanner_torch.prediction.predictor import PredictorCfg

    names = sorted(p.stem for p in (Path(CONF_DIR) / "predictor").glob("*.yaml"))
    out: dict[str, dict[str, Any]] = {}
    for option in [*options, *(n for n in names if n not in options)]:
        try:
            built = instantiate(option_node("predictor", option, cfg), PredictorCfg, "predictor")
        except ConfigError:
            if option in options:
                raise
            continue
        out[option] = _flat_settings(asdict(built))
    return out


def _check_predictor_option(
    cfg: DictConfig, option: str, predictor: Any, ckpt: Path, options: dict[str, dict[str, Any]]
) -> None:
    """Refuse a checkpoint whose predictor settings are not those of the option it stands for:
    ``noise_sweep`` labels ``<option>/predictor.ckpt`` with ``option``, so an iplanner_no_ni
    predictor in the iplanner_ni folder would swap the table's rows without a word.

    The settings compared are those in which the options of ``conf/predictor`` differ from one
    another (what tells the variants apart: ``svgp.noisy_input`` for iplanner_ni and
    iplanner_no_ni), leaving out the ``svgp`` fields the checkpoint's and the option's
    ``noisy_input`` both do not read; a predictor trained otherwise on purpose in the rest
    (``iplanner-train ... predictor.svgp.epochs=5`` into the folder) is used as it is. The
    keys that follow ``seed`` (``seed``, ``svgp.seed``) are not compared: in ``noise_sweep``
    ``seed`` draws the noise, and a checkpoint trained with another is used, as its recorded
    split is (:func:`_evaluation_split`).

    Args:
        cfg: the root config.
        option: the option of ``evaluate.compare`` whose folder holds ``ckpt``.
        predictor: the loaded checkpoint.
        ckpt: its path.
        options: :func:`_option_settings` (``option`` among them).

    Raises:
        ConfigError: naming the checkpoint, the option, each setting that differs
            (recorded -> config) and the way out.
    """
    from dataclasses import asdict

    from iplanner_torch.cli.experiment import option_node, train_command
    from iplanner_torch.prediction.svgp import UNREAD_BY_NOISY_INPUT

    now = options[option]
    saved = _flat_settings(asdict(predictor.cfg))
    keys = {
        k
        for values in options.values()
        for k, v in values.items()
        if any(other.get(k) != v for other in options.values())
    }
    keys -= _follows_seed(option_node("predictor", option, cfg))
    unread = set(UNREAD_BY_NOISY_INPUT.get(str(saved.get("svgp.noisy_input")), ()))
    unread &= set(UNREAD_BY_NOISY_INPUT.get(str(now.get("svgp.noisy_input")), ()))
    keys -= {f"svgp.{k}" for k in unread}
    differ = setting_changes(saved, now, keys)
    if differ:
        trainer = _group_choice("trainer") or "default"  # the sweep trains with `trainer`
        retrain = train_command(
            cfg, cfg.data, option, ckpt.parent, trainer=trainer, overwrite=True
        )
        raise ConfigError(
            f"{ckpt} was trained with other predictor settings than conf/predictor/"
            f"{option}.yaml, so the sweep would report it as {option}: "
            f"{'; '.join(differ)} (recorded -> config). Retrain it into that folder "
            f"(`{retrain}`), or delete {ckpt.parent} to have the sweep train it"
        )


def _noise_sweep_grid(cfg: DictConfig) -> tuple[list[str], list[float], list[str]]:
    """``evaluate.compare``, ``noises`` and ``speeds`` of a noise sweep, checked, after the
    overrides it does not read are refused.

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    from iplanner_torch.eval.prediction_sweep import check_sweep_grid

    _refuse_unread_sweep_overrides(cfg)  # the more specific message first
    _refuse_unread("noise_sweep")
    noises = cfg_list(cfg.evaluate, "noises", float)
    speeds = cfg_list(cfg.evaluate, "speeds", str)
    compare = cfg_list(cfg.evaluate, "compare", str)
    try:
        check_sweep_grid(compare, noises, speeds)
    except ConfigError as err:
        raise ConfigError(f"evaluate.{err}") from None
    return compare, noises, speeds


#: the entry of ``evaluate.compare`` that stands for the constant-velocity forecast (no
#: checkpoint: built from ``run.cv``, on the windows of the compared checkpoints)
CV_OPTION = "constant_velocity"


def _cv_cfg(cfg: DictConfig) -> Any:
    """The constant-velocity forecast's settings: ``run.cv`` (as ``iplanner-experiment``'s
    planner ``iplanner_cv`` reads them).

    Raises:
        ConfigError: naming the ``run.cv`` key that is wrong.
    """
    from iplanner_torch.prediction.constant_velocity import ConstantVelocityCfg

    return instantiate(cfg.run.cv, ConstantVelocityCfg, "run.cv")


def _cv_predictor(cfg: DictConfig, cv_cfg: Any, held_out: list[Any], learned: list[Any]) -> Any:
    """The constant-velocity predictor of a noise sweep, scored on the windows of the first
    compared checkpoint (its ``n_prev``, ``n_future`` and window settings), else on
    ``data.windows``; at the held-out data's frame rate and joints.

    Raises:
        ConfigError: when those windows hold fewer frames than ``run.cv.fit_frames``.
    """
    from dataclasses import replace

    from omegaconf import OmegaConf

    from iplanner_torch.prediction.constant_velocity import ConstantVelocityPredictor

    if learned:
        ref = learned[0]
        n_prev, n_future, window_cfg = ref.n_prev, ref.n_future, ref.window_cfg
    else:
        window_cfg = OmegaConf.to_container(cfg.data.windows, resolve=True)
        assert isinstance(window_cfg, dict)
        window_cfg.pop("_target_", None)
        n_prev, n_future = int(window_cfg["n_prev"]), int(window_cfg["n_future"])
    try:
        cv_cfg = replace(cv_cfg, n_prev=n_prev, n_future=n_future)
    except ConfigError as err:
        raise ConfigError(f"run.cv: on windows of {n_prev} frames: {err}") from None
    return ConstantVelocityPredictor(
        cv_cfg,
        fps=held_out[0].fps,
        joint_names=tuple(held_out[0].joint_names),
        window_cfg=window_cfg,
    )


def _noise_sweep(cfg: DictConfig) -> None:
    from iplanner_torch.cli.experiment import option_node, training_lock
    from iplanner_torch.cli.train import train_from_config
    from iplanner_torch.eval.prediction_sweep import (
        check_clean_positions,
        prediction_vs_noise,
        write_noise_report,
    )
    from iplanner_torch.prediction.predictor import HumanMotionPredictor

    compare, noises, speeds = _noise_sweep_grid(cfg)
    _check_data_settings(cfg)  # before a checkpoint loads
    cv_cfg = _cv_cfg(cfg) if CV_OPTION in compare else None  # checked before any work
    report_dir = _refuse_earlier(_out_dir(cfg), "noise_sweep")
    device = _device(cfg)
    folder = predictor_folder(cfg, cfg.data)
    learned = _learned(compare)
    ckpts = {o: repo_path(folder / o) / "predictor.ckpt" for o in learned}
    for ckpt in ckpts.values():
        if ckpt.is_dir():
            raise CheckpointError(f"{ckpt}: is a folder, not a checkpoint file")
    missing = [option for option, ckpt in ckpts.items() if not ckpt.exists()]
    # the trained ones first: their settings, windows and split are checked before anything
    # is trained
    loaded, recorded = {}, {}
    options = _option_settings(cfg, learned) if len(missing) < len(ckpts) else {}
    for option, ckpt in ckpts.items():
        if option not in missing:
            loaded[option] = HumanMotionPredictor.load(ckpt, map_location=device)
            _check_predictor_option(cfg, option, loaded[option], ckpt, options)
            _check_joints(cfg, loaded[option], ckpt)
            _check_windows(cfg, loaded[option], ckpt)
            recorded[ckpt] = _recorded_split(ckpt, loaded[option])
    split = _evaluation_split(cfg, recorded, [ckpts[o] for o in missing], seed_draws_noise=True)
    record = next((r for r in recorded.values() if r is not None), None)
    source = _split_source(record, [c for o, c in ckpts.items() if o not in missing])
    if missing:
        source = f"from seed and data.split, which {', '.join(missing)} will be trained on"
    # the parallel jobs of a sweep that lack the same dataset or predictor make it once
    with training_lock(folder) if missing else contextlib.nullcontext():
        held_out = _held_out(
            cfg, split, source, recorded=record is not None and not missing, generate=bool(missing)
        )
        check_clean_positions(held_out)  # before any missing predictor is trained
        for option in missing:
            if not ckpts[option].exists():  # else another job trained it meanwhile
                print(f"training missing predictor {option} ...", flush=True)
                train_from_config(
                    cfg,
                    option_node("predictor", option, cfg),
                    ckpts[option].parent,
                    trainer_node=cfg.trainer,
                )
            loaded[option] = HumanMotionPredictor.load(ckpts[option], map_location=device)
            _check_joints(cfg, loaded[option], ckpts[option])
    if cv_cfg is not None:
        loaded[CV_OPTION] = _cv_predictor(cfg, cv_cfg, held_out, [loaded[o] for o in learned])
    predictors = {option: loaded[option] for option in compare}  # in evaluate.compare's order
    df = prediction_vs_noise(
        predictors,
        held_out,
        noises=noises,
        speeds=speeds,
        seed=cfg_scalar(cfg, "seed", int),
        progress=cfg_scalar(cfg, "progress", bool),
    )
    command = shell_command("iplanner-evaluate", *_task_overrides())
    written = write_noise_report(df, report_dir, command=command)
    print(df.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    print("wrote " + ", ".join(str(p) for p in written))


def _episode_rows(path: Path) -> Any:
    """The episode rows of one source of ``evaluate.logs`` (an .mcap file, a folder of them or
    a results .csv; in a run or multirun folder, the ``results.csv`` of a run that wrote no
    log stands for it), refused with a clear error when it holds none. In a folder, an .mcap
    file that is not a readable episode log (not MCAP, e.g. a Git LFS pointer, or another
    program's MCAP file) is left out with a DataWarning naming it; given by its path, it is
    refused."""
    from iplanner_torch.cli.callbacks import run_rows
    from iplanner_torch.eval.report import gather_results

    if path.is_dir():
        df = run_rows(path)  # every log below it, in numbered order, then log-less runs
        if df.empty and any(path.rglob("*.mcap")):  # each named in gather_results' warning
            raise DataError(
                f"{path}: none of its .mcap files is a readable episode log, and it holds no "
                "results.csv of a run folder; nothing to report"
            )
        if df.empty:
            raise ConfigError(
                f"{path}: no .mcap episode logs found, nor the results.csv of a run folder"
            )
    else:
        df = gather_results(path)
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

    from iplanner_torch.cli.callbacks import episode_report, split_columns, sweep_overrides
    from iplanner_torch.eval.report import (
        comparison_key,
        comparison_table,
        incomplete_logs_note,
        overrun_note,
        paired_skip_note,
        print_table,
        report_groups,
    )

    _refuse_unread("episode")
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
    if (out_dir / "episodes").is_dir():  # its results.csv would be replaced by this report
        raise ConfigError(
            f"evaluate.out_dir={out_dir} is the folder of an iplanner-experiment run (it holds "
            "episodes/), whose results.csv and results.md this report would replace; choose "
            "another evaluate.out_dir (or leave it unset: a new run folder)"
        )
    _refuse_earlier(out_dir, "episode")
    frames, swept = [], []
    for i, path in enumerate(paths):
        df = _episode_rows(path)
        if path.is_dir():  # a multirun folder: the overrides its jobs differ in
            df, keys = sweep_overrides(df, path)
        else:  # a sweep's gathered rows: the override columns sweep_overrides named
            keys = _override_columns(df)
        swept += [k for k in keys if k not in swept]
        if labels is not None:  # keep the runs apart: itomp@held, itomp@spread, ...
            named = df["planner"].notna()  # a log cut before its metadata has none
            df = df.assign(planner=df["planner"].where(~named, df["planner"] + "@" + labels[i]))
        frames.append(df)
    df = pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]
    if labels is None:  # one results CSV can repeat rows too (two tables pasted together)
        _warn_repeated_episodes(df, swept)
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
    # the columns and units of iplanner-experiment's table, in the rows of results.md (the
    # swept overrides kept apart, as episode_report keeps them)
    groups = report_groups(df)
    extra = split_columns(df, groups, swept)
    groups = (*groups[:-1], *extra, groups[-1]) if extra else groups
    table = comparison_table(df, groups)
    print_table(table)
    print(comparison_key(table))
    for note in (incomplete_logs_note(df), overrun_note(df)):
        if note:
            print(note)
    skipped = paired_skip_note(df, groups, baseline)  # results.md says it too
    if skipped:
        print(skipped)
    print(f"{len(df)} episode(s); wrote " + ", ".join(str(p) for p in written))


#: The columns that tell two episodes apart (with the swept settings of a multirun folder).
EPISODE_SETTINGS = (
    "planner", "scenario", "arrangement", "task_order", "confidence", "noise", "dropout",
    "speed", "seed",
)  # fmt: skip


def _override_columns(df: Any) -> list[str]:
    """The columns of rows read from a results CSV that hold a sweep's overrides, as
    :func:`~iplanner_torch.cli.callbacks.sweep_overrides` names them in a summary's
    ``results.csv``: dotted keys (``planner.itomp_spread_mps``, ``override.seed``), not metrics
    (``stage/name``) nor the ``path``."""
    from iplanner_torch.eval.report import DEFAULT_METRICS

    return [
        str(c)
        for c in df.columns
        if "." in str(c) and "/" not in str(c) and str(c) not in DEFAULT_METRICS
    ]


def _warn_repeated_episodes(df: Any, swept: list[str]) -> None:
    """Warn when sources given without ``evaluate.labels`` hold episodes with the same settings
    (the same run given twice, or as its results.csv and its episodes folder, or reached twice
    below one folder): their rows would be counted as more episodes. Episodes of jobs of a
    multirun that differ in an override (``swept``) are not repeats."""
    import warnings

    from iplanner_torch.errors import DataWarning

    keys = [c for c in (*EPISODE_SETTINGS, *swept) if c in df.columns]
    repeated = df.duplicated(keys, keep="first") & df["planner"].notna()
    if bool(repeated.any()):
        warnings.warn(
            f"{int(repeated.sum())} of the {len(df)} episodes repeat the settings "
            f"({', '.join(keys)}) of another: is a run given twice (or as its results.csv and "
            "its episodes folder, or copied twice below one folder)? They are counted as more "
            "episodes; give evaluate.labels to keep different runs of the same settings apart",
            DataWarning,
            stacklevel=2,
        )


#: What each mode reads besides ``evaluate.mode`` and ``evaluate.out_dir``
#: (:func:`~iplanner_torch.cli._common.unread_overrides`).
MODE_READS = {
    "prediction": ("data", "seed", "device", "paths", "evaluate.checkpoint"),
    "noise_sweep": (
        "data", "trainer", "seed", "device", "paths",
        "evaluate.compare", "evaluate.noises", "evaluate.speeds", "run.cv",
    ),
    "episode": ("evaluate.logs", "evaluate.labels", "evaluate.baseline"),
}  # fmt: skip
#: Why a mode does not read what it does not read.
MODE_HINTS = {
    "prediction": (
        "the checkpoint defines the predictor and how it was trained; choose it with "
        "evaluate.checkpoint=<file> or predictor=<option> (read from train.out_dir). "
        "evaluate.compare, noises and speeds belong to evaluate.mode=noise_sweep, "
        "evaluate.logs, labels and baseline to evaluate.mode=episode, and the closed-loop "
        "settings (robot, scenario, planner, sim, run, tracker, human) to iplanner-experiment"
    ),
    "noise_sweep": (
        "it re-noises held-out demonstrations of data at each of evaluate.noises and "
        "evaluate.speeds for the predictors of evaluate.compare (trained with trainer when "
        "missing); evaluate.logs, labels and baseline belong to evaluate.mode=episode, and the "
        "closed-loop settings (robot, scenario, planner, sim, run, tracker, human) to "
        "iplanner-experiment"
    ),
    "episode": (
        "it summarises what the logs recorded; it reads evaluate.logs, evaluate.labels, "
        "evaluate.baseline and evaluate.out_dir (the episodes' settings are those they ran "
        "with: set them on iplanner-experiment)"
    ),
}


def _refuse_unread(mode: str) -> None:
    """Refuse command-line settings ``mode`` does not read (:data:`MODE_READS`)."""
    read = [*MODE_READS[mode], "evaluate.mode", "evaluate.out_dir"]
    hint = MODE_HINTS[mode]
    if mode == "prediction" and "evaluate.checkpoint" not in _given():
        read += ["predictor=", "train.out_dir"]  # they name the default checkpoint
    elif mode == "prediction":
        hint = "evaluate.checkpoint names the checkpoint, and " + hint
    refuse_unread_overrides(
        f"iplanner-evaluate evaluate.mode={mode}", read, hint, _task_overrides()
    )


def _kept_when_interrupted(cfg: DictConfig) -> str:
    """What an interrupted evaluation keeps, for its ``interrupted: ...`` line."""
    text = "no results were written (they are written when the evaluation ends)"
    if str(cfg.evaluate.mode) == "noise_sweep":
        folder = predictor_folder(cfg, cfg.data)
        text += (
            "; the sub-models of a missing predictor trained before the signal are kept in "
            f"{folder}/<option>/ (*.ckpt)"
        )
    return text


def _mode(cfg: DictConfig) -> str:
    """``evaluate.mode``, one of :data:`MODES`."""
    mode = str(cfg.evaluate.mode)
    if mode not in MODES:
        raise ConfigError(f"evaluate.mode must be one of {MODES}, got {mode!r}")
    return mode


def check_job(cfg: DictConfig) -> dict[str, Path]:
    """What a sweep checks of each ``iplanner-evaluate`` job before the first starts: the mode,
    the overrides it does not read and, for ``noise_sweep``, its grid.

    Returns:
        ``{"evaluate.out_dir": folder}`` when ``evaluate.out_dir`` is set (two jobs would
        write their tables into the same folder), else ``{}`` (each job writes its own).

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    check_added_keys(cfg)
    check_root_keys(cfg)
    mode = _mode(cfg)
    if mode == "noise_sweep":
        _noise_sweep_grid(cfg)
    else:
        _refuse_unread(mode)
    return {"evaluate.out_dir": repo_path(cfg.evaluate.out_dir)} if cfg.evaluate.out_dir else {}


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
@friendly_errors(kept=_kept_when_interrupted)
def _app(cfg: DictConfig) -> None:
    mode = _mode(cfg)
    {"prediction": _prediction, "noise_sweep": _noise_sweep, "episode": _episode}[mode](cfg)


def main() -> None:
    """Console entry point."""
    # predictor: which checkpoint (prediction); trainer: a missing one's (noise_sweep)
    print_help_if_asked(__doc__ or "", sys.argv[1:], groups=("data", "predictor", "trainer"))
    run_app(_app)


if __name__ == "__main__":
    main()
