"""A chain with a prismatic joint against MuJoCo's own kinematics.

Neither committed robot moves a prismatic joint (the Fetch torso lift is fixed), so this toy
chain (a tilted slide, then two hinges) is the only check of the ``slide`` branches of
``SerialChainKinematics``: link frames against MuJoCo's body poses and the analytic backward
pass of ``sphere_centers`` against MuJoCo's point Jacobians (``mj_jac``).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import torch

from iplanner_torch.robot.description import JointSpec, LinkSpec, RobotDescription, mjcf_string
from iplanner_torch.robot.geometry import Capsule
from iplanner_torch.robot.kinematics import SerialChainKinematics

BASE_POSITION = (0.4, -0.1, 0.05)
BASE_YAW = 0.7
# link-frame sphere centres [m] of the moving links, in chain order
SPHERES = {
    "slider": np.array([[0.0, 0.0, 0.0], [0.1, 0.02, -0.01]]),
    "arm": np.array([[0.05, 0.0, 0.01], [0.2, -0.03, 0.0]]),
    "tool": np.array([[0.04, 0.01, 0.02]]),
}


def _toy() -> RobotDescription:
    axis = np.array([0.3, -0.4, 0.866])
    axis = tuple(float(a) for a in axis / np.linalg.norm(axis))
    links = tuple(
        LinkSpec(name=name, mass=1.0, geometry=(Capsule(a=(0, 0, 0), b=(0.1, 0, 0), radius=0.04),))
        for name in ("base", "slider", "arm", "tool")
    )
    gains = {"velocity": 1.0, "effort": 10.0, "kp": 100.0, "kv": 10.0}
    tilt = (0.2, -0.3, 0.5)  # the slide's frame, rotated about all three axes
    rows = [  # name, type, parent, child, xyz, rpy, axis, lower, upper
        ("lift", "prismatic", "base", "slider", (0.1, 0.02, 0.3), tilt, axis, -0.2, 0.4),
        ("j1", "revolute", "slider", "arm", (0.1, 0, 0.05), (0.0, 0.4, -0.2), (0, 1, 0), -2, 2),
        ("j2", "revolute", "arm", "tool", (0.2, 0, 0), (0.0, 0.0, 0.0), (0, 0, 1), -2, 2),
    ]  # fmt: skip
    fields = ("name", "type", "parent", "child", "xyz", "rpy", "axis", "lower", "upper")
    joints = tuple(JointSpec(**dict(zip(fields, row)), **gains) for row in rows)
    return RobotDescription(
        name="toy",
        links=links,
        joints=joints,
        base_link="base",
        tool_link="tool",
        sphere_links=("slider", "arm", "tool"),
        q_home=(0.0, 0.0, 0.0),
        default_base_position=BASE_POSITION,
        default_base_yaw=BASE_YAW,
    )


def _world_from_base() -> tuple[np.ndarray, np.ndarray]:
    c, s = math.cos(BASE_YAW), math.sin(BASE_YAW)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array(BASE_POSITION)


def _configurations(n: int) -> np.ndarray:
    rng = np.random.default_rng(3)
    return rng.uniform([-0.2, -2.0, -2.0], [0.4, 2.0, 2.0], size=(n, 3))


def test_prismatic_chain_link_frames_equal_mujoco() -> None:
    """Every link frame at 50 configurations, the slide's travel included. Both sides compute
    in float64 from the same numbers: 1e-9 leaves room for rounding only."""
    desc = _toy()
    fk = SerialChainKinematics(desc, BASE_POSITION, BASE_YAW)
    mj = mujoco.MjModel.from_xml_string(mjcf_string(desc))
    data = mujoco.MjData(mj)
    assert [mj.joint(i).type for i in range(mj.njnt)] == [
        mujoco.mjtJoint.mjJNT_SLIDE,
        mujoco.mjtJoint.mjJNT_HINGE,
        mujoco.mjtJoint.mjJNT_HINGE,
    ]
    rot_wb, p_wb = _world_from_base()
    q = _configurations(50)
    rotations, positions, _ = fk.frames(torch.from_numpy(q))
    for k in range(len(q)):
        data.qpos[:] = q[k]
        mujoco.mj_kinematics(mj, data)
        for i, link in enumerate(fk.link_names):
            body = data.body(link)
            rot = rotations[i][min(k, rotations[i].shape[0] - 1)].numpy()
            pos = positions[i][min(k, positions[i].shape[0] - 1)].numpy()
            np.testing.assert_allclose(pos, rot_wb @ body.xpos + p_wb, rtol=0, atol=1e-9)
            np.testing.assert_allclose(rot, rot_wb @ body.xmat.reshape(3, 3), rtol=0, atol=1e-9)


def test_prismatic_chain_sphere_gradient_equals_mujoco_point_jacobians() -> None:
    """The analytic vector-Jacobian product of ``sphere_centers`` (a slide moves every
    downstream centre along its world axis, with no moment) against sum_s g_s^T J_s, with J_s
    MuJoCo's translational Jacobian of the sphere's centre on its body."""
    desc = _toy()
    fk = SerialChainKinematics(desc, BASE_POSITION, BASE_YAW, SPHERES)
    mj = mujoco.MjModel.from_xml_string(mjcf_string(desc))
    data = mujoco.MjData(mj)
    rot_wb, p_wb = _world_from_base()
    q = torch.from_numpy(_configurations(20)).requires_grad_(True)
    centers = fk.sphere_centers(q)  # (N, S, 3)
    g = torch.from_numpy(np.random.default_rng(4).normal(size=tuple(centers.shape)))
    (grad,) = torch.autograd.grad((centers * g).sum(), q)
    links = [link for link, c in SPHERES.items() for _ in c]
    local = np.concatenate(list(SPHERES.values()))
    jacp = np.zeros((3, mj.nv))
    for k in range(q.shape[0]):
        data.qpos[:] = q[k].detach().numpy()
        mujoco.mj_kinematics(mj, data)
        mujoco.mj_comPos(mj, data)
        want = np.zeros(mj.nv)
        for s, (link, c) in enumerate(zip(links, local)):
            body = data.body(link)
            point = body.xpos + body.xmat.reshape(3, 3) @ c
            np.testing.assert_allclose(
                centers[k, s].detach().numpy(), rot_wb @ point + p_wb, rtol=0, atol=1e-9
            )
            mujoco.mj_jac(mj, data, jacp, None, point, body.id)
            want += g[k, s].numpy() @ (rot_wb @ jacp)
        np.testing.assert_allclose(grad[k].numpy(), want, rtol=0, atol=1e-9)
