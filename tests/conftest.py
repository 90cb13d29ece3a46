"""Shared test fixtures: fixed seeds, a device fixture, the shared data folder."""

from __future__ import annotations

import os
import random
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

os.environ.setdefault("MPLBACKEND", "Agg")

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"

# --import-mode=importlib puts no test folder on sys.path: shared helpers (tiny_settings) sit here
sys.path.insert(0, str(Path(__file__).resolve().parent))


@pytest.fixture(autouse=True)
def _fixed_seeds() -> None:
    """Every test starts from the same random state."""
    random.seed(0)
    np.random.seed(0)
    torch.manual_seed(0)


@pytest.fixture(params=["cpu", "cuda"])
def device(request: pytest.FixtureRequest) -> torch.device:
    """CPU always; CUDA where a GPU is present (skipped otherwise)."""
    if request.param == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    return torch.device(request.param)


@pytest.fixture
def lego_dir() -> Path:
    """The real LEGO assembly recording beside the repository (skips where absent)."""
    path = SHARED_DATA / "lego_assembly_3d"
    if not path.is_dir():
        pytest.skip("shared LEGO assembly recording not found")
    return path


class FakeClock:
    """Stands in for the ``time`` module of the code under test: ``perf_counter`` reads
    ``now``, which only the test moves, so timing metrics do not depend on the machine."""

    def __init__(self) -> None:
        self.now = 100.0

    def perf_counter(self) -> float:
        return self.now


@pytest.fixture
def fake_clock(monkeypatch: pytest.MonkeyPatch):
    """``fake_clock(module)``: replace ``module.time`` by a :class:`FakeClock` (undone after
    the test) and return the clock."""

    def patch(module: object) -> FakeClock:
        clock = FakeClock()
        monkeypatch.setattr(module, "time", clock)
        return clock

    return patch
