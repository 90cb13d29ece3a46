"""The in-memory form of one recorded demonstration (paper sec. 3.1: xi, a^h)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(kw_only=True)
class Demonstration:
    """One recording of a person: joint positions and per-frame action labels.

    Attributes:
        positions: (T, K, 3) joint positions [m], float32; NaN marks a joint the tracker lost
            in that frame (kept as NaN, never silently filled).
        labels: (T,) int64 index into ``action_names`` of the action performed at each frame;
            -1 means unlabelled.
        fps: frames per second.
        joint_names: the K joint names, in the order of the K axis.
        action_names: the A action names; label ``a`` means ``action_names[a]``.
        timestamps: (T,) float64 seconds, strictly increasing; ``arange(T) / fps`` when the
            file gives none.
        name: an identifier (a loaded file's path relative to its folder, without the suffix;
            a generated id).
        metadata: free-form provenance (subject, target, speed factor, noise sigma, seed ...).
        clean_positions: (T, K, 3) noise-free joint positions [m], float32, when the recording
            is synthetic (ground truth for evaluations); None for real recordings.
    """

    positions: np.ndarray
    labels: np.ndarray
    fps: float
    joint_names: tuple[str, ...]
    action_names: tuple[str, ...]
    timestamps: np.ndarray | None = None
    name: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)
    clean_positions: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float32)
        if self.clean_positions is not None:
            self.clean_positions = np.asarray(self.clean_positions, dtype=np.float32)
        self.labels = np.asarray(self.labels, dtype=np.int64)
        self.joint_names = tuple(self.joint_names)
        self.action_names = tuple(self.action_names)
        if self.timestamps is None:
            self.timestamps = np.arange(self.positions.shape[0], dtype=np.float64) / self.fps
        else:
            self.timestamps = np.asarray(self.timestamps, dtype=np.float64)

    @property
    def num_frames(self) -> int:
        """T, the number of frames."""
        return int(self.positions.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return float(self.timestamps[-1] - self.timestamps[0]) if self.num_frames else 0.0

    @property
    def num_joints(self) -> int:
        """K, the number of joints."""
        return int(self.positions.shape[1])

    def select_joints(self, joints: tuple[str, ...] | list[str]) -> Demonstration:
        """A copy holding only ``joints`` (in the given order).

        Raises:
            ValueError: when a joint is not in ``joint_names``.
        """
        idx = [self.joint_names.index(j) for j in joints]
        return Demonstration(
            positions=self.positions[:, idx],
            labels=self.labels.copy(),
            fps=self.fps,
            joint_names=tuple(joints),
            action_names=self.action_names,
            timestamps=self.timestamps.copy(),
            name=self.name,
            metadata=dict(self.metadata),
            clean_positions=None if self.clean_positions is None else self.clean_positions[:, idx],
        )
