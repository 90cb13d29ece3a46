"""Helpers shared by the Hydra entry points (the only modules of the package that use Hydra)."""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import torch
from omegaconf import DictConfig, OmegaConf

from iplanner_torch.errors import ConfigError, IPlannerError

#: conf/ at the repository root (the package is installed editable from the clone).
CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")

log = logging.getLogger("iplanner_torch")

# ${basename:some/path} -> "path" (checkpoint folders are named after their dataset folder)
if not OmegaConf.has_resolver("basename"):
    OmegaConf.register_new_resolver("basename", lambda p: Path(str(p)).name)

F = TypeVar("F", bound=Callable[..., Any])


def instantiate(node: Any) -> Any:
    """Build the dataclass described by a config node (``_target_`` plus keyword arguments).

    Raises:
        ConfigError: when the node cannot be built (unknown key, wrong type, bad value), with
            the underlying reason.
    """
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate as hydra_instantiate

    try:
        return hydra_instantiate(node, _convert_="all")
    except InstantiationException as exc:
        cause = exc.__cause__ or exc
        if isinstance(cause, IPlannerError):
            raise ConfigError(str(cause)) from exc
        raise ConfigError(f"cannot build config node: {cause}") from exc


def resolve_device(name: str) -> torch.device:
    """``auto`` -> CUDA when available, else CPU; anything else is passed to torch.device."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError as exc:
        raise ConfigError(f"unknown device {name!r}") from exc
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device=cuda asked for, but no CUDA device is available")
    return device


def repo_path(path: str | Path) -> Path:
    """A config path: absolute as given, relative ones against the current directory."""
    return Path(path).expanduser().resolve()


def friendly_errors(fn: F) -> F:
    """Turn library errors into a one-line message and exit code 2 instead of a traceback."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except IPlannerError as exc:
            print(f"error: {type(exc).__name__}: {exc}", file=sys.stderr)
            raise SystemExit(2) from None

    return wrapper  # type: ignore[return-value]


def dump_config(cfg: DictConfig) -> str:
    """The resolved config as YAML (for logs and reports)."""
    return OmegaConf.to_yaml(cfg, resolve=True)


def load_dataset(
    data_cfg: DictConfig, *, generate_if_missing: bool = False, progress: bool = True
) -> list[Any]:
    """Load the demonstrations a ``data`` config node describes.

    Args:
        data_cfg: the ``data`` node (``path``, optional ``format``, ``fps``, ``generator``,
            ``windows``).
        generate_if_missing: generate the dataset with its generator when the folder is absent.
        progress: progress bars.

    Returns:
        The list of :class:`~iplanner_torch.data.demonstration.Demonstration`.

    Raises:
        DataError: when the folder is absent and cannot (or may not) be generated.
    """
    from iplanner_torch.data.io import load_demonstrations, load_lego_assembly
    from iplanner_torch.errors import DataError

    path = repo_path(data_cfg.path)
    fps = data_cfg.get("fps", None)
    if data_cfg.get("format", "native") == "lego_assembly":
        return load_lego_assembly(path, fps=float(fps or 30.0))
    if not path.exists() or not any(path.iterdir()):
        if not generate_if_missing or data_cfg.get("generator") is None:
            raise DataError(
                f"{path}: dataset not found; generate it with `iplanner-data generate "
                f"data.path={data_cfg.path}`"
            )
        log.info("generating dataset into %s", path)
        print(f"dataset {path} missing: generating it", flush=True)
        generate_dataset(data_cfg, path, progress=progress)
    joints = data_cfg.windows.get("joints", None) if "windows" in data_cfg else None
    return load_demonstrations(path, fps=fps, joints=list(joints) if joints else None)


def generate_dataset(
    data_cfg: DictConfig, path: Path, *, progress: bool, command: str | None = None
) -> Any:
    """Run the generator a ``data`` node names (reaching or task demonstrations) into ``path``.

    Returns:
        The generator's :class:`~iplanner_torch.data.dataset_card.DatasetSummary`.

    Raises:
        ConfigError: when the node has no generator or it builds something else.
    """
    from iplanner_torch.data.reaching import ReachingCfg, generate_reaching_dataset
    from iplanner_torch.data.tasks import TaskDatasetCfg, generate_task_dataset

    if data_cfg.get("generator") is None:
        raise ConfigError(
            f"data config has no generator (a recorded dataset at {data_cfg.path}): "
            "nothing to generate; use `iplanner-data info` to check it"
        )
    gen_cfg = instantiate(data_cfg.generator)
    if isinstance(gen_cfg, ReachingCfg):
        return generate_reaching_dataset(gen_cfg, path, progress=progress, command=command)
    if isinstance(gen_cfg, TaskDatasetCfg):
        return generate_task_dataset(gen_cfg, path, progress=progress, command=command)
    raise ConfigError(f"data.generator builds {type(gen_cfg).__name__}: not a generator")
