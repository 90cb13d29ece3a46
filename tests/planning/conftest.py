"""Fixtures of the planning tests (the analytic robots live in ``planning_fakes``)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

# --import-mode=importlib puts no test folder on sys.path; the fakes module sits beside us.
sys.path.insert(0, str(Path(__file__).resolve().parent))

from planning_fakes import PlanarArm, PointRobot  # noqa: E402


@pytest.fixture
def point_robot() -> PointRobot:
    return PointRobot()


@pytest.fixture
def planar_arm() -> PlanarArm:
    return PlanarArm()
