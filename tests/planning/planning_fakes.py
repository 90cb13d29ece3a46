"""Small analytic robots and human forecasts for the planning tests."""

from __future__ import annotations

import math

import torch

from iplanner_torch.collision.human_spheres import HumanSphereMap
from iplanner_torch.prediction.forecast import Forecast


class PointRobot:
    """J = 2: one sphere of radius ``r`` at (q_0, q_1, 0)."""

    def __init__(self, r: float = 0.05, dtype: torch.dtype = torch.float32, device="cpu"):
        self.q_min = torch.tensor([-2.0, -2.0], dtype=dtype, device=device)
        self.q_max = -self.q_min
        self.v_max = torch.tensor([3.0, 3.0], dtype=dtype, device=device)
        self.sphere_radii = torch.tensor([r], dtype=dtype, device=device)
        self.num_joints = 2

    def sphere_centers(self, q: torch.Tensor) -> torch.Tensor:
        return torch.cat([q, torch.zeros_like(q[..., :1])], -1).unsqueeze(-2)


class PlanarArm:
    """A 3-link planar arm in the z = 0 plane, 2 spheres per link (analytic FK)."""

    def __init__(self, lengths=(0.4, 0.3, 0.2), r: float = 0.04, dtype=torch.float32):
        self.lengths = torch.tensor(lengths, dtype=dtype)
        self.q_min = torch.full((3,), -math.pi, dtype=dtype)
        self.q_max = -self.q_min
        self.v_max = torch.full((3,), 2.0, dtype=dtype)
        self.sphere_radii = torch.full((6,), r, dtype=dtype)
        self.num_joints = 3

    def sphere_centers(self, q: torch.Tensor) -> torch.Tensor:
        angles = torch.cumsum(q, dim=-1)  # (..., 3)
        seg = self.lengths * torch.stack([angles.cos(), angles.sin()], -1).movedim(-1, 0)
        seg = seg.movedim(0, -1)  # (..., 3 links, 2)
        ends = torch.cumsum(seg, dim=-2)
        starts = ends - seg
        pts = [starts + 0.5 * seg, ends]  # mid and end of each link
        c = torch.stack(pts, dim=-2).flatten(-3, -2)  # (..., 6, 2)
        return torch.cat([c, torch.zeros_like(c[..., :1])], -1)


def one_sphere_map(radius: float) -> HumanSphereMap:
    """A human of one joint carrying one sphere."""
    return HumanSphereMap(torch.ones(1, 1), torch.tensor([radius]))


def static_forecast(
    center, std: float, n_f: int = 30, dt: float = 0.1, dtype=torch.float32, device="cpu"
) -> Forecast:
    """One action, one joint resting at ``center`` with isotropic ``std`` [m]."""
    mean = torch.tensor(center, dtype=dtype, device=device).view(1, 1, 1, 1, 3)
    mean = mean.expand(1, 1, n_f, 1, 3).clone()
    return Forecast(
        weights=torch.ones(1, 1, dtype=dtype, device=device),
        mean=mean,
        var=torch.full_like(mean, std * std),
        dt=dt,
        joint_names=("j",),
        action_names=("rest",),
    )


def mc_ball_probability(
    d: torch.Tensor, var: torch.Tensor, rad: float, n: int = 200_000, seed: int = 0
) -> float:
    """Monte Carlo P(||x|| <= rad) for x ~ N(d, diag(var)), float64."""
    gen = torch.Generator().manual_seed(seed)
    x = d.double() + var.double().sqrt() * torch.randn(n, 3, generator=gen, dtype=torch.float64)
    return float((x.norm(dim=-1) <= rad).double().mean())


def approaching(
    start_x: float,
    arrive_s: float,
    y: float,
    std: float = 0.05,
    dtype: torch.dtype = torch.float64,
) -> Forecast:
    """One joint at (x, y, 0) moving from x = ``start_x`` to 0 over ``arrive_s`` seconds, then
    resting; isotropic ``std`` [m]; 30 frames at 0.05 s."""
    n_f, dt = 30, 0.05
    t = dt * torch.arange(1, n_f + 1, dtype=dtype)
    mean = torch.zeros(1, 1, n_f, 1, 3, dtype=dtype)
    mean[0, 0, :, 0, 0] = start_x * (1.0 - t / arrive_s).clamp_min(0.0)
    mean[0, 0, :, 0, 1] = y
    return Forecast(
        weights=torch.ones(1, 1, dtype=dtype),
        mean=mean,
        var=torch.full_like(mean, std * std),
        dt=dt,
        joint_names=("j",),
        action_names=("approach",),
    )
