"""The trajectory optimiser on analytic problems, a 2-D point robot around a Gaussian obstacle,
the iiwa beside a Gaussian human sphere, and the infeasible case that waits."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from planning_fakes import (
    PlanarArm,
    PointRobot,
    approaching,
    mc_ball_probability,
    one_sphere_map,
    static_forecast,
)

from iplanner_torch.collision.human_spheres import HumanSphereMap
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.planning.costs import CostWeights, HumanObstacle
from iplanner_torch.planning.itomp import ITOMP, path_forecast, static_human_forecast
from iplanner_torch.planning.optimizer import (
    ACC_TOL,
    MAX_HORIZON_S,
    KinematicModel,
    OptimizerCfg,
    TrajectoryOptimizer,
    smooth_stop,
    unsafe_if_not_finite,
)
from iplanner_torch.planning.trajectory import accelerations
from iplanner_torch.prediction.forecast import Forecast


def test_smoothness_bowl_converges_to_the_straight_line() -> None:
    """Squared accelerations with pinned ends: the unique minimum is the uniform straight line."""
    arm = PlanarArm(dtype=torch.float64)
    cfg = OptimizerCfg(
        num_trajectories=4,
        iterations=200,
        lr=0.005,
        lr_final_ratio=0.001,
        perturbation_std=0.5,
        weights=CostWeights(joint_acc_l2=1.0),
    )
    opt = TrajectoryOptimizer(arm, cfg)
    q_s = torch.tensor([0.1, -0.5, 0.3], dtype=torch.float64)
    q_g = torch.tensor([1.0, 0.4, -0.6], dtype=torch.float64)
    res = opt.solve(q_s, q_g, duration=2.0)
    s = torch.linspace(0, 1, cfg.num_waypoints, dtype=torch.float64)[:, None]
    line = q_s + s * (q_g - q_s)
    assert float((res.candidates - line).abs().max()) < 1e-3
    assert res.feasible and res.wait_s == 0.0


def test_point_robot_goes_around_a_gaussian_obstacle(point_robot: PointRobot) -> None:
    std, r_h = 0.05, 0.1
    cfg = OptimizerCfg(iterations=60, confidence=0.95)
    opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(r_h))
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    res = opt.solve(q_s, q_g, forecast=static_forecast([0.0, 0.0, 0.0], std), duration=3.0)
    assert res.feasible
    assert torch.equal(res.q[0], q_s) and torch.equal(res.q[-1], q_g)
    assert float(res.bound.max()) <= 1 - cfg.confidence
    # independent check: Monte Carlo collision probability of every waypoint, and the path is
    # a detour, not a flight away from the obstacle
    rad = r_h + 0.05
    for q in res.q:
        d = torch.tensor([0.0, 0.0, 0.0]) - torch.cat([q, torch.zeros(1)])
        p = mc_ball_probability(d, torch.full((3,), std**2), rad, n=50_000)
        assert p <= 1 - cfg.confidence
    assert float(res.q[:, 1].abs().max()) < 0.6
    assert res.cost_terms["max_vel_ratio"] <= 1.0
    # the straight line would have collided
    assert float(res.q[:, 1].abs().max()) > rad


def test_same_seed_same_plan(point_robot: PointRobot) -> None:
    opt = TrajectoryOptimizer(
        point_robot, OptimizerCfg(iterations=10), human_spheres=one_sphere_map(0.1)
    )
    args = (torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0]))
    fc = static_forecast([0.0, 0.05, 0.0], 0.05)
    a = opt.solve(*args, forecast=fc)
    b = opt.solve(*args, forecast=fc)
    assert torch.equal(a.candidates, b.candidates)


def test_infeasible_goal_inside_the_human_waits(point_robot: PointRobot) -> None:
    cfg = OptimizerCfg(iterations=30, confidence=0.99)
    opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(0.15))
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([0.9, 0.0])
    res = opt.solve(q_s, q_g, forecast=static_forecast([1.0, 0.0, 0.0], 0.05), duration=2.0)
    assert not res.feasible
    assert res.wait_s > 0.0 and res.hold_index is not None
    h = res.hold_index
    assert torch.equal(res.q[h:], res.q[h].expand_as(res.q[h:]))
    # the held pose is safe (independent Monte Carlo) and the prefix respects the bound
    d = torch.tensor([1.0, 0.0, 0.0]) - torch.cat([res.q[h], torch.zeros(1)])
    assert mc_ball_probability(d, torch.full((3,), 0.05**2), 0.2, n=50_000) <= 0.01
    assert float(res.bound.max()) <= 1 - cfg.confidence
    assert res.wait_s == pytest.approx(float(res.times[-1] - res.times[h]))
    # an execution window past the plan's end: the wait still ends with the plan
    late = opt.solve(q_s, q_g, forecast=static_forecast([1.0, 0.0, 0.0], 0.05), duration=2.0,
                     window=(0.0, 5.0))  # fmt: skip
    assert not late.feasible and late.hold_index is not None
    assert late.wait_s == pytest.approx(float(late.times[-1] - late.times[late.hold_index]))


def test_a_wait_holds_at_the_last_safe_waypoint_of_the_path() -> None:
    # A straight path (x = 0.09 k, k = 0..10) through a person resting at x = 0.6 (std 0.02,
    # contact radius 0.15), not optimised. The paper's wait (sec. 5) follows the path up to
    # its last waypoint before the first unsafe one and holds there: the waypoints' collision
    # probabilities, by Monte Carlo, say which that is.
    robot = PointRobot(dtype=torch.float64)
    w = 11
    s = torch.linspace(0.0, 1.0, w, dtype=torch.float64)
    path = torch.stack([0.9 * s, torch.zeros_like(s)], -1)
    cfg = OptimizerCfg(num_trajectories=2, num_waypoints=w, warm_iterations=0,
                       collision_substeps=1)  # fmt: skip
    opt = TrajectoryOptimizer(robot, cfg, human_spheres=one_sphere_map(0.1))
    fc = static_forecast([0.6, 0.0, 0.0], 0.02, dtype=torch.float64)
    res = opt.solve(path[0], path[-1], forecast=fc, duration=1.0, q_init=torch.stack([path, path]))
    person = torch.tensor([0.6, 0.0, 0.0], dtype=torch.float64)
    var = torch.full((3,), 0.02**2, dtype=torch.float64)
    risk = [
        mc_ball_probability(person - torch.cat([q, q.new_zeros(1)]), var, 0.15, n=50_000)
        for q in path
    ]
    first_unsafe = next(k for k, p in enumerate(risk) if p > 1 - cfg.confidence)
    assert first_unsafe == 5  # the geometry above: x = 0.45 is 0.15 from the person
    assert not res.feasible and res.hold_index == first_unsafe - 1
    assert torch.equal(res.q[:first_unsafe], path[:first_unsafe])
    assert torch.equal(res.q[first_unsafe:], path[first_unsafe - 1].expand(w - first_unsafe, 2))
    assert res.wait_s == pytest.approx(float(res.times[-1] - res.times[first_unsafe - 1]))


def test_itomp_avoids_the_observed_pose(point_robot: PointRobot) -> None:
    pose = torch.tensor([[0.0, 0.0, 0.0]])
    fc = static_human_forecast(pose, n_f=10, dt=0.1, joint_names=("j",))
    assert fc.mean.shape == (1, 1, 10, 1, 3) and float(fc.var.max()) == pytest.approx(1e-4)
    opt = ITOMP(point_robot, OptimizerCfg(iterations=60), human_spheres=one_sphere_map(0.1))
    res = opt.solve_observed(
        torch.tensor([-1.0, 0.0]),
        torch.tensor([1.0, 0.0]),
        pose=pose,
        joint_names=("j",),
        duration=3.0,
    )
    assert res.feasible
    dist = (res.q - pose[0, :2]).norm(dim=-1)
    assert float(dist.min()) > 0.15  # r_robot + r_human
    with pytest.raises(ShapeError, match=r"expected pose \(1, 3\)"):
        static_human_forecast(torch.zeros(2, 3), 5, 0.1, ("j",))
    path = torch.rand(4, 1, 3, dtype=torch.float64)
    fc = path_forecast(path, 0.2, ("j",), std=0.03, action="walk")
    assert fc.action_names == ("walk",) and fc.weights.tolist() == [[1.0]]
    assert torch.equal(fc.mean[0, 0], path) and float(fc.var.max()) == pytest.approx(9e-4)
    with pytest.raises(ShapeError, match="path"):
        path_forecast(torch.zeros(4, 2, 3), 0.1, ("j",), std=0.01, action="a")
    with pytest.raises(ConfigError, match="std"):
        path_forecast(path, 0.1, ("j",), std=0.0, action="a")
    with pytest.raises(ConfigError, match="n_f"):
        static_human_forecast(pose, 0, 0.1, ("j",))
    with pytest.raises(ConfigError, match=r"expected path with n_f >= 1 frames, got \(0, 1, 3\)"):
        path_forecast(torch.zeros(0, 1, 3), 0.1, ("j",), std=0.01, action="a")
    # a pose observed at t0 = 5 s: the plan starts at 5 s, as solve's with the pose seen then
    later = opt.solve_observed(torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0]), pose=pose,
                               joint_names=("j",), duration=3.0, t0=5.0)  # fmt: skip
    fc = opt.forecast_from_pose(pose, ("j",))
    same = opt.solve(torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0]), forecast=fc,
                     forecast_t0=5.0, t0=5.0, duration=3.0)  # fmt: skip
    torch.testing.assert_close(later.bound, same.bound)
    torch.testing.assert_close(later.q, same.q)
    assert float(later.times[0]) == 5.0


def test_itomp_spread_grows_the_held_pose_and_the_bound_covers_it(
    point_robot: PointRobot,
) -> None:
    """``spread`` widens the held pose by a std growing linearly in time; the planner's bound
    for a robot 0.3 m away then rises over the first 1.5 s and stays above the Monte Carlo
    collision probability of that widened pose (and is ~0 for the pose held still)."""
    pose = torch.tensor([[0.0, 0.0, 0.0]])
    still = static_human_forecast(pose, 20, 0.1, ("j",))
    wide = static_human_forecast(pose, 20, 0.1, ("j",), spread=0.1)
    assert torch.equal(wide.mean, still.mean) and wide.action_names == ("observed",)
    k = torch.arange(1, 21, dtype=wide.var.dtype)
    expected = ((0.01 + 0.01 * k) ** 2)[:, None].expand(20, 3)
    torch.testing.assert_close(wide.var[0, 0, :, 0], expected)
    assert torch.equal(static_human_forecast(pose, 20, 0.1, ("j",), spread=0.0).var, still.var)
    opt = ITOMP(point_robot, OptimizerCfg(), human_spheres=one_sphere_map(0.1))
    times = torch.tensor([0.5, 1.0, 1.5, 2.0])
    q = torch.tensor([0.3, 0.0]).expand(4, 2)
    bound = opt.collision_bound(q, times, wide, 0.0)
    assert float(opt.collision_bound(q, times, still, 0.0).max()) < 1e-6
    with pytest.raises(DataError, match="times is NaN/Inf at configuration 1"):  # IndexError
        opt.collision_bound(q, torch.tensor([0.5, math.nan, 1.5, 2.0]), wide, 0.0)
    assert bool((bound[:3].diff() > 0).all())  # later the pose spreads thinner
    d = torch.tensor([0.3, 0.0, 0.0])
    for t, b in zip(times.tolist(), bound.tolist(), strict=True):
        std = 0.01 + 0.1 * t
        p = mc_ball_probability(d, torch.full((3,), std * std), 0.05 + 0.1, n=100_000)
        assert b >= p - 0.005
    assert p > 0.02  # at 2 s the widened pose reaches the robot
    for bad in (-0.1, float("nan"), True):
        with pytest.raises(ConfigError, match="spread"):
            static_human_forecast(pose, 5, 0.1, ("j",), spread=bad)


def test_window_restricts_the_constraint(point_robot: PointRobot) -> None:
    opt = TrajectoryOptimizer(
        point_robot, OptimizerCfg(iterations=0), human_spheres=one_sphere_map(0.1)
    )
    res = opt.solve(
        torch.tensor([-1.0, 0.0]),
        torch.tensor([1.0, 0.0]),
        forecast=static_forecast([0.0, 0.0, 0.0], 0.05),
        duration=1.9,
        window=(0.0, 0.5),
    )
    inside = res.times <= 0.5 + 1e-6
    assert float(res.bound[~inside].abs().max()) == 0.0
    assert res.feasible  # the straight line meets the human only after the window


def test_check_ahead_extends_the_constraint_past_the_window(point_robot: PointRobot) -> None:
    """A straight line that meets the human only after the window is accepted on the window
    alone; with ``check_ahead_s`` it is unsafe there: the plan runs the whole window and holds
    at its last waypoint clear of the human (independent Monte Carlo probability)."""
    std, r_h = 0.05, 0.1
    fc = static_forecast([0.0, 0.0, 0.0], std)
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    held = {}
    for ahead in (0.0, 1.0):
        cfg = OptimizerCfg(num_trajectories=1, iterations=0, confidence=0.95, check_ahead_s=ahead)
        opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(r_h))
        res = opt.solve(q_s, q_g, forecast=fc, duration=1.9, window=(0.0, 0.5))
        held[ahead] = res
        checked = res.times <= 0.5 + ahead + 1e-6
        after = ~checked
        assert float(res.bound[after].abs().max()) == 0.0  # nothing checked beyond
    assert held[0.0].feasible and held[0.0].wait_s == 0.0
    cut = held[1.0]
    assert not cut.feasible
    assert cut.wait_s == 0.0  # the whole window still runs: the hold comes after it
    probs = [
        mc_ball_probability(
            -torch.cat([q, torch.zeros(1)]), torch.full((3,), std**2), r_h + 0.05, n=20_000
        )
        for q in cut.q
    ]
    assert max(probs) <= 0.05  # the held plan stays clear of the human over its whole span
    assert float(cut.q[:, 0].max()) < -0.1  # it stops short of the human at x = 0
    in_window = cut.times <= 0.5 + 1e-6
    assert float(cut.bound[in_window].max()) <= 0.05
    with pytest.raises(ConfigError, match=r"check_ahead_s in \[0, 60\] s"):
        OptimizerCfg(check_ahead_s=-0.1)
    with pytest.raises(ConfigError, match="check_ahead_s"):
        OptimizerCfg(check_ahead_s=float("nan"))


def test_lookahead_bends_the_plan_after_the_window_and_never_constrains_it(
    point_robot: PointRobot,
) -> None:
    """The look-ahead penalty moves the waypoints after the window off the predicted human
    (independent Monte Carlo probability), while feasibility still depends on the window only."""
    std, r_h = 0.05, 0.1
    fc = static_forecast([0.0, 0.0, 0.0], std)
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    worst = []
    for weight in (0.0, 10.0):
        cfg = OptimizerCfg(
            iterations=60, confidence=0.95, weights=CostWeights(human_lookahead_penalty=weight)
        )
        opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(r_h))
        res = opt.solve(q_s, q_g, forecast=fc, duration=1.9, window=(0.0, 0.5))
        assert res.feasible
        after = res.times > 0.5 + 1e-6
        assert float(res.bound[after].abs().max()) == 0.0  # the bound reported is the window's
        assert ("human_lookahead_penalty" in res.cost_terms) == (weight > 0)
        probs = [
            mc_ball_probability(
                -torch.cat([q, torch.zeros(1)]), torch.full((3,), std**2), r_h + 0.05, n=20_000
            )
            for q in res.q[after]
        ]
        worst.append(max(probs))
    assert worst[0] > 0.5  # without it the path runs through the predicted human
    assert worst[1] <= 0.05  # with it the later waypoints keep to the confidence level


def test_inputs_and_config_are_validated(point_robot: PointRobot) -> None:
    assert isinstance(point_robot, KinematicModel)
    with pytest.raises(ConfigError, match="confidence"):
        OptimizerCfg(confidence=1.0)
    with pytest.raises(ConfigError, match="num_waypoints"):
        OptimizerCfg(num_waypoints=2)
    for b, w in ((8, 10**7), (10**9, 20), (2**14 + 1, 4)):
        with pytest.raises(ConfigError, match=rf"<= 65536 \(MAX_PLAN_WAYPOINTS.*got {b} \* {w}$"):
            OptimizerCfg(num_trajectories=b, num_waypoints=w)
    assert OptimizerCfg(num_trajectories=2**14, num_waypoints=4).num_trajectories == 2**14
    for bad in (float("inf"), float("nan"), 0.0, 60.5):
        with pytest.raises(ConfigError, match=r"expected horizon_s in \(0, 60\] s"):
            OptimizerCfg(horizon_s=bad)
    assert OptimizerCfg(horizon_s=60.0).horizon_s == 60.0
    for name in ("static_margin", "prune_margin", "lr"):  # NaN ran, changing the results
        for bad in (float("nan"), float("inf"), -0.1):
            with pytest.raises(ConfigError, match=f"expected {name} >"):
                OptimizerCfg(**{name: bad})
    for bad in (float("nan"), float("inf"), -0.1):
        with pytest.raises(ConfigError, match="expected perturbation_std finite and >= 0"):
            OptimizerCfg(perturbation_std=bad)
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(iterations=1))
    with pytest.raises(ShapeError, match=r"expected q_start \(2\)"):
        opt.solve(torch.zeros(3), torch.zeros(2))
    with pytest.raises(ShapeError, match=r"expected q_init \(8, 20, 2\)"):
        opt.solve(torch.zeros(2), torch.ones(2), q_init=torch.zeros(8, 10, 2))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        # a float count ran (10.0) or failed mid-solve with a raw TypeError (10.5)
        ({"iterations": 10.5}, r"expected iterations an integer, got 10\.5"),
        ({"iterations": 10.0}, r"expected iterations an integer, got 10\.0"),
        ({"warm_iterations": 2.0}, "expected warm_iterations an integer"),
        ({"iterations": True}, "expected iterations an integer"),
        ({"num_trajectories": "8"}, r"expected num_trajectories an integer >= 1, got '8'"),
        ({"num_trajectories": 8.0}, "expected num_trajectories an integer"),
        ({"num_waypoints": "20"}, "expected num_waypoints an integer >= 3"),
        ({"collision_substeps": 2.0}, "expected collision_substeps an integer >= 1"),
        ({"prune_every": "8"}, "expected prune_every an integer >= 1"),
        ({"seed": 1.5}, "expected seed an integer"),
        # a negative seed was taken as given (every other seed of the project is >= 0)
        ({"seed": -1}, "expected seed an integer >= 0"),
        ({"seed": 2**32}, r"expected seed an integer <= 4294967295 \(2\^32 - 1\)"),
        ({"horizon_s": "1"}, r"expected horizon_s in \(0, 60\] s, got '1'"),
        ({"lr": "0.005"}, "expected lr > 0 and finite"),
        ({"lr_final_ratio": "0.1"}, r"expected lr_final_ratio in \(0, 1\]"),
        ({"lr_final_ratio": math.nan}, r"expected lr_final_ratio in \(0, 1\]"),
        ({"perturbation_std": "0.3"}, "expected perturbation_std finite and >= 0"),
        ({"confidence": "0.95"}, r"expected confidence in \(0, 1\)"),
        ({"confidence": True}, r"expected confidence in \(0, 1\)"),
        ({"penalty_target": "0.5"}, r"expected penalty_target in \(0, 1\]"),
        ({"drop_action_mass": "0.01"}, r"expected drop_action_mass in \[0, 1\)"),
        ({"drop_action_mass": math.nan}, r"expected drop_action_mass in \[0, 1\)"),
        ({"acc_max": "6"}, "expected acc_max > 0 or None"),
        ({"acc_max": math.nan}, "expected acc_max > 0 or None"),
        ({"escape_within_s": "0.5"}, "expected escape_within_s >= 0 or None"),
        ({"escape_within_s": math.nan}, "expected escape_within_s >= 0 or None"),
        ({"static_margin": "0.02"}, "expected static_margin >= 0 and finite"),
        ({"prune_margin": None}, "expected prune_margin >= 0 and finite"),
        ({"safe_hold": 1}, "expected safe_hold True or False"),
        ({"human_spheres": ["inner"]}, "expected human_spheres 'inner' or 'cover'"),
        ({"weights": {}}, "expected weights to be CostWeights"),
        # unknown device names were taken here and failed later with torch's RuntimeError
        ({"device": "gpu0"}, r"expected device None or a torch device name .*'gpu0'"),
        ({"device": "cuda:x"}, r"expected device None or a torch device name .*'cuda:x'"),
        ({"device": 0}, "expected device None or a torch device name"),
    ],
)
def test_wrongly_typed_settings_are_config_errors_naming_the_field(
    kwargs: dict, match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        OptimizerCfg(**kwargs)


def test_valid_settings_keep_their_values() -> None:
    """Integer-valued numpy counts, ints for floats, inf where it means no limit, and device
    names torch parses (CUDA need not be present to name it) are all taken as given."""
    cfg = OptimizerCfg(
        num_trajectories=np.int64(4),
        iterations=0,
        horizon_s=2,
        confidence=np.float32(0.9),
        acc_max=math.inf,
        escape_within_s=math.inf,
        seed=np.int64(2**32 - 1),
        device="cuda:1",
    )
    assert cfg.num_trajectories == 4 and cfg.horizon_s == 2 and cfg.device == "cuda:1"
    for device in (None, "", "cpu", "cuda", "meta", torch.device("cpu")):
        assert OptimizerCfg(device=device).device == device


@pytest.mark.parametrize("field", ["mean", "var"])
def test_person_on_the_robot_with_a_nan_joint_is_never_a_safe_plan(
    point_robot: PointRobot, field: str
) -> None:
    """A person standing on the robot whose forecast holds one NaN: the Forecast refuses to be
    built, and one that was corrupted after it was built makes the bound 1 (unsafe), never 0."""
    with pytest.raises(DataError, match=f"forecast {field} is NaN/Inf for joint 'j'"):
        fc = static_forecast([0.0, 0.0, 0.0], 0.05)
        tensors = {"mean": fc.mean.clone(), "var": fc.var.clone()}
        tensors[field][0, 0, 3, 0, 1] = float("nan")
        Forecast(
            weights=fc.weights, dt=fc.dt, joint_names=("j",), action_names=("rest",), **tensors
        )
    fc = static_forecast([0.0, 0.0, 0.0], 0.05)
    getattr(fc, field)[0, 0, 3, 0, 1] = float("nan")  # bypasses the check on purpose
    cfg = OptimizerCfg(iterations=10)
    opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(0.2))
    q_s, q_g = torch.tensor([0.0, 0.0]), torch.tensor([0.05, 0.0])
    res = opt.solve(q_s, q_g, forecast=fc, duration=1.0)
    assert not res.feasible and not res.evasive
    assert res.hold_index == 0 and res.wait_s == pytest.approx(1.0)
    assert float(res.bound[1:].min()) == 1.0
    q = torch.zeros(3, 2)
    assert opt.collision_bound(q, torch.tensor([0.0, 0.5, 1.0]), fc, 0.0).tolist() == [1.0] * 3
    # independent check that the robot is in danger there: Monte Carlo collision probability
    assert mc_ball_probability(torch.zeros(3), torch.full((3,), 0.05**2), 0.25, n=20_000) > 0.99


def test_unsafe_if_not_finite_keeps_finite_bounds_and_their_gradients() -> None:
    mean = torch.zeros(4, 1, 2, 3)
    human = HumanObstacle(
        mean=mean, var=torch.ones_like(mean), radii=torch.ones(2), weights=torch.ones(1)
    )
    raw = torch.tensor([[0.1, 0.0, float("nan"), 0.7]], requires_grad=True)
    out = unsafe_if_not_finite(raw, human)
    assert out.tolist() == [[pytest.approx(0.1), 0.0, 1.0, pytest.approx(0.7)]]
    (out * torch.tensor([1.0, 2.0, 3.0, 4.0])).sum().backward()
    assert raw.grad.tolist() == [[1.0, 2.0, 0.0, 4.0]]
    for name in ("mean", "var", "weights"):
        t = getattr(human, name).clone()
        t.view(-1)[-1] = float("inf")
        bad = replace(human, **{name: t})  # the caches are not copied (init=False)
        assert unsafe_if_not_finite(raw.detach()[:, :2], bad).tolist() == [[1.0, 1.0]]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"window": (float("nan"), float("nan"))}, "window end a finite time"),
        ({"window": (0.0, float("inf"))}, "window end a finite time"),
        ({"window": (float("-inf"), 0.5)}, "window start a finite time"),
        ({"window": (0.6, 0.5)}, r"t_a <= t_b"),
        ({"window": (0.5,)}, r"expected window \(t_a, t_b\)"),
        ({"arrive": float("nan")}, "arrive a finite time"),
        ({"t0": float("inf")}, "t0 a finite time"),
        ({"forecast_t0": float("nan")}, "forecast_t0 a finite time"),
        ({"duration": float("nan")}, "duration a finite time"),
        ({"t0": "soon"}, "t0 a finite time"),
        ({"window": (None, 0.5)}, "window start a finite time"),
    ],
)
def test_non_finite_times_are_config_errors(
    point_robot: PointRobot, kwargs: dict, match: str
) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(iterations=1))
    with pytest.raises(ConfigError, match=match):
        opt.solve(torch.zeros(2), torch.ones(2), **kwargs)


def test_runs_on_the_device(device: torch.device) -> None:
    robot = PointRobot(device=device)
    opt = TrajectoryOptimizer(robot, OptimizerCfg(iterations=5), human_spheres=one_sphere_map(0.1))
    fc = static_forecast([0.0, 0.3, 0.0], 0.05, device=device)
    res = opt.solve(
        torch.tensor([-1.0, 0.0], device=device),
        torch.tensor([1.0, 0.0], device=device),
        forecast=fc,
    )
    assert res.q.device.type == device.type
    # the same plan as on the CPU (on the CPU itself: the same numbers again, seeded)
    cpu = TrajectoryOptimizer(
        PointRobot(), OptimizerCfg(iterations=5), human_spheres=one_sphere_map(0.1)
    ).solve(
        torch.tensor([-1.0, 0.0]),
        torch.tensor([1.0, 0.0]),
        forecast=static_forecast([0.0, 0.3, 0.0], 0.05),
    )
    torch.testing.assert_close(res.q.cpu(), cpu.q, atol=1e-4, rtol=0)
    torch.testing.assert_close(res.bound.cpu(), cpu.bound, atol=1e-4, rtol=0)
    assert res.feasible == cpu.feasible


def _iiwa():
    from iplanner_torch.robot.model import RobotModel

    return RobotModel.load("kuka_iiwa14")


def test_iiwa_plan_beside_a_gaussian_human_sphere() -> None:
    robot = _iiwa()
    q_s = robot.q_home.clone()
    q_g = q_s.clone()
    q_g[0] = 1.2
    # put a human sphere on the tool point's straight-line path, halfway
    mid = 0.5 * (q_s + q_g)
    p_mid = robot.ee_position(mid)
    cfg = OptimizerCfg(iterations=60, confidence=0.95)
    opt = TrajectoryOptimizer(robot, cfg, human_spheres=one_sphere_map(0.08))
    fc = static_forecast(p_mid.tolist(), 0.03)
    straight = opt.solve(q_s, q_g, forecast=fc, duration=3.0)
    assert straight.feasible, straight.cost_terms
    assert float(straight.bound.max()) <= 1 - cfg.confidence
    # independent check on the accepted plan: Monte Carlo over every robot sphere and waypoint
    centers = robot.sphere_centers(straight.q)  # (W, S_r, 3)
    d = p_mid - centers  # (W, S_r, 3)
    rad = robot.sphere_radii + 0.08
    near = (d.norm(dim=-1) - rad).flatten().argsort()[:5]
    for k in near.tolist():
        w, s = divmod(k, centers.shape[1])
        p = mc_ball_probability(d[w, s], torch.full((3,), 0.03**2), float(rad[s]), n=50_000)
        assert p <= 1 - cfg.confidence
    # without the human the straight line passes through it
    line_c = robot.sphere_centers(mid)
    assert float(((p_mid - line_c).norm(dim=-1) - rad).min()) < 0.0


class _Wall:
    """Half-space x >= x0 (signed distance of spheres to it)."""

    def __init__(self, x0: float) -> None:
        self.x0 = x0

    def clearance(self, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        return self.x0 - centers[..., 0] - radii


class _Box:
    """Axis-aligned square |x|, |y| <= h (signed distance of spheres to it, brute force)."""

    def __init__(self, h: float) -> None:
        self.h = h

    def clearance(self, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        d = centers[..., :2].abs() - self.h
        outside = d.clamp_min(0.0).norm(dim=-1)
        inside = d.max(dim=-1).values.clamp(max=0.0)
        return outside + inside - radii


def test_static_check_tolerates_a_goal_the_task_puts_in_contact() -> None:
    """A goal 1 cm into the wall (sphere model) is reachable; a path through a box is not."""
    from iplanner_torch.planning.optimizer import END_CLEARANCE_SLACK

    robot = PointRobot(r=0.05, dtype=torch.float64)
    cfg = OptimizerCfg(num_trajectories=4, num_waypoints=12, iterations=10, seed=0)
    opt = TrajectoryOptimizer(robot, cfg, static_scene=_Wall(1.0))
    q_s = torch.tensor([0.0, 0.0], dtype=torch.float64)
    q_g = torch.tensor([0.96, 0.0], dtype=torch.float64)  # clearance -0.01 m
    res = opt.solve(q_s, q_g, duration=2.0)
    assert res.feasible and res.wait_s == 0.0
    clear = 1.0 - res.q[:, 0] - 0.05
    assert float(clear.min()) >= -0.01 - END_CLEARANCE_SLACK - 1e-9
    # ends well clear, straight line (no iterations) through the box: rejected, and it waits
    opt_box = TrajectoryOptimizer(
        robot, OptimizerCfg(num_trajectories=1, num_waypoints=12, iterations=0), _Box(0.2)
    )
    res = opt_box.solve(
        torch.tensor([0.0, -1.0], dtype=torch.float64),
        torch.tensor([0.0, 1.0], dtype=torch.float64),
        duration=2.0,
    )
    assert not res.feasible and res.hold_index is not None
    held = torch.cat([res.q[res.hold_index], torch.zeros(1, dtype=torch.float64)])
    assert float(_Box(0.2).clearance(held.view(1, 3), robot.sphere_radii).min()) >= 0.0


def test_initial_trajectories_respect_the_velocity_limits_for_a_duration() -> None:
    """Large perturbations are scaled down per joint so finite-difference velocities stay within
    INIT_VEL_FRACTION of the limits; the base path and the pinned ends are unchanged."""
    from iplanner_torch.planning.optimizer import INIT_VEL_FRACTION

    arm = PlanarArm(dtype=torch.float64)
    opt = TrajectoryOptimizer(arm, OptimizerCfg(num_trajectories=16, perturbation_std=1.0))
    q_s = torch.tensor([0.0, -0.2, 0.1], dtype=torch.float64)
    q_g = torch.tensor([0.5, 0.3, -0.4], dtype=torch.float64)
    duration = 1.0
    free = opt.initial_trajectories(q_s, q_g, 16, seed=3)
    dt = duration / (opt.cfg.num_waypoints - 1)
    vel_free = (free[:, 1:] - free[:, :-1]).abs() / dt / opt.v_max
    assert float(vel_free.max()) > 1.0  # the unscaled perturbations are too fast
    q = opt.initial_trajectories(q_s, q_g, 16, seed=3, duration=duration)
    vel = (q[:, 1:] - q[:, :-1]).abs() / dt / opt.v_max
    assert float(vel.max()) <= INIT_VEL_FRACTION + 1e-9
    assert torch.allclose(q[:, 0], q_s.expand(16, 3))
    assert torch.allclose(q[:, -1], q_g.expand(16, 3))
    s = torch.linspace(0, 1, opt.cfg.num_waypoints, dtype=torch.float64)[:, None]
    assert torch.allclose(q[0], q_s + (3 * s**2 - 2 * s**3) * (q_g - q_s))  # rest to rest
    # a long duration leaves room: no scaling, the same trajectories as without a duration
    assert torch.allclose(opt.initial_trajectories(q_s, q_g, 16, seed=3, duration=100.0), free)


def test_initial_path_is_the_clamped_cubic_to_the_arrival() -> None:
    """The unperturbed initial trajectory is the cubic with the start velocity and rest at the
    arrival waypoint (scipy's clamped CubicSpline as reference), then holds the goal; its
    smoothness cost is below the constant-speed straight line's."""
    from scipy.interpolate import CubicSpline

    from iplanner_torch.planning.costs import joint_acc_l2

    arm = PlanarArm(dtype=torch.float64)
    opt = TrajectoryOptimizer(arm, OptimizerCfg(num_trajectories=4))
    w = opt.cfg.num_waypoints
    q_s = torch.tensor([0.0, -0.2, 0.1], dtype=torch.float64)
    q_g = torch.tensor([0.5, 0.3, -0.4], dtype=torch.float64)
    qd_s = torch.tensor([0.4, -0.3, 0.0], dtype=torch.float64)
    duration, travel = 1.9, 1.4
    arrival = opt.arrival_index(duration, travel)
    assert arrival == 14  # waypoint times are k * 0.1 s
    q = opt.initial_trajectories(
        q_s, q_g, 4, seed=0, duration=duration, qd_start=qd_s, arrival=arrival
    )
    dt = duration / (w - 1)
    t_a = arrival * dt
    ref = CubicSpline(
        [0.0, t_a],
        np.stack([q_s.numpy(), q_g.numpy()]),
        bc_type=((1, qd_s.numpy()), (1, np.zeros(3))),
    )
    t = np.minimum(np.arange(w) * dt, t_a)
    np.testing.assert_allclose(q[0].numpy(), ref(t), atol=1e-12)
    assert torch.allclose(q[:, arrival:], q_g.expand(4, w - arrival, 3))
    assert torch.allclose(q[:, 0], q_s.expand(4, 3))
    # the straight line at constant speed to the same arrival, for comparison
    s = torch.clamp(torch.arange(w, dtype=torch.float64) / arrival, max=1.0)[:, None]
    line = q_s + s * (q_g - q_s)
    acc_cubic = float(joint_acc_l2(q[:1], dt, qd_s))
    acc_line = float(joint_acc_l2(line[None], dt, qd_s))
    assert acc_cubic < 0.5 * acc_line
    with pytest.raises(ShapeError, match="qd_start"):
        opt.initial_trajectories(q_s, q_g, 4, seed=0, duration=duration, qd_start=qd_s[:2])


def _cubic_peaks(q_s, q_g, qd_s, t_total):
    """Peak |velocity| and |acceleration| per joint of scipy's clamped cubic (reference)."""
    from scipy.interpolate import CubicSpline

    cs = CubicSpline(
        [0.0, t_total],
        np.stack([q_s.numpy(), q_g.numpy()]),
        bc_type=((1, qd_s.numpy()), (1, np.zeros(q_s.shape[0]))),
    )
    t = np.linspace(0.0, t_total, 2001)
    return np.abs(cs(t, 1)).max(0), np.abs(cs(t, 2)).max(0)


def test_min_duration_from_rest_is_the_line_at_two_thirds_of_the_limits() -> None:
    arm = PlanarArm(dtype=torch.float64)
    opt = TrajectoryOptimizer(arm, OptimizerCfg())
    q_s = torch.tensor([0.0, -0.2, 0.1], dtype=torch.float64)
    q_g = torch.tensor([0.5, 0.9, -0.4], dtype=torch.float64)
    expected = float(1.5 * ((q_g - q_s).abs() / opt.v_max).max())
    assert opt.min_duration(q_s, q_g) == pytest.approx(expected, rel=1e-12)
    v_peak, _ = _cubic_peaks(q_s, q_g, torch.zeros(3, dtype=torch.float64), expected)
    assert np.all(v_peak <= opt.v_max.numpy() * (1 + 1e-6))


@pytest.mark.parametrize(
    "qd_s",
    # the last starts above the velocity limit (2): the cubic may keep that speed, not stop
    # the search at its longest duration (675 s)
    [[1.5, 0.0, 0.0], [-1.0, 0.8, 0.3], [0.0, 0.0, 0.0], [3.0, 0.0, -2.5]],
)
def test_min_duration_keeps_the_cubic_within_velocity_and_acceleration_limits(qd_s) -> None:
    """With a start velocity and an acceleration limit, the cubic of the returned duration
    stays within both limits (scipy's clamped CubicSpline, sampled densely, as reference) and
    one grid step shorter it does not: the shortest such duration."""
    from iplanner_torch.planning.optimizer import DURATION_GRID

    arm = PlanarArm(dtype=torch.float64)
    acc_max = 6.0
    opt = TrajectoryOptimizer(arm, OptimizerCfg(acc_max=acc_max))
    q_s = torch.tensor([0.0, -0.2, 0.1], dtype=torch.float64)
    q_g = torch.tensor([0.05, 0.1, -0.1], dtype=torch.float64)  # short moves: acc-bound
    qd = torch.tensor(qd_s, dtype=torch.float64)
    t_min = opt.min_duration(q_s, q_g, qd)
    v_lim = np.maximum(opt.v_max.numpy(), np.abs(qd.numpy()))
    v_peak, a_peak = _cubic_peaks(q_s, q_g, qd, t_min)
    assert np.all(v_peak <= v_lim * (1 + 1e-6))
    assert np.all(a_peak <= acc_max * (1 + 1e-6))
    v_short, a_short = _cubic_peaks(q_s, q_g, qd, t_min / DURATION_GRID)
    assert np.any(v_short > v_lim * (1 + 1e-6)) or np.any(a_short > acc_max * (1 + 1e-6))
    # the line's time ignores both the start velocity and the acceleration limit
    assert t_min > float(1.5 * ((q_g - q_s).abs() / opt.v_max).max())
    with pytest.raises(ShapeError, match="qd_start"):
        opt.min_duration(q_s, q_g, qd[:2])


@pytest.mark.parametrize("qd_s", [[0.0, 0.0, 0.0], [-1.0, 0.8, 0.3], [3.0, 0.0, -2.5]])
def test_min_duration_keeps_the_cubic_within_a_share_of_the_velocity_limits(qd_s) -> None:
    """With ``duration_vel_fraction`` f the cubic of the returned duration peaks within f
    times the velocity limits (or the start speed, where that is higher), one grid step
    shorter above them (scipy's clamped CubicSpline as reference); from rest, the line at
    2/3 of f times the limits; bad fractions are refused."""
    from iplanner_torch.planning.optimizer import DURATION_GRID

    arm = PlanarArm(dtype=torch.float64)
    f = 0.8
    opt = TrajectoryOptimizer(arm, OptimizerCfg(duration_vel_fraction=f))
    q_s = torch.tensor([0.0, -0.2, 0.1], dtype=torch.float64)
    q_g = torch.tensor([0.5, 0.9, -0.4], dtype=torch.float64)
    qd = torch.tensor(qd_s, dtype=torch.float64)
    t_min = opt.min_duration(q_s, q_g, qd)
    v_lim = np.maximum(f * opt.v_max.numpy(), np.abs(qd.numpy()))
    v_peak, _ = _cubic_peaks(q_s, q_g, qd, t_min)
    assert np.all(v_peak <= v_lim * (1 + 1e-6))
    # the search starts at the line at 2/3 of f times the limits; above it, the shortest
    line = float(1.5 * ((q_g - q_s).abs() / opt.v_max).max()) / f
    assert t_min >= line * (1 - 1e-12)
    if t_min > line * (1 + 1e-9):
        v_short, _ = _cubic_peaks(q_s, q_g, qd, t_min / DURATION_GRID)
        assert np.any(v_short > v_lim * (1 + 1e-6))
    full = TrajectoryOptimizer(arm, OptimizerCfg()).min_duration(q_s, q_g, qd)
    assert t_min >= full
    assert opt.min_duration(q_s, q_g) == pytest.approx(line, rel=1e-12)
    for bad in (0.0, 1.5, float("nan"), "0.9"):
        with pytest.raises(ConfigError, match="expected duration_vel_fraction in"):
            OptimizerCfg(duration_vel_fraction=bad)


def test_one_kinematics_call_gives_the_collision_point_spheres() -> None:
    """The merged forward kinematics equals sphere_centers of _collision_points (reference)."""
    arm = PlanarArm(dtype=torch.float64)
    opt = TrajectoryOptimizer(arm, OptimizerCfg(num_trajectories=3, collision_substeps=3))
    q = torch.randn(3, opt.cfg.num_waypoints, 3, generator=torch.Generator().manual_seed(0))
    q = q.double()
    win = torch.tensor([4, 5, 6, 7])
    centers, centers_x = opt._sphere_centers(q, win, True)
    assert torch.allclose(centers, arm.sphere_centers(q))
    assert torch.allclose(centers_x, arm.sphere_centers(opt._collision_points(q, win)))


def _approaching_forecast(std: float) -> Forecast:
    """One sphere on the x axis moving from x = 0.6 to 0 over 1 s, then resting."""
    n_f, dt = 30, 0.05
    t = dt * torch.arange(1, n_f + 1, dtype=torch.float64)
    mean = torch.zeros(1, 1, n_f, 1, 3, dtype=torch.float64)
    mean[0, 0, :, 0, 0] = 0.6 * (1.0 - t).clamp_min(0.0)
    return Forecast(
        weights=torch.ones(1, 1, dtype=torch.float64),
        mean=mean,
        var=torch.full_like(mean, std * std),
        dt=dt,
        joint_names=("j",),
        action_names=("approach",),
    )


def test_when_holding_is_riskier_than_moving_the_least_risky_trajectory_is_taken() -> None:
    # The person comes towards the start pose: no candidate meets the bound, and holding at
    # the last safe waypoint of the best one would be riskier than moving away on it.
    robot = PointRobot(dtype=torch.float64)
    cfg = OptimizerCfg(
        num_trajectories=2, num_waypoints=5, warm_iterations=0, collision_substeps=1
    )
    opt = TrajectoryOptimizer(robot, cfg, human_spheres=one_sphere_map(0.1))
    k = torch.arange(5, dtype=torch.float64)
    away = torch.stack([-0.1 * k, torch.zeros(5, dtype=torch.float64)], -1)  # (5, 2)
    towards = torch.stack([0.1 * k, torch.zeros(5, dtype=torch.float64)], -1)
    q_init = torch.stack([towards, away])
    res = opt.solve(
        away[0], away[-1], forecast=_approaching_forecast(0.2), duration=1.0, q_init=q_init
    )
    assert not res.feasible and res.evasive
    assert res.wait_s == 0.0 and res.hold_index is None
    assert torch.equal(res.q, away)

    # independent check: Monte Carlo risk of the chosen path's worst waypoint is below that of
    # holding at the away path's last safe waypoint (x = -0.2, first violation at t = 0.75)
    def risk(x: float, t: float) -> float:
        d = torch.tensor([0.6 * max(1.0 - t, 0.0) - x, 0.0, 0.0], dtype=torch.float64)
        return mc_ball_probability(d, torch.full((3,), 0.04, dtype=torch.float64), 0.15, n=50_000)

    moving = max(risk(float(q[0]), float(t)) for q, t in zip(res.q[1:], res.times[1:]))
    holding = max(risk(-0.2, float(t)) for t in res.times[3:])
    assert float(res.bound.max()) > 1 - cfg.confidence  # the bound rules the path out
    assert moving < holding
    # a hold that is itself safe is still a wait (paper sec. 5): a person resting further away
    res2 = opt.solve(
        away[0],
        torch.tensor([0.9, 0.0], dtype=torch.float64),
        forecast=static_forecast([1.0, 0.0, 0.0], 0.05, dtype=torch.float64),
        duration=1.0,
    )
    assert not res2.feasible and not res2.evasive and res2.wait_s > 0.0


class _Behind:
    """Half-space x <= x1 (signed distance of spheres to it): something behind the robot."""

    def __init__(self, x1: float) -> None:
        self.x1 = x1

    def clearance(self, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        return centers[..., 0] - self.x1 - radii


def _wait_cfg(**cfg_kw: object) -> OptimizerCfg:
    """Two given trajectories of 11 waypoints, not optimised, under an acceleration limit."""
    return OptimizerCfg(
        num_trajectories=2,
        num_waypoints=11,
        warm_iterations=0,
        collision_substeps=1,
        acc_max=6.0,
        **cfg_kw,
    )


def _escape_setup(behind: bool, **cfg_kw: object) -> tuple[TrajectoryOptimizer, dict]:
    robot = PointRobot(dtype=torch.float64)
    w = 11
    cfg = _wait_cfg(**{"escape_within_s": 0.2, **cfg_kw})
    static = _Behind(-0.08) if behind else None
    opt = TrajectoryOptimizer(robot, cfg, static_scene=static, human_spheres=one_sphere_map(0.1))
    s = torch.linspace(0.0, 1.0, w, dtype=torch.float64)
    towards = torch.stack([0.9 * s, torch.zeros_like(s)], -1)  # (W, 2), through the person
    bent = torch.stack([0.9 * s, -0.05 * torch.sin(math.pi * s)], -1)
    args = {
        "q_start": torch.zeros(2, dtype=torch.float64),
        "q_goal": torch.tensor([0.9, 0.0], dtype=torch.float64),
        "duration": 1.0,
        "q_init": torch.stack([towards, bent]),
    }
    return opt, args


@pytest.mark.parametrize("behind", [False, True])
def test_when_no_candidate_is_less_risky_than_holding_the_robot_steps_out_of_the_way(
    behind: bool,
) -> None:
    # The person comes at where the robot stands, arriving within 0.3 s, and every candidate
    # heads for a goal beyond the person: holding is unsafe at once and moving along any
    # candidate is riskier still. The plan then steps out of the way (the escape) instead of
    # waiting there. With a wall right behind the robot, the way out goes sideways, never into
    # the wall.
    opt, args = _escape_setup(behind)
    forecast = approaching(0.3, 0.3, -0.04)  # coming in just right of centre
    start = torch.zeros(2, dtype=torch.float64)
    res = opt.solve(
        args.pop("q_start"), args.pop("q_goal"), forecast=forecast, qd_start=start, **args
    )
    assert not res.feasible and res.evasive and res.escape
    assert res.wait_s == 0.0 and res.hold_index is None
    assert torch.equal(res.q[0], start)
    w = res.q.shape[0]
    hold_bound = opt.collision_bound(start.expand(w - 1, 2), res.times[1:], forecast, 0.0)
    assert float(res.bound.max()) < float(hold_bound.max())
    # within the velocity and acceleration limits, and clear of the wall
    dt = float(res.times[1] - res.times[0])
    vel = (res.q[1:] - res.q[:-1]) / dt
    assert bool((vel.abs() <= opt.v_max).all())
    # from rest: the first waypoint's acceleration too (its first step may change the
    # velocity by half acc_max dt only, see trajectory.accelerations)
    acc = accelerations(res.q.unsqueeze(0), dt, start).abs().max()
    assert float(acc) <= ACC_TOL * opt.cfg.acc_max
    if behind:
        assert float(res.q[:, 0].min()) >= -0.08 + 0.05 - 1e-9  # the sphere never enters
        assert float(res.q[-1, 1]) > 0.1  # sideways, away from the person's side
    else:
        assert float(res.q[-1, 0]) < -0.1  # straight back

    # independent check: Monte Carlo risk of the escape's worst waypoint against holding
    def risk(q: torch.Tensor, t: float) -> float:
        c = torch.tensor([0.3 * max(1.0 - t / 0.3, 0.0), -0.04, 0.0], dtype=torch.float64)
        d = c - torch.cat([q, torch.zeros(1, dtype=torch.float64)])
        var = torch.full((3,), 0.05**2, dtype=torch.float64)
        return mc_ball_probability(d, var, 0.15, n=50_000)

    escaping = max(risk(q, float(t)) for q, t in zip(res.q[1:], res.times[1:]))
    holding = max(risk(start, float(t)) for t in res.times[1:])
    assert escaping < holding
    assert holding > 1 - opt.cfg.confidence


def test_a_hold_that_breaks_the_limit_only_later_or_with_the_escape_off_stays_a_wait() -> None:
    # the same person arriving only after 1 s: the next cycle can still react, so it waits
    opt, args = _escape_setup(False)
    q_s, q_g = args.pop("q_start"), args.pop("q_goal")
    late = opt.solve(q_s, q_g, forecast=approaching(0.6, 1.0, -0.04), **args)
    assert not late.feasible and not late.evasive and not late.escape
    # arriving at once, but with the escape off
    opt_off, _ = _escape_setup(False, escape_within_s=None)
    off = opt_off.solve(q_s, q_g, forecast=approaching(0.3, 0.3, -0.04), **args)
    assert not off.feasible and not off.evasive and not off.escape and off.wait_s > 0.0
    with pytest.raises(ConfigError, match="escape_within_s"):
        OptimizerCfg(escape_within_s=-0.1)


def test_safe_hold_stops_before_where_the_person_is_predicted_to_come() -> None:
    # The person comes from x = 0.8 to rest at x = 0.3 by 1 s, and the only path heads for a
    # goal beyond them. The paper's wait holds at the path's last safe waypoint, where the
    # person then arrives (the hold breaks the limit); with safe_hold it stops earlier, at
    # the latest waypoint whose hold stays within the limit.
    robot = PointRobot(dtype=torch.float64)
    w = 11
    s = torch.linspace(0.0, 1.0, w, dtype=torch.float64)
    path = torch.stack([0.9 * s, torch.zeros_like(s)], -1)
    q_init = torch.stack([path, path])
    forecast = approaching(0.8, 1.0, 0.0)
    forecast.mean[..., 0] = forecast.mean[..., 0].clamp_min(0.3)
    results = {}
    for safe in (False, True):
        cfg = _wait_cfg(safe_hold=safe)
        opt = TrajectoryOptimizer(robot, cfg, human_spheres=one_sphere_map(0.1))
        res = opt.solve(path[0], path[-1], forecast=forecast, duration=1.0, q_init=q_init)
        assert not res.feasible and not res.evasive and res.wait_s > 0.0
        results[safe] = res
    limit = 1 - 0.95
    paper, safe = results[False], results[True]
    assert float(paper.bound.max()) > limit  # the paper's wait holds in the person's way
    assert float(safe.bound.max()) <= limit
    assert safe.hold_index < paper.hold_index
    assert float(safe.q[-1, 0]) < float(paper.q[-1, 0])

    # independent check: Monte Carlo risk of every waypoint of the safe-hold plan
    def risk(q: torch.Tensor, t: float) -> float:
        c = torch.tensor([max(0.8 * (1.0 - t), 0.3), 0.0, 0.0], dtype=torch.float64)
        d = c - torch.cat([q, torch.zeros(1, dtype=torch.float64)])
        var = torch.full((3,), 0.05**2, dtype=torch.float64)
        return mc_ball_probability(d, var, 0.15, n=50_000)

    assert max(risk(q, float(t)) for q, t in zip(safe.q[1:], safe.times[1:])) <= limit
    assert max(risk(q, float(t)) for q, t in zip(paper.q[1:], paper.times[1:])) > limit
    with pytest.raises(ConfigError, match="safe_hold"):
        OptimizerCfg(safe_hold=1)


def test_smooth_stop_slows_down_along_the_path_and_never_passes_the_hold() -> None:
    w = 20
    s = torch.linspace(0.0, 1.0, w, dtype=torch.float64)
    path = torch.stack([s, s.square()], -1)  # (W, 2), a curved path at uniform times
    for hold in (1, 4, 12):
        q = smooth_stop(path, hold)
        assert torch.equal(q[0], path[0])
        # starts at the path's own speed (first step within the second-order term)
        assert float((q[1] - path[1]).abs().max()) <= float((path[1] - path[0]).abs().max())
        # stops: constant from k = min(2 hold, W - 1) on, at or before the held waypoint
        k_stop = min(2 * hold, w - 1)
        assert torch.allclose(q[k_stop:], q[k_stop].expand_as(q[k_stop:]))
        assert float(q[:, 0].max()) <= float(path[hold, 0]) + 1e-12
        # on the path: every waypoint lies between two consecutive path waypoints (x = s)
        assert torch.allclose(q[:, 1], q[:, 0].square(), atol=(1 / (w - 1)) ** 2)
        # the speed never increases (a constant-rate slow-down)
        speed = (q[1:] - q[:-1]).norm(dim=-1)
        assert bool((speed[1:] <= speed[:-1] + 1e-9).all())


def test_acceleration_limit_is_met_by_the_accepted_plan(point_robot: PointRobot) -> None:
    # rest to rest over 1 m in 0.8 s (arrive): the least-squared-acceleration path peaks near
    # 6 / 0.8^2 = 9.4 m/s^2 (about 7 at the waypoints), a bang-bang profile needs
    # 4 / 0.8^2 = 6.25; with acc_max = 0.92 x the free peak the plan keeps
    # every waypoint acceleration (the first one, from the start velocity, included) within it
    q_s, q_g = torch.tensor([0.0, 0.0]), torch.tensor([1.0, 0.0])
    qd = torch.zeros(2)
    free = TrajectoryOptimizer(point_robot, OptimizerCfg(iterations=60))
    res_free = free.solve(q_s, q_g, duration=1.0, qd_start=qd, arrive=0.8)
    acc_free = accelerations(res_free.q, float(res_free.times[1] - res_free.times[0]), qd)
    limit = 0.92 * float(acc_free.abs().max())
    assert limit > 6.25 * 1.05  # feasible: above the bang-bang minimum
    capped = TrajectoryOptimizer(point_robot, OptimizerCfg(iterations=60, acc_max=limit))
    res = capped.solve(q_s, q_g, duration=1.0, qd_start=qd, arrive=0.8)
    acc = accelerations(res.q, float(res.times[1] - res.times[0]), qd)
    assert res.feasible
    assert float(acc.abs().max()) <= ACC_TOL * limit
    # the reported term is the squared excess of the plan's own accelerations (tiny: a hinge);
    # float32 accelerations near 8 leave an excess near 0.02 good to about 1e-4 relative
    excess = float(torch.relu(acc.abs() - limit).square().sum())
    assert float(res.cost_terms["joint_acc_limit_violation"]) == pytest.approx(excess, rel=1e-3)
    assert "joint_acc_limit_violation" not in res_free.cost_terms
    with pytest.raises(ConfigError, match="acc_max"):
        OptimizerCfg(acc_max=0.0)


def test_non_finite_gradients_leave_their_trajectories_where_they_are(
    point_robot: PointRobot, monkeypatch: pytest.MonkeyPatch
) -> None:
    """NaN or inf gradient entries in some trajectories keep those trajectories at their
    start; they do not spread to the others through the shared pair screen."""
    cfg = OptimizerCfg(iterations=20, prune_every=4)
    opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=one_sphere_map(0.1))
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    fc = static_forecast([0.0, 0.3, 0.0], 0.05)
    clean = opt.solve(q_s, q_g, forecast=fc)
    grad = torch.autograd.grad
    poisoned = [1, 4]

    def bad_grad(*args, **kwargs):
        (g,) = grad(*args, **kwargs)
        g = g.clone()
        g[1] = float("nan")
        g[4, 0] = float("inf")
        return (g,)

    monkeypatch.setattr(torch.autograd, "grad", bad_grad)
    res = opt.solve(q_s, q_g, forecast=fc)
    assert torch.isfinite(res.candidates).all() and torch.isfinite(res.q).all()
    duration = float(res.times[-1] - res.times[0])
    q0 = opt.initial_trajectories(q_s, q_g, cfg.num_trajectories, cfg.seed, duration)
    assert torch.allclose(res.candidates[1], q0[1], atol=1e-6)  # never moved
    assert not torch.allclose(res.candidates[4], q0[4], atol=1e-4)  # moved by its finite rows
    for b in range(cfg.num_trajectories):  # the others were optimised as before
        if b not in poisoned:
            assert torch.allclose(res.candidates[b], clean.candidates[b], atol=1e-5), b


def test_non_finite_start_goal_or_warm_start_is_a_data_error(point_robot: PointRobot) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(iterations=2))
    q_s, q_g, nan = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0]), float("nan")
    with pytest.raises(DataError, match="q_start is NaN/Inf at joint 0"):
        opt.solve(torch.tensor([nan, 0.0]), q_g)
    with pytest.raises(DataError, match="q_goal is NaN/Inf at joint 1"):
        opt.solve(q_s, torch.tensor([1.0, float("inf")]))
    with pytest.raises(DataError, match="qd_start is NaN/Inf at joint 0"):
        opt.solve(q_s, q_g, qd_start=torch.tensor([nan, 0.0]))
    q_init = torch.zeros(8, 20, 2)
    q_init[3, 5, 1] = nan
    with pytest.raises(DataError, match="q_init is NaN/Inf at trajectory 3, waypoint 5, joint 1"):
        opt.solve(q_s, q_g, q_init=q_init)


def test_optimizer_uses_the_configured_layout(point_robot) -> None:
    for layout, n in (("inner", 22), ("cover", None)):
        opt = TrajectoryOptimizer(point_robot, OptimizerCfg(human_spheres=layout))
        got = opt._spheres_for(JOINT_NAMES)
        want = HumanSphereMap.from_segments(JOINT_NAMES, layout=layout)
        assert torch.equal(got.matrix, want.matrix) and torch.equal(got.radii, want.radii)
        assert n is None or got.num_spheres == n
    with pytest.raises(ConfigError, match="human_spheres"):
        OptimizerCfg(human_spheres="outer")  # type: ignore[arg-type]


def test_solve_refuses_a_duration_beyond_max_horizon(point_robot: PointRobot) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(iterations=2))
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    for duration in (MAX_HORIZON_S + 1e-6, 1e9):
        with pytest.raises(ConfigError, match=r"expected duration <= 60 s \(MAX_HORIZON_S\)"):
            opt.solve(q_s, q_g, duration=duration)
    assert opt.solve(q_s, q_g, duration=MAX_HORIZON_S).times[-1] == pytest.approx(MAX_HORIZON_S)


def test_solve_refuses_an_arrival_before_the_start(point_robot: PointRobot) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(iterations=2))
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    with pytest.raises(ConfigError, match=r"expected arrive >= t0, got arrive=0.0, t0=1.0"):
        opt.solve(q_s, q_g, t0=1.0, duration=2.0, arrive=0.0)
    assert opt.solve(q_s, q_g, t0=1.0, duration=2.0, arrive=1.0) is not None


@pytest.mark.parametrize("forecast", ["x", 0.5, torch.zeros(1, 1, 3)])
def test_solve_and_collision_bound_refuse_a_forecast_of_another_type(
    point_robot: PointRobot, forecast: object
) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(iterations=2))
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    kind = type(forecast).__name__
    with pytest.raises(ShapeError, match=f"expected forecast a Forecast or None, got {kind}"):
        opt.solve(q_s, q_g, forecast=forecast)  # type: ignore[arg-type]
    with pytest.raises(ShapeError, match=f"expected forecast a Forecast, got {kind}"):
        opt.collision_bound(torch.zeros(2, 2), torch.tensor([0.1, 0.2]), forecast, 0.0)  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_collision_bound_refuses_non_finite_configurations(
    point_robot: PointRobot, value: float
) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(), human_spheres=one_sphere_map(0.1))
    fc = static_forecast([0.0, 0.5, 0.0], 0.05)
    q = torch.tensor([[1.5, -1.5], [0.0, 0.5]])
    q[1, 0] = value
    with pytest.raises(DataError, match="q is NaN/Inf at configuration 1, joint 0"):
        opt.collision_bound(q, torch.tensor([0.1, 0.2]), fc, 0.0)


def test_collision_bound_refuses_no_configurations(point_robot: PointRobot) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(), human_spheres=one_sphere_map(0.1))
    fc = static_forecast([0.0, 0.5, 0.0], 0.05)
    with pytest.raises(ShapeError, match=r"expected q \(N, 2\) with N >= 1, got \(0, 2\)"):
        opt.collision_bound(torch.zeros(0, 2), torch.zeros(0), fc, 0.0)


@pytest.mark.parametrize("name", ["q_start", "q_goal", "qd_start"])
@pytest.mark.parametrize("value", [math.nan, math.inf])
def test_min_duration_refuses_non_finite_inputs(
    point_robot: PointRobot, name: str, value: float
) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg())
    args = {"q_start": torch.tensor([-1.0, 0.0]), "q_goal": torch.tensor([1.0, 0.0])}
    args["qd_start"] = torch.zeros(2)
    args[name][1] = value
    with pytest.raises(DataError, match=f"{name} is NaN/Inf at joint 1"):
        opt.min_duration(**args)


@pytest.mark.parametrize("num", [0, -1, 2.5, True])
def test_initial_trajectories_refuse_a_bad_count(point_robot: PointRobot, num: object) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg())
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    with pytest.raises(ConfigError, match="expected num an integer >= 1"):
        opt.initial_trajectories(q_s, q_g, num, 0)  # type: ignore[arg-type]


@pytest.mark.parametrize("name", ["q_start", "q_goal", "qd_start"])
def test_initial_trajectories_refuse_non_finite_ends(point_robot: PointRobot, name: str) -> None:
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg())
    args = {"q_start": torch.tensor([-1.0, 0.0]), "q_goal": torch.tensor([1.0, 0.0])}
    args["qd_start"] = torch.zeros(2)
    args[name][0] = math.nan
    with pytest.raises(DataError, match=f"{name} is NaN/Inf at joint 0"):
        opt.initial_trajectories(
            args["q_start"], args["q_goal"], 2, 0, 1.0, qd_start=args["qd_start"]
        )


@pytest.mark.parametrize("hold", [0, -1, 1.5, True])
def test_smooth_stop_refuses_a_hold_below_one(hold: object) -> None:
    with pytest.raises(ConfigError, match="expected hold an integer >= 1"):
        smooth_stop(torch.zeros(5, 2), hold)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("n_f", "dt", "match"),
    [
        (2.5, 0.1, "expected n_f an integer >= 1, got 2.5"),
        (3, "a", "expected dt > 0 and finite, got 'a'"),
        (3, math.inf, "expected dt > 0 and finite, got inf"),
        (3, 0.0, "expected dt > 0 and finite, got 0.0"),
    ],
)
def test_static_human_forecast_refuses_bad_frames_and_steps(
    n_f: object, dt: object, match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        static_human_forecast(torch.zeros(1, 3), n_f, dt, ("j",))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: static_human_forecast(torch.zeros(1, 3), 3, 0.1, ("j",), std="x"),
         "expected std > 0 and finite, got 'x'"),
        (lambda: static_human_forecast(torch.zeros(1, 3), 3, 0.1, None),
         "expected joint_names a sequence of strings, got None"),
        (lambda: static_human_forecast(torch.zeros(4, 3), 3, 0.1, "head"),
         "expected joint_names a sequence of strings, got 'head'"),
        (lambda: path_forecast(torch.zeros(3, 1, 3), "0.1", ("j",), std=0.01, action="a"),
         "expected dt > 0 and finite, got '0.1'"),
        (lambda: path_forecast(torch.zeros(3, 1, 3), True, ("j",), std=0.01, action="a"),
         "expected dt > 0 and finite, got True"),
        (lambda: path_forecast(torch.zeros(3, 1, 3), 0.1, ("j",), std=None, action="a"),
         "expected std > 0 and finite, got None"),
    ],
    ids=["std_str", "names_none", "names_one_string", "dt_str", "dt_bool", "std_none"],
)  # fmt: skip
def test_forecast_helpers_name_arguments_of_the_wrong_type(call, match: str) -> None:
    """They were bare TypeErrors, a dt of True was taken as 1 s, and one string of joint
    names was split into one-letter names."""
    with pytest.raises(ConfigError, match=match):
        call()


def test_a_goal_outside_the_joint_limits_is_refused(point_robot: PointRobot) -> None:
    """It was planned towards, stopped at the limit, never pinned and never feasible (a
    replanning robot would wait there for good); a goal at a limit is fine."""
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg(num_trajectories=2, iterations=2))
    start = torch.tensor([-1.0, 0.0])
    with pytest.raises(DataError, match=r"expected q_goal within the joint limits, got "
                       r"q_goal\[0\] = 5.0 rad outside \[-2.0, 2.0\]"):  # fmt: skip
        opt.solve(start, torch.tensor([5.0, 0.0]))
    res = opt.solve(start, torch.tensor([2.0, 0.0]))
    assert res.q[-1].tolist() == [2.0, 0.0]


def test_solve_refuses_a_unix_timestamp_but_plans_hours_into_an_episode(
    point_robot: PointRobot,
) -> None:
    """At t0 = 1.7e9 s the float32 waypoint times were all equal: forecast lookups collapsed,
    the plan was reported feasible and its trajectory() raised ConfigError."""
    opt = TrajectoryOptimizer(
        point_robot, OptimizerCfg(iterations=2), human_spheres=one_sphere_map(0.1)
    )
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    fc = static_forecast([0.0, 1.0, 0.0], 0.05)
    with pytest.raises(ConfigError, match="pass times relative to the episode start"):
        opt.solve(q_s, q_g, forecast=fc, forecast_t0=1.7e9, t0=1.7e9)
    # four hours of simulated time (the replanner's t0 is the simulation clock) still plan
    t0 = 4 * 3600.0
    res = opt.solve(q_s, q_g, forecast=fc, forecast_t0=t0, t0=t0, duration=1.0)
    traj = res.trajectory()
    assert traj.t_start == pytest.approx(t0) and traj.t_end == pytest.approx(t0 + 1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"seed": 1.5}, "expected seed an integer, got 1.5"),
        ({"seed": 2**64}, "expected seed a 64-bit integer"),
        ({"arrival": math.nan}, "expected arrival an integer, got nan"),
        ({"duration": math.nan}, "expected duration > 0 and finite, got nan"),
        ({"duration": -1.0}, "expected duration > 0 and finite, got -1.0"),
    ],
)
def test_initial_trajectories_refuse_bad_numbers(
    point_robot: PointRobot, kwargs: dict, match: str
) -> None:
    """A float seed and a NaN arrival used to raise raw errors; a NaN duration was ignored."""
    opt = TrajectoryOptimizer(point_robot, OptimizerCfg())
    q_s, q_g = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0])
    args = {"seed": 0, **kwargs}
    with pytest.raises(ConfigError, match=match):
        opt.initial_trajectories(q_s, q_g, 2, **args)


def test_smooth_stop_refuses_a_path_without_joints_or_of_one_waypoint() -> None:
    """A (W,) path used to give a (W, W) result; a single waypoint an IndexError."""
    with pytest.raises(ShapeError, match=r"expected q \(W, J\), got \(5,\)"):
        smooth_stop(torch.zeros(5), 1)
    with pytest.raises(ShapeError, match=r"expected q \(W, J\) with W >= 2, got \(1, 2\)"):
        smooth_stop(torch.zeros(1, 2), 1)


def test_optimizer_refuses_a_non_robot_or_a_dict_cfg(point_robot: PointRobot) -> None:
    """Both used to raise raw AttributeErrors."""
    with pytest.raises(ConfigError, match="expected cfg an OptimizerCfg or None, got dict"):
        TrajectoryOptimizer(point_robot, {"iterations": 3})  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected robot a KinematicModel .* got NoneType"):
        TrajectoryOptimizer(None)  # type: ignore[arg-type]
    point_robot.sphere_radii = point_robot.sphere_radii.long()
    with pytest.raises(ShapeError, match="expected robot.sphere_radii of a floating dtype"):
        TrajectoryOptimizer(point_robot)


def test_speed_scale_slows_every_plan_to_its_share_of_the_velocity_limits() -> None:
    """``speed_scale``: the limits the optimiser plans to are that share of the robot's, the
    shortest time from rest grows by its inverse, and a plan at the default duration keeps
    every finite-difference joint speed within the scaled limits, where the unscaled plan of
    the same move exceeds them (the setting binds)."""
    arm = PlanarArm(dtype=torch.float64)
    q_s = torch.tensor([0.1, -0.5, 0.3], dtype=torch.float64)
    q_g = torch.tensor([1.2, 0.6, -0.9], dtype=torch.float64)
    peaks, times = {}, {}
    for scale in (1.0, 0.5):
        opt = TrajectoryOptimizer(arm, OptimizerCfg(speed_scale=scale))
        torch.testing.assert_close(opt.v_max, scale * arm.v_max)
        times[scale] = opt.min_duration(q_s, q_g)
        res = opt.solve(q_s, q_g)
        assert res.feasible
        speed = (res.q[1:] - res.q[:-1]).abs() / (res.times[1:] - res.times[:-1])[:, None]
        peaks[scale] = (speed / arm.v_max).max().item()  # (W - 1, J) -> share of the limits
    assert times[0.5] == pytest.approx(2.0 * times[1.0], rel=1e-12)
    assert peaks[0.5] <= 0.5 * (1 + 1e-3)
    assert peaks[1.0] > 0.5 * (1 + 1e-3)
    for bad in (0.0, 1.5, math.nan, "0.5"):
        with pytest.raises(ConfigError, match="expected speed_scale in"):
            OptimizerCfg(speed_scale=bad)


def test_keep_start_takes_the_start_when_the_iterations_made_it_rougher() -> None:
    """``keep_start``: with a step size large enough for Adam's normalised steps to throw the
    cubic cold start off, the plan is that start itself (the least-acceleration cubic, rebuilt
    here with the solve's seed and duration), not the rougher iterated trajectory the default
    takes; the next cycle's warm starts hold the plan."""
    arm = PlanarArm(dtype=torch.float64)
    q_s = torch.tensor([0.1, -0.5, 0.3], dtype=torch.float64)
    q_g = torch.tensor([0.5, -0.1, 0.0], dtype=torch.float64)
    plans = {}
    for keep in (False, True):
        cfg = OptimizerCfg(lr=0.05, keep_start=keep, num_trajectories=4)
        opt = TrajectoryOptimizer(arm, cfg)
        res = opt.solve(q_s, q_g)
        assert res.feasible
        assert res.candidates.shape == (4, cfg.num_waypoints, 3)
        assert any(torch.equal(row, res.q) for row in res.candidates)
        plans[keep] = res
    duration = max(cfg.horizon_s, opt.min_duration(q_s, q_g))
    cubic = opt.initial_trajectories(q_s, q_g, 4, cfg.seed, duration)[0]
    dt = duration / (cfg.num_waypoints - 1)

    def rough(q: torch.Tensor) -> float:
        return float(accelerations(q, dt).square().sum())

    assert rough(plans[False].q) > 2.0 * rough(cubic)  # the iterations made it rougher
    torch.testing.assert_close(plans[True].q, cubic, rtol=0.0, atol=1e-12)
    for bad in (1, "yes", None):
        with pytest.raises(ConfigError, match="keep_start"):
            OptimizerCfg(keep_start=bad)


class _TimedOptimizer(TrajectoryOptimizer):
    """On a fake clock, every optimiser iteration takes 10 ms and every acceptance check
    30 ms (the clock only moves here, so the counts do not depend on the machine)."""

    def __init__(self, *args, clock, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.clock, self._accepting = clock, False

    def _terms(self, *args, **kwargs):
        if not self._accepting:
            self.clock.now += 0.010
        return super()._terms(*args, **kwargs)

    def _accept(self, *args, **kwargs):
        self._accepting = True
        self.clock.now += 0.030
        try:
            return super()._accept(*args, **kwargs)
        finally:
            self._accepting = False


def test_a_deadline_stops_the_iterations_before_it_is_passed(
    point_robot: PointRobot, fake_clock
) -> None:
    """No iteration starts that would, with the acceptance check, end after the deadline; the
    first always runs; a deadline never reached changes nothing."""
    import iplanner_torch.planning.optimizer as optimizer_module

    clock = fake_clock(optimizer_module)
    cfg = OptimizerCfg(iterations=20)
    opt = _TimedOptimizer(point_robot, cfg, human_spheres=one_sphere_map(0.1), clock=clock)
    args = (torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 0.0]))
    fc = static_forecast([0.0, 0.05, 0.0], 0.05)
    full = opt.solve(*args, forecast=fc)  # no deadline: every iteration, and the check's time
    assert full.timings["iterations"] == 20 and not full.cut_short
    # 10 ms an iteration and 30 ms for the check: 9 iterations end at 90 ms, the check at
    # 120 ms; a 10th would end the solve at 130 ms
    start = clock.now
    cut = opt.solve(*args, forecast=fc, deadline=start + 0.125)
    assert cut.timings["iterations"] == 9 and cut.cut_short
    assert clock.now - start == pytest.approx(0.120)
    cut = opt.solve(*args, forecast=fc, deadline=clock.now + 0.135)
    assert cut.timings["iterations"] == 10
    assert opt.solve(*args, forecast=fc, deadline=clock.now - 1.0).timings["iterations"] == 1
    late = opt.solve(*args, forecast=fc, deadline=clock.now + 1e6)
    assert late.timings["iterations"] == 20 and not late.cut_short
    assert torch.equal(late.candidates, full.candidates) and torch.equal(late.q, full.q)
    for bad in (math.nan, math.inf):
        with pytest.raises(ConfigError, match="deadline"):
            opt.solve(*args, forecast=fc, deadline=bad)


def test_window_indices_by_hand() -> None:
    """Waypoints at 0, 0.25, ..., 1 s and the window (0, 0.6): the segments that overlap it
    end at waypoints 1, 2 and 3 (the one over 0.5-0.75 s crosses the window's end and is
    checked); (0.3, 0.3) gives the segment that holds 0.3 s; no window, every waypoint but
    the pinned start."""
    arm = PlanarArm(dtype=torch.float64)
    opt = TrajectoryOptimizer(arm, OptimizerCfg())
    times = torch.linspace(0.0, 1.0, 5, dtype=torch.float64)
    assert opt._window_indices(times, (0.0, 0.6)).tolist() == [1, 2, 3]
    assert opt._window_indices(times, (0.3, 0.3)).tolist() == [2]
    assert opt._window_indices(times, None).tolist() == [1, 2, 3, 4]


def test_the_summed_bound_refuses_a_path_between_two_spheres_that_the_maximum_accepts(
    point_robot: PointRobot,
) -> None:
    """A straight path through the gap between two person spheres: each is touched at the
    middle with probability about 0.032 (Monte Carlo), either of them with about 0.064, over
    the limit of 0.05. The paper's maximum (0.048) accepts the path; Boole's sum refuses it
    and the plan waits before the gap."""
    from iplanner_torch.planning.costs import PRUNED_PAIR_BOUND

    std, n_f = 0.03, 30
    mean = torch.tensor([[0.0, 0.2, 0.0], [0.0, -0.2, 0.0]], dtype=torch.float64)
    mean = mean.view(1, 1, 1, 2, 3).expand(1, 1, n_f, 2, 3).clone()
    forecast = Forecast(
        weights=torch.ones(1, 1, dtype=torch.float64),
        mean=mean,
        var=torch.full_like(mean, std * std),
        dt=0.1,
        joint_names=("a", "b"),
        action_names=("rest",),
    )
    spheres = HumanSphereMap(torch.eye(2), torch.tensor([0.1, 0.1]))
    w = 11
    x = torch.linspace(-1.0, 1.0, w, dtype=torch.float64)
    line = torch.stack([x, torch.zeros_like(x)], -1)  # (W, 2), through (0, 0) at k = 5
    gen = torch.Generator().manual_seed(0)
    draws = mean[0, 0, 0] + std * torch.randn(400_000, 2, 3, generator=gen, dtype=torch.float64)
    p_any = float((draws.norm(dim=-1) <= 0.15).any(-1).double().mean())  # robot radius 0.05
    assert p_any > 0.06
    plans = {}
    for reduce in ("max", "sum"):
        cfg = OptimizerCfg(
            num_trajectories=1, num_waypoints=w, iterations=0, warm_iterations=0,
            collision_substeps=1, bound_reduce=reduce,
        )  # fmt: skip
        opt = TrajectoryOptimizer(point_robot, cfg, human_spheres=spheres)
        middle = opt.collision_bound(line[5:6], torch.tensor([1.0]), forecast, 0.0)
        plans[reduce] = (float(middle), opt.solve(
            line[0], line[-1], forecast=forecast, duration=2.0, q_init=line.unsqueeze(0)
        ))  # fmt: skip
    top, by_max = plans["max"]
    total, by_sum = plans["sum"]
    assert top < 0.05 < p_any <= total
    assert total == pytest.approx(2.0 * top + 2 * PRUNED_PAIR_BOUND, rel=1e-6)  # symmetric
    assert by_max.feasible and torch.allclose(by_max.q.double(), line, atol=1e-6)
    assert not by_sum.feasible and by_sum.wait_s > 0.0
    assert float(by_sum.q[:, 0].max()) < -0.1  # held before the gap
    with pytest.raises(ConfigError, match="expected bound_reduce 'max' or 'sum', got 'mean'"):
        OptimizerCfg(bound_reduce="mean")


def test_covariant_step_is_chomps_update_and_adams_is_not() -> None:
    """``step_rule="covariant"``: one iteration moves the free waypoints x of every trajectory
    by ``-s A^-1 grad_x U`` (CHOMP's covariant update; A = D^T D with D the second-difference
    matrix, built here), with s such that the step's largest second difference is lr; Adam's
    normalised step (the default) is not along that direction. U is the smoothness cost alone
    (a slow path inside the joint limits), written out here."""
    arm = PlanarArm(dtype=torch.float64)
    w, j, b, lr, duration = 12, 3, 2, 1e-3, 4.0
    dt = duration / (w - 1)
    gen = torch.Generator().manual_seed(3)
    s = torch.linspace(0.0, 1.0, w, dtype=torch.float64).view(1, w, 1)
    q_s = torch.tensor([0.1, -0.5, 0.3], dtype=torch.float64)
    q_g = torch.tensor([0.5, -0.1, 0.0], dtype=torch.float64)
    bump = torch.sin(math.pi * s) * torch.randn(b, 1, j, generator=gen, dtype=torch.float64)
    q_init = q_s + s * (q_g - q_s) + 0.2 * bump  # (B, W, J)

    n = w - 2
    d = torch.zeros(n + 2, n + 2, dtype=torch.float64)  # second differences, all waypoints
    for i in range(1, n + 1):
        d[i, i - 1 : i + 2] = torch.tensor([1.0, -2.0, 1.0], dtype=torch.float64)
    d = d[1 : n + 1]  # (n, W): one row per interior waypoint
    x = q_init.clone().requires_grad_(True)
    acc = torch.einsum("iw,bwj->bij", d, x) / dt**2
    u = CostWeights().joint_acc_l2 * dt * acc.square().sum()
    (grad,) = torch.autograd.grad(u, x)
    g_x = grad[:, 1:-1]  # (B, n, J) the free waypoints' gradient
    d_free = d[:, 1:-1]  # (n, n)
    a_inv = torch.linalg.inv(d_free.T @ d_free)

    steps = {}
    for rule in ("covariant", "adam"):
        cfg = OptimizerCfg(
            num_trajectories=b, num_waypoints=w, warm_iterations=1, lr=lr, step_rule=rule
        )
        res = TrajectoryOptimizer(arm, cfg).solve(q_s, q_g, duration=duration, q_init=q_init)
        steps[rule] = (res.candidates - q_init)[:, 1:-1]  # (B, n, J)
    want = -torch.einsum("mn,bnj->bmj", a_inv, g_x)
    z_step = torch.einsum("mn,bnj->bmj", d_free, want)
    want = want * lr / z_step.abs().amax(dim=(1, 2), keepdim=True)
    torch.testing.assert_close(steps["covariant"], want, rtol=1e-9, atol=1e-12)
    cos = torch.nn.functional.cosine_similarity(steps["adam"].flatten(1), want.flatten(1))
    assert bool((cos < 0.99).all())  # Adam's step leaves the covariant direction
    with pytest.raises(ConfigError, match="step_rule"):
        OptimizerCfg(step_rule="sgd")
