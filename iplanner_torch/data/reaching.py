"""Synthetic human reaching demonstrations (paper sec. 4.1 and 7.1).

A seated person in front of a table rests both hands on it, then reaches with the left or
right arm to one of ``n_targets`` positions on the table, holds briefly and returns; idle
periods come before and after. Each demonstration is one reach, labelled per frame with the
actions ``("idle", "reach_0", ..., "reach_{n-1}", "return")`` (the hold at the target belongs to
``reach_i``).

Target layout (:func:`reach_targets`): two rows on the table, the near row at x = 0.04 m and
the far row at x = 0.18 m, each with ``n_targets / 2`` targets spread evenly over
y in [+0.36, -0.36] m from the human's left to right; target ``i`` is row ``i // cols``,
column ``i % cols`` (column 0 on the human's far left). With the default 8 targets, 0, 1, 4, 5
lie on the left half (reached with the left arm) and 2, 3, 6, 7 on the right half (right arm).
Hand targets are 4 cm above the table top (the palm centre of a hand on the table).

The human is kinematic (:mod:`iplanner_torch.data.kinematic_human`): a rigid trunk that leans
forward and twists as far as a target needs, 2-link arms solved by IK with a natural elbow
swivel, and minimum-jerk hand paths through a via point, so speed profiles are bell-shaped.
Between reaches vary: the body (6 subjects by default: size, bone lengths, seat, resting
hands), the duration, the path's curvature, the reaction time, the trunk sway and the idle
periods. Speed variants (paper sec. 7.1: "we synthesize fast and slow motions by changing the
speed of captured motions") resample time: a factor ``f`` samples the same motion at
``t_k = k f / fps``, so the demonstration lasts ``1 / f`` as long (0.5 slow, 1 medium, 2
fast). Kinect-like sensor noise (Gaussian per coordinate) and bursts of dropped joints (NaN)
are applied on top; the clean positions are kept in ``clean_positions``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

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
    Arm,
    BodyParams,
    MotionPlan,
    arm_for_target,
    plan_hand_move,
    random_sway,
    rest_pose,
    sample_body,
)
from iplanner_torch.data.skeleton import JOINT_INDEX, JOINT_NAMES
from iplanner_torch.errors import ConfigError

__all__ = [
    "BodyParams",
    "DatasetSummary",
    "ReachingCfg",
    "add_tracker_noise",
    "generate_reaching_dataset",
    "reach_action_names",
    "reach_motion",
    "reach_targets",
    "rest_pose",
    "sample_body",
    "speed_name",
]

PHASE_REACH, PHASE_HOLD, PHASE_RETURN = 0, 1, 2


def _numbers(name: str, value: Any) -> tuple[float, ...]:
    """``value`` (a list, tuple or array, not a string) as finite floats."""
    try:
        items = () if isinstance(value, (str, bytes)) else tuple(value)
    except TypeError:
        items = ()
    if not items:
        raise ConfigError(f"{name} must be a non-empty list of numbers, got {value!r}")
    return tuple(checks.finite(name, v) for v in items)


def finite_range(name: str, value: Any) -> tuple[float, float]:
    """``value`` as ``(low, high)`` with ``0 <= low <= high``, both finite [s].

    Raises:
        ConfigError: naming ``name``, unless ``value`` is two such numbers.
    """
    low, high = checks.finite_tuple(name, value, 2)
    if not 0 <= low <= high:
        raise ConfigError(f"{name} must be (low, high) with 0 <= low <= high, got {value!r}")
    return low, high


def check_recording_numbers(prefix: str, fps: Any, noise_sigma: Any, dropout_rate: Any) -> None:
    """Check a generator's frame rate, tracker noise and dropout rate (each a real number,
    not a bool, and finite: :mod:`iplanner_torch.checks`).

    Args:
        prefix: put before each name in the message (``"ReachingCfg."``, or ``""``).

    Raises:
        ConfigError: naming the first of them that is not a finite number or out of its range
            (fps > 0, noise_sigma >= 0, dropout_rate in [0, 1)).
    """
    checks.positive(f"{prefix}fps", fps)
    checks.non_negative(f"{prefix}noise_sigma", noise_sigma)
    if not 0 <= checks.finite(f"{prefix}dropout_rate", dropout_rate) < 1:
        raise ConfigError(f"expected {prefix}dropout_rate in [0, 1), got {dropout_rate!r}")


def reach_targets(n_targets: int = 8) -> np.ndarray:
    """(n_targets, 3) hand targets on the table [m], in the layout of the module docstring.

    Raises:
        ConfigError: unless ``n_targets`` is an even number from 2 to 16.
    """
    if n_targets % 2 or not 2 <= n_targets <= 16:
        raise ConfigError(f"n_targets must be even and in [2, 16], got {n_targets}")
    cols = n_targets // 2
    ys = np.linspace(0.36, -0.36, cols) if cols > 1 else np.array([0.2])
    # rows far enough from the resting hands (x ~ -0.25) that a robot gripper placing a block
    # there keeps ~10 cm from them
    xs = np.array([0.04, 0.18])
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    return np.concatenate([grid, np.full((n_targets, 1), 0.04)], axis=1)


def reach_action_names(n_targets: int) -> tuple[str, ...]:
    """``("idle", "reach_0", ..., "reach_{n-1}", "return")``."""
    return ("idle", *(f"reach_{i}" for i in range(n_targets)), "return")


def speed_name(factor: float) -> str:
    """ "slow" (< 1), "medium" (1) or "fast" (> 1)."""
    return "medium" if np.isclose(factor, 1.0) else ("slow" if factor < 1.0 else "fast")


def frame_times(duration: float, fps: float, speed: float) -> np.ndarray:
    """Times ``k speed / fps`` covering [0, duration]."""
    n = int(np.ceil(duration * fps / speed - 1e-9)) + 1
    return np.arange(n) * (speed / fps)


def reach_motion(
    body: BodyParams,
    arm: Arm,
    target: np.ndarray,
    rng: np.random.Generator,
    *,
    fps: float = 15.0,
    speed: float = 1.0,
    hold_s: float = 0.3,
    start_pose: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One reach of ``arm`` to ``target``, a hold, and the return to the start, without idle.

    Args:
        body: the person (e.g. from :func:`sample_body`).
        arm: the reaching arm.
        target: (3,) hand target [m], table frame.
        rng: random generator for duration, path curvature, lean and sway.
        fps: frame rate [Hz].
        speed: time-resampling factor (2 = twice as fast); ``hold_s`` scales with it.
        hold_s: seconds at the target at speed 1.
        start_pose: (K, 3) pose [m] to start from and return to; its waist places the seat
            and its hands are the start (the trunk starts upright, elbows follow by IK), so a
            translated :func:`rest_pose` moves the whole motion.

    Returns:
        (positions (T, K, 3) clean joint positions [m] float64, phases (T,) int64 with
        0 = reach, 1 = hold, 2 = return); hold frames have the hand exactly at the target.

    Raises:
        ConfigError: for a non-positive fps or speed, a negative hold, a value that is not
            finite, or a bad shape.
    """
    target = np.asarray(target, dtype=np.float64)
    if target.shape != (3,):
        raise ConfigError(f"expected target (3,), got {target.shape}")
    checks.positive("fps", fps)
    checks.positive("speed", speed)
    checks.non_negative("hold_s", hold_s)
    if start_pose is not None:
        start_pose = np.asarray(start_pose, dtype=np.float64)
        if start_pose.shape != (len(JOINT_NAMES), 3):
            raise ConfigError(
                f"expected start_pose ({len(JOINT_NAMES)}, 3), got {start_pose.shape}"
            )
        waist = start_pose[JOINT_INDEX["waist"]]
        body = replace(body, seat_x=waist[0], seat_y=waist[1], waist_z=waist[2])
    plan = MotionPlan(body=body)
    if start_pose is not None:
        plan.start_hands = {a: start_pose[JOINT_INDEX[f"{a}_hand"]] for a in ("left", "right")}
    random_sway(plan, rng, amplitude=0.01)
    start_hand = plan.state_at_end()[0][arm]
    go = plan_hand_move(plan, arm, target, 0.0, rng, lean=True)
    back = plan_hand_move(
        plan, arm, start_hand, go.t1 + hold_s, rng, lean=False,
        duration=go.duration * rng.uniform(1.0, 1.2),
    )  # fmt: skip
    t = frame_times(back.t1, fps, speed)
    phases = np.where(t < go.t1, PHASE_REACH, np.where(t < back.t0, PHASE_HOLD, PHASE_RETURN))
    return plan.positions(t), phases.astype(np.int64)


def add_tracker_noise(
    clean: np.ndarray,
    rng: np.random.Generator,
    *,
    sigma: float = 0.01,
    dropout_rate: float = 0.005,
    dropout_burst: float = 3.0,
) -> np.ndarray:
    """Kinect-like tracking errors on top of clean positions.

    Gaussian noise of standard deviation ``sigma`` on every coordinate, and lost joints (all
    three coordinates NaN) in bursts: a burst starts at a joint-frame with probability
    ``dropout_rate / dropout_burst`` and lasts 1 + Poisson(``dropout_burst`` - 1) frames, so
    about ``dropout_rate`` of joint-frames are lost.

    Args:
        clean: (T, K, 3) positions [m].
        rng: random generator.
        sigma: noise standard deviation [m].
        dropout_rate: expected fraction of lost joint-frames.
        dropout_burst: mean burst length [frames], >= 1.

    Returns:
        (T, K, 3) noisy positions [m], float32, NaN where lost.
    """
    t, k, _ = clean.shape
    noisy = clean + sigma * rng.standard_normal(clean.shape)
    if dropout_rate > 0:
        starts = np.argwhere(rng.random((t, k)) < dropout_rate / dropout_burst)
        lengths = 1 + rng.poisson(max(dropout_burst - 1.0, 0.0), size=len(starts))
        for (f, j), n in zip(starts, lengths):
            noisy[f : f + n, j] = np.nan
    return noisy.astype(np.float32)


@dataclass(frozen=True, kw_only=True)
class ReachingCfg:
    """Settings of the synthetic reaching dataset (paper sec. 7.1: 8 targets x 30 reaches)."""

    n_targets: int = 8  # targets on the table (even, 2..16); layout in the module docstring
    reaches_per_target: int = 30  # demonstrations per target (per speed)
    n_subjects: int = 6  # distinct bodies; reach r of every target is done by subject r % n
    fps: float = 15.0  # frame rate of the tracker [Hz] (Kinect in the paper)
    noise_sigma: float = 0.01  # Gaussian tracker noise per coordinate [m]
    dropout_rate: float = 0.005  # expected fraction of lost (NaN) joint-frames
    dropout_burst: float = 3.0  # mean length of a dropout burst [frames]
    speeds: tuple[float, ...] = (1.0,)  # time-resampling factors (0.5 slow, 1, 2 fast)
    hold_s: tuple[float, float] = (0.2, 0.5)  # uniform range of the hold at the target [s]
    idle_start_s: tuple[float, float] = (0.6, 1.2)  # uniform range of the first idle [s]
    reaction_s: tuple[float, float] = (0.1, 0.4)  # uniform range of extra reaction time [s]
    idle_end_s: tuple[float, float] = (0.5, 1.0)  # uniform range of the final idle [s]
    seed: int = 0  # everything is a function of this seed
    file_format: Literal["npz", "csv"] = "npz"  # one file per demonstration

    def __post_init__(self) -> None:
        # every float is checked finite first (NaN and Inf pass a bare "x < 0" test)
        speeds = _numbers("ReachingCfg.speeds", self.speeds)
        if any(not v > 0 for v in speeds):
            raise ConfigError(f"ReachingCfg.speeds must be > 0, got {speeds}")
        object.__setattr__(self, "speeds", speeds)
        for name in ("hold_s", "idle_start_s", "reaction_s", "idle_end_s"):
            object.__setattr__(
                self, name, finite_range(f"ReachingCfg.{name}", getattr(self, name))
            )
        reach_targets(self.n_targets)  # validates n_targets
        for name in ("reaches_per_target", "n_subjects"):  # each by name
            checks.integer(f"ReachingCfg.{name}", getattr(self, name), minimum=1)
        check_recording_numbers("ReachingCfg.", self.fps, self.noise_sigma, self.dropout_rate)
        if not checks.finite("ReachingCfg.dropout_burst", self.dropout_burst) >= 1:
            raise ConfigError(
                f"expected ReachingCfg.dropout_burst >= 1 [frames], got {self.dropout_burst!r}"
            )
        if self.file_format not in ("npz", "csv"):
            raise ConfigError(f"file_format must be 'npz' or 'csv', got {self.file_format!r}")
        object.__setattr__(self, "seed", checks.seed(self.seed, name="ReachingCfg.seed"))


def reaching_demonstrations(cfg: ReachingCfg, target: int, rep: int) -> list[Demonstration]:
    """The demonstrations of reach ``rep`` to ``target``, one per speed in ``cfg.speeds``.

    Deterministic: a function of ``(cfg.seed, target, rep)`` only.
    """
    targets = reach_targets(cfg.n_targets)
    subject = rep % cfg.n_subjects
    body = sample_body(np.random.default_rng([cfg.seed, 0, subject]))
    rng = np.random.default_rng([cfg.seed, 1, target, rep])
    p = targets[target]
    arm = arm_for_target(body, p)
    plan = MotionPlan(body=body)
    random_sway(plan, rng)
    idle0 = rng.uniform(*cfg.idle_start_s)
    reaction = rng.uniform(*cfg.reaction_s)
    hold = rng.uniform(*cfg.hold_s)
    start_hand = body.rest_hand(arm)
    go = plan_hand_move(plan, arm, p, idle0 + reaction, rng, lean=True)
    back = plan_hand_move(
        plan, arm, start_hand, go.t1 + hold, rng, lean=False,
        duration=go.duration * rng.uniform(1.0, 1.25),
    )  # fmt: skip
    end = back.t1 + rng.uniform(*cfg.idle_end_s)
    actions = reach_action_names(cfg.n_targets)
    out = []
    for si, speed in enumerate(cfg.speeds):
        t = frame_times(end, cfg.fps, speed)
        labels = np.where(
            t < go.t0,
            0,
            np.where(t < back.t0, 1 + target, np.where(t < back.t1, len(actions) - 1, 0)),
        )
        clean = plan.positions(t).astype(np.float32)
        noise_rng = np.random.default_rng([cfg.seed, 2, target, rep, si])
        noisy = add_tracker_noise(
            clean,
            noise_rng,
            sigma=cfg.noise_sigma,
            dropout_rate=cfg.dropout_rate,
            dropout_burst=cfg.dropout_burst,
        )
        out.append(
            Demonstration(
                positions=noisy,
                labels=labels,
                fps=cfg.fps,
                joint_names=JOINT_NAMES,
                action_names=actions,
                name=f"reach_t{target}_r{rep:02d}_v{speed:g}",
                clean_positions=clean,
                metadata={
                    "generator": "reaching",
                    "target": target,
                    "target_position": p.tolist(),
                    "arm": arm,
                    "repetition": rep,
                    "subject": subject,
                    "speed": speed,
                    "speed_name": speed_name(speed),
                    "noise_sigma": cfg.noise_sigma,
                    "dropout_rate": cfg.dropout_rate,
                    "seed": cfg.seed,
                    "reaction_s": reaction / speed,
                    "hold_s": hold / speed,
                    "body_scale": body.scale,
                },
            )
        )
    return out


def generate_reaching_dataset(
    cfg: ReachingCfg,
    out_dir: str | Path = Path("datasets/reaching"),
    *,
    progress: bool = True,
    command: str | None = None,
    replace: Sequence[Path] = (),
) -> DatasetSummary:
    """Generate the reaching dataset: one file per demonstration plus ``README.md``.

    Files are named ``reach_t{target}_r{rep:02d}_v{speed}.{npz|csv}``. They are written into
    a temporary folder beside ``out_dir`` and moved into it only when all are written, so an
    error or interrupt leaves ``out_dir`` as it was
    (:func:`~iplanner_torch.data.dataset_card.staged_dataset`).

    Args:
        cfg: the settings.
        out_dir: destination folder (created; same-named files in it are replaced).
        progress: show a tqdm progress bar.
        command: the command line to record in the dataset card (default: the Python call).
        replace: an earlier dataset's files in ``out_dir``
            (:func:`~iplanner_torch.data.dataset_card.check_dataset_folder`), deleted once the
            new dataset is complete.

    Returns:
        The summary (counts, files, time, size).
    """
    out_dir = Path(out_dir)
    t_start = time.perf_counter()
    files: list[Path] = []
    n_frames = 0
    jobs = [(t, r) for t in range(cfg.n_targets) for r in range(cfg.reaches_per_target)]
    with staged_dataset(out_dir) as staging:
        for target, rep in tqdm(jobs, desc="reaching", disable=not progress, unit="reach"):
            for demo in reaching_demonstrations(cfg, target, rep):
                path = staging / f"{demo.name}.{cfg.file_format}"
                files.append(save_demonstration(demo, path))
                n_frames += demo.num_frames
        seconds = time.perf_counter() - t_start
        summary = DatasetSummary.of_files(staging, files, n_frames, seconds)
        speeds = ", ".join(f"{s:g} ({speed_name(s)})" for s in cfg.speeds)
        write_dataset_card(
            summary,
            title="Synthetic reaching dataset",
            facts=[
                ("targets x reaches per target", f"{cfg.n_targets} x {cfg.reaches_per_target}"),
                ("subjects", str(cfg.n_subjects)),
                ("actions", ", ".join(reach_action_names(cfg.n_targets))),
                ("joints", ", ".join(JOINT_NAMES)),
                ("fps", f"{cfg.fps:g}"),
                ("speed factors", speeds),
                ("noise sigma", f"{cfg.noise_sigma:g} m"),
                ("dropout rate / burst", f"{cfg.dropout_rate:g} / {cfg.dropout_burst:g} frames"),
                ("seed", str(cfg.seed)),
                ("format", cfg.file_format),
            ],
            settings=generator_settings(cfg),
            command=command
            or (
                'python -c "from iplanner_torch.data.reaching import *; '
                f"generate_reaching_dataset({cfg!r}, '{out_dir}')\""
            ),
        )
    return finish_staged_dataset(summary, out_dir, replace=replace)
