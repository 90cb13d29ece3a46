"""Human bounding spheres as a linear map of joint Gaussians (paper eq. center_distribution).

A sphere centre ``c_l = (1 - u) z_1 + u z_2`` between two joints with independent diagonal
Gaussians has mean ``(1 - u) mu_1 + u mu_2`` and variance ``(1 - u)^2 s_1 + u^2 s_2`` per
coordinate, so all centres are one matrix product: ``mean_s = M @ mean_k`` and
``var_s = (M * M) @ var_k`` with ``M`` of shape (S_h, K).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from iplanner_torch.data.skeleton import SEGMENTS, Segment
from iplanner_torch.errors import ConfigError
from iplanner_torch.types import check_shape


class HumanSphereMap:
    """Linear map from K joint Gaussians to S_h sphere-centre Gaussians.

    Args:
        matrix: (S_h, K) interpolation weights, each row sums to 1.
        radii: (S_h,) sphere radii [m].
    """

    def __init__(self, matrix: torch.Tensor, radii: torch.Tensor) -> None:
        check_shape("matrix", matrix, ("S_h", "K"))
        check_shape("radii", radii, (matrix.shape[0],))
        if not torch.allclose(matrix.sum(-1), torch.ones_like(matrix[:, 0]), atol=1e-5):
            raise ConfigError("expected every row of the sphere map to sum to 1")
        self.matrix = matrix
        self.radii = radii

    @classmethod
    def from_segments(
        cls,
        joint_names: Sequence[str],
        segments: Sequence[Segment] = SEGMENTS,
        *,
        scale: float = 1.0,
    ) -> HumanSphereMap:
        """Spheres spread evenly along each segment (``u = (i + 0.5) / n``; ``u = 0`` when the
        segment is a single joint).

        Args:
            joint_names: the K joint names of the forecast, in its order.
            segments: the body segments carrying spheres.
            scale: radius scale for a body larger or smaller than the reference.

        Raises:
            ConfigError: when a segment names a joint that is not in ``joint_names``.
        """
        index = {name: i for i, name in enumerate(joint_names)}
        rows: list[torch.Tensor] = []
        radii: list[float] = []
        for seg in segments:
            for name in (seg.joint_a, seg.joint_b):
                if name not in index:
                    raise ConfigError(f"segment {seg.name!r} needs joint {name!r}, not tracked")
            for i in range(seg.n_spheres):
                u = 0.0 if seg.joint_a == seg.joint_b else (i + 0.5) / seg.n_spheres
                row = torch.zeros(len(joint_names))
                row[index[seg.joint_a]] += 1.0 - u
                row[index[seg.joint_b]] += u
                rows.append(row)
                radii.append(seg.radius * scale)
        return cls(torch.stack(rows), torch.tensor(radii))

    @property
    def num_spheres(self) -> int:
        """S_h."""
        return int(self.matrix.shape[0])

    def centers(self, joints: torch.Tensor) -> torch.Tensor:
        """Sphere centres of known joint positions: (..., K, 3) [m] -> (..., S_h, 3) [m]."""
        m = self.matrix.to(device=joints.device, dtype=joints.dtype)
        return torch.einsum("sk,...kc->...sc", m, joints)

    def centers_diag(
        self, mean: torch.Tensor, var: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Sphere-centre Gaussians from joint Gaussians (eq. center_distribution).

        Args:
            mean: (..., K, 3) joint means [m].
            var: (..., K, 3) joint per-coordinate variances [m^2].

        Returns:
            mean (..., S_h, 3) [m] and var (..., S_h, 3) [m^2].
        """
        m = self.matrix.to(device=mean.device, dtype=mean.dtype)
        return self.centers(mean), torch.einsum("sk,...kc->...sc", m * m, var)
