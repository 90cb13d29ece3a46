"""conf/robot option files instantiate to RobotCfg and build the documented default robots."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from iplanner_torch.robot.description import ROBOT_NAMES
from iplanner_torch.robot.model import RobotCfg, RobotModel

CONF = Path(__file__).resolve().parents[2] / "conf" / "robot"


OPTIONS = sorted(p.stem for p in CONF.glob("*.yaml"))


def test_every_robot_has_an_option_named_after_it() -> None:
    assert set(OPTIONS) == set(ROBOT_NAMES)


@pytest.mark.parametrize("name", OPTIONS)
def test_robot_option_instantiates_to_the_defaults(name: str) -> None:
    cfg = instantiate(OmegaConf.load(CONF / f"{name}.yaml"))
    assert isinstance(cfg, RobotCfg) and cfg.name == name
    assert isinstance(cfg.base_position, tuple)
    model = RobotModel.from_cfg(cfg)
    default = RobotModel.load(name)
    assert torch.equal(model.base_position, default.base_position)
    assert model.base_yaw == pytest.approx(default.base_yaw)
    assert model.torso_height == default.torso_height
    q = default.q_home.expand(3, -1)
    assert torch.allclose(model.sphere_centers(q), default.sphere_centers(q))
