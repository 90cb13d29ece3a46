"""The smoothness breakdown against a trajectory whose accelerations are known in closed form."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.eval.smoothness import (
    PlanRecord,
    episode_breakdown,
    plan_changes,
    smoothness_breakdown,
    wait_windows,
)

H = 0.04  # sample period [s]
A = 2.0  # acceleration of joint 0 on [2, 3] s [rad/s^2]


def _executed() -> tuple[np.ndarray, np.ndarray]:
    """(T,), (T, 2): joint 0 accelerates at A on [2, 3] s and moves at constant speed or rests
    elsewhere (C1), joint 1 rests; 10 s in all."""
    t = np.round(np.arange(0.0, 10.0 + H / 2, H), 10)
    q0 = np.where(
        t < 2.0, 0.0, np.where(t <= 3.0, 0.5 * A * (t - 2.0) ** 2, 0.5 * A + A * (t - 3.0))
    )
    return t, np.stack([q0, np.zeros_like(t)], axis=1)


def _plan(t0: float, t1: float, acc: float, wait_s: float) -> PlanRecord:
    times = np.linspace(t0, t1, 16)
    q0 = 0.5 * acc * (times - t0) ** 2  # the three-point formula is exact on a quadratic
    return PlanRecord(times=times, q=np.stack([q0, np.zeros_like(q0)], 1), wait_s=wait_s)


PLANS = [_plan(0.0, 3.0, 1.0, 0.0), _plan(2.0, 4.0, 0.0, 0.5), _plan(2.5, 5.0, 3.0, 0.0)]


def test_wait_windows() -> None:
    assert wait_windows(PLANS, 1.0) == [(2.0, 3.5)]
    assert wait_windows(PLANS, 0.0) == [(2.0, 2.5)]
    # a wait with no plan after it lasts to its own end
    assert wait_windows(PLANS[:2], 0.5) == [(2.0, 4.5)]
    assert wait_windows([PLANS[0]]) == []
    with pytest.raises(ConfigError, match="settle_s"):
        wait_windows(PLANS, -1.0)


def test_breakdown_against_closed_form() -> None:
    t, q = _executed()
    b = smoothness_breakdown(t, q, PLANS, settle_s=1.0)
    # int qdd^2 = A^2 * 1 s over the interior samples' 10 - H seconds; the two kink samples
    # (t = 2, 3) see A / 2 from the three-point formula, each standing for H seconds
    # (the interior samples stand for the whole 10 s, the end ones for half a period more)
    exact = (A * A * (1.0 - H) + 2 * (A / 2) ** 2 * H) / 10.0
    assert b.smoothness == pytest.approx(exact, rel=1e-9)
    assert b.waits == 1
    # the acceleration lies inside the wait window [2, 3.5] s: all of it is the wait's
    assert b.wait_share == pytest.approx(1.0)
    assert b.smoothness_outside == pytest.approx(0.0, abs=1e-9)
    # the 38 samples 2.00, 2.04, ..., 3.48 s lie in the window [2, 3.5] s
    assert b.wait_time_share == pytest.approx(38 * H / 10.0, rel=1e-9)
    # plans: A's waypoints before 2.0 s (acc 1), B's before 2.5 s (0), all of C's (acc 3)
    assert b.plan_executed == pytest.approx((1.0 + 0.0 + 9.0) / 3, rel=1e-9)


def test_breakdown_outside_waits() -> None:
    t, q = _executed()
    late = [PlanRecord(times=p.times + 5.0, q=p.q, wait_s=p.wait_s) for p in PLANS]
    b = smoothness_breakdown(t, q, late, settle_s=1.0)  # window [7, 8.5] s: no acceleration
    assert b.wait_share == pytest.approx(0.0)
    # the 38 samples 7.00, 7.04, ..., 8.48 s lie in the window; the whole integral lies
    # outside it, over the other 10 - 38 H seconds
    exact = (A * A * (1.0 - H) + 2 * (A / 2) ** 2 * H) / 10.0
    assert b.wait_time_share == pytest.approx(38 * H / 10.0, rel=1e-9)
    assert b.smoothness_outside == pytest.approx(exact * 10.0 / (10.0 - 38 * H), rel=1e-9)


def test_breakdown_errors() -> None:
    t, q = _executed()
    bad = PlanRecord(times=np.linspace(0, 1, 5), q=np.zeros((5, 3)), wait_s=0.0)
    with pytest.raises(ShapeError, match="plan 0"):
        smoothness_breakdown(t, q, [bad])


def _write_log(path: Path, plans: list[PlanRecord], bounds_of: tuple[int, ...] = ()) -> None:
    """An episode log of :func:`_executed` with ``plans``, each logged at its take-over, and
    for the plans ``bounds_of`` a bound rising to the plan's ``max_bound`` at confidence 0.95."""
    from iplanner_torch.recording import EpisodeWriter

    t, q = _executed()
    with EpisodeWriter(path, metadata={"planner": "test"}) as log:
        k = 0
        for i in range(t.shape[0]):
            while k < len(plans) and plans[k].times[0] <= t[i] + 1e-9:
                p = plans[k]
                log.plan(float(t[i]), p.times, p.q, True, p.wait_s, 1.0)
                if k in bounds_of:
                    bound = np.linspace(0.0, p.max_bound, p.times.shape[0])
                    log.collision_bound(float(t[i]), p.times, bound, 0.95)
                k += 1
            log.robot_state(float(t[i]), q[i], np.zeros(2), ["a", "b"])


def test_episode_breakdown_reads_a_log(tmp_path: Path) -> None:
    from iplanner_torch.recording import read_episode

    t, q = _executed()
    path = tmp_path / "ep.mcap"
    _write_log(path, PLANS)
    b = episode_breakdown(read_episode(path))
    assert b == smoothness_breakdown(t, q, PLANS)

    class NoPlans:
        frames: dict = {}

        def robot_q(self):
            return torch.as_tensor(t), torch.as_tensor(q)

    with pytest.raises(DataError, match="plan"):
        episode_breakdown(NoPlans())


def test_breakdown_script_groups_by_swept_speed(tmp_path: Path) -> None:
    """scripts/smoothness_breakdown.py: one row per scenario, speed (it varies) and planner,
    the means of the episodes' breakdowns."""
    import subprocess
    import sys

    from iplanner_torch.recording import EpisodeWriter

    t, q = _executed()
    expected = {}
    for speed, scale in (("slow", 1.0), ("fast", 2.0)):
        for seed in (0, 1):
            meta = {"scenario": "s1", "planner": "itomp", "speed": speed, "seed": seed}
            with EpisodeWriter(tmp_path / f"{speed}_{seed}.mcap", metadata=meta) as log:
                for p in PLANS:
                    log.plan(float(p.times[0]), p.times, p.q, True, p.wait_s, 1.0)
                for i in range(t.shape[0]):
                    log.robot_state(float(t[i]), scale * q[i], np.zeros(2), ["a", "b"])
            expected[speed] = smoothness_breakdown(t, scale * q, PLANS).smoothness
    script = Path(__file__).resolve().parents[2] / "scripts" / "smoothness_breakdown.py"
    res = subprocess.run(
        [sys.executable, str(script), str(tmp_path)], capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr
    rows = [ln.split("|")[1:-1] for ln in res.stdout.splitlines() if ln.startswith("| s1")]
    got = {r[1].strip(): (r[2].strip(), int(r[3]), float(r[4])) for r in rows}
    assert set(got) == {"slow", "fast"}
    for speed, (planner, episodes, smooth) in got.items():
        assert planner == "itomp" and episodes == 2
        assert smooth == pytest.approx(expected[speed], rel=2e-3)  # 3 significant digits
    assert expected["fast"] == pytest.approx(4 * expected["slow"])
    # a log with its robot states lost (cut before them) is left out and named; the rest stay
    with EpisodeWriter(tmp_path / "cut.mcap", metadata={"scenario": "s1", "planner": "itomp"}):
        pass
    res = subprocess.run(
        [sys.executable, str(script), str(tmp_path)], capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr
    assert "skipped " in res.stderr and "cut.mcap" in res.stderr
    assert sum(ln.startswith("| s1") for ln in res.stdout.splitlines()) == 2
    res = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "none")], capture_output=True, text=True
    )
    assert res.returncode == 2 and res.stderr.startswith("error: no *.mcap episode logs")


def test_plan_records_take_lists_and_check_their_fields() -> None:
    """Lists raised AttributeError in smoothness_breakdown; empty times an IndexError in
    wait_windows; settle_s = 'a' a TypeError."""
    p = PLANS[1]
    listed = PlanRecord(times=p.times.tolist(), q=p.q.tolist(), wait_s=p.wait_s)
    assert isinstance(listed.times, np.ndarray) and isinstance(listed.q, np.ndarray)
    t, q = _executed()
    assert smoothness_breakdown(t, q, [PLANS[0], listed, PLANS[2]]) == smoothness_breakdown(
        t, q, PLANS
    )
    with pytest.raises(ShapeError, match=r"expected plan times \(W,\) with W >= 1"):
        PlanRecord(times=np.zeros(0), q=np.zeros((0, 2)), wait_s=0.5)
    with pytest.raises(ShapeError, match="expected times an array of real numbers"):
        PlanRecord(times=[0.0, "a"], q=np.zeros((2, 2)), wait_s=0.0)
    with pytest.raises(ShapeError, match="expected q an array of real numbers"):
        PlanRecord(times=[0.0, 1.0], q=[[0.0, 1.0], [0.0]], wait_s=0.0)
    with pytest.raises(DataError, match="expected wait_s a finite number"):
        PlanRecord(times=[0.0, 1.0], q=np.zeros((2, 2)), wait_s=float("nan"))
    for settle in ("a", None, float("nan")):
        with pytest.raises(ConfigError, match="expected settle_s >= 0"):
            wait_windows(PLANS, settle)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("times", "plan", "message"),
    [
        ([0.0, 0.1], True, "expected at least 3 robot states in the log, got 2"),
        ([0.0, 0.1, 0.2], False, "the log has no /planner/plan messages"),
        ([0.0, 0.1, 0.1, 0.2], True, "expected strictly increasing"),
    ],
)
def test_episode_breakdown_names_the_log_it_cannot_split(
    tmp_path: Path, times: list[float], plan: bool, message: str
) -> None:
    from iplanner_torch.recording import EpisodeWriter, read_episode

    path = tmp_path / "ep 1.mcap"
    with EpisodeWriter(path, metadata={"planner": "test"}) as log:
        if plan:
            log.plan(0.0, np.array([0.0, 1.0]), np.zeros((2, 2)), True, 0.0, 1.0)
        for t in times:
            log.robot_state(t, np.zeros(2), np.zeros(2), ["a", "b"])
    with pytest.raises(DataError, match=f"^{re.escape(str(path))}: {message}"):
        episode_breakdown(read_episode(path))


def _line(t0: float, t1: float, slope: float, offset: float) -> PlanRecord:
    """Joint 0 at ``offset + slope t`` (linear: interpolation is exact), joint 1 at rest."""
    times = np.linspace(t0, t1, 11)
    return PlanRecord(
        times=times, q=np.stack([offset + slope * times, np.zeros(11)], 1), wait_s=0.0
    )


def test_plan_changes_against_closed_form() -> None:
    """Successive plans q = t on [0, 2], t + 0.1 on [1, 3], 2 t on [2.5, 4], then one on
    [5, 6] that overlaps nothing: the second moves the path by 0.1 everywhere, the third by
    |2 t - (t + 0.1)| = t - 0.1 at its waypoints in [2.5, 3] (0.15 s apart), at most 2.85
    at t = 2.95; the last is left out."""
    plans = [_line(0.0, 2.0, 1.0, 0.0), _line(1.0, 3.0, 1.0, 0.1), _line(2.5, 4.0, 2.0, 0.0),
             _line(5.0, 6.0, 0.0, 7.0)]  # fmt: skip
    np.testing.assert_allclose(plan_changes(plans), [0.1, 2.85], rtol=1e-12)
    t, q = _executed()
    b = smoothness_breakdown(t, q, plans, settle_s=1.0)
    assert b.plan_change == pytest.approx(1.475, rel=1e-12)  # the median of 0.1 and 2.85
    assert np.isnan(smoothness_breakdown(t, q, [plans[0], plans[3]]).plan_change)
    assert plan_changes(plans[:1]).shape == (0,)
    three = PlanRecord(times=np.linspace(0.5, 1.0, 3), q=np.zeros((3, 3)), wait_s=0.0)
    with pytest.raises(ShapeError, match=r"plans 0 and 1: expected q \(W, J\) with one J"):
        plan_changes([plans[0], three])


def _with_bounds(plans: list[PlanRecord], max_bounds: list[float]) -> list[PlanRecord]:
    return [
        PlanRecord(times=p.times, q=p.q, wait_s=p.wait_s, max_bound=b, limit=0.05)
        for p, b in zip(plans, max_bounds, strict=True)
    ]


def test_near_limit_share_against_closed_form() -> None:
    """Plans A and C pass a tenth of the limit (0.005), B does not: the windows are A's run
    [0, 2) s and C's [2.5, 5) s (its own end, no plan after it)."""
    from iplanner_torch.eval.smoothness import near_limit_windows

    plans = _with_bounds(PLANS, [0.03, 1e-4, 0.01])
    assert near_limit_windows(plans, 0.1) == [(0.0, 2.0), (2.5, 5.0)]
    assert near_limit_windows(plans, 0.5) == [(0.0, 2.0)]
    assert near_limit_windows(PLANS) is None  # no bounds known
    t, q = _executed()
    b = smoothness_breakdown(t, q, plans)
    # the 12 samples 2.52, ..., 2.96 s at A and the kink at 3.00 s at A / 2 of the 24 at A
    # and two kinks in all, each standing for H seconds
    assert b.near_limit_share == pytest.approx((12 + 0.25) / (24 + 0.5), rel=1e-9)
    # samples 0.04, ..., 1.96 s (49, the first standing for 1.5 H) and 2.52, ..., 4.96 s (62)
    assert b.near_limit_time_share == pytest.approx((49.5 + 62) * H / 10.0, rel=1e-9)
    none = smoothness_breakdown(t, q, PLANS)
    assert np.isnan(none.near_limit_share) and np.isnan(none.near_limit_time_share)
    assert smoothness_breakdown(t, q, plans, near_fraction=1.0).near_limit_share == 0.0
    with pytest.raises(ConfigError, match="near_fraction"):
        smoothness_breakdown(t, q, plans, near_fraction=0.0)
    with pytest.raises(DataError, match="max_bound"):
        PlanRecord(times=[0.0], q=[[0.0]], wait_s=0.0, max_bound="high")


def test_episode_breakdown_reads_the_bounds(tmp_path: Path) -> None:
    """Each plan's largest bound and limit come from the bound message with its waypoint
    times; a plan without one has none."""
    from iplanner_torch.recording import read_episode

    t, q = _executed()
    path = tmp_path / "ep.mcap"
    _write_log(path, _with_bounds(PLANS, [0.03, 1e-4, 0.01]), bounds_of=(0, 2))  # not B's
    b = episode_breakdown(read_episode(path))
    expected = _with_bounds(PLANS, [0.03, float("nan"), 0.01])
    assert b == smoothness_breakdown(t, q, expected)
    assert b.near_limit_share == pytest.approx((12 + 0.25) / (24 + 0.5), rel=1e-9)


def test_plan_executed_counts_only_the_waypoints_run_before_the_take_over() -> None:
    """A plan q = t^3 on t = 0..4 (1 s apart) replaced at t = 2 runs its interior waypoint
    t = 1 only: acceleration (q(2) - 2 q(1) + q(0)) / 1 = 6, squared 36; the plan after it
    rests (0). Counting the waypoint at the take-over too (t = 2: 12, squared 144) gave 45."""
    times = np.arange(5.0)
    cubic = PlanRecord(times=times, q=np.stack([times**3, np.zeros(5)], 1), wait_s=0.0)
    rest = PlanRecord(times=np.array([2.0, 3.0, 4.0]), q=np.full((3, 2), 8.0), wait_s=0.0)
    t, q = _executed()
    b = smoothness_breakdown(t, q, [cubic, rest])
    assert b.plan_executed == pytest.approx((36.0 + 0.0) / 2, rel=1e-12)


def test_plan_change_is_the_median_not_the_mean() -> None:
    """Changes 0.1, 0.2 and 7.6 (q = t, t + 0.1, t + 0.3, then 3 t whose waypoints in the
    previous span reach t = 3.95: 3 t - (t + 0.3) = 7.6): one plan far off does not set the
    typical change, 0.2 (the mean would be 2.63)."""
    plans = [_line(0.0, 2.0, 1.0, 0.0), _line(1.0, 3.0, 1.0, 0.1), _line(2.5, 4.0, 1.0, 0.3),
             _line(3.5, 5.0, 3.0, 0.0)]  # fmt: skip
    np.testing.assert_allclose(plan_changes(plans), [0.1, 0.2, 7.6], rtol=1e-12)
    t, q = _executed()
    assert smoothness_breakdown(t, q, plans).plan_change == pytest.approx(0.2, rel=1e-12)


def test_a_sample_at_the_wait_windows_end_is_inside_it() -> None:
    """The wait window of PLANS is [2.0, 3.5] s (B waits from 2.0 s, C does not and takes
    over at 2.5 s, + 1 s settle), ends included. q = max(0, t - 3.5) on t = 0, 0.5, ..., 10:
    the three-point second difference is 0 everywhere but at t = 3.5 s, 2 (0 / 0.5 before,
    0.5 / 0.5 after, over 1 s), so all of the integral is the wait's; the interior samples
    2.0, 2.5, 3.0 and 3.5 s (0.5 s each) make 2 s of the 10."""
    t = np.arange(21) * 0.5
    q = np.stack([np.maximum(0.0, t - 3.5), np.zeros_like(t)], 1)
    b = smoothness_breakdown(t, q, PLANS, settle_s=1.0)
    assert b.smoothness == pytest.approx(2.0**2 * 0.5 / 10.0, rel=1e-12)
    assert b.wait_share == 1.0
    assert b.wait_time_share == pytest.approx(4 * 0.5 / 10.0, rel=1e-12)


def test_a_bound_equal_to_the_threshold_is_not_near_the_limit() -> None:
    """A plan is near the limit when its bound exceeds near_fraction * limit: with limit 0.5
    and near_fraction 0.5 (threshold 0.25, all binary-exact) a plan at 0.25 is not near, one
    at 0.25 + 2^-10 is (its run from 2.5 s to its own last waypoint, 5 s)."""
    from iplanner_torch.eval.smoothness import near_limit_windows

    def bounded(bound_b: float, bound_c: float) -> list[PlanRecord]:
        return [
            PlanRecord(times=p.times, q=p.q, wait_s=p.wait_s, max_bound=b, limit=0.5)
            for p, b in zip(PLANS, [0.0, bound_b, bound_c], strict=True)
        ]

    assert near_limit_windows(bounded(0.25, 0.25), 0.5) == []
    assert near_limit_windows(bounded(0.25, 0.25 + 2**-10), 0.5) == [(2.5, 5.0)]
    t, q = _executed()
    b = smoothness_breakdown(t, q, bounded(0.25, 0.25), near_fraction=0.5)
    assert b.near_limit_time_share == 0.0 and b.near_limit_share == 0.0
