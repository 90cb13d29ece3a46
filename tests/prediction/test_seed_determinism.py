"""The predictor's random choices (IVM import candidates, SVGP inducing points, the DTW
bandwidth's sample of pairs) draw only from their seeds: the same seed gives the same numbers
whatever random state the process had before, another seed gives other ones, and a value that
is not a seed is refused rather than read as another seed."""

from __future__ import annotations

import random

import numpy as np
import pytest
import torch

from iplanner_torch.errors import ConfigError
from iplanner_torch.prediction.dtw import RBFKernel, median_dtw
from iplanner_torch.prediction.ivm import IVMClassifier
from iplanner_torch.prediction.svgp import SVGPCfg, SVGPRegressor

pytestmark = pytest.mark.usefixtures("one_thread")


def _global_state(seed: int) -> None:
    """Seeds the global generators that the models must not read."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


@pytest.fixture(scope="module")
def windows() -> tuple[torch.Tensor, torch.Tensor]:
    """80 windows (80, 6, 2) and their classes in {0, 1, 2}."""
    g = torch.Generator().manual_seed(0)
    y = torch.randint(0, 3, (80,), generator=g)
    x = y.float()[:, None, None] + torch.randn(80, 6, 2, generator=g)
    return x, y


def _imports(windows: tuple[torch.Tensor, torch.Tensor], seed: int, global_seed: int) -> list:
    _global_state(global_seed)
    x, y = windows
    ivm = IVMClassifier(RBFKernel(3.0), num_classes=3, max_import=6, candidates=10, seed=seed)
    return ivm.fit(x, y).import_index_.tolist()


def test_ivm_imports_follow_their_seed_only(windows) -> None:
    first = _imports(windows, 3, global_seed=1)
    assert _imports(windows, 3, global_seed=2) == first
    assert _imports(windows, 4, global_seed=1) != first


@pytest.mark.parametrize("seed", [-1, 2**64 - 1, 2**64, 1.5, True])
def test_ivm_refuses_what_is_not_a_seed(seed: object) -> None:
    """-1 and 2^64 - 1 drew the same candidates (torch wraps negative seeds), and 2^64 failed
    only in fit, with torch's bare ValueError."""
    with pytest.raises(ConfigError, match="seed"):
        IVMClassifier(RBFKernel(3.0), num_classes=3, seed=seed)  # type: ignore[arg-type]


def _inducing(windows: tuple[torch.Tensor, torch.Tensor], seed: int, global_seed: int):
    _global_state(global_seed)
    x, y = windows
    x = x.reshape(len(x), -1)
    reg = SVGPRegressor.from_data(SVGPCfg(num_inducing=8, seed=seed), x, y.float()[:, None])
    return reg.model.variational_strategy.inducing_points.detach().clone()


def test_svgp_inducing_points_follow_their_seed_only(windows) -> None:
    z = _inducing(windows, 3, global_seed=1)
    assert torch.equal(_inducing(windows, 3, global_seed=2), z)
    assert not torch.equal(_inducing(windows, 4, global_seed=1), z)


def test_dtw_bandwidth_follows_its_seed_only(windows) -> None:
    x, _ = windows
    _global_state(1)
    first = median_dtw(x, 20, 3)
    _global_state(2)
    assert median_dtw(x, 20, 3) == first
    assert median_dtw(x, 20, 4) != first
