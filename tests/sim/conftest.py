"""Fixtures of the simulation tests."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sim_fakes import FakeArm, FakeMotion  # noqa: E402


@pytest.fixture
def arm(tmp_path: Path) -> FakeArm:
    return FakeArm(tmp_path)


@pytest.fixture
def motion() -> FakeMotion:
    return FakeMotion()
