"""Cost terms: the Gaussian ball bound against Monte Carlo and the collision module, gradients
against finite differences, pruning, forecast interpolation, sphere maps."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from planning_fakes import mc_ball_probability

from iplanner_torch.collision.gaussian import secular_multiplier
from iplanner_torch.collision.human_spheres import HumanSphereMap
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.planning import costs as C
from iplanner_torch.prediction.forecast import Forecast


def _cases(n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=gen, dtype=torch.float64) * 0.3
    var = (0.02 + 0.15 * torch.rand(n, 3, generator=gen, dtype=torch.float64)) ** 2
    rad = 0.05 + 0.2 * torch.rand(n, generator=gen, dtype=torch.float64)
    return d, var, rad


def _bisection_lambda(d, var, rad, iters: int = 200):
    lo = torch.zeros_like(rad)
    hi = torch.full_like(rad, 1e12)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        n = (d / (1 + mid[:, None] * var)).norm(dim=-1)
        lo = torch.where(n > rad, mid, lo)
        hi = torch.where(n > rad, hi, mid)
    return 0.5 * (lo + hi)


def test_newton_lambda_matches_bisection() -> None:
    d, var, rad = _cases(300)
    outside = d.norm(dim=-1) > rad
    lam = secular_multiplier(d, var, rad)
    ref = _bisection_lambda(d, var, rad)
    assert torch.allclose(lam[outside], ref[outside], rtol=1e-6)
    assert bool((lam[~outside] == 0).all())


def test_bound_is_never_below_monte_carlo_probability() -> None:
    d, var, rad = _cases(40, seed=1)
    bound, _ = C.gaussian_ball_bound_diag(d, var, rad)
    for i in range(d.shape[0]):
        p = mc_ball_probability(d[i], var[i], float(rad[i]), n=100_000, seed=i)
        se = math.sqrt(max(p * (1 - p), 1e-6) / 100_000)
        assert float(bound[i]) >= p - 4 * se, (i, float(bound[i]), p)
    # the bound is informative: far pairs are tiny, pairs with the mean inside are large
    far, _ = C.gaussian_ball_bound_diag(
        torch.tensor([[1.0, 0.0, 0.0]]), torch.full((1, 3), 0.01), torch.tensor([0.2])
    )
    assert float(far) < 1e-10


def test_bound_matches_collision_module() -> None:
    from iplanner_torch.collision import gaussian

    d, var, rad = _cases(200, seed=2)
    ours, _ = C.gaussian_ball_bound_diag(d, var, rad)
    ref = gaussian.sphere_collision_bound_diag(
        torch.zeros_like(d), 0.5 * rad, d, var, 0.5 * rad, method="min"
    )
    assert torch.allclose(ours, ref, rtol=1e-6, atol=1e-12)


def _fd_check(fn, x: torch.Tensor, eps: float = 1e-6, rtol: float = 1e-4) -> None:
    x = x.clone().requires_grad_(True)
    fn(x).backward()
    num = torch.zeros_like(x)
    flat = x.detach().view(-1)
    for i in range(flat.numel()):
        xp, xm = flat.clone(), flat.clone()
        xp[i] += eps
        xm[i] -= eps
        num.view(-1)[i] = (fn(xp.view_as(x)) - fn(xm.view_as(x))) / (2 * eps)
    assert torch.allclose(x.grad, num, rtol=rtol, atol=1e-7), (x.grad, num)


def test_gradients_of_joint_terms_match_finite_differences() -> None:
    gen = torch.Generator().manual_seed(4)
    q = torch.randn(2, 6, 3, generator=gen, dtype=torch.float64)
    q_min = torch.full((3,), -0.8, dtype=torch.float64)
    v_max = torch.full((3,), 2.0, dtype=torch.float64)
    qd0 = torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64)
    _fd_check(lambda x: C.joint_acc_l2(x, 0.2, qd0).sum(), q)
    _fd_check(lambda x: C.joint_limit_violation(x, q_min, -q_min).sum(), q)
    _fd_check(lambda x: C.joint_vel_limit_violation(x, 0.2, v_max).sum(), q)
    qd0 = torch.tensor([0.5, -2.0, 1.0], dtype=torch.float64)
    _fd_check(lambda x: C.joint_acc_limit_violation(x, 0.2, 3.0, qd0).sum(), q)
    # value: only the part of |acceleration| above the limit counts
    acc = torch.tensor([[[0.0], [0.0], [0.2 * 0.2 * 5.0]]], dtype=torch.float64)  # a = 5 at k=1
    assert float(C.joint_acc_limit_violation(acc, 0.2, 3.0)[0]) == pytest.approx(4.0)
    _fd_check(lambda x: C.goal_distance(x[:, -1], q[0, 0]).sum(), q)


class _Floor:
    """z = 0 floor: signed distance of a sphere is z - r."""

    def clearance(self, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        return centers[..., 2] - radii


def test_static_clearance_gradient_and_value() -> None:
    centers = torch.tensor([[[[0.0, 0.0, 0.01], [0.0, 0.0, 0.5]]]], dtype=torch.float64)
    radii = torch.tensor([0.02, 0.05], dtype=torch.float64)
    cost, clear = C.static_clearance(centers, radii, _Floor(), margin=0.02)
    assert float(cost) == pytest.approx((0.02 - (-0.01)) ** 2)
    assert float(clear[0, 0]) == pytest.approx(-0.01)
    _fd_check(lambda x: C.static_clearance(x, radii, _Floor(), 0.02)[0].sum(), centers)


def _obstacle(dtype=torch.float64) -> C.HumanObstacle:
    gen = torch.Generator().manual_seed(5)
    mean = torch.randn(3, 2, 4, 3, generator=gen, dtype=dtype) * 0.3  # (W_x, A, S_h, 3)
    var = (0.03 + 0.05 * torch.rand(3, 2, 4, 3, generator=gen, dtype=dtype)) ** 2
    radii = torch.tensor([0.05, 0.08, 0.1, 0.06], dtype=dtype)
    return C.HumanObstacle(
        mean=mean, var=var, radii=radii, weights=torch.tensor([0.7, 0.3], dtype=dtype)
    )


def test_human_bound_gradient_matches_finite_differences() -> None:
    human = _obstacle()
    gen = torch.Generator().manual_seed(6)
    centers = torch.randn(2, 3, 5, 3, generator=gen, dtype=torch.float64) * 0.3 + 0.25
    radii = torch.full((5,), 0.04, dtype=torch.float64)
    bound, _ = C.human_collision_bound(centers, radii, human)
    assert bool(((bound > 1e-6) & (bound < 0.9)).any())  # the smooth regime is exercised
    _fd_check(lambda x: C.human_collision_bound(x, radii, human)[0].sum(), centers, rtol=1e-3)
    _fd_check(lambda x: C.human_collision_bound(x, radii, human)[1].sum(), centers, rtol=1e-3)


@pytest.mark.parametrize("exact", [True, False])
def test_human_bound_with_gradient_equals_plain_evaluation(exact: bool) -> None:
    # with autograd only the maximising and the penetrating pairs are re-evaluated: values
    # must equal the no-grad evaluation of every pair, and gradients finite differences
    human = _obstacle()
    gen = torch.Generator().manual_seed(11)
    centers = torch.randn(3, 3, 5, 3, generator=gen, dtype=torch.float64) * 0.3
    centers[0, 1, 2] = human.mean[1, 0, 1]  # one sphere penetrates a human mean sphere
    radii = torch.full((5,), 0.04, dtype=torch.float64)
    with torch.no_grad():
        ref_bound, ref_pen = C.human_collision_bound(centers, radii, human, exact=exact)
    x = centers.clone().requires_grad_(True)
    bound, pen = C.human_collision_bound(x, radii, human, exact=exact)
    assert float(ref_pen[0]) > 0.0
    assert torch.allclose(bound, ref_bound, rtol=1e-12, atol=1e-15)
    assert torch.allclose(pen, ref_pen, rtol=1e-12, atol=1e-15)
    _fd_check(lambda y: C.human_collision_bound(y, radii, human, exact=exact)[1].sum(), centers)
    far = centers.clone()
    far[0, 1, 2] += 0.02  # off the kink of the norm at the mean itself
    _fd_check(
        lambda y: C.human_collision_bound(y, radii, human, exact=exact)[0].sum(), far, rtol=1e-3
    )


def test_isotropic_screen_of_far_pairs_stays_an_upper_bound_in_float32() -> None:
    # the screen clamps the normalised gap at GAP_CLAMP (no subnormal erfc): far pairs must
    # keep a positive bound at least the Gaussian tail of their true gap
    gaps = torch.tensor([0.5, 3.0, 8.0, 11.9, 12.0, 20.0, 40.0, 300.0], dtype=torch.float64)
    sigma, rad = 0.05, 0.1
    c = torch.zeros(len(gaps), 3, dtype=torch.float32)
    mu = torch.zeros(len(gaps), 1, 3, dtype=torch.float32)
    mu[:, 0, 0] = (rad + sigma * gaps).float()
    var = torch.full((len(gaps), 1, 3), sigma**2, dtype=torch.float32)
    inv_s = var.amax(-1).rsqrt()
    radius = torch.full((len(gaps), 1), rad, dtype=torch.float32)
    with torch.no_grad():
        bound, dist = C._pair_bounds(c, mu, var, inv_s, radius, exact=False)
    tail = torch.special.erfc(gaps / math.sqrt(2.0)) / 2
    assert torch.allclose(dist[:, 0].double(), rad + sigma * gaps, rtol=1e-6)
    assert bool((bound[:, 0] > 0).all())
    assert bool((bound[:, 0].double() >= tail * (1 - 1e-4)).all()), (bound, tail)
    floor = math.erfc(C.GAP_CLAMP / math.sqrt(2)) / 2
    assert float(bound[-1, 0]) == pytest.approx(floor, rel=1e-4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_isotropic_bound_is_the_masked_tail_to_the_bit(dtype: torch.dtype) -> None:
    # the bound without a mask, against where(gap > 0, Phi(-gap), 1) (values and gradients)
    # and against the normal tail in float64 (scipy); gaps at and around 0, the clamp, inf, NaN
    from scipy.stats import norm

    gen = torch.Generator().manual_seed(5)
    special = [0.0, -0.0, 1e-30, -1e-30, 1e-7, 11.99, 12.0, 12.5, 50.0, math.inf, -math.inf]
    gaps = torch.cat([torch.randn(2000, generator=gen, dtype=torch.float64) * 4.0,
                      torch.tensor(special + [math.nan], dtype=torch.float64)])  # fmt: skip
    rad = (0.05 + 0.1 * torch.rand(len(gaps), generator=gen, dtype=torch.float64)).to(dtype)
    inv_s = (5.0 + 40.0 * torch.rand(len(gaps), generator=gen, dtype=torch.float64)).to(dtype)
    dist = rad + gaps.to(dtype) / inv_s

    def masked(d: torch.Tensor) -> torch.Tensor:
        gap = (d - rad) * inv_s
        bound = 0.5 * torch.erfc(gap.clamp(max=C.GAP_CLAMP) * (1.0 / math.sqrt(2.0)))
        return torch.where(gap > 0.0, bound, 1.0)

    with torch.no_grad():
        fast = C._isotropic(dist, rad, inv_s)
    assert torch.equal(fast, masked(dist)), (fast - masked(dist)).abs().max()
    d1, d2 = dist.clone().requires_grad_(True), dist.clone().requires_grad_(True)
    got, want = C._isotropic(d1, rad, inv_s), masked(d2)
    assert torch.equal(got.detach(), want.detach())
    (g1,) = torch.autograd.grad(got.sum(), d1)
    (g2,) = torch.autograd.grad(want.sum(), d2)
    assert torch.equal(g1, g2)
    gap = ((dist - rad) * inv_s).double()
    tail = torch.from_numpy(norm.sf(gap.clamp(max=C.GAP_CLAMP).numpy()))
    expect = torch.where(gap > 0.0, tail, torch.ones_like(tail))
    assert torch.allclose(fast.double(), expect, rtol=1e-5 if dtype == torch.float32 else 1e-12)
    assert float(fast[-1]) == 1.0  # a NaN gap: unsafe


def test_secular_residual_in_place_equals_its_differentiable_form() -> None:
    from iplanner_torch.collision import gaussian as G

    gen = torch.Generator().manual_seed(6)
    for dtype in (torch.float32, torch.float64):
        d2 = (torch.randn(3, 500, generator=gen, dtype=torch.float64) * 0.3).square().to(dtype)
        s = ((0.02 + 0.2 * torch.rand(3, 500, generator=gen, dtype=torch.float64)) ** 2).to(dtype)
        R = (0.05 + 0.2 * torch.rand(500, generator=gen, dtype=torch.float64)).to(dtype)
        lam = (10.0 * torch.rand(500, generator=gen, dtype=torch.float64)).to(dtype)
        inputs = [x.clone() for x in (lam, d2, s, R)]
        with torch.no_grad():
            fast = G._secular_residual(*inputs), G._newton_step(*inputs)
        assert all(torch.equal(a, b) for a, b in zip(inputs, (lam, d2, s, R), strict=True))
        lam_g = lam.clone().requires_grad_(True)  # the differentiable (out-of-place) form
        slow = G._secular_residual(lam_g, d2, s, R), G._newton_step(lam_g, d2, s, R)
        assert torch.equal(fast[0][0], slow[0][0]) and torch.equal(fast[0][1], slow[0][1])
        assert torch.equal(fast[1], slow[1])


def test_screen_distance_matches_norm_of_difference() -> None:
    gen = torch.Generator().manual_seed(3)
    a = torch.randn(4, 1, 6, 3, generator=gen, dtype=torch.float64)
    b = torch.randn(1, 5, 6, 3, generator=gen, dtype=torch.float64)
    assert torch.allclose(C._distance3(a, b), (a - b).norm(dim=-1), rtol=1e-12, atol=0.0)


def _brute_force_pairs(
    centers: torch.Tensor, radii: torch.Tensor, human: C.HumanObstacle
) -> torch.Tensor:
    """(B, W_x, S_r, S_h) the mixture bound of every (trajectory, waypoint, robot sphere, human
    sphere) by brute force, in loops, each action by the exact diagonal-Gaussian bound."""
    b_n, w_n, s_r, _ = centers.shape
    s_h = human.radii.shape[0]
    ref = torch.zeros(b_n, w_n, s_r, s_h, dtype=torch.float64)
    for b in range(b_n):
        for w in range(w_n):
            for j in range(s_r):
                for ll in range(s_h):
                    d = human.mean[w, :, ll] - centers[b, w, j]
                    r = (radii[j] + human.radii[ll]).expand(human.weights.shape[0])
                    pb, _ = C.gaussian_ball_bound_diag(d, human.var[w, :, ll], r)
                    ref[b, w, j, ll] = float((pb * human.weights).sum())
    return ref


def _brute_force_bound(
    centers: torch.Tensor, radii: torch.Tensor, human: C.HumanObstacle
) -> torch.Tensor:
    """(B, W_x) the paper's bound by brute force: the largest pair of
    :func:`_brute_force_pairs`."""
    return _brute_force_pairs(centers, radii, human).flatten(2).amax(-1)


def test_human_bound_is_max_over_pairs_of_weighted_sum_and_pruning_is_safe() -> None:
    human = _obstacle()
    gen = torch.Generator().manual_seed(7)
    centers = torch.randn(2, 3, 5, 3, generator=gen, dtype=torch.float64) * 0.5
    radii = torch.full((5,), 0.04, dtype=torch.float64)
    bound, _ = C.human_collision_bound(centers, radii, human)
    ref = _brute_force_bound(centers, radii, human)
    # pairs below EXACT_FROM keep the (larger) isotropic bound
    assert bool((bound >= ref.clamp(max=1.0) - 1e-12).all())
    assert torch.allclose(bound, ref.clamp(max=1.0), atol=C.EXACT_FROM)
    pairs = C.candidate_pairs(centers, radii, human, margin=0.0)
    assert 0 < pairs.shape[0] < 20
    pruned, _ = C.human_collision_bound(centers, radii, human, pairs)
    assert float((bound - pruned).abs().max()) <= math.erfc(5 / math.sqrt(2)) / 2


def test_forecast_interpolation_hits_frames_and_midpoints() -> None:
    n_f, dt = 5, 0.1
    mean = torch.arange(n_f, dtype=torch.float32).view(1, 1, n_f, 1, 1).expand(1, 1, n_f, 1, 3)
    fc = Forecast(
        weights=torch.ones(1, 1),
        mean=mean.clone(),
        var=torch.full((1, 1, n_f, 1, 3), 0.01),
        dt=dt,
        joint_names=("j",),
        action_names=("a",),
    )
    sm = HumanSphereMap(torch.ones(1, 1), torch.tensor([0.1]))
    t0 = 2.0
    times = torch.tensor([t0, t0 + 0.1, t0 + 0.25, t0 + 0.5, t0 + 3.0])
    obs = C.forecast_to_obstacle(fc, times, t0, sm)
    got = obs.mean[:, 0, 0, 0]
    assert torch.allclose(got, torch.tensor([0.0, 0.0, 1.5, 4.0, 4.0]), atol=1e-6)


def test_sphere_map_interpolates_joints() -> None:
    sm = HumanSphereMap.from_segments(JOINT_NAMES)
    assert sm.num_spheres == 22
    gen = torch.Generator().manual_seed(8)
    mean = torch.randn(10, 3, generator=gen)
    var = torch.rand(10, 3, generator=gen)
    m, v = sm.centers_diag(mean, var)
    # first upper-arm sphere: u = 1/6 from left shoulder to left elbow (eq. center_distribution)
    row = 6  # head, neck, 2 upper torso, 2 lower torso -> index 6 is the left shoulder sphere
    i_ls, i_le = JOINT_NAMES.index("left_shoulder"), JOINT_NAMES.index("left_elbow")
    k = row + 2  # after both shoulder spheres
    u = 1 / 6
    assert torch.allclose(m[k], (1 - u) * mean[i_ls] + u * mean[i_le], atol=1e-6)
    assert torch.allclose(v[k], (1 - u) ** 2 * var[i_ls] + u**2 * var[i_le], atol=1e-6)
    # known positions (a batch of frames): the same interpolation, the means of centers_diag
    frames = torch.stack([mean, 2.0 * mean]).double()  # (2, K, 3)
    c = sm.centers(frames)
    assert c.shape == (2, 22, 3) and c.dtype == torch.float64
    assert torch.allclose(c[0, k], (1 - u) * frames[0, i_ls] + u * frames[0, i_le])
    assert torch.allclose(c[1].float(), sm.centers_diag(2.0 * mean, var)[0], atol=1e-6)
    with pytest.raises(ConfigError, match="needs joint 'head'"):
        HumanSphereMap.from_segments(JOINT_NAMES[1:])


def test_cost_weights_validate() -> None:
    with pytest.raises(ConfigError, match="joint_acc_l2"):
        C.CostWeights(joint_acc_l2=-1.0)


def test_dropping_light_actions_keeps_an_upper_bound() -> None:
    """full <= dropped <= full + dropped mass, on random sphere pairs (reference: all actions)."""
    from iplanner_torch.errors import ConfigError
    from iplanner_torch.planning.costs import (
        HumanObstacle,
        drop_light_actions,
        human_collision_bound,
    )

    gen = torch.Generator().manual_seed(5)
    w_x, a, s_h, s_r = 4, 4, 3, 2
    human = HumanObstacle(
        mean=0.3 * torch.randn(w_x, a, s_h, 3, generator=gen, dtype=torch.float64),
        var=0.01 + 0.02 * torch.rand(w_x, a, s_h, 3, generator=gen, dtype=torch.float64),
        radii=torch.full((s_h,), 0.08, dtype=torch.float64),
        weights=torch.tensor([0.0001, 0.9, 0.0004, 0.0995], dtype=torch.float64),
    )
    centers = 0.3 * torch.randn(5, w_x, s_r, 3, generator=gen, dtype=torch.float64)
    radii = torch.full((s_r,), 0.1, dtype=torch.float64)
    full, _ = human_collision_bound(centers, radii, human)
    light = drop_light_actions(human, 5e-4)
    assert light.weights.tolist() == [0.9, 0.0995] and light.residual == pytest.approx(5e-4)
    dropped, _ = human_collision_bound(centers, radii, light)
    assert bool((dropped >= full - 1e-12).all())
    assert bool((dropped <= full + 5e-4 + 1e-12).all())
    assert float(full.max()) > 1e-3  # some pairs are close: the comparison is not vacuous
    assert drop_light_actions(human, 0.0) is human
    with pytest.raises(ConfigError, match="max_mass"):
        drop_light_actions(human, -1.0)


@pytest.mark.parametrize("scale", [0.2, 0.6, 2.0])
@pytest.mark.parametrize("margin", [0.0, 0.15])
def test_candidate_pairs_match_brute_force_distance_list(scale: float, margin: float) -> None:
    gen = torch.Generator().manual_seed(int(10 * scale))
    b, w, s_r, a, s_h = 4, 6, 9, 3, 11
    centers = scale * torch.randn(b, w, s_r, 3, generator=gen)
    radii = 0.02 + 0.08 * torch.rand(s_r, generator=gen)
    human = C.HumanObstacle(
        mean=scale * torch.randn(w, a, s_h, 3, generator=gen),
        var=1e-4 + 2e-3 * torch.rand(w, a, s_h, 3, generator=gen),
        radii=0.03 + 0.07 * torch.rand(s_h, generator=gen),
        weights=torch.full((a,), 1.0 / a),
    )
    # brute force: every (robot, human) pair whose smallest distance over trajectories, times
    # and actions is within reach
    expected = []
    sigma = human.var.amax(dim=(0, 1, 3)).sqrt()
    for r in range(s_r):
        for h in range(s_h):
            gap = (centers[:, :, r, None] - human.mean[None, :, :, h]).norm(dim=-1).min()
            if gap <= radii[r] + human.radii[h] + C.PRUNE_SIGMAS * sigma[h] + margin:
                expected.append((r, h))
    got = [tuple(p) for p in C.candidate_pairs(centers, radii, human, margin).tolist()]
    assert got == expected
    if scale >= 1.0:  # the far case prunes some pairs and keeps some
        assert 0 < len(expected) < s_r * s_h


def test_candidate_pairs_keep_a_pair_of_widely_spread_actions() -> None:
    """Two actions put the human sphere at x = -1 and x = +1 m (std 1 cm), the robot sphere
    sits on the second: the cheap lower bound must take the spread of the actions' means
    into account (without it the pair was pruned and the bound read 0 where the person is
    with probability 0.5). The pruned bound equals the one over all pairs."""
    centers = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64).view(1, 1, 1, 3)
    radii = torch.tensor([0.05], dtype=torch.float64)
    human = C.HumanObstacle(
        mean=torch.tensor([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64).view(
            1, 2, 1, 3
        ),
        var=torch.full((1, 2, 1, 3), 1e-4, dtype=torch.float64),
        radii=torch.tensor([0.05], dtype=torch.float64),
        weights=torch.tensor([0.5, 0.5], dtype=torch.float64),
    )
    pairs = C.candidate_pairs(centers, radii, human, 0.0)
    assert pairs.tolist() == [[0, 0]]
    pruned, _ = C.human_collision_bound(centers, radii, human, pairs)
    everything, _ = C.human_collision_bound(centers, radii, human)
    torch.testing.assert_close(pruned, everything)
    assert float(everything) == pytest.approx(0.5, abs=1e-6)


@pytest.mark.parametrize("value", [True, False])
def test_cost_weights_refuse_bools(value: bool) -> None:
    with pytest.raises(
        ConfigError, match=f"expected weight joint_acc_l2 finite and >= 0, got {value}"
    ):
        C.CostWeights(joint_acc_l2=value)


def _one_sphere_human() -> C.HumanObstacle:
    """One human sphere of radius 0.1 m at the origin, nearly certain (std 1 cm)."""
    return C.HumanObstacle(
        mean=torch.zeros(1, 1, 1, 3),
        var=torch.full((1, 1, 1, 3), 1e-4),
        radii=torch.tensor([0.1]),
        weights=torch.ones(1),
    )


#: three robot spheres at one waypoint: two far away, the third on the human
_THREE_SPHERES = torch.tensor([[[[5.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 0.0, 0.0]]]])


def test_human_bound_refuses_radii_for_fewer_robot_spheres() -> None:
    """Two radii for three spheres used to skip the third, the one inside the person: a bound
    of 1.8e-33 instead of 1."""
    human = _one_sphere_human()
    bound, _ = C.human_collision_bound(_THREE_SPHERES, torch.full((3,), 0.05), human)
    assert bound.tolist() == [[1.0]]
    for dtype in (torch.int64, torch.int32):  # given pairs of either index dtype
        pair = torch.tensor([[2, 0]], dtype=dtype)
        bound, _ = C.human_collision_bound(_THREE_SPHERES, torch.full((3,), 0.05), human, pair)
        assert bound.tolist() == [[1.0]]
    short = torch.full((2,), 0.05)
    with pytest.raises(ShapeError, match=r"expected robot_radii \(3\), got \(2,\)"):
        C.human_collision_bound(_THREE_SPHERES, short, human)
    with pytest.raises(ShapeError, match=r"expected robot_radii \(3\), got \(2,\)"):
        C.candidate_pairs(_THREE_SPHERES, short, human, 0.0)


@pytest.mark.parametrize("margin", [math.nan, -0.1, math.inf])
def test_candidate_pairs_refuse_a_bad_margin(margin: float) -> None:
    """A NaN margin used to keep no pair: a bound of 0 for a sphere inside the person."""
    with pytest.raises(ConfigError, match="expected margin >= 0 and finite"):
        C.candidate_pairs(_THREE_SPHERES, torch.full((3,), 0.05), _one_sphere_human(), margin)


def _forecast_at(value: float = 0.7) -> tuple[Forecast, HumanSphereMap]:
    fc = Forecast(
        weights=torch.ones(1, 1),
        mean=torch.full((1, 1, 3, 1, 3), value),
        var=torch.full((1, 1, 3, 1, 3), 0.04),
        dt=0.1,
        joint_names=("j",),
        action_names=("a",),
    )
    return fc, HumanSphereMap(torch.ones(1, 1), torch.tensor([0.1]))


def test_forecast_to_obstacle_refuses_integer_times() -> None:
    """Integer times used to round the obstacle to integers: mean 0.7 -> 0, radius 0.1 -> 0."""
    fc, spheres = _forecast_at()
    obs = C.forecast_to_obstacle(fc, torch.tensor([1.0, 2.0]), 0.0, spheres)
    assert torch.allclose(obs.mean, torch.full_like(obs.mean, 0.7))
    with pytest.raises(ShapeError, match="expected times of a floating dtype, got torch.int64"):
        C.forecast_to_obstacle(fc, torch.tensor([1, 2]), 0.0, spheres)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"forecast_t0": math.nan}, ConfigError, "expected forecast_t0 a finite time"),
        ({"forecast_t0": "0"}, ConfigError, "expected forecast_t0 a finite time"),
        ({"times": torch.tensor([1.0, math.nan])}, DataError, "times is NaN at index 1"),
        ({"times": torch.zeros(2, 1)}, ShapeError, r"expected times \(W_x\), got \(2, 1\)"),
        ({"index": 1}, ConfigError, r"expected forecast index in \[0, 1\), got 1"),
        ({"index": -1}, ConfigError, r"expected forecast index in \[0, 1\), got -1"),
        ({"index": 0.5}, ConfigError, "expected forecast index an integer"),
        ({"forecast": None}, ShapeError, "expected forecast a Forecast, got NoneType"),
    ],
)
def test_forecast_to_obstacle_refuses_bad_arguments(
    kwargs: dict, error: type[Exception], match: str
) -> None:
    """These used to raise raw IndexError / AttributeError (a NaN time indexed frame -2^63)."""
    fc, spheres = _forecast_at()
    args = {"forecast": fc, "times": torch.tensor([1.0, 2.0]), "forecast_t0": 0.0}
    args.update(kwargs)
    with pytest.raises(error, match=match):
        C.forecast_to_obstacle(spheres=spheres, **args)


def test_forecast_to_obstacle_takes_infinite_times_and_skips_the_nan_test_on_request() -> None:
    fc, spheres = _forecast_at()
    times = torch.tensor([-math.inf, 0.15, math.inf])
    obs = C.forecast_to_obstacle(fc, times, 0.0, spheres)
    fast = C.forecast_to_obstacle(fc, times, 0.0, spheres, validate=False)
    assert torch.equal(obs.mean, fast.mean) and torch.equal(obs.var, fast.var)
    assert torch.allclose(obs.mean, torch.full_like(obs.mean, 0.7))


@pytest.mark.parametrize(
    ("centers", "radii", "match"),
    [
        # W_x = 2 against an obstacle of 1 time
        (torch.zeros(1, 2, 3, 3), torch.full((3,), 0.05), r"with W_x = 1 \(the human"),
        # no batch dimension
        (torch.zeros(1, 3, 3), torch.full((3,), 0.05), r"expected robot_centers \(B, W_x"),
        # float64 robot against a float32 obstacle
        (
            torch.zeros(1, 1, 3, 3, dtype=torch.float64),
            torch.full((3,), 0.05, dtype=torch.float64),
            r"expected robot_centers torch.float32 on cpu \(as the human obstacle\)",
        ),
        (
            torch.zeros(1, 1, 3, 3),
            torch.full((3,), 0.05, dtype=torch.float64),
            r"expected robot_radii torch.float32 on cpu \(as the human obstacle\)",
        ),
    ],
)
def test_human_bound_refuses_mismatched_robot_tensors(
    centers: torch.Tensor, radii: torch.Tensor, match: str
) -> None:
    """These used to raise raw RuntimeErrors or, for a wrong W_x or a missing batch axis,
    return a bound of the wrong shape."""
    with pytest.raises(ShapeError, match=match):
        C.human_collision_bound(centers, radii, _one_sphere_human())
    with pytest.raises(ShapeError, match=match):
        C.candidate_pairs(centers, radii, _one_sphere_human(), 0.0)


def test_candidate_pairs_refuse_an_empty_batch() -> None:
    with pytest.raises(ShapeError, match=r"with B >= 1 and W_x >= 1, got \(0, 1, 3, 3\)"):
        C.candidate_pairs(_THREE_SPHERES[:0], torch.full((3,), 0.05), _one_sphere_human(), 0.0)
    # the bound of no trajectory is still empty, as before
    bound, pen = C.human_collision_bound(
        _THREE_SPHERES[:0], torch.full((3,), 0.05), _one_sphere_human()
    )
    assert bound.shape == (0, 1) and pen.shape == (0,)


@pytest.mark.parametrize(
    ("pairs", "match"),
    [
        (torch.tensor([[5, 0]]), r"sphere indices below \(3, 1\) \(S_r, S_h\)"),
        (torch.tensor([[0, 3]]), r"sphere indices below \(3, 1\) \(S_r, S_h\)"),
        (torch.tensor([[2.0, 0.0]]), "expected pairs int64 or int32 on cpu, got torch.float32"),
        (torch.tensor([[True, False]]), "expected pairs int64 or int32 on cpu, got torch.bool"),
        (torch.tensor([2, 0]), r"expected pairs \(P, 2\), got \(2,\)"),
    ],
)
def test_human_bound_refuses_bad_pairs(pairs: torch.Tensor, match: str) -> None:
    with pytest.raises(ShapeError, match=match):
        C.human_collision_bound(_THREE_SPHERES, torch.full((3,), 0.05), _one_sphere_human(), pairs)


@pytest.mark.parametrize(
    ("field_name", "value", "error", "match"),
    [
        ("var", torch.ones(1, 1, 3), ShapeError, r"expected HumanObstacle.var \(1, 1, 1, 3\)"),
        ("radii", torch.ones(2), ShapeError, r"expected HumanObstacle.radii \(1\)"),
        ("weights", torch.ones(2), ShapeError, r"expected HumanObstacle.weights \(1\)"),
        ("var", torch.ones(1, 1, 1, 3, dtype=torch.float64), ShapeError, "HumanObstacle.var"),
        ("mean", torch.zeros(1, 1, 1, 3, dtype=torch.int64), ShapeError, "floating dtype"),
        ("residual", math.nan, ConfigError, "HumanObstacle.residual >= 0 and finite"),
        ("residual", -0.1, ConfigError, "HumanObstacle.residual >= 0 and finite"),
    ],
)
def test_human_obstacle_checks_its_tensors(
    field_name: str, value: object, error: type[Exception], match: str
) -> None:
    fields = {
        "mean": torch.zeros(1, 1, 1, 3),
        "var": torch.ones(1, 1, 1, 3),
        "radii": torch.ones(1),
        "weights": torch.ones(1),
        field_name: value,
    }
    with pytest.raises(error, match=match):
        C.HumanObstacle(**fields)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: C.joint_acc_l2(torch.zeros(1, 5), 0.1), r"expected q \(B, W, J\), got \(1, 5\)"),
        (
            lambda: C.joint_acc_l2(torch.zeros(1, 5, 2), 0.1, torch.zeros(3)),
            r"expected qd_start \(\.\.\., 2\), got \(3,\)",
        ),
        (
            lambda: C.joint_limit_violation(torch.zeros(1, 5, 2), torch.zeros(3), torch.ones(3)),
            r"expected q_min \(2\), got \(3,\)",
        ),
        (
            lambda: C.joint_vel_limit_violation(torch.zeros(1, 5, 2), 0.1, torch.ones(3)),
            r"expected v_max \(2\), got \(3,\)",
        ),
        (
            lambda: C.joint_acc_limit_violation(torch.zeros(5, 2), 0.1, 1.0),
            r"expected q \(B, W, J\), got \(5, 2\)",
        ),
        (
            lambda: C.goal_distance(torch.zeros(1, 2), torch.zeros(3)),
            r"expected q_goal \(2\), got \(3,\)",
        ),
        (
            lambda: C.goal_distance_ee(torch.zeros(1, 2), torch.zeros(3)),
            r"expected ee \(B, 3\), got \(1, 2\)",
        ),
        # another device: torch's "Tensor on device meta is not on the expected device cpu!"
        (
            lambda: C.joint_limit_violation(
                torch.zeros(1, 5, 2), torch.zeros(2, device="meta"), torch.ones(2)
            ),
            r"expected q_min on cpu \(where q is\), got meta",
        ),
        (
            lambda: C.joint_vel_limit_violation(
                torch.zeros(1, 5, 2), 0.1, torch.ones(2, device="meta")
            ),
            r"expected v_max on cpu \(where q is\), got meta",
        ),
        (
            lambda: C.goal_distance(torch.zeros(1, 2), torch.zeros(2, device="meta")),
            r"expected q_goal on cpu \(where q_last is\), got meta",
        ),
        (
            lambda: C.goal_distance_ee(torch.zeros(1, 3), torch.zeros(3, device="meta")),
            r"expected target on cpu \(where ee is\), got meta",
        ),
    ],
)
def test_cost_terms_refuse_mismatched_joint_axes(call, match: str) -> None:
    """These used to return a 0-d tensor (no batch axis) or raise raw Index/RuntimeErrors."""
    with pytest.raises(ShapeError, match=match):
        call()


def test_static_clearance_refuses_a_non_finite_margin() -> None:
    centers = torch.zeros(1, 2, 1, 3)
    with pytest.raises(ConfigError, match="expected margin a finite number, got nan"):
        C.static_clearance(centers, torch.ones(1), _Floor(), math.nan)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_exact_bound_is_finite_for_near_zero_radii_and_far_tiny_variances(
    dtype: torch.dtype,
) -> None:
    """The acceptance bound with a radius sum of 1e-30 m (raised to RADIUS_FLOOR), and a mean
    1e9 m away with variance 1e-12 m^2 in float32, whose Newton derivative underflowed: NaN
    before. Each agrees with the collision module's bound at the floor radius."""
    from iplanner_torch.collision import gaussian as G

    cases = [((0.3, 0.1, 0.0), 1e-2, 1e-30), ((1e9, 3e8, 0.0), 1e-12, 2e-9)]
    for mean, v, r in cases:
        d = torch.tensor([mean], dtype=dtype)
        var = torch.full((1, 3), v, dtype=dtype)
        bound, m2 = C.gaussian_ball_bound_diag(d, var, torch.tensor([r], dtype=dtype))
        assert torch.isfinite(bound).all() and torch.isfinite(m2).all(), (mean, r)
        ref = G.sphere_collision_bound_diag(
            torch.zeros(3, dtype=dtype), max(r, G.RADIUS_FLOOR), d[0], var[0], 0.0
        )
        assert float(bound) == pytest.approx(float(ref), rel=1e-3, abs=1e-30), (mean, r)


def _spread_scene(
    seed: int, dtype: torch.dtype = torch.float64
) -> tuple[torch.Tensor, torch.Tensor, C.HumanObstacle]:
    """Robot spheres (3, 4, 7, 3) and a person with 5 actions whose spheres lie apart (as the
    reaching predictor's targets do), some near the robot, most not."""
    gen = torch.Generator().manual_seed(seed)
    centers = 0.4 * torch.randn(3, 4, 7, 3, generator=gen, dtype=dtype)
    radii = 0.03 + 0.05 * torch.rand(7, generator=gen, dtype=dtype)
    offsets = 0.5 * torch.randn(1, 5, 1, 3, generator=gen, dtype=dtype)  # one per action
    human = C.HumanObstacle(
        mean=offsets + 0.2 * torch.randn(4, 5, 6, 3, generator=gen, dtype=dtype),
        var=(0.01 + 0.04 * torch.rand(4, 5, 6, 3, generator=gen, dtype=dtype)) ** 2,
        radii=0.03 + 0.06 * torch.rand(6, generator=gen, dtype=dtype),
        weights=torch.tensor([0.4, 0.25, 0.15, 0.12, 0.08], dtype=dtype),
    )
    return centers, radii, human


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("margin", [0.0, 0.15])
def test_candidate_entries_match_brute_force_distance_list(seed: int, margin: float) -> None:
    centers, radii, human = _spread_scene(seed)
    pairs, entries = C.candidate_entries(centers, radii, human, margin)
    assert torch.equal(pairs, C.candidate_pairs(centers, radii, human, margin))
    # brute force: every (waypoint, pair, action) whose smallest distance over trajectories
    # is within reach by that sphere's own largest standard deviation there
    expected = set()
    for p, (r, h) in enumerate(pairs.tolist()):
        for w in range(4):
            for a in range(5):
                dist = (centers[:, w, r] - human.mean[w, a, h]).norm(dim=-1).min()
                s_max = human.var[w, a, h].max().sqrt()
                if dist <= radii[r] + human.radii[h] + C.PRUNE_SIGMAS * s_max + margin:
                    expected.add((w, p, a))
    got = [tuple(e) for e in entries.tolist()]
    assert len(got) == len(set(got)) and set(got) == expected
    assert 0 < len(expected) < pairs.shape[0] * 4 * 5  # some kept, some left out


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("exact", [True, False])
def test_human_bound_on_entries_stays_within_the_pruning_level_of_the_full_bound(
    seed: int, exact: bool
) -> None:
    centers, radii, human = _spread_scene(seed)
    ref = _brute_force_bound(centers, radii, human)
    assert float(ref.max()) > 1e-3  # the comparison is not vacuous
    tail = math.erfc(C.PRUNE_SIGMAS / math.sqrt(2)) / 2
    pairs, entries = C.candidate_entries(centers, radii, human, 0.0)
    full, full_pen = C.human_collision_bound(centers, radii, human, exact=exact)
    bound, pen = C.human_collision_bound(
        centers, radii, human, pairs, exact=exact, entries=entries
    )
    assert bool((bound >= ref - tail - 1e-12).all())  # at most the pruning level below
    assert bool((bound <= full + 1e-12).all())  # never above the bound of every entry
    if exact:
        assert torch.allclose(bound, ref, atol=C.EXACT_FROM + tail)
    assert torch.allclose(pen, full_pen, rtol=1e-12, atol=0.0)  # penetrating entries are kept
    # every entry given: the same values as the dense evaluation of the pairs
    w, p, a = torch.meshgrid(
        torch.arange(4), torch.arange(pairs.shape[0]), torch.arange(5), indexing="ij"
    )
    every = torch.stack([w.flatten(), p.flatten(), a.flatten()], dim=-1)
    dense, _ = C.human_collision_bound(centers, radii, human, pairs, exact=exact)
    all_in, _ = C.human_collision_bound(centers, radii, human, pairs, exact=exact, entries=every)
    assert torch.allclose(all_in, dense, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("exact", [True, False])
def test_human_bound_on_entries_with_gradient_equals_plain_evaluation(exact: bool) -> None:
    # with autograd the maximising pair is evaluated again on its entries alone: the values
    # must equal the no-grad evaluation, and the gradients finite differences
    centers, radii, human = _spread_scene(1)
    pairs, entries = C.candidate_entries(centers, radii, human, 0.15)
    j, ll = (int(x) for x in pairs[0])
    centers[1, 2, j] = human.mean[2, 0, ll] + 0.01  # one robot sphere penetrates a mean sphere

    def bound_of(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return C.human_collision_bound(x, radii, human, pairs, exact=exact, entries=entries)

    with torch.no_grad():
        ref_bound, ref_pen = bound_of(centers)
    assert float(ref_pen[1]) > 0.0 and bool(((ref_bound > 1e-6) & (ref_bound < 0.9)).any())
    x = centers.clone().requires_grad_(True)
    bound, pen = bound_of(x)
    assert torch.allclose(bound, ref_bound, rtol=1e-12, atol=1e-15)
    assert torch.allclose(pen, ref_pen, rtol=1e-12, atol=1e-15)
    _fd_check(lambda y: bound_of(y)[0].sum(), centers, rtol=1e-3)
    _fd_check(lambda y: bound_of(y)[1].sum(), centers, rtol=1e-3)


@pytest.mark.parametrize("exact", [True, False])
def test_human_bound_on_entries_differentiates_the_person_means(exact: bool) -> None:
    # the entries' own arithmetic (coordinate planes) serves every call without autograd; the
    # person's means with a gradient take the autograd path: the same values, and gradients
    # that agree with finite differences
    centers, radii, human = _spread_scene(2)
    pairs, entries = C.candidate_entries(centers, radii, human, 0.15)

    def bound_of(mean: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = C.HumanObstacle(mean=mean, var=human.var, radii=human.radii, weights=human.weights)
        return C.human_collision_bound(centers, radii, h, pairs, exact=exact, entries=entries)

    with torch.no_grad():
        ref_bound, ref_pen = bound_of(human.mean)
    assert bool(((ref_bound > 1e-6) & (ref_bound < 0.9)).any())
    bound, pen = bound_of(human.mean.clone().requires_grad_(True))
    assert bound.requires_grad
    assert torch.allclose(bound, ref_bound, rtol=1e-12, atol=1e-15)
    assert torch.allclose(pen, ref_pen, rtol=1e-12, atol=1e-15)
    _fd_check(lambda m: bound_of(m)[0].sum(), human.mean, rtol=1e-3)


@pytest.mark.parametrize(
    ("pairs", "entries", "match"),
    [
        (None, torch.tensor([[0, 0, 0]]), "expected pairs with the entries"),
        (torch.tensor([[2, 0]]), torch.tensor([[0, 0]]), r"expected entries \(K, 3\)"),
        (torch.tensor([[2, 0]]), torch.tensor([[0, 0, 0]], dtype=torch.int32), "int64"),
        (torch.tensor([[2, 0]]), torch.tensor([[1, 0, 0]]), r"below \(1, 1, 1\) \(W_x, P, A\)"),
        (torch.tensor([[2, 0]]), torch.tensor([[0, 1, 0]]), r"below \(1, 1, 1\) \(W_x, P, A\)"),
        (torch.tensor([[2, 0]]), torch.tensor([[0, 0, 1]]), r"below \(1, 1, 1\) \(W_x, P, A\)"),
        (torch.tensor([[5, 0]]), torch.tensor([[0, 0, 0]]), r"below \(3, 1\) \(S_r, S_h\)"),
    ],
)
def test_human_bound_refuses_bad_entries(
    pairs: torch.Tensor | None, entries: torch.Tensor, match: str
) -> None:
    with pytest.raises(ShapeError, match=match):
        C.human_collision_bound(
            _THREE_SPHERES, torch.full((3,), 0.05), _one_sphere_human(), pairs, entries=entries
        )


def test_human_bound_on_entries_sees_the_sphere_inside_the_person() -> None:
    human = _one_sphere_human()
    pairs, entries = C.candidate_entries(_THREE_SPHERES, torch.full((3,), 0.05), human, 0.0)
    assert pairs.tolist() == [[2, 0]] and entries.tolist() == [[0, 0, 0]]
    bound, pen = C.human_collision_bound(
        _THREE_SPHERES, torch.full((3,), 0.05), human, pairs, entries=entries
    )
    assert bound.tolist() == [[1.0]] and float(pen[0]) == pytest.approx(0.15**2)
    # no entry: the dropped actions' weight alone, as without pairs
    none, _ = C.human_collision_bound(
        _THREE_SPHERES, torch.full((3,), 0.05), human, pairs, entries=entries[:0]
    )
    assert none.tolist() == [[0.0]]


@pytest.mark.parametrize("exact", [True, False])
def test_human_bound_on_entries_leaves_the_same_actions_out_with_a_gradient(exact: bool) -> None:
    # one robot sphere, one human sphere, two actions: the second just beyond the pruning
    # level (5.5 standard deviations: bound 1.9e-8), so its entry is left out
    sigma, rad = 0.02, 0.05
    human = C.HumanObstacle(
        mean=torch.tensor([[[[0.12, 0.0, 0.0]], [[0.0, 2 * rad + 5.5 * sigma, 0.0]]]]).double(),
        var=torch.full((1, 2, 1, 3), sigma**2, dtype=torch.float64),
        radii=torch.tensor([rad], dtype=torch.float64),
        weights=torch.tensor([0.5, 0.5], dtype=torch.float64),
    )
    centers = torch.zeros(1, 1, 1, 3, dtype=torch.float64)
    radii = torch.tensor([rad], dtype=torch.float64)
    pairs, entries = C.candidate_entries(centers, radii, human, 0.0)
    assert entries.tolist() == [[0, 0, 0]]
    full, _ = C.human_collision_bound(centers, radii, human, pairs, exact=exact)
    with torch.no_grad():
        plain, _ = C.human_collision_bound(
            centers, radii, human, pairs, exact=exact, entries=entries
        )
    x = centers.clone().requires_grad_(True)
    bound, _ = C.human_collision_bound(x, radii, human, pairs, exact=exact, entries=entries)
    left_out = 0.5 * math.erfc(5.5 / math.sqrt(2)) / 2
    assert float(full - plain) == pytest.approx(left_out, rel=1e-6)
    assert torch.allclose(bound, plain, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_exact_bound_on_entries_refines_where_the_maximum_can_change_with_the_same_result(
    seed: int,
) -> None:
    # without a gradient, only the isotropic maximiser and the pairs whose isotropic mixture
    # exceeds its exact one are refined: the maximum must be that of refining every entry
    centers, radii, human = _spread_scene(seed)
    human.var[..., 0] *= 9.0  # anisotropic: the isotropic screen is loose along the other axes
    pairs, entries = C.candidate_entries(centers, radii, human, 0.0)
    with torch.no_grad():
        bound, _ = C.human_collision_bound(centers, radii, human, pairs, entries=entries)
    # every entry refined: the dense evaluation of the same entries, pair by pair
    mean_p, var_p, inv_s_p, rad_p = human.pair_tensors(pairs, radii)
    kept = torch.zeros(mean_p.shape[:3], dtype=torch.float64)
    kept[entries[:, 0], entries[:, 1], entries[:, 2]] = 1.0
    c = centers[:, :, pairs[:, 0]]
    mixes = {}
    for exact in (False, True):
        b, _ = C._pair_bounds(c, mean_p.unsqueeze(0), var_p, inv_s_p, rad_p, exact)
        mixes[exact] = (b * kept * human.weights).sum(-1)  # (B, W_x, P)
    want = mixes[True].amax(-1)
    assert torch.allclose(bound, want, rtol=1e-12, atol=1e-15)
    # not vacuous: somewhere the isotropic maximiser's exact mixture is below the maximum, and
    # the true maximiser's isotropic mixture above it (refining the first pair alone is wrong)
    at_iso_top = mixes[True].gather(-1, mixes[False].argmax(-1, keepdim=True))[..., 0]
    at_top_iso = mixes[False].gather(-1, mixes[True].argmax(-1, keepdim=True))[..., 0]
    assert bool(((at_iso_top < want * (1 - 1e-6)) & (at_top_iso > want * (1 + 1e-6))).any())


def test_any_over_leading_dimensions_matches_torch_any() -> None:
    gen = torch.Generator().manual_seed(3)
    for shape, n in [
        ((8, 50), 1),
        ((4, 6, 7, 2), 2),
        ((3, 5), 2),
        ((1, 9), 1),
        ((0, 4), 1),
        ((3, 0), 1),
    ]:
        mask = torch.rand(shape, generator=gen) < 0.1
        assert torch.equal(C._any_leading(mask, n), mask.flatten(0, n - 1).any(0))


def test_joint_velocity_limit_counts_both_directions() -> None:
    """q = [0, -1, -1] at dt 0.1: -10 rad/s against a limit of 1, (10 - 1)^2 = 81; moving
    the other way costs the same. Only the positive direction was penalised by a mutant."""
    v_max = torch.ones(1)
    down = torch.tensor([0.0, -1.0, -1.0]).view(1, 3, 1)
    assert float(C.joint_vel_limit_violation(down, 0.1, v_max)) == pytest.approx(81.0)
    assert float(C.joint_vel_limit_violation(-down, 0.1, v_max)) == pytest.approx(81.0)


def _brute_force_sum(
    centers: torch.Tensor, radii: torch.Tensor, human: C.HumanObstacle
) -> torch.Tensor:
    """(B, W_x) Boole's bound by brute force: the pairs of :func:`_brute_force_pairs` summed,
    plus the left-out actions' weight."""
    return _brute_force_pairs(centers, radii, human).flatten(2).sum(-1) + human.residual


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_summed_bound_is_booles_bound_over_the_pairs(seed: int) -> None:
    """reduce="sum" against loops over every pair: exact where nothing is pruned, and with
    pruned pairs or entries never below it and at most the pruning allowance above."""
    centers, radii, human = _spread_scene(seed)
    human = C.HumanObstacle(  # 1 % of the weight left out: the kept actions hold 99 %
        mean=human.mean,
        var=human.var,
        radii=human.radii,
        weights=0.99 * human.weights,
        residual=0.01,
    )
    ref = _brute_force_sum(centers, radii, human)
    top = _brute_force_bound(centers, radii, human) + human.residual
    assert bool((ref > top + 1e-3).any())  # the sum is not the maximum here
    every, pen = C.human_collision_bound(centers, radii, human, reduce="sum")
    # pairs below EXACT_FROM keep the (larger) isotropic bound: at most that each above
    n_pairs = radii.shape[0] * human.radii.shape[0]
    assert bool((every >= ref.clamp(max=1.0) - 1e-12).all())
    assert torch.allclose(every, ref.clamp(max=1.0), atol=n_pairs * C.EXACT_FROM)
    _, max_pen = C.human_collision_bound(centers, radii, human)
    assert torch.equal(pen, max_pen)  # the penetration cost does not depend on the reduction
    allowance = n_pairs * C.PRUNED_PAIR_BOUND
    assert C.PRUNED_PAIR_BOUND >= math.erfc(C.PRUNE_SIGMAS / math.sqrt(2)) / 2
    pairs, entries = C.candidate_entries(centers, radii, human, 0.0)
    w_n, a_n = human.mean.shape[:2]
    assert entries.shape[0] < n_pairs * w_n * a_n  # some pairs or entries are left out
    for kept in (
        C.human_collision_bound(centers, radii, human, pairs, reduce="sum")[0],
        C.human_collision_bound(centers, radii, human, pairs, entries=entries, reduce="sum")[0],
    ):
        assert bool((kept >= ref.clamp(max=1.0) - 1e-12).all())
        assert bool((kept <= (every + allowance).clamp(max=1.0) + 1e-12).all())
    # "max" is unchanged by the option's presence
    assert torch.equal(
        C.human_collision_bound(centers, radii, human, reduce="max")[0],
        C.human_collision_bound(centers, radii, human)[0],
    )
    with pytest.raises(ConfigError, match="expected reduce 'max' or 'sum', got 'mean'"):
        C.human_collision_bound(centers, radii, human, reduce="mean")


def test_the_summed_bound_covers_touching_any_sphere_where_the_maximum_does_not() -> None:
    """A robot sphere among four person spheres, each touched with probability about 0.05:
    the paper's maximum (0.091) bounds each pair but not the chance that one of them
    touches, 0.186 by Monte Carlo (the spheres drawn independently); Boole's sum (0.365)
    does."""
    dtype = torch.float64
    around = torch.tensor([[0.12, 0, 0], [-0.12, 0, 0], [0, 0.12, 0], [0, -0.12, 0]], dtype=dtype)
    human = C.HumanObstacle(
        mean=around.view(1, 1, 4, 3),
        var=torch.full((1, 1, 4, 3), 0.03**2, dtype=dtype),
        radii=torch.full((4,), 0.03, dtype=dtype),
        weights=torch.ones(1, dtype=dtype),
    )
    centers = torch.zeros(1, 1, 1, 3, dtype=dtype)
    radii = torch.tensor([0.05], dtype=dtype)
    gen = torch.Generator().manual_seed(0)
    n = 200_000
    x = around + 0.03 * torch.randn(n, 4, 3, generator=gen, dtype=dtype)
    p_any = float((x.norm(dim=-1) <= 0.08).any(-1).double().mean())
    se = math.sqrt(p_any * (1 - p_any) / n)
    top, _ = C.human_collision_bound(centers, radii, human)
    total, _ = C.human_collision_bound(centers, radii, human, reduce="sum")
    assert float(top) < p_any - 10 * se  # the maximum is below the probability of touching
    assert float(total) >= p_any - 4 * se  # Boole's bound is not
    assert float(total) == pytest.approx(min(4 * float(top), 1.0), rel=1e-12)  # by symmetry


@pytest.mark.parametrize("with_entries", [False, True])
@pytest.mark.parametrize("exact", [True, False])
def test_the_summed_bound_with_gradient_equals_plain_evaluation(
    exact: bool, with_entries: bool
) -> None:
    """With autograd every evaluated pair passes its gradient (a sum depends on all): the
    values equal the evaluation without autograd, the gradients finite differences."""
    centers, radii, human = _spread_scene(1)
    pairs, entries = C.candidate_entries(centers, radii, human, 0.15)
    j, ll = (int(x) for x in pairs[0])
    centers[1, 2, j] = human.mean[2, 0, ll] + 0.01  # one robot sphere penetrates a mean sphere

    def bound_of(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return C.human_collision_bound(
            x, radii, human, pairs, exact=exact, entries=entries if with_entries else None,
            reduce="sum",
        )  # fmt: skip

    with torch.no_grad():
        ref_bound, ref_pen = bound_of(centers)
    assert bool(((ref_bound > 1e-6) & (ref_bound < 0.9)).any())
    x = centers.clone().requires_grad_(True)
    bound, pen = bound_of(x)
    assert torch.allclose(bound, ref_bound, rtol=1e-12, atol=1e-15)
    assert torch.allclose(pen, ref_pen, rtol=1e-12, atol=1e-15)
    _fd_check(lambda y: bound_of(y)[0].sum(), centers, rtol=1e-3)
    # more than one pair of a waypoint gets a gradient (the maximum passes it to one)
    x.grad = None
    bound[1].sum().backward()
    moved = (x.grad[1].abs().sum(-1) > 0).sum(-1)  # (W_x,) robot spheres with a gradient
    assert int(moved.max()) >= 2


@pytest.mark.parametrize(
    "change",
    [
        {"weights": torch.zeros(2, dtype=torch.float64)},  # was 0 everywhere: "no person"
        {"weights": torch.tensor([0.4, 0.1], dtype=torch.float64)},  # sums to 0.5
        {"weights": torch.tensor([1.2, -0.2], dtype=torch.float64)},
        {"radii": torch.tensor([0.05, -0.08, 0.1, 0.06], dtype=torch.float64)},
        {"var": None},  # one negative variance: was NaN
    ],
    ids=["zero-weights", "half-weights", "negative-weight", "negative-radius", "negative-var"],
)
def test_an_obstacle_that_cannot_make_a_probability_is_unsafe_everywhere(change: dict) -> None:
    """The public bound on values no Forecast would give: 1 at every waypoint (unsafe),
    never 0 (a person who is not there) nor NaN; a trusted obstacle's bound is unchanged."""
    human = _obstacle()
    gen = torch.Generator().manual_seed(6)
    centers = torch.randn(2, 3, 5, 3, generator=gen, dtype=torch.float64) * 0.3 + 0.25
    radii = torch.full((5,), 0.04, dtype=torch.float64)
    good, _ = C.human_collision_bound(centers, radii, human)
    assert bool(human.trusted()) and bool((good < 1).any())
    if change.get("var", 0) is None:
        var = human.var.clone()
        var[0, 0, 0, 0] = -1e-4
        change = {"var": var}
    bad = replace(human, **change)
    assert not bool(bad.trusted())
    bound, _ = C.human_collision_bound(centers, radii, bad)
    assert torch.equal(bound, torch.ones_like(bound))
    lost = replace(human, weights=0.99 * human.weights, residual=0.01)  # 1 % left out: fine
    assert bool(lost.trusted())
