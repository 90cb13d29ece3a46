"""A simulated depth-camera skeleton tracker: the planner's only view of the human.

It samples the true joint positions at ``fps`` (15 Hz, like the paper's Kinect tracking), adds
isotropic Gaussian noise of standard deviation ``noise_sigma`` per coordinate, drops whole
joints (all three coordinates NaN) independently with probability ``dropout_rate`` per joint
and frame, and keeps the last ``window`` frames.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, DataError, ShapeError

#: Observe catches up on missed samples one period at a time (as it always has, so the sample
#: times keep their floating-point sums) for gaps of up to this many periods; longer gaps jump
#: to the first sample after ``t`` arithmetically, so a far-off ``t`` cannot stall it.
_MAX_CATCH_UP = 1024


#: largest tracker noise standard deviation [m]: a metre of noise per coordinate is no longer
#: a tracker of a person at a table (larger values used to run, the I-Planner then stopping
#: at the predictor's coordinate limit and ITOMP planning around a person 100 m away)
MAX_NOISE_M = 1.0

#: most frames a tracker window holds (11 min at 15 Hz; predictors look at about 15): a window
#: of 10^12 frames was accepted and :meth:`Tracker.window` then ran out of memory padding it
MAX_WINDOW = 10_000


@dataclass(frozen=True, kw_only=True)
class TrackerCfg:
    """Sampling and corruption of the tracked skeleton."""

    # tracker frame rate [Hz]
    fps: float = 15.0
    # standard deviation of the additive Gaussian noise per coordinate [m]
    noise_sigma: float = 0.01
    # probability that a joint is missing (NaN) in a frame
    dropout_rate: float = 0.0
    # frames kept (n_p of the predictor), at most MAX_WINDOW
    window: int = 15

    def __post_init__(self) -> None:
        checks.positive("fps", self.fps)
        if not checks.non_negative("noise_sigma", self.noise_sigma) <= MAX_NOISE_M:
            raise ConfigError(
                f"expected noise_sigma in [0, {MAX_NOISE_M:g}] m, got {self.noise_sigma!r}"
            )
        if not 0.0 <= checks.finite("dropout_rate", self.dropout_rate) < 1.0:
            raise ConfigError(f"expected dropout_rate in [0, 1), got {self.dropout_rate!r}")
        if checks.integer("window", self.window, minimum=1) > MAX_WINDOW:
            raise ConfigError(f"expected window <= {MAX_WINDOW} frames, got {self.window!r}")


class Tracker:
    """Noisy, lossy 15 Hz observations of the human.

    Args:
        cfg: sampling and corruption.
        seed: seed of the noise and dropouts (same seed -> same observations), >= 0.

    Raises:
        ConfigError: when ``seed`` is not a non-negative integer.
    """

    def __init__(self, cfg: TrackerCfg, *, seed: int) -> None:
        self.cfg = cfg
        self.seed = checks.seed(seed)
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

        Samples are due at ``0, 1/fps, 2/fps, ...``; after a gap the next one is due at the first
        multiple of the period after ``t``.

        Args:
            t: simulated time [s], finite.
            joints: (K, 3) true joint positions [m] at ``t`` (any array-like); K must stay
                the same between frames.

        Returns:
            Whether a frame was taken.

        A true joint that is NaN or infinite (the caller could not place it) is taken as lost
        in that frame, like a dropout: NaN in :meth:`window`, held in :meth:`latest_pose`.

        Raises:
            DataError: when ``t`` is NaN or infinite, or a true joint of the first frame (which
                initialises the held pose) is not finite.
            ShapeError: when ``joints`` is not (K, 3) of real numbers, or K differs from
                the stored frames'.
        """
        # a tensor on any device, with a gradient or not, is taken as its values
        joints = checks.real_array("joints", joints)
        if joints.ndim != 2 or joints.shape[1] != 3:
            raise ShapeError(f"expected joints (K, 3), got {tuple(joints.shape)}")
        if self._frames and joints.shape[0] != self._frames[-1].shape[0]:
            raise ShapeError(
                f"expected joints ({self._frames[-1].shape[0]}, 3) like the stored frames, got "
                f"K = {joints.shape[0]}"
            )
        checks.finite_time("t", t, error=DataError)
        due = t + 1e-9
        if due < self._next_t:
            return False
        period = 1.0 / self.cfg.fps
        if (due - self._next_t) < _MAX_CATCH_UP * period:
            while self._next_t <= due:
                self._next_t += period
        else:
            periods = (due - self._next_t) / period
            if math.isfinite(periods):
                self._next_t += (math.floor(periods) + 1) * period
            if self._next_t <= due:  # rounding, or a t so large that a period vanishes in it
                self._next_t = max(self._next_t + period, math.nextafter(due, math.inf))
        unseen = ~np.isfinite(joints).all(1)  # (K,) a NaN or inf true joint: not observed
        if unseen.any() and self._last_valid is None:
            raise DataError(
                f"the tracker's first frame (t = {t:g} s) has non-finite true joints (index "
                f"{np.flatnonzero(unseen).tolist()}): it initialises the held pose"
            )
        frame = joints + self._rng.normal(0.0, self.cfg.noise_sigma, size=joints.shape)
        lost = (self._rng.random(joints.shape[0]) < self.cfg.dropout_rate) | unseen
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
