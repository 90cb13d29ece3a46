"""Helpers shared by the Hydra entry points (the only modules of the package that use Hydra)."""

from __future__ import annotations

import contextlib
import functools
import math
import re
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from omegaconf import DictConfig, ListConfig, OmegaConf
from yaml import YAMLError

from iplanner_torch.checks import field_kind, fits_kind
from iplanner_torch.errors import ConfigError, IPlannerError
from iplanner_torch.files import json_text
from iplanner_torch.sim.tracker import MAX_NOISE_M

#: conf/ at the repository root (the package is installed editable from the clone).
CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")


# ${basename:some/path} -> "path" (checkpoint folders are named after their dataset folder)
if not OmegaConf.has_resolver("basename"):
    OmegaConf.register_new_resolver("basename", lambda p: Path(str(p)).name)

F = TypeVar("F", bound=Callable[..., Any])
_E = TypeVar("_E", bound=BaseException)


def instantiate(node: Any, expected: type | None = None, name: str | None = None) -> Any:
    """Build the dataclass described by a config node (``_target_`` plus keyword arguments).

    A value whose type does not fit its dataclass field (``bool``, ``int``, ``float`` or
    ``str``, possibly ``| None``; an int is a float) is refused before anything is built,
    with its full key, so ``planner.optimizer.iterations=1.5`` fails at start-up, not in the
    middle of a run.

    Args:
        node: the config node.
        expected: the class the node must build (a group file without ``_target_``, e.g. a
            new ``conf/predictor/<name>.yaml`` that lists only the changed fields, would
            otherwise build a plain dict).
        name: the node's key in messages (default: its full key in the config).

    Raises:
        ConfigError: when the node cannot be built (unknown key, wrong type, bad value), with
            the underlying reason, or builds something other than ``expected``.
    """
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate as hydra_instantiate

    key = name or (_full_key(node, None) if isinstance(node, (DictConfig, ListConfig)) else "")
    wrong = _wrong_type(node) if isinstance(node, DictConfig) else None
    if wrong:
        if name and not _full_key(node, None):  # a node the command put together: named as given
            wrong = f"{name}.{wrong}"
        raise ConfigError(wrong)
    if isinstance(node, (ListConfig, list, tuple)):  # a group file whose top level is a list
        raise ConfigError(_list_node_text(key, expected))
    try:
        built = hydra_instantiate(node, _convert_="all")
    except InstantiationException as exc:
        cause = exc.__cause__ or exc
        if isinstance(cause, IPlannerError):
            text = str(cause)
            where = _bad_value_key(node, key, str(exc), text)
            # "ReachingCfg.fps" (the library's name of the field) -> "fps": the key says where
            text = re.sub(r"(?<![\w.])[A-Z]\w*Cfg\.(?=[a-z_])", "", text)
            field = where.rsplit(".", 1)[-1]
            if where != field and text.startswith(f"{field}: "):  # "seeds: ..." names it too
                text = text[len(field) + 2 :]
            elif where != field and text.startswith(f"{field}."):  # "per_kind.itomp.x: ..."
                raise ConfigError(where + text[len(field) :]) from exc
            raise ConfigError(
                f"{where}: {text}" if where and not text.startswith(where) else text
            ) from exc
        raise ConfigError(f"cannot build config node {key or '<root>'!r}: {cause}") from exc
    if expected is not None and not isinstance(built, expected):
        target = f"{expected.__module__}.{expected.__qualname__}"
        raise ConfigError(
            f"config node {key or '<root>'!r} built a {type(built).__name__}, not a "
            f"{expected.__name__}: its file needs '_target_: {target}', or, to change only "
            "some fields of an existing file of its group, a first line "
            "'defaults: [<that file>, _self_]'"
        )
    return built


def _list_node_text(key: str, expected: type | None) -> str:
    """The refusal of a config node that is a list where a mapping of fields is expected."""
    where = repr(key or "<root>")
    choice = _group_choice(key)
    if choice is not None:
        where += f" ({key}={choice})"
    text = f"config node {where} is a list, not a mapping of keys to values"
    if expected is None:
        return text + " ('key: value' lines)"
    target = f"{expected.__module__}.{expected.__qualname__}"
    return (
        f"{text}: its file needs '_target_: {target}' and {expected.__name__}'s fields as "
        "'key: value' lines, or, to change only some fields of an existing file of its group, "
        "a first line 'defaults: [<that file>, _self_]'"
    )


def _group_choice(key: str) -> str | None:
    """The option this Hydra run chose for config group ``key`` (None outside a run, or when
    ``key`` is not a group)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        choice = HydraConfig.get().runtime.choices.get(key)
    except Exception:  # noqa: BLE001 - not in a Hydra run
        return None
    return None if choice is None else str(choice)


def _bad_value_key(node: Any, key: str, hydra_message: str, text: str) -> str:
    """The dotted key of the value a dataclass refused, for the message (``sim.tracker_fps``).

    Hydra ends its message with the full key of the node whose ``_target_`` raised
    (``full_key: planner.optimizer``); the field is the first of that dataclass's fields that
    the message names as a word (``expected horizon_s in (0, 60] s``). Falls back to the node
    (``planner.optimizer``), then to ``key``.
    """
    import dataclasses

    from hydra.utils import get_class

    if not isinstance(node, DictConfig):
        return key
    found = re.search(r"full_key: (\S+)\s*$", hydra_message)
    own = _full_key(node, None) or ""
    inner = found.group(1) if found else own
    if own and inner != own and not inner.startswith(own + "."):
        return key
    suffix = inner[len(own) :].lstrip(".") if own else inner
    sub: Any = OmegaConf.select(node, suffix) if suffix else node
    where = ".".join(part for part in (key, suffix) if part)
    target = sub.get("_target_") if isinstance(sub, DictConfig) else None
    try:
        cls = get_class(target) if isinstance(target, str) else None
    except Exception:
        cls = None
    if cls is None or not dataclasses.is_dataclass(cls):
        return where
    own_name = re.escape(cls.__name__)
    named = [  # "fps" or "ReachingCfg.fps"
        (m.start(), f.name)
        for f in dataclasses.fields(cls)
        if (m := re.search(rf"(?<![\w.])(?:{own_name}\.)?{re.escape(f.name)}(?!\w)", text))
    ]
    if not named:
        return where
    return ".".join(part for part in (where, min(named)[1]) if part)


def _full_key(node: DictConfig, key: str | None) -> str:
    try:
        return str(node._get_full_key(key)) or key
    except Exception:  # a detached node
        return key


def _wrong_type(node: DictConfig) -> str | None:
    """The first value under ``node`` whose type does not fit its dataclass field
    (:func:`_scalar_kind`; ``"trainer.max_steps: expected int, got 'abc'"``; null only where
    the field may be None, and no mapping where it holds one value), or None."""
    import dataclasses

    from hydra.utils import get_class

    fields: dict[str, tuple[type, bool]] = {}
    target = node.get("_target_") if "_target_" in node else None
    if isinstance(target, str):
        try:
            cls = get_class(target)
        except Exception:
            cls = None
        if cls is not None and dataclasses.is_dataclass(cls):
            fields = {
                f.name: kind
                for f in dataclasses.fields(cls)
                if (kind := _scalar_kind(cls, f)) is not None
            }
    for key in node:
        try:
            value = node[key]
        except Exception:  # an interpolation that does not resolve: Hydra says so itself
            continue
        expected, nullable = fields.get(str(key), (None, True))
        if isinstance(value, DictConfig):
            if expected is not None:  # {} where a number or a name is expected
                got = _plain(value)
                return f"{_full_key(node, str(key))}: expected {expected.__name__}, got {got!r}"
            found = _wrong_type(value)
            if found:
                return found
            continue
        if expected is None or (value is None and nullable):
            continue
        if value is None or not fits_kind(value, expected):  # null where the field takes none
            got = "null" if value is None else repr(value)
            return f"{_full_key(node, str(key))}: expected {expected.__name__}, got {got}"
    return None


def _scalar_kind(cls: type, field: Any) -> tuple[type, bool] | None:
    """``(type, may be None)`` when a dataclass field holds a bool, int, float or str (``X``
    or ``X | None``; a ``Literal`` of strings is a str), else None
    (:func:`~iplanner_torch.checks.field_kind`). A field whose annotation does not resolve is
    judged by its default, and may be None."""
    kind = field_kind(cls, field.name)
    if kind is None or (kind.choices is not None and kind.base is not str):
        return None
    return kind.base, kind.nullable


def cfg_scalar(node: DictConfig, key: str, kind: type) -> Any:
    """``node[key]`` checked to be a ``kind`` (bool, int, float or str; an int is a float).

    Raises:
        ConfigError: naming the key, the expected type and the value given.
    """
    value = node[key]
    if not fits_kind(value, kind):
        raise ConfigError(f"{_full_key(node, key)}: expected {kind.__name__}, got {value!r}")
    return kind(value)


def cfg_list(node: DictConfig, key: str, kind: type) -> list[Any]:
    """``node[key]`` checked to be a list of ``kind`` (see :func:`cfg_scalar`).

    Raises:
        ConfigError: naming the key when it is not a list or an item is not a ``kind``.
    """
    value = node[key]
    if not isinstance(value, (list, tuple, ListConfig)) or not all(
        fits_kind(v, kind) for v in value
    ):
        name = _full_key(node, key)
        example = {int: "[0,1,2]", float: "[0.0,0.5]", bool: "[true,false]"}.get(kind, "[a,b]")
        if isinstance(value, str) or (
            not isinstance(value, (list, tuple, ListConfig, bool)) and fits_kind(value, kind)
        ):  # one value where a list was asked for: that value in a list
            example = f"[{value}]"
        raise ConfigError(
            f"{name}: expected a list of {kind.__name__}, got {value!r} (e.g. "
            f"{shell_word(f'{name}={example}')})"
        )
    return [kind(v) for v in value]


def repo_path(path: str | Path) -> Path:
    """A config path: absolute as given, relative ones against the current directory."""
    return Path(path).expanduser().resolve()


def predictor_folder(cfg: DictConfig, data_node: DictConfig) -> Path:
    """The folder of the predictors learned from the dataset ``data_node`` names (``cfg.data``,
    or a scenario's): ``<paths.checkpoints>/<dataset folder name>``, resolved."""
    return repo_path(Path(str(cfg.paths.checkpoints)) / Path(str(data_node.path)).name)


def _plain_text(rst: str) -> str:
    """A docstring's reStructuredText markup made terminal text: ``x`` -> x, ``Examples::``
    -> ``Examples:``, :role:`~a.b.c` -> c."""
    text = re.sub(r":[a-z]+:`~?(?:[\w.]+\.)?([^`]+)`", r"\1", rst)
    text = re.sub(r"``([^`]+)``", r"\1", text)
    return re.sub(r"::$", ":", text, flags=re.MULTILINE)


#: The root keys ``--help`` lists (``iplanner-train`` lists its own: it does not read ``device``).
ROOT_KEYS_HELP = "seed=<int>, device=auto|cpu|cuda, progress=true|false"


def command_help(
    doc: str, groups: Iterable[str] | None = None, root_keys: str = ROOT_KEYS_HELP
) -> str:
    """The ``--help`` text of a command: its docstring (``doc``), then the config groups of
    ``conf/`` it reads (``groups``; default all) and their options, its root keys
    (``root_keys``) and Hydra's own flags."""
    import textwrap

    conf = Path(CONF_DIR)
    names = sorted(d.name for d in conf.iterdir() if d.is_dir() and d.name != "hydra")
    if groups is not None:
        names = [n for n in names if n in set(groups)]
    root = OmegaConf.load(conf / "config.yaml")
    defaults = {}
    for item in root.get("defaults", []):
        if isinstance(item, DictConfig):
            defaults.update({str(k): v for k, v in item.items()})
    lines = [
        _plain_text(textwrap.dedent(doc).strip()),
        "",
        "Config groups (group=option; * the default):",
    ]
    for name in names:
        options = sorted(f.stem for f in (conf / name).glob("*.yaml"))
        shown = [f"{o}*" if o == defaults.get(name) else o for o in options]
        if name == "experiment":
            shown.insert(0, "null*")
        lines.append(f"  {name:15s} " + ", ".join(shown))
    launchers = sorted(f.stem for f in (conf / "hydra" / "launcher").glob("*.yaml"))
    lines += [
        f"  {'hydra/launcher':15s} basic*, joblib, "
        + ", ".join([*launchers, "submitit_local"])
        + " (slurm, submitit_local: pip install -e '.[slurm]')",
        "",
        f"Root keys: {root_keys}.",
        "Any key of these that the command reads can be overridden as key=value (others",
        "are refused); print the composed config with `--cfg job` (add `--resolve` to",
        "resolve interpolations).",
        "",
        "Hydra flags: -m (sweep over comma-separated values), --cfg job|hydra|all,",
        "--hydra-help (Hydra's own help), -cd/-cn (another config folder or name).",
    ]
    return "\n".join(lines)


def refuse_conflicting_flags(argv: list[str]) -> None:
    """Exit 2 with one line when ``argv`` asks for a sweep and a config print at once (Hydra
    would end in a traceback)."""
    sweep = any(a in ("-m", "--multirun") for a in argv)
    cfg = any(a in ("-c", "--cfg") or a.startswith("--cfg=") for a in argv)
    if sweep and cfg:
        print(
            "error: --cfg prints the config of a single run; drop -m (--multirun) to see it",
            file=sys.stderr,
        )
        raise SystemExit(2)


def print_help_if_asked(
    doc: str,
    argv: list[str],
    groups: Iterable[str] | None = None,
    root_keys: str = ROOT_KEYS_HELP,
) -> None:
    """Print :func:`command_help` (of ``groups`` and ``root_keys``) and exit 0 when ``-h`` or
    ``--help`` is among ``argv``; refuse flags that cannot go together
    (:func:`refuse_conflicting_flags`)."""
    if "-h" in argv or "--help" in argv:
        print(command_help(doc, groups, root_keys))
        raise SystemExit(0)
    refuse_conflicting_flags(argv)


#: Root keys every command reads, with their types (checked before the command runs).
ROOT_KEYS: dict[str, type] = {"seed": int, "progress": bool, "device": str}

#: Path keys of conf/config.yaml that must name a path (not null or empty), checked before the
#: command runs.
PATH_KEYS = (
    "paths.datasets",
    "paths.checkpoints",
    "data.path",
    "train.out_dir",
    "evaluate.checkpoint",
)

#: Path keys of conf/config.yaml that may be null (the command then uses its default), or else
#: must name a path, checked before the command runs.
OPTIONAL_PATH_KEYS = ("evaluate.out_dir", "evaluate.logs")
#: Those of :data:`OPTIONAL_PATH_KEYS` that may also list several paths.
PATH_LIST_KEYS = ("evaluate.logs",)


def _plain(value: Any) -> Any:
    """A config value as plain Python (a list for a ListConfig), for messages."""
    if isinstance(value, (DictConfig, ListConfig)):
        return OmegaConf.to_container(value, resolve=False)
    return value


def _not_a_path_text(key: str, value: Any, several: bool = False) -> str:
    """``data.path: expected a path (a string), got 123`` (a number or a list where a path is
    expected: Hydra reads ``data.path=2024`` as the integer 2024)."""
    what = "a path (a string) or a list of paths" if several else "a path (a string)"
    text = f"{key}: expected {what}, got {_plain(value)!r}"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        text += f" (quote a path that reads as a number: {key}=\"'{value}'\")"
    return text


#: Keys of conf/config.yaml that feed a field under another name (the sweep aliases, and run
#: settings), with the range each allows (checked before the command runs, so the message
#: names the key that was typed rather than the field it feeds).
ALIAS_RANGES: dict[str, tuple[float, float, str]] = {
    "tracker.noise": (0.0, math.nextafter(MAX_NOISE_M, math.inf), f"in [0, {MAX_NOISE_M:g}] m"),
    "tracker.dropout": (0.0, 1.0, "in [0, 1)"),
    "run.scene_hz": (0.0, math.inf, ">= 0 [Hz]"),
}


def check_root_keys(cfg: DictConfig) -> None:
    """Type-check :data:`ROOT_KEYS` and range-check :data:`ALIAS_RANGES` where ``cfg`` has them;
    ``device`` must name a usable torch device (:func:`iplanner_torch.types.resolve_device`).

    Raises:
        ConfigError: naming the key, what it expects and what it got.
    """
    for key, kind in ROOT_KEYS.items():
        if key in cfg:
            cfg_scalar(cfg, key, kind)
    if "seed" in cfg:  # numpy's generators refuse negative seeds, torch's huge ones
        from iplanner_torch.checks import MAX_SEED

        if not 0 <= cfg_scalar(cfg, "seed", int) <= MAX_SEED:
            raise ConfigError(f"seed: expected an integer in [0, 2^32 - 1], got {cfg.seed}")
    absent = object()
    for key in PATH_KEYS:
        try:
            value = OmegaConf.select(cfg, key, default=absent)
        except Exception:  # noqa: BLE001 - an interpolation the command that reads it reports
            continue
        if value is not absent and (value is None or not str(value).strip()):
            got = "null" if value is None else repr(value)
            raise ConfigError(f"{key}: expected a path, got {got}")
        if value is not absent and not isinstance(value, str):
            raise ConfigError(_not_a_path_text(key, value))
    for key in OPTIONAL_PATH_KEYS:
        try:
            value = OmegaConf.select(cfg, key, default=None)
        except Exception:  # noqa: BLE001 - an interpolation the command that reads it reports
            continue
        several = key in PATH_LIST_KEYS and isinstance(value, (ListConfig, list, tuple))
        if several and not all(isinstance(v, str) for v in value):
            raise ConfigError(f"{key}: expected a list of paths (strings), got {_plain(value)!r}")
        if value is not None and not several and not isinstance(value, str):
            raise ConfigError(_not_a_path_text(key, value, key in PATH_LIST_KEYS))
    check_run_keys(cfg)
    if "device" in cfg:  # a device torch does not know, meta or mps, or CUDA where there is none
        from iplanner_torch.types import resolve_device

        try:
            resolve_device(str(cfg.device))
        except ConfigError as err:
            raise ConfigError(f"device: {err}") from err
    human = cfg.get("human")
    if isinstance(human, DictConfig) and "speed" in human:
        from iplanner_torch.sim.human import SPEED_FACTORS

        speed = human.get("speed")
        if speed not in SPEED_FACTORS:
            raise ConfigError(
                f"human.speed: expected one of {sorted(SPEED_FACTORS)}, got {speed!r}"
            )
    for dotted, (lo, hi, text) in ALIAS_RANGES.items():
        group, key = dotted.split(".")
        node = cfg.get(group)
        if not isinstance(node, DictConfig) or key not in node:
            continue
        value = cfg_scalar(node, key, float)
        if not lo <= value < hi:  # NaN and inf fail too
            raise ConfigError(f"{dotted}: expected {text}, got {value}")


def check_run_keys(cfg: DictConfig) -> None:
    """Check the ``run.*`` settings that a run may never come to read (a run of ``itomp``
    alone trains nothing, so ``run.train_if_missing`` and ``run.train_trainer`` would pass
    unseen), naming the full key: ``run.train_if_missing`` must be a bool,
    ``run.train_trainer`` a ``conf/trainer`` option, ``run.stall_fallback_s`` null or a number
    > 0 [s] (``EpisodeCfg.stall_fallback_s``), ``run.task_crossing_radius`` null or a number
    >= 0 [m], ``run.mask_by_order`` and ``run.rest_when_nothing_available`` bools,
    ``run.reaction_s`` null or a number >= 0 [s], ``run.spread_tolerance`` null or a number
    > 0.

    Raises:
        ConfigError: naming the key, what it expects and what it got.
    """
    run = cfg.get("run")
    if not isinstance(run, DictConfig):
        return
    if "train_if_missing" in run:
        cfg_scalar(run, "train_if_missing", bool)
    if "train_trainer" in run:
        option = run.train_trainer
        options = sorted(f.stem for f in (Path(CONF_DIR) / "trainer").glob("*.yaml"))
        if not isinstance(option, str) or option not in options:
            raise ConfigError(
                f"run.train_trainer: expected a trainer option ({', '.join(options)}), "
                f"got {_plain(option)!r}"
            )
    if "stall_fallback_s" in run:
        stall = run.stall_fallback_s
        if stall is not None and (not fits_kind(stall, float) or not float(stall) > 0):
            raise ConfigError(
                f"run.stall_fallback_s: expected a number > 0 [s] or null (never), got "
                f"{_plain(stall)!r}"
            )
    for key, what, zero_ok in (  # null (off) or a finite number above 0 (or 0 itself)
        ("task_crossing_radius", "a distance >= 0 [m]", True),
        ("reaction_s", "a time >= 0 [s]", True),
        ("spread_tolerance", "a number > 0 (a mean normalised squared error)", False),
    ):
        if key in run:
            value = run[key]
            number = fits_kind(value, float) and 0 <= float(value) < math.inf
            if not (value is None or (number and (zero_ok or float(value) > 0))):
                raise ConfigError(
                    f"run.{key}: expected {what} or null (off), got {_plain(value)!r}"
                )
    for key in ("mask_by_order", "rest_when_nothing_available"):
        if key in run:
            cfg_scalar(run, key, bool)


class _Tee:
    """A text stream that writes to ``stream`` and copies finished lines to ``log``.

    A carriage return starts its line over (a progress bar redrawing itself), so the log gets
    each bar's last state once rather than every redraw."""

    def __init__(self, stream: Any, log_file: Any) -> None:
        self._stream = stream
        self._log = log_file
        self._line = ""

    def write(self, text: str) -> int:
        self._stream.write(text)
        *done, self._line = (self._line + text).split("\n")
        for line in done:
            self._log.write(line.rsplit("\r", 1)[-1] + "\n")
        if done:
            self._log.flush()
        return len(text)

    def flush(self) -> None:
        self._stream.flush()
        self._log.flush()

    def close_line(self) -> None:
        """Copy an unfinished last line (the state of a bar still open) to the log."""
        if self._line.rsplit("\r", 1)[-1].strip():
            self._log.write(self._line.rsplit("\r", 1)[-1] + "\n")
        self._line = ""
        self._log.flush()

    def __getattr__(self, name: str) -> Any:  # isatty, encoding, fileno, ...
        return getattr(self._stream, name)


#: file a failed job of a multirun leaves in its folder: the error line it printed
FAILED_MARKER = "FAILED"

_MEMORY_HINT = (
    "lower planner.optimizer.num_trajectories or num_waypoints, the training batch sizes, or "
    "the sweep's parallel jobs (hydra.launcher.n_jobs); what was written before is kept"
)


#: keys a command reads when they are set, though the default config has none:
#: ``+data.fps=<Hz>`` (the frame rate of files that do not state theirs) and ``data.format``
#: (``lego_assembly``, set by conf/data/lego.yaml)
OPTIONAL_KEYS = frozenset({"data.fps", "data.format"})


def _additions(given: list[str]) -> list[tuple[str, Any]]:
    """The ``+key=value`` and ``++key=value`` overrides of ``given``, each with Hydra's parse
    of it; none when there is no ``+`` or Hydra's parser refuses them (Hydra has parsed them
    already, and says what is wrong itself)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    if not any(o.lstrip().startswith("+") for o in given):
        return []
    try:
        parsed = OverridesParser.create().parse_overrides(given)
    except Exception:  # noqa: BLE001 - see the docstring
        return []
    return [
        (text, o) for text, o in zip(given, parsed, strict=True) if o.is_add() or o.is_force_add()
    ]


def check_added_keys(cfg: DictConfig, overrides: list[str] | None = None) -> None:
    """Refuse a key that a ``+key=value`` or ``++key=value`` override adds where nothing reads
    it: at the root, or in a node the command reads key by key (``tracker``, ``human``,
    ``run``, ``paths``, ``train``, ``evaluate``, ``data``). Hydra adds such a key without a
    word, so ``+tracker.nosie=0.05`` would run with the default noise.

    A key added under a node built into a settings class (one with ``_target_``:
    ``planner.optimizer``, ``experiment.episode``, ...) is left to that class, which refuses
    fields it does not have; so are the keys of :data:`OPTIONAL_KEYS`, config group choices
    (``+experiment=speed_response``) and ``hydra.*`` (:func:`check_added_hydra_keys`).
    ``++key=value`` is refused only when the key is not in the config composed without it
    (a key that exists is overridden); when that config cannot be composed here, ``++``
    overrides are left alone.

    Args:
        cfg: the composed config.
        overrides: the command-line overrides (default: this run's, :func:`task_overrides`).

    Raises:
        ConfigError: ``unknown key 'tracker.nosie' (did you mean 'tracker.noise'?): added by
            +tracker.nosie=0.05, which nothing reads``.
    """
    given = task_overrides() if overrides is None else overrides
    added = []
    for text, override in _additions(given):
        key = override.key_or_group
        if override.package is not None:
            continue
        if key.startswith("hydra.") or key == "hydra" or "/" in key or key in OPTIONAL_KEYS:
            continue
        if "." not in key and (Path(CONF_DIR) / key).is_dir():  # a group choice
            continue
        if _under_settings_class(cfg, key):
            continue
        added.append((text, key, override.is_force_add()))
    if any(force for _, _, force in added):
        reference = _composed_without([t for t, _, force in added if force], given)
        absent = object()
        added = [
            (text, key, force)
            for text, key, force in added
            if not force
            or (
                reference is not None
                and OmegaConf.select(reference, key, default=absent) is absent
            )
        ]
    if not added:
        return
    text, key, _ = added[0]
    top = key.split(".", 1)[0]
    if "." in key and (Path(CONF_DIR) / top).is_dir() and _no_option_chosen(top):
        raise ConfigError(f"{_unchosen_group_key_text(key, top)}: added by {text}")
    prefix, _, leaf = key.rpartition(".")
    parent = OmegaConf.select(cfg, prefix, default=None) if prefix else cfg
    own = {k for _, k, _ in added}
    candidates = [
        k
        for k in _flat_keys(parent, skip=("hydra",))
        if ".".join(filter(None, (prefix, k))) not in own
    ]
    candidates += [
        k[len(prefix) + 1 :] if prefix else k for k in OPTIONAL_KEYS if k.startswith(prefix)
    ]
    best = _closest(leaf, candidates)
    hint = "" if best is None else f" (did you mean {'.'.join(filter(None, (prefix, best)))!r}?)"
    raise ConfigError(f"unknown key {key!r}{hint}: added by {text}, which nothing reads")


def check_added_hydra_keys(
    hydra_cfg: DictConfig | None = None, overrides: list[str] | None = None
) -> None:
    """Refuse a ``+hydra.<key>=value`` or ``++hydra.<key>=value`` override that adds a field
    Hydra's settings class there does not have: Hydra adds it without a word, so
    ``+hydra.launcher.n_job=2`` would run the sweep's jobs one at a time. Keys added under a
    free mapping (``hydra.job.env_set``, a launcher's ``additional_parameters``) pass.

    Args:
        hydra_cfg: Hydra's own config (default: this run's, ``HydraConfig.get()``).
        overrides: the ``hydra.*`` overrides (default: this run's ``overrides.hydra``).

    Raises:
        ConfigError: ``unknown key 'hydra.launcher.n_job' (did you mean
            'hydra.launcher.n_jobs'?): added by +hydra.launcher.n_job=2, which Hydra does
            not read``.
    """
    import dataclasses

    from hydra.core.hydra_config import HydraConfig

    if hydra_cfg is None:
        try:
            hydra_cfg = HydraConfig.get()
        except ValueError:  # outside a Hydra run (tests)
            return
    if overrides is None:  # none recorded (a config built by hand): nothing was added
        overrides = list(OmegaConf.select(hydra_cfg, "overrides.hydra", default=None) or [])
    for text, override in _additions(overrides):
        key = override.key_or_group
        if not key.startswith("hydra."):
            continue
        prefix, _, leaf = key[len("hydra.") :].rpartition(".")
        parent = OmegaConf.select(hydra_cfg, prefix, default=None) if prefix else hydra_cfg
        kind = OmegaConf.get_type(parent) if isinstance(parent, DictConfig) else None
        if kind is None or not dataclasses.is_dataclass(kind):
            continue  # a free mapping (env_set, additional_parameters) or nothing to check
        fields = [f.name for f in dataclasses.fields(kind)]
        if leaf in fields:
            continue
        best = _closest(leaf, fields)
        where = ".".join(filter(None, ("hydra", prefix)))
        hint = "" if best is None else f" (did you mean '{where}.{best}'?)"
        raise ConfigError(f"unknown key {key!r}{hint}: added by {text}, which Hydra does not read")


def _no_option_chosen(group: str) -> bool:
    """Whether this Hydra run chose no option for config group ``group`` (``experiment``
    without ``experiment=<option>``); False outside a run."""
    try:
        from hydra.core.hydra_config import HydraConfig

        choices = HydraConfig.get().runtime.choices
    except Exception:  # noqa: BLE001 - not in a Hydra run
        return False
    return group in choices and choices.get(group) is None


def _under_settings_class(cfg: DictConfig, key: str) -> bool:
    """Whether ``key`` lies under a node of ``cfg`` built into a settings class (``_target_``)."""
    node: Any = cfg
    for part in key.split(".")[:-1]:
        if not isinstance(node, DictConfig) or part not in node:
            return False
        try:
            node = node[part]
        except Exception:  # noqa: BLE001 - an interpolation that does not resolve: no class
            return False
        if isinstance(node, DictConfig) and "_target_" in node:
            return True
    return False


def _composed_without(drop: list[str], overrides: list[str]) -> DictConfig | None:
    """The config of this run composed again without the overrides in ``drop``, or None when
    it cannot be composed here (outside a Hydra run, or in a process without Hydra's state)."""
    try:
        from hydra.core.global_hydra import GlobalHydra
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hydra = GlobalHydra.instance().hydra
        if hydra is None:
            return None
        return hydra.compose_config(
            HydraConfig.get().job.config_name,
            [o for o in overrides if o not in drop],
            RunMode.RUN,
        )
    except Exception:  # noqa: BLE001 - no reference: the ++ overrides are left alone
        return None


def write_job_record(name: str, values: dict[str, Any]) -> Path | None:
    """``values`` as JSON file ``name`` in this run's own folder, which a sweep gathers into
    its summary table (:data:`~iplanner_torch.cli.callbacks.JOB_METRICS_FILES`); floats of
    other kinds (numpy, torch) are written as floats. None (nothing written) outside a Hydra
    run."""

    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None
    path = Path(HydraConfig.get().runtime.output_dir) / name
    path.write_text(json_text(values, indent=2) + "\n", encoding="utf-8")
    return path


def multirun_job_dir() -> Path | None:
    """This job's folder when it is one job of a multirun (``-m``), else None."""
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
        return Path(hc.runtime.output_dir) if hc.mode == RunMode.MULTIRUN else None
    except Exception:  # noqa: BLE001 - not in a Hydra job
        return None


def job_log_path() -> Path | None:
    """The log file Hydra gives this job (``<run folder>/<command>.log``), or None outside a
    Hydra job."""
    try:
        from hydra.core.hydra_config import HydraConfig

        hc = HydraConfig.get()
        return Path(hc.runtime.output_dir) / f"{hc.job.name}.log"
    except Exception:  # noqa: BLE001 - not in a Hydra job
        return None


#: what a single run's folder holds when the command stopped on a config error before any
#: work: Hydra's record, the command's log, the resolved config and the run's inputs
#: (experiment)
_BARE_RUN_FILES = frozenset({".hydra", "config_resolved.yaml", "run_inputs.json"})
_HYDRA_RECORD_FILES = frozenset({"config.yaml", "hydra.yaml", "overrides.yaml"})
#: a record at INFO or DEBUG level in Hydra's job log format: ``[time][logger][INFO] - ...``
_QUIET_LOG_RECORD = re.compile(r"^\[[^\]]+\]\[[^\]]+\]\[(INFO|DEBUG)\] - ")


def bare_run_dir(line: str) -> Path | None:
    """This run's folder when it may be deleted after the config error ``line``: a single
    run (not a job of a multirun) in the dated folder Hydra made for it (``hydra.run.dir``
    not given on the command line), holding nothing but :data:`_BARE_RUN_FILES`, Hydra's own
    record in ``.hydra/`` and the command's log, which holds nothing but ``line`` (the
    command printed nothing before it: no work is recorded there) and libraries' INFO or
    DEBUG logging records; else None."""
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
        if hc.mode != RunMode.RUN:
            return None
        if any(override_key(o) == "hydra.run.dir" for o in hc.overrides.hydra):
            return None
        folder = Path(hc.runtime.output_dir)
        allowed = _BARE_RUN_FILES | {f"{hc.job.name}.log"}
        names = {p.name for p in folder.iterdir()}
        log = folder / f"{hc.job.name}.log"
        if log.exists():
            # what the command printed; a library's INFO / DEBUG record through Hydra's
            # job logging (an import announcing itself) is not the command's work
            kept = [
                t
                for t in log.read_text(encoding="utf-8").splitlines()
                if t.strip() and not _QUIET_LOG_RECORD.match(t)
            ]
            if kept not in ([], [line]):
                return None
        record = folder / ".hydra"
        if not names <= allowed or (
            record.exists() and not {p.name for p in record.iterdir()} <= _HYDRA_RECORD_FILES
        ):
            return None
        return folder
    except Exception:  # noqa: BLE001 - not in a Hydra job, or the folder does not read
        return None


def delete_run_dir(folder: Path, root: Path | None = None) -> None:
    """Delete a bare run folder (:func:`bare_run_dir`), then its parents that it leaves
    empty (``outputs/<job>/``, ``outputs/``) up to, not including, ``root`` (default: the
    working directory the command was started in). Parents outside ``root`` are kept; errors
    are ignored (a folder another run has written to since is not empty)."""
    import shutil

    if root is None:
        try:
            from hydra.core.hydra_config import HydraConfig

            root = Path(HydraConfig.get().runtime.cwd)
        except Exception:  # noqa: BLE001 - not in a Hydra job
            root = Path.cwd()
    shutil.rmtree(folder, ignore_errors=True)
    root = root.resolve()
    for parent in folder.resolve().parents:
        if parent == root or root not in parent.parents:
            break
        try:
            parent.rmdir()  # only an empty folder
        except OSError:
            break


@contextlib.contextmanager
def copy_output_to(path: Path | None) -> Iterator[None]:
    """Copy what the command prints (standard output and error) into ``path`` as well.

    Progress bars keep their final state only. The file is appended to, so what Hydra's own
    logging writes there stays. ``None``: nothing is copied."""
    if path is None:
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a", encoding="utf-8") as fh:
        out, err = _Tee(sys.stdout, fh), _Tee(sys.stderr, fh)
        old = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = out, err  # type: ignore[assignment]
        try:
            yield
        finally:
            sys.stdout, sys.stderr = old
            out.close_line()
            err.close_line()


def check_composed_keys(
    cfg: DictConfig, before: Callable[[DictConfig], None] | None = None
) -> None:
    """The checks every command makes of its composed config before anything else: keys
    added with ``+`` (:func:`check_added_keys`, :func:`check_added_hydra_keys`), then
    ``before(cfg)`` when given (a command's refusal of overrides it does not read), then the
    root keys' values (:func:`check_root_keys`)."""
    check_added_keys(cfg)
    check_added_hydra_keys()
    if before is not None:
        before(cfg)
    check_root_keys(cfg)


def friendly_errors(
    fn: F | None = None,
    *,
    before: Callable[[DictConfig], None] | None = None,
    kept: Callable[[DictConfig], str] | None = None,
) -> Any:
    """Turn library errors, and the operating system's (``OSError``: a path that is a file
    where a folder is expected, no permission, a full disk), into a one-line message and exit
    code 2 instead of a traceback.

    Used as ``@friendly_errors``, or ``@friendly_errors(before=check)`` to run ``check(cfg)``
    before the root keys are checked: a command's refusal of the overrides it does not read
    (``iplanner-train device=cuda``) then comes before a complaint about their values (no
    CUDA here), which would not matter to it.

    In one job of a multirun the job ends with that line instead, leaving a
    :data:`FAILED_MARKER` file in its folder, so the sweep's other jobs still run; the sweep
    lists the failed jobs at its end and exits 2. Running out of memory is a one-line error
    too, with what to lower. An exception raised while an interrupt was being handled (say by
    Lightning's teardown of a fit cut by Ctrl-C) is reported as that interrupt (exit 130).
    An unexpected exception (a bug) keeps its traceback outside a
    multirun (Hydra prints it, exit 1); in one job of a multirun it ends that job like a
    library error, its traceback kept in the ``FAILED`` file and the job's log
    (:func:`_record_unexpected_error`), since Hydra would otherwise stop the sweep with it,
    before the summary.

    The root keys are checked first (:func:`check_root_keys`), so ``seed=abc`` or
    ``tracker.noise=-1`` is named as such rather than where it is interpolated. A YAML file
    the command reads itself that does not parse is a config error too
    (:func:`yaml_error_text`). Inside a Hydra job, what the command prints, the error line
    included, is also written to the job's log file (:func:`copy_output_to`).

    An interrupted command (Ctrl-C, or SIGTERM: :func:`_terminate_as_interrupt`) prints one
    ``interrupted: ...`` line and exits 130, also when the signal lands inside a Lightning fit,
    which ends the process with its own ``SystemExit(1)`` (:func:`_exit_after_interrupt`).
    ``kept(cfg)`` says what the command keeps then (default: :func:`_kept_episodes`)."""

    if fn is None:
        return functools.partial(friendly_errors, before=before, kept=kept)

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        _task_started()
        one_line_warnings()  # also in the processes of a parallel sweep's jobs
        _clear_failed_marker()
        bare: list[Path] = []  # the run folder to delete once its log is closed
        try:
            return _guarded(args, kwargs, bare)
        finally:
            if bare:
                delete_run_dir(bare[0])

    def _guarded(args: tuple, kwargs: dict, bare: list[Path]) -> Any:
        log_path = job_log_path()
        with copy_output_to(log_path), _terminate_as_interrupt():
            try:
                if args and isinstance(args[0], DictConfig):
                    check_composed_keys(args[0], before)
                return fn(*args, **kwargs)
            except (IPlannerError, OSError, YAMLError) as exc:  # OSError: a path that is a file
                line = (
                    f"error: ConfigError: {yaml_error_text(exc)}"
                    if isinstance(exc, YAMLError)
                    else f"error: {type(exc).__name__}: {exc}"
                )
                print(line, file=sys.stderr)
                if isinstance(exc, ConfigError | YAMLError):
                    # a config error before any work leaves no dated folder behind; an
                    # unfinished line (a progress bar: work) reaches the log first
                    for stream in (sys.stdout, sys.stderr):
                        close = getattr(stream, "close_line", None)
                        if callable(close):
                            close()
                    folder = bare_run_dir(line)
                    if folder is not None:
                        bare.append(folder)
                _end_job(line)
                return None
            except (MemoryError, RuntimeError) as exc:  # torch's allocators: RuntimeError
                if _in_chain(exc.__context__, KeyboardInterrupt) is not None:
                    # raised while an interrupt was handled (Lightning's teardown of a fit
                    # cut by Ctrl-C or SIGTERM): the interrupt is what happened
                    _report_interrupt(args, kept, log_path)
                    raise SystemExit(130) from None
                text = str(exc).strip()
                if not isinstance(exc, MemoryError) and not (
                    "out of memory" in text or "can't allocate memory" in text
                ):
                    if _record_unexpected_error(exc, log_path):
                        return None
                    raise
                first = text.splitlines()[0][:200] if text else type(exc).__name__
                line = f"error: out of memory ({first}); {_MEMORY_HINT}"
                print(line, file=sys.stderr)
                _end_job(line)
                return None
            except KeyboardInterrupt:
                _report_interrupt(args, kept, log_path)
                raise SystemExit(130) from None
            except SystemExit as exc:  # Lightning ends an interrupted fit with SystemExit(1)
                if not _exit_after_interrupt(exc):
                    raise
                _report_interrupt(args, kept, log_path)
                raise SystemExit(130) from None
            except Exception as exc:  # a bug; outside a multirun Hydra prints its traceback
                if _in_chain(exc.__context__, KeyboardInterrupt) is not None:
                    _report_interrupt(args, kept, log_path)  # raised while one was handled
                    raise SystemExit(130) from None
                if _record_unexpected_error(exc, log_path):
                    return None
                raise

    return wrapper  # type: ignore[return-value]


def _end_job(line: str) -> None:
    """End the command on its error ``line`` (printed already): exit 2, or in one job of a
    multirun leave the line in the job's :data:`FAILED_MARKER` file and return, so the
    sweep's other jobs still run; the sweep names the failed jobs when it ends and exits 2
    (:class:`~iplanner_torch.cli.callbacks.GatherSweepResults`)."""
    job_dir = multirun_job_dir()
    if job_dir is None:
        raise SystemExit(2) from None
    (job_dir / FAILED_MARKER).write_text(line + "\n", encoding="utf-8")


def _record_unexpected_error(exc: BaseException, log_path: Path | None) -> bool:
    """In one job of a multirun, end the job on ``exc``, an exception that is none of the
    library's (a bug): print one ``error: ...`` line naming the job and where its traceback
    is, and write that line, then the traceback, into the job's :data:`FAILED_MARKER` file;
    the traceback goes to the job's log (``log_path``) too, not to the console. Hydra's
    sweeper would raise it again once the jobs ran, which ends the sweep before its summary
    and its list of failed jobs.

    Returns:
        Whether it was recorded: False outside a multirun, where the caller raises it again
        and Hydra prints its traceback as usual.
    """
    import traceback

    job_dir = multirun_job_dir()
    if job_dir is None:
        return False
    marker = job_dir / FAILED_MARKER
    trace = "".join(traceback.format_exception(exc))
    message = _one_line(str(exc))
    line = (
        f"error: {type(exc).__name__}{': ' + message if message else ''} (unexpected: job "
        f"{job_dir} stopped, traceback in {marker})"
    )
    print(line, file=sys.stderr, flush=True)
    marker.write_text(f"{line}\n{trace}", encoding="utf-8")
    if log_path is not None:
        with contextlib.suppress(OSError), log_path.open("a", encoding="utf-8") as fh:
            fh.write(trace)
    return True


def _clear_failed_marker() -> None:
    """Remove the :data:`FAILED_MARKER` an earlier run of this multirun job left in its
    folder (a sweep run again into the same ``hydra.sweep.dir``), so that the sweep reports
    only the errors of this run; outside a multirun, nothing."""
    job_dir = multirun_job_dir()
    if job_dir is not None:
        (job_dir / FAILED_MARKER).unlink(missing_ok=True)


def _exit_after_interrupt(exc: SystemExit) -> bool:
    """Whether ``exc`` ends the process with an error code because of an interrupt: it was
    raised while a KeyboardInterrupt was being handled (its ``__context__`` chain holds one).

    Lightning's ``Trainer.fit`` catches the KeyboardInterrupt of Ctrl-C (and of SIGTERM,
    :func:`_terminate_as_interrupt`), marks the trainer interrupted, tears it down and calls
    ``sys.exit(1)`` inside its ``except KeyboardInterrupt`` block, so the interrupt is that
    SystemExit's context; its log line says so at INFO, which the training silences."""
    if exc.code in (None, 0):
        return False
    return _in_chain(exc.__context__, KeyboardInterrupt) is not None


def _in_chain(link: BaseException | None, kind: type[_E]) -> _E | None:
    """The first exception of type ``kind`` along the chain from ``link`` (``link`` itself,
    then each one's ``__cause__`` or else ``__context__``), or None; a chain that loops back
    on itself ends there."""
    seen: set[int] = set()
    while link is not None and id(link) not in seen:
        if isinstance(link, kind):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


def _kept_episodes(log_path: Path | None) -> str:
    """What an interrupted experiment keeps: its run folder's finished episodes and the
    interrupted episode's log."""
    where = f" in {log_path.parent}" if log_path is not None else ""
    return (
        f"what was written before is kept{where} (finished episodes in results.csv, the "
        "interrupted episode's log up to where it stopped); the same command with "
        "run.resume=true and that hydra.run.dir goes on from there"
    )


def _report_interrupt(
    args: tuple[Any, ...],
    kept: Callable[[DictConfig], str] | None,
    log_path: Path | None,
) -> None:
    """Print the ``interrupted: ...`` line of :func:`friendly_errors`: ``kept(cfg)``, or the
    experiment's text when there is no ``kept`` or it cannot say (a config it cannot read)."""
    cfg = args[0] if args and isinstance(args[0], DictConfig) else None
    text = None
    if kept is not None and cfg is not None:
        try:
            text = kept(cfg)
        except Exception:  # noqa: BLE001 - the interrupt is reported in any case
            text = None
    print(f"interrupted: {text or _kept_episodes(log_path)}", file=sys.stderr)


#: Hydra's switch that makes it raise the errors it meets rather than print them and exit 1
_HYDRA_RAISES = "HYDRA_FULL_ERROR"
#: set in the environment with :data:`_HYDRA_RAISES` by :func:`run_app` while Hydra composes
#: the config, so that the task function unsets both, also in a launcher's worker process
#: (joblib), which inherits them; still set when an error comes: a composition error
_SET_BY_RUN_APP = "IPLANNER_TORCH_COMPOSING"


def one_line_warnings() -> None:
    """Show the project's own warnings (``DataWarning``, ``ConfigWarning``,
    ``NumericalWarning``, ``PlanningOverrunWarning``) as one ``warning: DataWarning: ...``
    line, without the file and source line Python adds (which would point into the package,
    not at the user's input); other libraries' warnings keep Python's format. Idempotent."""
    import warnings

    shown = warnings.formatwarning
    if getattr(shown, "_iplanner_one_line", False):
        return

    def formatwarning(message, category, filename, lineno, line=None):  # type: ignore[no-untyped-def]
        if getattr(category, "__module__", "").startswith("iplanner_torch."):
            return f"warning: {category.__name__}: {message}\n"
        return shown(message, category, filename, lineno, line)

    formatwarning._iplanner_one_line = True  # type: ignore[attr-defined]
    warnings.formatwarning = formatwarning


def run_app(app: Callable[[], Any]) -> None:
    """Run a ``@hydra.main`` app so that what is wrong in the config Hydra composes (a
    malformed YAML file, a misspelt key, an unknown option, an override it cannot parse)
    prints one line and exits 2, as the command's own config errors do
    (:func:`composition_error_text`); so does an operating system error before the command
    starts (a run folder that cannot be made, or a log file in it that cannot be opened,
    which Python's logging reports as a ValueError: :func:`_os_error_of`).

    Hydra itself prints these and exits 1, a YAML error as a long traceback. Until the task
    function starts (:func:`friendly_errors` ends it), ``HYDRA_FULL_ERROR=1`` makes it raise
    them here instead; an unexpected error inside the command is reported by Hydra as usual.
    When the environment sets ``HYDRA_FULL_ERROR=1`` already, Hydra's full traceback is what
    was asked for, and is left as it is."""
    import os

    one_line_warnings()
    if os.environ.get(_HYDRA_RAISES) == "1":
        app()
        return
    os.environ[_HYDRA_RAISES] = "1"
    os.environ[_SET_BY_RUN_APP] = "1"
    try:
        app()
    except Exception as exc:  # noqa: BLE001 - what is not a config error is raised again
        if _SET_BY_RUN_APP not in os.environ:  # raised by the command after it started
            raise
        text = composition_error_text(exc)
        if text is None and (text := _launcher_error_text(exc)) is not None:
            from iplanner_torch.cli.callbacks import drop_unlaunched_sweep

            drop_unlaunched_sweep()  # no job ran: no dated sweep folder is left behind
        os_error = _os_error_of(exc)
        if text is not None:
            line = f"error: ConfigError: {text}"
        elif os_error is not None:
            line = f"error: {type(os_error).__name__}: {os_error}"
        else:
            raise
        print(line, file=sys.stderr)
        raise SystemExit(2) from None
    finally:
        _task_started()


def _launcher_error_text(exc: BaseException) -> str | None:
    """What stops a sweep's launcher before its first job, in one line, or None: submitit's
    SLURM executor raises ``RuntimeError: Could not detect "srun"`` on a machine that is not a
    SLURM cluster (``hydra/launcher=slurm`` where no ``srun`` is on the PATH)."""
    if isinstance(exc, RuntimeError) and 'Could not detect "srun"' in str(exc):
        return (
            "hydra/launcher=slurm submits jobs to a SLURM cluster, but no `srun` is on the "
            "PATH here (not a SLURM login node?); run it where SLURM is, or use "
            "hydra/launcher=joblib to run the jobs on this machine"
        )
    return None


def _os_error_of(exc: BaseException) -> OSError | None:
    """``exc`` when it is an OSError; the OSError behind a ValueError (its ``__cause__`` or
    ``__context__`` chain), as Python's logging raises ``ValueError: Unable to configure
    handler 'file'`` when Hydra cannot open the run's log file (a run folder that is not
    writable); else None."""
    if isinstance(exc, OSError):
        return exc
    if not isinstance(exc, ValueError):
        return None
    return _in_chain(exc.__cause__ or exc.__context__, OSError)


def _task_started() -> None:
    """Give Hydra back its own report of errors: the command's task function has started."""
    import os

    if os.environ.pop(_SET_BY_RUN_APP, None) is not None:
        os.environ.pop(_HYDRA_RAISES, None)


def yaml_error_text(err: BaseException) -> str:
    """What is wrong in a YAML file, in one line: ``conf/robot/mine.yaml: malformed YAML at
    line 2, column 1: expected ',' or ']', but got '<stream end>' (while parsing a flow
    sequence from line 1, column 16)``."""
    from yaml import MarkedYAMLError

    if not isinstance(err, MarkedYAMLError):
        return "malformed YAML: " + " ".join(str(err).split())
    mark = err.problem_mark or err.context_mark
    text = f"{mark.name if mark is not None else 'a YAML file'}: malformed YAML"
    if mark is not None:
        text += f" at line {mark.line + 1}, column {mark.column + 1}"
    text += f": {err.problem or err.context or 'cannot be read'}"
    if err.problem and err.context:
        start = err.context_mark
        if start is not None and (start.line, start.column) != (mark.line, mark.column):
            text += f" ({err.context} from line {start.line + 1}, column {start.column + 1})"
        else:
            text += f" ({err.context})"
    return text


def composition_error_text(exc: BaseException) -> str | None:
    """The one-line message for an error Hydra raised while composing the config, or None when
    ``exc`` is not one.

    A YAML file that does not parse is named with the line and column of the problem
    (:func:`yaml_error_text`); a key that is not in the config is named in full, with the
    closest key there is (:func:`unknown_key_text`); an unknown group option lists the
    group's options; the rest is Hydra's own message on one line."""
    from hydra.errors import (
        ConfigCompositionException,
        MissingConfigException,
        OverrideParseException,
        SearchPathException,
    )

    yaml_error = _in_chain(exc, YAMLError)
    if yaml_error is not None:
        return yaml_error_text(yaml_error)
    if isinstance(exc, OverrideParseException):
        reason, _, rest = exc.message.partition("\n")
        see = re.search(r"https?://\S+", rest)
        return f"cannot parse override {exc.override!r}: {reason.strip()}" + (
            f" (see {see.group(0)})" if see else ""
        )
    if isinstance(exc, MissingConfigException):
        return _missing_option_text(exc)
    if not isinstance(exc, (ConfigCompositionException, SearchPathException)):
        return None
    unknown = unknown_key_text(exc)
    if unknown is not None:
        return unknown
    text = _one_line(str(exc)) or _one_line(str(exc.__cause__ or ""))
    found = re.match(r"In '([^']+)': ", text)
    if found and "with ListConfig" in text:  # a @package _global_ file holding a list
        return (
            f"config file {found.group(1)}.yaml: its top level is a list, not a mapping of keys "
            "to values ('key: value' lines)"
        )
    return text or type(exc).__name__


def _one_line(text: str) -> str:
    """Hydra's (and OmegaConf's) message on one line, without the config search path and
    OmegaConf's ``full_key:`` and ``object_type=`` lines."""
    skip = ("full_key:", "object_type=", "Config search path", "provider=")
    lines = [s for line in text.splitlines() if (s := line.strip()) and not s.startswith(skip)]
    return " ".join(lines)


#: Hydra launcher configs of plugins that are optional extras: the plugin and how to install it
PLUGIN_LAUNCHERS = {
    "submitit_slurm": ("hydra-submitit-launcher", 'pip install -e ".[slurm]"'),
    "submitit_local": ("hydra-submitit-launcher", 'pip install -e ".[slurm]"'),
    "joblib": ("hydra-joblib-launcher", "pip install -e ."),
}


def _launcher_option(exc: Any) -> str | None:
    """The ``conf/hydra/launcher`` option whose defaults name a missing plugin config
    (``slurm`` for ``In 'hydra/launcher/slurm': Could not load ...``), or None."""
    found = re.match(r"In 'hydra/launcher/([^']+)': ", str(exc))
    return found.group(1) if found else None


def _missing_option_text(exc: Any) -> str:
    """``unknown option robot=nope (robot options: fetch, kuka_iiwa14)``, or Hydra's message
    on one line when the missing config is not a group option."""
    missing = str(exc.missing_cfg_file or "")
    group, _, option = missing.rpartition("/")
    if group == "hydra/launcher" and option in PLUGIN_LAUNCHERS:
        plugin, install = PLUGIN_LAUNCHERS[option]
        return (
            f"hydra/launcher={_launcher_option(exc) or option} needs the Hydra plugin {plugin}, "
            f"which is not installed: {install}"
        )
    if not group or exc.options is None:
        return _one_line(str(exc)) or f"config not found: {missing}"
    found = re.match(r"In '([^']+)': ", str(exc))
    named_in = f" (named in {found.group(1)})" if found and "/" in found.group(1) else ""
    options = ", ".join(exc.options) if exc.options else "none"
    return f"unknown option {group}={option}{named_in}; {group} options: {options}"


def unknown_key_text(exc: BaseException) -> str | None:
    """``unknown key 'run.max_duraton_s' (did you mean 'run.max_duration_s'?)`` for Hydra's
    refusal of an override whose key is not in the config (OmegaConf names only the first
    part that is missing: ``Key 'experiment' is not in struct``), or None for another error.

    The suggestion is the closest key (:mod:`difflib`) under the part of the key that exists.
    A key of a config group that no option is chosen for (``experiment.*`` without
    ``experiment=<option>``) is looked up in the group's options, which are named."""
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError

    found = re.match(r"Could not override '([^']+)'", str(exc))
    cause = exc.__cause__
    if found is None or not isinstance(cause, (ConfigAttributeError, ConfigKeyError)):
        return None
    key = found.group(1)
    if key in OPTIONAL_KEYS:  # read when set, absent from the default config
        return (
            f"key {key!r} is not in this config (it is read when set): add it with +{key}=<value>"
        )
    missing = str(getattr(cause, "full_key", "") or "")
    if not missing or not (key == missing or key.startswith(missing + ".")):
        return f"unknown key {key!r}"
    entry = re.match(r"planner\.per_kind\.([^.]+)$", missing)
    if entry is not None:  # a planner without an entry (PlannerCfg.per_kind)
        return (
            f"unknown key {key!r}: planner.per_kind has no entry for {entry.group(1)!r}; "
            f"add the setting with +{key}=<value>"
        )
    if "." not in missing and (Path(CONF_DIR) / missing).is_dir():
        return _unchosen_group_key_text(key, missing)
    prefix = missing.rpartition(".")[0]
    parent = getattr(cause, "parent_node", None)
    candidates = _flat_keys(parent, skip=() if key.startswith("hydra.") else ("hydra",))
    if not prefix:
        candidates += _group_names()
    best = _closest(key[len(prefix) + 1 :] if prefix else key, candidates)
    if best is None:
        return f"unknown key {key!r} (print the config with --cfg job to see its keys)"
    return f"unknown key {key!r} (did you mean {'.'.join(filter(None, (prefix, best)))!r}?)"


def _unchosen_group_key_text(key: str, group: str) -> str:
    """A key under config group ``group`` that has no option chosen: its options that hold
    the key (or the closest), to choose one of."""
    options: dict[str, list[str]] = {}
    for path in sorted((Path(CONF_DIR) / group).glob("*.yaml")):
        try:
            node = OmegaConf.load(path)
        except Exception:  # noqa: BLE001 - a file that does not load suggests nothing
            continue
        header = re.search(r"^#\s*@package\s+(\S+)", path.read_text(encoding="utf-8"), re.M)
        package = header.group(1) if header else group
        keys = _flat_keys(node, skip=("defaults",))
        if package != "_global_":
            keys = [f"{package}.{k}" for k in keys]
        options[path.stem] = keys
    if key in {k for keys in options.values() for k in keys}:
        having = [name for name, keys in options.items() if key in keys]
        return (
            f"key {key!r} needs {group}=<option> ({', '.join(having)}): with {group}=null "
            f"there is no {group} node"
        )
    start = group + "."
    inside = [k[len(start) :] for keys in options.values() for k in keys if k.startswith(start)]
    best = _closest(key[len(start) :], inside) if key.startswith(start) else None
    best = None if best is None else start + best
    if best is None:
        names = ", ".join(options) or "none"
        return f"unknown key {key!r} ({group}.* keys need {group}=<option>: {names})"
    having = [name for name, keys in options.items() if best in keys]
    return (
        f"unknown key {key!r} (did you mean {best!r}? it needs {group}=<option>: "
        f"{', '.join(having)})"
    )


def _flat_keys(node: Any, skip: Iterable[str] = ()) -> list[str]:
    """Every dotted key under ``node`` (its nodes and their values), relative to it, leaving
    out the top keys in ``skip``; interpolations are not resolved."""
    if not isinstance(node, DictConfig):
        return []
    try:
        tree = OmegaConf.to_container(node, resolve=False)
    except Exception:  # noqa: BLE001 - a node OmegaConf cannot convert suggests nothing
        return []
    out: list[str] = []

    def walk(value: Any, prefix: str) -> None:
        for k, v in value.items():
            key = f"{prefix}{k}"
            out.append(key)
            if isinstance(v, dict):
                walk(v, key + ".")

    walk({k: v for k, v in tree.items() if k not in set(skip)}, "")
    return out


def _group_names() -> list[str]:
    """The config groups of ``conf/`` (``data``, ``experiment``, ...)."""
    conf = Path(CONF_DIR)
    return sorted(d.name for d in conf.iterdir() if d.is_dir() and d.name != "hydra")


def _closest(key: str, candidates: list[str], cutoff: float = 0.75) -> str | None:
    """The candidate closest to ``key`` (:func:`difflib.get_close_matches` at ``cutoff``),
    among those as deep as ``key`` when there are any; None when none is close."""
    import difflib

    depth = key.count(".")
    same = [c for c in candidates if c.count(".") == depth]
    matches = difflib.get_close_matches(key, same or candidates, n=1, cutoff=cutoff)
    return matches[0] if matches else None


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """Handle SIGTERM (a cluster's stop, ``kill``) like Ctrl-C while the command runs, so
    open logs are closed with what they hold; nothing changes outside the main thread.

    An interrupt that lands while a finalizer runs (a ``__del__``, whose exceptions Python
    prints and ignores: Lightning's profiler has one, run whenever the garbage collector
    frees a finished trainer) would be lost, and the command would go on; it is raised again
    in the main thread an instant later instead (:data:`sys.unraisablehook`)."""
    import _thread
    import signal
    import threading

    def _raise(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, _raise)
    except ValueError:  # not the main thread
        yield
        return
    previous_hook = sys.unraisablehook
    timers: list[threading.Timer] = []

    def _hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            # from another thread, once the finalizer is over (if the main thread is in one
            # again then, this comes back here)
            timer = threading.Timer(0.01, _thread.interrupt_main)
            timer.daemon = True
            timers.append(timer)
            timer.start()
            return
        previous_hook(unraisable)

    sys.unraisablehook = _hook
    try:
        yield
    finally:
        sys.unraisablehook = previous_hook
        for timer in timers:
            timer.cancel()
        signal.signal(signal.SIGTERM, previous)


def dump_config(cfg: DictConfig) -> str:
    """The resolved config as YAML (for logs and reports)."""
    return OmegaConf.to_yaml(cfg, resolve=True)


#: frame rate of a LEGO assembly recording when ``data.fps`` does not say
LEGO_FPS = 30.0

#: the keys a ``data`` node may hold (conf/data/*.yaml, ``+data.fps``, ``+data.format``): the
#: commands read them key by key, so any other key (``fsp: 60.0``) would be ignored
DATA_KEYS = ("path", "format", "fps", "split", "overwrite", "generator", "windows")


def check_data_keys(data_cfg: DictConfig) -> None:
    """Refuse a key of a ``data`` node that no command reads (not in :data:`DATA_KEYS`): a
    misspelt ``fsp: 60.0`` in a ``conf/data`` file would otherwise leave ``data.fps`` at its
    default without a word, where every other config group refuses an unknown key.

    Raises:
        ConfigError: naming the key (with the closest known one, and the ``data`` option
            when this run chose one) and listing the known keys.
    """
    unknown = [str(k) for k in data_cfg if str(k) not in DATA_KEYS]
    if not unknown:
        return
    key = unknown[0]
    # a lower cutoff than for dotted keys: the data keys are short (fsp for fps is 0.67)
    close = _closest(key, list(DATA_KEYS), cutoff=0.6)
    hint = f" (did you mean 'data.{close}'?)" if close else ""
    choice = _group_choice("data") if _full_key(data_cfg, None) == "data" else None
    where = f" (data={choice})" if choice is not None else ""
    raise ConfigError(
        f"unknown key 'data.{key}'{hint} in the data config{where}, which nothing reads; "
        f"data keys: {', '.join(DATA_KEYS)}"
    )


def data_fps(data_cfg: DictConfig) -> float | None:
    """``data.fps`` (the frame rate of files that do not state theirs), or None when unset.

    Raises:
        ConfigError: when it is not a finite number > 0, or the node holds a key no command
            reads (:func:`check_data_keys`).
    """
    check_data_keys(data_cfg)
    fps = data_cfg.get("fps", None)
    if fps is None:
        return None
    if not fits_kind(fps, float) or not 0 < float(fps) < math.inf:
        raise ConfigError(f"data.fps: expected a frame rate > 0 [Hz], got {fps!r}")
    return float(fps)


#: values of ``data.format``: demonstration files (``.npz``, ``.csv``; the default, also when
#: the key is absent) or the LEGO assembly recording's trial ``.txt`` files (conf/data/lego.yaml)
DATA_FORMATS = ("native", "lego_assembly")


def data_format(data_cfg: DictConfig) -> str:
    """``data.format``: ``native`` when unset (or null), else one of :data:`DATA_FORMATS`.

    Raises:
        ConfigError: for any other value (``+data.format=lego`` was read as ``native``), or
            when the node holds a key no command reads (:func:`check_data_keys`).
    """
    check_data_keys(data_cfg)
    fmt = data_cfg.get("format", None)
    if fmt is None:
        return "native"
    if not isinstance(fmt, str) or fmt not in DATA_FORMATS:
        raise ConfigError(
            f"data.format: expected one of {', '.join(DATA_FORMATS)}, got {fmt!r} (native: "
            ".npz / .csv demonstration files; lego_assembly: the LEGO assembly recording's "
            "trial .txt files, as data=lego sets it)"
        )
    return fmt


def data_joints(data_cfg: DictConfig) -> tuple[str, ...] | None:
    """The joints ``data.windows.joints`` selects (None: every joint), checked by
    :class:`~iplanner_torch.data.windows.WindowCfg` as training checks them.

    Raises:
        ConfigError: naming ``data.windows.joints`` for a single string (``right_hand``, not
            ``[right_hand]``), an empty list or a name given twice.
    """
    from iplanner_torch.data.windows import WindowCfg

    windows = data_cfg.get("windows", None)
    joints = windows.get("joints", None) if isinstance(windows, DictConfig) else None
    if OmegaConf.is_config(joints):
        joints = OmegaConf.to_container(joints)
    try:
        return WindowCfg(joints=joints).joints
    except ConfigError as err:  # "joints: ..." -> "data.windows.joints: ...", as instantiate
        text = str(err).removeprefix("joints: ")
        raise ConfigError(f"data.windows.joints: {text}") from None


def data_settings(data_cfg: DictConfig) -> tuple[str, float | None, tuple[str, ...] | None]:
    """The settings every format reads, checked before anything is read or generated:
    ``(data.format, data.fps, data.windows.joints)`` (:func:`data_format`, :func:`data_fps`,
    :func:`data_joints`).

    Raises:
        ConfigError: naming the key of the first that is wrong.
    """
    return data_format(data_cfg), data_fps(data_cfg), data_joints(data_cfg)


def read_demonstrations(data_cfg: DictConfig, path: Path) -> list[Any]:
    """The demonstrations at ``path`` as ``data.format`` reads them, each holding the joints
    ``data.windows.joints`` selects: every command reads a dataset through here.

    Args:
        data_cfg: the ``data`` node (``format``, ``fps``, ``windows.joints``, ``path`` as
            typed, for messages).
        path: its folder (or file), resolved.

    Raises:
        ConfigError: from :func:`data_settings`.
        DataError: from the loaders; for a LEGO recording, a selected joint it lacks. A
            folder with no demonstration files but ``.txt`` files says how to read them as
            the LEGO recording.
    """
    from iplanner_torch.data.io import load_demonstrations, load_lego_assembly
    from iplanner_torch.errors import DataError

    fmt, fps, joints = data_settings(data_cfg)
    if fmt == "lego_assembly":
        demos = load_lego_assembly(path, fps=LEGO_FPS if fps is None else fps)
        return _select_recorded_joints(demos, joints, path)
    try:
        return load_demonstrations(path, fps=fps, joints=joints)
    except DataError as err:
        hint = _trial_files_hint(path, data_cfg.path)
        if hint is None:
            raise
        raise DataError(f"{err}; {hint}") from None


def _select_recorded_joints(
    demos: list[Any], joints: tuple[str, ...] | None, path: Path
) -> list[Any]:
    """``demos`` (a LEGO recording's trials) holding only ``joints`` (all when None), as
    :func:`~iplanner_torch.data.io.load_demonstrations` selects them from native files.

    Raises:
        DataError: for a joint the recording lacks, or a trial in which every selected joint
            is NaN in every frame.
    """
    from iplanner_torch.data.io import lost_joints
    from iplanner_torch.errors import DataError

    if not joints or not demos:
        return demos
    have = demos[0].joint_names
    missing = [j for j in joints if j not in have]
    if missing:
        raise DataError(
            f"{path}: data.windows.joints names {missing}, which the LEGO assembly recording "
            f"lacks; its joints: {list(have)}"
        )
    out = [d.select_joints(joints) for d in demos]
    for d in out:
        if len(lost_joints(d)) == d.num_joints:
            raise DataError(
                f"{path}: trial {d.name}: every selected joint {list(joints)} is NaN in every "
                "frame: nothing observed to learn from"
            )
    return out


def _trial_files_hint(path: Path, typed: Any) -> str | None:
    """For a folder without demonstration files that holds ``.txt`` files (the LEGO recording
    read as native files): how to read it as the recording; None otherwise."""
    from iplanner_torch.data.io import demonstration_files
    from iplanner_torch.errors import DataError

    if not path.is_dir():
        return None
    try:
        if demonstration_files(path):
            return None
    except DataError:  # an unfinished generation's folder: its own message says it
        return None
    n = sum(1 for p in path.rglob("*.txt") if p.is_file())
    if not n:
        return None
    files = "1 .txt file" if n == 1 else f"{n} .txt files"
    return f"it holds {files}: for LEGO-assembly trials use data=lego data.path={typed}"


def _command_line_path(data_cfg: DictConfig) -> bool:
    """Whether ``data_cfg`` is this run's ``data`` node and the command line sets its path
    (``data.path=...``, ``++data.path=...``) to a folder outside ``paths.datasets``; not the
    datasets a command picks itself (``iplanner-experiment``'s task sets), nor a folder in
    the generated-data home (``data.path=datasets/tasks_1x4_...``, as the README trains one)."""
    if _full_key(data_cfg, None) != "data":
        return False
    given = (o for o in task_overrides() if not o.startswith("~"))
    if not any(override_key(o) == "data.path" for o in given):
        return False
    home = OmegaConf.select(data_cfg._get_root(), "paths.datasets", default=None)
    if isinstance(home, str) and repo_path(data_cfg.path).is_relative_to(repo_path(home)):
        return False
    return True


def shell_word(word: str) -> str:
    """``word`` quoted for a POSIX shell so that pasting it gives the program ``word`` again:
    as it is when nothing needs quoting, in double quotes when that is enough (an override
    such as ``"data.generator.order='(0,1)->(2,3)'"`` reads as typed), else in single quotes."""
    import shlex

    if shlex.quote(word) == word or re.search(r'["$`\\!]', word):
        return shlex.quote(word)
    return f'"{word}"'


def override_word(key: str, value: Any) -> str:
    """``key=value`` as an override that Hydra reads back as ``value`` (a string value that
    Hydra would take for a number, a bool, null, a list or a sweep, such as the folder
    ``2024``, is put in Hydra's quotes) and the shell passes as one word (:func:`shell_word`):
    for the commands that hints and records suggest."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    text = str(value)
    if isinstance(value, str | Path):
        try:
            parsed = OverridesParser.create().parse_overrides([f"{key}={text}"])[0].value()
        except Exception:  # noqa: BLE001 - a value Hydra does not parse bare
            parsed = None
        if parsed != text:
            # Hydra's quoted strings: \' is a quote; backslashes before one, or before the
            # closing quote, are doubled; others are literal
            text = re.sub(r"(\\+)(?='|$)", lambda m: m.group(1) * 2, text)
            text = "'" + text.replace("'", "\\'") + "'"
    return shell_word(f"{key}={text}")


def shell_command(*words: str) -> str:
    """A command line that a POSIX shell splits back into ``words`` (see :func:`shell_word`);
    for the "run with" / "regenerate with" lines the commands write into their records."""
    return " ".join(shell_word(w) for w in words)


def _generate_command(data_cfg: DictConfig) -> str:
    """The ``iplanner-data generate`` command that writes the dataset this run's command line
    asks for: its ``data=<option>`` and ``data.generator.*`` overrides, and ``data.path``."""
    given = [
        shell_word(o)
        for o in task_overrides()
        if not o.startswith("~")
        and (override_key(o) == "data" or override_key(o).startswith("data.generator."))
    ]
    return " ".join(["iplanner-data generate", *given, override_word("data.path", data_cfg.path)])


def load_dataset(
    data_cfg: DictConfig,
    *,
    generate_if_missing: bool = False,
    progress: bool = True,
    overridden: set[str] | None = None,
) -> list[Any]:
    """Load the demonstrations a ``data`` config node describes (:func:`read_demonstrations`).

    Args:
        data_cfg: the ``data`` node (``path``, optional ``format``, ``fps``, ``generator``,
            ``windows``).
        generate_if_missing: generate the dataset with its generator when the folder is absent
            or empty, unless the command line gives that folder (``data.path=...``) outside
            ``paths.datasets``: a mistyped path to one's own data must not become a
            synthetic dataset.
        progress: progress bars.
        overridden: the ``data.generator`` fields compared with an existing generated
            dataset's card (default: those this run's command line sets; see
            :func:`_check_generator_settings`).

    Returns:
        The list of :class:`~iplanner_torch.data.demonstration.Demonstration`.

    Raises:
        DataError: when the folder is absent (or empty) and cannot (or may not) be
            generated.
        ConfigError: when a generated folder's card keeps other generator settings than the
            command line gives, for a ``data.format`` other than :data:`DATA_FORMATS`, or a
            ``data.windows.joints`` that is not a list of unique names (a single string).

    A generated folder whose files no longer add up to the demonstration and frame counts its
    card records (files removed or added by hand) is read as it is, with a
    :class:`~iplanner_torch.errors.DataWarning`.
    """
    from iplanner_torch.errors import DataError

    path = repo_path(data_cfg.path)
    fmt, _, _ = data_settings(data_cfg)  # before anything is generated
    if fmt == "lego_assembly":
        return read_demonstrations(data_cfg, path)
    if not path.exists() or (path.is_dir() and not any(path.iterdir())):
        can_generate = generate_if_missing and data_cfg.get("generator") is not None
        if can_generate and _command_line_path(data_cfg):
            option = _group_choice("data")
            kind = f"synthetic {option} set" if option else "synthetic set"
            raise DataError(
                f"{path}: no such dataset folder (or empty); to generate the {kind} there, "
                f"run `{_generate_command(data_cfg)}`"
            )
        if not can_generate:
            raise DataError(
                f"{path}: dataset not found; generate it with `iplanner-data generate "
                f"{override_word('data.path', data_cfg.path)}`"
            )
        print(f"dataset {path} missing: generating it", flush=True)
        generate_dataset(data_cfg, path, progress=progress)
    else:
        _check_generator_settings(data_cfg, path, overridden)
    demos = read_demonstrations(data_cfg, path)
    if path.is_dir():
        import warnings

        from iplanner_torch.data.dataset_card import card_mismatch
        from iplanner_torch.errors import DataWarning

        differ = card_mismatch(path, len(demos), sum(d.num_frames for d in demos))
        if differ:
            warnings.warn(f"{differ}; using the files as they are", DataWarning, stacklevel=2)
    return demos


def config_split(cfg: DictConfig, data_node: DictConfig | None = None) -> Any:
    """The split by demonstration that ``seed`` and ``data.split`` draw (its held-out names
    not yet known), as a :class:`~iplanner_torch.eval.prediction.SplitRecord`.

    Args:
        cfg: the root config (``seed``).
        data_node: a ``conf/data`` node (default ``cfg.data``); without ``split``, the shares
            are :data:`~iplanner_torch.data.windows.DEFAULT_SPLIT`.

    Raises:
        ConfigError: naming ``data.split`` when it is not 3 non-negative shares summing to 1.
    """
    from iplanner_torch.data.windows import DEFAULT_SPLIT
    from iplanner_torch.eval.prediction import SplitRecord

    data_node = cfg.data if data_node is None else data_node
    seed = cfg_scalar(cfg, "seed", int)
    fractions = data_node.get("split", None)
    try:
        return SplitRecord(seed=seed, fractions=DEFAULT_SPLIT if fractions is None else fractions)
    except ConfigError as err:
        raise ConfigError(f"data.split: {err}") from None


def task_overrides() -> list[str]:
    """This run's command-line overrides (none outside a Hydra run)."""
    from hydra.core.hydra_config import HydraConfig

    try:
        return list(HydraConfig.get().overrides.task)
    except ValueError:  # HydraConfig not set: called outside a Hydra app (tests)
        return []


def override_key(override: str) -> str:
    """The key an override sets: ``data.windows.n_prev`` for ``+data.windows.n_prev=5``,
    ``planner`` for ``planner=itomp``."""
    return override.split("=", 1)[0].lstrip("+~")


def override_group(override: str) -> str:
    """The config group or root key an override sets: ``predictor`` for
    ``predictor=iplanner_no_ni``, ``predictor.svgp.epochs=2`` and
    ``predictor@alias.svgp.epochs=2``."""
    return override_key(override).split(".", 1)[0].split("@", 1)[0]


def overridden_fields(node: str, overrides: list[str] | None = None) -> set[str]:
    """The fields directly under ``node`` that the overrides (default: this run's command
    line) set: ``{"n_prev"}`` for ``node="data.windows"`` and ``data.windows.n_prev=5``."""
    prefix = node + "."
    keys = (override_key(o) for o in (task_overrides() if overrides is None else overrides))
    return {k[len(prefix) :].split(".")[0] for k in keys if k.startswith(prefix)}


def unread_overrides(read: Iterable[str], overrides: list[str] | None = None) -> list[str]:
    """The overrides (default: this run's command line) whose key a command does not read.

    Args:
        read: what the command reads: ``"data"`` reads ``data=<option>`` and every ``data.*``
            key, ``"evaluate.logs"`` that key (and any below it), and ``"predictor="`` the
            group's option alone (``predictor=iplanner_no_ni``, not ``predictor.svgp.*``).
            ``progress`` is always read.
    """
    exact = {r[:-1] for r in read if r.endswith("=")}
    prefixes = [r for r in read if not r.endswith("=")] + ["progress"]
    out = []
    for override in task_overrides() if overrides is None else overrides:
        rest = override_key(override).partition(".")[2]
        key = override_group(override) + ("." + rest if rest else "")  # p@x.y -> p.y
        if key in exact or any(key == r or key.startswith(r + ".") for r in prefixes):
            continue
        out.append(override)
    return out


def refuse_unread_overrides(
    command: str, read: Iterable[str], hint: str, overrides: list[str] | None = None
) -> None:
    """Refuse the command-line overrides ``command`` does not read (:func:`unread_overrides`),
    which would otherwise change nothing without a word.

    Args:
        command: how the message names the command (``iplanner-train``).
        read: as :func:`unread_overrides` takes it.
        hint: what decides those settings instead, or where they belong.

    Raises:
        ConfigError: ``"<command> does not read <overrides>: <hint>"``.
    """
    unread = unread_overrides(read, overrides)
    if unread:
        raise ConfigError(f"{command} does not read {' '.join(unread)}: {hint}")


def differing_settings(
    saved: dict[str, Any], now: dict[str, Any], keys: set[str]
) -> list[tuple[str, Any, Any]]:
    """``(key, saved value, value now)`` for each of ``keys`` that both dicts hold and whose
    values differ, in key order; a tuple equals the list of its items (a value read back from
    JSON or a checkpoint against a dataclass field)."""

    def plain(value: Any) -> Any:
        return list(value) if isinstance(value, tuple) else value

    return [
        (k, saved[k], now[k])
        for k in sorted(keys & set(saved) & set(now))
        if plain(saved[k]) != plain(now[k])
    ]


def setting_changes(
    saved: dict[str, Any], now: dict[str, Any], keys: set[str], prefix: str = ""
) -> list[str]:
    """``"<prefix><key>: <saved> -> <now>"`` for each :func:`differing_settings` entry, the
    lines the refusals of other settings list."""
    return [f"{prefix}{k}: {a!r} -> {b!r}" for k, a, b in differing_settings(saved, now, keys)]


def _check_generator_settings(
    data_cfg: DictConfig, path: Path, overridden: set[str] | None = None
) -> None:
    """Refuse an existing generated dataset whose card keeps another value of a generator
    setting than the command line gives (``data.generator.reaches_per_target=10`` over a folder
    generated with 30): the old files would otherwise be trained on silently.

    Only the settings the command line sets are compared, so ``data.path=<folder>`` alone
    reads a folder generated with any settings. A folder without a generator config, without
    a card, or with a card written before cards kept their settings is not checked; a card
    whose settings block was broken by hand is refused (``DataError``), since it cannot be.

    Args:
        data_cfg: the ``data`` node.
        path: its existing folder.
        overridden: the generator fields to compare (default: those this run's command line
            sets).

    Raises:
        ConfigError: naming each setting that differs (dataset -> data.generator).
    """
    from iplanner_torch.data.dataset_card import generator_settings, read_generator_settings

    keys = overridden_fields("data.generator") if overridden is None else overridden
    if not keys or data_cfg.get("generator") is None:
        return
    saved = read_generator_settings(path)
    if saved is None:
        return
    now = generator_settings(instantiate(data_cfg.generator, name="data.generator"))
    differ = setting_changes(saved, now, keys)
    if differ:
        raise ConfigError(
            f"{path} was generated with other settings than data.generator: "
            f"{'; '.join(differ)} (dataset -> data.generator). Generate it anew with "
            f"`iplanner-data generate data.path={data_cfg.path} data.overwrite=true` and the "
            "same data.generator overrides, or choose another data.path"
        )


def dataset_generator(data_cfg: DictConfig, name: str | None = None) -> tuple[Any, Any]:
    """The generator settings a ``data`` node builds, checked, and the function that generates
    that kind of dataset (reaching or task demonstrations).

    Args:
        data_cfg: the ``data`` node.
        name: the generator node's key in messages (default: its full key).

    Returns:
        ``(settings, generate)``: a :class:`~iplanner_torch.data.reaching.ReachingCfg` with
        :func:`~iplanner_torch.data.reaching.generate_reaching_dataset`, or a
        :class:`~iplanner_torch.data.tasks.TaskDatasetCfg` with
        :func:`~iplanner_torch.data.tasks.generate_task_dataset`.

    Raises:
        ConfigError: when the node has no generator, it builds something else, a setting
            is bad, or the node holds a key no command reads (:func:`check_data_keys`).
    """
    from iplanner_torch.data.reaching import ReachingCfg, generate_reaching_dataset
    from iplanner_torch.data.tasks import TaskDatasetCfg, generate_task_dataset

    check_data_keys(data_cfg)
    if data_cfg.get("generator") is None:
        raise ConfigError(
            f"data config has no generator (a recorded dataset at {data_cfg.path}): "
            "nothing to generate; use `iplanner-data info` to check it"
        )
    gen_cfg = instantiate(data_cfg.generator, name=name)
    if isinstance(gen_cfg, ReachingCfg):
        return gen_cfg, generate_reaching_dataset
    if isinstance(gen_cfg, TaskDatasetCfg):
        return gen_cfg, generate_task_dataset
    raise ConfigError(f"data.generator builds {type(gen_cfg).__name__}: not a generator")


def generate_dataset(
    data_cfg: DictConfig, path: Path, *, progress: bool, command: str | None = None
) -> Any:
    """Run the generator a ``data`` node names (:func:`dataset_generator`) into ``path``.

    Returns:
        The generator's :class:`~iplanner_torch.data.dataset_card.DatasetSummary`.

    Raises:
        ConfigError: when the node has no generator or it builds something else.
    """
    gen_cfg, generate = dataset_generator(data_cfg)
    return generate(gen_cfg, path, progress=progress, command=command)
