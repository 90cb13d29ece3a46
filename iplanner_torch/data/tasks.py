"""Task orders and synthetic task demonstrations (paper sec. 4.1 and 7).

A task order expression (paper sec. 7, table performance) lists object ids: parentheses hold a
group whose members may be taken in any order, arrows give precedence between groups, a bare
number is a group of one, and ``random`` is one group holding every object. ``(0,1)->(2,3)``
allows exactly 0-1-2-3, 0-1-3-2, 1-0-2-3 and 1-0-3-2.

A task demonstration is a person taking objects in an allowed order: for object ``i`` the
hand (the arm on the object's side) reaches to it, grasps, brings it back near the body and
lets go, then the person idles a little. The frames from the start of the reach to the
release are labelled ``take_i``; the others ``idle``. Progress states (which ``take_i`` are
done) and next-action statistics (sec. 4.1) are learned from such demonstrations.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from tqdm.auto import tqdm

from iplanner_torch import checks
from iplanner_torch.data.dataset_card import (
    DatasetSummary,
    finish_staged_dataset,
    generator_settings,
    staged_dataset,
    write_dataset_card,
)
from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.io import save_demonstration
from iplanner_torch.data.kinematic_human import (
    BodyParams,
    MotionPlan,
    arm_for_target,
    plan_hand_move,
    random_sway,
    sample_body,
)
from iplanner_torch.data.reaching import (
    add_tracker_noise,
    check_recording_numbers,
    finite_range,
    frame_times,
    reach_targets,
)
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.errors import ConfigError

_MAX_ORDERS = 1_000_000
# the characters of an object id (str.isdigit would also take "²", which int() refuses)
_DIGITS = frozenset("0123456789")


@dataclass(frozen=True)
class TaskOrder:
    """Groups of object ids; every id of a group must be taken before any id of the next.

    Attributes:
        groups: the groups in precedence order; within a group any order is allowed.
    """

    groups: tuple[tuple[int, ...], ...]

    @property
    def ids(self) -> tuple[int, ...]:
        """All object ids, group by group."""
        return tuple(i for g in self.groups for i in g)

    def num_orders(self) -> int:
        """How many orders are allowed (product of the groups' factorials)."""
        return math.prod(math.factorial(len(g)) for g in self.groups)

    def orders(self) -> list[list[int]]:
        """Every allowed order, in lexicographic order of the group permutations.

        Raises:
            ConfigError: when there are more than a million.
        """
        if self.num_orders() > _MAX_ORDERS:
            raise ConfigError(f"{self.num_orders()} orders allowed, too many to enumerate")
        perms = [sorted(itertools.permutations(g)) for g in self.groups]
        return [[i for p in combo for i in p] for combo in itertools.product(*perms)]

    def sample(self, rng: np.random.Generator) -> list[int]:
        """One allowed order, uniformly at random."""
        return [int(i) for g in self.groups for i in rng.permutation(np.array(g, dtype=int))]

    def allowed_next(self, done: set[int]) -> set[int]:
        """The ids that may be taken next once ``done`` are taken (empty when all are).

        Raises:
            ConfigError: when ``done`` holds an unknown id or breaks the precedence.
        """
        unknown = set(done) - set(self.ids)
        if unknown:
            raise ConfigError(f"unknown object ids {sorted(unknown)}; the task has {self.ids}")
        for gi, g in enumerate(self.groups):
            left = set(g) - set(done)
            if left:
                later = set(done) & {i for h in self.groups[gi + 1 :] for i in h}
                if later:
                    raise ConfigError(
                        f"done {sorted(done)} breaks the order: {sorted(later)} taken "
                        f"before {sorted(left)}"
                    )
                return left
        return set()

    def __str__(self) -> str:
        return "->".join(
            str(g[0]) if len(g) == 1 else "(" + ",".join(map(str, g)) + ")" for g in self.groups
        )


def parse_task_order(expr: str, n_objects: int | None = None) -> TaskOrder:
    """Parse a task order expression such as ``(0,1)->(2,3)``, ``0->(1,2)->3`` or ``random``.

    Grammar: ``order := group ("->" group)*``, ``group := INT | "(" INT ("," INT)* ")"``;
    whitespace is ignored and ``→`` may stand for ``->``.

    Args:
        expr: the expression.
        n_objects: number of objects; required for ``random`` (one group of 0..n-1), and when
            given every id must be below it.

    Raises:
        ConfigError: naming the position of a syntax error, a repeated id, or an id out of
            range (the position of that id).
    """
    if expr.replace("→", "->").strip().lower() == "random":
        if n_objects is None or n_objects < 1:
            raise ConfigError("task order 'random' needs n_objects >= 1")
        return TaskOrder(groups=(tuple(range(n_objects)),))
    order, where = _parse_with_positions(expr)
    if n_objects is not None:
        for i, at in zip(order.ids, where, strict=True):
            if i >= n_objects:
                raise ConfigError(
                    f"task order {expr!r}: object id {i} out of range for {n_objects} objects "
                    f"(ids 0..{n_objects - 1}) at position {at}"
                )
    return order


def _parse_with_positions(expr: str) -> tuple[TaskOrder, tuple[int, ...]]:
    """The order ``expr`` states (not ``random``) and the position of each of its ids.

    Positions count characters of ``expr`` with ``→`` written ``->``.

    Raises:
        ConfigError: naming the position of a syntax error or a repeated id.
    """
    s = expr.replace("→", "->")
    pos = 0
    where: list[int] = []  # the position of each id, in the order of TaskOrder.ids

    def err(msg: str) -> ConfigError:
        return ConfigError(f"task order {expr!r}: {msg} at position {pos}")

    def skip() -> None:
        nonlocal pos
        while pos < len(s) and s[pos].isspace():
            pos += 1

    def number() -> int:
        nonlocal pos
        skip()
        start = pos
        while pos < len(s) and s[pos] in _DIGITS:
            pos += 1
        if start == pos:
            got = f", got {s[pos]!r}" if pos < len(s) else ", got the end"
            raise err(f"expected an object id (digits 0-9){got}")
        where.append(start)
        return int(s[start:pos])

    groups: list[tuple[int, ...]] = []
    while True:
        skip()
        if pos < len(s) and s[pos] == "(":
            pos += 1
            members = [number()]
            skip()
            while pos < len(s) and s[pos] == ",":
                pos += 1
                members.append(number())
                skip()
            if pos >= len(s) or s[pos] != ")":
                raise err("expected ',' or ')'")
            pos += 1
            groups.append(tuple(members))
        else:
            groups.append((number(),))
        skip()
        if pos == len(s):
            break
        if s.startswith("->", pos):
            pos += 2
            continue
        raise err("expected '->' or the end")
    ids = [i for g in groups for i in g]
    for k, i in enumerate(ids):
        if i in ids[:k]:
            pos = where[k]
            raise err(f"repeated object id {i} in {ids}")
    return TaskOrder(groups=tuple(groups)), tuple(where)


def task_action_names(object_ids: Sequence[int]) -> tuple[str, ...]:
    """``("idle", "take_<id>" for each id)``."""
    return ("idle", *(f"take_{i}" for i in object_ids))


def generate_task_demonstration(
    order: Sequence[int],
    targets: np.ndarray,
    body: BodyParams,
    rng: np.random.Generator,
    *,
    fps: float = 15.0,
    object_ids: Sequence[int] | None = None,
    noise_sigma: float = 0.0,
    dropout_rate: float = 0.0,
    idle_s: tuple[float, float] = (0.3, 1.0),
    hold_s: tuple[float, float] = (0.3, 0.6),
) -> Demonstration:
    """A person taking the objects in ``order``.

    Args:
        order: object ids in the order they are taken.
        targets: (n, 3) object (grasp) positions [m], table frame; row ``j`` belongs to
            ``object_ids[j]``.
        body: the person.
        rng: random generator (durations, paths, idle and hold times, noise).
        fps: frame rate [Hz].
        object_ids: the ids of the ``n`` objects (default ``0..n-1``); actions are
            ``("idle", "take_<id>"...)`` in this order.
        noise_sigma: tracker noise per coordinate [m] (see :func:`add_tracker_noise`).
        dropout_rate: fraction of lost joint-frames.
        idle_s: uniform range of the idle before the first and after every take [s].
        hold_s: uniform range of the grasp and of the release [s].

    Returns:
        The demonstration; ``clean_positions`` holds the noise-free motion.

    Raises:
        ConfigError: for a bad ``targets`` shape, an id in ``order`` not in ``object_ids``, or
            a number out of its range or not finite.
    """
    targets = np.asarray(targets, dtype=np.float64)
    if targets.ndim != 2 or targets.shape[1] != 3:
        raise ConfigError(f"expected targets (n, 3), got {targets.shape}")
    ids = list(range(len(targets))) if object_ids is None else [int(i) for i in object_ids]
    if len(ids) != len(targets):
        raise ConfigError(f"object_ids has {len(ids)} ids for {len(targets)} targets")
    bad = [i for i in order if i not in ids]
    if bad:
        raise ConfigError(f"order has ids {bad} not among object_ids {ids}")
    check_recording_numbers("", fps, noise_sigma, dropout_rate)  # as TaskDatasetCfg's
    idle_s = finite_range("idle_s", idle_s)
    hold_s = finite_range("hold_s", hold_s)
    plan = MotionPlan(body=body)
    random_sway(plan, rng)
    t = rng.uniform(*idle_s)
    spans = []
    for oid in order:
        p = targets[ids.index(oid)]
        arm = arm_for_target(body, p)
        side = 1.0 if arm == "left" else -1.0
        go = plan_hand_move(plan, arm, p, t, rng, lean=True)
        place = np.array(
            [
                body.seat_x + rng.uniform(0.18, 0.24),
                body.seat_y + side * rng.uniform(0.06, 0.2),
                rng.uniform(0.05, 0.08),
            ]
        )
        back = plan_hand_move(plan, arm, place, go.t1 + rng.uniform(*hold_s), rng, lean=False)
        end = back.t1 + rng.uniform(*hold_s)
        spans.append((go.t0, end, 1 + ids.index(oid)))
        t = end + rng.uniform(*idle_s)
    times = frame_times(t, fps, 1.0)
    labels = np.zeros(len(times), dtype=np.int64)
    for t0, t1, a in spans:
        labels[(times >= t0) & (times < t1)] = a
    clean = plan.positions(times).astype(np.float32)
    noisy = add_tracker_noise(clean, rng, sigma=noise_sigma, dropout_rate=dropout_rate)
    return Demonstration(
        positions=noisy,
        labels=labels,
        fps=fps,
        joint_names=JOINT_NAMES,
        action_names=task_action_names(ids),
        clean_positions=clean,
        metadata={
            "generator": "tasks",
            "order": [int(i) for i in order],
            "body_scale": body.scale,
        },
    )


#: Object ids present in each arrangement; ids number the 2 x 4 grid of
#: :func:`iplanner_torch.data.reaching.reach_targets` (row * 4 + column), as in the paper's
#: orders (``(1,5)->(2,6)`` for 2 x 2).
ARRANGEMENTS: dict[str, tuple[int, ...]] = {
    "1x4": (0, 1, 2, 3),
    "2x2": (1, 2, 5, 6),
    "2x4": (0, 1, 2, 3, 4, 5, 6, 7),
}


def arrangement_targets(arrangement: str) -> tuple[tuple[int, ...], np.ndarray]:
    """(object ids, (n, 3) positions [m]) of an arrangement ("1x4", "2x2" or "2x4")."""
    if arrangement not in ARRANGEMENTS:
        raise ConfigError(f"unknown arrangement {arrangement!r}, expected {sorted(ARRANGEMENTS)}")
    ids = ARRANGEMENTS[arrangement]
    return ids, reach_targets(8)[list(ids)]


@dataclass(frozen=True, kw_only=True)
class TaskDatasetCfg:
    """Settings of a synthetic task dataset (paper sec. 7, table performance)."""

    order: str = "(0,1)->(2,3)"  # task order expression, or "random"
    arrangement: Literal["1x4", "2x2", "2x4"] = "1x4"  # which objects lie on the table
    n_demos: int = 40  # demonstrations, each one allowed order sampled uniformly
    n_subjects: int = 6  # distinct bodies; demonstration i is done by subject i % n
    fps: float = 15.0  # frame rate [Hz]
    noise_sigma: float = 0.01  # tracker noise per coordinate [m]
    dropout_rate: float = 0.005  # expected fraction of lost joint-frames
    # uniform range of the idle before the first and after every take [s]; long idles teach
    # the predictor that a waiting person stays put (in the closed loop the person waits for
    # the robot's delivery)
    idle_s: tuple[float, float] = (0.5, 4.0)
    seed: int = 0  # everything is a function of this seed
    file_format: Literal["npz", "csv"] = "npz"  # one file per demonstration

    def __post_init__(self) -> None:
        ids, _ = arrangement_targets(self.arrangement)
        if not isinstance(self.order, str):
            raise ConfigError(f"TaskDatasetCfg.order must be a string, got {self.order!r}")
        if self.order.strip().lower() != "random":
            order, where = _parse_with_positions(self.order)
            for i, at in zip(order.ids, where, strict=True):
                if i not in ids:
                    raise ConfigError(
                        f"task order {self.order!r}: object id {i} at position {at} is not on "
                        f"the table: arrangement {self.arrangement} has objects {list(ids)} "
                        "(ids number the 2 x 4 grid of places 0..7)"
                    )
            left = [i for i in ids if i not in order.ids]
            if left:
                raise ConfigError(
                    f"task order {self.order!r} leaves object(s) {left} out: arrangement "
                    f"{self.arrangement} has {list(ids)}, and the order must take each once"
                )
        for name in ("n_demos", "n_subjects"):  # each by name
            checks.integer(f"TaskDatasetCfg.{name}", getattr(self, name), minimum=1)
        # every float is checked finite first (NaN and Inf pass a bare "x < 0" test)
        check_recording_numbers("TaskDatasetCfg.", self.fps, self.noise_sigma, self.dropout_rate)
        if self.file_format not in ("npz", "csv"):
            raise ConfigError(f"file_format must be 'npz' or 'csv', got {self.file_format!r}")
        object.__setattr__(self, "idle_s", finite_range("TaskDatasetCfg.idle_s", self.idle_s))
        object.__setattr__(self, "seed", checks.seed(self.seed, name="TaskDatasetCfg.seed"))

    def task_order(self) -> TaskOrder:
        """The parsed order (``random`` -> one group of the arrangement's ids)."""
        if str(self.order).strip().lower() == "random":
            return TaskOrder(groups=(ARRANGEMENTS[self.arrangement],))
        return parse_task_order(self.order, n_objects=8)


def generate_task_dataset(
    cfg: TaskDatasetCfg,
    out_dir: str | Path = Path("datasets/tasks"),
    *,
    progress: bool = True,
    command: str | None = None,
    replace: Sequence[Path] = (),
) -> DatasetSummary:
    """Generate ``cfg.n_demos`` task demonstrations (``task_{i:03d}``) plus ``README.md``.

    Written into a temporary folder beside ``out_dir`` and moved into it when complete, as
    :func:`~iplanner_torch.data.reaching.generate_reaching_dataset` does; ``replace`` (an
    earlier dataset's files in ``out_dir``) is deleted then.
    """
    out_dir = Path(out_dir)
    t_start = time.perf_counter()
    order = cfg.task_order()
    ids, targets = arrangement_targets(cfg.arrangement)
    files, n_frames = [], 0
    with staged_dataset(out_dir) as staging:
        for i in tqdm(range(cfg.n_demos), desc="tasks", disable=not progress, unit="demo"):
            body = sample_body(np.random.default_rng([cfg.seed, 0, i % cfg.n_subjects]))
            rng = np.random.default_rng([cfg.seed, 3, i])
            demo = generate_task_demonstration(
                order.sample(rng), targets, body, rng, fps=cfg.fps, object_ids=ids,
                noise_sigma=cfg.noise_sigma, dropout_rate=cfg.dropout_rate,
                idle_s=tuple(cfg.idle_s),
            )  # fmt: skip
            demo.name = f"task_{i:03d}"
            demo.metadata.update(
                {"subject": i % cfg.n_subjects, "seed": cfg.seed, "order_expr": str(order)}
            )
            files.append(save_demonstration(demo, staging / f"{demo.name}.{cfg.file_format}"))
            n_frames += demo.num_frames
        summary = DatasetSummary.of_files(staging, files, n_frames, time.perf_counter() - t_start)
        write_dataset_card(
            summary,
            title="Synthetic task dataset",
            facts=[
                ("task order", str(order)),
                ("arrangement", f"{cfg.arrangement} (object ids {list(ids)})"),
                ("actions", ", ".join(task_action_names(ids))),
                ("fps", f"{cfg.fps:g}"),
                ("noise sigma", f"{cfg.noise_sigma:g} m"),
                ("dropout rate", f"{cfg.dropout_rate:g}"),
                ("seed", str(cfg.seed)),
            ],
            settings=generator_settings(cfg),
            command=command
            or (
                'python -c "from iplanner_torch.data.tasks import *; '
                f"generate_task_dataset({cfg!r}, '{out_dir}')\""
            ),
        )
    return finish_staged_dataset(summary, out_dir, replace=replace)
