"""Scripted human: waits for deliveries, follows its order, grasps, reports progress."""

from __future__ import annotations

import numpy as np
import pytest
from sim_fakes import FakeMotion, FakeOrder, deadline, fake_solo_duration

from iplanner_torch.data.skeleton import JOINT_INDEX
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.sim.human import HumanCfg, ScriptedHuman
from iplanner_torch.sim.scene import SceneCfg

SCENE = SceneCfg()
TARGETS = {i: SCENE.delivery_position(i) + [0.0, 0.0, 0.015] for i in SCENE.block_ids}


def _human(order=(2, 0, 1, 3), **kw) -> ScriptedHuman:
    return ScriptedHuman(
        HumanCfg(**kw), FakeMotion(), task_order=FakeOrder(order), targets=TARGETS, seed=4
    )


def _run(human: ScriptedHuman, delivered: set[int], until: float, dt: float = 0.01):
    events = []
    t = human.time
    while t < until:
        t += dt
        events += human.update(t, delivered)
    return events


def test_waits_for_delivery_then_takes_in_order() -> None:
    human = _human()
    assert _run(human, {0, 1}, 3.0) == []  # block 2 comes first and is not there
    np.testing.assert_allclose(human.joint_positions(), FakeMotion().rest_pose())
    events = _run(human, {0, 1, 2, 3}, 30.0)
    took = [e.block for e in events if e.kind == "human_took"]
    assert took == [2, 0, 1, 3]
    assert human.done
    kinds = [e.kind for e in events if e.block == 2]
    assert kinds == ["human_take_started", "human_grasped", "human_took"]


@pytest.mark.parametrize("reaction", [0.0, 0.4, 1.0])
def test_take_starts_a_reaction_time_after_the_block_lands(reaction: float) -> None:
    human = _human(order=(1, 0, 2, 3), idle_s=(0.0, 0.0), reaction_s=reaction)
    _run(human, set(), 2.0)  # idle long over, nothing delivered yet
    t_land = human.time
    events = _run(human, {1}, t_land + 2.0)
    start = next(e.time for e in events if e.kind == "human_take_started")
    # the first update that sees block 1 is one step after t_land
    assert start - (t_land + 0.01) == pytest.approx(reaction, abs=0.011)


def test_hand_reaches_the_block_when_it_grasps() -> None:
    human = _human(order=(1, 0, 2, 3))
    delivered = {1}
    t = 0.0
    while True:
        t += 0.01
        ev = human.update(t, delivered)
        if any(e.kind == "human_grasped" for e in ev):
            break
        assert t < 10.0
    hand = human.joint_positions(t)[JOINT_INDEX["left_hand"]]  # block 1 lies at y > 0
    assert np.linalg.norm(hand - TARGETS[1]) < 0.02
    assert human.carrying == (1, JOINT_INDEX["left_hand"])
    assert human.action_label == "take_1"


def test_the_grasp_comes_at_the_first_frame_within_5_mm_of_the_closest_approach() -> None:
    """The person grasps at the first frame of the reach whose hand is within 5 mm of its
    closest approach to the block: found here on the fake motion's own frames (which start at
    the held pose, so the start blend changes nothing), a few frames before the hand comes to
    rest on the block."""
    human = _human(order=(1, 0, 2, 3), idle_s=(0.0, 0.0))
    rest = human.joint_positions()
    t, start, grasped = 0.0, None, None
    while grasped is None:
        t = round(t + 0.01, 10)
        for e in human.update(t, {1}):
            if e.kind == "human_take_started":
                start = e.time
            if e.kind == "human_grasped":
                grasped = e.time
        assert t < 10.0
    cfg = HumanCfg()
    frames = FakeMotion().reach("left", TARGETS[1], None, speed=cfg.speed_factor,
                                hold_s=cfg.hold_s, start_pose=rest)  # fmt: skip
    dist = np.linalg.norm(frames[:, JOINT_INDEX["left_hand"]] - TARGETS[1], axis=-1)
    k = next(i for i, d in enumerate(dist) if d <= dist.min() + 0.005)
    assert 0 < k < int(np.argmin(dist))  # within 5 mm before the hand comes to rest
    # the first update on the 10 ms grid at or after frame k
    steps = int(np.ceil(round(k / FakeMotion.fps / 0.01, 9)))
    assert start is not None and grasped == pytest.approx(start + 0.01 * steps, abs=1e-9)


def _grouped_human(flexible: bool) -> ScriptedHuman:
    """A human under ``(0,1)->(2,3)`` whose personal order starts with block 1."""
    from iplanner_torch.sim.tasks import parse_order

    order = parse_order("(0,1)->(2,3)", SCENE.block_ids)
    for seed in range(100):
        cfg = HumanCfg(flexible_order=flexible, idle_s=(0.0, 0.0))
        human = ScriptedHuman(cfg, FakeMotion(), task_order=order, targets=TARGETS, seed=seed)
        if human.order[:2] == [1, 0]:
            return human
    raise AssertionError("no seed gives a personal order starting 1, 0")


@pytest.mark.parametrize("flexible", [False, True])
def test_flexible_order_takes_any_delivered_block_the_order_allows(flexible: bool) -> None:
    human = _grouped_human(flexible)
    # block 2 lies there first: the order forbids it before 0 and 1, in both modes
    assert _run(human, {2}, 2.0) == []
    events = _run(human, {0, 2}, 6.0)  # block 0 arrives; the person wanted 1 first
    took = [e.block for e in events if e.kind == "human_took"]
    # flexible: 0 is allowed now, so it is taken (and 2 is not: 1 is still to come)
    assert took == ([0] if flexible else [])
    events = _run(human, {0, 1, 2, 3}, 40.0)
    took += [e.block for e in events if e.kind == "human_took"]
    # with everything there, a flexible person keeps to the personal order where it can
    assert took == ([0, 1] if flexible else [1, 0]) + human.order[2:]
    assert human.done


def test_progress_bitmask_maps_take_to_predictor_actions() -> None:
    human = _human(order=(0, 1, 2, 3))
    _run(human, {0, 1}, 40.0)
    assert human.completed == [0, 1]
    names = ("idle", "reach_0", "reach_1", "reach_2", "return")
    assert human.progress_bitmask(names) == (1 << 1) | (1 << 2)
    assert human.progress_bitmask(("Take_1", "take_0")) == 0b11
    # names that say nothing of the blocks: block i is action i
    assert human.progress_bitmask(("a", "b", "c")) == 0b11


def test_the_seated_torso_sits_at_seat_x() -> None:
    """``seat_x`` places the torso, the rest of the body moved with it (bodies of other
    sizes would otherwise sit elsewhere)."""
    from iplanner_torch.data.skeleton import JOINT_INDEX
    from iplanner_torch.sim.human import ReachingMotionSource

    for seed in range(3):
        free = ReachingMotionSource(seed).rest_pose()
        seated = ReachingMotionSource(seed, seat_x=-0.45).rest_pose()
        assert seated[JOINT_INDEX["torso"], 0] == pytest.approx(-0.45)
        np.testing.assert_allclose(seated - seated[JOINT_INDEX["torso"]],
                                   free - free[JOINT_INDEX["torso"]], atol=1e-12)  # fmt: skip


def test_faster_human_finishes_sooner_and_seed_repeats() -> None:
    times = {}
    for speed in ("slow", "fast"):
        human = _human(speed=speed, idle_s=(0.5, 0.5))
        ev = _run(human, set(TARGETS), 60.0)
        times[speed] = [e.time for e in ev if e.kind == "human_took"][-1]
    assert times["fast"] < 0.6 * times["slow"]
    a = _run(_human(), set(TARGETS), 20.0)
    b = _run(_human(), set(TARGETS), 20.0)
    assert a == b


@pytest.mark.parametrize("idle", [(0.0, 0.0), (0.5, 0.5), (0.2, 0.9)])
def test_each_take_starts_an_idle_pause_after_the_last_ends(idle: tuple[float, float]) -> None:
    """With every block delivered and no reaction time the person pauses ``idle_s`` (drawn
    uniformly from its range) before the first take and after each: take i starts when the
    pause after take i - 1 ends, up to one 10 ms step."""
    human = _human(order=(1, 0, 2, 3), idle_s=idle, reaction_s=0.0)
    events = _run(human, set(TARGETS), 60.0)
    starts = [e.time for e in events if e.kind == "human_take_started"]
    ends = [0.0] + [e.time for e in events if e.kind == "human_took"]
    assert len(starts) == 4 and len(ends) == 5
    pauses = [s - e for s, e in zip(starts, ends)]
    assert all(idle[0] - 1e-9 <= p <= idle[1] + 0.01 + 1e-9 for p in pauses), pauses
    if idle[0] < idle[1]:  # drawn, not the same pause every time
        assert max(pauses) - min(pauses) > 0.02


def test_blocking_mode_moves_the_arm_into_the_path() -> None:
    cfg = dict(mode="blocking", blocking_start_s=0.3, blocking_target=(0.1, -0.1, 0.25))
    human = ScriptedHuman(HumanCfg(**cfg), FakeMotion(), task_order=None, targets={}, seed=0)
    events = _run(human, set(), 0.5)
    assert [e.kind for e in events] == ["blocking_started"]
    _run(human, set(), 2.0)
    hand = human.joint_positions()[JOINT_INDEX["right_hand"]]
    assert np.linalg.norm(hand - np.array(cfg["blocking_target"])) < 0.02


def test_errors() -> None:
    with pytest.raises(ConfigError, match="speed"):
        HumanCfg(speed="sprint")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="reaction_s"):
        HumanCfg(reaction_s=-0.1)
    with pytest.raises(ConfigError, match="task_order"):
        ScriptedHuman(HumanCfg(), FakeMotion(), task_order=None, targets=TARGETS, seed=0)
    with pytest.raises(ConfigError, match="absent"):
        ScriptedHuman(HumanCfg(), FakeMotion(), task_order=FakeOrder([9]), targets=TARGETS, seed=0)


def _reaching_human(seed: int = 3) -> ScriptedHuman:
    from iplanner_torch.sim.human import ReachingMotionSource

    return ScriptedHuman(
        HumanCfg(),
        ReachingMotionSource(seed, seat_x=SCENE.human_seat_x),
        task_order=FakeOrder((1, 0, 2, 3)),
        targets=TARGETS,
        seed=seed,
    )


@pytest.mark.parametrize("t_start", [0.2, 1.5, 4.0])
def test_preview_is_the_motion_the_script_then_plays(t_start: float) -> None:
    """The preview made at t_start equals the poses the human goes through afterwards (the
    reaching generator draws its motions from the script's random stream)."""
    delivered = set(TARGETS)
    human = _reaching_human()
    _run(human, delivered, t_start)
    t0 = human.time
    played_t, played = [], []
    t = t0
    while t < t0 + 3.0:
        t += 0.01
        human.update(t, delivered)
        played_t.append(t)
        played.append(human.joint_positions(t))
    twin = _reaching_human()
    _run(twin, delivered, t_start)
    preview = twin.preview(np.asarray(played_t), delivered, 0.01)
    np.testing.assert_allclose(preview, np.asarray(played), atol=1e-6)
    hand = JOINT_INDEX["left_hand"]  # block 1 lies at y > 0
    assert np.ptp(preview[:, hand], axis=0).max() > 0.1  # a reach happens in the span


@pytest.mark.parametrize("t_start", [0.5, 1.5, 4.0])
def test_preview_leaves_the_human_unchanged(t_start: float) -> None:
    """Previewing (idle, or in the middle of a reach) changes nothing of the script, its
    random stream included; the copy shares only the read-only collaborators."""
    delivered = set(TARGETS)
    a, b = _reaching_human(), _reaching_human()
    _run(a, delivered, t_start)
    _run(b, delivered, t_start)
    twin = b._twin()
    assert twin.motion is b.motion and twin.cfg is b.cfg and twin.targets is b.targets
    assert twin._rng is not b._rng and twin.completed is not b.completed
    b.preview(b.time + 0.1 * np.arange(1, 31), delivered, 0.01)
    assert _run(a, delivered, 12.0) == _run(b, delivered, 12.0)
    np.testing.assert_array_equal(a.joint_positions(), b.joint_positions())


def test_preview_errors() -> None:
    from iplanner_torch.errors import ShapeError

    human = _human()
    _run(human, set(), 1.0)
    with pytest.raises(ShapeError, match="times"):
        human.preview(np.ones((2, 2)), set(), 0.01)
    with pytest.raises(ConfigError, match="step_s"):
        human.preview(np.array([1.5]), set(), 0.0)
    with pytest.raises(ConfigError, match="increasing"):
        human.preview(np.array([0.5]), set(), 0.01)


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        (dict(hold_s=float("nan")), "hold_s"),
        (dict(reaction_s=float("nan")), "reaction_s"),
        (dict(reaction_s=float("inf")), "reaction_s"),
        (dict(blocking_start_s=float("nan")), "blocking_start_s"),
        (dict(blocking_hold_s=-1.0), "blocking_hold_s"),
        (dict(idle_s=(0.3,)), "idle_s"),
        (dict(idle_s=(0.3, float("nan"))), "idle_s"),
        (dict(idle_s=(1.0, 0.3)), "idle_s"),
        (dict(idle_s="0.3"), "idle_s"),
        (dict(blocking_target=(0.1, 0.0)), "blocking_target"),
        (dict(blocking_target=(0.1, 0.0, float("inf"))), "blocking_target"),
        (dict(flexible_order="yes"), "flexible_order"),
    ],
)
def test_cfg_rejects_meaningless_values(kw: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        HumanCfg(**kw)


def test_cfg_accepts_lists_and_negative_seeds_are_refused() -> None:
    assert HumanCfg(idle_s=[0.2, 0.5]).idle_s == [0.2, 0.5]  # as Hydra passes sequences
    with pytest.raises(ConfigError, match="seed"):
        ScriptedHuman(
            HumanCfg(), FakeMotion(), task_order=FakeOrder([0]), targets=TARGETS, seed=-1
        )


def test_preview_rejects_non_finite_times() -> None:
    human = _human()
    _run(human, set(), 1.0)
    for bad in (np.inf, np.nan):
        with deadline(10.0), pytest.raises(DataError, match="finite times"):
            human.preview(np.array([human.time + 0.5, bad]), set(), 0.01)
    with pytest.raises(ConfigError, match="step_s"):
        human.preview(np.array([1.5]), set(), float("inf"))


@pytest.mark.parametrize("delivered", [set(TARGETS), {2}, set()])
def test_preview_of_far_times_is_quick_and_exact(delivered: set[int]) -> None:
    """Once nothing can happen any more (every allowed block taken, or the human waits for
    a block that never comes) the preview stops stepping: far times cost nothing, and the
    poses equal those the script plays step by step."""
    human = _human()
    _run(human, delivered, 0.5)
    times = human.time + np.array([0.3, 2.0, 9.0, 25.0, 40.0])
    preview = human.preview(times, delivered, 0.01)
    twin = _human()
    _run(twin, delivered, 0.5)
    played = []
    for t in times:
        _run(twin, delivered, t - 1e-9)
        played.append(twin.joint_positions(t))
    np.testing.assert_array_equal(preview, np.asarray(played))
    with deadline(10.0):
        far = human.preview(np.array([human.time + 40.0, 1e7, 1e300]), delivered, 0.01)
    np.testing.assert_array_equal(far, np.repeat(preview[-1:], 3, axis=0))


def test_preview_of_far_times_in_blocking_mode() -> None:
    cfg = HumanCfg(mode="blocking", blocking_start_s=0.3)
    human = ScriptedHuman(cfg, FakeMotion(), task_order=None, targets={}, seed=0)
    with deadline(10.0):
        far = human.preview(np.array([30.0, 1e7]), set(), 0.01)
    np.testing.assert_array_equal(far[0], far[1])


@pytest.mark.parametrize("speed", ["slow", "medium", "fast"])
def test_solo_duration_sums_the_reaches_of_doing_every_task_alone(speed: str) -> None:
    """Efficiency's reference: a reach to each block's far position, one to its delivery
    spot, and the mean idle, in the task order, at the human's speed."""
    human = _human(speed=speed)
    far = {i: SCENE.block_position(i) + [0.0, 0.0, 0.015] for i in SCENE.block_ids}
    cfg = human.cfg
    expect = fake_solo_duration(
        (2, 0, 1, 3),
        far,
        TARGETS,
        speed=cfg.speed_factor,
        hold_s=cfg.hold_s,
        idle_s=cfg.idle_s,
    )
    assert human.solo_duration(far) == pytest.approx(expect, rel=1e-12)
    assert expect > 8 * cfg.hold_s  # eight reaches, each holding


class _OffsetMotion(FakeMotion):
    """FakeMotion whose reaches start 2 cm (head, neck, torso) off the pose they start from,
    as a generator's trunk sway or IK elbow can."""

    def reach(self, arm, target, rng, *, speed, hold_s, start_pose) -> np.ndarray:
        frames = (
            super()
            .reach(arm, target, rng, speed=speed, hold_s=hold_s, start_pose=start_pose)
            .copy()
        )
        frames[:, :3] += np.array([0.02, 0.0, 0.0])
        return frames


def test_a_reach_starts_at_the_pose_the_person_holds() -> None:
    """The first frames of a reach are blended from the pose held before it, so the joints do
    not jump when a take starts; after the blend the motion is the source's own."""
    from iplanner_torch.sim.human import START_BLEND_S

    motion = _OffsetMotion()
    human = ScriptedHuman(
        HumanCfg(), motion, task_order=FakeOrder((1, 0, 2, 3)), targets=TARGETS, seed=4
    )
    held = human.joint_positions()
    t, dt, largest = 0.0, 0.01, 0.0
    start = None
    while start is None or t < start + 2 * START_BLEND_S:
        before = human.joint_positions()
        t += dt
        events = human.update(t, {1})
        if start is None and any(e.kind == "human_take_started" for e in events):
            start = t
            np.testing.assert_allclose(human.joint_positions(), held, atol=1e-12)
        if start is not None:
            step = np.linalg.norm(human.joint_positions()[:3] - before[:3], axis=-1)
            largest = max(largest, float(step.max()))
    # the trunk, which only the offset moves: 2 cm by min-jerk over the blend, at most
    # 1.875 * 2 cm / 0.3 s = 1.25 mm per 10 ms step (it would be one 2 cm jump without it)
    assert largest < 0.0015
    late = human.joint_positions(start + 1.5 * START_BLEND_S)
    assert late[0, 0] - held[0, 0] == pytest.approx(0.02, abs=1e-9)  # the source's own offset


def test_a_motion_source_that_gives_bad_frames_is_refused() -> None:
    class Bad(FakeMotion):
        def __init__(self, frames: np.ndarray) -> None:
            super().__init__()
            self.frames = frames

        def reach(self, arm, target, rng, *, speed, hold_s, start_pose) -> np.ndarray:
            return self.frames

    for frames, error in (
        (np.zeros((5, 3, 3)), ShapeError),
        (np.full((5, 10, 3), np.nan), DataError),
    ):
        human = ScriptedHuman(
            HumanCfg(), Bad(frames), task_order=FakeOrder((1, 0, 2, 3)), targets=TARGETS, seed=4
        )
        with pytest.raises(error, match="motion source"):
            _run(human, {1}, 10.0)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "1.0"])
def test_a_time_that_is_no_finite_number_is_refused(bad) -> None:
    """update and joint_positions refuse a NaN, infinite or non-numeric time, idle and in
    motion, and the script keeps its clock (a NaN clock would never reach a motion's end)."""
    human = _human(order=(1, 0, 2, 3), idle_s=(0.0, 0.0))
    for motion in (False, True):
        if motion:
            _run(human, {1}, 1.0)
            assert human.action_label == "take_1"
        before = human.time
        with pytest.raises(DataError, match="finite time"):
            human.update(bad, {1})
        assert human.time == before
        with pytest.raises(DataError, match="finite time"):
            human.joint_positions(bad)
    took = [e.block for e in _run(human, {1}, 20.0) if e.kind == "human_took"]
    assert took == [1]


@pytest.mark.parametrize(
    ("target", "error", "match"),
    [
        ([0.1, 0.2], ShapeError, r"target 1 a \(3,\) point"),
        ([[0.1, 0.2, 0.3]], ShapeError, r"target 1 a \(3,\) point"),
        (["a", "b", "c"], ShapeError, r"target 1 a \(3,\) point"),
        ([0.1, [0.2], 0.3], ShapeError, r"target 1 a \(3,\) point"),
        ([0.1, 0.2, 0.3j], ShapeError, r"target 1 a \(3,\) point"),
        ([0.1, float("nan"), 0.3], DataError, "target 1 a finite point"),
        ([0.1, 0.2, float("inf")], DataError, "target 1 a finite point"),
    ],
)
def test_targets_must_be_finite_points(target, error: type[Exception], match: str) -> None:
    targets = {**TARGETS, 1: target}
    with pytest.raises(error, match=match):
        ScriptedHuman(
            HumanCfg(), FakeMotion(), task_order=FakeOrder((1,)), targets=targets, seed=0
        )
    with pytest.raises(ConfigError, match="target block id"):
        ScriptedHuman(
            HumanCfg(), FakeMotion(), task_order=FakeOrder((1,)), targets={"1": TARGETS[1]}, seed=0
        )


def test_update_refuses_time_going_back_and_unknown_blocks() -> None:
    human = _human()
    _run(human, {0}, 1.0)
    now = human.time
    with pytest.raises(DataError, match="expected t >= the previous update's"):
        human.update(now - 0.5, {0})
    with pytest.raises(DataError, match=r"delivered names blocks \[9\] without a target"):
        human.update(now + 0.01, {0, 9})
    assert human.time == now  # nothing changed
    human.update(now, {0})  # the same time again is fine
