"""Scenarios and the robot's delivery actions ``Fetch_i`` (paper sec. 7).

``Fetch_i`` is a sequence of phases, each with a tool-point target in the table frame:

==========  =====================================  =========================================
phase       target of the tool point               ends when
==========  =====================================  =========================================
approach    grasp point above block i (far)        tool point within ``pick_radius``: picked
carry       grasp point above delivery spot i      tool point within ``place_radius``:
                                                   released there, ``delivered``
return      (joint goal: the home configuration)   joints within ``home_tolerance``: done
==========  =====================================  =========================================

The grasp point is the block's top face centre raised by ``grasp_clearance``. A picked block is
carried kinematically: it keeps the offset it had to the tool point at pick time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Literal

import numpy as np

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, IPlannerError
from iplanner_torch.sim.human import TaskOrderLike
from iplanner_torch.sim.scene import ARRANGEMENT_IDS, Arrangement, SceneCfg


@dataclass(frozen=True, kw_only=True)
class ScenarioCfg:
    """One row of the paper's simulation table (arrangement, task order, confidence)."""

    # scenario name used in result tables
    name: str = "arrangement_1x4"
    # "delivery": fetch-and-take tasks; "blocking": robot crosses, human blocks (fig. speed)
    kind: Literal["delivery", "blocking"] = "delivery"
    # block arrangement "1x4", "2x2" or "2x4"
    arrangement: Arrangement = "1x4"
    # task order expression, e.g. "(0,1)->(2,3)", "0->1->2->3" or "random"
    task_order: str = "(0,1)->(2,3)"
    # confidence level delta_CL of the probabilistic collision check
    confidence: float = 0.95
    # blocking: tool-point start and goal of the robot's crossing motion, table frame [m]
    crossing_start: tuple[float, float, float] = (0.15, 0.35, 0.2)
    crossing_goal: tuple[float, float, float] = (0.15, -0.35, 0.2)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ConfigError(f"expected name a non-empty string, got {self.name!r}")
        if self.kind not in ("delivery", "blocking"):
            raise ConfigError(f"expected kind 'delivery' or 'blocking', got {self.kind!r}")
        if self.arrangement not in ARRANGEMENT_IDS:
            raise ConfigError(
                f"expected arrangement in {sorted(ARRANGEMENT_IDS)}, got {self.arrangement!r}"
            )
        if not 0.0 < checks.finite("confidence", self.confidence) < 1.0:
            raise ConfigError(f"expected confidence in (0, 1), got {self.confidence!r}")
        if not isinstance(self.task_order, str):
            raise ConfigError(
                f"expected task_order a string such as '(0,1)->(2,3)', got {self.task_order!r}"
            )
        if not self.task_order.strip():
            raise ConfigError(
                "expected task_order an expression such as '(0,1)->(2,3)', got an empty string"
            )
        # parsed now, so a malformed order fails here and not when an episode starts; blocking
        # runs do not use it (only its syntax is checked, against every block id)
        ids = ARRANGEMENT_IDS["2x4" if self.kind == "blocking" else self.arrangement]
        try:
            parse_order(self.task_order, ids, warn_untouched=self.kind != "blocking")
        except ConfigError as err:  # named by the field (the message says "task order")
            raise ConfigError(f"task_order: {err}") from None
        checks.finite_tuple("crossing_start", self.crossing_start, 3)
        checks.finite_tuple("crossing_goal", self.crossing_goal, 3)

    def scene(self, **overrides: object) -> SceneCfg:
        """The :class:`SceneCfg` of this scenario's arrangement (other fields by keyword)."""
        return SceneCfg(arrangement=self.arrangement, **overrides)  # type: ignore[arg-type]


def parse_order(
    expr: str, block_ids: tuple[int, ...], *, warn_untouched: bool = True
) -> TaskOrderLike:
    """Parse a task order expression and check that it names the scene's blocks.

    Args:
        expr: ``"(0,1)->(2,3)"``, ``"random"`` (any order of ``block_ids``) ...
        block_ids: the blocks present in the scene.
        warn_untouched: warn when the order leaves some of ``block_ids`` out.

    Raises:
        ConfigError: on a syntax error (naming its position) or when the order names blocks
            absent from the scene.

    Warns:
        ConfigWarning: when the order leaves some of the scene's blocks out (allowed: the
            episode then ends when the named blocks are done).
    """
    from iplanner_torch.data.tasks import parse_task_order

    if not isinstance(expr, str):
        raise ConfigError(f"expected a task order string, got {expr!r}")
    if expr.strip().lower() == "random":  # any order of the blocks present
        expr = "(" + ",".join(str(i) for i in block_ids) + ")"
    try:
        order = parse_task_order(expr)
    except ValueError as err:
        if isinstance(err, IPlannerError):
            raise
        raise ConfigError(f"task order {expr!r}: {err}") from err
    named = {int(i) for i in order.ids}  # Python ints: an id may exceed every integer dtype
    unknown = sorted(named - set(block_ids))
    if unknown:
        raise ConfigError(f"task order {expr!r} names blocks {unknown}, scene has {block_ids}")
    untouched = sorted(set(block_ids) - named)
    if untouched and warn_untouched:
        import warnings

        from iplanner_torch.errors import ConfigWarning

        warnings.warn(
            f"task order {expr!r} leaves blocks {untouched} of the scene untouched: an episode "
            "is complete when the blocks it names are done",
            ConfigWarning,
            stacklevel=2,
        )
    return order


def group_ranks(groups: Sequence[Sequence[int]]) -> dict[int, int]:
    """Block id -> the index of its group in a task order's groups (``TaskOrder.groups``)."""
    return {i: k for k, g in enumerate(groups) for i in g}


def next_feasible(order: TaskOrderLike, delivered: set[int], all_ids: tuple[int, ...]) -> int:
    """The default task choice: the smallest undelivered id the order allows next.

    The robot treats the blocks it has delivered as done, so its deliveries follow a valid
    order; -1 when nothing is left. With an order that has groups (``TaskOrder``), the
    smallest undelivered id of the earliest group that has one, which is the same block and
    is defined too when the deliveries broke the order (a fetch moved off the person's reach,
    ``EpisodeCfg.task_crossing_radius``); ids the order does not name come last.
    """
    remaining = [i for i in all_ids if i not in delivered]
    if not remaining:
        return -1
    groups = getattr(order, "groups", None)
    if groups is not None:
        rank = group_ranks(groups)
        return min(remaining, key=lambda i: (rank.get(i, len(groups)), i))
    allowed = order.allowed_next(set(delivered))
    for i in sorted(remaining):
        if i in allowed:
            return i
    return min(remaining)


class FetchPhase(Enum):
    """Phases of ``Fetch_i`` (module docstring)."""

    APPROACH = "approach"
    CARRY = "carry"
    RETURN = "return"


@dataclass(frozen=True, kw_only=True)
class FetchCfg:
    """Tolerances of the robot's delivery actions."""

    # tool point to grasp point distance that picks a block [m]
    pick_radius: float = 0.04
    # tool point to place point distance that releases a block on its spot [m]
    place_radius: float = 0.04
    # height of the grasp point above the block's top face [m]
    grasp_clearance: float = 0.01
    # max |q - q_home| that ends the return phase [rad]
    home_tolerance: float = 0.15

    def __post_init__(self) -> None:
        for name in ("pick_radius", "place_radius", "home_tolerance"):
            checks.positive(name, getattr(self, name))
        checks.non_negative("grasp_clearance", self.grasp_clearance)


@dataclass(kw_only=True)
class FetchTask:
    """The state of one ``Fetch_i``.

    Attributes:
        block: block id i.
        phase: current phase.
        pick_point: (3,) grasp point above the block at its far position [m].
        place_point: (3,) grasp point above the delivery spot [m].
        t_start: simulated time the action started [s].
    """

    block: int
    phase: FetchPhase
    pick_point: np.ndarray
    place_point: np.ndarray
    t_start: float

    @classmethod
    def create(cls, block: int, scene: SceneCfg, cfg: FetchCfg, t: float) -> FetchTask:
        """A new ``Fetch_block`` in its approach phase.

        Raises:
            ConfigError: when ``block`` is not one of the scene's block ids.
        """
        scene.check_block_id(block)
        lift = np.array([0.0, 0.0, 0.5 * scene.block_size + cfg.grasp_clearance])
        return cls(
            block=block,
            phase=FetchPhase.APPROACH,
            pick_point=scene.block_position(block) + lift,
            place_point=scene.delivery_position(block) + lift,
            t_start=t,
        )

    def target_point(self) -> np.ndarray | None:
        """(3,) tool-point target of the phase [m]; None in the return phase (joint goal)."""
        if self.phase is FetchPhase.APPROACH:
            return self.pick_point
        if self.phase is FetchPhase.CARRY:
            return self.place_point
        return None
