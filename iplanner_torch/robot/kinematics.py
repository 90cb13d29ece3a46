"""Batched forward kinematics of a serial chain, written as rotation + translation products.

Per joint ``i`` the child frame is ``T_i = T_{i-1} T_origin_i T_joint_i(q_i)``. For a revolute
joint with unit axis ``k`` (skew matrix ``K``), Rodrigues gives ``R_origin Rot(k, q) =
R_origin + sin q (R_origin K) + (1 - cos q) (R_origin K^2)``: the three constant matrices are
precomputed once, so a joint costs one product with a constant matrix and a few element-wise
operations. Everything is differentiable with autograd; ``SerialChainKinematics.sphere_centers``
has its own analytic backward pass (a few tensor operations instead of one autograd node per
element-wise step), which the trajectory optimiser calls every iteration.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from iplanner_torch.checks import finite, finite_tuple
from iplanner_torch.errors import ConfigError
from iplanner_torch.robot.description import RobotDescription, rpy_to_matrix


def _skew(k: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])


class SerialChainKinematics:
    """Link frames (and optionally sphere centres) of a serial chain at a base pose.

    Per link ``i`` with world rotation ``R_i``, one matrix product ``R_i @ C_i`` with a
    constant (3, 11 + S_i) block ``C_i = [R0 | R0 K | R0 K^2 | R0 a | p0 | c_1 .. c_S_i]`` gives
    everything the next joint and the link's spheres need; the rest is element-wise. The
    product is written as one (N*3, 3) @ (3, 11 + S_i) GEMM, which is far faster than a batched
    3x3 product on the CPU and is a single kernel on a GPU.

    Args:
        desc: the robot description (a serial chain).
        base_position: (3,) base origin in the world (table) frame [m].
        base_yaw: base rotation about the world z axis [rad].
        sphere_centers_local: link name -> (S_l, 3) sphere centres in that link's frame [m];
            spheres are returned in this mapping's order.

    Raises:
        ConfigError: when ``base_position`` is not 3 finite numbers, ``base_yaw`` not a
            finite number, or a sphere link is not in the chain or out of chain order.
    """

    def __init__(
        self,
        desc: RobotDescription,
        base_position: tuple[float, float, float],
        base_yaw: float,
        sphere_centers_local: dict[str, np.ndarray] | None = None,
    ) -> None:
        self.desc = desc
        self.link_names: tuple[str, ...] = (desc.base_link,) + tuple(j.child for j in desc.joints)
        spheres = {} if sphere_centers_local is None else dict(sphere_centers_local)
        unknown = set(spheres) - set(self.link_names)
        if unknown:
            raise ConfigError(f"sphere links not in the chain: {sorted(unknown)}")
        link_order = {n: i for i, n in enumerate(self.link_names)}
        if list(spheres) != sorted(spheres, key=lambda n: link_order[n]):
            raise ConfigError("sphere links must be given in chain order")
        self.num_spheres = sum(len(c) for c in spheres.values())
        if isinstance(base_yaw, torch.Tensor | np.ndarray) and base_yaw.ndim == 0:
            base_yaw = base_yaw.item()
        base_yaw = finite("base_yaw", base_yaw)
        base = finite_tuple(
            "base_position",
            base_position.tolist() if hasattr(base_position, "tolist") else base_position,
            3,
        )
        c, s = math.cos(base_yaw), math.sin(base_yaw)
        self._rot_world_base = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        self._p_world_base = np.asarray(base, dtype=np.float64)
        # One block per link: the link's child joint (if any) and its spheres (if any).
        self._kinds: list[str | None] = []
        self._blocks: list[np.ndarray] = []
        self._n_spheres: list[int] = []
        for i, link in enumerate(self.link_names):
            cols = np.zeros((3, 11))
            kind = None
            if i < len(desc.joints):
                j = desc.joints[i]
                r0 = rpy_to_matrix(j.rpy)
                axis = np.asarray(j.axis, dtype=np.float64)
                k = _skew(axis)
                cols = np.concatenate(
                    [r0, r0 @ k, r0 @ k @ k, (r0 @ axis)[:, None], np.asarray(j.xyz)[:, None]],
                    axis=1,
                )
                kind = "fixed" if not j.actuated else ("slide" if j.type == "prismatic" else "rev")
            centers = np.asarray(spheres.get(link, np.zeros((0, 3))), dtype=np.float64)
            self._blocks.append(np.concatenate([cols, centers.T], axis=1))  # (3, 11 + S_l)
            self._kinds.append(kind)
            self._n_spheres.append(len(centers))
        self._cache: dict[tuple[torch.device, torch.dtype], tuple] = {}
        # Actuated joints in q-column order: (child link index, kind, local axis); and the
        # link of every sphere (spheres are concatenated in chain order).
        self._actuated = [
            (i + 1, "slide" if j.type == "prismatic" else "rev", np.asarray(j.axis, float))
            for i, j in enumerate(desc.joints)
            if j.actuated
        ]
        sphere_link = np.repeat(np.arange(len(self.link_names)), self._n_spheres)
        # downstream[j, s] = 1 when sphere s moves with joint j (it lies on its child or later)
        self._downstream = np.stack(
            [(sphere_link >= child).astype(np.float64) for child, _, _ in self._actuated]
        ).reshape(len(self._actuated), self.num_spheres)

    def _constants(self, device: torch.device, dtype: torch.dtype) -> tuple:
        key = (device, dtype)
        if key not in self._cache:

            def t(x: np.ndarray) -> torch.Tensor:
                return torch.as_tensor(x, device=device, dtype=dtype)

            self._cache[key] = (
                t(self._rot_world_base.T).unsqueeze(1).contiguous(),  # (3, 1, 3), see frames
                t(self._p_world_base).unsqueeze(0),  # (1, 3)
                [t(b.T).contiguous() for b in self._blocks],  # (11 + S_l, 3)
                [t(b[:, :11].T).contiguous() for b in self._blocks],  # (11, 3)
                [t(b[:, 11:].T).contiguous() for b in self._blocks],  # (S_l, 3)
                t(self._downstream),  # (J, S)
                [t(a) for _, _, a in self._actuated],  # J x (3,)
            )
        return self._cache[key]

    def frames(
        self, q: torch.Tensor, with_spheres: bool = False
    ) -> tuple[list[torch.Tensor], list[torch.Tensor], torch.Tensor | None]:
        """World rotation and position of every link, and optionally the sphere centres.

        Args:
            q: (N, J) joint positions [rad or m], flat batch (N may be 0); not shape- or
                NaN-checked (hot path): a non-finite row gives non-finite frames in that row.
            with_spheres: also return the sphere centres.

        Returns:
            ``(rotations, positions, spheres)``: lists over links (base first, chain order) of
            (n, 3, 3) and (n, 3) tensors, n being N or 1 for links fixed to the world; and
            (N, S, 3) sphere centres in the world frame [m] (None unless ``with_spheres``).
        """
        # Rotations are carried as x[k, n, r] = R_n[r, k] (shape (3, n, 3)): then the product
        # with a constant block is one GEMM, and every slice below is contiguous.
        x_wb, p_wb, blocks, joint_blocks, sphere_blocks = self._constants(q.device, q.dtype)[:5]
        n = q.shape[0]
        x, pos = x_wb, p_wb
        xs, positions, parts = [], [], []
        col = 0
        last = len(self.link_names) - 1
        for i, (kind, n_sph) in enumerate(zip(self._kinds, self._n_spheres)):
            xs.append(x)
            positions.append(pos)
            want = with_spheres and n_sph > 0
            if i == last and not want:
                break
            if kind is None:
                block = sphere_blocks[i]
            else:
                block = blocks[i] if want else joint_blocks[i]
            m = x.shape[1]
            y = (block @ x.reshape(3, m * 3)).view(block.shape[0], m, 3)  # (cols, m, 3)
            if kind is None:
                parts.append(y + pos)  # (S_l, m, 3)
                break
            if want:
                parts.append(y[11:] + pos)  # (S_l, m, 3)
            pos = pos + y[10]
            if kind == "rev":
                qi = q[:, col].reshape(1, -1, 1)  # (1, N, 1)
                col += 1
                x = y[0:3] + torch.sin(qi) * y[3:6] + (1.0 - torch.cos(qi)) * y[6:9]
            elif kind == "slide":
                qi = q[:, col].reshape(-1, 1)  # (N, 1)
                col += 1
                pos = pos + qi * y[9]
                x = y[0:3]
            else:
                x = y[0:3]
        rotations = [xi.permute(1, 2, 0) for xi in xs]  # (n, 3, 3) views
        spheres = None
        if with_spheres:
            if not parts:
                spheres = q.new_zeros(n, 0, 3)
            else:
                spheres = torch.cat([p.expand(-1, n, 3) for p in parts], dim=0)  # (S, N, 3)
                spheres = spheres.transpose(0, 1)  # (N, S, 3)
        return rotations, positions, spheres

    def joint_axes(
        self, q: torch.Tensor
    ) -> tuple[list[torch.Tensor], list[torch.Tensor], torch.Tensor]:
        """World axis and origin of every actuated joint, and the last link's origin.

        Args:
            q: (N, J) joint positions [rad or m].

        Returns:
            ``(axes, origins, tip)``: lists over actuated joints of (N, 3) unit axes and (N, 3)
            joint origins in the world frame [m], and (N, 3) origin of the last link [m].
        """
        rotations, positions, _ = self.frames(q)
        axes, origins = [], []
        for i, j in enumerate(self.desc.joints):
            if not j.actuated:
                continue
            rot, pos = rotations[i + 1], positions[i + 1]
            a = torch.as_tensor(j.axis, device=q.device, dtype=q.dtype)
            axes.append((rot @ a).expand(q.shape[0], 3))
            origins.append(pos.expand(q.shape[0], 3))
        return axes, origins, positions[-1].expand(q.shape[0], 3)

    def sphere_centers(self, q: torch.Tensor) -> torch.Tensor:
        """Sphere centres with an analytic backward pass (no second derivatives).

        Args:
            q: (N, J) joint positions [rad or m], flat batch (N may be 0); not shape- or
                NaN-checked (hot path): a non-finite row gives non-finite centres in that row.

        Returns:
            (N, S, 3) sphere centres in the world frame [m].
        """
        if not (torch.is_grad_enabled() and q.requires_grad):
            return self.frames(q, with_spheres=True)[2]  # type: ignore[return-value]
        return _SphereCenters.apply(q, self)

    def _sphere_jacobian_t(
        self,
        rotations: list[torch.Tensor],
        positions: list[torch.Tensor],
        centers: torch.Tensor,
        grad: torch.Tensor,
    ) -> torch.Tensor:
        """Vector-Jacobian product of :meth:`sphere_centers`: (N, S, 3) -> (N, J).

        A revolute joint with world axis ``a`` through ``o`` moves a downstream sphere centre
        ``c`` by ``a x (c - o)`` per radian, so ``dL/dq = a . (sum_s c_s x g_s - o x sum_s
        g_s)`` over the spheres downstream of the joint; a prismatic joint gives ``a . sum g``.
        """
        down, axes_local = self._constants(centers.device, centers.dtype)[5:]
        n = centers.shape[0]
        moment = torch.einsum("js,nsc->njc", down, torch.linalg.cross(centers, grad))  # (N, J, 3)
        force = torch.einsum("js,nsc->njc", down, grad)  # (N, J, 3)
        axes = torch.stack(
            [(rotations[c] @ a).expand(n, 3) for (c, _, _), a in zip(self._actuated, axes_local)],
            dim=1,
        )  # (N, J, 3) world axes
        origins = torch.stack([positions[c].expand(n, 3) for c, _, _ in self._actuated], dim=1)
        revolute = [k for k, (_, kind, _) in enumerate(self._actuated) if kind == "rev"]
        if len(revolute) == len(self._actuated):
            torque = moment - torch.linalg.cross(origins, force)
        else:  # prismatic joints: a . sum g (no moment)
            torque = force.clone()
            torque[:, revolute] = moment[:, revolute] - torch.linalg.cross(
                origins[:, revolute], force[:, revolute]
            )
        return (axes * torque).sum(-1)


class _SphereCenters(torch.autograd.Function):
    """Sphere centres of a chain with the analytic vector-Jacobian product."""

    @staticmethod
    def forward(ctx, q: torch.Tensor, fk: SerialChainKinematics) -> torch.Tensor:  # type: ignore[override]
        rotations, positions, centers = fk.frames(q, with_spheres=True)
        ctx.fk = fk
        ctx.frames = (rotations, positions)  # outputs of no autograd graph (no-grad forward)
        ctx.save_for_backward(centers)
        return centers

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, None]:  # type: ignore[override]
        (centers,) = ctx.saved_tensors
        rotations, positions = ctx.frames
        return ctx.fk._sphere_jacobian_t(rotations, positions, centers, grad), None
