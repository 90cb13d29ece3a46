"""A tiny reaching dataset and predictor settings shared by the training and evaluation
settings tests."""

from __future__ import annotations

from collections.abc import Iterator
from types import SimpleNamespace

import pytest
from tiny_settings import tiny_predictor_cfg

from iplanner_torch.data.io import load_demonstrations
from iplanner_torch.data.reaching import ReachingCfg, generate_reaching_dataset
from iplanner_torch.data.windows import WindowCfg, build_windows, split_by_demonstration
from iplanner_torch.eval.prediction import SplitRecord

#: the split the tiny predictor is trained on (with seed 1)
FRACTIONS = (0.6, 0.2, 0.2)


@pytest.fixture(scope="session")
def tiny_reaching(tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    """10 generated reaching demonstrations (2 targets x 5 reaches) in a folder named ``ds``,
    split with seed 1 and :data:`FRACTIONS`: ``ds``, ``windows`` (train, val; n_prev 6,
    n_future 8, stride 2), ``held_out`` (test names), ``split`` (its record) and ``cfg`` (a
    predictor small enough to train on them in about a second)."""
    ds = tmp_path_factory.mktemp("tiny") / "ds"
    generate_reaching_dataset(ReachingCfg(n_targets=2, reaches_per_target=5), ds, progress=False)
    train, val, test = split_by_demonstration(load_demonstrations(ds), FRACTIONS, 1)
    wc = WindowCfg(n_prev=6, n_future=8, stride=2, joints=("torso", "left_hand", "right_hand"))
    held_out = [d.name for d in test]
    return SimpleNamespace(
        ds=ds,
        windows=(build_windows(train, wc), build_windows(val, wc)),
        held_out=held_out,
        split=SplitRecord(seed=1, fractions=FRACTIONS, held_out=held_out),
        cfg=tiny_predictor_cfg(),
    )


@pytest.fixture
def hydra_conf() -> Iterator[None]:
    """Hydra initialised on the project's ``conf/`` for ``compose`` (cleared before and after)."""
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from iplanner_torch.cli._common import CONF_DIR

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        yield
    GlobalHydra.instance().clear()
