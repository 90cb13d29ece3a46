"""One closed-loop episode of paper sec. 7: predictor + planner + MuJoCo + scripted human.

Loop (synchronous; simulated time stops while the planner thinks, and
``sim/realtime_factor`` reports simulated seconds per wall-clock second):

1. every ``replan_step_s`` (m) of simulated time: a forecast from the tracker window (I-Planner:
   ``predictor.predict_positions`` with the human's completed-action bitmask as progress) or
   the currently observed pose (ITOMP: ``static_human_forecast``), then ``Replanner.step``;
2. every control period: ``Replanner.command(t)`` -> :meth:`SimEnv.step`;
3. task events move the goal: ``fetch_started`` -> IK of the pick point, ``picked`` -> IK of the
   place point, ``delivered`` -> the next ``Fetch_i`` straight away when one remains
   (``direct_next_fetch``; else home first, and ``fetch_done`` starts the next one). The next
   ``Fetch_i`` is ``task_policy(taken, fetched)`` when given; else, with a predictor that has
   a next-action model, the Q-learning :class:`~iplanner_torch.planning.task_mdp.TaskPlanner`
   on ``predictor.next_action`` (:func:`predictor_task_policy`); else the smallest
   undelivered id the task order allows. With ``task_crossing_radius`` the predicting
   planners also keep the person's reaches in view: the next ``Fetch_i`` moves off a spot
   that a reach for a block the person takes soon crosses, and a picked block whose spot a
   reach crosses is held at its pick pose until no reach does (``delivery_held``,
   ``delivery_resumed``; the goal stays the pick pose, so an arm that picks on the move
   stops there rather than turning back). A goal change starts a replanning cycle at once
   (``replan_on_goal_change``; the new plan still takes over ``m`` later, as every plan).

The progress state given to the predictor is the bitmask of the human's completed ``Take_i``
over the predictor's actions (``reach_<i>``: delivery spot ``i`` is reaching target ``i``).
With ``mask_unavailable_actions`` (default) the forecast is also conditioned on the task state
the robot knows: taking a block that is not on its delivery spot gets weight 0
(:func:`action_mask`, :meth:`Forecast.mask_actions`); an idle person who waits for block ``i``
is then not predicted to reach for the empty spot ``i`` the robot must deliver to. With
``mask_by_order`` (default) a block on its spot that the task order does not let the person
take yet counts as unavailable too. With ``rest_when_nothing_available`` (default), when no
block is available to the person at all, the ``idle`` action's forecast is held at its first
frame (:meth:`Forecast.hold_actions`): the spread that the idle forecast learns from
demonstrations is the chance that a reach starts within the horizon, and no reach can start
then. Alone, before the other two settings, it cut the I-Planner's waits (iiwa, 20 seeds of 7
scenarios: fewer in 5 of 7, still no contact) without a gain in efficiency, and it made the
Fetch arm less safe (contact-free in 60 instead of 66 of 70 episodes); the three together
(``task_crossing_radius`` below) left the iiwa without contact in 140 of 140 table episodes
and the Fetch arm in 139 of 140 (138 before), at an efficiency of 1.64-1.83; with the
replanner's emergency check past the hand-over (``ReplannerCfg.emergency_ahead_s``) both arms
in 140 of 140 (``experiments/safety_seeds/README.md``).
With ``reaction_s`` (off by default; 0.3 s is the lower end of a person's choice reaction
time, the scripted person reacts after 0.4 s: ``HumanCfg.reaction_s``), while the person's
tracked hands rest (:func:`hands_still`), the forecast of taking a block that the robot put on
its spot less than ``reaction_s`` ago is delayed to start when that time is up
(:func:`reaction_delays`, :meth:`Forecast.delay_actions`): the predictor, which sees only the
resting hands, predicts the reach to start at once, and the arm leaving the spot it just
delivered to swerves from a hand that cannot be there yet. At 0.3 s the I-Planner NI in
``reach_across`` was smoother in 17 of 20 seeds (21.0 against 22.7), but in the table's
arrangement_2x2 rougher in 16 of 20 (29.8 against 25.9): in seed 2 there the arm went on
with its next fetch close to the spot it had just delivered to and swerved round the reach
once the forecast showed it (a plan is checked over its execution window only). So it is an
option (``experiments/reach_across/README.md``, ``experiments/safety_seeds/README.md``).
A predicting planner can wait for a reach the person never starts, e.g. for a delivered
block the person leaves on its spot while waiting for another one; the person then waits for
the robot. When ``stall_fallback_s`` (5 s) pass without task progress while the person's
tracked hands stay still and the robot waits, :class:`StallWatch` reports a stall (task event
``stall_fallback``) and the planner plans against the observed pose held still, as ITOMP
does, until the hands move or the task progresses (``plan/stall_cycles`` counts those cycles;
their forecasts are neither scored by ``eval/mhd`` nor logged as forecasts).
ITOMP plans against ``static_human_forecast`` of the latest tracked pose; both forecasts start
at the time of the last tracker frame (``forecast_t0``), and the optimiser samples them at the
waypoint times of the plan's execution window ``[t + m, t + 2m]``.

The ``oracle`` planner is the I-Planner's optimiser given the person's true future
(:func:`oracle_forecast`: the script run ahead on a copy, no tracker, no noise) and the
person's own task order: an upper bound on what better prediction could give, for comparing
planners rather than a planner a robot could run. Its ``eval/mhd`` measures how far that
future was off (only a block delivered within the span changes it).

The ``blind`` planner is the other reference: ITOMP's optimiser with no person at all (no
forecast, so no human cost, no confidence limit and no wait for the person), fetching as ITOMP
does. The person still moves and still counts for contacts and distances. How far the other
planners are from it shows how much the person is in the robot's way in a scene: a planner
that is as smooth as ``blind`` has no roughness that better prediction could remove.

The ``iplanner_cv`` planner is the I-Planner's optimiser given a constant-velocity forecast
of the tracked joints (:class:`~iplanner_torch.prediction.constant_velocity.\
ConstantVelocityPredictor`, ``EpisodeCfg.cv``): motion extrapolated, no learned actions, so
it chooses its fetches as ITOMP does. Between ITOMP (the seen pose held still) and the
I-Planner (learned actions and motions), it shows how much of the I-Planner's difference comes
from forecasting motion at all.

Torch runs with ``torch_threads`` threads during the episode (restored afterwards): the
planner's tensors are small, so one thread avoids the thread-pool overhead that dominates them
on a few cores.

Metrics (keys ``stage/name``): :func:`iplanner_torch.eval.metrics.episode_metrics` on the
measured joint trajectory and on sphere models of the robot and the true human, sampled at
``metrics_hz`` (``eval/smoothness`` and ``eval/jerkiness`` are NaN for an episode too short to
give 3 samples); plus

* ``eval/mhd``: mean over forecasts of the MHD between the predicted mean path of the moving
  hand and its true path over the next ``mhd_horizon_s`` (1 s); a forecast counts when that
  hand moves at least ``mhd_min_motion`` in that second (the hand that moves more);
* ``eval/efficiency`` (paper sec. 7; > 1: the pair finishes sooner than the human alone):
  the human-alone time (:meth:`ScriptedHuman.solo_duration`: the human's own reaches to every
  far position and to every delivery spot, plus mean idles, generated by the same motion
  source) divided by the time until the human took the last block; NaN when unfinished;
* ``sim/contacts`` / ``sim/contact_steps``: robot-human contacts from MuJoCo (onsets / control
  periods in contact); ``sim/body_distance``: the closest the robot's geoms came to the
  person's capsules [m] (MuJoCo's own geometry at the end of every control period, capped at
  1 m; < 0: overlap), where ``eval/min_distance`` is between the sphere models;
* ``plan/*``: replanning cycles, overruns, waits, evasions (no safe trajectory and holding
  riskier than moving: ``PlanResult.evasive``), escapes (the evasions that stepped out of the
  way: ``PlanResult.escape``), solve times and the solves cut short at their budget
  (``plan/cut_short``, with ``ReplannerCfg.stop_at_budget``; else 0);
* ``forecast/spread_scale_mean`` / ``_max`` (with ``spread_tolerance`` only): the factor the
  spread calibration multiplied the planner's forecast variances by, over the cycles.

The planner ``oracle`` in the blocking scenario may be made causal (``oracle_onset_delay_s``):
it then learns of the arm's block only that long after the arm starts, and until then plans on
the person held still at the true pose of each cycle.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import torch
from tqdm.auto import tqdm

from iplanner_torch.checks import (
    MAX_SEED,
    finite,
    flag,
    integer,
    is_real,
    non_negative,
    optional,
    positive,
)
from iplanner_torch.collision.human_spheres import HumanSphereMap
from iplanner_torch.data.skeleton import JOINT_INDEX, JOINT_NAMES
from iplanner_torch.errors import ConfigError, DataWarning, ShapeError
from iplanner_torch.eval import metrics as M
from iplanner_torch.planning.itomp import path_forecast, static_human_forecast
from iplanner_torch.planning.replanner import PlannerCfg, build_replanner
from iplanner_torch.prediction.calibration import CalibrationCfg, SpreadCalibrator
from iplanner_torch.prediction.constant_velocity import (
    ConstantVelocityCfg,
    ConstantVelocityPredictor,
)
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.sim.env import SimCfg, SimEnv
from iplanner_torch.sim.human import MotionSource, ReachingMotionSource, ScriptedHuman
from iplanner_torch.sim.scene import SceneCfg
from iplanner_torch.sim.tasks import ScenarioCfg, group_ranks, next_feasible, parse_order
from iplanner_torch.sim.tracker import Tracker
from iplanner_torch.types import torch_threads

#: Joint indices of the hands: the joints the forecasts are scored and logged on.
HAND_JOINTS: list[int] = [JOINT_INDEX["left_hand"], JOINT_INDEX["right_hand"]]

PlannerKind = Literal["itomp", "iplanner_no_ni", "iplanner_ni", "iplanner_cv", "oracle", "blind"]
#: how far the tool point may end from a blocking scenario's crossing start or goal [m]
CROSSING_TOLERANCE_M = 0.02

#: Planner kinds and the predictor variant each one reads (None: no predictor).
PLANNER_KINDS: dict[str, str | None] = {
    "itomp": None,
    "iplanner_no_ni": "no_ni",
    "iplanner_ni": "ni",
    "iplanner_cv": "cv",
    "oracle": None,
    "blind": None,
}
#: The predictor variants read from trained checkpoints (``cv`` is built from
#: ``EpisodeCfg.cv``).
CHECKPOINT_VARIANTS: tuple[str, ...] = ("no_ni", "ni")
#: The ``PlannerCfg.kind`` of the planners that are not I-Planners (``blind`` runs ITOMP's
#: optimiser, given no forecast).
_OPTIMIZER_KIND: dict[str, str] = {"itomp": "itomp", "oracle": "oracle", "blind": "itomp"}


class PredictorLike(Protocol):
    """What the loop needs of :class:`iplanner_torch.prediction.predictor.HumanMotionPredictor`
    (the README's "Another predictor model" spells the contract out).

    The loop calls :meth:`predict_positions` with B = 1 and the K joints of
    :data:`~iplanner_torch.data.skeleton.JOINT_NAMES` in that order, and checks the forecast
    (:func:`check_predicted`): batch 1, those joints in that order, at least one frame, the
    object's ``action_names`` when it names them. Read when present: ``n_prev`` / ``n_p``
    (window frames, :func:`_predictor_window`), ``fps`` (:func:`check_predictor_rate`),
    ``joint_names`` (:func:`check_predictor_joints`), ``action_names`` and ``next_action``
    (:func:`predictor_task_policy`). A forecast shorter than the plans' reach is warned about
    once an episode (:func:`warn_short_horizon`).
    """

    def predict_positions(self, positions: torch.Tensor, progress: torch.Tensor) -> Forecast:
        """(B, n_p, K, 3) tracked positions [m], table frame, NaN where lost; (B,) int64
        bitmask of the completed actions (``ScriptedHuman.progress_bitmask``) -> Forecast
        whose frame ``f`` lies ``(f + 1) dt`` after the last tracked frame."""
        ...


class ReplannerLike(Protocol):
    """What the loop needs of :class:`iplanner_torch.planning.replanner.Replanner`."""

    stats: Any

    def reset(self, q_start: torch.Tensor, q_goal: torch.Tensor, t: float) -> None: ...

    def set_goal(self, q_goal: torch.Tensor, t: float | None = None) -> None: ...

    def step(
        self, t: float, q_now: torch.Tensor, forecast: Forecast | None, *, forecast_t0: float
    ) -> Any: ...

    def command(self, t: float) -> tuple[torch.Tensor, torch.Tensor]: ...


#: task_policy(taken ids, delivered-or-fetched ids) -> next block id or None.
TaskPolicy = Callable[[set[int], set[int]], "int | None"]


@dataclass(frozen=True, kw_only=True)
class EpisodeCfg:
    """One closed-loop episode."""

    # arrangement, task order, confidence (or the blocking scenario)
    scenario: ScenarioCfg = field(default_factory=ScenarioCfg)
    # rates, tracker, human behaviour, delivery tolerances
    sim: SimCfg = field(default_factory=SimCfg)
    # the motion planner; its kind, predictor variant and confidence are set per episode
    planner: PlannerCfg = field(default_factory=PlannerCfg)
    # simulated seconds after which the episode stops unfinished
    max_duration_s: float = 90.0
    # ITOMP's static forecast and the oracle's true one: frames and spacing [s]
    static_forecast_frames: int = 30
    static_forecast_dt: float = 0.1
    # per-coordinate standard deviation of the oracle's forecast [m]
    oracle_std: float = 0.01
    # planner ``iplanner_cv``: its constant-velocity forecast (fit, horizon, spread)
    cv: ConstantVelocityCfg = field(default_factory=ConstantVelocityCfg)
    # MHD horizon [s] and the hand motion below which a forecast is not scored [m]
    mhd_horizon_s: float = 1.0
    mhd_min_motion: float = 0.05
    # sampling rate of the metric trajectories (smoothness, distance) [Hz]
    metrics_hz: float = 25.0
    # rate of the robot state and true human joints in the MCAP log [Hz], as a whole number
    # of control steps; None: metrics_hz, so the log holds the very samples the smoothness,
    # jerkiness and closest distance are computed from (the episode's log metadata records
    # both rates); the tracked joints are logged frame by frame at the tracker's own times
    log_hz: float | None = None
    # rate of the log's 3D scene (/scene: robot and human spheres, the latest forecast's
    # joint ellipsoids at SCENE_HORIZONS_S) for Foxglove's 3D panel [Hz], as a whole number of
    # control steps, as log_hz (40 Hz at 0.01 s: every 2nd step, 50 Hz); 0: none
    scene_hz: float = 5.0
    # blocking scenario: seconds the episode runs after the robot reached its goal
    blocking_tail_s: float = 0.5
    # show a progress bar over simulated time
    progress_bar: bool = False
    # torch threads during the episode (restored after); None leaves torch's setting
    torch_threads: int | None = 1
    # after a delivery, go straight to the next block (home only when none remains)
    direct_next_fetch: bool = True
    # a goal change (task event) starts a replanning cycle at once instead of at the next tick
    replan_on_goal_change: bool = True
    # Q-learning episodes of the task planner built from the predictor's next-action model
    task_planner_episodes: int = 300
    # task-state conditioning of the forecast: the weight of taking a block that is not on its
    # delivery spot (not delivered yet, or already taken) is set to 0 (:func:`action_mask`)
    mask_unavailable_actions: bool = True
    # with the mask on and no block available to the person, hold the idle action's forecast
    # at its first frame: a person with nothing to take is predicted to stay at rest (on by
    # default with mask_by_order and task_crossing_radius since they came together; alone,
    # before them, it made the Fetch arm less safe: see the module docstring)
    rest_when_nothing_available: bool = True
    # with the mask on, a block on its spot that the task order does not let the person take
    # yet counts as unavailable too (the robot knows the order: the person takes 6 only after
    # 1 in 4->0->5->1->6); False: every block on its spot is available
    mask_by_order: bool = True
    # stall fallback of the predicting planners (:class:`StallWatch`): after this many seconds
    # without task progress, with waits, during which the person's tracked hands stayed
    # still, plan against the observed pose held still (ITOMP's forecast) until the hands
    # move or the task progresses; None: never
    stall_fallback_s: float | None = 5.0
    # hands whose tracked position (mean of the last 0.5 s) stays within this distance, per
    # coordinate, of where it was count as still [m]
    still_radius: float = 0.08
    # the person's reaches in the predicting planners' task choice (I-Planner, oracle): a
    # reach is the straight line, seen from above, from the person's tracked shoulder to a
    # block the person takes soon (one on its delivery spot, or in the person's hand), and a
    # delivery spot within this distance of it [m] is crossed. The robot does not fetch a
    # block whose spot is crossed when a block of the same or the next group of the task
    # order is not (:func:`defer_crossed_fetch`, metric task/deferred_fetches), and holds a
    # block it has picked at its pick pose while its spot is crossed and the person has a
    # take under way or a block to take (task events delivery_held and delivery_resumed,
    # metric task/held_s); None: off (the paper; the
    # three settings together: experiments/reach_across/ and experiments/safety_seeds/)
    task_crossing_radius: float | None = 0.1
    # the person's least reaction time, a prior of the predicting planners [s]: with the mask
    # on and the tracked hands at rest, the forecast of taking a block that landed on its
    # spot less than this long ago is delayed until then (:func:`reaction_delays`,
    # :meth:`Forecast.delay_actions`), since a resting person cannot start that reach
    # sooner; 0.3 s is below the scripted person's own (``HumanCfg.reaction_s``, 0.4 s) and
    # the lower end of a choice reaction. None or 0: off (the default: smoother in
    # reach_across, rougher in arrangement_2x2; see the module docstring)
    reaction_s: float | None = None
    # online calibration of the predicting planners' forecast spread
    # (:class:`~iplanner_torch.prediction.calibration.SpreadCalibrator`): each forecast is
    # scored on the tracked frames that follow it, and while the last ``spread_memory_s``
    # of them missed by more than this mean normalised squared error (1: calibrated), the next
    # forecast's variances are multiplied by the excess, at most ``spread_max_scale``; None:
    # off (the predictor's variances as they are). Metrics forecast/spread_scale_mean, _max.
    spread_tolerance: float | None = None
    spread_memory_s: float = 1.0
    spread_max_scale: float = 16.0
    # blocking scenario, planner ``oracle``: the oracle learns of the arm's block only this
    # long after the arm started [s] (the event ``blocking_started``); until then it forecasts
    # the person held at the true pose of now, as a perfect but causal predictor that needs
    # this long to recognise the motion would. None: it knows from the start (the oracle)
    oracle_onset_delay_s: float | None = None

    def __post_init__(self) -> None:
        for name, kind in (
            ("scenario", ScenarioCfg),
            ("sim", SimCfg),
            ("planner", PlannerCfg),
            ("cv", ConstantVelocityCfg),
        ):
            if not isinstance(getattr(self, name), kind):
                raise ConfigError(
                    f"expected {name} a {kind.__name__}, got {type(getattr(self, name)).__name__}"
                )
        # NaN fails too (inf: until the tasks are done)
        if not is_real(self.max_duration_s) or not self.max_duration_s > 0:
            raise ConfigError(f"expected max_duration_s > 0, got {self.max_duration_s!r}")
        period = self.sim.substeps * self.sim.physics_dt  # one control step [s]
        if self.max_duration_s < period:  # the loop would not simulate a single step
            raise ConfigError(
                f"expected max_duration_s at least one control period ({period:g} s at "
                f"sim.control_hz={self.sim.control_hz:g}), got {self.max_duration_s!r}"
            )
        # each number by name; NaN and infinities fail (a bare "x <= 0" passes NaN)
        integer("static_forecast_frames", self.static_forecast_frames, minimum=1)
        positive("static_forecast_dt", self.static_forecast_dt)
        positive("oracle_std", self.oracle_std)
        positive("mhd_horizon_s", self.mhd_horizon_s)
        non_negative("mhd_min_motion", self.mhd_min_motion)
        positive("metrics_hz", self.metrics_hz)
        if self.log_hz is not None:
            positive("log_hz", self.log_hz)
        non_negative("scene_hz", self.scene_hz)
        non_negative("blocking_tail_s", self.blocking_tail_s)
        optional(integer, "torch_threads", self.torch_threads, minimum=1)
        integer("task_planner_episodes", self.task_planner_episodes, minimum=0)
        for name in (
            "progress_bar",
            "direct_next_fetch",
            "replan_on_goal_change",
            "mask_unavailable_actions",
            "rest_when_nothing_available",
            "mask_by_order",
        ):
            flag(name, getattr(self, name))
        stall = self.stall_fallback_s
        if stall is not None and (not is_real(stall) or not stall > 0):  # inf: never, as None
            raise ConfigError(f"expected stall_fallback_s > 0 or None, got {stall!r}")
        positive("still_radius", self.still_radius)
        optional(non_negative, "task_crossing_radius", self.task_crossing_radius)
        optional(non_negative, "reaction_s", self.reaction_s)
        optional(positive, "spread_tolerance", self.spread_tolerance)
        positive("spread_memory_s", self.spread_memory_s)
        optional(non_negative, "oracle_onset_delay_s", self.oracle_onset_delay_s)
        if self.oracle_onset_delay_s is not None and self.scenario.kind != "blocking":
            raise ConfigError(
                "oracle_onset_delay_s applies to the blocking scenario (scenario.kind=blocking), "
                f"got it with scenario.kind={self.scenario.kind}"
            )
        if not finite("spread_max_scale", self.spread_max_scale) >= 1.0:
            raise ConfigError(f"expected spread_max_scale >= 1, got {self.spread_max_scale!r}")

    def calibration_cfg(self) -> CalibrationCfg | None:
        """The spread calibration's settings, or None when it is off."""
        if self.spread_tolerance is None:
            return None
        return CalibrationCfg(
            tolerance=self.spread_tolerance,
            memory_s=self.spread_memory_s,
            max_scale=self.spread_max_scale,
        )

    def scene_cfg(self) -> SceneCfg:
        """The workspace of the scenario."""
        return SceneCfg(arrangement=self.scenario.arrangement)


@dataclass(kw_only=True)
class EpisodeResult:
    """What one episode produced.

    Attributes:
        metrics: ``stage/name`` -> value (module docstring).
        mcap_path: the episode log, or None.
        events: (time [s], kind, block) of every task event.
        planner_kind: the planner that ran.
        seed: the episode seed.
    """

    metrics: dict[str, float]
    mcap_path: Path | None
    events: list[tuple[float, str, int]]
    planner_kind: str
    seed: int


class StallWatch:
    """Tells when a predicting planner waits for a person who stays still: a stall.

    Forecasts can keep giving weight to a reach the person never starts: for a block the
    person leaves on its spot while waiting for another one, the classifier sees a person at
    rest, like the start of every reach, and the forecast knows nothing of how long the
    person has sat still. The robot then waits (and creeps between waits) for the reach, and
    the person waits for the robot. When ``after_s`` seconds have passed without task progress
    (a pick, delivery or take) while the person's hands stayed within ``radius`` (per
    coordinate) of where they were, and the robot waited at least once in that time, the watch
    reports a stall, and keeps reporting it until the hands move or the task progresses; the
    episode then plans against the observed pose held still, as ITOMP does
    (``EpisodeCfg.stall_fallback_s``).

    Args:
        after_s: seconds of stillness without progress before a stall [s].
        radius: per-coordinate distance the hands may drift and still count as still [m].
    """

    def __init__(self, after_s: float, radius: float) -> None:
        if not (after_s > 0 and radius > 0):
            raise ConfigError(f"expected after_s > 0 and radius > 0, got {after_s}, {radius}")
        self.after_s = float(after_s)
        self.radius = float(radius)
        self._ref: np.ndarray | None = None
        self._still_since = 0.0
        self._progress_at = 0.0
        self._waited_at = -math.inf
        self.active = False

    def observe_person(self, t: float, hands: np.ndarray) -> None:
        """The person's tracked hands at ``t``: (H, 3) [m]; NaN (not tracked) ends stillness."""
        hands = np.asarray(hands, dtype=np.float64)
        lost = not np.isfinite(hands).all()
        moved = self._ref is None or bool(np.abs(hands - self._ref).max() > self.radius)
        if lost or moved:
            self._ref = None if lost else hands.copy()
            self._still_since = float(t)
            self.active = False

    def observe_progress(self, t: float) -> None:
        """A task event at ``t`` (pick, delivery, take): the robot is not stuck."""
        self._progress_at = float(t)
        self.active = False

    def observe_plan(self, t: float, waited: bool) -> None:
        """Whether the cycle at ``t`` ended in a wait (no trajectory met the constraint)."""
        if waited:
            self._waited_at = float(t)

    def stalled(self, t: float) -> bool:
        """Whether the planner at ``t`` should plan against the held pose."""
        if not self.active and self._ref is not None:
            since = max(self._still_since, self._progress_at)
            self.active = t - since >= self.after_s - 1e-9 and self._waited_at >= since
        return self.active


def tracked_hands(window: np.ndarray, frames: int) -> np.ndarray:
    """(2, 3) mean of the last ``frames`` tracked positions of both hands (NaN frames left
    out; NaN when a hand has no frame) from a tracker window (T, K, 3)."""
    hands = np.asarray(window)[-frames:, HAND_JOINTS]
    ok = np.isfinite(hands).all(-1)  # (frames, 2)
    total = np.where(ok[..., None], hands, 0.0).sum(0)
    count = ok.sum(0)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


class TableClearance:
    """Signed distance of spheres to the table top (a box below z = 0), for the planner.

    Spheres within ``base_radius`` (horizontal) of the robot base are ignored: the base stands
    on the table.

    Args:
        scene: the workspace.
        base_xy: (2,) robot base position [m].
        base_radius: horizontal radius around the base that is not checked [m].
    """

    def __init__(self, scene: SceneCfg, base_xy: np.ndarray, base_radius: float = 0.3) -> None:
        self.lo = np.array(
            [scene.table_center_x - 0.5 * scene.table_size[0], -0.5 * scene.table_size[1], -0.04]
        )
        self.hi = np.array(
            [scene.table_center_x + 0.5 * scene.table_size[0], 0.5 * scene.table_size[1], 0.0]
        )
        self.base_xy = np.asarray(base_xy, dtype=np.float64)[:2]
        self.base_radius = float(base_radius)

    def clearance(self, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        """(..., S, 3) centres [m], (S,) radii [m] -> (..., S) signed distance [m]."""
        lo = torch.as_tensor(self.lo, dtype=centers.dtype, device=centers.device)
        hi = torch.as_tensor(self.hi, dtype=centers.dtype, device=centers.device)
        outside = torch.maximum(lo - centers, centers - hi).clamp_min(0.0).norm(dim=-1)
        inside = torch.minimum(centers - lo, hi - centers).min(dim=-1).values.clamp_min(0.0)
        dist = outside - inside - radii
        base = torch.as_tensor(self.base_xy, dtype=centers.dtype, device=centers.device)
        near_base = (centers[..., :2] - base).norm(dim=-1) < self.base_radius
        return torch.where(near_base, torch.full_like(dist, 10.0), dist)


def held_window(tracker: Any) -> np.ndarray:
    """The tracker's window (n_p, K, 3) [m] with every joint lost in all of its frames held at
    its last observation (``tracker.latest_pose()``); joints lost in some frames stay NaN for
    the predictor's interpolation.

    A joint the tracker lost for the whole window (a run of dropouts, or the first frames of an
    episode) would otherwise borrow a neighbouring joint's trajectory; held where it was last
    seen, it keeps the person's arm where it was.
    """
    win = tracker.window()  # a new array (np.stack)
    lost = ~np.isfinite(win).all(-1).any(0)  # (K,)
    if lost.any():
        win[:, lost] = np.asarray(tracker.latest_pose(), dtype=win.dtype)[lost]
    return win


def _predictor_window(predictor: object, default: int) -> int:
    """The frames a predictor forecasts from (``n_prev``, or ``n_p`` of a stand-in), else
    ``default`` (``sim.tracker_window``)."""
    for owner in (predictor, getattr(predictor, "cfg", None)):
        for attr in ("n_prev", "n_p"):
            n = getattr(owner, attr, None)
            if isinstance(n, int) and not isinstance(n, bool) and n > 0:
                return n
    return default


def check_predictor_rate(predictor: object, tracker_fps: float) -> None:
    """Refuse a tracker rate other than the one a predictor was trained at.

    Its windows are ``n_prev`` frames at its ``fps``; fed another rate it forecasts from a
    window of another duration and steps its forecast at the wrong ``dt``, without error.

    Raises:
        ConfigError: when the predictor states an ``fps`` that differs from ``tracker_fps``.
    """
    fps = getattr(predictor, "fps", None)
    if isinstance(fps, (int, float)) and not isinstance(fps, bool):
        if not math.isclose(float(fps), float(tracker_fps), rel_tol=1e-6):
            raise ConfigError(
                f"sim.tracker_fps={tracker_fps:g}, but the predictor was trained on "
                f"{float(fps):g} Hz frames: set sim.tracker_fps={float(fps):g}, or train it "
                "on data at the tracker's rate"
            )


def check_predictor_joints(predictor: object) -> None:
    """Refuse a predictor of other joints than the simulated person's.

    The closed loop feeds the predictor the tracked frames of every joint of
    :data:`~iplanner_torch.data.skeleton.JOINT_NAMES` and needs a forecast of each; one
    trained on a subset (``data.windows.joints``) or on another skeleton (the LEGO
    recording's arm joints) would fail only at the episode's first forecast. A predictor that
    names no ``joint_names`` (a custom one) is checked on its forecasts instead
    (:func:`check_predicted`).

    Raises:
        ConfigError: when the predictor's ``joint_names`` differ from ``JOINT_NAMES``.
    """
    names = getattr(predictor, "joint_names", None)
    if isinstance(names, tuple | list) and tuple(names) != tuple(JOINT_NAMES):
        raise ConfigError(
            f"the predictor forecasts the joints {list(names)}, but the simulated person "
            f"has the {len(JOINT_NAMES)} joints {list(JOINT_NAMES)}, each of which the "
            "closed loop forecasts: train it on data of that skeleton with every joint "
            "(data.windows.joints=null)"
        )


def _action_names(predictor: object) -> tuple[str, ...]:
    for owner in (predictor, getattr(predictor, "cfg", None)):
        names = getattr(owner, "action_names", None)
        if names:
            return tuple(names)
    return ()


def check_predicted(forecast: object, action_names: tuple[str, ...]) -> Forecast:
    """The forecast a predictor's ``predict_positions`` returned for one window, checked
    against what the loop needs: a :class:`Forecast` of batch 1, of every joint of
    :data:`~iplanner_torch.data.skeleton.JOINT_NAMES` in that order, at least one frame, and
    the predictor's actions (``action_names``, when it names them).

    Raises:
        ShapeError: naming what differs (a custom predictor's forecast of other joints, no
            frame, other actions, or not a Forecast at all).
    """
    if not isinstance(forecast, Forecast):
        raise ShapeError(
            f"the predictor's predict_positions returned a {type(forecast).__name__}, "
            "expected a Forecast (iplanner_torch.prediction.forecast)"
        )
    problems = []
    if forecast.batch_size != 1:
        problems.append(f"batch {forecast.batch_size} for one window")
    if tuple(forecast.joint_names) != tuple(JOINT_NAMES):
        problems.append(
            f"joints {list(forecast.joint_names)}, expected the {len(JOINT_NAMES)} of "
            f"JOINT_NAMES {list(JOINT_NAMES)}"
        )
    if forecast.horizon < 1:
        problems.append("no predicted frame (n_f = 0)")
    if action_names and tuple(forecast.action_names) != tuple(action_names):
        problems.append(
            f"actions {list(forecast.action_names)}, but the predictor names {list(action_names)}"
        )
    if problems:
        raise ShapeError(f"the predictor's forecast has {'; '.join(problems)}")
    return forecast


def warn_short_horizon(forecast: Forecast, replan_step_s: float) -> bool:
    """Warn (:class:`~iplanner_torch.errors.DataWarning`) when a forecast ends before the
    plans it serves are checked to: a plan's execution window ends up to ``2 m`` after the
    forecast's last observed frame (``m = replan_step_s``), and past its last frame the
    person is held there (:func:`~iplanner_torch.planning.costs.forecast_to_obstacle`), which is
    not conservative. The shipped predictors forecast 1 s, as long as ``2 m`` at m = 0.5 s.

    Returns:
        Whether it warned.
    """
    covered = forecast.horizon * forecast.dt
    if covered >= 2.0 * replan_step_s - 1e-9:
        return False
    warnings.warn(
        f"the predictor forecasts {forecast.horizon} frames of {forecast.dt:g} s "
        f"({covered:.3g} s), less than the {2.0 * replan_step_s:g} s (2 x replan_step_s) the "
        "plans are checked over: past its last frame the person is taken to stay there, which "
        "is not conservative; forecast further ahead",
        DataWarning,
        stacklevel=2,
    )
    return True


def action_mask(action_names: tuple[str, ...], available: set[int]) -> torch.Tensor:
    """(A,) bool: False for ``take_<i>`` / ``reach_<i>`` actions whose block ``i`` is not
    available to the human (not on its delivery spot and not in the human's hand); other
    actions (``idle``) stay possible.

    The scripted human, like a person, only reaches for a block that lies on its spot; without
    this the forecast of an idle human who waits for block ``i`` keeps predicting the reach to
    spot ``i``, and the robot that should deliver it waits for a reach that cannot start.
    """
    keep = []
    for name in action_names:
        block = _take_block(name)
        keep.append(block is None or block in available)
    return torch.tensor(keep, dtype=torch.bool)


def available_blocks(
    on_spot: set[int], in_hand: set[int], order: Any | None, taken: set[int]
) -> set[int]:
    """The blocks the person may take now, for :func:`action_mask`.

    Args:
        on_spot: blocks that lie on their delivery spots.
        in_hand: blocks in the person's hand (their take goes on).
        order: the task order (``allowed_next(taken)``), or None: every block on its spot.
        taken: blocks the person has taken.

    Returns:
        ``in_hand`` and the blocks on their spots that ``order`` lets the person take next.
    """
    if order is None:
        return set(on_spot) | set(in_hand)
    return (set(on_spot) & set(order.allowed_next(set(taken)))) | set(in_hand)


def rest_hold(action_names: tuple[str, ...], keep: torch.Tensor) -> torch.Tensor:
    """(A,) bool: the ``idle`` action when ``keep`` (from :func:`action_mask`) rules out every
    ``take_<i>`` / ``reach_<i>`` action, else all False (see ``rest_when_nothing_available``)."""
    takes = [_take_block(n) is not None for n in action_names]
    nothing = any(takes) and not any(bool(k) for k, t in zip(keep.tolist(), takes) if t)
    return torch.tensor([nothing and n.lower() == "idle" for n in action_names], dtype=torch.bool)


def reaction_delays(
    action_names: tuple[str, ...],
    available: set[int],
    landed: Mapping[int, float],
    t_obs: float,
    reaction_s: float,
    dt: float,
) -> torch.Tensor:
    """(A,) int64 frames by which each action's forecast is delayed (see ``reaction_s``).

    A resting person cannot start to take block ``i`` sooner than ``reaction_s`` after it
    landed on its spot at ``landed[i]``: ``take_<i>`` / ``reach_<i>`` is delayed by the whole
    frames of ``dt`` left until then after ``t_obs`` (rounded down: never more than the time
    left). ``idle``, whose spread is the chance that a reach starts, is delayed by the least
    delay of the available blocks' actions, so by none when one of them landed long enough
    ago, or has no landing time (it lay there from the start, or is in the person's hand).
    Actions of blocks that are not ``available`` keep 0 (their weight is masked anyway).

    Args:
        action_names: the forecast's A action names.
        available: the blocks the person may take now (:func:`available_blocks`).
        landed: block -> time it landed on its delivery spot [s].
        t_obs: time of the forecast's last observed frame [s].
        reaction_s: the person's least reaction time [s], >= 0.
        dt: seconds between predicted frames, > 0.
    """
    left: dict[int, float] = {
        b: max(0.0, reaction_s - (t_obs - landed[b])) if b in landed else 0.0 for b in available
    }
    frames = [0] * len(action_names)
    takes = []
    for a, name in enumerate(action_names):
        block = _take_block(name)
        if block is not None and block in left:
            frames[a] = math.floor(left[block] / dt + 1e-9)
            takes.append(frames[a])
    if takes:
        for a, name in enumerate(action_names):
            if name.lower() == "idle":
                frames[a] = min(takes)
    return torch.tensor(frames, dtype=torch.int64)


#: the tracked hands rest (``reaction_s``) when the mean of each over the later half of the
#: last REST_WINDOW_S [s] lies within REST_RADIUS_M [m] of its mean over the earlier half
REST_WINDOW_S = 0.3
REST_RADIUS_M = 0.03


def hands_still(window: np.ndarray, frames: int, radius: float) -> bool:
    """Whether both tracked hands rest: over the last ``frames`` frames of a tracker window
    (T, K, 3), the mean position of each hand in the later half lies within ``radius`` [m],
    per coordinate, of the mean in the earlier half (means, so that tracker noise does not
    read as motion). A NaN (dropped) hand frame, or fewer than 2 frames, counts as moving."""
    hands = np.asarray(window)[-frames:, HAND_JOINTS]  # (f, 2, 3)
    if hands.shape[0] < 2 or not bool(np.isfinite(hands).all()):
        return False
    half = hands.shape[0] // 2
    shift = np.abs(hands[half:].mean(0) - hands[:half].mean(0))
    return bool(shift.max() < radius)


#: Look-ahead times [s] of the predicted joint ellipsoids drawn in the log's ``/scene``.
SCENE_HORIZONS_S = (0.5, 1.0)


def forecast_ellipsoids(
    forecast: Forecast, horizons_s: tuple[float, ...] = SCENE_HORIZONS_S
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The predicted position of every joint at each look-ahead, as one Gaussian each.

    The action mixture of batch entry 0 is moment-matched per joint: mean ``sum_a w_a mu_a``
    and covariance ``sum_a w_a (diag(var_a) + (mu_a - mean)(mu_a - mean)^T)``, at the
    predicted frame nearest to each look-ahead (looks beyond the horizon are left out).

    Args:
        forecast: the forecast (batch entry 0 is drawn).
        horizons_s: seconds after the forecast's last observed frame.

    Returns:
        ``(mean (3,) [m], cov (3, 3) [m^2])`` pairs, joint-major within each look-ahead.
    """
    times = forecast.times.detach().cpu().double()  # (n_f,)
    w = forecast.weights[0].detach().cpu().double()  # (A,)
    out = []
    for h in horizons_s:
        if h > float(times[-1]) + 0.5 * forecast.dt:
            continue
        f = int((times - h).abs().argmin())
        mu = forecast.mean[0, :, f].detach().cpu().double()  # (A, K, 3)
        var = forecast.var[0, :, f].detach().cpu().double().clamp_min(0.0)
        mean = torch.einsum("a,akc->kc", w, mu)  # (K, 3)
        d = mu - mean  # (A, K, 3)
        cov = torch.einsum("a,akc,akd->kcd", w, d, d) + torch.diag_embed(
            torch.einsum("a,akc->kc", w, var)
        )  # (K, 3, 3)
        out.extend((mean[k].numpy(), cov[k].numpy()) for k in range(mean.shape[0]))
    return out


def _log_scene(
    writer: Any,
    t: float,
    robot: Any,
    q: np.ndarray,
    smap: HumanSphereMap,
    joints: np.ndarray,
    ellipsoids: list[tuple[np.ndarray, np.ndarray]],
) -> None:
    """One ``/scene`` message: the robot's spheres at ``q`` (J,), the person's spheres from
    the true ``joints`` (K, 3), and the predicted joint ``ellipsoids``."""
    from iplanner_torch.recording.mcap import SceneEllipsoid

    ref = robot.q_home
    with torch.no_grad():
        rc = robot.sphere_centers(torch.as_tensor(q, dtype=ref.dtype, device=ref.device))
    rs = torch.cat([rc.cpu().double(), robot.sphere_radii.cpu().double().unsqueeze(-1)], -1)
    hc = smap.centers(torch.as_tensor(joints, dtype=torch.float64))  # (S_h, 3)
    hs = torch.cat([hc, smap.radii.double().unsqueeze(-1)], -1)
    writer.scene(t, rs, hs, [SceneEllipsoid(mean=m, cov=c) for m, c in ellipsoids])


def _take_block(name: str) -> int | None:
    """The block id ``i`` of a ``take_<i>`` / ``reach_<i>`` action (any case), else None."""
    head, _, tail = name.lower().rpartition("_")
    return int(tail) if head in ("take", "reach") and tail.isdigit() else None


def oracle_forecast(
    human: ScriptedHuman,
    delivered: set[int],
    t0: float,
    n_f: int,
    dt: float,
    *,
    step_s: float,
    std: float,
    like: torch.Tensor,
) -> Forecast:
    """The person's true future as a forecast: one action of weight 1 whose mean is
    :meth:`ScriptedHuman.preview` at ``t0 + dt, ..., t0 + n_f dt`` (exact unless a block
    lands on its spot within the span), with a tiny variance.

    Args:
        human: the scripted human, at time ``t0``.
        delivered: ids of the blocks lying on their delivery spots now.
        t0: now [s] (the forecast's last observed frame).
        n_f: frames.
        dt: seconds between frames.
        step_s: the simulation's control period [s].
        std: per-coordinate standard deviation [m].
        like: a tensor whose dtype and device the forecast takes.

    Returns:
        Forecast with weights (1, 1), mean and var (1, 1, n_f, K, 3), action ``oracle``.
    """
    times = t0 + dt * np.arange(1, n_f + 1)
    pos = torch.as_tensor(human.preview(times, delivered, step_s), dtype=like.dtype)
    return path_forecast(pos.to(like.device), dt, JOINT_NAMES, std=std, action="oracle")


def planner_cfg_for(base: PlannerCfg, kind: str, confidence: float) -> PlannerCfg:
    """``base`` with the settings of planner ``kind`` (``base.per_kind[kind]``, see
    :meth:`PlannerCfg.for_planner`), and the kind, predictor variant and confidence of one
    episode.

    Raises:
        ConfigError: on an unknown planner kind.
    """
    if kind not in PLANNER_KINDS:
        raise ConfigError(f"expected planner_kind in {sorted(PLANNER_KINDS)}, got {kind!r}")
    variant = PLANNER_KINDS[kind]
    return replace(
        base.for_planner(kind),
        kind=_OPTIMIZER_KIND.get(kind, "iplanner"),  # type: ignore[arg-type]
        predictor_variant=variant,  # type: ignore[arg-type]
        confidence=confidence,
    )


def run_episode(
    cfg: EpisodeCfg,
    *,
    robot: Any,
    predictor: PredictorLike | None,
    planner_kind: PlannerKind,
    writer_path: Path | None,
    seed: int,
    replanner: ReplannerLike | None = None,
    motion: MotionSource | None = None,
    task_policy: TaskPolicy | None = None,
) -> EpisodeResult:
    """Run one closed-loop episode and compute its metrics.

    Args:
        cfg: the episode.
        robot: a :class:`iplanner_torch.robot.model.RobotModel`.
        predictor: the human motion predictor (required for ``iplanner_no_ni`` and
            ``iplanner_ni``; ``iplanner_cv`` builds its own from ``cfg.cv`` when None).
        planner_kind: ``itomp`` (observed pose only), ``iplanner_no_ni``, ``iplanner_ni``,
            ``iplanner_cv`` (constant-velocity forecast), ``oracle`` (the person's true
            future, :func:`oracle_forecast`) or ``blind`` (no person).
        writer_path: MCAP file to write, or None.
        seed: episode seed (human order, idles and motions, tracker noise, planner seed).
        replanner: a ready replanner; None builds one from ``cfg.planner``.
        motion: the human's motion source; None uses the reaching generator.
        task_policy: the robot's task planner (module docstring); None: next feasible (the
            oracle: the person's own order).

    Returns:
        The metrics, the log path and the task events.

    Raises:
        ConfigError: on an unknown planner kind or an I-Planner without a predictor, or a
            predictor whose ``fps`` or ``joint_names`` do not fit the simulation.
        ShapeError: when the predictor's forecast is not one of the simulated person's
            joints in their order, of batch 1 and at least one frame, or of the actions it
            names (:func:`check_predicted`).
    """
    with torch_threads(cfg.torch_threads):
        return _run_episode(
            cfg,
            robot=robot,
            predictor=predictor,
            planner_kind=planner_kind,
            writer_path=writer_path,
            seed=seed,
            replanner=replanner,
            motion=motion,
            task_policy=task_policy,
        )


def predictor_task_policy(
    predictor: Any,
    block_ids: tuple[int, ...],
    order: Any,
    *,
    episodes: int = 300,
    seed: int = 0,
) -> TaskPolicy | None:
    """The Q-learning task planner (paper sec. 4.2) on the predictor's next-action model.

    ``p(Take_i next | taken)`` is ``predictor.next_action(progress, current)[reach_i]`` with
    ``progress`` the bitmask of the taken blocks' ``reach_<i>`` actions and ``current`` the
    ``idle`` action (the human rests between takes when the robot chooses), renormalised over
    the blocks.

    Args:
        predictor: has ``action_names`` and ``next_action(progress, current) -> (A,)``.
        block_ids: the scene's block ids (block ``i`` is the predictor's ``reach_<i>``).
        order: the scenario's task order (``allowed_next``), or None.
        episodes: Q-learning training episodes.
        seed: training seed.

    Returns:
        ``task_policy(taken ids, fetched ids) -> block id or None``, or None when the
        predictor has no next-action model or lacks a ``reach_<i>`` for some block.
    """
    from iplanner_torch.planning.task_mdp import TaskMDPCfg, TaskPlanner

    names = [n.lower() for n in _action_names(predictor)]
    next_action = getattr(predictor, "next_action", None)
    if not callable(next_action) or not all(f"reach_{i}" in names for i in block_ids):
        return None
    col = [names.index(f"reach_{i}") for i in block_ids]  # object index -> action index
    idle = names.index("idle") if "idle" in names else 0
    n = len(block_ids)
    cache: dict[int, np.ndarray] = {}

    def probs(taken_mask: int) -> np.ndarray:
        if taken_mask not in cache:
            progress = sum(1 << col[k] for k in range(n) if taken_mask >> k & 1)
            p = np.asarray(next_action(progress, idle), dtype=np.float64)[col]
            cache[taken_mask] = p / p.sum() if p.sum() > 0 else np.full(n, 1.0 / n)
        return cache[taken_mask]

    class _IndexOrder:
        def allowed_next(self, done: set[int]) -> set[int]:
            if order is None:
                return set(range(n)) - done
            ids = order.allowed_next({block_ids[k] for k in done})
            return {block_ids.index(i) for i in ids if i in block_ids}

    planner = TaskPlanner(
        TaskMDPCfg(num_objects=n, episodes=episodes, seed=seed),
        task_order=_IndexOrder(),
        next_action_probs=probs,
    )
    planner.train()

    def policy(taken: set[int], fetched: set[int]) -> int | None:
        t_idx = {block_ids.index(i) for i in taken if i in block_ids}
        f_idx = {block_ids.index(i) for i in fetched if i in block_ids}
        k = planner.policy(t_idx, f_idx)
        return None if k is None else block_ids[k]

    return policy


#: Where the person's shoulders are taken to be, seen from above, while the tracker has not
#: seen them: (x offset from the seat [m], |y| [m]) (the rest pose's shoulders are at the
#: seat's x and 0.16-0.20 m to each side).
SEAT_SHOULDER = (0.0, 0.18)


def crossed_spots(
    blocks: list[int],
    *,
    pending: set[int],
    spots: dict[int, np.ndarray],
    shoulders: dict[str, np.ndarray],
    radius: float,
) -> np.ndarray:
    """Which of ``blocks``' delivery spots the person's reaches for ``pending`` cross.

    Each reach is the straight line, seen from above, from the person's shoulder on the
    spot's side (``y > 0``: the left) to the spot of a pending block
    (:func:`~iplanner_torch.planning.task_mdp.reach_crossings`); a block's own reach does not
    count against its spot.

    Args:
        blocks: block ids to test.
        pending: blocks that lie on their delivery spots, which the person takes soon.
        spots: block id -> (3,) delivery spot [m], for every id in ``blocks`` and ``pending``.
        shoulders: ``"left"`` / ``"right"`` -> (3,) shoulder position [m].
        radius: distance from a reach within which a spot counts as crossed [m].

    Returns:
        (len(blocks),) bool.

    Raises:
        ConfigError: when a block lacks a spot.
    """
    from iplanner_torch.planning.task_mdp import reach_crossings

    missing = sorted((set(blocks) | pending) - set(spots))
    if missing:
        raise ConfigError(f"no delivery spot for blocks {missing}")
    out = np.zeros(len(blocks), dtype=bool)
    for p in sorted(pending):
        end = np.asarray(spots[p], dtype=np.float64)
        start = np.asarray(shoulders["left" if end[1] > 0.0 else "right"], dtype=np.float64)
        others = [k for k, b in enumerate(blocks) if b != p]
        if others:
            pts = np.stack([np.asarray(spots[blocks[k]], dtype=np.float64) for k in others])
            out[others] |= reach_crossings(start[None], end[None], pts, radius)
    return out


def defer_crossed_fetch(
    choice: int,
    *,
    remaining: set[int],
    pending: set[int],
    spots: dict[int, np.ndarray],
    shoulders: dict[str, np.ndarray],
    groups: tuple[tuple[int, ...], ...] | None,
    radius: float,
) -> int:
    """The block to fetch instead of ``choice`` when the person's next reach crosses its spot.

    The task planner of the paper picks ``choice`` from the person's predicted next action;
    it does not know where the person's arm will be. When a block the person takes soon lies
    on its spot beyond ``choice``'s delivery spot, the robot would deliver into the reach
    (:func:`crossed_spots`).

    Args:
        choice: the task planner's block.
        remaining: blocks not yet fetched (``choice`` among them).
        pending: blocks that lie on their delivery spots, which the person takes soon.
        spots: block id -> (3,) delivery spot [m], for every id in ``remaining | pending``.
        shoulders: ``"left"`` / ``"right"`` -> (3,) shoulder position [m].
        groups: the task order's groups (``TaskOrder.groups``), or None (one group).
        radius: distance from a reach within which a spot counts as crossed [m].

    Returns:
        ``choice`` when no reach crosses its spot; else the block of the earliest group (then
        the smallest id) among those of ``choice``'s group and the next one whose spots no
        reach crosses; ``choice`` when there is none.

    Raises:
        ConfigError: when ``choice`` is not in ``remaining``, or a block lacks a spot.
    """
    if choice not in remaining:
        raise ConfigError(
            f"expected choice {choice} among the remaining blocks {sorted(remaining)}"
        )
    cand = sorted(remaining)
    crossed = crossed_spots(cand, pending=pending, spots=spots, shoulders=shoulders, radius=radius)
    if not crossed[cand.index(choice)]:
        return choice

    rank = group_ranks(groups) if groups is not None else {}

    def group(i: int) -> int:
        return rank.get(i, len(groups)) if groups is not None else 0

    limit = group(choice) + 1
    free = [i for i, c in zip(cand, crossed, strict=True) if not c and group(i) <= limit]
    return min(free, key=lambda i: (group(i), i)) if free else choice


def _run_episode(
    cfg: EpisodeCfg,
    *,
    robot: Any,
    predictor: PredictorLike | None,
    planner_kind: PlannerKind,
    writer_path: Path | None,
    seed: int,
    replanner: ReplannerLike | None,
    motion: MotionSource | None,
    task_policy: TaskPolicy | None,
) -> EpisodeResult:
    pcfg = planner_cfg_for(cfg.planner, planner_kind, cfg.scenario.confidence)
    use_prediction = PLANNER_KINDS[planner_kind] is not None
    oracle = planner_kind == "oracle"
    blind = planner_kind == "blind"  # plans with nobody there: no forecast at all
    # the planner's forecast predicts motion (ITOMP's holds the observed pose still)
    forecasts_motion = use_prediction or oracle
    # ITOMP's conservative spread of the held pose (not the stalled I-Planner's fallback)
    itomp_spread = pcfg.itomp_spread_mps if planner_kind == "itomp" else 0.0
    if planner_kind == "iplanner_cv" and predictor is None:
        predictor = ConstantVelocityPredictor(cfg.cv, fps=cfg.sim.tracker_fps)
    if use_prediction and predictor is None:
        raise ConfigError(f"planner_kind {planner_kind!r} needs a predictor, got None")
    scenario = cfg.scenario
    scene = cfg.scene_cfg()
    blocking = scenario.kind == "blocking"
    human_cfg = replace(cfg.sim.human, mode="blocking" if blocking else "tasks")
    if use_prediction:
        check_predictor_rate(predictor, cfg.sim.tracker_fps)
        check_predictor_joints(predictor)
    window = (
        _predictor_window(predictor, cfg.sim.tracker_window)
        if use_prediction
        else cfg.sim.tracker_window
    )
    sim_cfg = replace(cfg.sim, human=human_cfg, tracker_window=window)
    motion = motion or ReachingMotionSource(seed, seat_x=scene.human_seat_x)
    order = None if blocking else parse_order(scenario.task_order, scene.block_ids)
    lift = np.array([0.0, 0.0, 0.04 - 0.5 * scene.block_size])
    targets = {i: scene.delivery_position(i) + lift for i in scene.block_ids}
    human = ScriptedHuman(human_cfg, motion, task_order=order, targets=targets, seed=seed)
    # the episode seed + 1, wrapped to 0 after MAX_SEED (no other episode's tracker uses 0)
    tracker = Tracker(sim_cfg.tracker_cfg(), seed=(seed + 1) % (MAX_SEED + 1))
    env = SimEnv(scene, robot, human, tracker, seed, sim_cfg)
    ref = robot.q_home
    dev, dt_ = ref.device, ref.dtype

    def tens(x: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.asarray(x), dtype=dt_, device=dev)

    def ik(point: np.ndarray, q_init: torch.Tensor) -> torch.Tensor:
        return robot.ik(tens(point), q_init)

    if replanner is None:
        pcfg = replace(pcfg, optimizer=replace(pcfg.optimizer, seed=seed))
        base_xy = np.asarray(getattr(robot, "base_position", (0.75, 0.0, 0.0)).tolist())
        replanner = build_replanner(pcfg, robot, TableClearance(scene, base_xy))
    q_home = ref.detach().clone()
    goal_q: torch.Tensor
    if blocking:
        q_a = ik(np.asarray(scenario.crossing_start), q_home)
        goal_q = ik(np.asarray(scenario.crossing_goal), q_a)
        ends = {
            "crossing_start": (scenario.crossing_start, q_a),
            "crossing_goal": (scenario.crossing_goal, goal_q),
        }
        for key, (point, q_pt) in ends.items():
            miss = float(np.linalg.norm(robot.ee_position(q_pt).detach().cpu().numpy() - point))
            if miss > CROSSING_TOLERANCE_M:
                raise ConfigError(
                    f"scenario.{key}={list(point)}: the robot's tool point gets no closer than "
                    f"{100 * miss:.1f} cm to it (tolerance {100 * CROSSING_TOLERANCE_M:g} cm): "
                    "out of its reach or of its joint limits"
                )
        env.reset(q_init=q_a.detach().cpu().numpy())
    else:
        env.reset()
    if task_policy is None and use_prediction and not blocking:
        task_policy = predictor_task_policy(
            predictor, scene.block_ids, order, episodes=cfg.task_planner_episodes, seed=seed
        )
    if task_policy is None and oracle and not blocking:

        def task_policy(taken: set[int], fetched: set[int]) -> int | None:
            return next((i for i in human.order if i not in fetched), None)

    # whole numbers of control steps between the metric samples and the logged states
    n_sub_metrics = max(1, round(1.0 / (cfg.metrics_hz * env.control_dt)))
    log_hz = cfg.metrics_hz if cfg.log_hz is None else cfg.log_hz
    n_sub_log = max(1, round(1.0 / (log_hz * env.control_dt)))
    events: list[tuple[float, str, int]] = []
    writer = None
    if writer_path is not None:
        from iplanner_torch.recording.mcap import EpisodeWriter

        writer = EpisodeWriter(
            writer_path,
            metadata={
                "scenario": scenario.name,
                "arrangement": scenario.arrangement,
                "task_order": scenario.task_order,
                "confidence": scenario.confidence,
                "planner": planner_kind,
                "robot": robot.name,
                "seed": int(seed),
                "speed": human_cfg.speed,
                "noise": sim_cfg.tracker_noise,
                "dropout": sim_cfg.tracker_dropout,
                "human_speed": human_cfg.speed,
                "tracker_noise": sim_cfg.tracker_noise,
                "human_order": list(human.order),
                # the rates actually sampled [Hz]: the metric trajectories (smoothness,
                # jerkiness, closest distance) and the logged robot and true human states
                "metrics_hz": 1.0 / (n_sub_metrics * env.control_dt),
                "log_hz": 1.0 / (n_sub_log * env.control_dt),
            },
        )

    def record(t: float, kind: str, block: int) -> None:
        events.append((t, kind, block))
        if writer is not None:
            writer.task_event(t, kind, {"block": block})

    def oracle_knows(t: float) -> bool:
        """Whether the oracle knows the person's future at ``t`` (oracle_onset_delay_s)."""
        delay = cfg.oracle_onset_delay_s
        if delay is None:
            return True
        onset = next((te for te, kind, _ in events if kind == "blocking_started"), None)
        return onset is not None and t >= onset + delay - 1e-9

    crossing = cfg.task_crossing_radius if forecasts_motion and not blocking else None
    spots = {i: scene.delivery_position(i) for i in scene.block_ids}
    deferred = 0  # fetches moved off a spot the person's next reach crosses
    held: int | None = None  # the carried block held back while a reach crosses its spot
    held_s = 0.0
    held_frames = -1  # tracker frames when the hold was last checked
    landed: dict[int, float] = {}  # block -> when the robot put it on its spot [s]

    def shoulders() -> dict[str, np.ndarray]:
        pose = np.asarray(tracker.latest_pose(), dtype=np.float64)
        out = {}
        for side, sign in (("left", 1.0), ("right", -1.0)):
            p = pose[JOINT_INDEX[f"{side}_shoulder"]]
            seat = [scene.human_seat_x + SEAT_SHOULDER[0], sign * SEAT_SHOULDER[1], 0.0]
            out[side] = p if np.isfinite(p).all() else np.asarray(seat)
        return out

    def in_hand() -> set[int]:
        """Blocks in the person's hand (a take under way, past the grasp)."""
        return {i for i, st in env.block_state.items() if st == "human"}

    def pending_reaches() -> set[int]:
        """Blocks whose reach the person makes soon or makes now: those on their delivery
        spots and the one in the person's hand (its reach back crosses the same spots)."""
        return set(env.delivered) | in_hand()

    def choose_next() -> int | None:
        nonlocal deferred
        fetched = (
            set(env.delivered)
            | set(env.taken)
            | {i for i, s in env.block_state.items() if s in ("robot", "human")}
        )
        if len(fetched) == len(scene.block_ids):
            return None
        if task_policy is not None:
            nxt = task_policy(set(env.taken), fetched)
        else:
            first = next_feasible(order, fetched, scene.block_ids)  # type: ignore[arg-type]
            nxt = None if first < 0 else first
        if nxt is None or crossing is None or nxt in fetched:
            return nxt
        choice = defer_crossed_fetch(
            nxt,
            remaining=set(scene.block_ids) - fetched,
            pending=pending_reaches(),
            spots=spots,
            shoulders=shoulders(),
            groups=getattr(order, "groups", None),
            radius=crossing,
        )
        deferred += int(choice != nxt)
        return choice

    def reach_crosses(block: int) -> bool:
        """Whether ``block`` must wait clear of a reach (the option on): a reach for a block
        the person takes soon crosses its spot, and the person can go on meanwhile (a take
        under way, or a block on its spot the order lets the person take; else the person
        waits for ``block`` itself, as when the order puts it before the crossing block, and
        the hold would never end)."""
        reaching = pending_reaches()
        if crossing is None or not reaching:
            return False
        crossed = crossed_spots(
            [block], pending=reaching, spots=spots, shoulders=shoulders(), radius=crossing
        )
        if not crossed[0]:
            return False
        if in_hand():
            return True  # a take under way
        allowed = set(order.allowed_next(set(env.taken)))  # type: ignore[union-attr]
        return bool(allowed & set(env.delivered))

    def start_next(t: float) -> torch.Tensor:
        nxt = choose_next()
        q_now = tens(env.robot_q())
        if nxt is None:
            return q_home
        ev = env.start_fetch(nxt)
        record(t, ev.kind, ev.block)
        return ik(env.fetch.target_point(), q_now)  # type: ignore[union-attr]

    if not blocking:
        goal_q = start_next(0.0)
    replanner.reset(tens(env.robot_q()), goal_q, 0.0)
    m = pcfg.replan_step_s
    warned_horizon = False  # a forecast shorter than the plans' reach: said once an episode
    next_cycle = 0.0
    logged_frames = 0  # tracker frames written to /human/joints_tracked
    n_sub_scene = max(1, round(1.0 / (cfg.scene_hz * env.control_dt))) if cfg.scene_hz else 0
    scene_map = HumanSphereMap.from_segments(JOINT_NAMES) if n_sub_scene else None
    drawn: list[tuple[np.ndarray, np.ndarray]] = []  # the latest forecast's ellipsoids
    t_hist: list[float] = []
    q_hist: list[np.ndarray] = []
    h_hist: list[np.ndarray] = []
    true_t: list[float] = []
    true_h: list[np.ndarray] = []
    forecasts: list[tuple[float, np.ndarray, np.ndarray]] = []  # (t0, times, hands (n, 2, 3))
    predict_ms: list[float] = []
    action_names = _action_names(predictor) if use_prediction else ()
    watch = (
        StallWatch(cfg.stall_fallback_s, cfg.still_radius)
        if use_prediction and not blocking and cfg.stall_fallback_s is not None
        else None
    )
    still_frames = max(1, round(0.5 * sim_cfg.tracker_fps))
    rest_frames = max(2, round(REST_WINDOW_S * sim_cfg.tracker_fps))  # for reaction_s
    stall_cycles = 0
    calibration = cfg.calibration_cfg() if use_prediction else None
    calibrator = (
        SpreadCalibrator(calibration, JOINT_NAMES, noise_std=sim_cfg.tracker_noise)
        if calibration is not None
        else None
    )
    t_done: float | None = None
    t_goal: float | None = None
    step = 0
    wall0 = time.perf_counter()
    bar = tqdm(
        total=cfg.max_duration_s,
        desc=f"{cfg.scenario.name} {planner_kind} seed {seed}",
        unit="sim s",
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.0f} sim s "
        "[{elapsed}<{remaining}, {rate_fmt}]",
        disable=not cfg.progress_bar,
        leave=False,
    )
    try:
        while env.time < cfg.max_duration_s - 0.5 * env.control_dt:
            t = env.time
            q_now_np = env.robot_q()
            if t >= next_cycle - 1e-9:
                next_cycle += m
                t_obs = float(tracker.times()[-1])
                stalled = False
                if watch is not None:
                    watch.observe_person(t, tracked_hands(tracker.window(), still_frames))
                    was_active = watch.active
                    stalled = watch.stalled(t)
                    if stalled and not was_active:
                        record(t, "stall_fallback", -1)
                # a stalled person waits for the robot: plan on the held pose, as ITOMP
                stall_cycles += int(stalled)
                if use_prediction and not stalled:
                    pos = torch.as_tensor(held_window(tracker), device=dev).unsqueeze(0)
                    progress = torch.tensor(
                        [human.progress_bitmask(action_names)], dtype=torch.int64, device=dev
                    )
                    w0 = time.perf_counter()
                    forecast = check_predicted(
                        predictor.predict_positions(pos, progress),  # type: ignore[union-attr]
                        action_names,
                    )
                    predict_ms.append(1e3 * (time.perf_counter() - w0))
                    if not warned_horizon:
                        warned_horizon = warn_short_horizon(forecast, m)
                    if cfg.mask_unavailable_actions and action_names and not blocking:
                        available = available_blocks(
                            set(env.delivered),
                            in_hand(),
                            order if cfg.mask_by_order else None,
                            set(env.taken),
                        )
                        keep = action_mask(action_names, available)
                        forecast = forecast.mask_actions(keep)
                        if cfg.rest_when_nothing_available:
                            hold = rest_hold(action_names, keep)
                            if bool(hold.any()):
                                forecast = forecast.hold_actions(hold)
                        if cfg.reaction_s and hands_still(
                            tracker.window(), rest_frames, REST_RADIUS_M
                        ):
                            delay = reaction_delays(
                                action_names,
                                available,
                                landed,
                                t_obs,
                                cfg.reaction_s,
                                forecast.dt,
                            )
                            if bool((delay > 0).any()):
                                forecast = forecast.delay_actions(delay)
                    if calibrator is not None:  # scored unscaled, planned on widened
                        stamps = tracker.times()  # (len,), the window's newest frames
                        calibrator.observe(stamps, tracker.window()[-len(stamps) :])
                        calibrator.record(forecast, t_obs)
                        forecast = calibrator.apply(forecast)
                elif blind:
                    forecast = None
                elif oracle and not oracle_knows(t):  # the block not yet recognised
                    t_obs = t
                    now = tens(env.human_joints())  # (K, 3)
                    forecast = path_forecast(
                        now.expand(cfg.static_forecast_frames, *now.shape),
                        cfg.static_forecast_dt,
                        JOINT_NAMES,
                        std=cfg.oracle_std,
                        action="oracle",
                    )
                elif oracle:
                    t_obs = t
                    forecast = oracle_forecast(
                        human,
                        set(env.delivered),
                        t,
                        cfg.static_forecast_frames,
                        cfg.static_forecast_dt,
                        step_s=env.control_dt,
                        std=cfg.oracle_std,
                        like=ref,
                    )
                else:  # ITOMP, or a stalled I-Planner (whose person stays still)
                    forecast = static_human_forecast(
                        tens(tracker.latest_pose()),
                        cfg.static_forecast_frames,
                        cfg.static_forecast_dt,
                        JOINT_NAMES,
                        spread=itomp_spread,
                    )
                if forecasts_motion and not stalled:  # scored by eval/mhd and logged
                    mean = forecast.expected_mean()[0][:, HAND_JOINTS]  # (n_f, 2, 3)
                    forecasts.append(
                        (
                            t_obs,
                            forecast.times.detach().cpu().numpy(),
                            mean.detach().cpu().numpy(),
                        )
                    )
                result = replanner.step(t, tens(q_now_np), forecast, forecast_t0=t_obs)
                due = getattr(replanner, "next_cycle", None)
                if isinstance(due, float) and due > t:  # the replanner keeps its own cadence
                    next_cycle = due
                if watch is not None and result is not None:
                    watch.observe_plan(t, not (result.feasible or result.evasive))
                if writer is not None:
                    if forecasts_motion and not stalled:
                        writer.log_forecast(t_obs, forecast)
                    if scene_map is not None:
                        drawn = forecast_ellipsoids(forecast) if forecasts_motion else []
                    if result is not None:
                        stats = replanner.stats
                        solve = stats.solve_ms[-1] if getattr(stats, "solve_ms", None) else 0.0
                        writer.plan(
                            t, result.times, result.q, result.feasible, result.wait_s, solve
                        )
                        writer.collision_bound(t, result.times, result.bound, pcfg.confidence)
            q_des, qd_des = replanner.command(t)
            info = env.step(q_des, qd_des)
            step += 1
            t = env.time
            true_t.append(t)
            true_h.append(env.human_joints())
            if step % n_sub_metrics == 0:
                t_hist.append(t)
                q_hist.append(env.robot_q())
                h_hist.append(true_h[-1])
            if writer is not None and step % n_sub_log == 0:
                writer.robot_state(t, env.robot_q(), env.robot_qd(), robot.joint_names)
                writer.human_joints(t, true_h[-1], None, JOINT_NAMES)
            if writer is not None and tracker.num_frames != logged_frames:
                # each tracker frame once, at the time it was taken (stamping the newest
                # frame with the log grid's time made it look up to a frame period late)
                logged_frames = tracker.num_frames
                times = tracker.times()
                writer.human_joints(float(times[-1]), None, tracker.window()[-1], JOINT_NAMES)
            if writer is not None and scene_map is not None and step % n_sub_scene == 0:
                _log_scene(writer, t, robot, env.robot_q(), scene_map, true_h[-1], drawn)
            goal_changed = False
            for ev in info.events:
                record(ev.time, ev.kind, ev.block)
                if watch is not None:
                    watch.observe_progress(ev.time)
                if ev.kind == "picked":
                    if reach_crosses(ev.block):  # hold it at the pick pose (the goal stays)
                        held = ev.block
                        record(t, "delivery_held", ev.block)
                    else:
                        target = env.fetch.target_point()  # type: ignore[union-attr]
                        replanner.set_goal(ik(target, tens(env.robot_q())), t)
                        goal_changed = True
                elif ev.kind == "delivered":
                    landed[ev.block] = ev.time
                    replanner.set_goal(start_next(t) if cfg.direct_next_fetch else q_home, t)
                    goal_changed = True
                elif ev.kind == "fetch_done":
                    replanner.set_goal(start_next(t), t)
                    goal_changed = True
                elif ev.kind == "done":
                    t_done = ev.time
            if held is not None:
                held_s += env.control_dt
                # the crossing's inputs (the tracked shoulders, the blocks on their spots and
                # in the hand, the blocks taken) change only at tracker frames and task events
                fresh = bool(info.events) or tracker.num_frames != held_frames
                held_frames = tracker.num_frames
                if fresh and not reach_crosses(held):
                    record(t, "delivery_resumed", held)
                    held = None
                    target = env.fetch.target_point()  # type: ignore[union-attr]
                    replanner.set_goal(ik(target, tens(env.robot_q())), t)
                    goal_changed = True
            if goal_changed and cfg.replan_on_goal_change:
                next_cycle = t
            if info.new_contact:
                record(t, "contact", -1)
            bar.update(env.control_dt)
            if t_done is not None:
                break
            if blocking:
                reached = float((tens(env.robot_q()) - goal_q).abs().max()) < 0.05
                end_block = human_cfg.blocking_start_s + human_cfg.blocking_hold_s
                if reached and t_goal is None:
                    t_goal = t
                if t_goal is not None and t > max(t_goal, end_block) + cfg.blocking_tail_s:
                    break
        wall = time.perf_counter() - wall0
        metrics = _metrics(
            cfg=cfg,
            robot=robot,
            human=human,
            scene=scene,
            t_hist=t_hist,
            q_hist=q_hist,
            h_hist=h_hist,
            true_t=np.asarray(true_t),
            true_h=np.asarray(true_h),
            forecasts=forecasts,
            predict_ms=predict_ms,
            t_done=t_done,
            blocking=blocking,
        )
        stats = replanner.stats
        metrics.update(
            {
                "sim/duration_s": env.time,
                "sim/realtime_factor": env.time / wall if wall > 0 else math.inf,
                "sim/contacts": float(env.contact_onsets),
                "sim/contact_steps": float(env.contact_steps),
                "sim/body_distance": float(env.min_body_distance),
                "plan/cycles": float(getattr(stats, "cycles", 0)),
                "plan/overruns": float(getattr(stats, "overruns", 0)),
                "plan/cut_short": float(getattr(stats, "cut_short", 0)),
                "plan/waits": float(getattr(stats, "waits", 0)),
                "plan/wait_s": float(getattr(stats, "wait_s", 0.0)),
                "plan/evasions": float(getattr(stats, "evasions", 0)),
                "plan/escapes": float(getattr(stats, "escapes", 0)),
                "plan/emergencies": float(getattr(stats, "emergencies", 0)),
                "plan/stall_cycles": float(stall_cycles),
                "task/deferred_fetches": float(deferred),
                "task/held_s": float(held_s),
                "plan/mean_solve_ms": float(getattr(stats, "mean_solve_ms", 0.0)),
                **(
                    {
                        "forecast/spread_scale_mean": float(np.mean(calibrator.scales or [1.0])),
                        "forecast/spread_scale_max": float(max(calibrator.scales or [1.0])),
                    }
                    if calibrator is not None
                    else {}
                ),
                "eval/completed": float(t_done is not None or (blocking and t_goal is not None)),
            }
        )
        if writer is not None:
            writer.metrics(env.time, metrics)
    except BaseException as exc:  # interrupted or failed: the log keeps what was simulated
        if writer is not None:
            writer.close(exc)
        raise
    finally:
        bar.close()
    if writer is not None:
        writer.close()
    return EpisodeResult(
        metrics=metrics,
        mcap_path=Path(writer_path) if writer_path is not None else None,
        events=events,
        planner_kind=planner_kind,
        seed=int(seed),
    )


def _metrics(
    *,
    cfg: EpisodeCfg,
    robot: Any,
    human: ScriptedHuman,
    scene: SceneCfg,
    t_hist: list[float],
    q_hist: list[np.ndarray],
    h_hist: list[np.ndarray],
    true_t: np.ndarray,
    true_h: np.ndarray,
    forecasts: list[tuple[float, np.ndarray, np.ndarray]],
    predict_ms: list[float],
    t_done: float | None,
    blocking: bool,
) -> dict[str, float]:
    ref = robot.q_home
    q_np = np.asarray(q_hist, dtype=np.float64).reshape(-1, ref.shape[-1])  # (T, J); T may be 0
    q = torch.as_tensor(q_np, dtype=ref.dtype, device=ref.device)  # (T, J)
    with torch.no_grad():
        rc = robot.sphere_centers(q)  # (T, S_r, 3)
    smap = HumanSphereMap.from_segments(JOINT_NAMES)
    h_np = np.asarray(h_hist, dtype=np.float64).reshape(-1, len(JOINT_NAMES), 3)  # (T, K, 3)
    hj = torch.as_tensor(h_np)  # (T, K, 3)
    hc = smap.centers(hj)  # (T, S_h, 3)
    t_alone = None
    if not blocking:
        lift = np.array([0.0, 0.0, 0.04 - 0.5 * scene.block_size])
        far = {i: scene.block_position(i) + lift for i in scene.block_ids}
        t_alone = human.solo_duration(far)
    t_with = t_done  # efficiency is NaN for an unfinished episode
    mhd, mhd_count = _mean_mhd(cfg, true_t, true_h, forecasts)
    out = M.episode_metrics(
        t=np.asarray(t_hist, dtype=np.float64),
        q=q_np,
        robot_centers=rc.detach().cpu(),
        robot_radii=robot.sphere_radii.detach().cpu(),
        human_centers=hc,
        human_radii=smap.radii,
        t_human_alone=t_alone,
        t_with_robot=t_with if not blocking else None,
        mhd=mhd,
        prediction_ms=float(np.mean(predict_ms)) if predict_ms else None,
    )
    out["eval/task_time_s"] = float(t_with) if t_with is not None else math.nan
    out["eval/human_alone_s"] = float(t_alone) if t_alone is not None else math.nan
    out["eval/mhd_count"] = float(mhd_count)
    return out


def _mean_mhd(
    cfg: EpisodeCfg,
    true_t: np.ndarray,
    true_h: np.ndarray,
    forecasts: list[tuple[float, np.ndarray, np.ndarray]],
) -> tuple[float | None, int]:
    """Mean MHD of the moving hand over ``mhd_horizon_s`` (module docstring) and the number
    of scored forecasts; the mean is None when none was scored."""
    if not forecasts or true_t.size < 2:
        return None, 0
    values = []
    for t0, times, pred in forecasts:
        keep = times <= cfg.mhd_horizon_s + 1e-9
        if not keep.any() or t0 + times[keep][-1] > true_t[-1]:
            continue
        tq = t0 + times[keep]
        true = np.stack(
            [
                np.stack([np.interp(tq, true_t, true_h[:, k, c]) for c in range(3)], -1)
                for k in HAND_JOINTS
            ],
            1,
        )  # (n, 2, 3)
        start = np.array(
            [[np.interp(t0, true_t, true_h[:, k, c]) for c in range(3)] for k in HAND_JOINTS]
        )
        motion = np.linalg.norm(true - start[None], axis=-1).max(0)  # (2,)
        side = int(np.argmax(motion))
        if motion[side] < cfg.mhd_min_motion:
            continue
        values.append(M.prediction_mhd(pred[keep][:, side], true[:, side]))
    return (float(np.mean(values)) if values else None), len(values)
