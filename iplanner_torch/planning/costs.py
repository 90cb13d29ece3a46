"""Cost terms of the trajectory optimiser (paper sec. 5) and the human-collision bound.

Every term takes a batch of B trajectories and returns one value per trajectory, (B,), except
:func:`human_collision_bound`, which returns the per-waypoint bound (B, W_x) that the confidence
constraint reads (eq. max_collision_probability, summed over waypoints for eq.
collision_probability).

The sphere-versus-Gaussian bound here is the one of ``iplanner_torch.collision.gaussian``
specialised to diagonal covariances (the forecast's channels are independent, and so are the
sphere centres of eq. center_distribution) and evaluated on a pruned list of sphere pairs:
``min(4/3 pi R^3 f(x_max), Phi(-m), 1)`` with ``R = r_robot + r_human`` (the ball's volume; the
paper prints ``R^2``) and ``m`` the Mahalanobis distance from the mean to the ball. ``x_max`` is
found by Newton's method on the secular equation; its gradient uses the envelope theorem
(``d m^2 / d mu = 2 Sigma^-1 (mu - x_max)``), so the iterations are not differentiated. The
optimiser's iterations use a cheaper isotropic bound, never below this one (see
:func:`human_collision_bound`); acceptance uses the exact one.

These functions run in every optimiser iteration, so they check only what costs no host
synchronisation: shapes, dtypes, devices and Python numbers (``margin``, ``dt``,
``forecast_t0``). The values of tensors are not checked here, except the times of
:func:`forecast_to_obstacle` (once per plan, skipped by the optimiser, whose times are finite
by construction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Protocol, get_args

import torch

from iplanner_torch.checks import (
    finite,
    finite_time,
    integer,
    is_real,
    non_negative,
    positive,
)
from iplanner_torch.collision.gaussian import RADIUS_FLOOR, secular_multiplier
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.planning.trajectory import accelerations, velocities
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import check_device, check_shape

#: how far an obstacle's weights plus its residual may sum from 1 (float32 sums of a softmax
#: and masked renormalisations stay well within it)
WEIGHT_SUM_TOL = 1e-3
#: Mahalanobis distance beyond which a pair is pruned: its bound is below Phi(-5) < 3e-7.
PRUNE_SIGMAS = 5.0
#: Phi(-PRUNE_SIGMAS), the most a pruned pair (or a kept pair's pruned entries together) can
#: add to the bound; ``reduce="sum"`` adds it for every sphere pair, so that the sum stays an
#: upper bound (rounded up to 2.87e-7 from 2.8665e-7)
PRUNED_PAIR_BOUND = 2.87e-7
#: How :func:`human_collision_bound` combines the sphere pairs of a waypoint.
BoundReduce = Literal["max", "sum"]
#: The values of :data:`BoundReduce`.
BOUND_REDUCTIONS: tuple[str, ...] = get_args(BoundReduce)
#: Pair bounds (isotropic) above this get the exact diagonal-Gaussian bound.
EXACT_FROM = 1e-6
#: Relative slack [m per m] on the triangle-inequality pre-check of :func:`candidate_pairs`.
_LOWER_BOUND_SLACK = 1e-4
#: Normalised gap beyond which the isotropic bound is taken at this gap: Phi(-12) is about
#: 1.8e-33, still a normal float32, so the bound stays an upper bound while erfc never
#: underflows into subnormal numbers (about 3x slower on a CPU for the far pairs).
GAP_CLAMP = 12.0


class ClearanceScene(Protocol):
    """Anything with a signed-distance query for spheres (``collision.static.StaticScene``)."""

    def clearance(self, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        """(..., S, 3) centres [m], (S,) radii [m] -> (..., S) signed distance [m]."""
        ...


@dataclass(frozen=True, kw_only=True)
class CostWeights:
    """Weights of the optimiser's cost terms (all dimensionless multipliers)."""

    # smoothness: integral of squared joint accelerations
    joint_acc_l2: float = 1e-3
    # squared joint-limit violation [rad^2]
    joint_limit_violation: float = 100.0
    # squared joint-velocity-limit violation [(rad/s)^2]; 100 (10 until 8ba7343) keeps the
    # paths the iterations bend (round the table, the person) within the limits, where the
    # acceptance would refuse the smoothest for speed and take a rougher candidate: over 20
    # seeds of the 7 table scenarios on the iiwa both planners became smoother in 2x2 and 2x4
    # (by 2.2-5.1 rad^2/s^4), with no contact; the Fetch arm's hardly changed
    # (experiments/safety_seeds/, experiments/speed_scale/)
    joint_vel_limit_violation: float = 100.0
    # squared violation of the acceleration limit the robot's controller tracks [(rad/s^2)^2]
    # (only with OptimizerCfg.acc_max)
    joint_acc_limit_violation: float = 1.0
    # squared static-obstacle penetration beyond the margin [m^2]
    static_clearance: float = 1000.0
    # sum over the execution window of the human-collision bound (eq. collision_probability)
    human_collision_bound: float = 1.0
    # penalty on log(bound / target) above zero: the confidence constraint
    human_confidence_penalty: float = 10.0
    # squared penetration of robot spheres into the mean human spheres [m^2]
    human_mean_penetration: float = 1000.0
    # look-ahead: the confidence penalty on the waypoints after the execution window (a soft
    # cost, never a constraint: the plan bends around where the person is predicted to be
    # before that part of it is executed; those waypoints then also count in
    # human_mean_penetration); 0 leaves the later waypoints free, as in the paper
    human_lookahead_penalty: float = 0.0
    # squared distance of the last waypoint to the goal (only when the goal is not pinned)
    goal_distance: float = 0.0

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (is_real(value) and value >= 0.0 and math.isfinite(value)):
                raise ConfigError(f"expected weight {name} finite and >= 0, got {value!r}")


def joint_acc_l2(q: torch.Tensor, dt: float, qd_start: torch.Tensor | None = None) -> torch.Tensor:
    """Smoothness: ``sum ||q_ddot||^2`` over the waypoints times the time each stands for,
    the integral of the squared acceleration.

    An interior waypoint's second difference stands for ``dt`` (from the mid-point of the
    segment before it to that of the segment after); the first waypoint's acceleration (with
    ``qd_start``, see :func:`~iplanner_torch.planning.trajectory.accelerations`) for the
    half step ``dt / 2`` from the start to the first segment's mid-point.

    Args:
        q: (B, W, J) joint positions [rad].
        dt: seconds between waypoints.
        qd_start: (J,) velocity at the first waypoint [rad/s], or None (then the first
            waypoint's acceleration is not counted).

    Returns:
        (B,) [rad^2/s^3].

    Raises:
        ShapeError: when ``q`` is not (B, W, J) or ``qd_start`` does not end in J.
        ConfigError: when ``dt`` (a Python number) is not finite and > 0.
    """
    check_shape("q", q, ("B", "W", "J"))
    sq = accelerations(q, dt, qd_start).square().sum(-1)  # (B, W - 2) or (B, W - 1)
    if qd_start is None:
        return dt * sq.sum(-1)
    return dt * (sq.sum(-1) - 0.5 * sq[..., 0])


def joint_limit_violation(
    q: torch.Tensor, q_min: torch.Tensor, q_max: torch.Tensor
) -> torch.Tensor:
    """Squared violation of the joint position limits.

    Args:
        q: (B, W, J) joint positions [rad].
        q_min: (J,) lower limits [rad] (-inf for continuous joints).
        q_max: (J,) upper limits [rad] (+inf for continuous joints), each above its
            ``q_min``: that is not checked here (it runs in every optimiser iteration, without
            a host synchronisation); a robot's limits are checked when its description is
            built (``JointSpec``: lower < upper).

    Returns:
        (B,) [rad^2].

    Raises:
        ShapeError: when ``q`` is not (B, W, J) or a limit is not (J,) on its device.
    """
    check_shape("q", q, ("B", "W", "J"))
    check_shape("q_min", q_min, (q.shape[-1],))
    check_shape("q_max", q_max, (q.shape[-1],))
    check_device("q", q, q_min=q_min, q_max=q_max)
    over = torch.relu(q - q_max) + torch.relu(q_min - q)
    return over.square().sum(dim=(-2, -1))


def joint_vel_limit_violation(q: torch.Tensor, dt: float, v_max: torch.Tensor) -> torch.Tensor:
    """Squared violation of the joint velocity limits by the waypoint differences.

    Args:
        q: (B, W, J) joint positions [rad].
        dt: seconds between waypoints.
        v_max: (J,) velocity limits [rad/s].

    Returns:
        (B,) [(rad/s)^2].

    Raises:
        ShapeError: when ``q`` is not (B, W, J) or ``v_max`` is not (J,) on its device.
        ConfigError: when ``dt`` (a Python number) is not finite and > 0.
    """
    check_shape("q", q, ("B", "W", "J"))
    check_shape("v_max", v_max, (q.shape[-1],))
    check_device("q", q, v_max=v_max)
    return torch.relu(velocities(q, dt).abs() - v_max).square().sum(dim=(-2, -1))


def joint_acc_limit_violation(
    q: torch.Tensor, dt: float, a_max: float, qd_start: torch.Tensor | None = None
) -> torch.Tensor:
    """Squared violation of a per-joint acceleration limit by the waypoint accelerations.

    Args:
        q: (B, W, J) joint positions [rad].
        dt: seconds between waypoints.
        a_max: acceleration limit [rad/s^2], the same for every joint.
        qd_start: (J,) velocity at the first waypoint [rad/s] (then the first waypoint's
            acceleration counts too), or None.

    Returns:
        (B,) [(rad/s^2)^2].

    Raises:
        ShapeError: when ``q`` is not (B, W, J) or ``qd_start`` does not end in J.
        ConfigError: when ``dt`` (a Python number) is not finite and > 0, or ``a_max`` not a
            finite number > 0 (NaN gave NaN costs, -1 a cost on a path at rest).
    """
    check_shape("q", q, ("B", "W", "J"))
    a_max = positive("a_max", a_max)
    acc = accelerations(q, dt, qd_start)
    return torch.relu(acc.abs() - a_max).square().sum(dim=(-2, -1))


def static_clearance(
    centers: torch.Tensor, radii: torch.Tensor, scene: ClearanceScene, margin: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Hinge on the static scene's signed distance.

    Args:
        centers: (B, W, S_r, 3) robot sphere centres [m].
        radii: (S_r,) robot sphere radii [m].
        scene: the static obstacles.
        margin: clearance below which the cost starts [m].

    Returns:
        cost (B,) ``sum relu(margin - clearance)^2`` [m^2] and the minimum clearance over
        spheres (B, W) [m].

    Raises:
        ShapeError: when ``centers`` is not (B, W, S_r, 3).
        ConfigError: when ``margin`` is not a finite number.
    """
    check_shape("centers", centers, ("B", "W", "S_r", 3))
    finite("margin", margin)
    clear = scene.clearance(centers, radii)  # (B, W, S_r)
    cost = torch.relu(margin - clear).square().sum(dim=(-2, -1))
    return cost, clear.min(dim=-1).values


def goal_distance(q_last: torch.Tensor, q_goal: torch.Tensor) -> torch.Tensor:
    """Squared joint-space distance of the last waypoint to the goal.

    Args:
        q_last: (B, J) last waypoint [rad].
        q_goal: (J,) goal configuration [rad].

    Returns:
        (B,) [rad^2].

    Raises:
        ShapeError: when ``q_last`` is not (B, J) or ``q_goal`` not (J,) on its device.
    """
    check_shape("q_last", q_last, ("B", "J"))
    check_shape("q_goal", q_goal, (q_last.shape[-1],))
    check_device("q_last", q_last, q_goal=q_goal)
    return (q_last - q_goal).square().sum(-1)


def goal_distance_ee(ee: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Squared end-effector distance to a target point.

    Args:
        ee: (B, 3) tool point of the last waypoint [m], world frame.
        target: (3,) target point [m], world frame.

    Returns:
        (B,) [m^2].

    Raises:
        ShapeError: when ``ee`` is not (B, 3) or ``target`` not (3,) on its device.
    """
    check_shape("ee", ee, ("B", 3))
    check_shape("target", target, (3,))
    check_device("ee", ee, target=target)
    return (ee - target).square().sum(-1)


def gaussian_ball_bound_diag(
    d: torch.Tensor, var: torch.Tensor, rad: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Upper bound of P(||x|| <= R) for x ~ N(d, diag(var)) (paper eq. approx_sphere_collision).

    Args:
        d: (..., 3) Gaussian mean relative to the ball's centre [m] (differentiable).
        var: (..., 3) diagonal variances [m^2], > 0.
        rad: (...) ball radius R = r_robot + r_human [m]; below
            :data:`~iplanner_torch.collision.gaussian.RADIUS_FLOOR` raised to it (the bound
            stays an upper bound).

    Returns:
        bound (...) in [0, 1], ``min(4/3 pi R^3 f(x_max), Phi(-m), 1)``, and ``m^2`` (...)
        the squared Mahalanobis distance from the mean to the ball (0 inside).

    Inputs are not checked: this is the inner loop of :func:`human_collision_bound`, whose
    obstacle is checked (:meth:`HumanObstacle.trusted`). Called directly, a variance that is
    not > 0 gives NaN; ``d``, ``var`` and ``rad`` must be tensors of one floating dtype
    (:func:`iplanner_torch.collision.gaussian.sphere_collision_bound` is the checked entry
    point for one Gaussian and ball).
    """
    rad = rad.clamp_min(RADIUS_FLOOR)
    with torch.no_grad():
        lam = secular_multiplier(d, var, rad)
        y = d / (1.0 + lam.unsqueeze(-1) * var)  # x_max - ball centre, on the sphere
    maha2 = ((y - d).square() / var).sum(-1)  # envelope theorem: y is held fixed
    log_f = -0.5 * maha2 - 0.5 * torch.log(2.0 * math.pi * var).sum(-1)
    log_vol = math.log(4.0 / 3.0 * math.pi) + 3.0 * torch.log(rad)
    vol_bound = torch.exp(log_vol + log_f)
    inside = lam <= 0.0
    m = maha2.clamp_min(1e-12).sqrt()
    phi_bound = torch.where(inside, torch.ones_like(m), 0.5 * torch.erfc(m / math.sqrt(2.0)))
    bound = torch.minimum(torch.minimum(vol_bound, phi_bound), torch.ones_like(m))
    return bound, maha2


@dataclass(kw_only=True)
class HumanObstacle:
    """The forecast human as Gaussian spheres at the W_x waypoint times of the window.

    Attributes:
        mean: (W_x, A, S_h, 3) sphere-centre means [m], world frame.
        var: (W_x, A, S_h, 3) sphere-centre variances [m^2].
        radii: (S_h,) sphere radii [m].
        weights: (A,) action weights p(c | F, p), summing to 1.
        residual: weight of the actions left out, a finite number >= 0.

    Shapes, dtypes and devices are checked at construction (no host synchronisation; the
    values are not: :meth:`trusted` tells whether they can be, and
    :func:`human_collision_bound` counts an obstacle that cannot as a bound of 1).

    Raises:
        ShapeError: when the tensors' shapes disagree, or they are not all of one floating
            dtype and on one device.
        ConfigError: when ``residual`` is not a finite number >= 0.
    """

    mean: torch.Tensor
    var: torch.Tensor
    radii: torch.Tensor
    weights: torch.Tensor
    # total weight of actions left out (see :func:`drop_light_actions`); every pair's mixture
    # bound adds it, as those actions' collision probabilities are at most 1
    residual: float = 0.0
    # caches (init=False: dataclasses.replace makes a new obstacle without them, so a copy with
    # other values is never judged by the old ones)
    # the per-pair tensors of the last ``pairs`` seen (the optimiser reuses one pair set for
    # several iterations): (pairs, robot radii), then (mean, var, 1 / s_max, radius sums)
    _pair_cache: tuple[tuple, tuple] | None = field(
        default=None, repr=False, compare=False, init=False
    )
    # the per-entry tensors of the last ``entries`` seen (see :meth:`entry_tensors`):
    # (entries, pairs, robot radii), then the tensors
    _entry_cache: tuple[tuple, tuple] | None = field(
        default=None, repr=False, compare=False, init=False
    )
    # (W_x, A, S_h) largest standard deviations (computed once, see :meth:`max_std`)
    _max_std: torch.Tensor | None = field(default=None, repr=False, compare=False, init=False)
    # () bool tensor: whether mean, var and weights are all finite (computed once)
    _finite: torch.Tensor | None = field(default=None, repr=False, compare=False, init=False)
    # () bool tensor: whether the values can make a probability (see :meth:`trusted`)
    _trusted: torch.Tensor | None = field(default=None, repr=False, compare=False, init=False)

    def __post_init__(self) -> None:
        check_shape("HumanObstacle.mean", self.mean, ("W_x", "A", "S_h", 3))
        w_x, a, s_h, _ = self.mean.shape
        check_shape("HumanObstacle.var", self.var, (w_x, a, s_h, 3))
        check_shape("HumanObstacle.radii", self.radii, (s_h,))
        check_shape("HumanObstacle.weights", self.weights, (a,))
        dtype, device = self.mean.dtype, self.mean.device
        if not self.mean.is_floating_point():
            raise ShapeError(f"expected HumanObstacle.mean of a floating dtype, got {dtype}")
        for name in ("var", "radii", "weights"):
            x = getattr(self, name)
            if x.dtype != dtype or x.device != device:
                raise ShapeError(
                    f"expected HumanObstacle.{name} {dtype} on {device} (as mean), got "
                    f"{x.dtype} on {x.device}"
                )
        non_negative("HumanObstacle.residual", self.residual)

    def all_finite(self) -> torch.Tensor:
        """() bool tensor: every mean, variance and weight is finite (computed on the first
        call only: the obstacle is fixed during a solve, whose every iteration asks)."""
        if self._finite is None:
            self._finite = (
                torch.isfinite(self.mean).all()
                & torch.isfinite(self.var).all()
                & torch.isfinite(self.weights).all()
            )
        return self._finite

    def trusted(self) -> torch.Tensor:
        """() bool tensor: the values can make a probability: every mean, variance and weight
        finite (:meth:`all_finite`), the variances, radii and weights >= 0, and the weights
        with ``residual`` summing to 1 (within :data:`WEIGHT_SUM_TOL`). Weights of 0 made the
        bound 0, "no person", and a negative variance NaN. Computed on the first call only,
        without a host synchronisation (a tensor, for ``torch.where``)."""
        if self._trusted is None:
            total = self.weights.sum() + self.residual
            self._trusted = (
                self.all_finite()
                & (self.var >= 0).all()
                & (self.radii >= 0).all()
                & (self.weights >= 0).all()
                & ((total - 1.0).abs() <= WEIGHT_SUM_TOL)
            )
        return self._trusted

    def max_std(self) -> torch.Tensor:
        """(W_x, A, S_h) the largest standard deviation of each sphere centre [m] (computed on
        the first call only)."""
        if self._max_std is None:
            self._max_std = self.var.amax(-1).sqrt()
        return self._max_std

    def pair_tensors(
        self, pairs: torch.Tensor, robot_radii: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Human-side tensors of the sphere pairs (cached for the last ``pairs`` given).

        Args:
            pairs: (P, 2) (robot, human) sphere indices.
            robot_radii: (S_r,) [m].

        Returns:
            mean (W_x, P, A, 3) [m], var (W_x, P, A, 3) [m^2], ``1 / s_max`` (W_x, P, A)
            [1/m] with ``s_max`` the largest standard deviation, and ``R`` (P, 1) [m].
        """
        # the key holds the tensors themselves: an id() or data_ptr() alone could be reused by
        # a new tensor once the old one is freed
        key = (pairs, robot_radii)
        if self._pair_cache is None or not _same_objects(self._pair_cache[0], key):
            ri, hi = pairs[:, 0], pairs[:, 1]
            try:
                mean = self.mean.transpose(1, 2)[:, hi]  # (W_x, P, A, 3)
                var = self.var.transpose(1, 2)[:, hi]
                rad = (robot_radii[ri] + self.radii[hi])[:, None]
            except IndexError as err:  # (the CPU's bounds check; free)
                raise ShapeError(
                    f"expected pairs of (robot, human) sphere indices below "
                    f"({robot_radii.shape[0]}, {self.radii.shape[0]}) (S_r, S_h): {err}"
                ) from err
            self._pair_cache = (key, (mean, var, var.amax(-1).rsqrt(), rad))
        return self._pair_cache[1]

    def entry_tensors(
        self, pairs: torch.Tensor, entries: torch.Tensor, robot_radii: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        """Per-entry tensors of (waypoint, pair, action) entries (cached for the last ones).

        Args:
            pairs: (P, 2) (robot, human) sphere indices.
            entries: (K, 3) (waypoint, index into ``pairs``, action) indices.
            robot_radii: (S_r,) [m].

        Returns:
            mean (K, 1, 3) [m], var (K, 1, 3) [m^2], ``1 / s_max`` (K, 1) [1/m], ``R`` (K, 1)
            [m], the action weights (K,), the flat (waypoint, pair) index ``w P + p`` (K,),
            the flat (waypoint, robot sphere) index ``w S_r + r`` (K,), the pair index (K,),
            (W_x, P, A) 1 at the entries, else 0, and the means as coordinate planes (3, K)
            [m].
        """
        key = (entries, pairs, robot_radii)
        if self._entry_cache is None or not _same_objects(self._entry_cache[0], key):
            # gathered from the obstacle itself, not from :meth:`pair_tensors`: a check
            # without a gradient needs no (W_x, P, A) tensor of every entry of the pairs
            w_x, n_p, n_a = self.mean.shape[0], pairs.shape[0], self.weights.shape[0]
            w_k, p_k, a_k = entries.unbind(-1)
            try:
                r_k, h_k = pairs[p_k, 0], pairs[p_k, 1]
                mean = self.mean[w_k, a_k, h_k].unsqueeze(1)
                var = self.var[w_k, a_k, h_k].unsqueeze(1)
                rad = (robot_radii[r_k] + self.radii[h_k]).unsqueeze(1)
                weight = self.weights[a_k]
            except IndexError as err:  # (the CPU's bounds check; free)
                raise ShapeError(
                    f"expected entries of (waypoint, pair, action) indices below "
                    f"({w_x}, {n_p}, {n_a}) (W_x, P, A), and pairs of (robot, human) sphere "
                    f"indices below ({robot_radii.shape[0]}, {self.radii.shape[0]}) "
                    f"(S_r, S_h): {err}"
                ) from err
            inv_s = var.amax(-1).rsqrt()
            flat_wp = w_k * n_p + p_k
            flat_wr = w_k * robot_radii.shape[0] + r_k
            kept = torch.zeros(w_x, n_p, n_a, dtype=weight.dtype, device=weight.device)
            kept[w_k, p_k, a_k] = 1.0
            planes = mean[:, 0].T.contiguous()  # (3, K)
            self._entry_cache = (
                key,
                (mean, var, inv_s, rad, weight, flat_wp, flat_wr, p_k, kept, planes),
            )
        return self._entry_cache[1]


def _same_objects(a: tuple, b: tuple) -> bool:
    """Whether two tuples hold the very same objects, one by one."""
    return len(a) == len(b) and all(x is y for x, y in zip(a, b, strict=True))


def drop_light_actions(human: HumanObstacle, max_mass: float) -> HumanObstacle:
    """The obstacle without its lightest actions, their total weight at most ``max_mass``.

    The mixture bound ``sum_a w_a P_a`` is at most ``sum_kept w_a P_a + sum_dropped w_a``, so
    :func:`human_collision_bound` on the result (which adds ``residual``) is still an upper
    bound, looser by at most ``max_mass``; it evaluates fewer sphere pairs when the classifier
    is confident (a weight of 0.99 on one action is common).

    Args:
        human: the Gaussian human spheres.
        max_mass: largest total weight that may be dropped (>= 0).

    Returns:
        ``human`` itself when nothing can be dropped, else a new obstacle with the kept actions.
    """
    if max_mass < 0.0:
        raise ConfigError(f"expected max_mass >= 0, got {max_mass}")
    w = human.weights
    order = torch.argsort(w)
    cum = torch.cumsum(w[order], 0)
    n_drop = int((cum <= max_mass).sum())
    n_drop = min(n_drop, w.shape[0] - 1)  # keep at least one action
    if n_drop == 0:
        return human
    keep = order[n_drop:].sort().values
    return HumanObstacle(
        mean=human.mean[:, keep],
        var=human.var[:, keep],
        radii=human.radii,
        weights=w[keep],
        residual=human.residual + float(cum[n_drop - 1]),
    )


def _check_robot_spheres(
    robot_centers: torch.Tensor,
    robot_radii: torch.Tensor,
    human: HumanObstacle,
    *,
    nonempty: bool = False,
) -> None:
    """ShapeError unless ``human`` is a :class:`HumanObstacle`, ``robot_centers`` is
    (B, W_x, S_r, 3) with the obstacle's W_x (and, with ``nonempty``, B >= 1 and W_x >= 1),
    ``robot_radii`` is (S_r,), and both have the obstacle's dtype and device (no host
    synchronisation)."""
    if not isinstance(human, HumanObstacle):
        raise ShapeError(f"expected human a HumanObstacle, got {type(human).__name__}")
    check_shape("robot_centers", robot_centers, ("B", "W_x", "S_r", 3))
    b, w_x, s_r, _ = robot_centers.shape
    if w_x != human.mean.shape[0]:
        raise ShapeError(
            f"expected robot_centers (B, W_x, S_r, 3) with W_x = {human.mean.shape[0]} (the "
            f"human obstacle's times), got {tuple(robot_centers.shape)}"
        )
    if nonempty and (b == 0 or w_x == 0):
        raise ShapeError(
            "expected robot_centers (B, W_x, S_r, 3) with B >= 1 and W_x >= 1, got "
            f"{tuple(robot_centers.shape)}"
        )
    check_shape("robot_radii", robot_radii, (s_r,))
    dtype, device = human.mean.dtype, human.mean.device
    for name, x in (("robot_centers", robot_centers), ("robot_radii", robot_radii)):
        if x.dtype != dtype or x.device != device:
            raise ShapeError(
                f"expected {name} {dtype} on {device} (as the human obstacle), got {x.dtype} "
                f"on {x.device}"
            )


def candidate_pairs(
    robot_centers: torch.Tensor,
    robot_radii: torch.Tensor,
    human: HumanObstacle,
    margin: float,
) -> torch.Tensor:
    """Sphere pairs whose bound can exceed Phi(-PRUNE_SIGMAS) after a move of up to ``margin``.

    Args:
        robot_centers: (B, W_x, S_r, 3) robot sphere centres [m], B >= 1, W_x >= 1 the
            obstacle's.
        robot_radii: (S_r,) [m].
        human: the Gaussian human spheres (dtype and device of the robot's tensors).
        margin: extra distance the robot spheres may move before the pairs are refreshed [m],
            a finite number >= 0.

    Returns:
        (P, 2) long tensor of (robot sphere, human sphere) indices.

    Raises:
        ShapeError: on wrong shapes (B = 0, W_x = 0 or a W_x other than the obstacle's
            included), dtypes or devices.
        ConfigError: when ``margin`` is not a finite number >= 0 (a NaN margin would keep no
            pair, a bound of 0 for a sphere inside the person).
    """
    return _candidates(robot_centers, robot_radii, human, margin, with_entries=False)[0]


def candidate_entries(
    robot_centers: torch.Tensor,
    robot_radii: torch.Tensor,
    human: HumanObstacle,
    margin: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The pairs of :func:`candidate_pairs` and, within them, the (waypoint, pair, action)
    entries whose bound can exceed Phi(-PRUNE_SIGMAS) after a move of up to ``margin``.

    A pair is kept when one of its actions comes within reach at some waypoint; an entry only
    where that action's sphere does at that waypoint, by its own standard deviation there
    (the pair's test takes the largest over all waypoints and actions). With many actions
    spread over the workspace, most entries of the kept pairs are far: in the blocking scene
    with the reaching predictor's 9 weighted actions, 28 % of them are kept at the optimiser's
    margin of 0.15 m and 18 % at 0. :func:`human_collision_bound` given both evaluates only
    the entries.

    Args:
        robot_centers: (B, W_x, S_r, 3) robot sphere centres [m], B >= 1, W_x >= 1 the
            obstacle's.
        robot_radii: (S_r,) [m].
        human: the Gaussian human spheres (dtype and device of the robot's tensors).
        margin: extra distance the robot spheres may move before the entries are refreshed
            [m], a finite number >= 0.

    Returns:
        pairs (P, 2) long (robot sphere, human sphere) indices, as :func:`candidate_pairs`,
        and entries (K, 3) long (waypoint, index into ``pairs``, action), each left-out
        entry's isotropic bound at most Phi(-PRUNE_SIGMAS) for every trajectory.

    Raises:
        ShapeError: as :func:`candidate_pairs`.
        ConfigError: as :func:`candidate_pairs`.
    """
    pairs, entries = _candidates(robot_centers, robot_radii, human, margin, with_entries=True)
    assert entries is not None
    return pairs, entries


def _candidates(
    robot_centers: torch.Tensor,
    robot_radii: torch.Tensor,
    human: HumanObstacle,
    margin: float,
    *,
    with_entries: bool,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Pairs (P, 2) and, ``with_entries``, entries (K, 3) (:func:`candidate_entries`)."""
    _check_robot_spheres(robot_centers, robot_radii, human, nonempty=True)
    non_negative("margin", margin)
    with torch.no_grad():
        sigma = human.var.amax(dim=(-1, 1, 0)).sqrt()  # (S_h,)
        reach = robot_radii[:, None] + human.radii[None, :] + PRUNE_SIGMAS * sigma[None, :]
        thresh = reach + margin  # (S_r, S_h)
        # Cheap lower bound first: at each time, the B robot centres lie in a ball around their
        # mean and the A human means in a ball around theirs, so the distance of any two is at
        # least the distance of the ball centres minus both radii (triangle inequality).
        c_bar = robot_centers.mean(0)  # (W_x, S_r, 3)
        rho_r = (robot_centers - c_bar).norm(dim=-1).amax(0)  # (W_x, S_r)
        m_bar = human.mean.mean(1)  # (W_x, S_h, 3)
        rho_h = (human.mean - m_bar.unsqueeze(1)).norm(dim=-1).amax(1)  # (W_x, S_h)
        centre_dist = (c_bar.unsqueeze(2) - m_bar.unsqueeze(1)).norm(dim=-1)  # (W_x, S_r, S_h)
        lower = (centre_dist - rho_r.unsqueeze(2) - rho_h.unsqueeze(1)).amin(0)  # (S_r, S_h)
        # slack for the rounding of the bound (it must never exceed the true distance)
        maybe = lower <= thresh + _LOWER_BOUND_SLACK * (1.0 + thresh.abs())
        ri, hi = torch.nonzero(maybe, as_tuple=True)
        if ri.numel() == 0:
            pairs = torch.nonzero(maybe)
            return pairs, (pairs.new_zeros(0, 3) if with_entries else None)
        # exact minimum distance over (B, W_x, A) for the remaining pairs, gathered and summed
        # coordinate plane by plane (as _distance3: the same numbers, without its strided reads)
        r_pl = robot_centers.permute(3, 0, 1, 2).contiguous().index_select(-1, ri)
        h_pl = human.mean.permute(3, 0, 1, 2).contiguous().index_select(-1, hi)
        sq = _plane_squared_distances(r_pl.unsqueeze(3), h_pl)  # (B, W_x, A, P')
        near = sq.amin(0).sqrt_()  # (W_x, A, P'); sqrt is monotone: the min of the distances
        keep = near.amin(dim=(0, 1)) <= thresh[ri, hi]  # (P',)
        pairs = torch.stack([ri[keep], hi[keep]], dim=-1)
        if not with_entries:
            return pairs, None
        # per entry: within reach by that action's own largest standard deviation there
        s_max = human.max_std().index_select(-1, hi[keep])  # (W_x, A, P)
        rad = (robot_radii[ri[keep]] + human.radii[hi[keep]]).unsqueeze(0).unsqueeze(0)
        close = near[:, :, keep] <= rad + PRUNE_SIGMAS * s_max + margin  # (W_x, A, P)
        w_k, a_k, p_k = torch.nonzero(close, as_tuple=True)
        return pairs, torch.stack([w_k, p_k, a_k], dim=-1)


def _distance3(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Euclidean distance of broadcast (..., 3) points, summed per component.

    The same value as ``(a - b).norm(dim=-1)`` up to rounding, without the (..., 3)
    difference tensor and the reduction over a last dimension of 3, which dominate the cost of
    the collision bound on a CPU (about 3x faster there). Not for autograd: its gradient is
    not finite at a zero distance.
    """
    sq = (a[..., 0] - b[..., 0]).square()
    sq = sq + (a[..., 1] - b[..., 1]).square()
    sq = sq + (a[..., 2] - b[..., 2]).square()
    return sq.sqrt()


def _pair_bounds(
    c: torch.Tensor,
    mu: torch.Tensor,
    var: torch.Tensor,
    inv_s: torch.Tensor,
    rad: torch.Tensor,
    exact: bool,
    planes: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pair bounds and centre distances for every action.

    Args:
        c: (..., 3) robot sphere centres [m].
        mu: (..., A, 3) human sphere-centre means [m] (broadcast with ``c``).
        var: (..., A, 3) their variances [m^2].
        inv_s: (..., A) ``1 / s_max``, the largest standard deviation's inverse [1/m].
        rad: (..., 1) or (..., A) sums of the two radii [m].
        exact: refine the large bounds with :func:`gaussian_ball_bound_diag`.
        planes: for entries (``c`` (B, K, 3), ``mu`` (K, 1, 3)), the same points as
            coordinate planes, (3, B, K) and (3, K): without autograd the distances are
            summed plane by plane (:func:`_plane_distances`, the same numbers); None: from
            ``c`` and ``mu``.

    Returns:
        bound (..., A) in [0, 1] and distance (..., A) [m] between centre and mean.
    """
    differentiable = torch.is_grad_enabled() and (c.requires_grad or mu.requires_grad)
    d: torch.Tensor | None = None
    if differentiable:
        d = mu - c.unsqueeze(-2)  # (..., A, 3)
        dist = d.norm(dim=-1)  # (..., A)
    elif planes is not None:
        dist = _plane_distances(*planes).unsqueeze(-1)  # (B, K, 1)
    else:
        dist = _distance3(mu, c.unsqueeze(-2))
    bound = _isotropic(dist, rad, inv_s)
    if exact:
        bound = _refine(bound, bound.detach() > EXACT_FROM, c, mu, var, rad, d)
    return bound, dist


#: how far a gap that is not positive is moved down before the erfc of :func:`_isotropic`:
#: ``erfc(-_INSIDE_SHIFT / sqrt(2))`` is 2 to the last bit in float32 and float64
_INSIDE_SHIFT = 1000.0


def _isotropic(dist: torch.Tensor, rad: torch.Tensor, inv_s: torch.Tensor) -> torch.Tensor:
    """The isotropic bound ``Phi(-(dist - rad) inv_s)`` (1 where the gap is not positive or
    NaN) of broadcast centre distances [m], radius sums [m] and ``1 / s_max`` [1/m].

    Without a mask: a gap that is not positive is moved down by :data:`_INSIDE_SHIFT` through
    its sign (a positive gap by exactly 0), where the bound is 1, and a NaN bound becomes 1.
    The values and gradients are those of ``where(gap > 0, Phi(-gap), 1)``; on the CPU that
    mask's ``where`` took longer than the rest of the bound's element-wise work. Without a
    gradient the steps run in place.
    """
    if torch.is_grad_enabled() and (
        dist.requires_grad or rad.requires_grad or inv_s.requires_grad
    ):
        gap = ((dist - rad) * inv_s).clamp(max=GAP_CLAMP)
        gap = gap + (torch.sign(gap) - 1.0) * _INSIDE_SHIFT
        return (0.5 * torch.erfc(gap * (1.0 / math.sqrt(2.0)))).nan_to_num(nan=1.0)
    gap = (dist - rad).mul_(inv_s).clamp_(max=GAP_CLAMP)
    gap.add_(torch.sign(gap).sub_(1.0).mul_(_INSIDE_SHIFT))
    return torch.erfc(gap.mul_(1.0 / math.sqrt(2.0))).mul_(0.5).nan_to_num_(nan=1.0)


def _entry_planes(robot_centers: torch.Tensor, flat: torch.Tensor) -> torch.Tensor:
    """(3, B, K) the coordinates of the robot sphere centres (B, W_x, S_r, 3) at the flat
    (waypoint, sphere) indices ``flat`` (K,) ``w S_r + r``, one plane per coordinate.

    Gathered as whole columns of the (3 B, W_x S_r) planes: ``index_select`` along the middle
    dimension of (B, W_x S_r, 3), one (3,) slice per index, took about twice as long on the
    CPU for the optimiser's 60,000 entries, and the planes give the distances without the
    strided reads of :func:`_distance3`: gather and distances 1.3 ms against 6.8 ms there.
    """
    b = robot_centers.shape[0]
    cols = robot_centers.permute(3, 0, 1, 2).reshape(3 * b, -1)  # (3 B, W_x S_r)
    return cols.index_select(1, flat).view(3, b, -1)


def _plane_squared_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared Euclidean distances of points given as coordinate planes ``a`` (3, ...) and
    ``b`` (3, ...) (broadcast), summed in the order of :func:`_distance3` (the same numbers)."""
    sq = (a[0] - b[0]).square_()
    sq += (a[1] - b[1]).square_()
    sq += (a[2] - b[2]).square_()
    return sq


def _plane_distances(planes: torch.Tensor, mean_planes: torch.Tensor) -> torch.Tensor:
    """(B, K) Euclidean distances of the robot centres ``planes`` (3, B, K) to the means
    ``mean_planes`` (3, K)."""
    return _plane_squared_distances(mean_planes.unsqueeze(1), planes).sqrt_()


def _any_leading(mask: torch.Tensor, n: int) -> torch.Tensor:
    """``mask`` (bool) reduced with "any" over its first ``n`` dimensions.

    The same as ``mask.flatten(0, n - 1).any(0)``, as the maximum of its bytes: on the
    (8, about 62,000) penetration masks of 60 logged iterations of the Fetch arm, torch's
    ``any`` over the leading dimension took 0.30 ms a mask on one CPU thread, this 0.034 ms.
    """
    flat = mask.flatten(0, n - 1)
    if flat.shape[0] == 0:  # nothing to reduce: all false, as any's
        return flat.new_zeros(flat.shape[1:])
    return flat.view(torch.uint8).amax(0).bool()


def _refine(
    bound: torch.Tensor,
    sel: torch.Tensor,
    c: torch.Tensor,
    mu: torch.Tensor,
    var: torch.Tensor,
    rad: torch.Tensor,
    d: torch.Tensor | None = None,
) -> torch.Tensor:
    """``bound`` (..., A) with its entries where ``sel`` (..., A) is true lowered to the exact
    diagonal-Gaussian bound (:func:`gaussian_ball_bound_diag`); the other arguments as
    :func:`_pair_bounds`, ``d`` the (..., A, 3) differences ``mu - c`` when at hand."""
    idx = sel.nonzero(as_tuple=True)  # one scan of the mask, for every gather below
    if idx[0].numel() == 0:
        return bound
    shape3 = (*bound.shape, 3)
    if d is None:  # only the selected differences
        d_sel = mu.expand(shape3)[idx] - c.unsqueeze(-2).expand(shape3)[idx]
    else:
        d_sel = d[idx]
    exact_b, _ = gaussian_ball_bound_diag(
        d_sel, var.expand(shape3)[idx], rad.expand(bound.shape)[idx]
    )
    return bound.index_put(idx, torch.minimum(exact_b, bound[idx]))


def _entry_mixture(
    bound: torch.Tensor, weight: torch.Tensor, flat_wp: torch.Tensor, shape: tuple[int, int, int]
) -> torch.Tensor:
    """(B, W_x, P) the per-pair sums of the entries' weighted bounds ``bound`` (B, K, 1), each
    entry's at its flat (waypoint, pair) index ``flat_wp`` (K,); ``shape`` (B, W_x, P)."""
    b, w, n_p = shape
    return bound.new_zeros(b, w * n_p).index_add_(1, flat_wp, bound[..., 0] * weight).view(shape)


def _mixture_refined_at_the_max(
    bound: torch.Tensor,
    c: torch.Tensor,
    mu: torch.Tensor,
    var: torch.Tensor,
    rad: torch.Tensor,
    weight: torch.Tensor,
    flat_wp: torch.Tensor,
    shape: tuple[int, int, int],
) -> torch.Tensor:
    """The per-pair mixtures (B, W_x, P) of the entries' isotropic bounds ``bound`` (B, K, 1),
    refined (as ``exact=True``) only where the maximum over the pairs can depend on it.

    The exact bound only lowers an entry's isotropic one, so a pair whose isotropic mixture
    is at most the refined mixture of another pair at that waypoint cannot hold the maximum.
    The isotropic maximiser of each waypoint is refined first; then every pair whose
    isotropic mixture exceeds the maximiser's refined one. The maximum over the pairs is the
    one of refining every entry above ``EXACT_FROM`` (the same numbers: each refined pair's
    entries are refined alike and summed in the same order); the pairs left unrefined keep
    their isotropic mixtures, which are no larger.

    Args:
        bound: (B, K, 1) isotropic entry bounds.
        c, mu, var, rad: (B, K, 3), (K, 1, 3), (K, 1, 3), (K, 1) as :func:`_pair_bounds`.
        weight: (K,) the entries' action weights.
        flat_wp: (K,) the entries' flat (waypoint, pair) indices ``w P + p``.
        shape: (B, W_x, P).

    Returns:
        (B, W_x, P) mixtures (without the residual weight).
    """
    b, w, n_p = shape

    def mix(x: torch.Tensor) -> torch.Tensor:
        return _entry_mixture(x, weight, flat_wp, shape).view(b, -1)

    iso = mix(bound)  # (B, W_x P)
    big = bound > EXACT_FROM  # (B, K, 1)
    wp_b = flat_wp.expand(b, -1)  # (B, K)
    top = iso.view(b, w, n_p).argmax(-1)  # (B, W_x)
    flat_top = top + n_p * torch.arange(w, device=top.device)  # (B, W_x) into W_x P
    at_top = torch.zeros_like(iso, dtype=torch.bool).scatter_(1, flat_top, True)
    first = at_top.gather(1, wp_b).unsqueeze(-1) & big
    bound = _refine(bound, first, c, mu, var, rad)
    low = mix(bound).gather(1, flat_top)  # (B, W_x) the maximisers' refined mixtures
    over = (iso.view(b, w, n_p) > low.unsqueeze(-1)).view(b, -1) & ~at_top  # (B, W_x P)
    bound = _refine(bound, over.gather(1, wp_b).unsqueeze(-1) & big, c, mu, var, rad)
    return _entry_mixture(bound, weight, flat_wp, shape)


def human_collision_bound(
    robot_centers: torch.Tensor,
    robot_radii: torch.Tensor,
    human: HumanObstacle,
    pairs: torch.Tensor | None = None,
    *,
    exact: bool = True,
    entries: torch.Tensor | None = None,
    reduce: BoundReduce = "max",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-waypoint collision bound: max over sphere pairs of the action-weighted pair bound.

    An obstacle whose values cannot make a probability (:meth:`HumanObstacle.trusted`: not
    finite, a negative variance, radius or weight, weights that do not sum to 1) gives a
    bound of 1 at every waypoint (unsafe; weights of 0 gave 0, as if there were no person),
    as does a bound that is not finite (:func:`unsafe_if_not_finite`). See
    :func:`_human_collision_bound` for the rest.
    """
    bound, pen = _human_collision_bound(
        robot_centers, robot_radii, human, pairs, exact=exact, entries=entries, reduce=reduce
    )
    return unsafe_if_not_finite(bound, human), pen


def unsafe_if_not_finite(bound: torch.Tensor, human: HumanObstacle) -> torch.Tensor:
    """The collision bound with every value that cannot be trusted set to 1 (unsafe).

    A NaN or inf in the predicted human does not show up as a NaN bound: the sphere-pair
    pruning (:func:`candidate_pairs`, :func:`candidate_entries`) drops every pair it cannot
    compare (for all times, as it reduces over them), and the bound without pairs is the
    dropped actions' weight, usually 0 ("no human"). So the bound counts as 1 everywhere
    when the obstacle's values cannot make a probability (:meth:`HumanObstacle.trusted`: not
    finite, a negative variance, radius or weight, weights that do not sum to 1), and so does
    a non-finite bound itself; :func:`human_collision_bound` applies it to what it returns.
    Otherwise the values and their gradients are unchanged. (:class:`Forecast` rejects
    non-finite values when built; this is the planner's own second line of defence.)

    Args:
        bound: (..., W_x) collision bounds in [0, 1].
        human: the obstacle the bound was computed for.

    Returns:
        (..., W_x) bounds, equal to ``bound`` where it is finite and the human is finite.
    """
    human_ok = human.trusted().to(bound.device)
    return torch.where(human_ok & torch.isfinite(bound), bound, torch.ones_like(bound))


def _human_collision_bound(
    robot_centers: torch.Tensor,
    robot_radii: torch.Tensor,
    human: HumanObstacle,
    pairs: torch.Tensor | None = None,
    *,
    exact: bool = True,
    entries: torch.Tensor | None = None,
    reduce: BoundReduce = "max",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-waypoint collision bound: max over sphere pairs of the action-weighted pair bound
    (:func:`human_collision_bound` without its check of the obstacle's values).

    Eq. max_collision_probability with the mixture over actions:
    ``max_{j,l} sum_a p(a) P(B_j(q_i) cap C_l^a(t_i) != empty)``. That bounds each pair's
    probability of touching, not the probability that some pair touches, which can be larger
    (a robot sphere between two independently predicted hands). ``reduce="sum"`` gives
    Boole's bound on that probability instead: ``sum_{j,l}`` of the same mixtures, plus the
    left-out actions' weight once, plus :data:`PRUNED_PAIR_BOUND` for each of the S_r S_h
    pairs when ``pairs`` is given (a pruned pair, or a kept pair's pruned entries, add at
    most that), clamped at 1. Its gradient reaches every evaluated pair.

    Two pair bounds are available. The *isotropic* one, ``Phi(-(||mu - c|| - R) / s_max)``
    with ``s_max`` the largest standard deviation, is cheap (no secular equation) and never
    below the exact one (the Mahalanobis distance to the ball is at least the Euclidean gap
    over ``s_max``; its gap is taken at most ``GAP_CLAMP``, which only raises it); the
    optimiser's iterations use it. With ``exact=True`` the pairs whose
    isotropic bound exceeds ``EXACT_FROM`` get :func:`gaussian_ball_bound_diag`, the rest keep
    the isotropic value (still an upper bound, below ``EXACT_FROM``).

    When ``robot_centers`` requires a gradient, every pair is first evaluated without autograd
    and only the maximising pair of each waypoint (the only one the max passes a gradient to)
    and the pairs that penetrate are evaluated again with it: the values are the same, and
    the backward pass costs O(B W_x A) instead of O(B W_x P A).

    Args:
        robot_centers: (B, W_x, S_r, 3) robot sphere centres at the window's waypoints [m].
        robot_radii: (S_r,) [m].
        human: the Gaussian human spheres at the same W_x times.
        pairs: (P, 2) (robot, human) sphere indices to evaluate (from :func:`candidate_pairs`),
            int64 or int32 on the robot's device; None evaluates all S_r x S_h pairs. Pruned
            pairs contribute at most Phi(-5). Their values are not checked (that would cost a
            host synchronisation per iteration), except that an index beyond S_r or S_h is
            refused on the CPU.
        exact: refine the large pair bounds with the exact diagonal-Gaussian bound.
        entries: (K, 3) (waypoint, pair, action) indices into ``W_x``, ``pairs`` and the
            actions (from :func:`candidate_entries`, with these ``pairs``), int64 on the robot's
            device, or None for every entry of every pair. Only these are evaluated: a pair's
            left-out actions add nothing to its mixture, each at most Phi(-5) by construction,
            so the bound is at most that below the full one.

    Returns:
        bound (B, W_x) in [0, 1] and the penetration cost (B,) ``sum_a p(a) sum relu(R -
        ||c - mu||)^2`` [m^2] of robot spheres into the mean human spheres.

    Raises:
        ShapeError: when ``robot_centers`` is not (B, W_x, S_r, 3) with the obstacle's W_x,
            ``robot_radii`` not (S_r,), either not of the obstacle's dtype and
            device, or ``pairs`` not a (P, 2) integer tensor on that device (or, on the CPU,
            holding an index beyond S_r or S_h), or ``entries`` not a (K, 3) int64 tensor on
            that device given with ``pairs`` (or, on the CPU, holding an index beyond W_x, P
            or A).
        ConfigError: when ``reduce`` is not ``"max"`` or ``"sum"``.
    """
    if reduce not in BOUND_REDUCTIONS:
        raise ConfigError(f"expected reduce 'max' or 'sum', got {reduce!r}")
    _check_robot_spheres(robot_centers, robot_radii, human)
    if pairs is not None:
        check_shape("pairs", pairs, ("P", 2))
        if pairs.dtype not in (torch.int64, torch.int32) or pairs.device != robot_centers.device:
            raise ShapeError(
                f"expected pairs int64 or int32 on {robot_centers.device}, got {pairs.dtype} on "
                f"{pairs.device}"
            )
    if entries is not None:
        if pairs is None:
            raise ShapeError("expected pairs with the entries (they index the pairs), got None")
        check_shape("entries", entries, ("K", 3))
        if entries.dtype != torch.int64 or entries.device != robot_centers.device:
            raise ShapeError(
                f"expected entries int64 on {robot_centers.device}, got {entries.dtype} on "
                f"{entries.device}"
            )
    b, w = robot_centers.shape[:2]
    s_r, s_h = robot_radii.shape[0], human.radii.shape[0]
    summed = reduce == "sum"
    # what the pairs and entries left out can add to a sum (nothing is left out without pairs)
    slack = 0.0 if pairs is None or not summed else s_r * s_h * PRUNED_PAIR_BOUND
    if pairs is None:
        ii, jj = torch.meshgrid(
            torch.arange(s_r, device=robot_centers.device),
            torch.arange(s_h, device=robot_centers.device),
            indexing="ij",
        )
        pairs = torch.stack([ii.reshape(-1), jj.reshape(-1)], dim=-1)
    if pairs.shape[0] == 0 or (entries is not None and entries.shape[0] == 0):
        zero = robot_centers.sum() * 0.0
        floor = min(human.residual + slack, 1.0)
        return robot_centers.new_zeros(b, w) + zero + floor, robot_centers.new_zeros(b) + zero
    ri = pairs[:, 0]
    weights = human.weights
    need_grad = torch.is_grad_enabled() and robot_centers.requires_grad
    # a sum depends on every pair: with a gradient, all are evaluated with autograd at once
    with torch.set_grad_enabled(torch.is_grad_enabled() and not (need_grad and not summed)):
        if entries is None:
            mean_p, var_p, inv_s_p, rad_p = human.pair_tensors(pairs, robot_radii)
            bound, dist = _pair_bounds(
                robot_centers[:, :, ri], mean_p.unsqueeze(0), var_p, inv_s_p, rad_p, exact
            )  # (B, W_x, P, A)
            if summed or not need_grad:
                pen = torch.relu(rad_p - dist).square()  # (B, W_x, P, A)
                pen_cost = (pen @ weights).sum(dim=(1, 2))
            if summed:
                mixed = (bound @ weights).sum(-1) + (human.residual + slack)  # (B, W_x)
                return mixed.clamp(max=1.0), pen_cost
            mixed = bound @ weights + human.residual  # (B, W_x, P)
            if not need_grad:
                return mixed.amax(-1).clamp(max=1.0), pen_cost
            touch = _any_leading(dist < rad_p, 2).any(-1)  # (P,)
            touching = torch.nonzero(touch).squeeze(-1)  # (Q,)
        else:
            mean_k, var_k, inv_s_k, rad_k, w_k, wp_k, wr_k, p_k, kept, mean_planes = (
                human.entry_tensors(pairs, entries, robot_radii)
            )
            planes = _entry_planes(robot_centers, wr_k)  # (3, B, K)
            c_k = planes.permute(1, 2, 0)  # (B, K, 3), a view
            # without a gradient, only the entries the maximum can depend on are refined
            lazy = exact and not need_grad and not summed
            bound_k, dist_k = _pair_bounds(
                c_k, mean_k, var_k, inv_s_k, rad_k, exact and not lazy, (planes, mean_planes)
            )
            shape = (b, w, pairs.shape[0])
            if lazy:
                mixed = _mixture_refined_at_the_max(
                    bound_k, c_k, mean_k, var_k, rad_k, w_k, wp_k, shape
                )
            else:
                mixed = _entry_mixture(bound_k, w_k, wp_k, shape)
            dist_k, rad_1 = dist_k[..., 0], rad_k[:, 0]  # (B, K), (K,)
            if summed or not need_grad:
                pen_cost = (torch.relu(rad_1 - dist_k).square() * w_k).sum(-1)
            if summed:
                mixed = mixed.sum(-1) + (human.residual + slack)  # (B, W_x)
                return mixed.clamp(max=1.0), pen_cost
            mixed = mixed + human.residual  # (B, W_x, P)
            if not need_grad:
                return mixed.amax(-1).clamp(max=1.0), pen_cost
            touching = torch.unique(p_k[_any_leading(dist_k < rad_1, 1)])  # (Q,)
        top = mixed.argmax(-1)  # (B, W_x) index into the pairs
    mean_p, var_p, inv_s_p, rad_p = human.pair_tensors(pairs, robot_radii)  # cached
    # the maximising pair of each waypoint, again with autograd
    w_idx = torch.arange(w, device=robot_centers.device).unsqueeze(0)  # (1, W_x)
    c_top = robot_centers[torch.arange(b, device=ri.device)[:, None], w_idx, ri[top]]
    bound_top, _ = _pair_bounds(
        c_top, mean_p[w_idx, top], var_p[w_idx, top], inv_s_p[w_idx, top], rad_p[top], exact
    )  # (B, W_x, A)
    # the same entries as above: their weights, 0 for the ones left out
    top_weights = weights if entries is None else kept[w_idx, top] * weights  # (B, W_x, A)
    mixed_top = (bound_top * top_weights).sum(-1) + human.residual  # (B, W_x)
    # the penetrating pairs, again with autograd
    d_q = mean_p[:, touching].unsqueeze(0) - robot_centers[:, :, ri[touching]].unsqueeze(-2)
    pen_q = torch.relu(rad_p[touching] - d_q.norm(dim=-1)).square()  # (B, W_x, Q, A)
    pen_cost = (pen_q * weights).sum(dim=(1, 2, 3))
    return mixed_top.clamp(max=1.0), pen_cost


class SphereMap(Protocol):
    """Joint Gaussians to sphere Gaussians (as
    :class:`~iplanner_torch.collision.human_spheres.HumanSphereMap`)."""

    radii: torch.Tensor

    def centers_diag(
        self, mean: torch.Tensor, var: torch.Tensor, *, validate: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(..., K, 3), (..., K, 3) -> (..., S_h, 3), (..., S_h, 3); ``validate=False`` skips
        the finiteness tests (the forecast passed them)."""
        ...


def forecast_to_obstacle(
    forecast: Forecast,
    times: torch.Tensor,
    forecast_t0: float,
    spheres: SphereMap,
    index: int = 0,
    *,
    validate: bool = True,
) -> HumanObstacle:
    """The forecast's human spheres at given times (linear interpolation between frames).

    Frame ``f`` of the forecast lies at ``forecast_t0 + (f + 1) dt``; earlier times take the
    first frame and later times the last (the prediction does not extend further). That hold
    is not conservative: past the horizon the person stays where the last frame puts them and
    the spread stops growing. ``forecast_t0`` is the last tracker frame, at or before the
    plan's start, so the end of a 1 s execution window of a 1 s forecast, and the checks past
    it (``ReplannerCfg.emergency_ahead_s``, ``OptimizerCfg.check_ahead_s``), can fall there.

    Args:
        forecast: the predictor's output; batch entry ``index`` is used.
        times: (W_x,) absolute query times [s], of a floating dtype (the obstacle's); +-inf
            takes the last or the first frame.
        forecast_t0: time of the last observed frame the forecast starts from [s], finite.
        spheres: the joint-to-sphere map.
        index: batch entry of the forecast, in [0, B).
        validate: test ``times`` for NaN (one host synchronisation); False skips that (the
            optimiser's times are finite by construction).

    Returns:
        The Gaussian human spheres at ``times`` on the device/dtype of ``times``.

    Raises:
        ShapeError: when ``forecast`` is not a :class:`Forecast` or has no frame (n_f = 0:
            nothing to place the person at), or ``times`` is not a (W_x,) tensor of a
            floating dtype (integer times would round the forecast to integers).
        ConfigError: when ``forecast_t0`` is not a finite number, or ``index`` not an integer
            in [0, B).
        DataError: (``validate``) when ``times`` holds NaN (it selects no frame).
    """
    if not isinstance(forecast, Forecast):
        raise ShapeError(f"expected forecast a Forecast, got {type(forecast).__name__}")
    if forecast.horizon < 1:
        raise ShapeError("expected a forecast with at least one frame (n_f >= 1), got n_f = 0")
    check_shape("times", times, ("W_x",))
    if not times.is_floating_point():
        raise ShapeError(f"expected times of a floating dtype, got {times.dtype}")
    finite_time("forecast_t0", forecast_t0)
    n_b = forecast.weights.shape[0]
    integer("forecast index", index)
    if not 0 <= index < n_b:
        raise ConfigError(f"expected forecast index in [0, {n_b}), got {index}")
    if validate:
        nan = torch.isnan(times)
        if bool(nan.any()):
            first = int(nan.nonzero()[0, 0])
            raise DataError(f"times is NaN at index {first}: a NaN time selects no frame")
    dev, dt_ = times.device, times.dtype
    mean = forecast.mean[index].to(device=dev, dtype=dt_).transpose(0, 1)  # (n_f, A, K, 3)
    var = forecast.var[index].to(device=dev, dtype=dt_).transpose(0, 1)  # (n_f, A, K, 3)
    n_f = mean.shape[0]
    u = ((times - forecast_t0) / forecast.dt - 1.0).clamp(0.0, n_f - 1.0)  # (W_x,)
    lo = u.floor().long().clamp(max=n_f - 1)
    hi = (lo + 1).clamp(max=n_f - 1)
    a = (u - lo.to(dt_)).view(-1, 1, 1, 1)
    m = (1.0 - a) * mean[lo] + a * mean[hi]  # (W_x, A, K, 3)
    v = (1.0 - a) * var[lo] + a * var[hi]
    s_mean, s_var = spheres.centers_diag(m, v, validate=False)  # Forecast checked finite
    weights = forecast.weights[index].to(device=dev, dtype=dt_)
    radii = spheres.radii.to(device=dev, dtype=dt_)
    return HumanObstacle(mean=s_mean, var=s_var.clamp_min(1e-10), radii=radii, weights=weights)
