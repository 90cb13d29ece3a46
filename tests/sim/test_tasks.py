"""Scenarios, task orders and the default task choice; the conf option files instantiate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.errors import ConfigError
from iplanner_torch.sim.tasks import ScenarioCfg, next_feasible, parse_order

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_orders_of_the_paper_table() -> None:
    order = parse_order("(1,5)->(2,6)", (1, 2, 5, 6))
    assert order.allowed_next(set()) == {1, 5}
    assert next_feasible(order, {1, 5}, (1, 2, 5, 6)) == 2
    rnd = parse_order("random", (0, 1, 2, 3))
    samples = {tuple(rnd.sample(np.random.default_rng(s))) for s in range(20)}
    assert len(samples) > 3 and all(sorted(s) == [0, 1, 2, 3] for s in samples)
    assert next_feasible(order, {1, 2, 5, 6}, (1, 2, 5, 6)) == -1
    with pytest.raises(ConfigError, match="names blocks"):
        parse_order("(0,4)->(1,5)", (0, 1, 2, 3))
    with pytest.raises(ConfigError, match="confidence"):
        ScenarioCfg(confidence=1.0)


def test_conf_option_files_instantiate() -> None:
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from iplanner_torch.eval.experiment import ExperimentCfg
    from iplanner_torch.sim.env import SimCfg

    for path in sorted((CONF / "scenario").glob("*.yaml")):
        sc = instantiate(OmegaConf.load(path), _convert_="all")
        assert isinstance(sc, ScenarioCfg) and sc.name == path.stem
        if sc.kind == "delivery":
            parse_order(sc.task_order, sc.scene().block_ids)
    # conf/sim reads the root sweep aliases tracker.* and human.speed (conf/config.yaml)
    root = OmegaConf.create(
        {
            "tracker": {"noise": 0.01, "dropout": 0.0},
            "human": {"speed": "medium"},
            "sim": OmegaConf.load(CONF / "sim" / "default.yaml"),
        }
    )
    assert isinstance(instantiate(root.sim), SimCfg)
    for name in ("table_simulation", "speed_response"):
        node = OmegaConf.load(CONF / "experiment" / f"{name}.yaml")
        exp = instantiate(node.experiment, _convert_="all")
        assert isinstance(exp, ExperimentCfg) and exp.name == name
