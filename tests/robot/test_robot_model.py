"""RobotModel: our torch FK against pytorch-kinematics, gradients, limits, IK, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import pytorch_kinematics as pk
import torch

from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.robot.model import RobotCfg, RobotModel

ROBOTS = ("kuka_iiwa14", "fetch")


def _uniform_q(model: RobotModel, n: int, frac: float = 1.0) -> torch.Tensor:
    lo = torch.where(
        torch.isfinite(model.q_min), model.q_min, torch.full_like(model.q_min, -math.pi)
    )
    hi = torch.where(
        torch.isfinite(model.q_max), model.q_max, torch.full_like(model.q_max, math.pi)
    )
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * frac
    return mid + half * (2 * torch.rand(n, model.num_joints, dtype=model.dtype) - 1)


def _pk_reference_spheres(model: RobotModel, q: torch.Tensor) -> torch.Tensor:
    """Sphere centres from pytorch-kinematics link poses (float64), in the world frame."""
    chain = pk.build_serial_chain_from_urdf(model.urdf_xml(), model.tool_link).to(
        dtype=torch.float64
    )
    frames = chain.forward_kinematics(q.double(), end_only=False)
    c, s = math.cos(model.base_yaw), math.sin(model.base_yaw)
    t_wb = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    p_wb = model.base_position.double()
    out = []
    local = model.sphere_centers_local.double()
    for i, link in enumerate(model.sphere_link):
        m = frames[link].get_matrix()  # (N, 4, 4)
        p_base = (m[:, :3, :3] @ local[i]) + m[:, :3, 3]
        out.append(p_base @ t_wb.T + p_wb)
    return torch.stack(out, dim=1)  # (N, S, 3)


@pytest.mark.parametrize("name", ROBOTS)
def test_sphere_centers_equal_pytorch_kinematics(name: str) -> None:
    model = RobotModel.load(
        name, dtype=torch.float64, base_position=(0.5, 0.2, -0.1), base_yaw=2.0
    )
    q = _uniform_q(model, 500)
    ours = model.sphere_centers(q)
    assert ours.shape == (500, model.num_spheres, 3)
    assert (ours - _pk_reference_spheres(model, q)).abs().max() < 1e-5


@pytest.mark.parametrize("name", ROBOTS)
def test_float32_close_to_float64_and_batch_shapes(name: str) -> None:
    m64 = RobotModel.load(name, dtype=torch.float64)
    m32 = RobotModel.load(name)
    q = _uniform_q(m64, 3 * 20).view(3, 20, -1)  # (B, W, J)
    c64 = m64.sphere_centers(q)
    c32 = m32.sphere_centers(q.float())
    assert c32.dtype == torch.float32 and c32.shape == (3, 20, m32.num_spheres, 3)
    assert (c32.double() - c64).abs().max() < 1e-5
    flat = m64.sphere_centers(q.reshape(60, -1)).view(3, 20, -1, 3)
    assert torch.equal(flat, c64)
    one = m64.sphere_centers(q[1, 7])
    assert torch.allclose(one, c64[1, 7], atol=1e-12)


@pytest.mark.parametrize("name", ROBOTS)
def test_link_and_ee_positions_equal_pytorch_kinematics(name: str) -> None:
    model = RobotModel.load(name, dtype=torch.float64, base_position=(0, 0, 0), base_yaw=0.0)
    chain = pk.build_serial_chain_from_urdf(model.urdf_xml(), model.tool_link).to(
        dtype=torch.float64
    )
    q = _uniform_q(model, 200)
    frames = chain.forward_kinematics(q, end_only=False)
    ours = model.link_positions(q)
    assert set(ours) == set(frames) == set(model.link_names)
    for link, tf in frames.items():
        assert (ours[link] - tf.get_matrix()[:, :3, 3]).abs().max() < 1e-5, link
    poses = model.link_poses(q)
    for link, tf in frames.items():
        assert (poses[link][0] - tf.get_matrix()[:, :3, :3]).abs().max() < 1e-6, link
    ee = model.ee_position(q)
    assert (ee - frames[model.tool_link].get_matrix()[:, :3, 3]).abs().max() < 1e-5


@pytest.mark.parametrize("name", ROBOTS)
def test_gradients_match_finite_differences(name: str) -> None:
    model = RobotModel.load(name, dtype=torch.float64)
    q = _uniform_q(model, 2).requires_grad_(True)
    w = torch.randn(2, model.num_spheres, 3, dtype=torch.float64)
    assert torch.autograd.gradcheck(
        lambda x: (model.sphere_centers(x) * w).sum(), (q,), eps=1e-6, atol=1e-7
    )


@pytest.mark.parametrize("name", ROBOTS)
def test_analytic_sphere_backward_equals_autograd_through_the_chain(name: str) -> None:
    # sphere_centers has its own vector-Jacobian product; autograd through the plain chain
    # product (frames) is the reference
    model = RobotModel.load(name, dtype=torch.float64)
    q = _uniform_q(model, 64).requires_grad_(True)
    g = torch.randn(64, model.num_spheres, 3, dtype=torch.float64)
    (grad,) = torch.autograd.grad((model.sphere_centers(q) * g).sum(), q)
    (ref,) = torch.autograd.grad((model._fk.frames(q, with_spheres=True)[2] * g).sum(), q)
    assert torch.allclose(grad, ref, rtol=1e-10, atol=1e-12)
    assert float(ref.abs().max()) > 0.1


@pytest.mark.parametrize("name", ROBOTS)
def test_position_jacobian_matches_finite_differences(name: str) -> None:
    model = RobotModel.load(name, dtype=torch.float64)
    q = _uniform_q(model, 5)
    jac = model.position_jacobian(q)  # (5, 3, J)
    eps = 1e-6
    for i in range(model.num_joints):
        dq = torch.zeros_like(q)
        dq[:, i] = eps
        fd = (model.ee_position(q + dq) - model.ee_position(q - dq)) / (2 * eps)
        assert (jac[..., i] - fd).abs().max() < 1e-7


def test_limits_and_home() -> None:
    iiwa = RobotModel.load("kuka_iiwa14")
    deg = math.pi / 180
    np.testing.assert_allclose(
        iiwa.q_max.numpy(), np.array([170, 120, 170, 120, 170, 120, 175]) * deg, rtol=1e-6
    )
    np.testing.assert_allclose(
        iiwa.v_max.numpy(), np.array([85, 85, 100, 75, 130, 135, 135]) * deg, rtol=1e-6
    )
    assert torch.equal(iiwa.q_min, -iiwa.q_max)
    assert iiwa.joint_names == tuple(f"iiwa_joint_{i}" for i in range(1, 8))
    fetch = RobotModel.load("fetch")
    continuous = [
        n in ("upperarm_roll_joint", "forearm_roll_joint", "wrist_roll_joint")
        for n in fetch.joint_names
    ]
    assert torch.isinf(fetch.q_max).tolist() == continuous
    assert torch.isinf(fetch.q_min).tolist() == continuous
    assert fetch.q_min[1].item() == pytest.approx(-1.221) and fetch.q_max[
        1
    ].item() == pytest.approx(1.518)
    for m in (iiwa, fetch):
        assert m.num_joints == 7 and m.q_home.shape == (7,)
        assert bool(((m.q_home >= m.q_min) & (m.q_home <= m.q_max)).all())
        assert m.sphere_radii.shape == (m.num_spheres,) == (len(m.sphere_link),)
        assert m.urdf_path.is_file() and m.mjcf_path.is_file()
    assert RobotModel.available() == ("kuka_iiwa14", "fetch")


def test_default_base_poses_in_the_table_frame() -> None:
    iiwa = RobotModel.load("kuka_iiwa14")
    ee = iiwa.ee_position(iiwa.q_home)
    # Home flange (0.669, 0, 0.285) in the base frame, base at (0.75, 0, 0) facing -x.
    assert torch.allclose(ee, torch.tensor([0.75 - 0.669, 0.0, 0.285]), atol=0.01)
    fetch = RobotModel.load("fetch")
    shoulder = fetch.link_positions(fetch.q_home)["shoulder_lift_link"]
    assert abs(shoulder[2].item() - 0.3) < 0.02
    # Home is retracted towards the robot: over the far block rows (x 0.32-0.44), not over
    # the delivery spots where the person reaches (x 0.04-0.18).
    from iplanner_torch.sim.scene import SceneCfg

    scene = SceneCfg()
    ee = fetch.ee_position(fetch.q_home)
    assert ee[0].item() > max(scene.block_rows_x) and ee[2].item() > 0.2
    taller = RobotModel.load("fetch", torso_height=0.36)
    dz = taller.link_positions(taller.q_home)["shoulder_lift_link"][2] - shoulder[2]
    assert dz.item() == pytest.approx(0.1, abs=1e-6)


@pytest.mark.parametrize("name", ROBOTS)
def test_ik_reaches_reachable_targets(name: str) -> None:
    model = RobotModel.load(name, dtype=torch.float64)
    q_goal = _uniform_q(model, 30, frac=0.7)
    target = model.ee_position(q_goal)
    q = model.ik(target, model.q_home.expand(30, -1), iters=200)
    err = (model.ee_position(q) - target).norm(dim=-1)
    assert bool(((q >= model.q_min) & (q <= model.q_max)).all())
    assert (err < 0.01).float().mean() >= 0.9, err
    # Single target, the interface's (3,), (J,) -> (J,).
    q1 = model.ik(target[0], model.q_home)
    assert q1.shape == (model.num_joints,)
    assert (model.ee_position(q1) - target[0]).norm() < 0.01


def test_ik_clamps_to_limits_for_an_unreachable_target() -> None:
    model = RobotModel.load("kuka_iiwa14", dtype=torch.float64)
    q = model.ik(torch.tensor([5.0, 0.0, 0.0], dtype=torch.float64), model.q_home, iters=50)
    assert bool(((q >= model.q_min) & (q <= model.q_max)).all())
    reach = (model.ee_position(q) - model.link_positions(q)["iiwa_link_2"]).norm()
    assert reach.item() > 0.9  # stretched towards the target


def test_errors() -> None:
    with pytest.raises(ConfigError, match="unknown robot 'ur5'"):
        RobotModel.load("ur5")
    with pytest.raises(ConfigError, match="has no torso"):
        RobotModel.load("kuka_iiwa14", torso_height=0.2)
    with pytest.raises(ConfigError, match="torso_height"):
        RobotModel.load("fetch", torso_height=0.6)
    with pytest.raises(ConfigError, match="base_position"):
        RobotCfg(name="fetch", base_position=(0.0, 1.0))
    for excess in (float("inf"), float("nan"), 0.0, 10.0):  # inf made spheres of radius inf
        with pytest.raises(ConfigError, match=r"expected max_sphere_excess in \(0, 0.2\] m"):
            RobotCfg(name="kuka_iiwa14", max_sphere_excess=excess)
    model = RobotModel.load("kuka_iiwa14")
    with pytest.raises(ShapeError, match=r"expected q \(\.\.\., 7\), got \(4, 6\)"):
        model.sphere_centers(torch.zeros(4, 6))
    with pytest.raises(ShapeError, match="floating"):
        model.ee_position(torch.zeros(7, dtype=torch.long))
    with pytest.raises(ShapeError, match="equal leading"):
        model.ik(torch.zeros(2, 3), torch.zeros(3, 7))
    target, q0 = model.ee_position(model.q_home) + 0.1, model.q_home
    for kwargs, message in (
        ({"damping": float("inf")}, "expected damping > 0 and finite"),  # gave NaN joints
        ({"iters": 1.5}, "expected iters an integer >= 1"),  # a raw TypeError before
        ({"iters": "5"}, "expected iters an integer >= 1"),
        ({"max_step": float("nan")}, "expected max_step > 0 and finite"),
        ({"tol": -1.0}, "expected tol >= 0 and finite"),
    ):
        with pytest.raises(ConfigError, match=message):
            model.ik(target, q0, **kwargs)
    with pytest.raises(ConfigError, match="damping > 0"):
        model.ik(torch.zeros(3), model.q_home, damping=0.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        # a scalar failed with Python's "'float' object is not iterable"
        ({"base_position": 0.75}, r"expected base_position a list of 3 finite numbers .*0\.75"),
        ({"base_position": "0.75"}, "expected base_position a list of 3 finite numbers"),
        ({"base_position": [0.75, 0.0]}, "expected base_position a list of 3 finite numbers"),
        ({"base_position": [0.75, 0.0, 0.0, 0.0]}, "expected base_position a list of 3"),
        ({"base_position": [0.75, "0", 0.0]}, "expected base_position a list of 3"),
        ({"base_position": [0.75, 0.0, math.nan]}, "expected base_position a list of 3"),
        ({"base_position": [[0.75, 0.0, 0.0]]}, "expected base_position a list of 3"),
        ({"base_position": {"x": 0.75}}, "expected base_position a list of 3"),
        ({"base_yaw": "pi"}, "expected a finite base_yaw, got 'pi'"),
        ({"base_yaw": [3.14]}, "expected a finite base_yaw"),
        ({"max_sphere_excess": "0.02"}, r"expected max_sphere_excess in \(0, 0.2\] m"),
        ({"name": "fetch", "torso_height": "0.2"}, "expected torso_height a finite number"),
        ({"name": "fetch", "torso_height": [0.2]}, "expected torso_height a finite number"),
    ],
)
def test_wrongly_shaped_or_typed_settings_name_the_key(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        RobotCfg(**{"name": "kuka_iiwa14", **kwargs})


def test_a_robot_file_with_a_scalar_base_position_names_the_key(tmp_path) -> None:
    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import instantiate

    path = tmp_path / "my_iiwa.yaml"
    path.write_text(
        "_target_: iplanner_torch.robot.model.RobotCfg\n"
        "name: kuka_iiwa14\n"
        "base_position: 0.75\n"
        "base_yaw: 3.141592653589793\n"
    )
    with pytest.raises(
        ConfigError,
        match=r"^robot\.base_position: expected base_position a list of 3 finite numbers",
    ) as err:
        instantiate(OmegaConf.load(path), RobotCfg, name="robot")
    assert "not iterable" not in str(err.value)
    with pytest.raises(ConfigError, match="expected base_position a list of 3"):
        RobotModel.load("kuka_iiwa14", base_position=0.75)


def test_base_positions_of_every_kind_are_taken() -> None:
    for pos in ([1, 0, -0.75], (1.0, 0.0, -0.75), np.array([1.0, 0.0, -0.75])):
        assert RobotCfg(name="fetch", base_position=pos).base_position == (1.0, 0.0, -0.75)
    pos = torch.tensor([1.0, 0.0, -0.75], dtype=torch.float64)
    assert RobotCfg(name="fetch", base_position=pos).base_position == (1.0, 0.0, -0.75)
    model = RobotModel.load("fetch", dtype=torch.float64, base_position=pos)
    assert model.base_position.tolist() == [1.0, 0.0, -0.75]


def test_from_cfg_equals_load() -> None:
    cfg = RobotCfg(name="fetch", base_position=[1.1, 0.1, -0.75], base_yaw=3.0, torso_height=0.2)
    assert cfg.base_position == (1.1, 0.1, -0.75)
    a = RobotModel.from_cfg(cfg, dtype=torch.float64)
    b = RobotModel.load(
        "fetch",
        dtype=torch.float64,
        base_position=(1.1, 0.1, -0.75),
        base_yaw=3.0,
        torso_height=0.2,
    )
    q = _uniform_q(a, 4)
    assert torch.equal(a.sphere_centers(q), b.sphere_centers(q))


def test_device_follows_input(device: torch.device) -> None:
    model = RobotModel.load("kuka_iiwa14", device=device)
    q = _uniform_q(RobotModel.load("kuka_iiwa14"), 16).to(device)
    out = model.sphere_centers(q)
    assert out.device.type == device.type
    ref = RobotModel.load("kuka_iiwa14").sphere_centers(q.cpu())
    assert (out.cpu() - ref).abs().max() < 1e-5


def test_ik_and_clamp_reject_non_finite_input() -> None:
    model = RobotModel.load("kuka_iiwa14")
    with pytest.raises(DataError, match=r"target is NaN/Inf at index \(0,\)"):
        model.ik(torch.tensor([math.nan, 0.0, 0.5]), model.q_home)
    q_init = model.q_home.expand(3, -1).clone()
    q_init[1, 4] = math.inf
    with pytest.raises(DataError, match=r"q_init is NaN/Inf at index \(1, 4\)"):
        model.ik(torch.zeros(3, 3), q_init)
    q = model.q_home.clone()
    q[2] = math.nan
    with pytest.raises(DataError, match=r"q is NaN/Inf at index \(2,\)"):
        model.clamp(q)
    assert torch.equal(model.clamp(model.q_max + 1.0), model.q_max)


def test_ik_converts_the_target_to_the_configuration_dtype() -> None:
    model = RobotModel.load("kuka_iiwa14", dtype=torch.float64)
    q_goal = model.q_home + 0.2
    target = model.ee_position(q_goal)  # float64
    q32 = model.ik(target, model.q_home.float(), iters=200)
    assert q32.dtype == torch.float32
    assert (model.ee_position(q32.double()) - target).norm() < 1e-3
    # a float32 target with float64 q gives exactly the float64 answer of the upcast target
    t32 = target.float()
    assert torch.equal(model.ik(t32, model.q_home), model.ik(t32.double(), model.q_home))
    with pytest.raises(ShapeError, match="q_init of a floating dtype"):
        model.ik(target, torch.zeros(7, dtype=torch.long))


def test_empty_batches_give_empty_results() -> None:
    model = RobotModel.load("kuka_iiwa14")
    assert model.sphere_centers(torch.zeros(0, 7)).shape == (0, model.num_spheres, 3)
    assert model.sphere_centers(torch.zeros(4, 0, 7)).shape == (4, 0, model.num_spheres, 3)
    assert model.ee_position(torch.zeros(0, 7)).shape == (0, 3)
    assert model.position_jacobian(torch.zeros(0, 7)).shape == (0, 3, 7)
    q = torch.zeros(0, 7, requires_grad=True)
    model.sphere_centers(q).sum().backward()
    assert q.grad is not None and q.grad.shape == (0, 7)


def test_nan_configurations_propagate_through_forward_kinematics() -> None:
    # documented: no NaN check on the optimiser's hot path; other rows are unaffected
    model = RobotModel.load("kuka_iiwa14")
    q = model.q_home.expand(2, -1).clone()
    q[0, 3] = math.nan
    centers = model.sphere_centers(q)
    assert bool(torch.isnan(centers[0]).any())
    assert torch.allclose(centers[1], model.sphere_centers(model.q_home), atol=1e-6)


def test_load_rejects_unusable_devices_and_dtypes() -> None:
    with pytest.raises(ConfigError, match="floating dtypes only"):
        RobotModel.load("kuka_iiwa14", dtype=torch.int64)
    with pytest.raises(ConfigError, match="floating dtypes only"):
        RobotModel.from_cfg(RobotCfg(name="fetch"), dtype=torch.bool)
    with pytest.raises(ConfigError, match="unknown device 'tpu9'"):
        RobotModel.load("kuka_iiwa14", device="tpu9")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="CUDA is not available"):
            RobotModel.load("kuka_iiwa14", device="cuda")
    else:
        with pytest.raises(ConfigError, match="CUDA device"):
            RobotModel.load("kuka_iiwa14", device=f"cuda:{torch.cuda.device_count()}")


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_ik_in_half_precision_solves_in_float32(dtype: torch.dtype) -> None:
    """A half q_init raised NotImplementedError ('lu_cpu' not implemented for 'Half')."""
    model = RobotModel.load("kuka_iiwa14")
    target = model.ee_position(model.q_home + 0.2)
    q = model.ik(target, model.q_home.to(dtype), iters=200)
    assert q.dtype == dtype
    assert torch.equal(q, model.ik(target, model.q_home.to(dtype).float(), iters=200).to(dtype))
    assert (model.ee_position(q.float()) - target).norm() < 5e-3  # joints rounded to dtype
    assert bool(((q >= model.q_min.to(dtype)) & (q <= model.q_max.to(dtype))).all())


@pytest.mark.parametrize("yaw", [math.nan, math.inf, "pi"])
def test_constructor_rejects_a_non_finite_base_yaw(yaw: object) -> None:
    """RobotModel(desc, base_yaw=nan) built a model whose kinematics were all NaN."""
    desc = RobotModel.load("kuka_iiwa14").description
    with pytest.raises(ConfigError, match="expected a finite base_yaw"):
        RobotModel(desc, base_yaw=yaw)  # type: ignore[arg-type]


def test_one_ik_step_is_the_damped_least_squares_step() -> None:
    """One iteration from the middle of the limits towards a point 3 cm off the tool: the
    step ``J^T (J J^T + lambda^2 I)^-1 e``, with J by central differences of the tool point
    and the solve in numpy (lambda = 0.1 m, of the order of J J^T's small eigenvalues, so a
    lambda in place of lambda^2 shows)."""
    model = RobotModel.load("kuka_iiwa14", dtype=torch.float64)
    q0 = 0.5 * (model.q_min + model.q_max) + 0.3
    p0 = model.ee_position(q0).numpy()
    target = p0 + np.array([0.03, -0.02, 0.01])
    h = 1e-6
    jac = np.stack(
        [
            (model.ee_position(q0 + h * e).numpy() - model.ee_position(q0 - h * e).numpy())
            / (2 * h)
            for e in torch.eye(model.num_joints, dtype=torch.float64)
        ],
        axis=1,
    )  # (3, J)
    lam = 0.1
    step = jac.T @ np.linalg.solve(jac @ jac.T + lam**2 * np.eye(3), target - p0)
    got = model.ik(torch.from_numpy(target), q0, iters=1, tol=0.0, damping=lam, max_step=10.0)
    np.testing.assert_allclose(got.numpy(), q0.numpy() + step, rtol=0, atol=1e-8)
