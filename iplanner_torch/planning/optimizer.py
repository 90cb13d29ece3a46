"""Batched probabilistic trajectory optimisation (paper sec. 5, ITOMP with a prediction).

B trajectories of W space-time waypoints are optimised at once from diverse initial
trajectories (the path of least squared acceleration to the goal, a cubic in joint space from
the start velocity to rest, plus random smooth perturbations: the paper's parallel threads,
theorem threads). The optimiser is Adam on the free waypoints with a decaying
step and projection onto the joint limits, on the second differences of the waypoints (so
smoothness is a well-conditioned sum of squares and every step moves waypoints smoothly, as the
covariant updates of CHOMP / ITOMP do): every term is cheap to differentiate, the
collision-bound term is non-smooth (a max over sphere pairs) and badly scaled, which Adam's
per-coordinate normalisation tolerates, and each trajectory's moments are separate so the B
problems stay independent. The confidence constraint ``bound <= 1 - delta`` on every waypoint of
the execution window enters as a quadratic penalty on ``log(bound / target)`` above zero, with
``target`` a fraction of ``1 - delta`` so that solutions land inside the feasible set; the
constraint is then checked exactly (all sphere pairs) when a trajectory is accepted. When no
trajectory meets it, the plan follows the best one up to its last safe waypoint and waits there
(sec. 5), reporting the delay. Beyond the paper, always on: when holding there is itself
above the limit and moving along a candidate has a lower peak bound, the least risky
candidate runs instead (an evasion, ``OptimizeResult.evasive``; its bound is above the limit
too, but below the hold's). Beyond the paper, opt-in (the ``conf/planner`` files turn the
first on): ``OptimizerCfg.safe_hold`` stops a wait earlier when its hold would itself break the
constraint, and ``OptimizerCfg.escape_within_s`` steps out of the person's way when holding
breaks it within that time and no candidate is less risky. Also beyond the paper,
``CostWeights.human_lookahead_penalty`` puts the same penalty, as a soft cost only, on the
waypoints after the window, so a plan bends around where the person is predicted to be before
that part of it is executed, and ``OptimizerCfg.check_ahead_s`` (opt-in) makes the constraint
itself cover the waypoints up to that many seconds after the window (the forecast held at its
last frame beyond its horizon), so that no plan takes the robot where the person is
predicted to be just after the window. ``OptimizerCfg.keep_start`` (opt-in; the
``conf/planner`` files turn it on) sends each trajectory to the acceptance as iterated or as
it started, whichever has the lower cost: Adam's normalised steps move every waypoint by
about the step size, so the iterations can leave a start that needed no change rougher.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import torch

from iplanner_torch.checks import finite_time, flag, integer, is_real, non_negative, positive
from iplanner_torch.checks import seed as check_seed
from iplanner_torch.collision.human_spheres import HumanSphereMap, SphereLayout
from iplanner_torch.errors import ConfigError, DataError, PlanningError, ShapeError
from iplanner_torch.planning import costs as C
from iplanner_torch.planning.costs import unsafe_if_not_finite  # noqa: F401 (its old home)
from iplanner_torch.planning.trajectory import Trajectory, accelerations, uniform_times
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import all_finite, check_finite, check_shape

#: Accepted plans keep every waypoint-to-waypoint velocity within this factor of the limits.
VEL_TOL = 1.05
#: How far a goal may lie outside the joint limits [rad] (a goal at a limit, rounded).
GOAL_LIMIT_TOL = 1e-5
#: Tolerance on the acceleration limit (``OptimizerCfg.acc_max``) at acceptance.
ACC_TOL = 1.1
#: Slack [m] below the clearance of a plan's pinned ends within which its waypoints still pass
#: the static check: the start is where the robot is and the goal is what the task asks (a
#: grasp point just above the table), so a plan is only required to do as well as its ends.
END_CLEARANCE_SLACK = 0.01
#: Initial trajectories keep every waypoint-to-waypoint velocity within this share of the
#: limits: their random perturbations are scaled down per joint where needed (a perturbed
#: trajectory that starts too fast is rarely repaired by the few iterations of a cycle, and the
#: acceptance check rejects it).
INIT_VEL_FRACTION = 0.9
#: Relative step and number of the durations :meth:`TrajectoryOptimizer.min_duration` tries.
DURATION_GRID = 1.02
DURATION_STEPS = 400
#: Adam's first-moment decay.
BETA1 = 0.9
#: Adam's second-moment decay: short memory, so steps do not stall once the large early
#: gradients are gone (with 0.999 the smoothness bowl stalls about 1e-2 rad from its minimum).
BETA2 = 0.9
#: How an iteration steps (``OptimizerCfg.step_rule``).
StepRule = Literal["adam", "covariant"]
STEP_RULES: tuple[str, ...] = ("adam", "covariant")


@runtime_checkable
class KinematicModel(Protocol):
    """What the optimiser needs of a robot (``robot.model.RobotModel`` satisfies it).

    Attributes:
        q_min: (J,) lower joint limits [rad].
        q_max: (J,) upper joint limits [rad].
        v_max: (J,) joint velocity limits [rad/s].
        sphere_radii: (S_r,) bounding-sphere radii [m]; its device and dtype are the planner's.
        num_joints: J.
    """

    q_min: torch.Tensor
    q_max: torch.Tensor
    v_max: torch.Tensor
    sphere_radii: torch.Tensor
    num_joints: int

    def sphere_centers(self, q: torch.Tensor) -> torch.Tensor:
        """(..., J) joint positions [rad] -> (..., S_r, 3) sphere centres [m], differentiable."""
        ...


#: largest ``horizon_s``, the least duration of a plan [s]: a plan stretched over more than a
#: minute hardly moves the robot (a horizon of 1e9 s used to run and report an idle robot as
#: safe)
MAX_HORIZON_S = 60.0

#: most candidate waypoints one solve holds, ``num_trajectories * num_waypoints`` (the paper's
#: 8 x 20 is 160): the collision bound keeps a value per waypoint and sphere pair, so a count
#: beyond this (a typo's extra zeros) would exhaust the memory midway, killing the process
#: with what it had not yet written; it is refused when the settings are made
MAX_PLAN_WAYPOINTS = 2**16


@dataclass(frozen=True, kw_only=True)
class OptimizerCfg:
    """Settings of :class:`TrajectoryOptimizer`."""

    # B, trajectories optimised in parallel (the paper's threads)
    num_trajectories: int = 8
    # W, waypoints per trajectory including start and goal
    num_waypoints: int = 20
    # default time from start to goal [s] (lengthened to respect the velocity limits; 1 s lets
    # the velocity limits set the pace of a delivery)
    horizon_s: float = 1.0
    # Adam iterations from cold initial trajectories
    iterations: int = 40
    # Adam iterations when warm-started from a previous plan
    warm_iterations: int = 10
    # step size on the waypoints' second differences [rad] (Adam's, or the covariant step's
    # largest entry; a step moves a waypoint up to about lr (W - 2)^2 / 8)
    lr: float = 0.005
    # how an iteration steps on the waypoints' second differences: "adam", Adam's per-entry
    # normalised steps (every entry moves by about lr, whatever its gradient, so a step adds
    # about lr of second difference at every waypoint); "covariant", the gradient's own
    # direction (CHOMP's and ITOMP's covariant update, as the second differences are the
    # smoothness metric's coordinates) with momentum, scaled per trajectory so that its
    # largest entry moves by lr: entries the costs hardly push stay where they are. In the
    # closed loop it was no smoother than Adam at 0.001-0.002 and rougher at 0.005-0.01
    # (experiments/step_size/)
    step_rule: StepRule = "adam"
    # step size at the last iteration relative to the first (exponential decay)
    lr_final_ratio: float = 0.1
    # std of the amplitude of the smooth random perturbations of the initial trajectories [rad]
    perturbation_std: float = 0.3
    # delta_CL: the bound must be <= 1 - confidence at every waypoint of the window
    confidence: float = 0.95
    # how a waypoint's bound combines the robot-person sphere pairs: "max", the paper's (eq.
    # max_collision_probability: the largest pair's probability of touching), or "sum",
    # Boole's bound on the probability that any pair touches (never below "max"; stricter,
    # so more waits). The penalty, the acceptance and the replanner's checks all use it
    bound_reduce: C.BoundReduce = "max"
    # the penalty aims at bound <= penalty_target * (1 - confidence): a margin under the hard
    # limit (0.8 is smoother where the forecast is right, much less safe where it is wrong:
    # experiments/reach_across/, experiments/speed_response/)
    penalty_target: float = 0.5
    # actions whose total weight is at most this share of 1 - confidence are left out of the
    # bound and their weight added to it instead (still an upper bound; fewer sphere pairs)
    drop_action_mass: float = 0.01
    # collision checks per waypoint interval of the window (points at k / n, k = 1..n, of the
    # segment ending at each waypoint), so a fast robot cannot pass between two checks
    collision_substeps: int = 2
    # acceleration limit of the robot's trajectory interface [rad/s^2] (the replanner's
    # filtered tracking): a cost term keeps the plans within it and the acceptance prefers the
    # safe plans within ACC_TOL times it, so the executed motion is the one checked; None: no
    # limit
    acc_max: float | None = None
    # share of the robot's joint velocity limits the plans may use (and the replanner's
    # filtered tracking clips to), a speed reduction for working beside a person; 1: the
    # limits. It caps speeds only: a move short enough to take horizon_s at full speed takes
    # as long below 1; divide horizon_s by it too to slow every move (smoother at lr 0.001,
    # rougher at the default 0.005: experiments/speed_scale/)
    speed_scale: float = 1.0
    # the plan's duration is the shortest whose least-acceleration path (the cubic the
    # optimiser starts from) peaks at this share of the velocity limits: room for the
    # iterations to bend it (round the table, the person) before the acceptance's VEL_TOL
    # refuses it; at 1 a bent cubic can pass the limits and a rougher candidate is chosen
    duration_vel_fraction: float = 1.0
    # static-obstacle clearance below which the hinge cost starts [m]
    static_margin: float = 0.02
    # distance robot spheres may move before the pruned sphere pairs are refreshed [m]
    prune_margin: float = 0.15
    # iterations between refreshes of the pruned sphere pairs
    prune_every: int = 8
    # cost weights
    weights: C.CostWeights = field(default_factory=C.CostWeights)
    # a wait stops at the latest waypoint of its path whose hold keeps the bound within the
    # confidence limit, when the hold at the last waypoint before the first unsafe one
    # (the paper's wait) is itself unsafe; False: the paper's wait
    safe_hold: bool = False
    # when no trajectory is safe and holding breaks the confidence limit within this many
    # seconds of the window's start (before the next cycle, due wait_lead_s after a wait,
    # could react), and no candidate is less risky than holding: step out of the person's
    # way (PlanResult.escape) instead of waiting in it; None: always wait (the paper)
    escape_within_s: float | None = None
    # the person's collision spheres (HumanSphereMap.from_segments): "inner", the 22 spheres
    # on the skeleton, which leave parts of the body's capsules out (about 4 cm of the
    # forearm, 5 cm of the upper arm), so the bound is one on touching those spheres;
    # "cover", 42 spheres up to 1 cm larger than the capsules whose union contains them, so
    # the bound is one on touching the body
    human_spheres: SphereLayout = "inner"
    # the confidence constraint (and its penalty) also covers the plan's waypoints up to this
    # many seconds after the execution window, against the forecast held at its last frame
    # beyond its horizon: a plan may not move the robot to where the person is predicted to
    # be soon after the window, as a plan checked on the window alone can (then the hold
    # there is unsafe). A plan unsafe only there runs up to its last safe waypoint. 0: the
    # window alone (the paper)
    check_ahead_s: float = 0.0
    # each trajectory goes to the acceptance as iterated or as it started (the cubic of a
    # cold start, the previous cycle's plan of a warm one), whichever has the lower cost,
    # every term the iterations minimise included: Adam's normalised steps move every
    # waypoint by about the step size whatever its gradient, which can leave a smooth start
    # rougher or past the acceleration limit (experiments/speed_scale/); False: as iterated
    keep_start: bool = False
    # seed of the random initial perturbations (same seed -> same plan)
    seed: int = 0
    # device of the plan; None follows the robot model's tensors
    device: str | None = None

    def __post_init__(self) -> None:
        # each field by name: a wrong type (text, a float count) or NaN fails here, not
        # with a raw Python error in the middle of a solve
        integer("num_trajectories", self.num_trajectories, minimum=1)
        integer("num_waypoints", self.num_waypoints, minimum=3)
        if self.num_trajectories * self.num_waypoints > MAX_PLAN_WAYPOINTS:
            raise ConfigError(
                f"expected num_trajectories * num_waypoints <= {MAX_PLAN_WAYPOINTS} "
                f"(MAX_PLAN_WAYPOINTS, the candidate waypoints of one solve), got "
                f"{self.num_trajectories} * {self.num_waypoints}"
            )
        if not is_real(self.horizon_s) or not 0.0 < self.horizon_s <= MAX_HORIZON_S:
            raise ConfigError(
                f"expected horizon_s in (0, {MAX_HORIZON_S:g}] s, got {self.horizon_s!r}"
            )
        for name in ("iterations", "warm_iterations"):  # each by name
            if integer(name, getattr(self, name)) < 0:
                raise ConfigError(f"expected {name} >= 0, got {getattr(self, name)}")
        positive("lr", self.lr)  # NaN and inf refused too
        if self.step_rule not in STEP_RULES:
            raise ConfigError(f"expected step_rule 'adam' or 'covariant', got {self.step_rule!r}")
        if not is_real(self.speed_scale) or not 0.0 < self.speed_scale <= 1.0:
            raise ConfigError(f"expected speed_scale in (0, 1], got {self.speed_scale!r}")
        if not is_real(self.duration_vel_fraction) or not 0.0 < self.duration_vel_fraction <= 1.0:
            raise ConfigError(
                f"expected duration_vel_fraction in (0, 1], got {self.duration_vel_fraction!r}"
            )
        if not is_real(self.lr_final_ratio) or not 0.0 < self.lr_final_ratio <= 1.0:
            raise ConfigError(f"expected lr_final_ratio in (0, 1], got {self.lr_final_ratio!r}")
        if not is_real(self.perturbation_std) or not 0.0 <= self.perturbation_std < math.inf:
            raise ConfigError(
                f"expected perturbation_std finite and >= 0, got {self.perturbation_std!r}"
            )
        if not is_real(self.confidence) or not 0.0 < self.confidence < 1.0:
            raise ConfigError(f"expected confidence in (0, 1), got {self.confidence!r}")
        if not is_real(self.penalty_target) or not 0.0 < self.penalty_target <= 1.0:
            raise ConfigError(f"expected penalty_target in (0, 1], got {self.penalty_target!r}")
        if self.bound_reduce not in C.BOUND_REDUCTIONS:
            raise ConfigError(f"expected bound_reduce 'max' or 'sum', got {self.bound_reduce!r}")
        if not is_real(self.drop_action_mass) or not 0.0 <= self.drop_action_mass < 1.0:
            raise ConfigError(
                f"expected drop_action_mass in [0, 1), got {self.drop_action_mass!r}"
            )
        # inf is no limit, as None
        if self.acc_max is not None and (not is_real(self.acc_max) or not self.acc_max > 0.0):
            raise ConfigError(f"expected acc_max > 0 or None, got {self.acc_max!r}")
        integer("collision_substeps", self.collision_substeps, minimum=1)
        integer("prune_every", self.prune_every, minimum=1)
        non_negative("prune_margin", self.prune_margin)
        non_negative("static_margin", self.static_margin)
        if not isinstance(self.weights, C.CostWeights):
            raise ConfigError(f"expected weights to be CostWeights, got {type(self.weights)}")
        flag("safe_hold", self.safe_hold)
        flag("keep_start", self.keep_start)
        if self.human_spheres not in ("inner", "cover"):
            raise ConfigError(
                f"expected human_spheres 'inner' or 'cover', got {self.human_spheres!r}"
            )
        # inf: escape whenever holding breaks the limit anywhere in the window
        within = self.escape_within_s
        if within is not None and (not is_real(within) or not within >= 0.0):
            raise ConfigError(f"expected escape_within_s >= 0 or None, got {within!r}")
        if not is_real(self.check_ahead_s) or not 0.0 <= self.check_ahead_s <= MAX_HORIZON_S:
            raise ConfigError(
                f"expected check_ahead_s in [0, {MAX_HORIZON_S:g}] s, got {self.check_ahead_s!r}"
            )
        check_seed(self.seed)
        _check_device(self.device)


def _check_device(device: object) -> None:
    """ConfigError unless ``device`` is None, a :class:`torch.device` or a device name torch
    parses ("cpu", "cuda", "cuda:1", ...; "" follows the robot, as None). Whether the device
    is present is not asked here: the optimiser is built on the robot model's device."""
    if device is None or isinstance(device, torch.device):
        return
    accepted = "None or a torch device name such as 'cpu', 'cuda' or 'cuda:0'"
    if not isinstance(device, str):
        raise ConfigError(f"expected device {accepted}, got {device!r}")
    if not device:
        return
    try:
        torch.device(device)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise ConfigError(f"expected device {accepted}, got {device!r} ({exc})") from exc


@dataclass(kw_only=True)
class PlanResult:
    """The accepted plan of one solve.

    Attributes:
        feasible: the plan meets the confidence constraint, the static clearance and the
            velocity limits (within ``VEL_TOL``) on its own; the limits are checked on the
            waypoints (each segment's mean velocity, and ``acc_max`` on their differences).
            The cubic spline through them (:meth:`trajectory`, what ``tracking="exact"``
            executes) can exceed them between waypoints: up to 4/3 of the segment velocity
            where it starts or stops at rest, more acceleration where it must stop within one
            segment. The default ``tracking="filtered"`` clips what it commands to both.
            False means it is the best trajectory cut at its last safe waypoint plus a wait,
            or (``evasive``) the trajectory with the smallest peak bound.
        q: (W, J) waypoints [rad]; after a wait, the waypoints from the hold on repeat it.
        times: (W,) waypoint times [s].
        bound: (W,) human-collision bound per waypoint (0 outside the execution window and
            the ``cfg.check_ahead_s`` after it).
        wait_s: seconds the plan holds at its last safe pose inside the window (0 if feasible).
        hold_index: the waypoint held from, or None.
        qd_start: (J,) velocity at the first waypoint [rad/s] or None (rest).
        candidates: (B, W, J) all optimised trajectories (warm starts of the next solve);
            in a wait or escape result, the row of the trajectory the plan came from holds
            the plan ``q`` itself (the held or the escape path) instead.
        cost_terms: the accepted trajectory's unweighted cost terms and diagnostics.
        timings: milliseconds: ``predict_ms`` (forecast to human spheres at the waypoint
            times), ``collision_ms`` (bound evaluations, forward), ``optimiser_ms`` (the rest),
            ``total_ms``; and ``iterations``, the optimiser iterations run.
        evasive: no trajectory met the constraint and waiting would have been riskier than
            moving: the plan is the candidate with the smallest peak bound (no wait), or the
            escape.
        escape: an evasive plan that steps out of the person's way instead of heading for
            the goal: no candidate was less risky than holding
            (:meth:`TrajectoryOptimizer._escape`).
        cut_short: the solve stopped iterating at its deadline
            (:meth:`TrajectoryOptimizer.solve`'s ``deadline``).
    """

    feasible: bool
    q: torch.Tensor
    times: torch.Tensor
    bound: torch.Tensor
    wait_s: float
    hold_index: int | None
    qd_start: torch.Tensor | None
    candidates: torch.Tensor
    cost_terms: dict[str, float]
    timings: dict[str, float]
    evasive: bool = False
    escape: bool = False
    cut_short: bool = False

    def trajectory(self) -> Trajectory:
        """The plan as an executable :class:`Trajectory`."""
        return Trajectory(q=self.q, times=self.times, qd_start=self.qd_start)


class _Timer:
    """Accumulates wall-clock milliseconds, synchronising CUDA when needed."""

    def __init__(self, device: torch.device) -> None:
        self.cuda = device.type == "cuda"
        self.ms = 0.0
        self._t = 0.0

    def __enter__(self) -> _Timer:
        if self.cuda:
            torch.cuda.synchronize()
        self._t = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.cuda:
            torch.cuda.synchronize()
        self.ms += 1e3 * (time.perf_counter() - self._t)


def smooth_stop(q: torch.Tensor, hold: int) -> torch.Tensor:
    """The path of ``q`` slowed down at a constant rate until it stops (a wait without the
    abrupt halt at a waypoint).

    With waypoint index ``s(k) = k - k^2 / (2 K)`` for ``k <= K = min(2 hold, W - 1)``
    (then constant), the path starts at its own speed (``s'(0) = 1``) and stops at
    ``s = K / 2 <= hold``, so it never passes the held waypoint.

    Args:
        q: (W, J) waypoints [rad] at uniform times.
        hold: the last waypoint that may be reached (>= 1).

    Returns:
        (W, J) waypoints [rad] at the same times.

    Raises:
        ShapeError: when ``q`` is not (W, J) with W >= 2.
        ConfigError: when ``hold`` is not an integer >= 1.
    """
    integer("hold", hold, minimum=1)
    check_shape("q", q, ("W", "J"))
    if q.shape[0] < 2:
        raise ShapeError(f"expected q (W, J) with W >= 2, got {tuple(q.shape)}")
    w = q.shape[0]
    k_stop = min(2 * hold, w - 1)
    k = torch.arange(w, device=q.device, dtype=q.dtype).clamp(max=k_stop)
    s = k - k.square() / (2.0 * k_stop)  # (W,) fractional waypoint index
    lo = s.floor().long().clamp(max=w - 2)
    frac = (s - lo.to(q.dtype)).unsqueeze(-1)
    return (1.0 - frac) * q[lo] + frac * q[lo + 1]


def _check_forecast(forecast: object) -> None:
    """ShapeError unless ``forecast`` is a :class:`Forecast` or None."""
    if forecast is not None and not isinstance(forecast, Forecast):
        raise ShapeError(f"expected forecast a Forecast or None, got {type(forecast).__name__}")


def _held(q: torch.Tensor, hold: int) -> torch.Tensor:
    """(W, J) the path q (W, J) up to waypoint ``hold``, then held there (an abrupt stop)."""
    out = q.clone()
    out[hold + 1 :] = out[hold]
    return out


class TrajectoryOptimizer:
    """Optimises B space-time trajectories against the probabilistic human-collision bound.

    Args:
        robot: the kinematic model (any :class:`KinematicModel`).
        cfg: settings.
        static_scene: static obstacles with a ``clearance`` query, or None.
        human_spheres: joint-to-sphere map of the human (``centers_diag``, ``radii``); None
            builds :class:`HumanSphereMap` from the forecast's joint names (layout
            ``cfg.human_spheres``).

    Raises:
        ConfigError: when ``robot`` is not a :class:`KinematicModel` (it lacks one of its
            attributes), ``cfg`` is neither an :class:`OptimizerCfg` nor None, or
            ``cfg.device`` is not of the robot's device type.
        ShapeError: when the robot's ``sphere_radii`` is not an (S_r,) tensor of a floating
            dtype, or its ``q_min``, ``q_max`` or ``v_max`` not a (J,) tensor.
    """

    def __init__(
        self,
        robot: KinematicModel,
        cfg: OptimizerCfg | None = None,
        static_scene: C.ClearanceScene | None = None,
        human_spheres: C.SphereMap | None = None,
    ) -> None:
        if not isinstance(robot, KinematicModel):
            raise ConfigError(
                "expected robot a KinematicModel (q_min, q_max, v_max, sphere_radii, "
                f"num_joints, sphere_centers), got {type(robot).__name__}"
            )
        if cfg is not None and not isinstance(cfg, OptimizerCfg):
            raise ConfigError(f"expected cfg an OptimizerCfg or None, got {type(cfg).__name__}")
        check_shape("robot.sphere_radii", robot.sphere_radii, ("S_r",))
        if not robot.sphere_radii.is_floating_point():
            raise ShapeError(
                f"expected robot.sphere_radii of a floating dtype, got {robot.sphere_radii.dtype}"
            )
        j = integer("robot.num_joints", robot.num_joints, minimum=1)
        for name in ("q_min", "q_max", "v_max"):
            check_shape(f"robot.{name}", getattr(robot, name), (j,))
        self.robot = robot
        self.cfg = cfg or OptimizerCfg()
        self.static_scene = static_scene
        self.human_spheres = human_spheres
        self._sphere_cache: dict[tuple[str, ...], C.SphereMap] = {}
        self._d_cache: dict[tuple, tuple[torch.Tensor, torch.Tensor]] = {}
        ref = robot.sphere_radii
        self.device = torch.device(self.cfg.device) if self.cfg.device else ref.device
        if self.device.type != ref.device.type:
            raise ConfigError(f"cfg.device {self.device} differs from the robot's {ref.device}")
        self.dtype = ref.dtype
        self.q_min = robot.q_min.to(self.device, self.dtype)
        self.q_max = robot.q_max.to(self.device, self.dtype)
        self.v_max = robot.v_max.to(self.device, self.dtype)
        if self.cfg.speed_scale != 1.0:
            self.v_max = self.v_max * self.cfg.speed_scale
        self.radii = ref.to(self.device, self.dtype)
        self.num_joints = int(robot.num_joints)
        # wall-clock seconds of the last solve's acceptance check: what a solve with a
        # deadline keeps for its own (0 before the first)
        self._accept_s = 0.0

    # ----------------------------------------------------------------- set-up helpers
    def _spheres_for(self, joint_names: tuple[str, ...]) -> C.SphereMap:
        if self.human_spheres is not None:
            return self.human_spheres
        if joint_names not in self._sphere_cache:
            self._sphere_cache[joint_names] = HumanSphereMap.from_segments(
                joint_names, layout=self.cfg.human_spheres
            )
        return self._sphere_cache[joint_names]

    def _check_ends(
        self, q_start: torch.Tensor, q_goal: torch.Tensor, qd_start: torch.Tensor | None
    ) -> None:
        """ShapeError unless ``q_start``, ``q_goal`` and ``qd_start`` (when given) are (J,);
        DataError when one of them holds NaN or inf."""
        j = self.num_joints
        check_shape("q_start", q_start, (j,))
        check_shape("q_goal", q_goal, (j,))
        if qd_start is not None:
            check_shape("qd_start", qd_start, (j,))
        check_finite("q_start", q_start, ("joint",))
        check_finite("q_goal", q_goal, ("joint",))
        if qd_start is not None:
            check_finite("qd_start", qd_start, ("joint",))

    def check_goal(self, q_goal: torch.Tensor) -> None:
        """DataError unless the (J,) goal is within the joint limits (up to
        :data:`GOAL_LIMIT_TOL` [rad], for a goal at a limit rounded to another dtype).

        A goal outside them cannot be pinned: every plan would stop at the limit, never reach
        it and be infeasible, and a replanning robot would wait there for good.

        Raises:
            ShapeError: when ``q_goal`` is not a (J,) tensor.
            DataError: when it holds NaN or inf (NaN compared as within the limits), or a
                joint outside its limits.
        """
        check_shape("q_goal", q_goal, (self.num_joints,))
        check_finite("q_goal", q_goal, ("joint",))
        q = q_goal.to(self.device, self.dtype)
        out = (q < self.q_min - GOAL_LIMIT_TOL) | (q > self.q_max + GOAL_LIMIT_TOL)  # (J,)
        if bool(out.any()):
            i = int(out.nonzero()[0, 0])
            raise DataError(
                f"expected q_goal within the joint limits, got q_goal[{i}] = {float(q[i])!r} "
                f"rad outside [{float(self.q_min[i])!r}, {float(self.q_max[i])!r}]"
            )

    def min_duration(
        self,
        q_start: torch.Tensor,
        q_goal: torch.Tensor,
        qd_start: torch.Tensor | None = None,
    ) -> float:
        """Shortest start-to-goal time [s] whose least-acceleration path (the cubic of
        :meth:`initial_trajectories`) keeps within the limits.

        From rest this is a straight line at 2/3 of the velocity limits (the cubic's peak speed
        is then the limit). With a start velocity, the cubic from ``(q_start, qd_start)`` to
        ``(q_goal, rest)`` must also keep its speed within the limits, and with
        ``cfg.acc_max`` its accelerations (largest at its ends, ``(6 D - 4 v0 T) / T^2`` and
        ``(2 v0 T - 6 D) / T^2``) within that limit: a plan that must stop sooner than that
        either leaves the limits, which the tracking then cuts and the executed motion leaves
        the checked path, or is rejected.

        Args:
            q_start: (J,) start [rad].
            q_goal: (J,) goal [rad].
            qd_start: (J,) start velocity [rad/s]; None means rest.

        Returns:
            The shortest such time on a grid of ``DURATION_GRID`` relative steps [s].

        Raises:
            ShapeError: when ``q_start``, ``q_goal`` or ``qd_start`` is not (J,).
            DataError: when one of them holds NaN or inf.
        """
        self._check_ends(q_start, q_goal, qd_start)
        q_start = q_start.to(self.device, self.dtype)
        d = q_goal.to(q_start) - q_start  # (J,)
        v_plan = self.cfg.duration_vel_fraction * self.v_max  # (J,) the path's peak speeds
        t_line = float(1.5 * (d.abs() / v_plan).max())
        if qd_start is None and self.cfg.acc_max is None:
            return t_line
        v0 = torch.zeros_like(d) if qd_start is None else qd_start.to(d)
        lo = max(t_line, 1e-3)
        grid = lo * DURATION_GRID ** torch.arange(
            DURATION_STEPS, device=d.device, dtype=d.dtype
        )  # (N,) candidate durations [s]
        t = grid.unsqueeze(-1)  # (N, 1)
        # the cubic's velocity v(s) = 6 s (1 - s) D / T + (3 s^2 - 4 s + 1) v0, on a grid of s
        s = torch.linspace(0.0, 1.0, 33, device=d.device, dtype=d.dtype).view(-1, 1, 1)
        vel = 6 * s * (1 - s) * d / t + (3 * s * s - 4 * s + 1) * v0  # (S, N, J)
        v_lim = torch.maximum(v_plan, v0.abs())
        ok = (vel.abs() <= v_lim * (1.0 + 1e-9)).all(0).all(-1)  # (N,)
        if self.cfg.acc_max is not None:
            a0 = (6 * d - 4 * v0 * t) / (t * t)
            a1 = (2 * v0 * t - 6 * d) / (t * t)
            acc = torch.maximum(a0.abs(), a1.abs())  # (N, J)
            ok &= (acc <= self.cfg.acc_max).all(-1)
        if not bool(ok.any()):
            return float(grid[-1])
        return float(grid[int(ok.to(torch.int64).argmax())])

    def arrival_index(self, duration: float, travel: float | None) -> int:
        """Index of the first waypoint pinned to the goal for a plan of ``duration`` seconds
        that arrives ``travel`` seconds after its start (None: at its end), in [2, W - 1].

        Raises:
            DataError: when ``duration`` is not a finite number > 0 or ``travel`` not a
                finite number >= 0 (NaN gave the last waypoint without a word).
        """
        positive("duration", duration, error=DataError)
        if travel is not None:
            non_negative("travel", travel, error=DataError)
        w = self.cfg.num_waypoints
        if travel is None:
            return w - 1
        rel = torch.linspace(0.0, duration, w, dtype=torch.float64)
        n = int(torch.searchsorted(rel, rel.new_tensor([travel - 1e-6]))[0])
        return min(max(n, 2), w - 1)

    def initial_trajectories(
        self,
        q_start: torch.Tensor,
        q_goal: torch.Tensor,
        num: int,
        seed: int,
        duration: float | None = None,
        *,
        qd_start: torch.Tensor | None = None,
        arrival: int | None = None,
    ) -> torch.Tensor:
        """The minimum-acceleration path to the goal plus smooth random perturbations (the
        first one unperturbed).

        The base is the cubic from ``(q_start, qd_start)`` to ``(q_goal, rest)`` reaching the
        goal at waypoint ``arrival`` and holding it after: of all motions with these end
        conditions it has the least integral of squared acceleration (the smoothness cost),
        so the optimiser starts from the smoothest path and the random perturbations (sine
        modes over the same span) only add the diversity of the paper's parallel threads.
        A straight line at constant speed instead starts and stops with a velocity jump, which
        the iterations of a replanning cycle do not fully smooth out.

        Args:
            q_start: (J,) start [rad].
            q_goal: (J,) goal [rad].
            num: how many trajectories.
            seed: seed of the perturbations.
            duration: seconds from the first to the last waypoint; when given, each
                trajectory's perturbation is scaled down per joint so that its waypoint
                velocities stay within ``INIT_VEL_FRACTION`` of the limits (the base is not
                changed), and ``qd_start`` is used.
            qd_start: (J,) start velocity [rad/s]; None (or no ``duration``) means rest.
            arrival: first waypoint at the goal (:meth:`arrival_index`), an integer (clamped
                to [1, W - 1]); None: the last.

        Returns:
            (num, W, J) [rad], clamped to the joint limits, start and goal pinned.

        Raises:
            ShapeError: when ``q_start``, ``q_goal`` or ``qd_start`` is not (J,).
            DataError: when one of them holds NaN or inf.
            ConfigError: when ``num`` is not an integer >= 1, ``seed`` not an integer that
                torch's generator takes, ``duration`` (when given) not finite and > 0, or
                ``arrival`` (when given) not an integer.
        """
        w, j = self.cfg.num_waypoints, self.num_joints
        self._check_ends(q_start, q_goal, qd_start)
        integer("num", num, minimum=1)
        integer("seed", seed)
        if duration is not None:
            positive("duration", duration)
        if arrival is not None:
            integer("arrival", arrival)
        n_a = w - 1 if arrival is None else min(max(int(arrival), 1), w - 1)
        k = torch.arange(w, device=self.device, dtype=self.dtype)
        s = (k / n_a).clamp(max=1.0)  # (W,) progress to the arrival
        h00 = 2 * s**3 - 3 * s**2 + 1
        h01 = 3 * s**2 - 2 * s**3
        h10 = s**3 - 2 * s**2 + s
        base = h00[:, None] * q_start + h01[:, None] * q_goal  # (W, J)
        if qd_start is not None and duration is not None and duration > 0.0:
            span = n_a * duration / (w - 1)  # seconds to the arrival
            base = base + h10[:, None] * span * qd_start.to(base)
        try:
            gen = torch.Generator().manual_seed(seed)
        except (RuntimeError, ValueError, OverflowError) as err:  # beyond 64 bits
            raise ConfigError(f"expected seed a 64-bit integer, got {seed!r}") from err
        amp = torch.randn(num, 3, j, generator=gen, dtype=torch.float64)  # (num, 3 modes, J)
        amp = (amp * self.cfg.perturbation_std / torch.arange(1, 4).view(1, 3, 1)).to(
            self.device, self.dtype
        )
        amp[0] = 0.0
        modes = torch.stack([torch.sin(math.pi * m * s) for m in (1, 2, 3)])  # (3, W)
        pert = torch.einsum("nkj,kw->nwj", amp, modes)  # (num, W, J)
        if duration is not None and duration > 0.0:
            dt = duration / (w - 1)
            v_base = (base[1:] - base[:-1]).abs().amax(0) / dt  # (J,)
            v_pert = (pert[:, 1:] - pert[:, :-1]).abs().amax(1) / dt  # (num, J)
            room = (INIT_VEL_FRACTION * self.v_max - v_base).clamp_min(0.0)  # (J,)
            scale = (room / v_pert.clamp_min(1e-12)).clamp(max=1.0)  # (num, J)
            pert = pert * scale.unsqueeze(1)
        q = base + pert  # (num, W, J)
        return torch.maximum(torch.minimum(q, self.q_max), self.q_min)

    # ----------------------------------------------------------------- costs
    def _terms(
        self,
        q: torch.Tensor,
        dt: float,
        qd_start: torch.Tensor | None,
        q_goal: torch.Tensor,
        human: C.HumanObstacle | None,
        win_idx: torch.Tensor,
        pairs: tuple[torch.Tensor, torch.Tensor | None] | None,
        timer: _Timer,
        exact: bool = False,
        prune: float | None = None,
        look_idx: torch.Tensor | None = None,
    ) -> tuple[
        dict[str, torch.Tensor],
        torch.Tensor | None,
        torch.Tensor | None,
        tuple[torch.Tensor, torch.Tensor | None] | None,
    ]:
        """Unweighted (B,) cost terms, the window bound (B, W_x), the min clearance (B, W) and
        the sphere pairs and entries used; ``prune`` (a margin [m]) first refreshes them from
        this trajectory's own sphere centres (:meth:`_candidates`). With ``look_idx``
        (waypoints after the window, :meth:`_lookahead_indices`) the human obstacle also covers
        those waypoints, after the window's points, and they add ``human_lookahead_penalty``;
        the returned bound stays the window's."""
        terms = {
            "joint_acc_l2": C.joint_acc_l2(q, dt, qd_start),
            "joint_limit_violation": C.joint_limit_violation(q, self.q_min, self.q_max),
            "joint_vel_limit_violation": C.joint_vel_limit_violation(q, dt, self.v_max),
            "goal_distance": C.goal_distance(q[:, -1], q_goal),
        }
        if self.cfg.acc_max is not None:
            terms["joint_acc_limit_violation"] = C.joint_acc_limit_violation(
                q, dt, self.cfg.acc_max, qd_start
            )
        bound = clearance = None
        centers, centers_x = self._sphere_centers(q, win_idx, human is not None)
        if self.static_scene is not None:
            terms["static_clearance"], clearance = C.static_clearance(
                centers, self.radii, self.static_scene, self.cfg.static_margin
            )
        if human is not None:
            n_x = centers_x.shape[1]
            if look_idx is not None:
                centers_x = torch.cat([centers_x, centers[:, look_idx]], dim=1)
            with timer:
                if prune is not None:
                    pairs = self._candidates(centers_x.detach(), human, prune)
                bound, pen = C.human_collision_bound(
                    centers_x,
                    self.radii,
                    human,
                    None if pairs is None else pairs[0],
                    exact=exact,
                    entries=None if pairs is None else pairs[1],
                    reduce=self.cfg.bound_reduce,
                )
            if look_idx is not None:
                excess = self._excess(bound[:, n_x:])
                terms["human_lookahead_penalty"] = excess.square().sum(-1)
                bound = bound[:, :n_x]
            bound = bound.view(q.shape[0], -1, self.cfg.collision_substeps).amax(-1)  # (B, W_x)
            excess = self._excess(bound)
            terms["human_collision_bound"] = bound.sum(-1)
            terms["human_confidence_penalty"] = excess.square().sum(-1)
            terms["human_mean_penetration"] = pen
        return terms, bound, clearance, pairs

    def _candidates(
        self, centers: torch.Tensor, human: C.HumanObstacle, margin: float
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The sphere pairs to evaluate, and the (waypoint, pair, action) entries within them
        when the forecast has more than one action (:func:`costs.candidate_entries`; with one
        action the entries save less than their indexing costs, about 0.05 ms a call)."""
        if human.weights.shape[0] > 1:
            return C.candidate_entries(centers, self.radii, human, margin)
        return C.candidate_pairs(centers, self.radii, human, margin), None

    def _excess(self, bound: torch.Tensor) -> torch.Tensor:
        """``log(bound / target)`` where positive, else 0 (same shape as ``bound``): what the
        confidence penalty squares, with ``target = penalty_target (1 - confidence)``."""
        target = math.log(self.cfg.penalty_target * (1.0 - self.cfg.confidence))
        return torch.relu(torch.log(bound.clamp_min(1e-30)) - target)

    def _sphere_centers(
        self, q: torch.Tensor, win_idx: torch.Tensor, with_window: bool
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Robot sphere centres [m] at the waypoints of q (B, W, J), (B, W, S_r, 3), and at the
        collision points of the window (B, W_x * n_sub, S_r, 3) (as :meth:`_collision_points`)
        or None, from one forward-kinematics call (the last point of each window segment is the
        waypoint itself, so only the intermediate points are added)."""
        b, w, _ = q.shape
        n = self.cfg.collision_substeps
        if not with_window or n == 1:
            centers = self.robot.sphere_centers(q)
            return centers, (centers[:, win_idx] if with_window else None)
        qa, qb = q[:, win_idx - 1], q[:, win_idx]  # (B, W_x, J)
        f = torch.arange(1, n, device=q.device, dtype=q.dtype) / n  # (n - 1,)
        mids = qa.unsqueeze(2) + f.view(1, 1, n - 1, 1) * (qb - qa).unsqueeze(2)
        c = self.robot.sphere_centers(torch.cat([q, mids.flatten(1, 2)], dim=1))
        centers = c[:, :w]  # (B, W, S_r, 3)
        mid_c = c[:, w:].reshape(b, win_idx.shape[0], n - 1, *c.shape[2:])
        centers_x = torch.cat([mid_c, centers[:, win_idx].unsqueeze(2)], dim=2).flatten(1, 2)
        return centers, centers_x

    def _weighted(self, terms: dict[str, torch.Tensor]) -> torch.Tensor:
        w = self.cfg.weights
        return sum(getattr(w, name) * value for name, value in terms.items())  # (B,)

    # ----------------------------------------------------------------- solve
    def solve(
        self,
        q_start: torch.Tensor,
        q_goal: torch.Tensor,
        *,
        forecast: Forecast | None = None,
        forecast_t0: float = 0.0,
        t0: float = 0.0,
        duration: float | None = None,
        window: tuple[float, float] | None = None,
        q_init: torch.Tensor | None = None,
        qd_start: torch.Tensor | None = None,
        arrive: float | None = None,
        deadline: float | None = None,
        seed: int | None = None,
    ) -> PlanResult:
        """Plan from ``q_start`` at ``t0`` to ``q_goal`` at ``t0 + duration``.

        Args:
            q_start: (J,) start configuration [rad] (pinned), of any floating dtype and
                device: it is moved to the optimiser's (its robot model's), as the plan is.
            q_goal: (J,) goal configuration [rad] (pinned at the last waypoint), the same.
            forecast: the predicted human (batch entry 0), or None for no human.
            forecast_t0: time of the last observed frame of the forecast [s].
            t0: time of the first waypoint [s].
            duration: seconds from start to goal; None uses ``cfg.horizon_s``, lengthened to
                respect the velocity limits.
            window: (t_a, t_b) absolute times [s] of the execution window whose waypoints
                carry the human cost and the confidence constraint (eq. collision_probability),
                with a forecast extended by ``cfg.check_ahead_s`` at its end; None uses every
                waypoint after the start.
            q_init: (B, W, J) initial trajectories [rad] (a warm start: ``cfg.warm_iterations``
                iterations); None builds cold ones (``cfg.iterations``).
            qd_start: (J,) velocity at the start [rad/s] (continuity with the previous plan).
            arrive: absolute time [s] from which the plan holds the goal (the waypoints at or
                after it are pinned to ``q_goal``); None means the last waypoint.
            deadline: a :func:`time.perf_counter` instant by which the solve should return:
                no further iteration starts once the next one (as long as the mean of this
                solve's so far) and the acceptance check (as long as the last solve's) would
                end after it; the first iteration always runs, and the acceptance check runs
                in full. The plan then depends on this machine's speed and load. None: every
                iteration runs (the same inputs give the same plan).
            seed: seed of the cold initial trajectories (:meth:`initial_trajectories`; unused
                with ``q_init``); None uses ``cfg.seed``. The replanner gives each cycle its
                own (:func:`~iplanner_torch.seeds.derive_seed`).

        Returns:
            The accepted plan; ``timings["iterations"]`` counts the iterations run, and
            ``cut_short`` says whether the deadline stopped them.

        Raises:
            ShapeError: on inputs of the wrong shape.
            ShapeError: when ``forecast`` is not a :class:`Forecast` or None.
            ConfigError: when ``t0``, ``forecast_t0``, ``duration``, ``arrive`` or a bound of
                ``window`` is not a finite number, when ``window`` ends before it starts,
                when ``duration <= 0`` or ``duration > MAX_HORIZON_S``, when ``arrive`` is
                before ``t0``, or when ``t0`` is too large for the robot's dtype to resolve
                the waypoint spacing (a Unix timestamp in float32: pass times relative to the
                episode start; :func:`~iplanner_torch.planning.trajectory.uniform_times`).
            DataError: when ``q_start``, ``q_goal``, ``qd_start`` or ``q_init`` holds NaN or
                inf, or ``q_goal`` is outside the joint limits (:meth:`check_goal`; a start
                outside them is where the robot is, and is planned from).
            PlanningError: when the optimisation produces non-finite waypoints (it cannot
                from finite inputs: non-finite gradient entries are taken as 0).
        """
        t_begin = time.perf_counter()
        cfg, j, w = self.cfg, self.num_joints, self.cfg.num_waypoints
        check_shape("q_start", q_start, (j,))
        check_shape("q_goal", q_goal, (j,))
        check_finite("q_start", q_start, ("joint",))
        check_finite("q_goal", q_goal, ("joint",))
        self.check_goal(q_goal)
        _check_forecast(forecast)
        finite_time("t0", t0)
        finite_time("forecast_t0", forecast_t0)
        if duration is not None:
            finite_time("duration", duration)
            if duration > MAX_HORIZON_S:
                raise ConfigError(
                    f"expected duration <= {MAX_HORIZON_S:g} s (MAX_HORIZON_S), got {duration!r}"
                )
        if arrive is not None:
            finite_time("arrive", arrive)
            if arrive < t0:
                raise ConfigError(f"expected arrive >= t0, got arrive={arrive!r}, t0={t0!r}")
        if window is not None:
            try:
                t_a, t_b = window
            except (TypeError, ValueError) as err:
                raise ConfigError(f"expected window (t_a, t_b) [s], got {window!r}") from err
            finite_time("window end", t_b)  # the order: _window_indices
            finite_time("window start", t_a)
        if deadline is not None:
            finite_time("deadline", deadline)
        q_start = q_start.to(self.device, self.dtype)
        q_goal = q_goal.to(self.device, self.dtype)
        if qd_start is not None:
            check_shape("qd_start", qd_start, (j,))
            check_finite("qd_start", qd_start, ("joint",))
            qd_start = qd_start.to(self.device, self.dtype)
        if duration is None:
            duration = max(cfg.horizon_s, self.min_duration(q_start, q_goal, qd_start))
        if not duration > 0.0:
            raise ConfigError(f"expected duration > 0, got {duration}")
        times = uniform_times(t0, duration, w, q_start)
        dt = duration / (w - 1)
        checked = window
        if window is not None and forecast is not None and cfg.check_ahead_s > 0.0:
            checked = (float(window[0]), float(window[1]) + cfg.check_ahead_s)
        win_idx = self._window_indices(times, checked)
        look_idx = self._lookahead_indices(win_idx, w) if forecast is not None else None

        collision_timer = _Timer(self.device)
        predict_timer = _Timer(self.device)
        human = None
        if forecast is not None:
            with predict_timer:
                t_pts = self._collision_points(times.view(1, -1, 1), win_idx)[0, :, 0]
                if look_idx is not None:
                    t_pts = torch.cat([t_pts, times[look_idx]])
                human = self._human_obstacle(forecast, t_pts, forecast_t0)

        # first waypoint pinned to the goal (the replanner's fresh trajectories use the same)
        n_goal = self.arrival_index(duration, None if arrive is None else arrive - t0)
        if q_init is not None:
            check_shape("q_init", q_init, (cfg.num_trajectories, w, j))
            check_finite("q_init", q_init, ("trajectory", "waypoint", "joint"))
            q0 = q_init.to(self.device, self.dtype).clone()
            iterations = cfg.warm_iterations
        else:
            q0 = self.initial_trajectories(
                q_start,
                q_goal,
                cfg.num_trajectories,
                cfg.seed if seed is None else seed,
                duration,
                qd_start=qd_start,
                arrival=n_goal,
            )
            iterations = cfg.iterations
        q0 = torch.maximum(torch.minimum(q0, self.q_max), self.q_min)

        # Optimise the second differences z = D x + b of the free waypoints x (b carries the
        # pinned ends): smoothness is then a well-conditioned sum of squares, and a step in z
        # moves the waypoints smoothly (the covariant update of CHOMP / ITOMP).
        n_free = n_goal - 1
        d_mat, d_inv = self._difference_operators(n_free)
        b_vec = torch.zeros(cfg.num_trajectories, n_free, j, device=self.device, dtype=self.dtype)
        b_vec[:, 0] += q_start
        b_vec[:, -1] += q_goal
        z = (d_mat @ q0[:, 1:n_goal] + b_vec).requires_grad_(True)  # (B, n_free, J)
        head = q_start.expand(cfg.num_trajectories, 1, j)
        tail = q_goal.expand(cfg.num_trajectories, w - n_goal, j)
        adam_m = torch.zeros_like(z)
        adam_v = torch.zeros_like(z)
        decay = cfg.lr_final_ratio ** (1.0 / max(iterations - 1, 1))
        covariant = cfg.step_rule == "covariant"
        pairs = None
        x = q0[:, 1:n_goal]
        ran = 0
        t_iter = time.perf_counter()
        for it in range(iterations):
            if deadline is not None and it > 0:
                now = time.perf_counter()
                if now + (now - t_iter) / it + self._accept_s > deadline:
                    break
            ran = it + 1
            x = d_inv @ (z - b_vec)  # (B, n_free, J)
            q = torch.cat([head, x, tail], dim=1)  # (B, W, J)
            prune = cfg.prune_margin if it % cfg.prune_every == 0 else None
            terms, _, _, pairs = self._terms(
                q,
                dt,
                qd_start,
                q_goal,
                human,
                win_idx,
                pairs,
                collision_timer,
                prune=prune,
                look_idx=look_idx,
            )
            loss = self._weighted(terms).sum()
            (grad,) = torch.autograd.grad(loss, z)
            # A NaN or inf gradient entry (e.g. a distance's derivative at exactly zero
            # distance) would make its trajectory NaN, and the next pair screen, which pools
            # every trajectory, would spread it to all: such entries count as 0, so the
            # trajectory does not move there. Finite gradients are unchanged.
            grad.nan_to_num_(nan=0.0, posinf=0.0, neginf=0.0)
            with torch.no_grad():
                step = it + 1
                adam_m.mul_(BETA1).add_(grad, alpha=1 - BETA1)
                m_hat = adam_m / (1.0 - BETA1**step)
                if covariant:  # the largest entry of each trajectory's step is lr
                    scale = m_hat.abs().amax(dim=(1, 2), keepdim=True)
                    scale.clamp_min_(torch.finfo(z.dtype).tiny)
                    z -= cfg.lr * decay**it * m_hat / scale
                else:
                    adam_v.mul_(BETA2).addcmul_(grad, grad, value=1 - BETA2)
                    v_hat = adam_v / (1.0 - BETA2**step)
                    z -= cfg.lr * decay**it * m_hat / (v_hat.sqrt() + 1e-12)
                x = d_inv @ (z - b_vec)
                x_c = torch.maximum(torch.minimum(x, self.q_max), self.q_min)
                if not torch.equal(x_c, x):
                    x = x_c
                    z.copy_(d_mat @ x + b_vec)
        x = x.detach()

        with torch.no_grad():
            q_all = torch.cat([head, x, tail], dim=1)  # (B, W, J)
            if not all_finite(q_all):
                raise PlanningError("the optimisation produced non-finite waypoints")
            if cfg.keep_start and ran > 0:
                q_all = self._better_of_start(
                    q_all,
                    torch.cat([head, q0[:, 1:n_goal], tail], dim=1),
                    dt,
                    qd_start,
                    q_goal,
                    human,
                    win_idx,
                    collision_timer,
                    look_idx,
                )
            t_accept = time.perf_counter()
            result = self._accept(
                q_all,
                times,
                dt,
                qd_start,
                q_goal,
                human,
                win_idx,
                window,
                collision_timer,
                look_idx,
            )
            self._accept_s = time.perf_counter() - t_accept
        result.cut_short = ran < iterations
        total = 1e3 * (time.perf_counter() - t_begin)
        result.timings = {
            "predict_ms": predict_timer.ms,
            "collision_ms": collision_timer.ms,
            "optimiser_ms": total - predict_timer.ms - collision_timer.ms,
            "total_ms": total,
            "iterations": float(ran),
        }
        return result

    def _better_of_start(
        self,
        q_end: torch.Tensor,
        q_begin: torch.Tensor,
        dt: float,
        qd_start: torch.Tensor | None,
        q_goal: torch.Tensor,
        human: C.HumanObstacle | None,
        win_idx: torch.Tensor,
        timer: _Timer,
        look_idx: torch.Tensor | None,
    ) -> torch.Tensor:
        """(B, W, J) each trajectory as iterated (q_end) or as it started (q_begin, both
        (B, W, J)), whichever has the lower weighted cost, every term the iterations
        minimise included (``OptimizerCfg.keep_start``); ties keep the iterated one."""
        both = torch.cat([q_end, q_begin])  # (2 B, W, J)
        terms, _, _, _ = self._terms(
            both,
            dt,
            qd_start,
            q_goal,
            human,
            win_idx,
            None,
            timer,
            prune=self.cfg.prune_margin,
            look_idx=look_idx,
        )
        cost = self._weighted(terms)  # (2 B,)
        b = q_end.shape[0]
        take = cost[b:] < cost[:b]  # (B,)
        return torch.where(take.view(-1, 1, 1), q_begin, q_end)

    def collision_bound(
        self,
        q: torch.Tensor,
        times: torch.Tensor,
        forecast: Forecast,
        forecast_t0: float,
    ) -> torch.Tensor:
        """The human-collision bound of given configurations at given times (no optimisation).

        Args:
            q: (N, J) configurations [rad].
            times: (N,) absolute times [s] at which the robot is at them.
            forecast: the predicted human (batch entry 0).
            forecast_t0: time of the forecast's last observed frame [s].

        Returns:
            (N,) upper bounds of the collision probability (exact pair bounds); 1 (unsafe)
            everywhere when the human is not finite
            (:func:`~iplanner_torch.planning.costs.unsafe_if_not_finite`).

        Raises:
            ShapeError: on inputs of the wrong shape, for N = 0 (no batch of the optimiser
                is empty), or when ``forecast`` is not a :class:`Forecast`.
            ConfigError: when ``forecast_t0`` is not finite.
            DataError: when ``q`` or ``times`` holds NaN or inf.
        """
        check_shape("q", q, ("N", self.num_joints))
        if q.shape[0] == 0:
            raise ShapeError(
                f"expected q (N, {self.num_joints}) with N >= 1, got {tuple(q.shape)}"
            )
        check_shape("times", times, (q.shape[0],))
        if not isinstance(forecast, Forecast):
            raise ShapeError(f"expected forecast a Forecast, got {type(forecast).__name__}")
        finite_time("forecast_t0", forecast_t0)
        check_finite("q", q, ("configuration", "joint"))
        check_finite("times", times, ("configuration",))  # a NaN time indexes no frame
        q = q.to(self.device, self.dtype)
        with torch.no_grad():
            human = self._human_obstacle(forecast, times.to(self.device, self.dtype), forecast_t0)
            centers = self.robot.sphere_centers(q).unsqueeze(0)  # (1, N, S_r, 3)
            pairs, entries = self._candidates(centers, human, 0.0)
            bound, _ = C.human_collision_bound(
                centers, self.radii, human, pairs, exact=True, entries=entries,
                reduce=self.cfg.bound_reduce,
            )  # fmt: skip
        return bound[0]

    def _human_obstacle(
        self, forecast: Forecast, times: torch.Tensor, forecast_t0: float
    ) -> C.HumanObstacle:
        """The forecast's human spheres at ``times`` (W_x,) [s], without the actions too light
        to matter at this confidence (``drop_action_mass``)."""
        cfg = self.cfg
        spheres = self._spheres_for(tuple(forecast.joint_names))
        # the times are finite: built from checked numbers (solve) or checked (collision_bound)
        human = C.forecast_to_obstacle(forecast, times, forecast_t0, spheres, validate=False)
        return C.drop_light_actions(human, cfg.drop_action_mass * (1.0 - cfg.confidence))

    def _collision_points(self, q: torch.Tensor, win_idx: torch.Tensor) -> torch.Tensor:
        """(B, W_x * n_sub, J) points at k / n_sub along the segment ending at each window
        waypoint (k = 1..n_sub), from q (B, W, J)."""
        n = self.cfg.collision_substeps
        if n == 1:
            return q[:, win_idx]
        qa, qb = q[:, win_idx - 1], q[:, win_idx]  # (B, W_x, J)
        f = torch.arange(1, n + 1, device=q.device, dtype=q.dtype) / n  # (n,)
        pts = qa.unsqueeze(2) + f.view(1, 1, n, 1) * (qb - qa).unsqueeze(2)  # (B, W_x, n, J)
        return pts.flatten(1, 2)

    def _difference_operators(self, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(n, n) second-difference matrix D of n free waypoints and its inverse (cached)."""
        key = (n, self.device, self.dtype)
        if key not in self._d_cache:
            d = torch.diag(torch.full((n,), -2.0, dtype=torch.float64))
            d += torch.diag(torch.ones(n - 1, dtype=torch.float64), 1)
            d += torch.diag(torch.ones(n - 1, dtype=torch.float64), -1)
            self._d_cache[key] = (
                d.to(self.device, self.dtype),
                torch.linalg.inv(d).to(self.device, self.dtype),
            )
        return self._d_cache[key]

    def _window_indices(
        self, times: torch.Tensor, window: tuple[float, float] | None
    ) -> torch.Tensor:
        """(W_x,) waypoint indices inside the window (never the pinned start)."""
        w = times.shape[0]
        if window is None:
            return torch.arange(1, w, device=times.device)
        t_a, t_b = window
        if t_b < t_a:
            raise ConfigError(f"expected window (t_a, t_b) with t_a <= t_b, got {window}")
        eps = 1e-6
        # every segment [t_{i-1}, t_i] that overlaps the window: the plan runs until t_b
        inside = (times[1:] > t_a + eps) & (times[:-1] < t_b - eps)
        idx = torch.nonzero(inside).flatten() + 1
        if idx.numel() == 0:  # a degenerate window: the segment containing t_a
            idx = torch.searchsorted(times, times.new_tensor([t_a])).clamp(1, w - 1)
        return idx

    def _lookahead_indices(self, win_idx: torch.Tensor, w: int) -> torch.Tensor | None:
        """(W_l,) waypoints after the execution window that carry the look-ahead penalty, or
        None when its weight is 0 or no waypoint follows the window."""
        if self.cfg.weights.human_lookahead_penalty <= 0.0:
            return None
        last = int(win_idx.max())
        if last >= w - 1:
            return None
        return torch.arange(last + 1, w, device=win_idx.device)

    def _accept(
        self,
        q_all: torch.Tensor,
        times: torch.Tensor,
        dt: float,
        qd_start: torch.Tensor | None,
        q_goal: torch.Tensor,
        human: C.HumanObstacle | None,
        win_idx: torch.Tensor,
        window: tuple[float, float] | None,
        timer: _Timer,
        look_idx: torch.Tensor | None = None,
    ) -> PlanResult:
        """Exact check of all B trajectories, then the best feasible one or a wait (the
        look-ahead penalty, when on, ranks the safe ones; it never rules one out)."""
        cfg = self.cfg
        b, w, _ = q_all.shape
        limit = 1.0 - cfg.confidence
        terms, bound, clearance = self._accept_terms(
            q_all, dt, qd_start, q_goal, human, win_idx, timer, look_idx
        )
        rank = self._weighted(
            {k: v for k, v in terms.items() if not k.startswith("human_confidence")}
        )
        bad = self._static_bad(q_all, dt, clearance)  # (B, W)
        static_ok = ~bad.any(-1)  # (B,) clear of the static scene and within the limits
        if bound is not None:
            bad[:, win_idx] |= bound > limit
        ok = ~bad.any(-1)
        if cfg.acc_max is not None:
            # prefer plans the acceleration-limited tracking follows exactly (else the executed
            # motion leaves the checked path); when none is, the best safe one still goes
            smooth_ok = ok & self._within_acc(q_all, dt, qd_start, cfg.acc_max)
            if bool(smooth_ok.any()):
                ok = smooth_ok
        if bool(ok.any()):
            best = int(torch.where(ok, rank, torch.full_like(rank, math.inf)).argmin())
            return self._result(True, q_all, best, times, bound, win_idx, terms, qd_start, 0.0)
        # No trajectory is safe: follow the one that stays safe longest, then wait (sec. 5).
        first_bad = torch.where(
            bad,
            torch.arange(w, device=bad.device).expand(b, w),
            torch.full_like(bad, w, dtype=torch.long),
        ).amin(-1)  # (B,)
        score = first_bad.to(rank.dtype) * 1e6 - rank.clamp(max=1e5)
        best = int(score.argmax())
        hold = max(int(first_bad[best]) - 1, 0)
        q_hold = _held(q_all[best], hold)
        q_one = q_hold.unsqueeze(0)
        terms1, bound1, _ = self._accept_terms(
            q_one, dt, qd_start, q_goal, human, win_idx, timer, look_idx
        )
        if cfg.acc_max is not None and hold >= 1:
            # the stop the acceleration-limited tracking can follow: the same path, slowed
            # down at a constant rate until it stops at or before the held waypoint; kept
            # when its bound is no higher than the abrupt stop's (or within the limit)
            q_soft = smooth_stop(q_all[best], hold).unsqueeze(0)
            terms2, bound2, _ = self._accept_terms(
                q_soft, dt, qd_start, q_goal, human, win_idx, timer, look_idx
            )
            if (
                bound2 is None
                or bound1 is None
                or float(bound2.amax()) <= max(limit, float(bound1.amax()))
            ):
                q_hold, terms1, bound1 = q_soft[0], terms2, bound2
        if cfg.safe_hold and bound1 is not None and hold >= 1 and float(bound1.amax()) > limit:
            # The hold is itself unsafe (the person is predicted to come to the held pose):
            # stop earlier on the same path, at the latest waypoint whose hold is safe.
            earlier = list(range(hold - 1, -1, -1))
            stops = torch.stack([self._stop(q_all[best], h) for h in earlier])
            terms_s, bound_s, _ = self._accept_terms(
                stops, dt, qd_start, q_goal, human, win_idx, timer, look_idx
            )
            if bound_s is not None:
                safe = torch.nonzero(bound_s.amax(-1) <= limit).flatten()
                if safe.numel() > 0:
                    k = int(safe[0])
                    hold, q_hold, bound1 = earlier[k], stops[k], bound_s[k : k + 1]
                    terms1 = {name: v[k : k + 1] for name, v in terms_s.items()}
        t_end = float(times[-1]) if window is None else min(float(window[1]), float(times[-1]))
        wait_s = max(t_end - float(times[hold]), 0.0)
        if (
            human is not None
            and bound is not None
            and bound1 is not None
            and float(bound1.amax()) > limit
        ):
            # Holding is itself unsafe (the person comes towards the held pose): move along
            # the candidate with the smallest peak bound instead, when that is lower; when
            # none is (every candidate is riskier, or leaves the static scene or the limits),
            # step out of the person's way (:meth:`_escape`) when that is lower.
            hold_peak = float(bound1.amax())
            peak = torch.where(static_ok, bound.amax(-1), torch.full_like(rank, math.inf))
            evade = int(peak.argmin())
            if float(peak[evade]) < hold_peak:
                res = self._result(
                    False, q_all, evade, times, bound, win_idx, terms, qd_start, 0.0
                )
                res.evasive = True
                return res
            if not self._imminent(bound1[0], times, win_idx, window, limit):
                return self._wait_result(
                    q_all, best, q_hold, times, bound1, win_idx, terms1, qd_start, wait_s, hold
                )
            escape = self._escape(
                q_all[0, 0], qd_start, dt, q_goal, human, win_idx, timer, look_idx
            )
            q_esc = escape.unsqueeze(0)
            terms_e, bound_e, clear_e = self._accept_terms(
                q_esc, dt, qd_start, q_goal, human, win_idx, timer, look_idx
            )
            if (
                bound_e is not None
                and self._static_ok(q_esc, dt, clear_e, qd_start)
                and float(bound_e.amax()) < hold_peak
            ):
                res = self._replaced_result(
                    q_all, best, escape, times, bound_e, win_idx, terms_e, qd_start, 0.0
                )
                res.evasive = res.escape = True
                return res
        return self._wait_result(
            q_all, best, q_hold, times, bound1, win_idx, terms1, qd_start, wait_s, hold
        )

    def _wait_result(
        self,
        q_all: torch.Tensor,
        best: int,
        q_hold: torch.Tensor,
        times: torch.Tensor,
        bound1: torch.Tensor | None,
        win_idx: torch.Tensor,
        terms1: dict[str, torch.Tensor],
        qd_start: torch.Tensor | None,
        wait_s: float,
        hold: int,
    ) -> PlanResult:
        """The wait: candidate ``best`` replaced by its stop ``q_hold`` (W, J)."""
        res = self._replaced_result(
            q_all, best, q_hold, times, bound1, win_idx, terms1, qd_start, wait_s
        )
        res.hold_index = hold
        return res

    def _replaced_result(
        self,
        q_all: torch.Tensor,
        best: int,
        q_new: torch.Tensor,
        times: torch.Tensor,
        bound1: torch.Tensor | None,
        win_idx: torch.Tensor,
        terms1: dict[str, torch.Tensor],
        qd_start: torch.Tensor | None,
        wait_s: float,
    ) -> PlanResult:
        """An infeasible result whose plan is candidate ``best`` of q_all (B, W, J) replaced
        by q_new (W, J), with the bound (1, W_x) and terms of q_new alone."""
        q_cand = q_all.clone()
        q_cand[best] = q_new
        return self._result(
            False, q_cand, best, times, bound1, win_idx, terms1, qd_start, wait_s, row=0
        )

    def _imminent(
        self,
        hold_bound: torch.Tensor,
        times: torch.Tensor,
        win_idx: torch.Tensor,
        window: tuple[float, float] | None,
        limit: float,
    ) -> bool:
        """Whether the hold's bound (W_x,) breaks ``limit`` within ``cfg.escape_within_s`` of
        the window's start (False when the escape is off)."""
        within = self.cfg.escape_within_s
        if within is None:
            return False
        t_a = float(times[0]) if window is None else float(window[0])
        soon = times[win_idx] <= t_a + within + 1e-9  # (W_x,)
        return bool(soon.any()) and float(hold_bound[soon].max()) > limit

    def _stop(self, q: torch.Tensor, hold: int) -> torch.Tensor:
        """(W, J) the path q (W, J) stopped at waypoint ``hold``: slowed down to a stop at or
        before it (:func:`smooth_stop`) with ``acc_max`` and ``hold >= 1``, else held there
        from that waypoint on."""
        if self.cfg.acc_max is not None and hold >= 1:
            return smooth_stop(q, hold)
        return _held(q, hold)

    def _static_bad(
        self,
        q: torch.Tensor,
        dt: float,
        clearance: torch.Tensor | None,
        free_end: bool = False,
    ) -> torch.Tensor:
        """(B, W) waypoints of q (B, W, J) that break the static checks: clearance below the
        plan's ends (only its start with ``free_end``: a plan that does not end at the task's
        goal) by more than ``END_CLEARANCE_SLACK`` (below 0 at most), or reached by a segment
        faster than ``VEL_TOL`` times the velocity limits."""
        bad = torch.zeros(q.shape[:2], dtype=torch.bool, device=q.device)  # (B, W)
        if clearance is not None:
            ends = clearance[:, :1]  # (B, 1)
            if not free_end:
                ends = torch.minimum(ends, clearance[:, -1:])
            floor = (ends - END_CLEARANCE_SLACK).clamp(max=0.0)
            bad[:, 1:] |= clearance[:, 1:] < floor
        # a segment faster than the limits could jump past the checks
        bad[:, 1:] |= ((q[:, 1:] - q[:, :-1]).abs() / dt > VEL_TOL * self.v_max).any(-1)
        return bad

    def _static_ok(
        self,
        q: torch.Tensor,
        dt: float,
        clearance: torch.Tensor | None,
        qd_start: torch.Tensor | None,
    ) -> bool:
        """Whether the single trajectory q (1, W, J), which need not end at the goal, passes
        the static checks and, with ``acc_max``, stays within ``ACC_TOL`` times it."""
        if bool(self._static_bad(q, dt, clearance, free_end=True).any()):
            return False
        if self.cfg.acc_max is None:
            return True
        return bool(self._within_acc(q, dt, qd_start, self.cfg.acc_max).all())

    @staticmethod
    def _within_acc(
        q: torch.Tensor, dt: float, qd_start: torch.Tensor | None, acc_max: float
    ) -> torch.Tensor:
        """(B,) whether each trajectory of q (B, W, J) stays within ``ACC_TOL`` times
        ``acc_max`` [rad/s^2] (from ``qd_start``)."""
        acc = accelerations(q, dt, qd_start).abs().amax(dim=(-2, -1))  # (B,)
        return acc <= ACC_TOL * acc_max

    def _escape(
        self,
        q_start: torch.Tensor,
        qd_start: torch.Tensor | None,
        dt: float,
        q_goal: torch.Tensor,
        human: C.HumanObstacle,
        win_idx: torch.Tensor,
        timer: _Timer,
        look_idx: torch.Tensor | None,
    ) -> torch.Tensor:
        """(W, J) a way out of the person's path, for when holding is unsafe and no candidate
        is less risky (the robot waits where the person is about to reach, e.g. at the spot
        it has just delivered to).

        From ``q_start`` (moving at ``qd_start``), each waypoint inside the execution window
        heads down the gradient of the risk of staying at the current pose for the rest of
        the window (the confidence penalty of its bound on the window's later waypoints plus
        the penetration of the mean human spheres), at ``INIT_VEL_FRACTION`` of the velocity
        limits (scaled so that no joint exceeds its share), reached within ``cfg.acc_max``.
        When a step would bring the robot within ``cfg.static_margin`` of the static scene
        (or closer than it already is), its part along the clearance gradient is removed, so
        the way out slides along the table instead of into it. After the window, or where
        the gradient vanishes, the motion brakes to rest within ``cfg.acc_max``. Joint limits
        are respected. The caller checks the result exactly, as any plan.
        """
        cfg, w = self.cfg, self.cfg.num_waypoints
        weights = cfg.weights
        v_lim = INIT_VEL_FRACTION * self.v_max
        a_step = math.inf if cfg.acc_max is None else cfg.acc_max * dt
        last_window = int(win_idx.max())
        v = torch.zeros_like(q_start) if qd_start is None else qd_start.clone()
        path = [q_start]
        for i in range(1, w):
            p = path[-1]
            v_des = torch.zeros_like(p)
            normal = None  # gradient of the static clearance
            clear_now = math.inf
            with torch.enable_grad():
                x = p.detach().clone().requires_grad_(True)
                if i <= last_window:
                    terms, bound, _, _ = self._terms(
                        x.expand(1, w, -1),
                        dt,
                        None,
                        q_goal,
                        human,
                        win_idx,
                        None,
                        timer,
                        prune=cfg.prune_margin,
                        look_idx=look_idx,
                    )
                    later = (win_idx >= i).to(p.dtype)  # (W_x,)
                    excess = self._excess(bound[0]) * later
                    risk = weights.human_confidence_penalty * excess.square().sum()
                    pen = terms["human_mean_penetration"][0]
                    risk = risk + weights.human_mean_penetration * pen
                    if risk.requires_grad:
                        (g,) = torch.autograd.grad(risk, x)
                        g = g.nan_to_num(nan=0.0, posinf=0.0, neginf=0.0)
                        scale = float((g.abs() / v_lim).max())
                        if scale > 0.0:
                            v_des = -g / scale
                scene = self.static_scene
                if scene is not None:
                    clear = self._clearance(scene, x)
                    clear_now = float(clear.detach())
                    if clear.requires_grad:
                        (n,) = torch.autograd.grad(clear, x)
                        if all_finite(n) and float(n.square().sum()) > 0.0:
                            normal = n
            # the first segment's velocity is the velocity half a step after the start (see
            # trajectory.accelerations): half the change reaches acc_max there
            a_i = 0.5 * a_step if i == 1 else a_step
            v = torch.minimum(torch.maximum(v + (v_des - v).clamp(-a_i, a_i), -v_lim), v_lim)
            if normal is not None and scene is not None:
                with torch.no_grad():
                    # slide along the obstacle when the step would bring it closer than the
                    # margin (or closer than it already is)
                    limit_c = min(clear_now, cfg.static_margin)
                    if float(self._clearance(scene, p + v * dt)) < limit_c:
                        v = self._slide(v, normal)
            nxt = torch.minimum(torch.maximum(p + v * dt, self.q_min), self.q_max)
            v = (nxt - p) / dt
            path.append(nxt)
        return torch.stack(path)

    def _clearance(self, scene: C.ClearanceScene, q: torch.Tensor) -> torch.Tensor:
        """() the smallest clearance [m] of the robot's spheres at q (J,) from ``scene``."""
        centers = self.robot.sphere_centers(q).view(1, 1, -1, 3)
        return scene.clearance(centers, self.radii).min()

    @staticmethod
    def _slide(v: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
        """v (J,) without its part against ``normal`` (J,), the clearance gradient: a
        velocity that would reduce the clearance moves along the obstacle instead."""
        into = float(v @ normal)
        if into >= 0.0:
            return v
        return v - (into / float(normal @ normal)) * normal

    def _accept_terms(
        self,
        q: torch.Tensor,
        dt: float,
        qd_start: torch.Tensor | None,
        q_goal: torch.Tensor,
        human: C.HumanObstacle | None,
        win_idx: torch.Tensor,
        timer: _Timer,
        look_idx: torch.Tensor | None = None,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor | None, torch.Tensor | None]:
        """Cost terms with sphere pairs pruned at exactly PRUNE_SIGMAS (no margin)."""
        terms, bound, clearance, _ = self._terms(
            q,
            dt,
            qd_start,
            q_goal,
            human,
            win_idx,
            None,
            timer,
            exact=True,
            prune=0.0,
            look_idx=look_idx,
        )
        return terms, bound, clearance

    def _result(
        self,
        feasible: bool,
        q_all: torch.Tensor,
        best: int,
        times: torch.Tensor,
        bound: torch.Tensor | None,
        win_idx: torch.Tensor,
        terms: dict[str, torch.Tensor],
        qd_start: torch.Tensor | None,
        wait_s: float,
        row: int | None = None,
    ) -> PlanResult:
        r = best if row is None else row
        full = torch.zeros_like(times)
        if bound is not None:
            full[win_idx] = bound[r]
        cost_terms = {k: float(v[r]) for k, v in terms.items()}
        cost_terms["max_bound"] = float(full.max())
        vel = (q_all[best, 1:] - q_all[best, :-1]).abs() / (times[1] - times[0])
        cost_terms["max_vel_ratio"] = float((vel / self.v_max).max())
        return PlanResult(
            feasible=feasible,
            q=q_all[best].clone(),
            times=times.clone(),
            bound=full,
            wait_s=wait_s,
            hold_index=None,
            qd_start=qd_start,
            candidates=q_all,
            cost_terms=cost_terms,
            timings={},
        )
