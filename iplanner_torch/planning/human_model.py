"""Human bounding spheres as a linear map of joint Gaussians (paper eq. center_distribution).

A sphere centre ``c_l = (1 - u) z_1 + u z_2`` between two joints with independent diagonal
Gaussians has mean ``(1 - u) mu_1 + u mu_2`` and variance ``(1 - u)^2 s_1 + u^2 s_2`` per
coordinate, so all centres are one matrix product: ``mean_s = M @ mean_k`` and
``var_s = (M * M) @ var_k`` with ``M`` of shape (S_h, K).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import torch

from iplanner_torch.checks import positive
from iplanner_torch.data.skeleton import SEGMENTS, Segment
from iplanner_torch.errors import ConfigError
from iplanner_torch.types import check_shape

#: ``"inner"``: spheres on the skeleton, inside the body (the default); ``"cover"``: spheres
#: whose union contains the body's capsules (:meth:`HumanSphereMap.from_segments`).
SphereLayout = Literal["inner", "cover"]
#: the most a covering sphere's radius exceeds its segment's [m]
COVER_MAX_GAP = 0.01
#: design length of the covering layout relative to the reference body (body sizes of the
#: generated people reach about 1.19 times it)
COVER_LENGTH_SCALE = 1.25


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
        layout: SphereLayout = "inner",
        max_gap: float = COVER_MAX_GAP,
        length_scale: float = COVER_LENGTH_SCALE,
    ) -> HumanSphereMap:
        """The spheres of each segment, as linear maps of its two joints.

        Layouts:

        - ``"inner"``: ``n_spheres`` spheres of the segment's radius at ``u = (i + 0.5) / n``
          (``u = 0`` when the segment is a single joint). They lie inside the capsule of that
          radius around the segment but leave parts of it out: about 4 cm of the forearm,
          5 cm of the upper arm and 7 cm of the torso on the reaching set's bodies
          (``scripts/human_sphere_gaps.py``).
        - ``"cover"``: spheres at ``u = i / m``, ``i = 0..m``, of radius
          ``sqrt(r^2 + (L / 2m)^2)``, with ``m`` the fewest intervals that keep that radius
          within ``r + max_gap`` at the design length ``L = length_scale * scale *
          segment.length``. Their union contains the capsule of radius ``r`` around the
          segment for every segment length up to ``L`` (a point of the capsule lies within
          ``r`` of its projection on the segment, or of an end joint, and that projection
          within ``L / 2m`` of a centre). A single joint gets one sphere of radius ``r``. A
          joint shared by segments keeps one sphere, the largest.

        Args:
            joint_names: the K joint names of the forecast, in its order.
            segments: the body segments carrying spheres.
            scale: radius (and, for ``"cover"``, length) scale for a body larger or smaller
                than the reference.
            layout: ``"inner"`` or ``"cover"``.
            max_gap: ``"cover"``: the most a sphere's radius may exceed the segment's [m].
            length_scale: ``"cover"``: design length relative to the reference body's.

        Raises:
            ConfigError: when a segment names a joint that is not in ``joint_names``, on an
                unknown layout, a ``scale``, ``max_gap`` or ``length_scale`` that is not a
                finite number > 0, or (``"cover"``) a two-joint segment without a positive
                ``length``.
        """
        if layout not in ("inner", "cover"):
            raise ConfigError(f"expected layout 'inner' or 'cover', got {layout!r}")
        scale = positive("scale", scale)
        max_gap = positive("max_gap", max_gap)
        length_scale = positive("length_scale", length_scale)
        index = {name: i for i, name in enumerate(joint_names)}
        rows: list[torch.Tensor] = []
        radii: list[float] = []
        at_joint: dict[int, int] = {}  # cover: joint index -> its sphere's row

        def add(weights: dict[int, float], radius: float) -> None:
            joints = [j for j, wt in weights.items() if wt != 0.0]
            if layout == "cover" and len(joints) == 1:
                j = joints[0]
                if j in at_joint:
                    radii[at_joint[j]] = max(radii[at_joint[j]], radius)
                    return
                at_joint[j] = len(rows)
            row = torch.zeros(len(joint_names))
            for j, wt in weights.items():
                row[j] += wt
            rows.append(row)
            radii.append(radius)

        for seg in segments:
            for name in (seg.joint_a, seg.joint_b):
                if name not in index:
                    raise ConfigError(f"segment {seg.name!r} needs joint {name!r}, not tracked")
            a, b = index[seg.joint_a], index[seg.joint_b]
            r = seg.radius * scale
            if layout == "inner":
                for i in range(seg.n_spheres):
                    u = 0.0 if a == b else (i + 0.5) / seg.n_spheres
                    add({a: 1.0 - u, b: u} if a != b else {a: 1.0}, r)
                continue
            if a == b:
                add({a: 1.0}, r)
                continue
            if not seg.length > 0.0:
                raise ConfigError(
                    f"segment {seg.name!r} needs a length > 0 for the covering layout"
                )
            length = length_scale * scale * seg.length
            half = math.sqrt((r + max_gap) ** 2 - r**2)  # the largest half spacing
            m = max(1, math.ceil(length / (2.0 * half) - 1e-9))
            radius = math.sqrt(r**2 + (length / (2.0 * m)) ** 2)
            for i in range(m + 1):
                u = i / m
                add({a: 1.0 - u, b: u} if 0 < i < m else {a if i == 0 else b: 1.0}, radius)
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
