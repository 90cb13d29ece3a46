"""Human sphere centres: the interpolated Gaussian against a Monte Carlo of the joints."""

from __future__ import annotations

import math

import pytest
import torch

from iplanner_torch.collision.human_spheres import HumanSphereModel
from iplanner_torch.data.skeleton import JOINT_NAMES, SEGMENTS, Segment
from iplanner_torch.errors import ConfigError, DataError, ShapeError

F64 = torch.float64


def test_sphere_layout() -> None:
    model = HumanSphereModel(JOINT_NAMES, scale=1.2)
    assert model.num_spheres == sum(s.n_spheres for s in SEGMENTS)
    assert model.radii.shape == (model.num_spheres,)
    assert abs(float(model.radii[0]) - 0.11 * 1.2) < 1e-6
    u = dict(zip(model.names, model.fractions.tolist()))
    assert u["left_forearm_0"] == pytest.approx(1 / 3) and u["left_forearm_2"] == 1.0
    assert u["neck_0"] == 0.5 and u["head_0"] == 1.0


def test_untracked_segments_are_skipped() -> None:
    joints = ("neck", "left_shoulder", "left_elbow", "left_hand")
    model = HumanSphereModel(joints)
    assert all(n.startswith(("left_", "left")) for n in model.names)
    assert model.num_spheres == 1 + 3 + 3 + 1


def test_centres_match_monte_carlo() -> None:
    gen = torch.Generator().manual_seed(0)
    model = HumanSphereModel(JOINT_NAMES)
    K = len(JOINT_NAMES)
    mean = torch.randn(K, 3, generator=gen, dtype=F64)
    A = torch.randn(K, 3, 3, generator=gen, dtype=F64) * 0.05
    cov = A @ A.transpose(-1, -2) + 1e-4 * torch.eye(3, dtype=F64)
    m, c = model.centers(mean, cov)
    n = 200_000
    L = torch.linalg.cholesky(cov)
    z = mean + torch.einsum("kij,nkj->nki", L, torch.randn(n, K, 3, generator=gen, dtype=F64))
    # Interpolate sampled joints explicitly, sphere by sphere.
    idx = {name: i for i, name in enumerate(JOINT_NAMES)}
    samples = []
    for seg in SEGMENTS:
        us = (
            [1.0] * seg.n_spheres
            if seg.joint_a == seg.joint_b
            else [0.5]
            if seg.n_spheres == 1
            else [(i + 1) / seg.n_spheres for i in range(seg.n_spheres)]
        )
        for u in us:
            samples.append((1 - u) * z[:, idx[seg.joint_a]] + u * z[:, idx[seg.joint_b]])
    x = torch.stack(samples, 1)  # (n, S_h, 3)
    torch.testing.assert_close(m, x.mean(0), atol=4e-3, rtol=0)
    xc = x - x.mean(0)
    emp = torch.einsum("nsi,nsj->sij", xc, xc) / (n - 1)
    torch.testing.assert_close(c, emp, atol=3e-4, rtol=0.02)


def test_diag_equals_full_with_diagonal_covariance() -> None:
    gen = torch.Generator().manual_seed(1)
    model = HumanSphereModel(JOINT_NAMES)
    mean = torch.randn(2, 4, len(JOINT_NAMES), 3, generator=gen)
    var = torch.rand(2, 4, len(JOINT_NAMES), 3, generator=gen) * 0.01
    m1, v1 = model.centers_diag(mean, var)
    m2, c2 = model.centers(mean, torch.diag_embed(var))
    torch.testing.assert_close(m1, m2)
    torch.testing.assert_close(torch.diag_embed(v1), c2)


def test_errors() -> None:
    with pytest.raises(ConfigError, match="expected scale > 0"):
        HumanSphereModel(JOINT_NAMES, scale=0.0)
    with pytest.raises(ConfigError, match="no segment"):
        HumanSphereModel(("head_top",))
    model = HumanSphereModel(JOINT_NAMES)
    with pytest.raises(ShapeError, match="expected mean"):
        model.centers_diag(torch.zeros(3, 3), torch.zeros(3, 3))


@pytest.mark.parametrize("bad", [math.nan, math.inf])
@pytest.mark.parametrize("name", ["mean", "cov", "var"])
def test_non_finite_input_raises_data_error(name: str, bad: float) -> None:
    model = HumanSphereModel(JOINT_NAMES)
    K = len(JOINT_NAMES)
    args = {
        "mean": torch.zeros(2, K, 3, dtype=F64),
        "cov": torch.eye(3, dtype=F64).expand(2, K, 3, 3).clone() * 0.01,
        "var": torch.full((2, K, 3), 0.01, dtype=F64),
    }
    args[name][1, 0, 0] = bad
    with pytest.raises(DataError, match=f"expected finite {name}, got"):
        if name in ("mean", "cov"):
            model.centers(args["mean"], args["cov"])
        else:
            model.centers_diag(args["mean"], args["var"])
    if name == "mean":
        with pytest.raises(DataError, match="expected finite mean, got"):
            model.centers_diag(args["mean"], args["var"])


def test_bad_dtypes_ranges_and_config() -> None:
    model = HumanSphereModel(JOINT_NAMES)
    K = len(JOINT_NAMES)
    mean, var = torch.zeros(K, 3), torch.full((K, 3), 0.01)
    with pytest.raises(DataError, match="expected var >= 0"):
        model.centers_diag(mean, -var)
    with pytest.raises(ShapeError, match="expected var torch.float32 on cpu \\(as mean\\)"):
        model.centers_diag(mean, var.double())
    with pytest.raises(ShapeError, match="expected mean of a floating dtype"):
        # integer means used to truncate the fractions u to 0 silently
        model.centers_diag(mean.long(), var.long())
    with pytest.raises(ShapeError, match="expected cov"):
        model.centers(mean, var)
    with pytest.raises(ConfigError, match="expected scale > 0 and finite"):
        HumanSphereModel(JOINT_NAMES, scale=math.inf)
    seg = Segment(name="head", joint_a="head", joint_b="head", radius=-0.1, n_spheres=1)
    with pytest.raises(ConfigError, match="expected radius > 0 and finite in segment 'head'"):
        HumanSphereModel(JOINT_NAMES, segments=(seg,))
