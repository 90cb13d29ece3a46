"""The project's root Hydra config composed outside a Hydra run, shared by the command-line
tests (``tests/conftest.py`` puts this folder on ``sys.path``)."""

from __future__ import annotations

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

from iplanner_torch.cli._common import CONF_DIR


def root_config(*overrides: str, return_hydra_config: bool = False) -> DictConfig:
    """``conf/config.yaml`` with ``overrides`` and ``progress=false`` (no progress bars in
    tests), Hydra cleared before and after; ``return_hydra_config`` keeps the ``hydra`` node."""
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            return compose(
                config_name="config",
                overrides=[*overrides, "progress=false"],
                return_hydra_config=return_hydra_config,
            )
    finally:
        GlobalHydra.instance().clear()
