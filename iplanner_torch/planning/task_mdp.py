"""MDP task planner over progress states with Q-learning (paper sec. 3.1, 4.2).

With n objects the human actions are ``Take_i`` and the robot actions ``Fetch_i``. A progress
state ``p`` is a bitmask over both: bit ``i`` is ``Take_i`` done, bit ``n + i`` is ``Fetch_i``
done. The robot picks the next ``Fetch_i``; Q is learned with

    Q(p, a) <- (1 - alpha) Q(p, a) + alpha (R + gamma max_a' Q(p', a'))
    R = w_prep R_prep(p, a) + w_delay R_delay,   R_prep(p, a) = sum_h p(n = h | p) H(h, a)

(eq. reward), where ``p(n | p)`` is the predicted next human action (eq. next_action) and
``R_delay = -d`` the delay of the robot's motion (waits forced by the human, sec. 5) plus the
time the human stood waiting for an object not yet fetched.

Episodes are simulated: during each fetch, the human picks the next object from ``p(n | p)``
restricted to what the task order allows; ``Take_i`` is possible only after ``Fetch_i``.
"""

from __future__ import annotations

import json
import math
import numbers
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Protocol

import numpy as np

from iplanner_torch import checks
from iplanner_torch.errors import CheckpointError, ConfigError, DataError, ShapeError
from iplanner_torch.files import whole_file


class TaskOrderLike(Protocol):
    """The human's task order (``data.TaskOrder`` satisfies it)."""

    def allowed_next(self, done: set[int]) -> set[int]:
        """Objects the human may take next, given the set already taken."""
        ...


#: p(n | human progress): the human-progress bitmask -> (n,) probabilities of Take_i next.
NextActionProbs = Callable[[int], Sequence[float]] | Mapping[int, Sequence[float]]
#: delay of the robot's motion for Fetch_i in state p [s]: (p, i, rng) -> seconds.
DelayFn = Callable[[int, int, np.random.Generator], float]


@dataclass(frozen=True, kw_only=True)
class TaskMDPCfg:
    """Settings of :class:`TaskPlanner`."""

    # n, objects to hand over (robot actions Fetch_i, human actions Take_i)
    num_objects: int
    # alpha, the Q-learning rate (paper: 0.1)
    alpha: float = 0.1
    # gamma, the discount
    gamma: float = 0.9
    # epsilon of the epsilon-greedy exploration while training
    epsilon: float = 0.2
    # simulated training episodes
    episodes: int = 2000
    # w_prep, weight of the preparation reward
    w_prep: float = 1.0
    # w_delay, weight of the (negative) delay reward [1/s]
    w_delay: float = 0.1
    # seconds the human waits when the next object is not yet fetched (one fetch's time)
    idle_delay_s: float = 2.0
    # seed of the training episodes
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("num_objects", "episodes", "seed"):
            checks.integer(name, getattr(self, name))
        for name in ("alpha", "gamma", "epsilon", "w_prep", "w_delay", "idle_delay_s"):
            checks.finite(name, getattr(self, name))
        if not 1 <= self.num_objects <= 16:
            raise ConfigError(f"expected num_objects in [1, 16], got {self.num_objects}")
        if not 0.0 < self.alpha <= 1.0:
            raise ConfigError(f"expected alpha in (0, 1], got {self.alpha}")
        if not 0.0 <= self.gamma <= 1.0:
            raise ConfigError(f"expected gamma in [0, 1], got {self.gamma}")
        if not 0.0 <= self.epsilon <= 1.0:
            raise ConfigError(f"expected epsilon in [0, 1], got {self.epsilon}")
        if self.episodes < 0:
            raise ConfigError(f"expected episodes >= 0, got {self.episodes}")
        if self.seed < 0:
            raise ConfigError(f"expected seed >= 0, got {self.seed}")
        if self.w_prep < 0.0 or self.w_delay < 0.0 or self.idle_delay_s < 0.0:
            raise ConfigError("expected w_prep, w_delay and idle_delay_s >= 0")


def encode_state(taken: set[int] | int, fetched: set[int] | int, num_objects: int) -> int:
    """The progress bitmask: bit i for Take_i, bit n + i for Fetch_i.

    Args:
        taken: the objects the human has taken, as a collection of indices in [0, n) or a
            bitmask in [0, 2^n) (a Python or numpy integer).
        fetched: the objects the robot has fetched, likewise.
        num_objects: n, an integer >= 1.

    Raises:
        ConfigError: for an object index or bitmask out of range (it would set another
            object's bit), an argument that is neither, or a ``num_objects`` below 1.
    """
    n = checks.integer("num_objects", num_objects, minimum=1)
    return _encode(_object_mask("taken", taken, n), _object_mask("fetched", fetched, n), n)


def decode_state(state: int, num_objects: int) -> tuple[int, int]:
    """(taken mask, fetched mask) of a progress bitmask.

    Raises:
        ConfigError: when ``state`` is not an integer in [0, 4^n), or ``num_objects`` is not
            an integer >= 1.
    """
    n = checks.integer("num_objects", num_objects, minimum=1)
    return _decode(_state("state", state, n), n)


def _encode(taken: int, fetched: int, n: int) -> int:
    return taken | (fetched << n)


def _decode(state: int, n: int) -> tuple[int, int]:
    full = (1 << n) - 1
    return state & full, (state >> n) & full


def _state(name: str, state: object, n: int) -> int:
    """``state`` as an int; ConfigError unless it is a progress bitmask of ``n`` objects."""
    if isinstance(state, (bool, np.bool_)) or not isinstance(state, numbers.Integral):
        raise ConfigError(f"expected {name} a progress bitmask (an integer), got {state!r}")
    if not 0 <= state < 1 << (2 * n):
        raise ConfigError(
            f"expected {name} a progress bitmask of {n} objects in [0, {1 << (2 * n)}), "
            f"got {state}"
        )
    return int(state)


def _action(action: object, n: int) -> int:
    """``action`` as an int; ConfigError unless it is an object index in [0, n)."""
    a = checks.integer("action", action)
    if not 0 <= a < n:
        raise ConfigError(f"expected action an object index in [0, {n}), got {action}")
    return a


def _object_mask(name: str, objs: object, n: int) -> int:
    """The bitmask of ``objs`` (a bitmask or a collection of object indices in [0, n))."""
    if isinstance(objs, numbers.Integral):
        if not 0 <= objs < 1 << n:
            raise ConfigError(f"expected {name} a bitmask of {n} objects, got {objs}")
        return int(objs)
    if not isinstance(objs, Iterable) or isinstance(objs, (str, bytes)):
        raise ConfigError(f"expected {name} a set of object indices or a bitmask, got {objs!r}")
    items = set(objs)
    for i in items:
        if isinstance(i, bool) or not isinstance(i, numbers.Integral) or not 0 <= i < n:
            raise ConfigError(f"unknown object {i!r} in {name}: expected indices in [0, {n})")
    return sum(1 << int(i) for i in items)


def _bits(mask: int, n: int) -> set[int]:
    return {i for i in range(n) if mask >> i & 1}


def _numeric_table(table: object) -> np.ndarray:
    """``table`` as a float64 array; DataError when it is not numeric or is complex."""
    if np.iscomplexobj(table):  # float64 conversion would drop the imaginary part
        raise DataError(
            f"expected h_table a real (n, n) table, got complex values "
            f"(dtype {np.asarray(table).dtype})"
        )
    try:
        return np.asarray(table, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"expected h_table a numeric (n, n) table, got {exc}") from exc


def reach_crossings(
    starts: np.ndarray, ends: np.ndarray, points: np.ndarray, radius: float
) -> np.ndarray:
    """Which points lie within ``radius`` of a person's reach, seen from above.

    A reach is the straight segment from ``starts[k]`` (the shoulder) to ``ends[k]`` (the
    spot of a block the person is about to take); only x and y count, the table's plane, since
    the hand passes over what lies below its path. A delivery spot near a reach is one where a
    robot that delivers there meets the person's arm (``EpisodeCfg.task_crossing_radius``).

    Args:
        starts: (P, D) reach starts [m], D >= 2 (x, y first).
        ends: (P, D) reach ends [m].
        points: (N, D) points to test [m].
        radius: distance within which a point counts as crossed [m], finite and >= 0.

    Returns:
        (N,) bool: point ``n`` lies within ``radius`` of at least one reach (all False for
        P = 0).

    Raises:
        ShapeError: when the arrays are not (P, D), (P, D) and (N, D) with D >= 2, or hold
            anything but real numbers.
        DataError: when one of them holds NaN or inf.
        ConfigError: when ``radius`` is not a finite number >= 0.
    """
    radius = checks.non_negative("radius", radius)
    a = checks.real_array("starts", starts).astype(np.float64)
    b = checks.real_array("ends", ends).astype(np.float64)
    x = checks.real_array("points", points).astype(np.float64)
    if a.ndim != 2 or a.shape[1] < 2 or b.shape != a.shape:
        raise ShapeError(
            f"expected starts and ends (P, D) with D >= 2, got {a.shape} and {b.shape}"
        )
    if x.ndim != 2 or x.shape[1] != a.shape[1]:
        raise ShapeError(f"expected points (N, {a.shape[1]}), got {x.shape}")
    for name, arr in (("starts", a), ("ends", b), ("points", x)):
        if not np.isfinite(arr).all():
            raise DataError(f"expected finite {name}, got NaN or inf")
    a, b, x = a[:, :2], b[:, :2], x[:, :2]
    d = b - a  # (P, 2)
    len2 = (d * d).sum(-1)  # (P,)
    rel = x[:, None, :] - a[None, :, :]  # (N, P, 2)
    s = np.where(len2 > 0, (rel * d).sum(-1) / np.where(len2 > 0, len2, 1.0), 0.0)
    foot = a[None] + np.clip(s, 0.0, 1.0)[..., None] * d[None]  # (N, P, 2)
    dist = np.linalg.norm(x[:, None, :] - foot, axis=-1)  # (N, P)
    return (dist <= radius).any(axis=1)  # (N,); all False for P = 0


class TaskPlanner:
    """Q-learning task planner: which object the robot fetches next.

    Args:
        cfg: settings.
        task_order: the human's order constraints (only needed for training).
        next_action_probs: p(n | p) as a callable or a table keyed by the human-progress
            bitmask (missing entries: uniform over the allowed objects).
        h_table: (n, n) prior reward H[h, a] of fetching ``a`` before the human's ``Take_h``;
            None is the identity (+1 when Fetch_i precedes Take_i, else 0).
        delay_fn: the robot's motion delay for a fetch [s]; None means no delay.

    Raises:
        ConfigError: when ``h_table`` is not (n, n).
        DataError: when ``h_table`` is not numeric, is complex or holds NaN or inf.
    """

    def __init__(
        self,
        cfg: TaskMDPCfg,
        task_order: TaskOrderLike | None = None,
        next_action_probs: NextActionProbs | None = None,
        h_table: np.ndarray | None = None,
        delay_fn: DelayFn | None = None,
    ) -> None:
        n = cfg.num_objects
        self.cfg = cfg
        self.task_order = task_order
        self.next_action_probs = next_action_probs
        self.h_table = np.eye(n) if h_table is None else _numeric_table(h_table)
        if self.h_table.shape != (n, n):
            raise ConfigError(f"expected h_table ({n}, {n}), got {self.h_table.shape}")
        if not np.isfinite(self.h_table).all():
            h, a = (int(i) for i in np.argwhere(~np.isfinite(self.h_table))[0])
            raise DataError(
                f"expected a finite h_table, got h_table[{h}, {a}] = {self.h_table[h, a]}"
            )
        self.delay_fn = delay_fn
        self.q: dict[int, np.ndarray] = {}
        # the training episodes' random stream: a second train() continues it
        self._rng = np.random.default_rng(cfg.seed)

    # ------------------------------------------------------------ model pieces
    def _allowed_takes(self, taken: int) -> set[int]:
        done = _bits(taken, self.cfg.num_objects)
        if self.task_order is None:
            return set(range(self.cfg.num_objects)) - done
        return set(self.task_order.allowed_next(done)) - done

    def human_next_probs(self, taken: int) -> np.ndarray:
        """(n,) p(n = Take_i | p) restricted to the allowed objects and renormalised.

        Args:
            taken: bitmask (or set of indices) of the objects the human has taken.

        Raises:
            ConfigError: when ``taken`` is not a bitmask of n objects, or
                ``next_action_probs`` gives a shape other than (n,).
            DataError: when it gives a NaN or infinite probability, or values that are not
                real numbers (complex, text, a set).
        """
        return self._human_next_probs(_object_mask("taken", taken, self.cfg.num_objects))

    def _human_next_probs(self, taken: int) -> np.ndarray:
        """:meth:`human_next_probs` of a checked bitmask (the learning loop's)."""
        n = self.cfg.num_objects
        allowed = self._allowed_takes(taken)
        raw = None
        if callable(self.next_action_probs):
            raw = self.next_action_probs(taken)
        elif self.next_action_probs is not None:
            raw = self.next_action_probs.get(taken)
        try:
            if np.iscomplexobj(raw):  # float64 conversion would drop the imaginary part
                raise TypeError("complex values")
            p = np.zeros(n) if raw is None else np.asarray(raw, dtype=np.float64).copy()
        except (TypeError, ValueError) as exc:
            raise DataError(
                f"expected real next-action probabilities for taken mask {taken}, got "
                f"{raw!r} ({exc})"
            ) from exc
        if p.shape != (n,):
            raise ConfigError(f"expected next-action probabilities of shape ({n},), got {p.shape}")
        if not np.isfinite(p).all():
            raise DataError(
                f"expected finite next-action probabilities for taken mask {taken}, got "
                f"{p.tolist()}"
            )
        mask = np.array([i in allowed for i in range(n)])
        p = np.where(mask, np.clip(p, 0.0, None), 0.0)
        if p.sum() <= 0.0 and mask.any():
            p = mask.astype(np.float64)
        return p / p.sum() if p.sum() > 0 else p

    def r_prep(self, state: int, action: int) -> float:
        """Eq. reward: ``sum_h p(n = h | p) H(h, a)``.

        Raises:
            ConfigError: when ``state`` is not a progress bitmask in [0, 4^n) or ``action``
                not an object index in [0, n) (-1 took the last column of H).
        """
        n = self.cfg.num_objects
        return self._r_prep(_state("state", state, n), _action(action, n))

    def _r_prep(self, state: int, action: int) -> float:
        taken, _ = _decode(state, self.cfg.num_objects)
        return float(self._human_next_probs(taken) @ self.h_table[:, action])

    def available(self, state: int) -> list[int]:
        """Objects not yet fetched in ``state`` (ConfigError unless a progress bitmask in
        [0, 4^n))."""
        return self._available(_state("state", state, self.cfg.num_objects))

    def _available(self, state: int) -> list[int]:
        _, fetched = _decode(state, self.cfg.num_objects)
        return [i for i in range(self.cfg.num_objects) if not fetched >> i & 1]

    def q_values(self, state: int) -> np.ndarray:
        """(n,) Q(p, Fetch_i); -inf for objects already fetched (ConfigError unless ``state``
        is a progress bitmask in [0, 4^n))."""
        return self._q_values(_state("state", state, self.cfg.num_objects))

    def _q_values(self, state: int) -> np.ndarray:
        q = self.q.get(state)
        out = np.full(self.cfg.num_objects, -math.inf)
        avail = self._available(state)
        out[avail] = 0.0 if q is None else q[avail]
        return out

    # ------------------------------------------------------------ learning
    def update(self, state: int, action: int, reward: float, next_state: int | None) -> None:
        """One Q-learning update (``next_state`` None: terminal).

        Raises:
            ConfigError: when ``state`` or ``next_state`` is not a progress bitmask in
                [0, 4^n), or ``action`` not an object index in [0, n).
            DataError: when ``reward`` is not a finite number.
        """
        n = self.cfg.num_objects
        state = _state("state", state, n)
        if next_state is not None:
            next_state = _state("next_state", next_state, n)
        action = _action(action, n)
        reward = checks.finite("reward", reward, error=DataError)
        self._update(state, action, reward, next_state)

    def _update(self, state: int, action: int, reward: float, next_state: int | None) -> None:
        n = self.cfg.num_objects
        q = self.q.setdefault(state, np.zeros(n))
        future = 0.0
        if next_state is not None and self._available(next_state):
            future = float(np.max(self._q_values(next_state)))
        a = self.cfg.alpha
        q[action] = (1.0 - a) * q[action] + a * (reward + self.cfg.gamma * future)

    def simulate_step(
        self, state: int, action: int, rng: np.random.Generator
    ) -> tuple[int, float, float]:
        """The robot fetches ``action`` while the human picks a next object.

        Returns:
            next state, reward, delay [s] (robot motion delay plus human idle time).

        Raises:
            ConfigError: when ``state`` is not a progress bitmask in [0, 4^n) or ``action``
                not an object index in [0, n).
            DataError: when ``delay_fn`` gives anything but a finite number of seconds >= 0
                (NaN, inf, a negative delay, a string), naming the state and action.
        """
        n = self.cfg.num_objects
        return self._simulate_step(_state("state", state, n), _action(action, n), rng)

    def _simulate_step(
        self, state: int, action: int, rng: np.random.Generator
    ) -> tuple[int, float, float]:
        """:meth:`simulate_step` of a checked state and action (the learning loop's)."""
        n = self.cfg.num_objects
        taken, fetched = _decode(state, n)
        reward_prep = self._r_prep(state, action)
        delay = 0.0
        if self.delay_fn is not None:
            raw = self.delay_fn(state, action, rng)
            where = f"delay_fn(state={state}, action={action})"
            delay = checks.finite_time(where, raw, error=DataError)
            if delay < 0.0:
                raise DataError(f"expected {where} a delay [s] >= 0, got {raw!r}")
        fetched |= 1 << action
        probs = self._human_next_probs(taken)
        if probs.sum() > 0:
            h = int(rng.choice(n, p=probs))
            if fetched >> h & 1:
                taken |= 1 << h
            else:
                delay += self.cfg.idle_delay_s
        reward = self.cfg.w_prep * reward_prep - self.cfg.w_delay * delay
        return _encode(taken, fetched, n), reward, delay

    def train(self, episodes: int | None = None) -> list[float]:
        """Epsilon-greedy Q-learning over simulated episodes.

        A second call continues the first one's random stream (``train(a)`` then ``train(b)``
        gives the Q-table of ``train(a + b)``), rather than replaying the same episodes.

        Args:
            episodes: how many (>= 0); None uses ``cfg.episodes``.

        Returns:
            The return (sum of rewards) of each episode.

        Raises:
            ConfigError: when ``episodes`` is not an integer >= 0.
        """
        if episodes is not None:
            episodes = checks.integer("episodes", episodes, minimum=0)
        rng = self._rng
        returns = []
        for _ in range(self.cfg.episodes if episodes is None else episodes):
            state, total = 0, 0.0
            while self._available(state):
                avail = self._available(state)
                if rng.random() < self.cfg.epsilon:
                    action = int(rng.choice(avail))
                else:
                    action = self._greedy(state)
                nxt, reward, _ = self._simulate_step(state, action, rng)
                self._update(state, action, reward, nxt if self._available(nxt) else None)
                state, total = nxt, total + reward
            returns.append(total)
        return returns

    def _greedy(self, state: int) -> int:
        q = self._q_values(state)
        if state not in self.q:  # unseen: the immediate preparation reward decides
            q = np.array(
                [
                    self._r_prep(state, a) if a in self._available(state) else -math.inf
                    for a in range(self.cfg.num_objects)
                ]
            )
        return int(np.argmax(q))

    def policy(self, taken: set[int] | int, fetched: set[int] | int) -> int | None:
        """pi(p): the object to fetch next, or None when all are fetched.

        Args:
            taken: the objects the human has taken, as a set of indices in [0, n) or a bitmask
                (a Python or numpy integer).
            fetched: the objects the robot has fetched, likewise.

        Raises:
            ConfigError: for an object index (or bitmask) out of range, or an argument that
                is neither a bitmask nor a collection of indices.
            DataError: when an object is taken but not fetched (``Take_i`` is possible only
                after ``Fetch_i``).
        """
        n = self.cfg.num_objects
        t_mask, f_mask = _object_mask("taken", taken, n), _object_mask("fetched", fetched, n)
        if t_mask & ~f_mask:
            raise DataError(
                f"expected every taken object fetched (Take_i only after Fetch_i), got taken "
                f"{sorted(_bits(t_mask, n))} with fetched {sorted(_bits(f_mask, n))}"
            )
        state = _encode(t_mask, f_mask, n)
        return self._greedy(state) if self._available(state) else None

    # ------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> None:
        """Write the settings, H and the Q table as JSON.

        The file is written whole or not at all (:func:`iplanner_torch.files.whole_file`): a
        temporary file beside ``path`` replaces it in one step, so a save that fails or is
        interrupted (a full disk) leaves an earlier file at ``path`` as it was.

        Raises:
            ConfigError: when ``path`` is not a file path (str or os.PathLike).
            OSError: when the file cannot be written (a missing folder, no permission, a
                full disk); ``path`` is then unchanged.
        """
        _check_path(path)
        data = {
            "format": "iplanner_torch.task_mdp/1",
            "cfg": asdict(self.cfg),
            "h_table": self.h_table.tolist(),
            "q": {str(k): v.tolist() for k, v in self.q.items()},
        }
        text = json.dumps(data)
        with whole_file(path) as tmp:
            tmp.write_text(text, encoding="utf-8")

    @classmethod
    def load(
        cls,
        path: str | Path,
        task_order: TaskOrderLike | None = None,
        next_action_probs: NextActionProbs | None = None,
        delay_fn: DelayFn | None = None,
    ) -> TaskPlanner:
        """Read a planner written by :meth:`save`.

        Raises:
            ConfigError: when ``path`` is not a file path (str or os.PathLike).
            CheckpointError: when the file is missing, not a task-planner file, or malformed
                (not JSON, JSON nested too deep to decode or holding an integer of too many
                digits to read, unknown or invalid settings, an H or a Q table that does not
                fit them).
        """
        _check_path(path)
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CheckpointError(f"cannot read task planner {path}: {exc}") from exc
        except ValueError as exc:  # an integer of more digits than int() reads (4300)
            raise CheckpointError(
                f"cannot read task planner {path}: malformed JSON (an integer of too many "
                "digits to read, a corrupted number)"
            ) from exc
        except RecursionError as exc:  # "[" * 100000: the decoder recursed too deep
            raise CheckpointError(
                f"cannot read task planner {path}: malformed JSON (nested too deep to decode; "
                "a task planner file nests three levels)"
            ) from exc
        if not isinstance(data, dict):
            raise CheckpointError(
                f"{path} is not a task planner file (expected a JSON object, got "
                f"{type(data).__name__})"
            )
        if data.get("format") != "iplanner_torch.task_mdp/1":
            raise CheckpointError(
                f"{path} is not a task planner file (format {data.get('format')!r})"
            )
        missing = [k for k in ("cfg", "h_table", "q") if k not in data]
        if missing:
            raise CheckpointError(f"task planner {path}: missing {', '.join(map(repr, missing))}")
        cfg = _load_cfg(path, data["cfg"])
        n = cfg.num_objects
        try:
            h_table = np.asarray(data["h_table"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise CheckpointError(f"task planner {path}: h_table is not numeric: {exc}") from exc
        if h_table.shape != (n, n) or not np.isfinite(h_table).all():
            raise CheckpointError(
                f"task planner {path}: expected a finite h_table ({n}, {n}), got shape "
                f"{h_table.shape}"
            )
        q = _load_q(path, data["q"], n)
        planner = cls(cfg, task_order, next_action_probs, h_table, delay_fn)
        planner.q = q
        return planner


def _check_path(path: object) -> None:
    """ConfigError unless ``path`` is a str or os.PathLike (``Path()`` raised TypeError)."""
    checks.path_argument(path, "of a task planner", error=ConfigError)


def _load_cfg(path: str | Path, raw: object) -> TaskMDPCfg:
    """The :class:`TaskMDPCfg` of a task-planner file, or :class:`CheckpointError`."""
    if not isinstance(raw, dict):
        raise CheckpointError(f"task planner {path}: expected cfg an object, got {raw!r}")
    known = {f.name for f in fields(TaskMDPCfg)}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise CheckpointError(f"task planner {path}: unknown cfg keys {unknown}")
    if "num_objects" not in raw:
        raise CheckpointError(f"task planner {path}: cfg is missing 'num_objects'")
    try:
        return TaskMDPCfg(**raw)
    except ConfigError as exc:
        raise CheckpointError(f"task planner {path}: invalid cfg: {exc}") from exc


def _load_q(path: str | Path, raw: object, n: int) -> dict[int, np.ndarray]:
    """The Q table of a task-planner file: progress state (in [0, 4^n)) -> (n,) finite values."""
    if not isinstance(raw, dict):
        raise CheckpointError(
            f"task planner {path}: expected q an object, got {type(raw).__name__}"
        )
    q: dict[int, np.ndarray] = {}
    for key, row in raw.items():
        try:
            state = int(key)
        except ValueError:
            state = -1
        if not 0 <= state < 1 << (2 * n):
            raise CheckpointError(
                f"task planner {path}: q key {key!r} is not a progress state of {n} objects "
                f"(an int in [0, {1 << (2 * n)}))"
            )
        try:
            values = np.asarray(row, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise CheckpointError(f"task planner {path}: q[{key}] is not numeric: {exc}") from exc
        if values.shape != (n,):
            raise CheckpointError(
                f"task planner {path}: expected q[{key}] of shape ({n},) for num_objects={n}, "
                f"got {values.shape}"
            )
        if not np.isfinite(values).all():
            raise CheckpointError(f"task planner {path}: q[{key}] has non-finite values")
        q[state] = values
    return q
