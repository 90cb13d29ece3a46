"""Public helpers one layer below the main entry points, given what those entry points
refuse: each is named by a typed error (they returned silent NaN or wrong values, or raised
torch's, numpy's or Python's own errors)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from iplanner_torch.collision.human_spheres import HumanSphereMap
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.data.windows import next_action_labels
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.eval.metrics import classification_precision
from iplanner_torch.planning.costs import forecast_to_obstacle, joint_acc_limit_violation
from iplanner_torch.planning.optimizer import OptimizerCfg, TrajectoryOptimizer
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.robot.description import robot_description
from iplanner_torch.robot.kinematics import SerialChainKinematics
from iplanner_torch.robot.model import RobotModel


@pytest.fixture(scope="module")
def optimizer() -> TrajectoryOptimizer:
    return TrajectoryOptimizer(RobotModel.load("kuka_iiwa14"), OptimizerCfg())


@pytest.mark.parametrize(
    ("goal", "error", "match"),
    [
        (torch.full((7,), math.nan), DataError, "q_goal"),  # NaN compared as within limits
        (torch.zeros(2, 7), ShapeError, "q_goal"),  # was broadcast
        (torch.zeros(3), ShapeError, "q_goal"),  # was torch's size mismatch
    ],
)
def test_check_goal_names_a_goal_of_no_joint_positions(optimizer, goal, error, match) -> None:
    with pytest.raises(error, match=match):
        optimizer.check_goal(goal)
    optimizer.check_goal(optimizer.q_min * 0.5 + optimizer.q_max * 0.5)  # a goal inside


@pytest.mark.parametrize(
    ("duration", "travel", "match"),
    [(math.nan, 0.5, "duration"), (1.0, math.nan, "travel"), (-1.0, 0.5, "duration")],
)
def test_arrival_index_refuses_times_that_are_no_times(optimizer, duration, travel, match):
    with pytest.raises(DataError, match=match):  # all three were the last waypoint
        optimizer.arrival_index(duration, travel)
    assert 2 <= optimizer.arrival_index(1.0, 0.5) < optimizer.cfg.num_waypoints


@pytest.mark.parametrize(
    ("labels", "error"),
    [
        (np.array([0.7, 0.2, 1.9]), ShapeError),  # floats were cut: [1, 1, -1]
        (np.array([0.0, np.nan]), ShapeError),  # NaN became int64's minimum
        (np.array([0, -5, 1]), DataError),
        (np.zeros((2, 2), dtype=np.int64), ShapeError),  # numpy's ValueError
    ],
)
def test_next_action_labels_refuses_what_progress_bitmask_refuses(labels, error) -> None:
    with pytest.raises(error, match="label"):
        next_action_labels(labels)
    assert next_action_labels(np.array([0, 0, -1, 1, 1])).tolist() == [1, 1, 1, -1, -1]
    assert next_action_labels(torch.tensor([2, 3])).tolist() == [3, -1]


def test_forecast_to_obstacle_names_a_forecast_without_frames() -> None:
    k = len(JOINT_NAMES)
    empty = Forecast(
        weights=torch.ones(1, 1),
        mean=torch.zeros(1, 1, 0, k, 3),
        var=torch.ones(1, 1, 0, k, 3),
        dt=0.1,
        joint_names=tuple(JOINT_NAMES),
        action_names=("a",),
    )
    spheres = HumanSphereMap.from_segments(JOINT_NAMES)
    with pytest.raises(ShapeError, match="at least one frame"):  # was an IndexError
        forecast_to_obstacle(empty, torch.linspace(0, 1, 5), 0.0, spheres)


@pytest.mark.parametrize("a_max", [math.nan, -1.0, 0.0, "1"])
def test_joint_acc_limit_violation_refuses_a_limit_that_is_none(a_max) -> None:
    q = torch.zeros(2, 5, 3)
    with pytest.raises(ConfigError, match="a_max"):  # NaN costs; -1: a cost at rest
        joint_acc_limit_violation(q, 0.1, a_max)
    assert joint_acc_limit_violation(q, 0.1, 1.0).tolist() == [0.0, 0.0]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sphere_centers_local": {"nope": np.zeros((1, 3))}}, "not in the chain"),
        ({"base_yaw": "x"}, "base_yaw"),
        ({"base_position": (0.0, 0.0, math.nan)}, "base_position"),
    ],
)
def test_serial_chain_kinematics_refuses_with_config_errors(kwargs: dict, match: str) -> None:
    args = {"base_position": (0.0, 0.0, 0.0), "base_yaw": 0.0, **kwargs}
    with pytest.raises(ConfigError, match=match):  # were ValueError, TypeError or accepted
        SerialChainKinematics(robot_description("kuka_iiwa14"), **args)


def test_classification_precision_of_no_frame_counts_none() -> None:
    assert math.isnan(classification_precision(torch.zeros(0, 0), torch.zeros(0))[0])
    with pytest.raises(DataError):
        classification_precision(torch.zeros(2, 0), torch.zeros(2))


def test_gp_inputs_refuses_a_misspelt_kind_and_too_few_columns() -> None:
    from iplanner_torch.prediction.predictor import gp_inputs

    f = torch.randn(2, 5, 36)  # 10 joints: 30 position columns, then 6 more
    with pytest.raises(ConfigError, match="kind"):  # 'absolute' gave 'window''s inputs
        gp_inputs(f, 10, "absolute")
    with pytest.raises(ShapeError, match="D >= 3 K = 30"):
        gp_inputs(torch.randn(2, 5, 6), 10)
    with pytest.raises(ShapeError, match="f_prev"):  # was an IndexError
        gp_inputs(torch.randn(5, 36), 10)
    assert gp_inputs(f, 10, "window").shape == (2, 180)


@pytest.mark.parametrize(
    ("times", "error"),
    [([1.0, 0.5, 0.0], DataError), ([math.nan, 0.5, 1.0], DataError), ([0.0, 1.0], ShapeError)],
)
def test_a_plan_record_of_times_out_of_order_is_named_as_the_plans(times, error) -> None:
    """Times out of order or NaN were taken, and a later error named the trajectory's own
    times; q of another length than the times was taken too."""
    from iplanner_torch.eval.smoothness import PlanRecord

    with pytest.raises(error, match="plan"):
        PlanRecord(times=times, q=np.zeros((3, 2)), wait_s=0.0)


def test_the_spread_calibrator_refuses_times_it_cannot_score() -> None:
    from iplanner_torch.prediction.calibration import CalibrationCfg, SpreadCalibrator

    cal = SpreadCalibrator(CalibrationCfg(), JOINT_NAMES, noise_std=0.01)
    frames = np.zeros((2, len(JOINT_NAMES), 3))
    with pytest.raises(DataError, match="strictly increasing"):  # was scored twice
        cal.observe(np.array([0.9, 1 / 30]), frames)
    with pytest.raises(DataError, match="strictly increasing"):
        cal.observe(np.array([math.nan, math.nan]), frames)
    with pytest.raises(ShapeError, match="numbers"):  # was numpy's ValueError
        cal.observe(np.array([0.1]), [["a"]])
    with pytest.raises(ShapeError, match="Forecast"):  # was an AttributeError
        cal.record("x", 0.0)  # type: ignore[arg-type]


def test_a_trajectory_names_tensors_on_another_device() -> None:
    from iplanner_torch.planning.trajectory import Trajectory

    q, t = torch.zeros(3, 2), torch.tensor([0.0, 0.5, 1.0])
    with pytest.raises(ShapeError, match="times on cpu"):  # was torch's RuntimeError
        Trajectory(q=q, times=t.to("meta"))
    with pytest.raises(ShapeError, match="meta"):
        Trajectory(q=q.to("meta"), times=t.to("meta"))


def test_svgp_fit_inputs_and_bank_predictions_are_checked() -> None:
    from iplanner_torch.prediction.svgp import SVGPBank, SVGPCfg, SVGPRegressor

    g = torch.Generator().manual_seed(0)
    x, y = torch.randn(40, 6, generator=g), torch.randn(40, 3, generator=g)
    bad_x, bad_y = x.clone(), y.clone()
    bad_x[3, 2], bad_y[5, 1] = math.nan, math.inf
    cfg = SVGPCfg(num_inducing=8)
    with pytest.raises(DataError, match="x"):  # was gpytorch's constraint error
        SVGPRegressor.from_data(cfg, bad_x, y)
    with pytest.raises(DataError, match="y"):  # every prediction came out NaN
        SVGPRegressor.from_data(cfg, x, bad_y)
    reg = SVGPRegressor.from_data(cfg, x, y)
    with pytest.raises(DataError, match="y"):
        reg.fit(x, bad_y)
    bank = SVGPBank([reg, reg])
    with pytest.raises(ShapeError, match="bank"):  # float64: torch's 'expected scalar type'
        bank.predict(x.double())
    with pytest.raises(ShapeError, match="bank"):  # int64 was taken
        bank.predict(x.long())
    with pytest.raises(ConfigError, match="chunk"):  # 0: range()'s ValueError
        bank.predict(x, chunk=0)
    mean, var = bank.predict(x[:0])  # no window: empty (was torch.cat's ValueError)
    assert mean.shape == var.shape == (0, 2, 3)
    assert bank.predict(x[:5])[0].shape == (5, 2, 3)
