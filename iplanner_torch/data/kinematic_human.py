"""A kinematic seated human: body sizes, a leaning trunk and two 2-link arms solved by IK.

Frame (see :mod:`iplanner_torch.data.skeleton`): the table frame, x from the human towards the
robot across the table, y to the human's left, z up, table top at z = 0. The human sits at about
``x = -0.45`` facing +x with the waist just below the table top and the shoulders about 0.4 m
above it.

Motion is described by a :class:`MotionPlan`: a list of hand moves (:class:`HandMove`), each a
minimum-jerk (bell-shaped speed) traversal of a quadratic Bezier path through a via point, with
the trunk pitch / yaw and the elbow swivel blending to new values with the same time profile.
:meth:`MotionPlan.positions` evaluates the plan at any array of times, fully vectorised, so a
speed variant is the same plan sampled on a scaled time grid. Bone lengths are constant by
construction: the trunk is rigid, and the elbow lies on the circle of points at the upper-arm
length from the shoulder and the forearm length from the hand.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from iplanner_torch.data.skeleton import JOINT_INDEX, K_UPPER_BODY
from iplanner_torch.errors import ConfigError

Arm = Literal["left", "right"]
_SIDE = {"left": 1.0, "right": -1.0}


@dataclass(frozen=True, kw_only=True)
class BodyParams:
    """Sizes and seating of one person (constant within a demonstration).

    Lengths are metres, angles radians; positions are in the table frame.
    """

    scale: float = 1.0  # overall body size relative to the reference adult (height ~1.75 m)
    seat_x: float = -0.45  # x of the waist (hip centre) [m]
    seat_y: float = 0.0  # y of the waist [m]
    waist_z: float = -0.12  # z of the waist; the table top is z = 0 [m]
    waist_torso: float = 0.25  # waist -> torso (mid spine) length [m]
    torso_neck: float = 0.30  # torso -> neck length [m]
    neck_head: float = 0.20  # neck -> head centre length [m]
    shoulder_half_width: float = 0.18  # lateral neck -> shoulder offset [m]
    shoulder_drop: float = 0.03  # vertical neck -> shoulder offset (shoulders lower) [m]
    upper_arm: float = 0.30  # shoulder -> elbow length [m]
    forearm: float = 0.28  # elbow -> hand (palm centre) length [m]
    rest_hand_forward: float = 0.25  # x of the resting hands in front of the waist [m]
    rest_hand_lateral: float = 0.17  # |y| of the resting hands from the waist [m]
    rest_hand_z: float = 0.04  # z of the resting hands (on the table) [m]
    swivel_rest: float = 0.35  # elbow swivel at rest, outwards from "elbow down" [rad]

    def __post_init__(self) -> None:
        lengths = {
            "scale": self.scale,
            "waist_torso": self.waist_torso,
            "torso_neck": self.torso_neck,
            "neck_head": self.neck_head,
            "shoulder_half_width": self.shoulder_half_width,
            "upper_arm": self.upper_arm,
            "forearm": self.forearm,
            "rest_hand_lateral": self.rest_hand_lateral,
        }
        for name, value in lengths.items():
            if not value > 0.0:
                raise ConfigError(f"BodyParams.{name} must be > 0, got {value}")
        if not 0.0 <= self.swivel_rest <= np.pi / 2:
            raise ConfigError(
                f"BodyParams.swivel_rest must be in [0, pi/2], got {self.swivel_rest}"
            )

    @property
    def arm_length(self) -> float:
        """Upper arm plus forearm [m]."""
        return self.upper_arm + self.forearm

    @property
    def waist(self) -> np.ndarray:
        """(3,) waist position [m]."""
        return np.array([self.seat_x, self.seat_y, self.waist_z])

    def rest_hand(self, arm: Arm) -> np.ndarray:
        """(3,) resting hand position of ``arm`` [m] (on the table near its edge)."""
        return np.array(
            [
                self.seat_x + self.rest_hand_forward,
                self.seat_y + _SIDE[arm] * self.rest_hand_lateral,
                self.rest_hand_z,
            ]
        )

    def trunk_offsets(self) -> np.ndarray:
        """(6, 3) head, neck, torso, waist, left shoulder, right shoulder relative to the waist,
        upright [m]."""
        neck = np.array([0.0, 0.0, self.waist_torso + self.torso_neck])
        return np.stack(
            [
                neck + np.array([0.02 * self.scale, 0.0, self.neck_head]),
                neck,
                np.array([0.0, 0.0, self.waist_torso]),
                np.zeros(3),
                neck + np.array([0.0, self.shoulder_half_width, -self.shoulder_drop]),
                neck + np.array([0.0, -self.shoulder_half_width, -self.shoulder_drop]),
            ]
        )


def sample_body(rng: np.random.Generator) -> BodyParams:
    """A random adult: overall size about N(1, 0.06) (clipped to 0.88..1.12), each segment
    varied a further 3 %, the seat moved by up to 3 cm, the resting hands and elbow swivel
    varied.

    Args:
        rng: the random generator (same state -> same body).
    """
    scale = float(np.clip(rng.normal(1.0, 0.06), 0.88, 1.12))

    def seg(ref: float) -> float:
        return float(ref * scale * (1.0 + 0.03 * np.clip(rng.standard_normal(), -2.0, 2.0)))

    return BodyParams(
        scale=scale,
        seat_x=float(-0.45 + rng.uniform(-0.03, 0.03)),
        seat_y=float(rng.uniform(-0.03, 0.03)),
        waist_z=float(rng.uniform(-0.16, -0.08)),
        waist_torso=seg(0.25),
        torso_neck=seg(0.30),
        neck_head=seg(0.20),
        shoulder_half_width=seg(0.18),
        shoulder_drop=seg(0.03),
        upper_arm=seg(0.30),
        forearm=seg(0.28),
        rest_hand_forward=float(rng.uniform(0.21, 0.28)),
        rest_hand_lateral=float(rng.uniform(0.14, 0.20) * scale),
        rest_hand_z=float(rng.uniform(0.03, 0.05)),
        swivel_rest=float(rng.uniform(0.2, 0.5)),
    )


def min_jerk(u: np.ndarray) -> np.ndarray:
    """Minimum-jerk progress ``10u^3 - 15u^4 + 6u^5`` of normalised time ``u`` (clipped to
    [0, 1]); its derivative is the bell-shaped speed profile of human reaching (Flash and
    Hogan 1985)."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u))


def _rotation(pitch: np.ndarray, yaw: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotation Rz(yaw) Ry(pitch) Rx(roll); positive pitch leans forward (+x)."""
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    cr, sr = np.cos(roll), np.sin(roll)
    r = np.empty(pitch.shape + (3, 3))
    r[..., 0, 0] = cy * cp
    r[..., 0, 1] = cy * sp * sr - sy * cr
    r[..., 0, 2] = cy * sp * cr + sy * sr
    r[..., 1, 0] = sy * cp
    r[..., 1, 1] = sy * sp * sr + cy * cr
    r[..., 1, 2] = sy * sp * cr - cy * sr
    r[..., 2, 0] = -sp
    r[..., 2, 1] = cp * sr
    r[..., 2, 2] = cp * cr
    return r


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def solve_elbow(
    shoulder: np.ndarray,
    hand: np.ndarray,
    upper: float,
    fore: float,
    swivel: np.ndarray,
    side: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Two-link arm IK with a swivel angle.

    The elbow lies on the circle of points at ``upper`` from the shoulder and ``fore`` from the
    hand; ``swivel`` rotates it about the shoulder-hand axis from "elbow down" towards the
    body's outside. A hand out of reach is pulled back along the shoulder-hand line.

    Args:
        shoulder: (T, 3) shoulder positions [m].
        hand: (T, 3) desired hand positions [m].
        upper: shoulder-elbow length [m].
        fore: elbow-hand length [m].
        swivel: (T,) swivel angle [rad].
        side: +1 for the left arm, -1 for the right arm.

    Returns:
        (elbow (T, 3), hand (T, 3)) positions [m]; the hand equals the input where reachable.
    """
    d_vec = hand - shoulder
    d = np.linalg.norm(d_vec, axis=-1, keepdims=True)
    u = d_vec / np.maximum(d, 1e-12)
    d_c = np.clip(d, abs(upper - fore) + 1e-4, (upper + fore) * (1.0 - 1e-6))
    hand = shoulder + u * d_c
    a = (d_c * d_c + upper * upper - fore * fore) / (2.0 * d_c)  # along the axis from shoulder
    r = np.sqrt(np.maximum(upper * upper - a * a, 0.0))
    # "elbow down": the relaxed elbow points down and back; project that on the circle's plane
    down = np.array([-0.6, 0.0, -0.8])
    e0 = down - np.sum(down * u, axis=-1, keepdims=True) * u
    e0 = np.where(np.linalg.norm(e0, axis=-1, keepdims=True) < 1e-6, np.array([0, 0, -1.0]), e0)
    e0 = _unit(e0)
    out = np.array([0.0, side, 0.0])
    e1 = out - np.sum(out * u, axis=-1, keepdims=True) * u
    e1 = _unit(e1 - np.sum(e1 * e0, axis=-1, keepdims=True) * e0)
    sw = swivel[:, None]
    elbow = shoulder + a * u + r * (np.cos(sw) * e0 + np.sin(sw) * e1)
    return elbow, hand


@dataclass(kw_only=True)
class HandMove:
    """One minimum-jerk hand move, with the trunk and elbow blending along with it.

    Attributes:
        arm: which hand moves.
        t0: start time [s].
        duration: seconds from rest to rest.
        p0: (3,) start position [m] (the hand's position when the move starts).
        p1: (3,) end position [m].
        via: (3,) offset of the Bezier control point from the chord's midpoint [m]; the path
            passes ``via / 2`` away from the midpoint.
        pitch: trunk pitch at the end of the move [rad] (forward lean).
        yaw: trunk yaw at the end of the move [rad].
        swivel: the moving arm's elbow swivel at the end of the move [rad].
    """

    arm: Arm
    t0: float
    duration: float
    p0: np.ndarray
    p1: np.ndarray
    via: np.ndarray
    pitch: float
    yaw: float
    swivel: float

    @property
    def t1(self) -> float:
        """End time [s]."""
        return self.t0 + self.duration


@dataclass(kw_only=True)
class MotionPlan:
    """A body plus a sequence of hand moves and a slow trunk sway; evaluate with
    :meth:`positions`.

    Attributes:
        body: the person.
        moves: hand moves in start-time order (moves of one arm must not overlap).
        sway_amp: (2,) amplitudes of the pitch and roll sway [rad].
        sway_freq: (2,) their frequencies [Hz].
        sway_phase: (2,) their phases [rad].
        start_hands: optional start positions of the hands [m] by arm, replacing the body's
            resting hands.
    """

    body: BodyParams
    moves: list[HandMove] = field(default_factory=list)
    start_hands: dict[str, np.ndarray] | None = None
    sway_amp: np.ndarray = field(default_factory=lambda: np.zeros(2))
    sway_freq: np.ndarray = field(default_factory=lambda: np.full(2, 0.3))
    sway_phase: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def state_at_end(self) -> tuple[dict[str, np.ndarray], float, float, dict[str, float]]:
        """(hands, pitch, yaw, swivels) after the last move: the start of the next one."""
        hands = {a: self._start_hand(a) for a in ("left", "right")}
        swivel = {a: self.body.swivel_rest for a in ("left", "right")}
        pitch = yaw = 0.0
        for m in self.moves:
            hands[m.arm] = np.asarray(m.p1, dtype=np.float64)
            swivel[m.arm] = m.swivel
            pitch, yaw = m.pitch, m.yaw
        return hands, pitch, yaw, swivel

    def _start_hand(self, arm: Arm) -> np.ndarray:
        if self.start_hands is not None and arm in self.start_hands:
            return np.asarray(self.start_hands[arm], dtype=np.float64)
        return self.body.rest_hand(arm)

    @property
    def end_time(self) -> float:
        """End of the last move [s] (0 when there is none)."""
        return max((m.t1 for m in self.moves), default=0.0)

    def positions(self, times: np.ndarray) -> np.ndarray:
        """Joint positions at ``times``.

        Args:
            times: (T,) seconds.

        Returns:
            (T, K, 3) positions [m] of the 10 upper-body joints, float64.
        """
        t = np.asarray(times, dtype=np.float64)
        b = self.body
        hands = {a: np.broadcast_to(self._start_hand(a), t.shape + (3,)).copy() for a in _SIDE}
        swivel = {a: np.full(t.shape, b.swivel_rest) for a in _SIDE}
        pitch = np.zeros(t.shape)
        yaw = np.zeros(t.shape)
        pitch_by = {a: np.zeros(t.shape) for a in _SIDE}  # lean caused by each arm's moves
        prev_pitch = prev_yaw = 0.0
        prev_swivel = {a: b.swivel_rest for a in _SIDE}
        for m in self.moves:
            s = min_jerk((t - m.t0) / m.duration)[:, None]  # (T, 1)
            mid = 0.5 * (m.p0 + m.p1)
            ctrl = mid + m.via
            bez = (1 - s) ** 2 * m.p0 + 2 * s * (1 - s) * ctrl + s**2 * m.p1  # (T, 3)
            hands[m.arm] += bez - m.p0
            pitch += (m.pitch - prev_pitch) * s[:, 0]
            pitch_by[m.arm] += (m.pitch - prev_pitch) * s[:, 0]
            yaw += (m.yaw - prev_yaw) * s[:, 0]
            swivel[m.arm] += (m.swivel - prev_swivel[m.arm]) * s[:, 0]
            prev_pitch, prev_yaw, prev_swivel[m.arm] = m.pitch, m.yaw, m.swivel
        sway = self.sway_amp[:, None] * np.sin(
            2 * np.pi * self.sway_freq[:, None] * t[None] + self.sway_phase[:, None]
        )  # (2, T)
        rot = _rotation(pitch + sway[0], yaw, sway[1])  # (T, 3, 3)
        trunk = b.waist + np.einsum("tij,kj->tki", rot, b.trunk_offsets())  # (T, 6, 3)
        out = np.empty(t.shape + (K_UPPER_BODY, 3))
        for k, name in enumerate(
            ("head", "neck", "torso", "waist", "left_shoulder", "right_shoulder")
        ):
            out[:, JOINT_INDEX[name]] = trunk[:, k]
        upright = b.waist + np.einsum(
            "tij,kj->tki", _rotation(sway[0], np.zeros(t.shape), sway[1]), b.trunk_offsets()[4:]
        )  # (T, 2, 3) shoulders without the lean
        for ai, arm in enumerate(("left", "right")):
            shoulder = out[:, JOINT_INDEX[f"{arm}_shoulder"]]
            # a resting hand slides along the table with the trunk when the other arm leans it
            other = "right" if arm == "left" else "left"
            frac = np.clip(pitch_by[other] / np.maximum(np.abs(pitch), 1e-6), 0.0, 1.0)
            slide = shoulder - upright[:, ai]
            slide[:, 2] = 0.0
            hands[arm] = hands[arm] + 0.6 * frac[:, None] * slide
            elbow, hand = solve_elbow(
                shoulder, hands[arm], b.upper_arm, b.forearm, swivel[arm], _SIDE[arm]
            )
            out[:, JOINT_INDEX[f"{arm}_elbow"]] = elbow
            out[:, JOINT_INDEX[f"{arm}_hand"]] = hand
        return out


def lean_for_target(
    body: BodyParams,
    arm: Arm,
    target: np.ndarray,
    yaw: float,
    *,
    reach_fraction: float = 0.95,
    max_pitch: float = 0.6,
) -> float:
    """The smallest forward trunk pitch that brings ``target`` within ``reach_fraction`` of the
    arm's length from the shoulder (``max_pitch`` when even that is not enough).

    Args:
        body: the person.
        arm: the reaching arm.
        target: (3,) hand target [m].
        yaw: trunk yaw at the target [rad].
        reach_fraction: how stretched the arm may be at the target (1 = straight).
        max_pitch: the largest forward lean considered [rad].
    """
    grid = np.linspace(0.0, max_pitch, 141)
    rot = _rotation(grid, np.full_like(grid, yaw), np.zeros_like(grid))  # (G, 3, 3)
    k = 4 if arm == "left" else 5
    shoulder = body.waist + rot @ body.trunk_offsets()[k]  # (G, 3)
    ok = np.linalg.norm(target - shoulder, axis=-1) <= reach_fraction * body.arm_length
    return float(grid[np.argmax(ok)]) if ok.any() else float(max_pitch)


def plan_hand_move(
    plan: MotionPlan,
    arm: Arm,
    target: np.ndarray,
    t0: float,
    rng: np.random.Generator,
    *,
    lean: bool,
    duration: float | None = None,
    lift: tuple[float, float] = (0.03, 0.08),
) -> HandMove:
    """Append a natural hand move of ``arm`` to ``target`` starting at ``t0`` to ``plan``.

    The duration follows the distance (about 0.55 s + 1.1 s/m, varied 12 % log-normally) unless
    given; the path arcs up by ``lift`` (uniform range, metres) and sideways by up to 3 cm
    (capped at 35 % of the distance so the speed profile stays single-peaked). With ``lean``
    the trunk pitches forward as far as the target needs (plus a little) and twists the
    reaching shoulder forward; without it the trunk returns upright.

    Returns:
        The appended move.
    """
    hands, _, _, _ = plan.state_at_end()
    p0 = hands[arm]
    p1 = np.asarray(target, dtype=np.float64)
    chord = p1 - p0
    dist = float(np.linalg.norm(chord))
    if duration is None:
        duration = (0.55 + 1.1 * dist) * float(
            np.exp(0.12 * np.clip(rng.standard_normal(), -2, 2))
        )
    horiz = np.array([-chord[1], chord[0], 0.0])
    horiz = horiz / max(np.linalg.norm(horiz), 1e-9)
    via = np.array([0.0, 0.0, 1.0]) * rng.uniform(*lift) + horiz * rng.uniform(-0.03, 0.03)
    via = 2.0 * via  # the quadratic Bezier passes half-way to its control point
    cap = 0.35 * dist
    if np.linalg.norm(via) > cap:
        via = via * cap / np.linalg.norm(via)
    if lean:
        yaw = -_SIDE[arm] * rng.uniform(0.05, 0.18)
        pitch = lean_for_target(plan.body, arm, p1, yaw) + rng.uniform(0.0, 0.1)
        swivel = plan.body.swivel_rest + rng.uniform(0.0, 0.3)
    else:
        yaw = pitch = 0.0
        swivel = plan.body.swivel_rest + rng.uniform(-0.05, 0.05)
    move = HandMove(
        arm=arm,
        t0=float(t0),
        duration=float(duration),
        p0=p0,
        p1=p1,
        via=via,
        pitch=float(pitch),
        yaw=float(yaw),
        swivel=float(np.clip(swivel, 0.0, np.pi / 2)),
    )
    plan.moves.append(move)
    return move


def random_sway(plan: MotionPlan, rng: np.random.Generator, amplitude: float = 0.02) -> None:
    """Give ``plan`` a slow random trunk sway (pitch and roll, up to ``amplitude`` rad,
    0.15-0.45 Hz)."""
    plan.sway_amp = rng.uniform(0.3, 1.0, size=2) * amplitude
    plan.sway_freq = rng.uniform(0.15, 0.45, size=2)
    plan.sway_phase = rng.uniform(0, 2 * np.pi, size=2)


def rest_pose(body: BodyParams) -> np.ndarray:
    """(K, 3) joint positions [m] of ``body`` sitting upright with both hands resting on the
    table."""
    return MotionPlan(body=body).positions(np.zeros(1))[0]


def arm_for_target(body: BodyParams, target: np.ndarray) -> Arm:
    """The arm a person uses for ``target``: left when it lies on their left (y >= seat y)."""
    return "left" if float(target[1]) >= body.seat_y else "right"
