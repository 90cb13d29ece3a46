"""Human sphere centres: the interpolated Gaussian against a Monte Carlo of the joints."""

from __future__ import annotations

import pytest
import torch

from iplanner_torch.collision.human_spheres import HumanSphereModel
from iplanner_torch.data.skeleton import JOINT_NAMES, SEGMENTS
from iplanner_torch.errors import ConfigError, ShapeError

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
