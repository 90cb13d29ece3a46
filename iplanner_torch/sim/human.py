"""A scripted, kinematic human for the closed loop (paper sec. 7).

The human sits at the table with a personal task order (sampled from the scenario's
:class:`TaskOrder`, uniformly over the orders it allows). It waits until the robot has
delivered a block it may take next, idles for a random while, then performs ``Take_i``: a
reaching motion to the block, a hold, and the return with the block in its hand. By default
(``HumanCfg.flexible_order``) it takes any delivered block that the task order allows next,
preferring its personal order: the paper's ``(0, 1) -> (2, 3)`` means 0 and 1 "can be
performed in any order", and its person "waits till the robot delivers the object". With
``flexible_order=False`` it waits for exactly the next block of its personal order, even while
another allowed block lies there (a person with a fixed private plan: the robot can only guess
it, so every planner loses time; see ``experiments/safety_seeds/``). Motions come from the
synthetic reaching generator (:mod:`iplanner_torch.data.reaching`) with a seed stream that the
training set never uses (``numpy.random.default_rng([seed, HUMAN_SEED_SALT])``), so the
predictor is evaluated on motions it was not trained on.

Progress state for the predictor (paper sec. 4: p, the set of completed actions): the
completed ``Take_i`` map to the predictor's action set by name: ``Take_i`` is the predictor
action named ``take_<i>`` or else ``reach_<i>`` (case-insensitive; delivery spot ``i`` is
reaching target ``i``, see :mod:`iplanner_torch.sim.scene`); when no name matches, action
index ``i`` is used if it exists, else the action is left out of the bitmask. See
:meth:`ScriptedHuman.progress_bitmask`.

"blocking" mode (fig. speed_response): at ``blocking_start_s`` the human moves one arm to
``blocking_target`` (into the robot's path), holds it ``blocking_hold_s`` and returns.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from iplanner_torch import checks
from iplanner_torch.data.kinematic_human import min_jerk
from iplanner_torch.data.skeleton import JOINT_INDEX
from iplanner_torch.errors import ConfigError, DataError, ShapeError

Speed = Literal["slow", "medium", "fast"]
Arm = Literal["left", "right"]

#: Added to every episode seed for the human's motions (keeps them out of the training seeds).
HUMAN_SEED_SALT = 7919
#: Seconds over which a motion's first frames are blended from the pose the person holds.
START_BLEND_S = 0.3
#: The least update period :meth:`ScriptedHuman.preview` steps its copy with [s] (far below
#: any control period; the copy is stepped through every motion in the span).
MIN_PREVIEW_STEP_S = 1e-4
#: Speed factor of each named human speed (1 = the generator's nominal speed).
SPEED_FACTORS: dict[str, float] = {"slow": 0.5, "medium": 1.0, "fast": 2.0}


class TaskOrderLike(Protocol):
    """A task order (``(0,1)->(2,3)``, ``random`` ...): the parser's ``TaskOrder``."""

    def sample(self, rng: np.random.Generator) -> list[int]:
        """One admissible sequence of task ids."""
        ...

    def allowed_next(self, done: set[int]) -> set[int]:
        """Task ids that may be performed next once ``done`` are complete."""
        ...


class MotionSource(Protocol):
    """Where the human's reaching motions come from."""

    fps: float

    def rest_pose(self) -> np.ndarray:
        """(K, 3) seated rest pose [m]."""
        ...

    def reach(
        self,
        arm: Arm,
        target: np.ndarray,
        rng: np.random.Generator,
        *,
        speed: float,
        hold_s: float,
        start_pose: np.ndarray,
    ) -> np.ndarray:
        """(T, K, 3) joint positions [m] at ``fps``: reach ``target`` (3,), hold, return.

        The first frame should be ``start_pose``; the person blends what it differs by away
        over :data:`START_BLEND_S`."""
        ...


class ReachingMotionSource:
    """:class:`MotionSource` backed by :mod:`iplanner_torch.data.reaching` (one sampled body).

    Args:
        seed: seed of the body sample (the body is fixed for an episode), >= 0.
        fps: frame rate of the generated motions [Hz].
        seat_x: where the body's torso is placed along x [m]; ``None`` keeps the generator's.

    Raises:
        ConfigError: for a negative seed, or a non-finite or non-positive ``fps`` or
            non-finite ``seat_x``.
    """

    def __init__(self, seed: int, *, fps: float = 30.0, seat_x: float | None = None) -> None:
        from iplanner_torch.data import reaching

        checks.seed(seed)
        checks.positive("fps", fps)
        if seat_x is not None:
            checks.finite("seat_x", seat_x)
        self._reaching = reaching
        self.fps = float(fps)
        self.body = reaching.sample_body(np.random.default_rng([seed, HUMAN_SEED_SALT, 1]))
        self._rest = np.asarray(reaching.rest_pose(self.body), dtype=np.float64)
        if seat_x is not None:
            self._rest = self._rest.copy()
            self._rest[:, 0] += seat_x - self._rest[JOINT_INDEX["torso"], 0]

    def rest_pose(self) -> np.ndarray:
        """(K, 3) seated rest pose [m]."""
        return self._rest.copy()

    def reach(
        self,
        arm: Arm,
        target: np.ndarray,
        rng: np.random.Generator,
        *,
        speed: float,
        hold_s: float,
        start_pose: np.ndarray,
    ) -> np.ndarray:
        """(T, K, 3) reach to ``target``, hold ``hold_s`` and return [m]."""
        positions, _ = self._reaching.reach_motion(
            self.body,
            arm,
            np.asarray(target, dtype=np.float64),
            rng,
            fps=self.fps,
            speed=speed,
            hold_s=hold_s,
            start_pose=start_pose,
        )
        return np.asarray(positions, dtype=np.float64)


@dataclass(frozen=True, kw_only=True)
class HumanCfg:
    """Behaviour of the scripted human."""

    # "tasks": wait for deliveries and take blocks; "blocking": one arm motion into the path
    mode: Literal["tasks", "blocking"] = "tasks"
    # named motion speed (factor in SPEED_FACTORS)
    speed: Speed = "medium"
    # seconds the hand holds still at the block (or the blocking pose)
    hold_s: float = 0.4
    # idle time before each Take_i is drawn uniformly from this range [s]
    idle_s: tuple[float, float] = (0.3, 1.0)
    # reaction time [s]: Take_i starts no earlier than this after block i landed on its spot
    # (people do not grab the instant an object lands: seeing it placed and the gripper
    # open is a choice reaction, about 0.3-0.5 s)
    reaction_s: float = 0.4
    # True: take the first delivered block of the personal order that the task order allows
    # next (the paper's "any order" within parentheses); False: wait for exactly the next
    # block of the personal order, even while another allowed block lies there
    flexible_order: bool = True
    # blocking mode: start time of the motion [s]
    blocking_start_s: float = 0.5
    # blocking mode: where the hand goes, table frame [m]
    blocking_target: tuple[float, float, float] = (0.1, 0.0, 0.25)
    # blocking mode: which arm moves
    blocking_arm: Arm = "right"
    # blocking mode: how long the arm stays in the path [s]
    blocking_hold_s: float = 1.5

    def __post_init__(self) -> None:
        if self.speed not in SPEED_FACTORS:
            raise ConfigError(f"expected speed in {sorted(SPEED_FACTORS)}, got {self.speed!r}")
        if self.mode not in ("tasks", "blocking"):
            raise ConfigError(f"expected mode 'tasks' or 'blocking', got {self.mode!r}")
        for name in ("hold_s", "reaction_s", "blocking_start_s", "blocking_hold_s"):
            checks.non_negative(name, getattr(self, name))
        lo, hi = checks.finite_tuple("idle_s", self.idle_s, 2)
        if not 0.0 <= lo <= hi:
            raise ConfigError(f"expected 0 <= idle_s[0] <= idle_s[1], got {self.idle_s!r}")
        checks.flag("flexible_order", self.flexible_order)
        checks.finite_tuple("blocking_target", self.blocking_target, 3)
        if self.blocking_arm not in ("left", "right"):
            raise ConfigError(
                f"expected blocking_arm 'left' or 'right', got {self.blocking_arm!r}"
            )

    @property
    def speed_factor(self) -> float:
        """Multiplier of the generator's nominal speed."""
        return SPEED_FACTORS[self.speed]


@dataclass(frozen=True, kw_only=True)
class HumanEvent:
    """Something the human did at a simulated time.

    Attributes:
        kind: ``human_take_started``, ``human_grasped``, ``human_took`` or ``blocking_started``.
        block: the block id (-1 for blocking).
        time: simulated time [s].
    """

    kind: str
    block: int
    time: float


@dataclass(kw_only=True)
class _Motion:
    frames: np.ndarray  # (T, K, 3)
    t_start: float
    block: int  # -1 for blocking
    grasp_frame: int
    hand: int  # K index of the moving hand
    fps: float  # frame rate of ``frames`` [Hz]
    grasped: bool = False

    @property
    def t_end(self) -> float:
        return self.t_start + (self.frames.shape[0] - 1) / self.fps


def _target_point(block: object, value: object) -> np.ndarray:
    """``value`` as a (3,) float64 point; the errors name the target's ``block``."""
    try:
        point = np.asarray(value)
    except (TypeError, ValueError) as err:  # ragged nested sequences
        raise ShapeError(f"expected target {block!r} a (3,) point [m], got {value!r}") from err
    if point.shape != (3,) or point.dtype.kind not in "iuf":
        raise ShapeError(
            f"expected target {block!r} a (3,) point of real numbers [m], got shape "
            f"{point.shape} of dtype {point.dtype}"
        )
    if not np.isfinite(point).all():
        raise DataError(f"expected target {block!r} a finite point [m], got {point}")
    return point.astype(np.float64)


class ScriptedHuman:
    """The kinematic human of the closed loop.

    Args:
        cfg: behaviour.
        motion: where reaching motions come from.
        task_order: the scenario's task order (tasks mode).
        targets: block id -> (3,) grasp point of the block on its delivery spot [m].
        seed: episode seed (same seed -> same order, idles and motions), >= 0.

    Raises:
        ConfigError: without a task order in tasks mode, for a negative seed, or for a target
            whose block id is not an integer.
        ShapeError: when a target is not a (3,) point of real numbers.
        DataError: when a target holds NaN or infinity.
    """

    def __init__(
        self,
        cfg: HumanCfg,
        motion: MotionSource,
        *,
        task_order: TaskOrderLike | None,
        targets: dict[int, np.ndarray],
        seed: int,
    ) -> None:
        if cfg.mode == "tasks" and task_order is None:
            raise ConfigError("expected a task_order for a human in 'tasks' mode, got None")
        self.cfg = cfg
        self.motion = motion
        self.task_order = task_order
        self.targets = {
            checks.integer("target block id", k): _target_point(k, v) for k, v in targets.items()
        }
        self.seed = checks.seed(seed)
        self.reset()

    def reset(self) -> None:
        """Back to the rest pose at t = 0, with a fresh personal order and idle draws."""
        self._rng = np.random.default_rng([self.seed, HUMAN_SEED_SALT])
        self._rest = self.motion.rest_pose()
        self._pose = self._rest.copy()
        self.order: list[int] = (
            [int(i) for i in self.task_order.sample(self._rng)]
            if self.cfg.mode == "tasks" and self.task_order is not None
            else []
        )
        unknown = [i for i in self.order if i not in self.targets]
        if unknown:
            raise ConfigError(f"task order names blocks {unknown} absent from the scene")
        self.completed: list[int] = []
        self._landed: dict[int, float] = {}  # block id -> time it was first seen delivered
        self._motion: _Motion | None = None
        self._idle_until = self._draw_idle(0.0)
        self._blocking_done = False
        self.time = 0.0

    def _draw_idle(self, t: float) -> float:
        lo, hi = self.cfg.idle_s
        return t + float(self._rng.uniform(lo, hi))

    @property
    def done(self) -> bool:
        """Whether every task of the personal order has been completed."""
        return self.cfg.mode == "tasks" and len(self.completed) == len(self.order)

    @property
    def current_block(self) -> int:
        """Block of the ongoing ``Take_i`` (-1 when idle or blocking)."""
        return self._motion.block if self._motion is not None else -1

    @property
    def action_label(self) -> str:
        """``take_<i>``, ``block`` or ``idle``."""
        if self._motion is None:
            return "idle"
        return "block" if self._motion.block < 0 else f"take_{self._motion.block}"

    @property
    def carrying(self) -> tuple[int, int] | None:
        """(block id, hand joint index) while the hand holds a block, else None."""
        m = self._motion
        if m is None or m.block < 0 or not m.grasped:
            return None
        return m.block, m.hand

    def _next_block(self, delivered: set[int]) -> int | None:
        remaining = [i for i in self.order if i not in self.completed]
        if not remaining:
            return None
        if not self.cfg.flexible_order:
            return remaining[0] if remaining[0] in delivered else None
        allowed = self.task_order.allowed_next(set(self.completed)) if self.task_order else set()
        for i in remaining:
            if i in delivered and i in allowed:
                return i
        return None

    def _start(self, arm: Arm, target: np.ndarray, hold_s: float, block: int, t: float) -> None:
        frames = np.array(
            self.motion.reach(
                arm,
                target,
                self._rng,
                speed=self.cfg.speed_factor,
                hold_s=hold_s,
                start_pose=self._pose.copy(),
            ),
            dtype=np.float64,
        )
        if frames.ndim != 3 or frames.shape[0] < 1 or frames.shape[1:] != self._pose.shape:
            raise ShapeError(
                f"expected the motion source's reach (T, {self._pose.shape[0]}, 3), "
                f"got {frames.shape}"
            )
        if not np.isfinite(frames).all():
            raise DataError("the motion source's reach holds NaN or inf joint positions")
        # the motion starts at the pose held now: what its first frame differs by (the trunk
        # sway's phase, an elbow placed by IK) fades out over START_BLEND_S instead of a jump
        n = min(frames.shape[0], max(1, int(round(START_BLEND_S * self.motion.fps))))
        fade = 1.0 - min_jerk(np.arange(n) / n)
        frames[:n] += fade[:, None, None] * (self._pose - frames[0])
        hand = JOINT_INDEX[f"{arm}_hand"]
        dist = np.linalg.norm(frames[:, hand] - target, axis=-1)
        grasp = int(np.argmax(dist <= dist.min() + 0.005))
        self._motion = _Motion(
            frames=frames,
            t_start=t,
            block=block,
            grasp_frame=grasp,
            hand=hand,
            fps=self.motion.fps,
        )

    @staticmethod
    def arm_for(target: np.ndarray) -> Arm:
        """The arm on the target's side (y > 0 is the human's left)."""
        return "left" if float(target[1]) > 0.0 else "right"

    def update(self, t: float, delivered: set[int]) -> list[HumanEvent]:
        """Advance the script to time ``t``.

        Args:
            t: simulated time [s] (non-decreasing across calls).
            delivered: ids of the blocks lying on their delivery spots now.

        Returns:
            The events that happened since the previous call.

        Raises:
            DataError: when ``t`` is NaN, infinite, not a number or before the previous
                call's, or ``delivered`` names a block without a target (nothing changes
                then).
        """
        checks.finite_time("t", t, error=DataError)
        if t < self.time:
            raise DataError(f"expected t >= the previous update's {self.time} s, got {t}")
        unknown = [i for i in delivered if i not in self.targets]
        if unknown:
            raise DataError(
                f"delivered names blocks {sorted(unknown)} without a target "
                f"(targets: {sorted(self.targets)})"
            )
        events: list[HumanEvent] = []
        self.time = t
        for i in delivered:
            self._landed.setdefault(int(i), t)
        delivered = {
            i for i in delivered if t - self._landed[int(i)] >= self.cfg.reaction_s - 1e-9
        }
        m = self._motion
        if m is not None:
            frame = (t - m.t_start) * self.motion.fps
            if m.block >= 0 and not m.grasped and frame >= m.grasp_frame:
                m.grasped = True
                events.append(HumanEvent(kind="human_grasped", block=m.block, time=t))
            if t >= m.t_end:
                self._pose = m.frames[-1].copy()
                self._motion = None
                if m.block >= 0:
                    self.completed.append(m.block)
                    events.append(HumanEvent(kind="human_took", block=m.block, time=t))
                self._idle_until = self._draw_idle(t)
            return events
        if self.cfg.mode == "blocking":
            if not self._blocking_done and t >= self.cfg.blocking_start_s:
                self._blocking_done = True
                target = np.asarray(self.cfg.blocking_target, dtype=np.float64)
                self._start(self.cfg.blocking_arm, target, self.cfg.blocking_hold_s, -1, t)
                events.append(HumanEvent(kind="blocking_started", block=-1, time=t))
            return events
        if t < self._idle_until:
            return events
        nxt = self._next_block(delivered)
        if nxt is not None:
            target = self.targets[nxt]
            self._start(self.arm_for(target), target, self.cfg.hold_s, nxt, t)
            events.append(HumanEvent(kind="human_take_started", block=nxt, time=t))
        return events

    def joint_positions(self, t: float | None = None) -> np.ndarray:
        """(K, 3) true joint positions [m] at ``t`` (default: the last update time).

        Within the ongoing motion the frames are interpolated linearly; ``t`` must not lie
        before the motion's start (the past is not stored).

        Raises:
            DataError: when ``t`` is NaN, infinite or not a number.
        """
        if t is None:
            t = self.time
        else:
            checks.finite_time("t", t, error=DataError)
        m = self._motion
        if m is None:
            return self._pose.copy()
        f = float(np.clip((t - m.t_start) * self.motion.fps, 0.0, m.frames.shape[0] - 1))
        i = int(np.floor(f))
        j = min(i + 1, m.frames.shape[0] - 1)
        w = f - i
        return (1.0 - w) * m.frames[i] + w * m.frames[j]

    def preview(self, times: np.ndarray, delivered: set[int], step_s: float) -> np.ndarray:
        """The true future: joint positions at ``times`` if the delivered set stays as it is.

        A copy of the script (its random stream included) is advanced with :meth:`update`
        every ``step_s`` from :attr:`time`, as the simulation does, so a reach that starts
        within the span is the one the person will make; this human is left unchanged. Only
        deliveries after now can make the preview differ from what happens (and rounding: the
        copy's clock adds ``step_s`` up, so where a motion ends exactly on a step the two may
        differ by that one step). The copy stops stepping once nothing can happen any more
        (see :meth:`_settled`), so far-off times cost no more than near ones.

        Args:
            times: (n,) increasing finite times [s], none before :attr:`time`.
            delivered: ids of the blocks lying on their delivery spots now.
            step_s: the simulation's update period [s] (its control period).

        Returns:
            (n, K, 3) joint positions [m].

        Raises:
            ShapeError: when ``times`` is not 1-D real numbers.
            DataError: when ``times`` holds NaN or infinity.
            ConfigError: when ``step_s`` is not a finite real number >=
                :data:`MIN_PREVIEW_STEP_S` (a smaller one stepped the copy through each motion
                for minutes: 1e-9 s never returned), or ``times`` decrease or lie before now.
        """
        ts = checks.real_array("times", times).astype(np.float64)
        if ts.ndim != 1:
            raise ShapeError(f"expected times (n,), got {ts.shape}")
        if checks.positive("step_s", step_s) < MIN_PREVIEW_STEP_S:
            raise ConfigError(
                f"expected step_s >= {MIN_PREVIEW_STEP_S} s (the simulation's control period), "
                f"got {step_s!r}"
            )
        if not np.isfinite(ts).all():
            raise DataError(f"expected finite times, got {ts}")
        if ts.size and (ts[0] < self.time - 1e-9 or bool(np.any(np.diff(ts) < 0.0))):
            raise ConfigError(f"expected increasing times from t = {self.time}, got {ts}")
        twin = self._twin()
        out = np.empty((ts.size, *self._pose.shape), dtype=np.float64)
        for k, t in enumerate(ts):
            while twin.time + step_s <= t + 1e-9 and not twin._settled(delivered):
                twin.update(twin.time + step_s, delivered)
            out[k] = twin.joint_positions(float(t))
        return out

    def _settled(self, delivered: set[int]) -> bool:
        """Whether :meth:`update` with this ``delivered`` set can change nothing but
        :attr:`time` from now on, so that the pose stays :attr:`_pose` for ever.

        True when no motion runs and either the blocking motion is over (blocking mode) or,
        in tasks mode, every delivered block has its landing time recorded and none of them
        may be taken next (:meth:`_next_block` can only return fewer blocks once the
        reaction time filters some out, and without a motion the completed set is fixed).
        """
        if self._motion is not None:
            return False
        if self.cfg.mode == "blocking":
            return self._blocking_done
        if any(int(i) not in self._landed for i in delivered):
            return False
        return self._next_block(set(delivered)) is None

    def _twin(self) -> ScriptedHuman:
        """An independent copy of the script: every piece of state is deep-copied (a field
        added later is copied too), only the read-only collaborators (settings, motion
        source, task order, targets) are shared."""
        shared = (self.cfg, self.motion, self.task_order, self.targets)
        return copy.deepcopy(self, {id(obj): obj for obj in shared})

    def progress_bitmask(self, action_names: Sequence[str]) -> int:
        """The completed-action bitmask over the predictor's action set (module docstring)."""
        lower = [n.lower() for n in action_names]
        mask = 0
        for i in self.completed:
            for name in (f"take_{i}", f"reach_{i}"):
                if name in lower:
                    mask |= 1 << lower.index(name)
                    break
            else:
                if i < len(action_names):
                    mask |= 1 << i
        return mask

    def solo_duration(self, far_targets: dict[int, np.ndarray]) -> float:
        """Time the human needs to do every task alone [s] (the efficiency reference).

        Alone, each object costs a reach to its far position (fetching it), a reach to its
        delivery spot (putting it down where the robot would have) and the mean idle time;
        the motions are generated with the same source and speed but an independent seed.

        Args:
            far_targets: block id -> (3,) grasp point at the block's far position [m].
        """
        rng = np.random.default_rng([self.seed, HUMAN_SEED_SALT, 2])
        idle = 0.5 * (self.cfg.idle_s[0] + self.cfg.idle_s[1])
        total = 0.0
        pose = self.motion.rest_pose()
        for i in self.order:
            for target in (far_targets[i], self.targets[i]):
                frames = self.motion.reach(
                    self.arm_for(target),
                    target,
                    rng,
                    speed=self.cfg.speed_factor,
                    hold_s=self.cfg.hold_s,
                    start_pose=pose,
                )
                total += (frames.shape[0] - 1) / self.motion.fps
                pose = frames[-1]
            total += idle
        return total
