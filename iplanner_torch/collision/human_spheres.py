"""The person's collision spheres as a linear map of joint Gaussians (eq. center_distribution).

A sphere centre ``c = (1 - u) z_a + u z_b`` between two joints with independent Gaussians
``z_a ~ N(mu_a, S_a)`` and ``z_b ~ N(mu_b, S_b)`` is ``N((1 - u) mu_a + u mu_b,
(1 - u)^2 S_a + u^2 S_b)``. So all centres are one matrix product: ``mean_s = M @ mean_k``
and ``cov_s = sum_k M_sk^2 S_k`` (per coordinate ``var_s = (M * M) @ var_k``), with ``M``
of shape (S_h, K). The planner, the episode metrics and the logs all use this one map.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from typing import Literal

import torch

from iplanner_torch.checks import is_real, positive
from iplanner_torch.data.skeleton import SEGMENTS, Segment
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.types import check_shape, non_finite_error

#: ``"inner"``: spheres on the skeleton, inside the body (the default); ``"cover"``: spheres
#: whose union contains the body's capsules (:meth:`HumanSphereMap.from_segments`).
SphereLayout = Literal["inner", "cover"]
#: the most a covering sphere's radius exceeds its segment's [m]
COVER_MAX_GAP = 0.01
#: design length of the covering layout relative to the reference body (body sizes of the
#: generated people reach about 1.19 times it)
COVER_LENGTH_SCALE = 1.25
#: the most spheres :meth:`HumanSphereMap.from_segments` builds (the reference body takes 22
#: ``"inner"`` and 42 ``"cover"`` spheres; ``"cover"`` counts grow as ``1 / sqrt(max_gap)``,
#: reaching this near ``max_gap = 1e-4`` m): every planner cost term scales with S_h
MAX_HUMAN_SPHERES = 1000


class HumanSphereMap:
    """Linear map from K joint Gaussians to S_h sphere-centre Gaussians.

    Build one with :meth:`from_segments`; the constructor takes the map itself.

    Args:
        matrix: (S_h, K) interpolation weights, each row >= 0 and summing to 1.
        radii: (S_h,) sphere radii [m], finite and > 0.
        names: S_h sphere names (default ``sphere_0`` ...).

    Raises:
        ShapeError: on wrong shapes, a bool or complex ``matrix`` or ``radii``, or a ``names``
            of another length.
        ConfigError: on no sphere or no joint, a row that is negative somewhere or does not
            sum to 1, or a radius that is not finite and > 0.
    """

    def __init__(
        self,
        matrix: torch.Tensor,
        radii: torch.Tensor,
        names: Sequence[str] | None = None,
    ) -> None:
        check_shape("matrix", matrix, ("S_h", "K"))
        check_shape("radii", radii, (matrix.shape[0],))
        for arg_name, arg in (("matrix", matrix), ("radii", radii)):
            if arg.dtype == torch.bool or arg.is_complex():
                raise ShapeError(f"expected {arg_name} of real numbers, got {arg.dtype}")
        if matrix.shape[0] == 0:
            raise ConfigError("expected at least one sphere in the sphere map")
        if matrix.shape[1] == 0:
            raise ConfigError("expected at least one joint in the sphere map")
        if not torch.allclose(matrix.sum(-1), torch.ones_like(matrix[:, 0]), atol=1e-5):
            raise ConfigError("expected every row of the sphere map to sum to 1")
        if bool((matrix < 0).any()):
            raise ConfigError("expected sphere map weights >= 0")
        if not bool((torch.isfinite(radii) & (radii > 0)).all()):
            raise ConfigError(f"expected sphere radii > 0 and finite, got {radii.tolist()}")
        if names is None:
            names = [f"sphere_{i}" for i in range(len(radii))]
        names = tuple(names)
        if len(names) != matrix.shape[0]:
            raise ShapeError(f"expected {matrix.shape[0]} sphere names, got {len(names)}")
        self.matrix = matrix
        self.radii = radii
        self.names: tuple[str, ...] = names

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

        Sphere names are ``<segment>_<i>``; a covering layout's sphere on a joint is named
        after the joint. At most :data:`MAX_HUMAN_SPHERES` spheres in all.

        Args:
            joint_names: the K joint names of the forecast, in its order (distinct).
            segments: the body segments carrying spheres.
            scale: radius (and, for ``"cover"``, length) scale for a body larger or smaller
                than the reference.
            layout: ``"inner"`` or ``"cover"``.
            max_gap: ``"cover"``: the most a sphere's radius may exceed the segment's [m].
            length_scale: ``"cover"``: design length relative to the reference body's.

        Raises:
            ConfigError: when ``joint_names`` is not a sequence of distinct strings, a
                segment is not a :class:`Segment` or names a joint that is not in
                ``joint_names``, on an unknown layout, a ``scale``, ``max_gap`` or
                ``length_scale`` that is not a finite number > 0, a segment radius that is
                not, an ``"inner"`` segment whose ``n_spheres`` is not an integer >= 1, no
                segment, (``"cover"``) a two-joint segment without a positive ``length``, or
                more than :data:`MAX_HUMAN_SPHERES` spheres (raise ``max_gap``).
        """
        if layout not in ("inner", "cover"):
            raise ConfigError(f"expected layout 'inner' or 'cover', got {layout!r}")
        scale = positive("scale", scale)
        max_gap = positive("max_gap", max_gap)
        length_scale = positive("length_scale", length_scale)
        joint_names = _names_tuple(joint_names)
        if len(set(joint_names)) != len(joint_names):
            raise ConfigError(f"expected distinct joint names, got {joint_names}")
        try:
            segments = tuple(segments)
        except TypeError:
            raise ConfigError(
                f"expected segments a sequence of Segment, got {segments!r}"
            ) from None
        if not segments:
            raise ConfigError("expected at least one body segment")
        index = {name: i for i, name in enumerate(joint_names)}
        plans = [_plan(seg, index, layout, scale, max_gap, length_scale) for seg in segments]
        total = sum(count for _, count in plans)
        if total > MAX_HUMAN_SPHERES:
            fix = f"raise max_gap (got {max_gap} m)" if layout == "cover" else "lower n_spheres"
            raise ConfigError(
                f"the {layout!r} sphere layout would take about {total:.4g} spheres, more than "
                f"MAX_HUMAN_SPHERES = {MAX_HUMAN_SPHERES}: {fix}"
            )
        rows: list[torch.Tensor] = []
        radii: list[float] = []
        names: list[str] = []
        at_joint: dict[int, int] = {}  # cover: joint index -> its sphere's row

        def add(weights: dict[int, float], radius: float, name: str) -> None:
            joints = [j for j, wt in weights.items() if wt != 0.0]
            if layout == "cover" and len(joints) == 1:
                j = joints[0]
                if j in at_joint:
                    radii[at_joint[j]] = max(radii[at_joint[j]], radius)
                    return
                at_joint[j] = len(rows)
                name = joint_names[j]
            row = torch.zeros(len(joint_names))
            for j, wt in weights.items():
                row[j] += wt
            rows.append(row)
            radii.append(radius)
            names.append(name)

        for seg, (m, _) in zip(segments, plans):
            a, b = index[seg.joint_a], index[seg.joint_b]
            r = seg.radius * scale
            if layout == "inner":
                for i in range(seg.n_spheres):
                    u = 0.0 if a == b else (i + 0.5) / seg.n_spheres
                    add({a: 1.0 - u, b: u} if a != b else {a: 1.0}, r, f"{seg.name}_{i}")
                continue
            if a == b:
                add({a: 1.0}, r, seg.name)
                continue
            length = length_scale * scale * seg.length
            radius = math.hypot(r, length / (2.0 * m))
            for i in range(m + 1):
                u = i / m
                weights = {a: 1.0 - u, b: u} if 0 < i < m else {a if i == 0 else b: 1.0}
                add(weights, radius, f"{seg.name}_{i}")
        return cls(torch.stack(rows), torch.tensor(radii), names)

    @property
    def num_spheres(self) -> int:
        """S_h."""
        return int(self.matrix.shape[0])

    @property
    def num_joints(self) -> int:
        """K."""
        return int(self.matrix.shape[1])

    def centers(self, joints: torch.Tensor) -> torch.Tensor:
        """Sphere centres of known joint positions.

        Args:
            joints: (..., K, 3) joint positions [m], floating.

        Returns:
            (..., S_h, 3) sphere centres [m], in the dtype of ``joints``. Values are not
            checked: a NaN joint (untracked) gives NaN centres for the spheres on it.

        Raises:
            ShapeError: on a wrong shape or a non-floating dtype.
        """
        self._check_mean("joints", joints)
        m = self.matrix.to(device=joints.device, dtype=joints.dtype)
        return torch.einsum("sk,...kc->...sc", m, joints)

    def centers_diag(
        self, mean: torch.Tensor, var: torch.Tensor, *, validate: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Sphere-centre Gaussians from joint Gaussians with per-axis variances.

        Args:
            mean: (..., K, 3) joint means [m].
            var: (..., K, 3) joint per-coordinate variances [m^2], >= 0.
            validate: test ``mean`` and ``var`` for NaN, inf and negative variances (one
                host synchronisation). The planner passes False for a
                :class:`~iplanner_torch.prediction.forecast.Forecast`, already checked
                finite, whose rounding negatives it floors afterwards. Shapes and dtypes
                are checked always.

        Returns:
            mean (..., S_h, 3) [m] and var (..., S_h, 3) [m^2].

        Raises:
            ShapeError: on wrong shapes, a non-floating dtype, or ``var`` of another dtype
                or device than ``mean``.
            DataError: (``validate``) on NaN or inf in ``mean`` or ``var``, or a negative
                variance.
        """
        self._check(mean, "var", var, (), validate)
        m = self.matrix.to(device=mean.device, dtype=mean.dtype)
        mean_s = torch.einsum("sk,...kc->...sc", m, mean)
        return mean_s, torch.einsum("sk,...kc->...sc", m * m, var)

    def centers_full(
        self, mean: torch.Tensor, cov: torch.Tensor, *, validate: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Sphere-centre Gaussians from joint Gaussians with full covariances.

        Args:
            mean: (..., K, 3) joint means [m].
            cov: (..., K, 3, 3) joint covariances [m^2] (joints independent of each other).
            validate: test ``mean`` and ``cov`` for NaN and inf (one host synchronisation).

        Returns:
            ``(mean (..., S_h, 3) [m], cov (..., S_h, 3, 3) [m^2])``.

        Raises:
            ShapeError: on wrong shapes, a non-floating dtype, or ``cov`` of another dtype
                or device than ``mean``.
            DataError: (``validate``) on NaN or inf in ``mean`` or ``cov``.
        """
        self._check(mean, "cov", cov, (3,), validate)
        m = self.matrix.to(device=mean.device, dtype=mean.dtype)
        mean_s = torch.einsum("sk,...kc->...sc", m, mean)
        return mean_s, torch.einsum("sk,...kij->...sij", m * m, cov)

    def _check_mean(self, name: str, mean: torch.Tensor) -> None:
        check_shape(name, mean, ("...", self.num_joints, 3))
        if not mean.is_floating_point():
            raise ShapeError(f"expected {name} of a floating dtype, got {mean.dtype}")

    def _check(
        self,
        mean: torch.Tensor,
        name: str,
        spread: torch.Tensor,
        event: tuple[int, ...],
        validate: bool,
    ) -> None:
        """Shapes, dtypes and devices of ``mean`` and its covariance or variance ``spread``
        (named ``name``); with ``validate`` also finiteness and, for a variance, >= 0, in one
        host synchronisation."""
        self._check_mean("mean", mean)
        check_shape(name, spread, tuple(mean.shape) + event)
        if spread.dtype != mean.dtype or spread.device != mean.device:
            raise ShapeError(
                f"expected {name} {mean.dtype} on {mean.device} (as mean), "
                f"got {spread.dtype} on {spread.device}"
            )
        if not validate:
            return
        mean_ok, spread_ok, spread_nonneg = torch.stack(
            [torch.isfinite(mean).all(), torch.isfinite(spread).all(), (spread >= 0).all()]
        ).tolist()
        for arg_name, arg, ok in (("mean", mean, mean_ok), (name, spread, spread_ok)):
            if not ok:
                raise non_finite_error(arg_name, arg)
        if name == "var" and not spread_nonneg:
            raise DataError(f"expected var >= 0, got min {float(spread.min())}")


def _names_tuple(joint_names: object) -> tuple[str, ...]:
    """``joint_names`` as a tuple of strings; ConfigError for None, a single string or
    anything else that is not an iterable of strings."""
    bad = ConfigError(f"expected joint_names a sequence of joint names, got {joint_names!r}")
    if joint_names is None or isinstance(joint_names, str):
        raise bad
    try:
        names = tuple(joint_names)  # type: ignore[call-overload]
    except TypeError:
        raise bad from None
    if not all(isinstance(name, str) for name in names):
        raise bad
    return names


def _plan(
    seg: object,
    index: dict[str, int],
    layout: SphereLayout,
    scale: float,
    max_gap: float,
    length_scale: float,
) -> tuple[int, float]:
    """Check one segment for :meth:`HumanSphereMap.from_segments` and count its spheres
    before any is built.

    Returns:
        ``(m, count)``: the ``"cover"`` intervals ``m`` (0 for ``"inner"`` and single joints)
        and the number of spheres (an upper bound for ``"cover"``, whose joint spheres may be
        shared; a float estimate where it exceeds :data:`MAX_HUMAN_SPHERES`).

    Raises:
        ConfigError: as :meth:`HumanSphereMap.from_segments`.
    """
    if not isinstance(seg, Segment):
        raise ConfigError(f"expected segments of Segment, got {type(seg).__name__} {seg!r}")
    for name in (seg.joint_a, seg.joint_b):
        if name not in index:
            raise ConfigError(f"segment {seg.name!r} needs joint {name!r}, not tracked")
    if not (is_real(seg.radius) and 0.0 < seg.radius < math.inf):
        raise ConfigError(
            f"expected radius > 0 and finite in segment {seg.name!r}, got {seg.radius!r}"
        )
    if layout == "inner":
        n = seg.n_spheres
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
            raise ConfigError(
                f"expected n_spheres >= 1 in segment {seg.name!r} (an integer), got {n!r}"
            )
        return 0, int(n)
    if seg.joint_a == seg.joint_b:
        return 0, 1
    if not (is_real(seg.length) and 0.0 < seg.length < math.inf):
        raise ConfigError(
            f"segment {seg.name!r} needs a length > 0 (finite) for the covering layout, got "
            f"{seg.length!r}"
        )
    r = seg.radius * scale
    length = length_scale * scale * seg.length
    # the largest half spacing, sqrt((r + g)^2 - r^2) factored: no square of r to overflow
    half = math.sqrt(max_gap * (2.0 * r + max_gap))
    # 0 where max_gap is below the rounding of r: inf intervals, counted before any rounding
    intervals = math.inf if half == 0.0 else length / (2.0 * half) - 1e-9
    if not intervals < MAX_HUMAN_SPHERES:
        return 0, intervals + 1.0
    m = max(1, math.ceil(intervals))
    return m, m + 1
