"""Human bounding spheres on body segments and their Gaussian centres (eq. center_distribution).

A sphere at fraction ``u`` of the segment from joint ``a`` to joint ``b`` has the centre
``(1 - u) z_a + u z_b``. With independent Gaussian joints ``z_a ~ N(mu_a, S_a)`` and
``z_b ~ N(mu_b, S_b)`` the centre is ``N((1 - u) mu_a + u mu_b, (1 - u)^2 S_a + u^2 S_b)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from iplanner_torch.checks import positive
from iplanner_torch.data.skeleton import SEGMENTS, Segment
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.types import check_shape, non_finite_error


class HumanSphereModel:
    """The human's collision spheres, spread along the skeleton's segments.

    Each segment with ``n_spheres = n`` gets spheres at ``u = i / n`` for ``i = 1..n`` (evenly
    spaced in ``(0, 1]``), or at ``u = 0.5`` when ``n = 1``; a segment from a joint to itself
    puts its spheres on the joint (``u = 1``). Segments whose joints are not
    tracked are skipped.

    Args:
        joint_names: the K tracked joint names, in the order of the K axis.
        segments: body segments (default: :data:`iplanner_torch.data.skeleton.SEGMENTS`).
        scale: body size relative to the reference body; radii are multiplied by it.

    Raises:
        ConfigError: on a non-positive or non-finite scale, duplicate joint names, a used
            segment with a non-positive or non-finite radius or fewer than one sphere, or no
            usable segment.
    """

    def __init__(
        self,
        joint_names: Sequence[str],
        segments: Sequence[Segment] = SEGMENTS,
        scale: float = 1.0,
    ) -> None:
        positive("scale", scale)
        names = tuple(joint_names)
        if len(set(names)) != len(names):
            raise ConfigError(f"expected distinct joint names, got {names}")
        index = {n: i for i, n in enumerate(names)}
        ia, ib, us, radii, sphere_names = [], [], [], [], []
        for seg in segments:
            if seg.joint_a not in index or seg.joint_b not in index:
                continue
            if seg.n_spheres < 1:
                raise ConfigError(f"expected n_spheres >= 1 in segment {seg.name!r}")
            if not 0 < seg.radius < math.inf:
                raise ConfigError(
                    f"expected radius > 0 and finite in segment {seg.name!r}, got {seg.radius}"
                )
            if seg.joint_a == seg.joint_b:
                # One joint: u = 1 keeps the joint's own covariance (z_a and z_b are the same
                # variable, so the independent-joints formula would halve it at u = 0.5).
                fractions = [1.0] * seg.n_spheres
            elif seg.n_spheres == 1:
                fractions = [0.5]
            else:
                fractions = [(i + 1) / seg.n_spheres for i in range(seg.n_spheres)]
            for i, u in enumerate(fractions):
                ia.append(index[seg.joint_a])
                ib.append(index[seg.joint_b])
                us.append(u)
                radii.append(seg.radius * scale)
                sphere_names.append(f"{seg.name}_{i}")
        if not radii:
            raise ConfigError(f"no segment has both joints among {names}")
        self.joint_names: tuple[str, ...] = names
        self.names: tuple[str, ...] = tuple(sphere_names)
        self.scale = float(scale)
        self._ia = torch.tensor(ia, dtype=torch.long)
        self._ib = torch.tensor(ib, dtype=torch.long)
        self._u = torch.tensor(us, dtype=torch.float64)
        self._radii = torch.tensor(radii, dtype=torch.float64)

    @property
    def num_spheres(self) -> int:
        """S_h."""
        return len(self.names)

    @property
    def radii(self) -> torch.Tensor:
        """(S_h,) sphere radii [m], float32."""
        return self._radii.float()

    @property
    def fractions(self) -> torch.Tensor:
        """(S_h,) position ``u`` of each sphere along its segment, float32."""
        return self._u.float()

    def _gather(self, x: torch.Tensor, axis: int) -> tuple[torch.Tensor, torch.Tensor]:
        ia = self._ia.to(x.device)
        ib = self._ib.to(x.device)
        return x.index_select(axis, ia), x.index_select(axis, ib)

    def _check(
        self, mean: torch.Tensor, name: str, spread: torch.Tensor, event: tuple[int, ...]
    ) -> None:
        """Shapes, dtypes, devices and finiteness of ``mean`` and its covariance or variance
        ``spread`` (named ``name``), with one host sync; a variance must also be >= 0."""
        check_shape("mean", mean, ("...", len(self.joint_names), 3))
        check_shape(name, spread, tuple(mean.shape) + event)
        if not mean.is_floating_point():
            raise ShapeError(f"expected mean of a floating dtype, got {mean.dtype}")
        if spread.dtype != mean.dtype or spread.device != mean.device:
            raise ShapeError(
                f"expected {name} {mean.dtype} on {mean.device} (as mean), "
                f"got {spread.dtype} on {spread.device}"
            )
        mean_ok, spread_ok, spread_nonneg = torch.stack(
            [torch.isfinite(mean).all(), torch.isfinite(spread).all(), (spread >= 0).all()]
        ).tolist()
        for arg_name, arg, ok in (("mean", mean, mean_ok), (name, spread, spread_ok)):
            if not ok:
                raise non_finite_error(arg_name, arg)
        if name == "var" and not spread_nonneg:
            raise DataError(f"expected var >= 0, got min {float(spread.min())}")

    def centers(self, mean: torch.Tensor, cov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Gaussian sphere centres from Gaussian joints with full covariances.

        Args:
            mean: (..., K, 3) joint means [m].
            cov: (..., K, 3, 3) joint covariances [m^2] (joints independent of each other).

        Returns:
            ``(mean (..., S_h, 3) [m], cov (..., S_h, 3, 3) [m^2])``.

        Raises:
            ShapeError: on wrong shapes, a non-floating dtype, or ``cov`` of another dtype
                or device than ``mean``.
            DataError: on NaN or Inf in ``mean`` or ``cov``.
        """
        self._check(mean, "cov", cov, (3,))
        k_axis = mean.dim() - 2
        u = self._u.to(mean)[:, None]  # (S_h, 1)
        ma, mb = self._gather(mean, k_axis)  # (..., S_h, 3)
        ca, cb = self._gather(cov, k_axis)  # (..., S_h, 3, 3)
        m = (1.0 - u) * ma + u * mb
        uu = u[..., None]  # (S_h, 1, 1)
        c = (1.0 - uu) ** 2 * ca + uu**2 * cb
        return m, c

    def centers_diag(
        self, mean: torch.Tensor, var: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Gaussian sphere centres from joints with per-axis variances.

        Args:
            mean: (..., K, 3) joint means [m].
            var: (..., K, 3) joint per-axis variances [m^2], >= 0. A
                :class:`~iplanner_torch.prediction.forecast.Forecast` lets rounding
                negatives through (the planner floors them); pass ``var.clamp_min(0)``
                of a forecast built elsewhere than the package's predictors.

        Returns:
            ``(mean (..., S_h, 3) [m], var (..., S_h, 3) [m^2])``.

        Raises:
            ShapeError: on wrong shapes, a non-floating dtype, or ``var`` of another dtype
                or device than ``mean``.
            DataError: on NaN or Inf in ``mean`` or ``var``, or a negative variance.
        """
        self._check(mean, "var", var, ())
        k_axis = mean.dim() - 2
        u = self._u.to(mean)[:, None]  # (S_h, 1)
        ma, mb = self._gather(mean, k_axis)
        va, vb = self._gather(var, k_axis)
        return (1.0 - u) * ma + u * mb, (1.0 - u) ** 2 * va + u**2 * vb
