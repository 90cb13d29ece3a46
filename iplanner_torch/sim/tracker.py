"""A simulated depth-camera skeleton tracker: the planner's only view of the human.

It samples the true joint positions at ``fps`` (15 Hz, like the paper's Kinect tracking), adds
isotropic Gaussian noise of standard deviation ``noise_sigma`` per coordinate, drops whole
joints (all three coordinates NaN) independently with probability ``dropout_rate`` per joint
and frame, and keeps the last ``window`` frames.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from iplanner_torch.errors import ConfigError, ShapeError


@dataclass(frozen=True, kw_only=True)
class TrackerCfg:
    """Sampling and corruption of the tracked skeleton."""

    # tracker frame rate [Hz]
    fps: float = 15.0
    # standard deviation of the additive Gaussian noise per coordinate [m]
    noise_sigma: float = 0.01
    # probability that a joint is missing (NaN) in a frame
    dropout_rate: float = 0.0
    # frames kept (n_p of the predictor)
    window: int = 15

    def __post_init__(self) -> None:
        if self.fps <= 0:
            raise ConfigError(f"expected fps > 0, got {self.fps}")
        if self.noise_sigma < 0:
            raise ConfigError(f"expected noise_sigma >= 0, got {self.noise_sigma}")
        if not 0.0 <= self.dropout_rate < 1.0:
            raise ConfigError(f"expected dropout_rate in [0, 1), got {self.dropout_rate}")
        if self.window < 1:
            raise ConfigError(f"expected window >= 1, got {self.window}")


class Tracker:
    """Noisy, lossy 15 Hz observations of the human.

    Args:
        cfg: sampling and corruption.
        seed: seed of the noise and dropouts (same seed -> same observations).
    """

    def __init__(self, cfg: TrackerCfg, *, seed: int) -> None:
        self.cfg = cfg
        self.seed = int(seed)
        self.reset()

    def reset(self) -> None:
        """Forget every frame; the next :meth:`observe` samples immediately."""
        self._rng = np.random.default_rng([self.seed, 15])
        self._frames: deque[np.ndarray] = deque(maxlen=self.cfg.window)
        self._times: deque[float] = deque(maxlen=self.cfg.window)
        self._last_valid: np.ndarray | None = None
        self._next_t = 0.0
        self.num_frames = 0

    def observe(self, t: float, joints: np.ndarray) -> bool:
        """Take a frame of ``joints`` if a sample is due at time ``t``.

        Args:
            t: simulated time [s].
            joints: (K, 3) true joint positions [m] at ``t``.

        Returns:
            Whether a frame was taken.

        Raises:
            ShapeError: when ``joints`` is not (K, 3).
        """
        if joints.ndim != 2 or joints.shape[1] != 3:
            raise ShapeError(f"expected joints (K, 3), got {tuple(joints.shape)}")
        if t + 1e-9 < self._next_t:
            return False
        period = 1.0 / self.cfg.fps
        while self._next_t <= t + 1e-9:
            self._next_t += period
        frame = joints + self._rng.normal(0.0, self.cfg.noise_sigma, size=joints.shape)
        lost = self._rng.random(joints.shape[0]) < self.cfg.dropout_rate
        frame[lost] = np.nan
        if self._last_valid is None:
            self._last_valid = np.where(lost[:, None], joints, frame)
        else:
            self._last_valid = np.where(lost[:, None], self._last_valid, frame)
        self._frames.append(frame)
        self._times.append(float(t))
        self.num_frames += 1
        return True

    @property
    def ready(self) -> bool:
        """Whether a full window has been observed."""
        return len(self._frames) == self.cfg.window

    def window(self) -> np.ndarray:
        """(n_p, K, 3) the last ``window`` frames [m], oldest first, NaN where lost.

        Before ``window`` frames exist, the oldest frame is repeated in front.

        Raises:
            ShapeError: when nothing has been observed yet.
        """
        if not self._frames:
            raise ShapeError("expected at least one tracked frame, got none")
        frames = list(self._frames)
        pad = [frames[0]] * (self.cfg.window - len(frames))
        return np.stack(pad + frames).astype(np.float32)

    def times(self) -> np.ndarray:
        """(len,) times of the stored frames [s], oldest first."""
        return np.asarray(self._times, dtype=np.float64)

    def latest_pose(self) -> np.ndarray:
        """(K, 3) the newest frame with lost joints filled from their last observation [m].

        The first frame's lost joints (never seen) are filled from the true pose of that frame
        (the tracker's initialisation).

        Raises:
            ShapeError: when nothing has been observed yet.
        """
        if self._last_valid is None:
            raise ShapeError("expected at least one tracked frame, got none")
        return self._last_valid.astype(np.float32)
