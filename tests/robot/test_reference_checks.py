"""RobotModel against MuJoCo's own kinematics of the same description.

The model's MJCF (``RobotModel.mjcf_xml``, in the base frame) is compiled by MuJoCo; its link
poses, tool Jacobian and collision geoms, moved to the table frame by the model's base pose,
are the references for the torch forward kinematics, the analytic Jacobian and the bounding
spheres.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from iplanner_torch.robot.model import RobotModel

# (name, load arguments): a moved base, and for the Fetch a torso height other than the
# committed asset's
CASES = [
    ("kuka_iiwa14", {"base_position": (0.7, 0.1, 0.05), "base_yaw": 2.8}),
    ("fetch", {"base_position": (1.1, -0.2, -0.75), "base_yaw": -2.5, "torso_height": 0.05}),
]
IDS = [name for name, _ in CASES]


def _world_from_base(model: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and origin (3,) of the base frame in the table frame."""
    c, s = math.cos(model.base_yaw), math.sin(model.base_yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot, model.base_position.double().numpy()


def _random_q(model: RobotModel, n: int, seed: int) -> np.ndarray:
    lo = np.nan_to_num(model.q_min.double().numpy(), neginf=-math.pi)
    hi = np.nan_to_num(model.q_max.double().numpy(), posinf=math.pi)
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, model.num_joints))


def _mujoco(model: RobotModel) -> tuple[mujoco.MjModel, mujoco.MjData]:
    mj = mujoco.MjModel.from_xml_string(model.mjcf_xml())
    assert [mj.joint(i).name for i in range(mj.njnt)] == list(model.joint_names)
    return mj, mujoco.MjData(mj)


@pytest.mark.parametrize(("name", "kwargs"), CASES, ids=IDS)
def test_link_poses_equal_mujoco_kinematics(name: str, kwargs: dict) -> None:
    """Every link frame (rotation and origin) at 200 random configurations. Tolerance: both
    sides compute in float64 from the same numbers (the MJCF prints them with repr, its
    quaternions are normalised by MuJoCo), so 1e-9 m / 1e-9 leaves room for rounding only."""
    model = RobotModel.load(name, dtype=torch.float64, **kwargs)
    mj, data = _mujoco(model)
    rot_wb, p_wb = _world_from_base(model)
    q = _random_q(model, 200, seed=0)
    poses = model.link_poses(torch.from_numpy(q))
    assert set(poses) == {mj.body(i).name for i in range(1, mj.nbody)}
    for k in range(q.shape[0]):
        data.qpos[:] = q[k]
        mujoco.mj_kinematics(mj, data)
        for link, (rot, pos) in poses.items():
            body = data.body(link)
            want_pos = rot_wb @ body.xpos + p_wb
            want_rot = rot_wb @ body.xmat.reshape(3, 3)
            np.testing.assert_allclose(pos[k].numpy(), want_pos, rtol=0, atol=1e-9)
            np.testing.assert_allclose(rot[k].numpy(), want_rot, rtol=0, atol=1e-9)
    # the tool point is MuJoCo's ee_site
    ee = model.ee_position(torch.from_numpy(q[-1])).numpy()
    np.testing.assert_allclose(ee, rot_wb @ data.site("ee_site").xpos + p_wb, rtol=0, atol=1e-9)


@pytest.mark.parametrize(("name", "kwargs"), CASES, ids=IDS)
def test_sphere_centres_are_mujoco_body_frames_applied_to_the_local_centres(
    name: str, kwargs: dict
) -> None:
    """``sphere_centers`` (the hot path with its own analytic backward pass) equals MuJoCo's
    body pose applied to each sphere's link-frame centre. Tolerance as above."""
    model = RobotModel.load(name, dtype=torch.float64, **kwargs)
    mj, data = _mujoco(model)
    rot_wb, p_wb = _world_from_base(model)
    q = _random_q(model, 50, seed=1)
    got = model.sphere_centers(torch.from_numpy(q)).numpy()  # (N, S, 3)
    local = model.sphere_centers_local.numpy()
    for k in range(q.shape[0]):
        data.qpos[:] = q[k]
        mujoco.mj_kinematics(mj, data)
        for s, link in enumerate(model.sphere_link):
            body = data.body(link)
            c = body.xmat.reshape(3, 3) @ local[s] + body.xpos
            np.testing.assert_allclose(got[k, s], rot_wb @ c + p_wb, rtol=0, atol=1e-9)


@pytest.mark.parametrize(("name", "kwargs"), CASES, ids=IDS)
def test_position_jacobian_equals_mujoco_site_jacobian(name: str, kwargs: dict) -> None:
    """``position_jacobian`` against ``mj_jacSite`` at the tool site (rotated to the table
    frame; a translation of the base does not change it). Tolerance: float64 rounding."""
    model = RobotModel.load(name, dtype=torch.float64, **kwargs)
    mj, data = _mujoco(model)
    rot_wb, _ = _world_from_base(model)
    site = mj.site("ee_site").id
    q = _random_q(model, 30, seed=2)
    got = model.position_jacobian(torch.from_numpy(q)).numpy()  # (N, 3, J)
    jacp = np.zeros((3, mj.nv))
    for k in range(q.shape[0]):
        data.qpos[:] = q[k]
        mujoco.mj_kinematics(mj, data)
        mujoco.mj_comPos(mj, data)
        mujoco.mj_jacSite(mj, data, jacp, None, site)
        np.testing.assert_allclose(got[k], rot_wb @ jacp, rtol=0, atol=1e-9)


def _surface_points(mj: mujoco.MjModel, data: mujoco.MjData, g: int, rng, n: int) -> np.ndarray:
    """(n', 3) points on the surface of MuJoCo geom ``g`` (capsule, cylinder or box), edges and
    rims included, in the base frame, from MuJoCo's own geom pose and size."""
    size = mj.geom_size[g]
    kind = mj.geom_type[g]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        p = rng.uniform(-size, size, (n, 3))
        axis = rng.integers(0, 3, n)
        p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -1.0, 1.0) * size[axis]
        corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * 3)).reshape(3, -1).T * size
        local = np.concatenate([p, corners])
    else:
        r, half = size[0], size[1]  # the local z axis is the geom's axis
        phi = rng.uniform(0.0, 2 * math.pi, n)
        ring = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], 1)
        z = rng.uniform(-half, half, n)[:, None] * np.array([0.0, 0.0, 1.0])
        side = r * ring + z
        if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            d = rng.normal(size=(n, 3))
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            cap = np.where(d[:, 2:] >= 0, half, -half) * np.array([0.0, 0.0, 1.0])
            local = np.concatenate([side, cap + r * d])
        else:
            assert kind == mujoco.mjtGeom.mjGEOM_CYLINDER
            ends = np.where(rng.random((n, 1)) < 0.5, half, -half) * np.array([0.0, 0.0, 1.0])
            disc = np.sqrt(rng.random((n, 1))) * r * ring + ends
            rims = np.concatenate([r * ring + [0, 0, half], r * ring - [0, 0, half]])
            local = np.concatenate([side, disc, rims])
    return local @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]


@pytest.mark.parametrize(("name", "kwargs"), CASES, ids=IDS)
def test_spheres_cover_mujoco_collision_geoms(name: str, kwargs: dict) -> None:
    """Surface points of every collision geom of a sphere-carrying link, placed by MuJoCo and
    read from MuJoCo's own geom sizes, lie inside the model's world spheres (the spheres
    cover the solid the simulator collides with). Tolerance 1e-9 m: covering is exact by
    construction, rounding only."""
    model = RobotModel.load(name, dtype=torch.float64, **kwargs)
    mj, data = _mujoco(model)
    rot_wb, p_wb = _world_from_base(model)
    rng = np.random.default_rng(3)
    q = _random_q(model, 4, seed=4)
    centers = model.sphere_centers(torch.from_numpy(q)).numpy()
    radii = model.sphere_radii.numpy()
    owner = np.array(model.sphere_link)
    checked = 0
    for k in range(q.shape[0]):
        data.qpos[:] = q[k]
        mujoco.mj_kinematics(mj, data)
        for g in range(mj.ngeom):
            link = mj.body(mj.geom_bodyid[g]).name
            if link not in model.description.sphere_links:
                continue
            pts = _surface_points(mj, data, g, rng, 1500) @ rot_wb.T + p_wb
            mine = owner == link
            gap = np.linalg.norm(pts[:, None] - centers[k, mine][None], axis=-1) - radii[mine]
            assert gap.min(axis=1).max() <= 1e-9, (link, k, gap.min(axis=1).max())
            checked += 1
    assert checked == q.shape[0] * len(model.description.sphere_links)
