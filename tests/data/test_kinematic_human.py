"""The synthetic body's kinematics: minimum-jerk timing and the two-link arm."""

from __future__ import annotations

import numpy as np

from iplanner_torch.data.kinematic_human import min_jerk, solve_elbow


def test_min_jerk_is_the_rest_to_rest_quintic() -> None:
    """The unique quintic from 0 to 1 with zero velocity and acceleration at both ends
    (coefficients solved here from those six conditions), clipped outside [0, 1]."""
    rows = []
    for u in (0.0, 1.0):
        rows.append([u**k for k in range(6)])  # position
        rows.append([k * u ** (k - 1) if k >= 1 else 0.0 for k in range(6)])  # velocity
        rows.append([k * (k - 1) * u ** (k - 2) if k >= 2 else 0.0 for k in range(6)])  # acc
    coef = np.linalg.solve(np.array(rows), np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]))
    u = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(min_jerk(u), np.polyval(coef[::-1], u), atol=1e-12)
    np.testing.assert_array_equal(min_jerk(np.array([-0.5, 1.7])), [0.0, 1.0])
    assert min_jerk(np.array([0.5]))[0] == 0.5  # symmetric about the midpoint


def test_solve_elbow_keeps_both_bones_and_reaches_what_it_can() -> None:
    rng = np.random.default_rng(0)
    upper, fore = 0.30, 0.27
    t = 200
    shoulder = rng.normal(0.0, 0.2, (t, 3))
    direction = rng.normal(size=(t, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    dist = rng.uniform(0.05, 0.75, (t, 1))  # some within reach, some beyond 0.57 m
    hand_in = shoulder + dist * direction
    swivel = rng.uniform(-1.5, 1.5, t)
    for side in (1.0, -1.0):
        elbow, hand = solve_elbow(shoulder, hand_in, upper, fore, swivel, side)
        np.testing.assert_allclose(np.linalg.norm(elbow - shoulder, axis=1), upper, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(hand - elbow, axis=1), fore, atol=1e-9)
        reach = (dist[:, 0] > abs(upper - fore) + 1e-3) & (dist[:, 0] < upper + fore - 1e-3)
        assert reach.sum() > 50 and (~reach).sum() > 30
        np.testing.assert_allclose(hand[reach], hand_in[reach], atol=1e-12)
        # out of reach: pulled back along the shoulder-hand line to full extension
        far = dist[:, 0] >= upper + fore
        got = hand[far] - shoulder[far]
        np.testing.assert_allclose(np.linalg.norm(got, axis=1), upper + fore, rtol=1e-5)
        np.testing.assert_allclose(
            got / np.linalg.norm(got, axis=1, keepdims=True), direction[far], atol=1e-9
        )


def test_swivel_turns_the_elbow_about_the_shoulder_hand_axis() -> None:
    """Swivel 0 and pi put the elbow on opposite sides of the axis (their midpoint on it);
    +pi/2 turns it to the body's outside: +y for the left arm, -y for the right."""
    shoulder = np.array([[0.0, 0.0, 0.0]])
    hand = np.array([[0.45, 0.0, 0.0]])  # straight ahead
    e0, _ = solve_elbow(shoulder, hand, 0.3, 0.27, np.array([0.0]), 1.0)
    e1, _ = solve_elbow(shoulder, hand, 0.3, 0.27, np.array([np.pi]), 1.0)
    mid = 0.5 * (e0 + e1)
    np.testing.assert_allclose(mid[0, 1:], [0.0, 0.0], atol=1e-12)  # on the x axis
    assert e0[0, 2] < 0.0  # swivel 0: the relaxed elbow points down
    left, _ = solve_elbow(shoulder, hand, 0.3, 0.27, np.array([np.pi / 2]), 1.0)
    right, _ = solve_elbow(shoulder, hand, 0.3, 0.27, np.array([np.pi / 2]), -1.0)
    assert left[0, 1] > 0.1 and right[0, 1] < -0.1
    np.testing.assert_allclose(left[0, [0, 2]], right[0, [0, 2]], atol=1e-12)


def test_shoulders_hang_below_the_neck_on_their_own_side() -> None:
    """Left shoulder at +y, right at -y, both ``shoulder_drop`` below the neck (upright)."""
    from iplanner_torch.data.kinematic_human import BodyParams

    body = BodyParams()
    head, neck, _, _, left, right = body.trunk_offsets()
    for shoulder, side in ((left, 1.0), (right, -1.0)):
        np.testing.assert_allclose(
            shoulder - neck, [0.0, side * body.shoulder_half_width, -body.shoulder_drop]
        )
    assert head[2] > neck[2]


def test_lean_for_target_by_hand() -> None:
    """Upright, the left shoulder sits at waist + (0, 0.18, 0.25 + torso_neck - 0.03): a
    target 0.5 arm lengths to its left is reached without leaning with the left arm, and is
    out of reach of the right arm even leaning (max_pitch); a target 2 m away takes
    max_pitch."""
    from iplanner_torch.data.kinematic_human import BodyParams, lean_for_target

    body = BodyParams()
    left = body.waist + body.trunk_offsets()[4]
    target = left + np.array([0.0, 0.5 * body.arm_length, 0.0])
    assert lean_for_target(body, "left", target, 0.0) == 0.0
    assert lean_for_target(body, "right", target, 0.0, max_pitch=0.6) == 0.6
    far = body.waist + np.array([2.0, 0.0, 0.0])
    assert lean_for_target(body, "left", far, 0.0, max_pitch=0.45) == 0.45


def test_a_leaning_reach_twists_the_reaching_shoulder_forward_and_ends_on_time() -> None:
    """A left reach with ``lean``: the trunk yaw turns the left shoulder ahead (larger x) of
    the right at the end of the move, and the right one for a right reach (positions from
    the plan, as the generator reads them); the plan ends when its last move does."""
    from iplanner_torch.data.kinematic_human import BodyParams, MotionPlan, plan_hand_move
    from iplanner_torch.data.skeleton import JOINT_INDEX

    for arm, ahead in (("left", "left_shoulder"), ("right", "right_shoulder")):
        plan = MotionPlan(body=BodyParams())
        side = 1.0 if arm == "left" else -1.0
        first = plan_hand_move(plan, arm, np.array([0.1, 0.3 * side, 0.05]), 0.5,
                               np.random.default_rng(0), lean=True)  # fmt: skip
        second = plan_hand_move(plan, arm, np.array([0.0, 0.2 * side, 0.1]), first.t1 + 0.2,
                                np.random.default_rng(1), lean=True)  # fmt: skip
        assert plan.end_time == second.t1 == second.t0 + second.duration
        pose = plan.positions(np.array([first.t1]))[0]
        other = "right_shoulder" if ahead == "left_shoulder" else "left_shoulder"
        assert pose[JOINT_INDEX[ahead], 0] > pose[JOINT_INDEX[other], 0], arm
