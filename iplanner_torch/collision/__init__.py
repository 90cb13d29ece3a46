"""Collision checking: probabilistic bounds against Gaussian human spheres, static obstacles.

This package knows nothing of where the Gaussians come from (prediction) or where the robot
spheres come from (robot): it takes tensors.
"""

from iplanner_torch.collision.exact import (
    exact_ball_probability,
    mc_ball_probability,
    ruben_ball_probability,
)
from iplanner_torch.collision.gaussian import (
    max_density_point,
    pairwise_bound_matrix,
    sphere_collision_bound,
    sphere_collision_bound_diag,
    trajectory_collision_bound,
)
from iplanner_torch.collision.human_spheres import HumanSphereMap, SphereLayout
from iplanner_torch.collision.static import (
    Box,
    Plane,
    StaticScene,
    sphere_box_distance,
    sphere_plane_distance,
)

__all__ = [
    "Box",
    "HumanSphereMap",
    "Plane",
    "SphereLayout",
    "StaticScene",
    "exact_ball_probability",
    "max_density_point",
    "mc_ball_probability",
    "pairwise_bound_matrix",
    "ruben_ball_probability",
    "sphere_box_distance",
    "sphere_collision_bound",
    "sphere_collision_bound_diag",
    "sphere_plane_distance",
    "trajectory_collision_bound",
]
