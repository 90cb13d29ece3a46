"""Features, imputation, progress bitmasks, next actions, window counts and splits."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.reaching import ReachingCfg, reaching_demonstrations
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.data.windows import (
    DEFAULT_SPLIT,
    WindowCfg,
    build_windows,
    check_split_fractions,
    compute_features,
    impute_nan,
    next_action_labels,
    progress_bitmask,
    split_by_demonstration,
)
from iplanner_torch.errors import ConfigError, DataError, ShapeError

FPS = 15.0


def _poly(t: np.ndarray, degree: int):
    """A polynomial trajectory per joint-coordinate and its analytic derivatives."""
    rng = np.random.default_rng(degree)
    c = rng.normal(size=(degree + 1, 4, 3))
    x = sum(c[i] * t[:, None, None] ** i for i in range(degree + 1))
    v = sum(i * c[i] * t[:, None, None] ** (i - 1) for i in range(1, degree + 1))
    a = sum(i * (i - 1) * c[i] * t[:, None, None] ** (i - 2) for i in range(2, degree + 1))
    return x, v, a


def test_features_layout_and_exact_on_quadratic():
    t = np.arange(15) / FPS
    x, v, a = _poly(t, 2)
    f = compute_features(torch.tensor(x, dtype=torch.float64), FPS)
    assert f.shape == (15, 36) and f.dtype == torch.float64
    np.testing.assert_allclose(f[:, :12].numpy(), x.reshape(15, 12), atol=1e-12)
    np.testing.assert_allclose(f[:, 12:24].numpy(), v.reshape(15, 12), atol=1e-9)
    np.testing.assert_allclose(f[:, 24:].numpy(), np.broadcast_to(a, x.shape).reshape(15, 12),
                               atol=1e-7)  # fmt: skip


def test_features_match_cubic_derivatives_to_second_order():
    t = np.arange(30) / FPS
    x, v, a = _poly(t, 3)
    f = compute_features(torch.tensor(x), FPS).numpy()
    c3 = np.abs(np.random.default_rng(3).normal(size=(4, 4, 3))[3]).max()
    dt = 1 / FPS
    # central differences of a cubic are off by c3 dt^2 (velocity), edges by 2 c3 dt^2
    assert np.abs(f[:, 12:24] - v.reshape(30, 12)).max() <= 2.5 * c3 * dt**2
    assert np.abs(f[2:-2, 24:] - a.reshape(30, 12)[2:-2]).max() <= 1e-6
    # a coarser grid has a larger error (the test can fail)
    x2, v2, _ = _poly(np.arange(30) / 3.0, 3)
    f2 = compute_features(torch.tensor(x2), 3.0).numpy()
    assert np.abs(f2[:, 12:24] - v2.reshape(30, 12)).max() > 2.5 * c3 * dt**2


def test_features_nan_free_with_interpolated_gaps():
    t = np.arange(20) / FPS
    x, _, _ = _poly(t, 1)  # linear: interpolation over a gap is exact
    xn = x.copy()
    xn[5:8, 1] = np.nan
    xn[0:2, 2] = np.nan  # leading gap: held from the first observation
    xn[-3:, 3, 0] = np.nan  # one coordinate lost -> the joint counts as lost
    f = compute_features(torch.tensor(xn), FPS)
    assert not torch.isnan(f).any()
    pos = f[:, :12].reshape(20, 4, 3).numpy()
    np.testing.assert_allclose(pos[5:8, 1], x[5:8, 1], atol=1e-12)
    np.testing.assert_allclose(pos[0:2, 2], np.broadcast_to(x[2, 2], (2, 3)), atol=1e-12)
    np.testing.assert_allclose(pos[-3:, 3], np.broadcast_to(x[-4, 3], (3, 3)), atol=1e-12)


def test_batched_features_equal_single_calls():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(5, 15, 10, 3)).astype(np.float32)
    x[1, 3:6, 4] = np.nan
    x[3, 14, 9] = np.nan
    f = compute_features(torch.tensor(x), FPS)
    for b in range(5):
        torch.testing.assert_close(f[b], compute_features(torch.tensor(x[b]), FPS))


def test_joint_lost_in_whole_window():
    x = np.random.default_rng(0).normal(size=(15, 10, 3))
    x[:, JOINT_NAMES.index("left_hand")] = np.nan
    with pytest.raises(DataError, match="lost \\(NaN\\) in every frame"):
        compute_features(torch.tensor(x), FPS)
    out = impute_nan(torch.tensor(x), JOINT_NAMES).numpy()
    np.testing.assert_array_equal(out[:, 6], x[:, 5])  # from the left elbow
    alone = np.full((15, 1, 3), np.nan)
    with pytest.raises(DataError, match="no other joint is observed"):
        impute_nan(torch.tensor(alone), ["right_hand"])
    # a subset with no connected joint: the lost torso takes an observed hand's trajectory
    subset = np.random.default_rng(1).normal(size=(15, 3, 3))
    subset[:, 0] = np.nan
    out = impute_nan(torch.tensor(subset), ["torso", "left_hand", "right_hand"]).numpy()
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out[:, 1:], subset[:, 1:])


def test_windows_with_the_whole_body_lost_are_left_out_with_a_warning():
    """A demonstration whose every joint is lost for longer than a window: those windows are
    dropped (with a DataWarning naming it), the others kept, their targets interpolated."""
    from iplanner_torch.errors import DataWarning

    rc = ReachingCfg(n_targets=2, reaches_per_target=2)
    demos = [d for r in range(2) for d in reaching_demonstrations(rc, 0, r)]
    cfg = WindowCfg(n_prev=5, n_future=4, stride=1)
    full = build_windows(demos, cfg)
    blind = demos[0].positions.copy()
    blind[30:45] = np.nan  # 15 frames, every joint
    demos[0] = Demonstration(
        positions=blind, labels=demos[0].labels, fps=demos[0].fps,
        joint_names=demos[0].joint_names, action_names=demos[0].action_names,
        name=demos[0].name,
    )  # fmt: skip
    with pytest.warns(DataWarning, match=rf"{demos[0].name}.*11 window\(s\) in which no joint"):
        w = build_windows(demos, cfg)
    assert len(w) == len(full) - 11  # windows ending at frames 34..44 see nothing
    assert torch.isfinite(w.f_prev).all() and torch.isfinite(w.xi_next).all()


def test_feature_errors():
    with pytest.raises(ShapeError, match=r"expected positions \(..., T, K, 3\)"):
        compute_features(torch.zeros(15, 10, 2), FPS)
    with pytest.raises(ShapeError, match="T >= 3"):
        compute_features(torch.zeros(2, 10, 3), FPS)
    with pytest.raises(ConfigError, match="must start with 'position'"):
        compute_features(torch.zeros(15, 10, 3), FPS, ("velocity",))


def test_progress_bitmask_brute_force():
    rng = np.random.default_rng(1)
    labels = rng.integers(-1, 5, size=60)
    labels = np.repeat(labels, rng.integers(1, 4, size=60))
    got = progress_bitmask(labels, [1, 2, 4]).numpy()

    def ends(s: int) -> bool:  # does the action of frame s end at frame s + 1?
        if labels[s + 1] == labels[s]:
            return False
        after = [c for c in labels[s + 1 :] if c >= 0]
        return not after or after[0] != labels[s]  # a gap inside the action does not end it

    for t in range(len(labels)):
        want = 0
        for a in (1, 2, 4):
            if any(labels[s] == a and ends(s) for s in range(t)):
                want |= 1 << a
        assert got[t] == want, t
    assert (labels == -1).sum() > 10


def test_impute_nan_checks_its_input() -> None:
    """(T, 3) with a NaN failed with an IndexError; integer positions were taken."""
    x = torch.zeros(40, 3)
    x[3, 0] = float("nan")
    with pytest.raises(ShapeError, match=r"expected positions \(\.\.\., T, K, 3\), got \(40, 3\)"):
        impute_nan(x)
    with pytest.raises(
        ShapeError, match=r"expected positions \(\.\.\., T, K, 3\), got \(10, 4, 4\)"
    ):
        impute_nan(torch.full((10, 4, 4), float("nan")))
    with pytest.raises(ShapeError, match="floating dtype, got torch.int64"):
        impute_nan(torch.zeros(10, 2, 3, dtype=torch.long))
    with pytest.raises(ShapeError, match="expected 2 joint_names"):
        impute_nan(torch.zeros(10, 2, 3), ["a"])


def test_progress_bitmask_refuses_labels_that_are_not_action_indices() -> None:
    """NaN, 1.5 and -5 were taken without a word (NaN cut to a large negative integer)."""
    for bad in ([0.0, float("nan"), 1.0], np.array([0.0, 1.5]), [True, False]):
        with pytest.raises(ShapeError, match="expected labels \\(T,\\) of an integer dtype"):
            progress_bitmask(bad)
    with pytest.raises(DataError, match="frame 2 has label -5; expected an action index >= 0"):
        progress_bitmask(np.array([0, -1, -5, 1]))
    assert progress_bitmask(np.array([0, 0, -1, 1], dtype=np.int32)).tolist() == [0, 0, 1, 1]


@pytest.mark.parametrize(
    ("labels", "want"),
    [
        ([1, 1, -1, -1, 1, 2, 2], [0, 0, 0, 0, 0, 2, 2]),  # a gap inside action 1
        ([1, 1, -1, -1, 2, 2], [0, 0, 2, 2, 2, 2]),  # 1 stopped where the gap starts
        ([1, 1, -1, -1], [0, 0, 2, 2]),  # nothing follows the gap
        ([-1, -1, 1], [0, 0, 0]),
        ([-1, -1], [0, 0]),
    ],
)
def test_progress_reads_through_unlabelled_gaps(labels, want) -> None:
    got = progress_bitmask(np.array(labels), [1, 2]).tolist()
    assert got == want


def test_next_action_brute_force():
    labels = np.array([0, 0, 3, 3, -1, 3, 5, 5, -1, -1, 0, 2, 2])
    got = next_action_labels(labels)
    for s, c in enumerate(labels):
        later = [a for a in labels[s + 1 :] if a != c and a >= 0]
        # the current segment ends at the first different label
        end = next((u for u in range(s + 1, len(labels)) if labels[u] != c), len(labels))
        want = next((a for a in labels[end:] if a != c and a >= 0), -1)
        assert got[s] == want, (s, got[s], want, later)


@pytest.fixture(scope="module")
def reach_demos():
    cfg = ReachingCfg(n_targets=4, reaches_per_target=6)
    return [d for t in range(4) for r in range(6) for d in reaching_demonstrations(cfg, t, r)]


@pytest.mark.parametrize("stride", [1, 3])
def test_window_count_formula(reach_demos, stride):
    cfg = WindowCfg(n_prev=10, n_future=8, stride=stride)
    ws = build_windows(reach_demos, cfg)
    want = sum((d.num_frames - 10 - 8) // stride + 1 for d in reach_demos)
    assert len(ws) == want
    assert ws.f_prev.shape == (want, 10, 90) and ws.xi_next.shape == (want, 8, 10, 3)
    assert not torch.isnan(ws.f_prev).any()


def test_window_contents(reach_demos):
    cfg = WindowCfg(n_prev=10, n_future=8)
    ws = build_windows(reach_demos, cfg)
    i = 37
    d = reach_demos[int(ws.demo_index[i])]
    s = int(ws.frame_index[i])
    np.testing.assert_array_equal(ws.xi_next[i].numpy(), d.clean_positions[s + 1 : s + 9])
    torch.testing.assert_close(ws.pose_now[i], ws.f_prev[i, -1, :30].reshape(10, 3))
    assert int(ws.current[i]) == d.labels[s]
    assert int(ws.next_action[i]) == next_action_labels(d.labels)[s]
    torch.testing.assert_close(
        ws.f_prev[i], compute_features(torch.tensor(d.positions[s - 9 : s + 1]), d.fps)
    )
    # progress: reach_t done once the return started; idle/return never count
    t = d.metadata["target"]
    done = ws.progress[ws.demo_index == ws.demo_index[i]]
    cur = ws.current[ws.demo_index == ws.demo_index[i]]
    assert set(done[cur == 5].tolist()) == {1 << (1 + t)}
    assert set(done[cur == 1 + t].tolist()) == {0}
    sub = ws.subset(torch.tensor([0, 5]))
    assert len(sub) == 2 and sub.f_prev.shape[1:] == ws.f_prev.shape[1:]


def test_unlabelled_frames_skipped_and_joint_selection():
    d = Demonstration(
        positions=np.random.default_rng(0).normal(size=(30, 10, 3)),
        labels=np.r_[np.full(15, -1), np.zeros(15)].astype(int),
        fps=FPS,
        joint_names=JOINT_NAMES,
        action_names=("idle",),
    )
    ws = build_windows([d], WindowCfg(n_prev=5, n_future=3, joints=("right_hand",)))
    assert (ws.frame_index >= 15).all() and len(ws) == 30 - 3 - 15
    assert ws.xi_next.shape[2] == 1 and ws.f_prev.shape[2] == 9
    with pytest.raises(DataError, match=r"has no joint\(s\) \['tail'\] of the selection \['tail', "
                       r"'right_hand'\] \(it has \['head'"):  # fmt: skip
        build_windows([d], WindowCfg(joints=("tail", "right_hand")))


def test_a_demonstration_with_nothing_observed_is_named():
    d = Demonstration(
        positions=np.full((30, 10, 3), np.nan),
        labels=np.zeros(30, dtype=int),
        fps=FPS,
        joint_names=JOINT_NAMES,
        action_names=("idle",),
        name="trial_7",
    )
    with pytest.raises(DataError, match="demonstration 'trial_7': .*every frame"):
        build_windows([d], WindowCfg(n_prev=5, n_future=3))


def test_split_no_leakage_and_stratified(reach_demos):
    tr, va, te = split_by_demonstration(reach_demos, (0.5, 0.25, 0.25), seed=3)
    names = [{d.name for d in s} for s in (tr, va, te)]
    assert not (names[0] & names[1] or names[0] & names[2] or names[1] & names[2])
    assert sum(map(len, names)) == len(reach_demos)
    for split in (tr, va, te):
        assert {d.metadata["target"] for d in split} == {0, 1, 2, 3}
    ws = [build_windows(s, WindowCfg()) for s in (tr, va, te)]
    keys = [{(s[int(i)].name) for i in w.demo_index} for s, w in zip((tr, va, te), ws)]
    assert not (keys[0] & keys[1] or keys[0] & keys[2] or keys[1] & keys[2])
    again = split_by_demonstration(reach_demos, (0.5, 0.25, 0.25), seed=3)
    assert [d.name for d in again[1]] == [d.name for d in va]
    with pytest.raises(ConfigError, match="summing to 1"):
        split_by_demonstration(reach_demos, (0.5, 0.5, 0.5))


@pytest.mark.parametrize(
    ("fractions", "message"),
    [
        ((0.5, 0.5), r"3 non-negative shares .* got \[0.5, 0.5\]"),
        ((1.2, -0.1, -0.1), r"got \[1.2, -0.1, -0.1\]"),
        ((float("nan"), 0.5, 0.5), r"got \[nan, 0.5, 0.5\]"),
        (("a", 0.5, 0.5), r"expected 3 numbers .*could not convert"),
        (0.8, r"expected 3 numbers"),
    ],
)
def test_split_fractions_are_checked(reach_demos, fractions, message) -> None:
    """One check serves split_by_demonstration, SplitRecord and the data module: a share
    that is not a number, NaN, negative, or shares not summing to 1 are refused by name."""
    with pytest.raises(ConfigError, match=message):
        check_split_fractions(fractions)
    with pytest.raises(ConfigError, match=message):
        split_by_demonstration(reach_demos, fractions)
    assert check_split_fractions(["0.6", 0.2, 0.2]) == (0.6, 0.2, 0.2)
    assert check_split_fractions(DEFAULT_SPLIT) == (0.8, 0.1, 0.1)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_features_and_progress_on_cuda_match_cpu():
    x = np.random.default_rng(0).normal(size=(4, 15, 10, 3)).astype(np.float32)
    x[0, 3:5, 2] = np.nan
    cpu = compute_features(torch.tensor(x), FPS)
    gpu = compute_features(torch.tensor(x, device="cuda"), FPS)
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-5, atol=1e-5)
    lab = torch.tensor([0, 1, 1, 2, 0, 3], device="cuda")
    assert progress_bitmask(lab).device.type == "cuda"
    torch.testing.assert_close(progress_bitmask(lab).cpu(), progress_bitmask(lab.cpu()))


def test_progress_indices_default_and_explicit() -> None:
    """By default every action but idle/return/unlabelled records progress; an explicit list
    picks those actions in its own order, and a name that is not an action is refused."""
    names = ("idle", "reach_0", "return", "reach_1", "unlabelled", "take_2")
    assert WindowCfg().progress_indices(names) == (1, 3, 5)
    cfg = WindowCfg(progress_actions=("take_2", "reach_0"))
    assert cfg.progress_indices(names) == (5, 1)
    with pytest.raises(ConfigError, match=r"progress_actions \['reach_9'\] are not among"):
        WindowCfg(progress_actions=("reach_0", "reach_9")).progress_indices(names)


@pytest.mark.parametrize(
    ("field", "value", "least"),
    [
        ("n_prev", 2, 3),
        ("n_future", 0, 1),
        ("n_future", -5, 1),
        ("stride", 0, 1),
        ("stride", True, 1),
        ("n_prev", 15.0, 3),
    ],
)
def test_window_settings_are_checked_one_field_at_a_time(field: str, value: object, least: int):
    """Each count names itself: ``n_future=0`` was refused as ``need n_prev >= 3, n_future
    >= 1, stride >= 1; got 30, 0, 2``, which the command line reported under n_prev."""
    with pytest.raises(ConfigError, match=rf"^{field}: expected an integer >= {least}, got "):
        WindowCfg(**{field: value})


def test_window_joints_must_be_a_list_not_one_string():
    """A single string was taken as a list of one; every format and command now refuses it
    (a list of one joint is the way to select one)."""
    single = r"^joints: expected a list of joint names, got the single string 'right_hand'; "
    with pytest.raises(ConfigError, match=single + r"write it as a list: \[right_hand\]$"):
        WindowCfg(joints="right_hand")
    assert WindowCfg(joints=["right_hand"]).joints == ("right_hand",)


def _tiny_demo(name: str, labels: list[int], metadata: dict | None = None) -> Demonstration:
    return Demonstration(
        positions=np.zeros((len(labels), 10, 3)),
        labels=np.array(labels),
        fps=FPS,
        joint_names=JOINT_NAMES,
        action_names=("idle", "reach_0", "reach_1", "return"),
        name=name,
        metadata=metadata or {},
    )


def test_split_sizes_of_one_group_by_hand():
    """Ten demonstrations of one target, (0.8, 0.1, 0.1): round(1) for val and for test,
    the remaining 8 for training."""
    demos = [_tiny_demo(f"d{i}", [0, 1], {"target": 0}) for i in range(10)]
    assert tuple(map(len, split_by_demonstration(demos, (0.8, 0.1, 0.1), seed=0))) == (8, 1, 1)


def test_split_strata_by_the_first_action_past_idle():
    """Without a target, a demonstration is grouped by its first action other than idle and
    return: 4 that start idle and reach 1, 4 that start idle and reach 2, split half and half
    with no validation share, put 2 of each in the test split whatever the seed (one group of
    8 would put 3 or 4 of one there for some seeds)."""
    demos = [_tiny_demo(f"a{i}", [0, 0, 1]) for i in range(4)]
    demos += [_tiny_demo(f"b{i}", [0, 0, 2]) for i in range(4)]
    for seed in range(10):
        _, _, test = split_by_demonstration(demos, (0.5, 0.0, 0.5), seed=seed)
        assert sorted(d.name[0] for d in test) == ["a", "a", "b", "b"], seed


def test_a_joint_lost_everywhere_takes_its_nearest_neighbour_along_the_bones():
    """In (torso, left_elbow, left_hand) a hand lost in every frame takes the elbow's path
    (its neighbour along the bones), not the torso's; in the whole skeleton a lost neck takes
    one of the joints next to it (head, torso, shoulders), never a hand."""
    t = torch.arange(6.0)[:, None]  # (T, 1)
    x = torch.stack([t * 0 + 1.0, t * 0 + 2.0, t * 0 + 3.0], 1).expand(6, 3, 3).clone()
    x[:, 2] = float("nan")
    out = impute_nan(x, ("torso", "left_elbow", "left_hand"))
    torch.testing.assert_close(out[:, 2], out[:, 1])
    full = torch.arange(10.0).view(1, 10, 1).expand(4, 10, 3).clone()
    neck = JOINT_NAMES.index("neck")
    full[:, neck] = float("nan")
    filled = float(impute_nan(full, JOINT_NAMES)[0, neck, 0])
    near = {"head", "torso", "left_shoulder", "right_shoulder"}
    assert JOINT_NAMES[int(filled)] in near


def test_joints_as_near_as_each_other_are_taken_in_name_order():
    """A lost neck's four neighbours (head, left_shoulder, right_shoulder, torso) are one
    bone away: the head's trajectory is taken, in any order of the joint names; without the
    head, the left shoulder's."""
    names = list(JOINT_NAMES)
    for order in (names, names[::-1], names[3:] + names[:3]):
        x = torch.arange(float(len(order))).view(1, -1, 1).expand(5, -1, 3).clone()
        neck = order.index("neck")
        x[:, neck] = float("nan")
        out = impute_nan(x, order)
        torch.testing.assert_close(out[:, neck], x[:, order.index("head")])
        x[:, order.index("head")] = float("nan")
        out = impute_nan(x, order)
        torch.testing.assert_close(out[:, neck], x[:, order.index("left_shoulder")])


@pytest.mark.parametrize("fps", [math.inf, math.nan, 0.0, -15.0, "30", None, True])
def test_compute_features_refuses_a_frame_rate_that_is_no_positive_number(fps) -> None:
    """An infinite fps made the derivatives' spacing 0 (inf and NaN features, no error); a
    string or None fps was Python's TypeError."""
    with pytest.raises(ConfigError, match="expected fps > 0 and finite"):
        compute_features(torch.randn(5, 2, 3), fps, ("position", "velocity"))


@pytest.mark.parametrize("seed", [None, -1, 2.5, "0", 2**32])
def test_split_by_demonstration_refuses_a_seed_that_would_not_repeat(seed, reach_demos) -> None:
    """``seed=None`` split differently at every call (5 different test sets in 5 calls);
    -1 and 2.5 were numpy's ValueError and TypeError."""
    demos = reach_demos
    with pytest.raises(ConfigError, match="seed"):
        split_by_demonstration(demos, DEFAULT_SPLIT, seed)
    assert split_by_demonstration(demos, DEFAULT_SPLIT, 7) == split_by_demonstration(
        demos, DEFAULT_SPLIT, 7
    )
