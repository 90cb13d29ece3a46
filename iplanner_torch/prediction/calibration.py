"""Online calibration of the forecast's spread from how far recent forecasts missed.

A predictor can be overconfident exactly where it matters most: a motion it was never trained on
(``experiments/speed_response/``: an arm raised into the robot's path at twice the trained
speed, which the forecasts miss by 15 cm) gets the narrow variances of a familiar reach. The
planner's collision bound then trusts a forecast that the person has already left.

:class:`SpreadCalibrator` scores every recorded forecast against the tracked frames that arrive
afterwards. For a tracked joint ``o`` at a forecast frame with mixture mean ``mu`` and mixture
variance ``v`` per coordinate (moment matched over the actions) and tracker noise ``sigma``,
the normalised squared error

    z = mean over the 3 coordinates of (o - mu)^2 / (v + sigma^2)

has expectation 1 when the forecast is calibrated. The calibrator keeps the residuals of the
last ``memory_s`` seconds and multiplies the variances of the next forecast by

    s = clip(mean z / tolerance, 1, max_scale),

so a forecast is never made narrower, and widened only when its recent predecessors missed by
more than ``tolerance`` times what their own variances allowed. Only the chosen joints are
scored (by default elbows and hands, the parts of a person that move into the robot's way).

Measured in that experiment it did not prevent a contact: the arm reaches the robot about
0.25 s after it starts, before the misses show (``experiments/speed_response/``). It is off by
default (``EpisodeCfg.spread_tolerance``).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.prediction.forecast import Forecast

#: the joints scored by default: the arm parts that reach into the shared workspace
DEFAULT_JOINTS: tuple[str, ...] = ("left_elbow", "left_hand", "right_elbow", "right_hand")


@dataclass(frozen=True, kw_only=True)
class CalibrationCfg:
    """How the forecast's spread follows its recent errors."""

    # joints scored (names of the forecast's joints)
    joints: tuple[str, ...] = DEFAULT_JOINTS
    # a forecast frame is scored only up to this long after the forecast's last observation [s]
    horizon_s: float = 1.0
    # residuals of tracked frames at most this old count in the scale [s]
    memory_s: float = 1.0
    # the mean normalised squared error that is still accepted (1: exact calibration)
    tolerance: float = 2.0
    # the largest variance factor (16: standard deviations up to 4x the predictor's)
    max_scale: float = 16.0

    def __post_init__(self) -> None:
        joints = self.joints
        if isinstance(joints, str | bytes) or not isinstance(joints, Sequence) or not joints:
            raise ConfigError(
                f"expected CalibrationCfg.joints a non-empty list of names, got {joints!r}"
            )
        if not all(isinstance(j, str) for j in joints):
            raise ConfigError(f"expected CalibrationCfg.joints names (strings), got {joints!r}")
        object.__setattr__(self, "joints", tuple(joints))
        checks.positive("CalibrationCfg.horizon_s", self.horizon_s)
        checks.positive("CalibrationCfg.memory_s", self.memory_s)
        checks.positive("CalibrationCfg.tolerance", self.tolerance)
        if not checks.finite("CalibrationCfg.max_scale", self.max_scale) >= 1.0:
            raise ConfigError(f"expected CalibrationCfg.max_scale >= 1, got {self.max_scale!r}")


class SpreadCalibrator:
    """Scores forecasts against the frames tracked after them and widens the next forecast.

    Use per planning cycle: :meth:`observe` the tracker's frames, :meth:`record` the new
    forecast as the predictor made it, then :meth:`apply` the scale to it for the planner
    (scored unscaled, the forecasts do not make the scale chase its own widening).

    Args:
        cfg: the calibration settings.
        joint_names: the K joint names of the forecasts and tracked frames.
        noise_std: standard deviation of the tracker's noise per coordinate [m], >= 0.

    Raises:
        ConfigError: when a joint of ``cfg.joints`` is not among ``joint_names``, or
            ``noise_std`` is not a finite number >= 0.
    """

    def __init__(self, cfg: CalibrationCfg, joint_names: Sequence[str], *, noise_std: float):
        self.cfg = cfg
        names = list(joint_names)
        missing = [j for j in cfg.joints if j not in names]
        if missing:
            raise ConfigError(
                f"CalibrationCfg.joints {missing} are not among the forecast's joints {names}"
            )
        self._idx = np.array([names.index(j) for j in cfg.joints], dtype=np.int64)
        self._k = len(names)
        self._noise_var = checks.non_negative("noise_std", noise_std) ** 2
        # recorded forecasts: (t0, dt, mixture mean (n_f, J_c, 3), mixture var (n_f, J_c, 3))
        self._forecasts: deque[tuple[float, float, np.ndarray, np.ndarray]] = deque()
        # (time of the tracked frame, z) of every scored joint
        self._residuals: deque[tuple[float, float]] = deque()
        self._last_frame_t = -math.inf
        self.scales: list[float] = []  # the scale of every apply, for the episode's metrics

    def record(self, forecast: Forecast, t0: float) -> None:
        """Keep ``forecast`` (batch row 0), made from frames up to ``t0`` [s], for scoring.

        Raises:
            ShapeError: when ``forecast`` is not a Forecast or its joints are not the
                calibrator's K.
            DataError: when ``t0`` is not a finite time (NaN was kept and never scored).
        """
        if not isinstance(forecast, Forecast):
            raise ShapeError(f"expected forecast a Forecast, got {type(forecast).__name__}")
        t0 = checks.finite_time("t0", t0, error=DataError)
        k = int(forecast.mean.shape[3])
        if k != self._k:
            raise ShapeError(f"expected a forecast of {self._k} joints, got {k}")
        w = forecast.weights[0].detach().to("cpu", torch.float64)  # (A,)
        # (A, n_f, J_c, 3): the scored joints
        mean = forecast.mean[0][:, :, self._idx].detach().to("cpu", torch.float64)
        var = forecast.var[0][:, :, self._idx].detach().to("cpu", torch.float64).clamp(min=0.0)
        mu = torch.einsum("a,afjc->fjc", w, mean)  # (n_f, J_c, 3)
        second = torch.einsum("a,afjc->fjc", w, var + mean.square())
        v = (second - mu.square()).clamp(min=0.0)  # (n_f, J_c, 3) moment-matched variance
        self._forecasts.append((float(t0), float(forecast.dt), mu.numpy(), v.numpy()))

    def observe(self, times: np.ndarray, frames: np.ndarray) -> None:
        """Score the recorded forecasts on the tracked frames newer than those seen before.

        Args:
            times: (T,) times of the tracked frames [s], increasing.
            frames: (T, K, 3) tracked joint positions [m]; NaN where a joint was lost (not
                scored).

        Raises:
            ShapeError: when ``times`` or ``frames`` are not numbers, or ``frames`` is not
                (T, K, 3) for the ``times`` given.
            DataError: when ``times`` are not finite and strictly increasing (a frame out of
                order moved the frames seen back, and frames were scored twice).
        """
        try:
            times = np.asarray(times, dtype=np.float64)
            frames = np.asarray(frames, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ShapeError(f"expected times and frames arrays of numbers ({err})") from None
        if times.ndim != 1 or frames.shape != (times.shape[0], self._k, 3):
            raise ShapeError(
                f"expected times (T,) and frames (T, {self._k}, 3), got {times.shape} and "
                f"{frames.shape}"
            )
        checks.increasing_times("times", times)
        new = times > self._last_frame_t
        if not new.any():
            return
        horizon = self.cfg.horizon_s
        for t, frame in zip(times[new], frames[new], strict=True):
            obs = frame[self._idx]  # (J_c, 3)
            seen = np.isfinite(obs).all(-1)  # (J_c,)
            if not seen.any():
                continue
            for t0, dt, mu, v in self._forecasts:
                lead = t - t0
                if not 0.0 < lead <= horizon + 1e-9:
                    continue
                k = int(round(lead / dt)) - 1  # frame k lies at t0 + (k + 1) dt
                if not 0 <= k < mu.shape[0] or abs(t0 + (k + 1) * dt - t) > 0.5 * dt + 1e-9:
                    continue
                err = (obs[seen] - mu[k, seen]) ** 2 / (v[k, seen] + self._noise_var + 1e-12)
                for z in err.mean(-1):  # one residual per scored joint
                    self._residuals.append((float(t), float(z)))
        self._last_frame_t = float(times[new][-1])
        # forget forecasts that no new frame can score, and residuals beyond the memory
        while self._forecasts and self._forecasts[0][0] + horizon < self._last_frame_t:
            self._forecasts.popleft()
        while self._residuals and self._residuals[0][0] < self._last_frame_t - self.cfg.memory_s:
            self._residuals.popleft()

    def scale(self) -> float:
        """The variance factor for the next forecast: 1 with no residual in memory."""
        if not self._residuals:
            return 1.0
        mean_z = sum(z for _, z in self._residuals) / len(self._residuals)
        return float(min(max(mean_z / self.cfg.tolerance, 1.0), self.cfg.max_scale))

    def apply(self, forecast: Forecast) -> Forecast:
        """``forecast`` with every variance multiplied by :meth:`scale` (the same forecast when
        it is 1); the scale is appended to :attr:`scales`."""
        s = self.scale()
        self.scales.append(s)
        return forecast if s == 1.0 else forecast.scale_var(s)
