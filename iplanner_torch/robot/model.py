"""RobotModel: batched, differentiable forward kinematics to bounding spheres, plus limits.

The planner sees a robot arm as ``J`` joint positions and ``S_r`` bounding spheres
(paper sec. 3.2: ``R_i subset union_j B_ij``). :class:`RobotModel` places one of our own robot
descriptions (``description.py``; the committed URDF / MJCF in ``assets/`` are generated from
it) at a base pose in the table frame and maps ``q (..., J)`` to sphere centres
``(..., S_r, 3)``, link positions and the tool point, all differentiable.

Table frame: x from the seated human towards the robot, y to the human's left, z up, table
top at z = 0, floor at z = -0.75 m; the human sits near x = -0.45 m. Default base poses (config
values, see ``conf/robot/*.yaml``):

* ``kuka_iiwa14``: base on the table top at (0.75, 0, 0), yaw pi (facing the human). At the
  home pose the flange is at about (0.08, 0, 0.285).
* ``fetch``: mobile base on the floor at (1.0, 0, -0.75), yaw pi, torso lift 0.26 m, which puts
  the shoulder (shoulder lift joint) about 0.30 m above the table.

Example:
    >>> model = RobotModel.load("kuka_iiwa14")
    >>> centers = model.sphere_centers(model.q_home.expand(4, 20, -1))  # (4, 20, S_r, 3)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, ShapeError
from iplanner_torch.robot.description import (
    ROBOT_NAMES,
    RobotDescription,
    asset_paths,
    has_torso,
    mjcf_string,
    robot_description,
    urdf_string,
)
from iplanner_torch.robot.kinematics import SerialChainKinematics
from iplanner_torch.robot.spheres import fit_link_spheres
from iplanner_torch.types import check_finite, check_shape, resolve_device

#: a robot name: one of :data:`~iplanner_torch.robot.description.ROBOT_NAMES`
RobotName = str


def _check_device_dtype(device: torch.device | str, dtype: torch.dtype) -> torch.device:
    """The model's device (:func:`~iplanner_torch.types.resolve_device`), or ConfigError for
    an unknown or unavailable device or a non-floating dtype."""
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise ConfigError(f"expected a floating dtype (floating dtypes only), got {dtype}")
    return resolve_device(device)


#: the largest max_sphere_excess [m]: spheres reaching further beyond their links than this
#: no longer describe the arm (the default is 0.02 m)
MAX_SPHERE_EXCESS = 0.2


@dataclass(frozen=True, kw_only=True)
class RobotCfg:
    """Which robot, where it stands, and how tightly spheres bound its links."""

    name: RobotName  # one of ROBOT_NAMES: "kuka_iiwa14", "fetch", or one added there
    base_position: tuple[float, float, float] | None = None  # table frame [m]; None: default
    base_yaw: float | None = None  # rotation about the table's z axis [rad]; None: default
    torso_height: float | None = None  # Fetch torso lift in [0, 0.38615] m; None: default
    max_sphere_excess: float = 0.02  # largest distance of a sphere point beyond a link [m]

    def __post_init__(self) -> None:
        if self.name not in ROBOT_NAMES:
            raise ConfigError(
                f"name: unknown robot {self.name!r}; available: {', '.join(ROBOT_NAMES)}"
            )
        if self.base_position is not None:
            object.__setattr__(self, "base_position", _base_position(self.base_position))
        _check_base_yaw(self.base_yaw)
        checks.optional(checks.finite, "torso_height", self.torso_height)
        if self.torso_height is not None and not has_torso(self.name):
            raise ConfigError(f"{self.name} has no torso: expected torso_height=None")
        excess = self.max_sphere_excess
        # NaN and inf fail too
        if not checks.is_real(excess) or not 0 < excess <= MAX_SPHERE_EXCESS:
            raise ConfigError(
                f"expected max_sphere_excess in (0, {MAX_SPHERE_EXCESS:g}] m, got {excess!r}"
            )


def _check_base_yaw(yaw: object) -> None:
    """ConfigError unless ``yaw`` is None or a finite real number [rad]."""
    if yaw is not None and not (checks.is_real(yaw) and math.isfinite(yaw)):  # type: ignore[arg-type]
        raise ConfigError(f"expected a finite base_yaw, got {yaw!r}")


def _base_position(value: object) -> tuple[float, float, float]:
    """``value`` as a base position (x, y, z) [m]; ConfigError naming the key and the shape
    unless it is 3 finite numbers (a list in ``conf/robot/*.yaml``, a tuple, an array or a
    (3,) tensor)."""
    items = value.tolist() if isinstance(value, torch.Tensor) else value
    try:
        x, y, z = checks.finite_tuple("base_position", items, 3)
    except ConfigError:
        raise ConfigError(
            f"expected base_position a list of 3 finite numbers [x, y, z] in m, got {value!r}"
        ) from None
    return (x, y, z)


class RobotModel:
    """A robot arm at a base pose: forward kinematics to spheres, limits, inverse kinematics.

    Build it with :meth:`load` or :meth:`from_cfg`. Tensors returned by the attributes live on
    ``device`` with ``dtype``; the kinematic functions follow the device and dtype of ``q``.

    The forward kinematics (:meth:`sphere_centers`, :meth:`ee_position`, :meth:`link_positions`,
    ...) check shapes but not values: the trajectory optimiser calls :meth:`sphere_centers` every
    iteration, so a NaN or infinite joint gives NaN in that configuration's outputs (no error).
    :meth:`clamp` and :meth:`ik` reject non-finite input (:class:`DataError`).

    Raises:
        ConfigError: for a non-floating ``dtype``, a CUDA ``device`` where CUDA is not
            available, a ``base_position`` that is not 3 finite numbers, a ``base_yaw`` that
            is not finite (NaN gave NaN kinematics), or a ``max_sphere_excess`` that is not
            finite and > 0 or needs more than
            :data:`~iplanner_torch.robot.spheres.MAX_LINK_SPHERES` spheres for a link.

    Attributes:
        name: robot name.
        joint_names: (J,) names of the moving joints, equal in the URDF and the MJCF.
        num_joints: J.
        q_min, q_max: (J,) position limits [rad]; -inf / +inf for continuous joints.
        v_max: (J,) speed limits [rad/s] (from the URDF; MuJoCo carries none).
        effort_max: (J,) torque limits [N m].
        q_home: (J,) home configuration [rad].
        sphere_radii: (S_r,) bounding sphere radii [m].
        sphere_link: S_r link names, one per sphere.
        link_names: every link, base first, in chain order.
        base_position: (3,) base origin in the table frame [m].
        base_yaw: base rotation about z [rad].
        torso_height: Fetch torso lift [m], None for the iiwa.
        urdf_path, mjcf_path: our committed asset files (default torso height).
        description: the :class:`RobotDescription` everything is built from.
    """

    def __init__(
        self,
        desc: RobotDescription,
        *,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        base_position: Sequence[float] | None = None,
        base_yaw: float | None = None,
        max_sphere_excess: float = 0.02,
    ) -> None:
        self.device = _check_device_dtype(device, dtype)
        _check_base_yaw(base_yaw)
        self.description = desc
        self.name = desc.name
        self.dtype = dtype
        pos = (
            desc.default_base_position if base_position is None else _base_position(base_position)
        )
        self.base_position = torch.tensor([float(x) for x in pos], device=self.device, dtype=dtype)
        self.base_yaw = float(desc.default_base_yaw if base_yaw is None else base_yaw)
        self.torso_height = desc.torso_height
        self.urdf_path, self.mjcf_path = asset_paths(desc.name)
        joints = desc.actuated_joints
        self.joint_names: tuple[str, ...] = tuple(j.name for j in joints)
        self.num_joints = len(joints)

        def vec(values: Sequence[float]) -> torch.Tensor:
            return torch.tensor(list(values), device=self.device, dtype=dtype)

        self.q_min = vec(j.lower for j in joints)
        self.q_max = vec(j.upper for j in joints)
        self.v_max = vec(j.velocity for j in joints)
        self.effort_max = vec(j.effort for j in joints)
        self.q_home = vec(desc.q_home)
        centers, radii, owners = {}, [], []
        for link in desc.sphere_links:
            try:
                c, r = fit_link_spheres(desc.link(link).geometry, max_excess=max_sphere_excess)
            except ConfigError as err:
                raise ConfigError(f"link {link!r}: {err}") from None
            centers[link] = c.numpy()
            radii.append(r)
            owners += [link] * len(r)
        self.sphere_link: tuple[str, ...] = tuple(owners)
        self.sphere_radii = torch.cat(radii).to(device=self.device, dtype=dtype)
        self.sphere_centers_local = torch.cat([torch.from_numpy(c) for c in centers.values()]).to(
            device=self.device, dtype=dtype
        )  # (S_r, 3) in each sphere's link frame
        self._fk = SerialChainKinematics(
            desc, tuple(float(x) for x in pos), self.base_yaw, sphere_centers_local=centers
        )
        self.link_names = self._fk.link_names

    # ------------------------------------------------------------------ construction

    @staticmethod
    def available() -> tuple[str, ...]:
        """Names accepted by :meth:`load`."""
        return ROBOT_NAMES

    @classmethod
    def load(
        cls,
        name: str,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        base_position: Sequence[float] | None = None,
        base_yaw: float | None = None,
        torso_height: float | None = None,
        max_sphere_excess: float = 0.02,
    ) -> RobotModel:
        """Build robot ``name`` at a base pose.

        Args:
            name: one of :meth:`available`.
            device: where the model's tensors live.
            dtype: floating dtype of the model's tensors.
            base_position: (3,) base origin in the table frame [m]; None: robot default.
            base_yaw: base rotation about the table's z axis [rad]; None: robot default.
            torso_height: Fetch torso lift [m] in [0, 0.38615]; None: default (0.26 m). Must be
                None for the iiwa.
            max_sphere_excess: bound on how far spheres reach beyond the links [m].

        Raises:
            ConfigError: unknown name, torso height out of range or given for the iiwa, a
                non-floating ``dtype``, a CUDA ``device`` where CUDA is not available, or a
                ``max_sphere_excess`` outside (0, 0.2] m or so small that a link would need
                more than :data:`~iplanner_torch.robot.spheres.MAX_LINK_SPHERES` spheres
                (the Fetch gripper does below about 0.0018 m).
        """
        cfg = RobotCfg(
            name=name,  # type: ignore[arg-type]
            base_position=base_position,  # type: ignore[arg-type]
            base_yaw=base_yaw,
            torso_height=torso_height,
            max_sphere_excess=max_sphere_excess,
        )
        return cls.from_cfg(cfg, device=device, dtype=dtype)

    @classmethod
    def from_cfg(
        cls, cfg: RobotCfg, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
    ) -> RobotModel:
        """Build the robot a :class:`RobotCfg` names (errors as :meth:`load`)."""
        _check_device_dtype(device, dtype)
        desc = robot_description(cfg.name, torso_height=cfg.torso_height)
        return cls(
            desc,
            device=device,
            dtype=dtype,
            base_position=cfg.base_position,
            base_yaw=cfg.base_yaw,
            max_sphere_excess=cfg.max_sphere_excess,
        )

    def urdf_xml(self) -> str:
        """The URDF text of this model's description (its torso height), in the base frame."""
        return urdf_string(self.description)

    def mjcf_xml(self) -> str:
        """The MJCF text of this model's description (its torso height), in the base frame."""
        return mjcf_string(self.description)

    @property
    def num_spheres(self) -> int:
        """S_r, the number of bounding spheres."""
        return int(self.sphere_radii.shape[0])

    @property
    def tool_link(self) -> str:
        """The link whose origin is the tool point (``ee_site`` in the MJCF)."""
        return self.description.tool_link

    # ------------------------------------------------------------------ kinematics

    def _flat(self, q: torch.Tensor, name: str = "q") -> tuple[torch.Tensor, tuple[int, ...]]:
        check_shape(name, q, ("...", self.num_joints))
        if not q.is_floating_point():
            raise ShapeError(f"expected {name} of a floating dtype, got {q.dtype}")
        lead = tuple(q.shape[:-1])
        return q.reshape(-1, self.num_joints), lead  # (N, J)

    def sphere_centers(self, q: torch.Tensor) -> torch.Tensor:
        """Bounding sphere centres in the world (table) frame, differentiable in ``q``.

        Args:
            q: (..., J) joint positions [rad]; leading dimensions may be empty. Not checked for
                NaN (the optimiser's hot path): a non-finite configuration gives NaN centres.

        Returns:
            (..., S_r, 3) sphere centres [m], ordered like :attr:`sphere_radii`.

        Raises:
            ShapeError: when the last dimension of ``q`` is not J or ``q`` is not floating.
        """
        qf, lead = self._flat(q)
        spheres = self._fk.sphere_centers(qf)
        return spheres.reshape(*lead, self.num_spheres, 3)

    def link_positions(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """Origin of every link frame in the world frame.

        Args:
            q: (..., J) joint positions [rad]. Not checked for NaN: a non-finite
                configuration gives NaN positions.

        Returns:
            link name -> (..., 3) position [m], for every name in :attr:`link_names`, of
            ``q``'s dtype and on its device.

        Raises:
            ShapeError: when the last dimension of ``q`` is not J or ``q`` is not floating.
        """
        qf, lead = self._flat(q)
        _, positions, _ = self._fk.frames(qf)
        n = qf.shape[0]
        return {
            name: p.expand(n, 3).reshape(*lead, 3) for name, p in zip(self.link_names, positions)
        }

    def link_poses(self, q: torch.Tensor) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
        """Rotation and origin of every link frame in the world frame.

        Args:
            q: (..., J) joint positions [rad]. Not checked for NaN: a non-finite
                configuration gives NaN poses.

        Returns:
            link name -> ((..., 3, 3) rotation, (..., 3) position [m]).

        Raises:
            ShapeError: when the last dimension of ``q`` is not J or ``q`` is not floating.
        """
        qf, lead = self._flat(q)
        rotations, positions, _ = self._fk.frames(qf)
        n = qf.shape[0]
        return {
            name: (r.expand(n, 3, 3).reshape(*lead, 3, 3), p.expand(n, 3).reshape(*lead, 3))
            for name, r, p in zip(self.link_names, rotations, positions)
        }

    def ee_position(self, q: torch.Tensor) -> torch.Tensor:
        """The tool point (iiwa flange / Fetch gripper_link origin) in the world frame.

        Args:
            q: (..., J) joint positions [rad]. Not checked for NaN (called every IK iteration):
                a non-finite configuration gives a NaN tool point.

        Returns:
            (..., 3) tool point [m].

        Raises:
            ShapeError: when the last dimension of ``q`` is not J or ``q`` is not floating.
        """
        qf, lead = self._flat(q)
        _, positions, _ = self._fk.frames(qf)
        return positions[-1].expand(qf.shape[0], 3).reshape(*lead, 3)

    def position_jacobian(self, q: torch.Tensor) -> torch.Tensor:
        """Analytic Jacobian of :meth:`ee_position`: column i is ``a_i x (p_ee - o_i)``.

        Args:
            q: (..., J) joint positions [rad]. Not checked for NaN (called every IK
                iteration): a non-finite configuration gives a NaN Jacobian.

        Returns:
            (..., 3, J) d p_ee / d q [m/rad].

        Raises:
            ShapeError: when the last dimension of ``q`` is not J or ``q`` is not floating.
        """
        qf, lead = self._flat(q)
        axes, origins, p_ee = self._fk.joint_axes(qf)
        cols = []
        for j, a, o in zip(self.description.actuated_joints, axes, origins):
            cols.append(a if j.type == "prismatic" else torch.linalg.cross(a, p_ee - o))
        return torch.stack(cols, dim=-1).reshape(*lead, 3, self.num_joints)

    def clamp(self, q: torch.Tensor) -> torch.Tensor:
        """``q`` (..., J) [rad] clamped into [q_min, q_max] (continuous joints untouched).

        Raises:
            ShapeError: when the last dimension of ``q`` is not J or ``q`` is not floating.
            DataError: when ``q`` has a NaN or infinite entry (it has no place in the limits).
        """
        self._flat(q)
        check_finite("q", q)
        return self._clamp(q)

    def _clamp(self, q: torch.Tensor) -> torch.Tensor:
        """:meth:`clamp` without checks (inside the IK loop)."""
        lo = self.q_min.to(device=q.device, dtype=q.dtype)
        hi = self.q_max.to(device=q.device, dtype=q.dtype)
        return torch.maximum(torch.minimum(q, hi), lo)

    def ik(
        self,
        target: torch.Tensor,
        q_init: torch.Tensor,
        *,
        iters: int = 100,
        damping: float = 1e-2,
        tol: float = 1e-4,
        max_step: float = 0.3,
    ) -> torch.Tensor:
        """Position-only inverse kinematics by damped least squares with joint clamping.

        Iterates ``dq = J^T (J J^T + damping^2 I)^-1 (target - p_ee(q))``, the step scaled to
        at most ``max_step`` [rad] and ``q`` clamped into the limits after every step. Batched:
        leading dimensions of ``target`` and ``q_init`` must agree. Computed on ``q_init``'s
        device in its dtype (``target`` is converted), or in float32 for a dtype narrower than
        that (float16, bfloat16: ``torch.linalg.solve`` takes neither), the result converted
        back.

        Args:
            target: (..., 3) tool point target in the world frame [m], finite.
            q_init: (..., J) start configuration [rad], finite, of a floating dtype.
            iters: maximum number of iterations.
            damping: ``lambda`` of the damped pseudo-inverse [m].
            tol: stop when every position error is below this [m].
            max_step: largest joint step norm per iteration [rad].

        Returns:
            (..., J) joint positions [rad] in ``q_init``'s dtype, within the limits (rounded
            to that dtype). Unreachable targets return the configuration closest found; check
            ``ee_position`` against the target.

        Raises:
            ShapeError: for mismatched shapes or a non-floating ``q_init``.
            ConfigError: for ``iters`` that is not an integer >= 1, ``damping`` or
                ``max_step`` not finite and > 0, or ``tol`` not finite and >= 0.
            DataError: for a NaN or infinite entry in ``target`` or ``q_init``.
        """
        checks.integer("iters", iters, minimum=1)
        checks.positive("damping", damping)  # inf made every joint NaN
        checks.positive("max_step", max_step)
        checks.non_negative("tol", tol)
        check_shape("target", target, ("...", 3))
        check_shape("q_init", q_init, ("...", self.num_joints))
        if tuple(target.shape[:-1]) != tuple(q_init.shape[:-1]):
            raise ShapeError(
                f"expected target (..., 3) and q_init (..., J) with equal leading dimensions, "
                f"got {tuple(target.shape)} and {tuple(q_init.shape)}"
            )
        if not q_init.is_floating_point():
            raise ShapeError(f"expected q_init of a floating dtype, got {q_init.dtype}")
        check_finite("target", target)
        check_finite("q_init", q_init)
        out_dtype = q_init.dtype
        if torch.finfo(out_dtype).bits < 32:  # float16, bfloat16, float8: solve in float32
            q_init = q_init.float()
        target = target.to(device=q_init.device, dtype=q_init.dtype)
        with torch.no_grad():
            q = self._clamp(q_init.detach().clone())
            eye = torch.eye(3, device=q.device, dtype=q.dtype)
            for _ in range(iters):
                err = target - self.ee_position(q)  # (..., 3)
                if bool((err.norm(dim=-1) < tol).all()):
                    break
                jac = self.position_jacobian(q)  # (..., 3, J)
                a = jac @ jac.transpose(-1, -2) + (damping**2) * eye  # (..., 3, 3)
                dq = (jac.transpose(-1, -2) @ torch.linalg.solve(a, err.unsqueeze(-1))).squeeze(
                    -1
                )  # (..., J)
                scale = (max_step / dq.norm(dim=-1, keepdim=True).clamp_min(1e-12)).clamp(max=1.0)
                q = self._clamp(q + scale * dq)
        return q.to(out_dtype)

    def __repr__(self) -> str:
        base = tuple(round(float(x), 4) for x in self.base_position)
        return (
            f"RobotModel({self.name!r}, J={self.num_joints}, S_r={self.num_spheres}, "
            f"base_position={base}, base_yaw={self.base_yaw:.4f}, dtype={self.dtype})"
        )
