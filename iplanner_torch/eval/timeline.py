"""One episode over time, from its log: how close the robot came to the person, how near the
planner's collision bound came to its limit, what the predictor believed the person was doing,
and how fast the arm moved, with the waits and task events marked.

:func:`episode_timeline` reads the series out of an :class:`~iplanner_torch.recording.Episode`
(plain numpy arrays, for your own plots); :func:`plot_episode_timeline` draws them as one
figure of four panels sharing the time axis. ``iplanner-experiment`` writes one such figure
beside each episode log (``episodes/<episode>.png``), and ``scripts/plot_episode.py`` draws
them for logs already written.

Sources (channels of the log):

- closest distance: ``/scene`` (the robot's and the person's spheres, a few times a second),
  the least ``|c_r - c_h| - r_r - r_h`` over all sphere pairs: the sphere-model distance of
  ``eval/min_distance``, sampled at the scene channel's rate, which the figure states beside
  it (the episode's ``/metrics`` message; that metric is sampled at ``metrics_hz``, 25 Hz, so
  where the scene's samples are some of the metric's, as at the default 5 Hz, their least
  value is at or above it; at another scene rate it may fall between two metric samples);
- collision bound: ``/planner/plan`` and ``/planner/bound`` (each plan's largest per-waypoint
  bound, and ``1 - confidence``, the most it may be);
- action probabilities: ``/prediction/forecast`` (absent for ``itomp``, which has no
  predictor), with the person's real reaches from the ``/task/events``
  ``human_take_started`` .. ``human_took`` of each block;
- arm speed: ``/robot/joint_state`` (the norm of the joint velocities).

A log cut short (``episode.complete`` False) is drawn as far as it goes, and says so.

Each figure carries a :class:`TimelineStamp` in its PNG text (:data:`STAMP_KEY`): the log it
was drawn from, that log's extremes and the axes drawn on, so that a resumed run keeps the
figures that would come out the same (:func:`read_timeline_stamp`).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import LogFormatter

from iplanner_torch.checks import is_real
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.eval.report import PLANNERS
from iplanner_torch.recording.reader import Episode, read_episode

__all__ = [
    "STAMP_KEY",
    "TIMELINE_FORMAT",
    "SharedAxes",
    "Timeline",
    "TimelineExtremes",
    "TimelineStamp",
    "action_colours",
    "axes_by_scenario",
    "axes_from_extremes",
    "episode_timeline",
    "log_fingerprint",
    "plot_episode_timeline",
    "read_timeline_stamp",
    "shared_axes",
    "shared_axes_by_scenario",
    "timeline_extremes",
    "timeline_path",
]


def action_colours(n: int) -> list[tuple[float, ...]]:
    """``n`` different colours for the actions, by index, none of them red (kept for the
    waits): the tab20 palette's dark colours, then its light ones (18 in all); more actions
    than that get evenly spaced colours of the ``turbo`` map.

    Returns:
        ``n`` RGB(A) tuples, no two the same.
    """
    from matplotlib import colormaps

    tab20 = colormaps["tab20"].colors  # (dark, light) pairs of the tab10 colours; 3 is red
    palette = [c for i, c in enumerate(tab20[0::2]) if i != 3]
    palette += [c for i, c in enumerate(tab20[1::2]) if i != 3]
    if n <= len(palette):
        return [tuple(c) for c in palette[:n]]
    return [tuple(colormaps["turbo"](x)) for x in np.linspace(0.05, 0.95, n)]


#: robot task events drawn as vertical lines, with their line style
ROBOT_EVENTS: dict[str, str] = {"picked": ":", "delivered": "--"}


@dataclass
class Timeline:
    """The series of one episode (all times in seconds of simulation time).

    Attributes:
        scene_t: (T_s,) times of the ``/scene`` messages.
        gap_m: (T_s,) closest surface distance between the robot's and the person's spheres
            [m] (< 0: the sphere models overlap; NaN: no finite sphere on a side).
        plan_t: (T_p,) times of the plans.
        max_bound: (T_p,) each plan's largest per-waypoint collision bound (NaN: none logged).
        limit: (T_p,) ``1 - confidence`` of each plan's bound (NaN: none logged).
        feasible: (T_p,) whether each plan was feasible (met the bound, the static clearance
            and the velocity limits; see ``PlanResult.feasible``).
        waits: ``(start, end)`` of each wait the planner chose [s].
        forecast_t: (T_f,) times of the forecasts (empty for ``itomp``).
        weights: (T_f, A) the forecast action probabilities.
        action_names: (A,) their names.
        reaches: ``(start, end, action name)`` of each of the person's reaches for a block
            (``end`` NaN: not finished when the log ends).
        robot_events: ``(t, kind, block)`` of the robot's pick and delivery events.
        robot_t: (T_r,) times of the robot joint states.
        speed: (T_r,) the norm of the joint velocities [rad/s].
        end_t: the last time in the log [s].
        title: planner, robot, scenario, speed, noise, confidence and seed, as the metadata
            says.
        min_distance_m: the episode's own closest distance of the sphere models
            (``eval/min_distance`` of its metrics message, at the metric samples) [m]; NaN
            when the log holds no metrics (cut short) or no value.
        complete: whether the log holds every record (``Episode.complete``).
        notes: what is missing, in words (e.g. "no forecasts: itomp has no predictor").
        scenario: the scenario's name, as the metadata says ("" when it says none): the
            figures of one scenario share their axes (:func:`shared_axes_by_scenario`).
    """

    scene_t: np.ndarray
    gap_m: np.ndarray
    plan_t: np.ndarray
    max_bound: np.ndarray
    limit: np.ndarray
    feasible: np.ndarray
    waits: list[tuple[float, float]]
    forecast_t: np.ndarray
    weights: np.ndarray
    action_names: tuple[str, ...]
    reaches: list[tuple[float, float, str]]
    robot_events: list[tuple[float, str, int]]
    robot_t: np.ndarray
    speed: np.ndarray
    end_t: float
    title: str
    min_distance_m: float = float("nan")
    complete: bool = True
    notes: list[str] = field(default_factory=list)
    scenario: str = ""


def _frame(episode: Episode, topic: str) -> pd.DataFrame:
    df = episode.frames.get(topic)
    return df if df is not None else pd.DataFrame({"t": []})


def closest_gaps(robot: np.ndarray, human: np.ndarray) -> np.ndarray:
    """The closest surface distance between two sets of spheres, frame by frame.

    Args:
        robot: (T, S_r, 4) sphere centres and radii [m] (rows with NaN are left out).
        human: (T, S_h, 4) the same for the person.

    Returns:
        (T,) ``min |c_r - c_h| - r_r - r_h`` over the pairs of finite spheres [m]; NaN in a
        frame with no finite sphere on one side.

    Raises:
        DataError: when the arrays are not (T, S, 4) with the same T.
    """
    robot = np.asarray(robot, dtype=np.float64)
    human = np.asarray(human, dtype=np.float64)
    if robot.ndim != 3 or human.ndim != 3 or robot.shape[-1] != 4 or human.shape[-1] != 4:
        raise DataError(
            f"expected spheres (T, S, 4), got robot {robot.shape} and human {human.shape}"
        )
    if robot.shape[0] != human.shape[0]:
        raise DataError(
            f"expected as many robot as human frames, got {robot.shape[0]} and {human.shape[0]}"
        )
    d = np.linalg.norm(robot[:, :, None, :3] - human[:, None, :, :3], axis=-1)
    gap = d - robot[:, :, None, 3] - human[:, None, :, 3]  # (T, S_r, S_h), NaN where any NaN
    out = np.full(gap.shape[0], np.nan)
    flat = gap.reshape(gap.shape[0], -1)
    has = np.isfinite(flat).any(axis=1)
    out[has] = np.nanmin(flat[has], axis=1)
    return out


def _stack(values: pd.Series, width: int) -> np.ndarray:
    rows = [np.asarray(v, dtype=np.float64).reshape(-1) for v in values]
    out = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        out[i, : min(width, r.size)] = r[:width]
    return out


def episode_timeline(episode: Episode | str | Path) -> Timeline:
    """The series to draw of one episode.

    Args:
        episode: an episode read with :func:`~iplanner_torch.recording.read_episode`, or the
            path of its ``.mcap`` log.

    Returns:
        The :class:`Timeline`; a channel with no messages gives empty arrays (and a note).

    Raises:
        DataError: when the path is not a readable episode log (see ``read_episode``), the
            file is another program's MCAP file, or it holds nothing to draw (no robot, scene,
            plan or forecast message: a log cut before its first complete chunk).
    """
    if not isinstance(episode, Episode):
        episode = read_episode(episode)
    if episode.foreign:
        raise DataError(f"{episode.path}: not an episode log (another program's MCAP file)")
    notes: list[str] = []

    scene = _frame(episode, "/scene")
    scene_t = scene["t"].to_numpy(dtype=np.float64)
    if len(scene):
        _, robot, human = episode.scene_spheres()
        gap = closest_gaps(robot.numpy(), human.numpy())
    else:
        gap = np.zeros(0)
        notes.append("no /scene messages: no distances")

    plans = _frame(episode, "/planner/plan")
    plan_t = plans["t"].to_numpy(dtype=np.float64)
    feasible = plans["feasible"].to_numpy(dtype=bool) if len(plans) else np.zeros(0, dtype=bool)
    waits = []
    if len(plans):
        wait_s = plans["wait_s"].to_numpy(dtype=np.float64)
        waits = [(float(t), float(t + w)) for t, w in zip(plan_t, wait_s) if w > 0]
    bounds = _frame(episode, "/planner/bound")
    by_t = {}
    for row in bounds.itertuples(index=False):
        b = np.asarray(row.bound, dtype=np.float64)
        finite = b[np.isfinite(b)]
        by_t[float(row.t)] = (
            float(finite.max()) if finite.size else np.nan,
            1.0 - float(row.confidence),
        )
    max_bound = np.array([by_t.get(float(t), (np.nan, np.nan))[0] for t in plan_t])
    limit = np.array([by_t.get(float(t), (np.nan, np.nan))[1] for t in plan_t])

    fc = _frame(episode, "/prediction/forecast")
    if len(fc):
        action_names = tuple(str(a) for a in fc["action_names"].iloc[0])
        weights = _stack(fc["weights"], len(action_names))
        forecast_t = fc["t"].to_numpy(dtype=np.float64)
    else:
        action_names, weights, forecast_t = (), np.zeros((0, 0)), np.zeros(0)

    reaches: list[tuple[float, float, str]] = []
    robot_events: list[tuple[float, str, int]] = []
    started: dict[int, float] = {}
    for ev in episode.events():
        kind, t = str(ev.get("kind")), float(ev.get("t", np.nan))
        detail = ev.get("detail") if isinstance(ev.get("detail"), dict) else {}
        block = int(detail.get("block", -1)) if isinstance(detail, dict) else -1
        if kind == "human_take_started":
            started[block] = t
        elif kind == "human_took" and block in started:
            reaches.append((started.pop(block), t, f"take_{block}"))
        elif kind in ROBOT_EVENTS:
            robot_events.append((t, kind, block))
    reaches += [(s, np.nan, f"take_{b}") for b, s in started.items()]

    joints = _frame(episode, "/robot/joint_state")
    robot_t = joints["t"].to_numpy(dtype=np.float64)
    if len(joints):
        _, qd = episode.robot_qd()
        speed = np.linalg.norm(qd.numpy(), axis=-1)
    else:
        speed = np.zeros(0)
        notes.append("no /robot/joint_state messages: no arm speed")

    ends = [a[-1] for a in (scene_t, plan_t, forecast_t, robot_t) if a.size]
    if not ends:
        raise DataError(
            f"{episode.path}: no robot, scene, plan or forecast messages to draw"
            + ("" if episode.complete else " (the log was cut before its first complete chunk)")
        )
    planner = str(episode.metadata.get("planner", ""))
    if not len(fc):
        notes.append(
            "no forecasts: itomp has no predictor" if planner == "itomp" else "no forecasts logged"
        )
    end_t = float(max(ends))
    meta = episode.metadata
    noise, planner = meta.get("noise"), meta.get("planner")
    confidence = meta.get("confidence")
    title = (
        " · ".join(
            str(v)
            for v in (
                PLANNERS.get(str(planner), planner),  # as the tables name it
                meta.get("robot"),  # (the file names of two robots' runs are the same)
                meta.get("scenario"),
                f"{meta['speed']} speed" if meta.get("speed") is not None else None,
                f"noise {100 * float(noise):g} cm"
                if is_real(noise) and math.isfinite(noise)
                else None,
                f"confidence {float(confidence):g}"
                if is_real(confidence) and math.isfinite(confidence)
                else None,
                f"seed {meta['seed']}" if "seed" in meta else None,
            )
            if v is not None and v == v
        )
        or Path(episode.path).stem
    )
    if episode.interrupted:  # a whole file whose episode was stopped (Ctrl-C, an error)
        title += f"  (interrupted at t = {end_t:.1f} s: no metrics)"
    return Timeline(
        scene_t=scene_t,
        gap_m=gap,
        plan_t=plan_t,
        max_bound=max_bound,
        limit=limit,
        feasible=feasible,
        waits=waits,
        forecast_t=forecast_t,
        weights=weights,
        action_names=action_names,
        reaches=reaches,
        robot_events=robot_events,
        robot_t=robot_t,
        speed=speed,
        end_t=end_t,
        title=title,
        min_distance_m=_metric(episode, "eval/min_distance"),
        scenario=str(meta.get("scenario") or ""),
        complete=bool(episode.complete),
        notes=notes,
    )


def _metric(episode: Episode, key: str) -> float:
    """The episode's metric ``key`` as a float (NaN when absent or not a number)."""
    try:
        return float(episode.metrics().get(key, np.nan))
    except (TypeError, ValueError):
        return float("nan")


@dataclass(frozen=True)
class SharedAxes:
    """Axis ranges that the timelines of several episodes share, so that their panels compare
    at a glance (the same height is the same distance or speed in every figure of a
    scenario).

    Attributes:
        end_t: the right end of the time axis [s] (None: each episode's own end).
        distance_cm: ``(bottom, top)`` of the distance panel [cm] (None: matplotlib's own).
        speed: the top of the arm-speed panel [rad/s], whose bottom is 0 (None: its own).
    """

    end_t: float | None = None
    distance_cm: tuple[float, float] | None = None
    speed: float | None = None


@dataclass(frozen=True)
class TimelineExtremes:
    """What the shared axes need of one timeline: its finite extremes.

    Attributes:
        scenario: ``Timeline.scenario`` (the axes are shared per scenario).
        end_t: the last time in the log [s], None when not finite.
        gap_cm: ``(least, largest)`` of the sampled sphere-model distances and the episode's
            own minimum [cm], None when none is finite.
        speed: the largest finite arm speed [rad/s], None when there is none.
    """

    scenario: str = ""
    end_t: float | None = None
    gap_cm: tuple[float, float] | None = None
    speed: float | None = None


def timeline_extremes(tl: Timeline) -> TimelineExtremes:
    """The finite extremes of one timeline's series (NaN and inf left out)."""
    gaps = 100.0 * np.append(np.asarray(tl.gap_m, dtype=np.float64), tl.min_distance_m)
    gaps = gaps[np.isfinite(gaps)]
    sp = np.asarray(tl.speed, dtype=np.float64)
    sp = sp[np.isfinite(sp)]
    return TimelineExtremes(
        scenario=tl.scenario,
        end_t=float(tl.end_t) if math.isfinite(tl.end_t) else None,
        gap_cm=(float(gaps.min()), float(gaps.max())) if gaps.size else None,
        speed=float(sp.max()) if sp.size else None,
    )


def axes_from_extremes(extremes: Iterable[TimelineExtremes]) -> SharedAxes:
    """:func:`shared_axes` from the timelines' :func:`timeline_extremes` (the same ranges)."""
    ends, lows, highs, tops = [], [], [], []
    for ex in extremes:
        if ex.end_t is not None:
            ends.append(ex.end_t)
        if ex.gap_cm is not None:
            lows.append(ex.gap_cm[0])
            highs.append(ex.gap_cm[1])
        if ex.speed is not None:
            tops.append(ex.speed)
    distance = None
    if lows:
        lo, hi = min(min(lows), 0.0), max(max(highs), 0.0)
        pad = 0.05 * (hi - lo) if hi > lo else 1.0
        distance = (lo - pad, hi + pad)
    top = max(tops) if tops else 0.0
    return SharedAxes(
        end_t=max(ends) if ends else None,
        distance_cm=distance,
        speed=1.05 * top if top > 0.0 else None,
    )


def shared_axes(timelines: Iterable[Timeline]) -> SharedAxes:
    """The axis ranges that hold every given timeline's series, with a margin of 5 %.

    The distance range spans the sampled distances and each episode's own minimum
    (``min_distance_m``), and always holds 0 (where the sphere models touch); NaN and inf are
    left out. A range no timeline has a finite value for is None (each figure's own).

    Args:
        timelines: the episodes' :class:`Timeline` (e.g. of one ``iplanner-experiment`` run).

    Returns:
        The :class:`SharedAxes` for :func:`plot_episode_timeline`.
    """
    return axes_from_extremes(timeline_extremes(tl) for tl in timelines)


def shared_axes_by_scenario(timelines: Sequence[Timeline]) -> list[SharedAxes]:
    """:func:`shared_axes` over the timelines of each scenario (``Timeline.scenario``), one
    per timeline in order: the planners of a scenario compare on the same axes, and a short
    scenario's episodes are not drawn on the time axis of a long one."""
    return axes_by_scenario([timeline_extremes(tl) for tl in timelines])


def axes_by_scenario(extremes: Sequence[TimelineExtremes]) -> list[SharedAxes]:
    """:func:`shared_axes_by_scenario` from the timelines' :func:`timeline_extremes`."""
    by: dict[str, list[TimelineExtremes]] = {}
    for ex in extremes:
        by.setdefault(ex.scenario, []).append(ex)
    axes = {name: axes_from_extremes(group) for name, group in by.items()}
    return [axes[ex.scenario] for ex in extremes]


def timeline_path(log: str | Path) -> Path:
    """Where the timeline figure of an episode log goes: beside it, ``<log stem>.png``."""
    return Path(log).with_suffix(".png")


#: the PNG text key under which :func:`plot_episode_timeline` records what a figure was drawn
#: from (:class:`TimelineStamp`)
STAMP_KEY = "iplanner:timeline"
#: the figures' drawing; a figure stamped with another is drawn again by a resumed run (raise
#: it when :func:`plot_episode_timeline` draws differently)
TIMELINE_FORMAT = 1


@dataclass(frozen=True)
class TimelineStamp:
    """What a timeline figure was drawn from, kept in its PNG (:data:`STAMP_KEY`): a resumed
    ``iplanner-experiment`` keeps a figure whose log and axes have not changed, and takes the
    log's extremes from here instead of reading the log again.

    Attributes:
        extremes: the episode's :func:`timeline_extremes`.
        axes: the ranges the figure was drawn on.
        source: the log's :func:`log_fingerprint` (None: drawn from a timeline or an episode
            without its file).
    """

    extremes: TimelineExtremes
    axes: SharedAxes
    source: tuple[str, int, int] | None = None

    def to_json(self) -> str:
        """The stamp as one line of JSON (floats written to the last bit)."""
        return json.dumps(
            {
                "format": TIMELINE_FORMAT,
                "extremes": {
                    "scenario": self.extremes.scenario,
                    "end_t": self.extremes.end_t,
                    "gap_cm": self.extremes.gap_cm,
                    "speed": self.extremes.speed,
                },
                "axes": {
                    "end_t": self.axes.end_t,
                    "distance_cm": self.axes.distance_cm,
                    "speed": self.axes.speed,
                },
                "source": self.source,
            }
        )

    @classmethod
    def from_json(cls, text: str) -> TimelineStamp | None:
        """The stamp in ``text``, or None when it is not one of this format (malformed JSON,
        JSON nested too deep for the parser, or another record)."""
        try:
            raw = json.loads(text)
            if raw.get("format") != TIMELINE_FORMAT:
                return None
            ex, ax, src = raw["extremes"], raw["axes"], raw["source"]
            extremes = TimelineExtremes(
                scenario=_str(ex["scenario"]),
                end_t=_opt_float(ex["end_t"]),
                gap_cm=_opt_pair(ex["gap_cm"]),
                speed=_opt_float(ex["speed"]),
            )
            axes = SharedAxes(
                end_t=_opt_float(ax["end_t"]),
                distance_cm=_opt_pair(ax["distance_cm"]),
                speed=_opt_float(ax["speed"]),
            )
            source = None
            if src is not None:
                name, size, mtime = src
                if not (isinstance(size, int) and isinstance(mtime, int)):
                    raise TypeError("size and mtime are integers")
                source = (_str(name), size, mtime)
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError):
            return None
        return cls(extremes=extremes, axes=axes, source=source)


def _str(x: object) -> str:
    if not isinstance(x, str):
        raise TypeError(f"expected a string, got {type(x).__name__}")
    return x


def _opt_float(x: object) -> float | None:
    if x is None:
        return None
    if not is_real(x):
        raise TypeError(f"expected a number, got {type(x).__name__}")
    return float(x)


def _opt_pair(x: object) -> tuple[float, float] | None:
    if x is None:
        return None
    if not isinstance(x, list) or len(x) != 2:
        raise TypeError("expected a pair")
    lo, hi = (_opt_float(v) for v in x)
    if lo is None or hi is None:
        raise TypeError("expected two numbers")
    return (lo, hi)


def log_fingerprint(log: str | Path) -> tuple[str, int, int]:
    """``(file name, size [bytes], modification time [ns])`` of an episode log: a log that
    was written again (a re-run episode) has another, so its figure is drawn again.

    Raises:
        OSError: when the file cannot be read.
    """
    st = os.stat(log)
    return (Path(log).name, int(st.st_size), int(st.st_mtime_ns))


#: the first bytes of every PNG file
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def read_timeline_stamp(png: str | Path) -> TimelineStamp | None:
    """The :class:`TimelineStamp` of a figure that :func:`plot_episode_timeline` drew, or
    None when the file is missing, not a PNG, cut short, or holds no stamp of this format
    (then the figure is drawn again). Reads the PNG's chunk headers and its text chunks only,
    not the image."""
    key = STAMP_KEY.encode("latin-1") + b"\x00"
    try:
        with open(png, "rb") as f:
            if f.read(8) != _PNG_SIGNATURE:
                return None
            while True:
                head = f.read(8)
                if len(head) < 8:
                    return None
                n, kind = int.from_bytes(head[:4], "big"), head[4:]
                if kind == b"IEND":
                    return None
                if kind == b"tEXt":
                    data = f.read(n)
                    if len(data) < n:
                        return None
                    if data.startswith(key):
                        return TimelineStamp.from_json(data[len(key) :].decode("latin-1"))
                    f.seek(4, os.SEEK_CUR)  # CRC
                else:
                    f.seek(n + 4, os.SEEK_CUR)
    except OSError:
        return None


def plot_episode_timeline(
    episode: Episode | str | Path | Timeline,
    out_path: str | Path,
    axes: SharedAxes | None = None,
    *,
    source: str | Path | None = None,
) -> Path:
    """Draw one episode as four panels sharing the time axis.

    1. closest distance between the robot's and the person's spheres [cm], at the scene
       samples, with their least value marked and the episode's own minimum
       (``eval/min_distance``, at the metric samples, 25 Hz by default) drawn
       as a dotted line, both named in the legend;
    2. each plan's largest collision bound against ``1 - confidence`` (log scale, values below
       1e-12 drawn at 1e-12; plans that were not feasible, cut short by a wait or evasive,
       as crosses: the bound, the static clearance or the velocity limits stopped them);
    3. the forecast action probabilities, with the person's real reaches shaded in the colour
       of their action;
    4. the arm's joint speed [rad/s].

    The planner's waits are shaded red in every panel and the robot's picks and deliveries
    are vertical lines. Every action has its own colour (:func:`action_colours`); the legends
    stand to the right of their panels, outside the plotting area. With ``axes`` the time,
    distance and speed axes span the given ranges (``iplanner-experiment`` gives the figures
    of a scenario the same, from :func:`shared_axes_by_scenario`), so figures side by side
    compare by eye.

    Args:
        episode: an :class:`~iplanner_torch.recording.Episode`, the path of its log, or a
            :class:`Timeline` already made.
        out_path: the PNG to write (its folder is created).
        axes: ranges shared with other episodes' figures (:func:`shared_axes`); None: this
            episode's own (time from 0 to its end).
        source: the log the timeline was read from, when ``episode`` is not its path; its
            :func:`log_fingerprint` goes into the figure's :class:`TimelineStamp` (the PNG
            text :data:`STAMP_KEY`, with the extremes and the axes drawn on).

    Returns:
        ``out_path`` as a Path.

    Raises:
        DataError: see :func:`episode_timeline`.
        ConfigError: when ``axes`` is not a :class:`SharedAxes` or None.
    """
    if axes is not None and not isinstance(axes, SharedAxes):
        raise ConfigError(f"expected axes a SharedAxes or None, got {type(axes).__name__}")
    if source is None and isinstance(episode, (str, Path)):
        source = episode
    tl = episode if isinstance(episode, Timeline) else episode_timeline(episode)
    try:  # after the read, whose DataError names a missing log
        fingerprint = None if source is None else log_fingerprint(source)
    except OSError:  # gone since: the figure is stamped without it and drawn again next time
        fingerprint = None
    shared = axes if axes is not None else SharedAxes()
    fig = Figure(figsize=(11.0, 8.0))
    panels = fig.subplots(4, 1, sharex=True, height_ratios=[1.2, 1.0, 1.2, 0.8])
    dist, bound, act, speed = panels
    end = max(tl.end_t, 1e-3)
    for ax in panels:
        for i, (s, e) in enumerate(tl.waits):
            ax.axvspan(
                s,
                e,
                color="tab:red",
                alpha=0.15,
                lw=0,
                label="wait" if i == 0 and ax is dist else None,
            )
        for t, kind, _ in tl.robot_events:
            ax.axvline(t, color="0.55", lw=0.8, ls=ROBOT_EVENTS[kind])
        ax.grid(alpha=0.3)

    # 1. distance
    if tl.gap_m.size:
        every = float(np.median(np.diff(tl.scene_t))) if tl.scene_t.size > 1 else np.nan
        rate = f", every {every:.2g} s" if np.isfinite(every) else ""
        label = f"closest distance (scene samples{rate})"
        dist.plot(tl.scene_t, 100.0 * tl.gap_m, color="k", lw=1.3, label=label)
        dist.axhline(0.0, color="tab:red", lw=1.0)
        if np.isfinite(tl.gap_m).any():
            i = int(np.nanargmin(tl.gap_m))
            dist.plot(
                tl.scene_t[i],
                100.0 * tl.gap_m[i],
                "o",
                color="tab:red",
                ms=5,
                label=f"least sampled {100.0 * tl.gap_m[i]:.1f} cm at {tl.scene_t[i]:.1f} s",
            )
    else:
        _empty(dist, "no scene messages")
    if np.isfinite(tl.min_distance_m):
        dist.axhline(
            100.0 * tl.min_distance_m,
            color="tab:red",
            lw=1.0,
            ls=":",
            label=f"episode minimum {100.0 * tl.min_distance_m:.1f} cm\n"
            "(eval/min_distance, at the metric samples)",
        )
    dist.set_ylabel("robot-person\ndistance [cm]")
    if shared.distance_cm is not None:
        dist.set_ylim(*shared.distance_cm)
    for s, e, _ in tl.reaches:
        dist.axvspan(s, e if e == e else end, color="tab:blue", alpha=0.08, lw=0)
    handles, labels = dist.get_legend_handles_labels()
    if handles:
        _legend_outside(dist)

    # 2. collision bound
    if tl.plan_t.size and np.isfinite(tl.max_bound).any():
        floor = 1e-12
        b = np.clip(tl.max_bound, floor, None)
        ok = tl.feasible & np.isfinite(b)
        bound.semilogy(tl.plan_t[ok], b[ok], "o", ms=3, color="tab:green", label="plan")
        bad = ~tl.feasible & np.isfinite(b)
        if bad.any():
            bound.semilogy(
                tl.plan_t[bad],
                b[bad],
                "x",
                ms=5,
                color="tab:red",
                label="plan cut short (wait or evasion)",
            )
        if np.isfinite(tl.limit).any():
            bound.step(
                tl.plan_t, tl.limit, where="post", color="k", lw=1.0, label="limit 1 - confidence"
            )
        _legend_outside(bound)
    else:
        _empty(bound, "no collision bounds logged")
    bound.set_ylabel("collision bound\n(floor 1e-12)")
    # plain "1e-05" labels: the default ones are mathtext, which needs fonts a stripped
    # matplotlib may lack (it then prints a page of findfont warnings)
    bound.yaxis.set_major_formatter(LogFormatter())

    # 3. action probabilities
    if tl.forecast_t.size:
        colours = action_colours(len(tl.action_names))
        for j, name in enumerate(tl.action_names):
            colour = colours[j]
            act.plot(tl.forecast_t, tl.weights[:, j], color=colour, lw=1.2, label=name)
            for s, e, real in tl.reaches:
                if real == name:
                    act.axvspan(s, e if e == e else end, color=colour, alpha=0.15, lw=0)
        act.set_ylim(-0.03, 1.03)
        _legend_outside(act, ncol=1 if len(tl.action_names) <= 12 else 2)
    else:
        _empty(act, next((n for n in tl.notes if n.startswith("no forecasts")), "no forecasts"))
        for s, e, _ in tl.reaches:
            act.axvspan(s, e if e == e else end, color="tab:blue", alpha=0.08, lw=0)
    act.set_ylabel("action\nprobability")

    # 4. arm speed
    if tl.speed.size:
        speed.plot(tl.robot_t, tl.speed, color="tab:purple", lw=1.0)
    else:
        _empty(speed, "no joint states")
    speed.set_ylabel("arm speed\n[rad/s]")
    if shared.speed is not None:
        speed.set_ylim(0.0, shared.speed)
    speed.set_xlabel(
        "time [s]   (shaded: red waits, the person's reaches; lines: "
        "robot picks ··· and deliveries - -)",
        fontsize="small",
    )
    speed.set_xlim(0.0, max(end, shared.end_t or 0.0))

    title = tl.title + ("" if tl.complete else "  (log cut short: drawn as far as it goes)")
    fig.suptitle(title, fontsize="medium")
    fig.tight_layout()
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    stamp = TimelineStamp(timeline_extremes(tl), shared, fingerprint)
    fig.savefig(out, dpi=100, metadata={STAMP_KEY: stamp.to_json()})
    return out


def _legend_outside(ax, ncol: int = 1) -> None:
    """The legend of ``ax`` to the right of it, outside the plotting area, so that it covers
    no line or marker (``fig.tight_layout()`` makes room for it)."""
    ax.legend(
        fontsize="x-small",
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        borderaxespad=0.0,
        ncol=ncol,
    )


def _empty(ax, text: str) -> None:
    ax.text(
        0.5,
        0.5,
        text,
        transform=ax.transAxes,
        ha="center",
        va="center",
        color="0.4",
        fontsize="small",
    )
