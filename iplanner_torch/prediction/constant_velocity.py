"""A constant-velocity forecast: the reference a learned predictor has to beat.

Each joint's last ``fit_frames`` tracked positions are fitted with a straight line in time
(least squares, per coordinate, the lost frames left out), and the line is extended over the
horizon: one action, no intention, no learning. It is the usual baseline of human motion
prediction, and it tells apart what the I-Planner gains from forecasting motion at all (ITOMP
holds the seen pose still) from what it gains from the learned actions.

The spread of frame ``k`` (at ``t_k = k dt`` after the last frame) is the prediction interval
of that line fit plus a growth for the motion's changes, per coordinate:

    var_k = s^2 (1 / n + (t_k - t_bar)^2 / sum_i (t_i - t_bar)^2) + (spread_mps t_k)^2

with ``s`` the residual standard deviation of the fit (at least ``min_std``), ``n`` the
frames fitted and ``t_i`` their times (``t_bar`` their mean, the last frame at 0). A joint seen
in one frame of the window is held there (no velocity; the spread grows all the same), and a
joint never seen in the window is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from iplanner_torch import checks
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.errors import DataError, ShapeError
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import MAX_POSITION_M, check_shape

#: the one action's name in a constant-velocity forecast
ACTION = "constant_velocity"


@dataclass(frozen=True, kw_only=True)
class ConstantVelocityCfg:
    """A constant-velocity forecast (module doc)."""

    # newest tracked frames each joint's line is fitted to (>= 2)
    fit_frames: int = 5
    # frames of the window the predictor is given (>= fit_frames; as a learned predictor's
    # n_prev, the episode keeps this many tracked frames)
    n_prev: int = 15
    # forecast frames, one every 1 / fps seconds after the last tracked frame
    n_future: int = 15
    # the least residual standard deviation of a fit [m] (the tracker's noise, about)
    min_std: float = 0.01
    # growth of the standard deviation per second ahead for changes of the motion [m/s]
    spread_mps: float = 0.1

    def __post_init__(self) -> None:
        checks.integer("fit_frames", self.fit_frames, minimum=2)
        checks.integer("n_prev", self.n_prev, minimum=self.fit_frames)
        checks.integer("n_future", self.n_future, minimum=1)
        checks.positive("min_std", self.min_std)
        checks.non_negative("spread_mps", self.spread_mps)


class ConstantVelocityPredictor:
    """Constant-velocity forecasts of every joint (module doc), in the shape of
    :meth:`~iplanner_torch.prediction.predictor.HumanMotionPredictor.predict_positions`.

    Args:
        cfg: the fit and the horizon.
        fps: the tracker's frame rate [Hz]: frames are ``1 / fps`` apart, in the window and in
            the forecast.
        joint_names: the K joint names (default: the skeleton's).
        window_cfg: the settings of the held-out windows it is scored on
            (:class:`~iplanner_torch.data.windows.WindowCfg` fields, as a trained predictor
            records them; :func:`~iplanner_torch.eval.prediction.evaluate_prediction` reads
            them), or None for the defaults.

    Raises:
        ConfigError: on an ``fps`` that is not a finite number > 0.
    """

    #: the window features it reads: the joint positions, the first 3 K of any features
    feature_kinds: tuple[str, ...] = ("position",)
    #: no action model: one action in each forecast, no class to score, no next action
    action_names: tuple[str, ...] = ()

    def __init__(
        self,
        cfg: ConstantVelocityCfg | None = None,
        *,
        fps: float,
        joint_names: tuple[str, ...] = JOINT_NAMES,
        window_cfg: dict[str, object] | None = None,
    ) -> None:
        self.cfg = cfg or ConstantVelocityCfg()
        self.fps = checks.positive("fps", fps)
        self.joint_names = tuple(joint_names)
        #: the frames the episode gives (read by the closed loop as a learned predictor's)
        self.n_prev = self.cfg.n_prev
        self.n_future = self.cfg.n_future
        self.window_cfg = dict(window_cfg) if window_cfg else None

    def predict(self, f_prev: torch.Tensor, progress: torch.Tensor) -> Forecast:
        """Forecast from window features, as a trained predictor's ``predict``.

        Args:
            f_prev: (B, n_prev, D) features whose first 3 K are the joint positions [m]
                (:func:`~iplanner_torch.data.windows.compute_features`, lost joints imputed).
            progress: (B,) progress states (not read).

        Returns:
            As :meth:`predict_positions`.

        Raises:
            ShapeError: when ``f_prev`` is not (B, n_prev, D >= 3 K).
            DataError: as :meth:`predict_positions`.
        """
        k = len(self.joint_names)
        check_shape("f_prev", f_prev, ("B", self.n_prev, "D"))
        if f_prev.shape[-1] < 3 * k:
            raise ShapeError(
                f"expected f_prev (B, {self.n_prev}, D >= {3 * k}) with the {k} joints' "
                f"positions first, got {tuple(f_prev.shape)}"
            )
        positions = f_prev[..., : 3 * k].reshape(*f_prev.shape[:2], k, 3)  # (B, n_prev, K, 3)
        return self.predict_positions(positions, progress)

    def predict_positions(self, positions: torch.Tensor, progress: torch.Tensor) -> Forecast:
        """Forecast from tracked positions.

        Args:
            positions: (B, n_prev, K, 3) tracked joint positions [m], NaN where lost.
            progress: (B,) progress states (not read: the forecast knows no actions).

        Returns:
            Forecast with weights (B, 1), mean and var (B, 1, n_future, K, 3), action
            :data:`ACTION`, ``dt = 1 / fps``, of ``positions``' dtype and device (a trained
            predictor's are float32 on its own device).

        Raises:
            ShapeError: when ``positions`` is not (B >= 1, n_prev, K, 3) of a floating dtype,
                or ``progress`` not (B,).
            DataError: when a joint is lost in every frame of a window, or a coordinate is
                inf or beyond :data:`~iplanner_torch.types.MAX_POSITION_M`.
        """
        cfg = self.cfg
        check_shape("positions", positions, ("B", cfg.n_prev, len(self.joint_names), 3))
        check_shape("progress", progress, (positions.shape[0],))
        if positions.shape[0] == 0 or not positions.dtype.is_floating_point:
            raise ShapeError(
                f"expected positions of a floating dtype with B >= 1, got "
                f"{tuple(positions.shape)} {positions.dtype}"
            )
        x = positions.detach()[:, -cfg.fit_frames :]  # (B, n, K, 3)
        if bool((x.abs() > MAX_POSITION_M).any()):  # inf included, NaN not
            raise DataError(
                f"positions hold inf or a coordinate beyond {MAX_POSITION_M:g} m; mark a lost "
                "joint with NaN"
            )
        seen = torch.isfinite(x).all(-1)  # (B, n, K)
        # a joint lost in the frames fitted: held where the whole window saw it last
        held = _last_seen(positions.detach())  # (B, K, 3), NaN where never seen
        never = torch.isnan(held).any(-1)  # (B, K)
        if bool(never.any()):
            b, k = never.nonzero()[0].tolist()
            raise DataError(
                f"joint {self.joint_names[k]!r} is lost in every frame of window {b}: "
                "cannot forecast it"
            )
        dt = 1.0 / self.fps
        n = x.shape[1]
        t = dt * torch.arange(1 - n, 1, dtype=x.dtype, device=x.device)  # (n,) last at 0
        w = seen.to(x.dtype).unsqueeze(-1)  # (B, n, K, 1) 1 where seen
        count = w.sum(1)  # (B, K, 1)
        y = torch.where(w > 0, x, torch.zeros_like(x))
        tt = t.view(1, n, 1, 1)
        t_bar = (w * tt).sum(1) / count.clamp(min=1.0)  # (B, K, 1)
        y_bar = (w * y).sum(1) / count.clamp(min=1.0)  # (B, K, 3)
        dtn = (tt - t_bar.unsqueeze(1)) * w  # (B, n, K, 1) centred times of the seen frames
        sxx = (dtn * dtn).sum(1)  # (B, K, 1)
        fitted = sxx > 1e-12 * dt * dt  # two or more frames seen
        slope = torch.where(
            fitted, (dtn * (y - y_bar.unsqueeze(1))).sum(1) / sxx.clamp(min=1e-30), 0.0
        )  # (B, K, 3) [m/s]
        origin = torch.where(fitted, y_bar - slope * t_bar, held)  # (B, K, 3) at t = 0
        resid = (y - origin.unsqueeze(1) - slope.unsqueeze(1) * tt) * w  # (B, n, K, 3)
        dof = (count - 2.0).clamp(min=1.0)
        s2 = torch.where(count > 2.0, resid.square().sum(1) / dof, torch.zeros_like(origin)).clamp(
            min=cfg.min_std**2
        )  # (B, K, 3) [m^2]
        ahead = dt * torch.arange(1, cfg.n_future + 1, dtype=x.dtype, device=x.device)
        a = ahead.view(1, -1, 1, 1)  # (1, n_f, 1, 1)
        mean = origin.unsqueeze(1) + slope.unsqueeze(1) * a  # (B, n_f, K, 3)
        lever = torch.where(
            fitted.unsqueeze(1),
            1.0 / count.clamp(min=1.0).unsqueeze(1)
            + (a - t_bar.unsqueeze(1)).square() / sxx.clamp(min=1e-30).unsqueeze(1),
            1.0,
        )  # (B, n_f, K, 1)
        var = s2.unsqueeze(1) * lever + (cfg.spread_mps * a).square()  # (B, n_f, K, 3)
        b = positions.shape[0]
        return Forecast(
            weights=torch.ones(b, 1, dtype=x.dtype, device=x.device),
            mean=mean.unsqueeze(1),
            var=var.unsqueeze(1),
            dt=dt,
            joint_names=self.joint_names,
            action_names=(ACTION,),
        )

    def __repr__(self) -> str:
        c = self.cfg
        return (
            f"ConstantVelocityPredictor(fit_frames={c.fit_frames}, n_future={c.n_future}, "
            f"fps={self.fps:g}, min_std={c.min_std:g}, spread_mps={c.spread_mps:g})"
        )


def _last_seen(positions: torch.Tensor) -> torch.Tensor:
    """(B, K, 3) each joint's newest position seen in the window (B, n_p, K, 3); NaN for a
    joint lost in every frame."""
    seen = torch.isfinite(positions).all(-1)  # (B, n_p, K)
    n_p = positions.shape[1]
    frame = torch.arange(n_p, device=positions.device).view(1, n_p, 1)
    last = torch.where(seen, frame, -1).amax(1)  # (B, K) newest seen frame, -1: none
    idx = last.clamp(min=0).view(positions.shape[0], 1, -1, 1).expand(-1, 1, -1, 3)
    out = positions.gather(1, idx)[:, 0]  # (B, K, 3)
    return torch.where((last >= 0).unsqueeze(-1), out, math.nan)
