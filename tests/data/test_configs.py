"""conf/data option files instantiate into the data config dataclasses."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra.utils import instantiate
from omegaconf import OmegaConf

from iplanner_torch.data.reaching import ReachingCfg
from iplanner_torch.data.tasks import TaskDatasetCfg
from iplanner_torch.data.windows import WindowCfg

CONF = Path(__file__).resolve().parents[2] / "conf" / "data"


OPTIONS = [("reaching", ReachingCfg), ("tasks", TaskDatasetCfg), ("lego", None)]


@pytest.mark.parametrize("name, gen_type", OPTIONS)
def test_data_options_instantiate(name, gen_type):
    cfg = OmegaConf.load(CONF / f"{name}.yaml")
    win = instantiate(cfg.windows)
    assert isinstance(win, WindowCfg) and isinstance(win.feature_kinds, tuple)
    hash(win)  # frozen dataclass with tuple fields
    if gen_type is None:
        assert cfg.generator is None
        assert win.joints[2] == "left_hand"
    else:
        gen = instantiate(cfg.generator)
        assert isinstance(gen, gen_type)
        hash(gen)
    if name == "reaching":
        assert gen == ReachingCfg() and win == WindowCfg()
