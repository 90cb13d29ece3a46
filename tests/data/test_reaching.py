"""Synthetic reaching generator: determinism, kinematics, targets, speed profiles, labels."""

from __future__ import annotations

import numpy as np
import pytest

from iplanner_torch.data.reaching import (
    ReachingCfg,
    add_tracker_noise,
    generate_reaching_dataset,
    reach_action_names,
    reach_motion,
    reach_targets,
    reaching_demonstrations,
    rest_pose,
    sample_body,
)
from iplanner_torch.data.skeleton import BONES, JOINT_INDEX
from iplanner_torch.errors import ConfigError

CFG = ReachingCfg(reaches_per_target=4, speeds=(0.5, 1.0, 2.0))


@pytest.fixture(scope="module")
def demos():
    return {
        (t, r): reaching_demonstrations(CFG, t, r)
        for t in range(CFG.n_targets)
        for r in range(CFG.reaches_per_target)
    }


def _hand(demo):
    return demo.clean_positions[:, JOINT_INDEX[f"{demo.metadata['arm']}_hand"]].astype(float)


def test_same_seed_same_arrays_other_seed_differs():
    a = reaching_demonstrations(CFG, 3, 1)[1]
    b = reaching_demonstrations(CFG, 3, 1)[1]
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.clean_positions, b.clean_positions)
    np.testing.assert_array_equal(a.labels, b.labels)
    c = reaching_demonstrations(ReachingCfg(reaches_per_target=4, seed=1), 3, 1)[0]
    assert c.positions.shape != a.positions.shape or not np.allclose(
        c.clean_positions, a.clean_positions, atol=1e-3
    )


def test_bone_lengths_constant_within_demonstration(demos):
    for demo_list in demos.values():
        for d in demo_list:
            c = d.clean_positions.astype(np.float64)
            for a, b in BONES:
                length = np.linalg.norm(c[:, JOINT_INDEX[a]] - c[:, JOINT_INDEX[b]], axis=1)
                assert (length.max() - length.min()) / length.mean() < 1e-5, (d.name, a, b)


def test_hand_reaches_target_and_arm_matches_side(demos):
    targets = reach_targets(CFG.n_targets)
    for (t, _), demo_list in demos.items():
        for d in demo_list:
            hand = _hand(d)
            at_target = d.labels == 1 + t
            dist = np.linalg.norm(hand[at_target] - targets[t], axis=1)
            assert dist.min() < 0.03, (d.name, dist.min())
            assert d.metadata["arm"] == ("left" if targets[t, 1] > 0 else "right")


def _count_peaks(v: np.ndarray) -> int:
    thr = 0.1 * v.max()
    inner = (v[1:-1] > v[:-2]) & (v[1:-1] >= v[2:]) & (v[1:-1] > thr)
    return int(inner.sum())


def test_single_peak_speed_profile_per_reach(demos):
    for (t, _), demo_list in demos.items():
        d = demo_list[1]  # speed 1
        hand = _hand(d)
        reach = np.flatnonzero(d.labels == 1 + t)
        # the reach phase plus one rest frame on either side, up to the start of the hold
        first = reach[0] - 1
        seg = hand[first : reach[-1] + 1]
        v = np.linalg.norm(np.diff(seg, axis=0), axis=1) * d.fps
        moving = np.flatnonzero(v > 1e-4)
        v = v[: moving[-1] + 2]  # drop the hold
        assert _count_peaks(v) == 1, (d.name, np.round(v, 3))
        ret = np.flatnonzero(d.labels == len(d.action_names) - 1)
        v_ret = np.linalg.norm(np.diff(hand[ret[0] - 1 : ret[-1] + 2], axis=0), axis=1)
        assert _count_peaks(v_ret) == 1, d.name


def test_speed_variants_scale_duration(demos):
    for demo_list in demos.values():
        slow, medium, fast = (d.duration for d in demo_list)
        step = 2.0 / CFG.fps  # one frame of the slowest sampling
        assert abs(slow - 2.0 * medium) <= step
        assert abs(fast - 0.5 * medium) <= step
        assert [d.metadata["speed_name"] for d in demo_list] == ["slow", "medium", "fast"]


def test_labels_cover_idle_reach_return(demos):
    names = reach_action_names(CFG.n_targets)
    for (t, _), demo_list in demos.items():
        d = demo_list[1]
        assert d.action_names == names
        seq = [int(a) for i, a in enumerate(d.labels) if i == 0 or a != d.labels[i - 1]]
        assert seq == [0, 1 + t, len(names) - 1, 0]


def test_noise_and_dropout_statistics():
    clean = np.zeros((4000, 10, 3))
    noisy = add_tracker_noise(clean, np.random.default_rng(0), sigma=0.02, dropout_rate=0.01)
    lost = np.isnan(noisy).all(axis=-1)
    assert np.isnan(noisy).any(axis=-1).sum() == lost.sum()  # whole joints are lost
    assert 0.006 < lost.mean() < 0.014
    assert abs(np.nanstd(noisy) - 0.02) < 0.001
    runs = np.diff(np.r_[0, lost[:, 0].astype(int), 0])
    burst = (np.flatnonzero(runs == -1) - np.flatnonzero(runs == 1)).mean()
    assert burst > 1.5  # bursts, not isolated frames


def test_noisy_differs_from_clean_by_sigma(demos):
    d = demos[(0, 0)][1]
    diff = (d.positions - d.clean_positions)[np.isfinite(d.positions)]
    assert 0.007 < diff.std() < 0.013


def test_reach_motion_public_api():
    body = sample_body(np.random.default_rng(5))
    target = np.array([0.05, -0.25, 0.04])
    pos, phase = reach_motion(body, "right", target, np.random.default_rng(1), hold_s=0.4)
    assert pos.shape[1:] == (10, 3) and phase.shape == (pos.shape[0],)
    assert set(np.unique(phase)) == {0, 1, 2}
    hand = pos[:, JOINT_INDEX["right_hand"]]
    assert np.linalg.norm(hand[phase == 1] - target, axis=1).max() < 0.01
    np.testing.assert_allclose(pos[0], rest_pose(body), atol=0.03)  # starts at rest (sway)
    np.testing.assert_allclose(hand[-1], hand[0], atol=1e-6)  # returns
    fast, _ = reach_motion(body, "right", target, np.random.default_rng(1), hold_s=0.4, speed=2)
    assert abs(len(fast) - (len(pos) - 1) / 2 - 1) <= 1
    start = rest_pose(body)
    start[JOINT_INDEX["right_hand"]] += [0.05, 0.0, 0.02]
    pos2, _ = reach_motion(body, "right", target, np.random.default_rng(1), start_pose=start)
    np.testing.assert_allclose(
        pos2[0, JOINT_INDEX["right_hand"]], start[JOINT_INDEX["right_hand"]]
    )


def test_bad_configs_raise():
    with pytest.raises(ConfigError, match="n_targets must be even"):
        ReachingCfg(n_targets=7)
    with pytest.raises(ConfigError, match="speeds"):
        ReachingCfg(speeds=(1.0, -2.0))
    with pytest.raises(ConfigError, match="noise_sigma"):
        ReachingCfg(noise_sigma=-0.1)
    with pytest.raises(ConfigError, match="expected target"):
        reach_motion(sample_body(np.random.default_rng(0)), "left", np.zeros(2),
                     np.random.default_rng(0))  # fmt: skip


def test_generate_dataset_writes_files_and_card(tmp_path):
    cfg = ReachingCfg(n_targets=4, reaches_per_target=2, speeds=(1.0, 2.0))
    s = generate_reaching_dataset(cfg, tmp_path, progress=False)
    assert s.n_demonstrations == 16 == len(list(tmp_path.glob("*.npz")))
    card = (tmp_path / "README.md").read_text()
    for fact in ("| demonstrations | 16 |", "reach_3", "| seed | 0 |", "generation time"):
        assert fact in card
    assert s.bytes_on_disk == sum(p.stat().st_size for p in tmp_path.glob("*.npz"))


def test_translated_start_pose_moves_the_whole_motion():
    body = sample_body(np.random.default_rng(4))
    target = np.array([0.0, 0.2, 0.04])
    start = rest_pose(body) + np.array([0.07, -0.02, 0.0])
    pos, phase = reach_motion(body, "left", target, np.random.default_rng(2), start_pose=start)
    np.testing.assert_allclose(pos[0], start, atol=0.03)  # trunk and hands where asked
    hand = pos[:, JOINT_INDEX["left_hand"]]
    assert np.linalg.norm(hand[phase == 1] - target, axis=1).max() < 0.01


@pytest.mark.parametrize("bad", [float("inf"), float("-inf"), float("nan")])
@pytest.mark.parametrize(
    ("field", "value"),
    [  # None stands for the bad value
        ("fps", None),  # fps=inf was an OverflowError in frame_times
        ("noise_sigma", None),
        ("dropout_rate", None),
        ("dropout_burst", None),
        ("speeds", (1.0, None)),
        ("hold_s", (0.2, None)),
        ("idle_start_s", (None, 1.0)),
        ("reaction_s", (0.1, None)),
        ("idle_end_s", (0.5, None)),
    ],
)
def test_non_finite_config_values_raise(field, value, bad):
    if isinstance(value, tuple):
        arg = tuple(bad if v is None else v for v in value)
    else:
        arg = bad
    with pytest.raises(ConfigError, match=rf"^expected ReachingCfg\.{field} (a |>|in )"):
        ReachingCfg(**{field: arg})


def test_bad_config_messages_name_the_field():
    with pytest.raises(ConfigError, match=r"^expected ReachingCfg\.fps > 0 and finite, got -15"):
        ReachingCfg(fps=-15)
    with pytest.raises(ConfigError, match=r"^expected ReachingCfg\.fps > 0 and finite, got True"):
        ReachingCfg(fps=True)
    # text is not a number, even when float() reads it (the package's checks refuse it)
    with pytest.raises(ConfigError, match=r"^expected ReachingCfg\.noise_sigma >= 0 and finite"):
        ReachingCfg(noise_sigma="0.01")
    with pytest.raises(ConfigError, match=r"^expected ReachingCfg\.hold_s a sequence of 2"):
        ReachingCfg(hold_s=("0.1", 0.2))
    with pytest.raises(ConfigError, match=r"^expected ReachingCfg\.dropout_burst >= 1"):
        ReachingCfg(dropout_burst=0.5)
    with pytest.raises(ConfigError, match=r"^ReachingCfg\.speeds must be a non-empty list"):
        ReachingCfg(speeds=())
    with pytest.raises(ConfigError, match=r"^expected fps > 0 and finite, got inf"):
        reach_motion(sample_body(np.random.default_rng(0)), "left", np.zeros(3),
                     np.random.default_rng(0), fps=float("inf"))  # fmt: skip


def test_targets_lie_4_cm_above_the_table_in_two_rows() -> None:
    """The layout of the module docstring: rows at x = 0.04 and 0.18 m, the hand 4 cm above
    the table top."""
    t = reach_targets(8)
    assert (t[:, 2] == 0.04).all() and set(np.round(t[:, 0], 6)) == {0.04, 0.18}
    np.testing.assert_allclose(sorted(set(np.round(t[:, 1], 6))), [-0.36, -0.12, 0.12, 0.36])


def test_single_frame_dropouts_reach_the_rate() -> None:
    """Bursts of one frame (``dropout_burst=1``): the lost share is the rate, 0.01 within
    20 % over 40,000 joint-frames (the standard error is 5 %)."""
    clean = np.zeros((4000, 10, 3))
    noisy = add_tracker_noise(
        clean, np.random.default_rng(1), sigma=0.0, dropout_rate=0.01, dropout_burst=1.0
    )
    assert 0.008 < np.isnan(noisy).all(axis=-1).mean() < 0.012


def test_metadata_of_speed_and_subject() -> None:
    """The reaction time scales with the speed as the motion does; reach r is made by
    subject r mod n_subjects."""
    cfg = ReachingCfg(reaches_per_target=5, speeds=(1.0, 2.0), n_subjects=3)
    one, two = reaching_demonstrations(cfg, 2, 0)
    assert two.metadata["reaction_s"] == pytest.approx(one.metadata["reaction_s"] / 2)
    assert two.metadata["hold_s"] == pytest.approx(one.metadata["hold_s"] / 2)
    assert [reaching_demonstrations(cfg, 2, r)[0].metadata["subject"] for r in range(5)] == [
        0, 1, 2, 0, 1,
    ]  # fmt: skip
