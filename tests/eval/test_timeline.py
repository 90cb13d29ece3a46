"""Episode timelines: the series read out of a log against the values written into it, the
sphere distances against a brute-force loop, the figure, and the script for logs on disk."""

from __future__ import annotations

import importlib.util
import math
import sys
import warnings
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from foreign_mcap import write_foreign_mcap

from iplanner_torch.errors import DataError
from iplanner_torch.eval.timeline import (
    closest_gaps,
    episode_timeline,
    plot_episode_timeline,
    timeline_path,
)
from iplanner_torch.recording import EpisodeWriter

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"
ACTIONS = ["idle", "take_0", "take_1"]


def _brute_gap(robot: np.ndarray, human: np.ndarray) -> float:
    best = math.inf
    for r in robot:
        for h in human:
            if not (np.isfinite(r).all() and np.isfinite(h).all()):
                continue
            d = math.sqrt(sum((float(r[i]) - float(h[i])) ** 2 for i in range(3)))
            best = min(best, d - float(r[3]) - float(h[3]))
    return best if best < math.inf else math.nan


def test_closest_gaps_match_a_loop_over_all_pairs() -> None:
    rng = np.random.default_rng(3)
    robot = np.concatenate([rng.normal(size=(6, 5, 3)), rng.uniform(0.01, 0.3, (6, 5, 1))], -1)
    human = np.concatenate([rng.normal(size=(6, 4, 3)), rng.uniform(0.01, 0.3, (6, 4, 1))], -1)
    robot[1, 2] = np.nan  # a sphere dropped in one frame
    human[4, :] = np.nan  # no person sphere at all in another
    got = closest_gaps(robot, human)
    want = [_brute_gap(robot[t], human[t]) for t in range(6)]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert np.isnan(got[4]) and np.isfinite(got[1])
    # overlapping spheres give a negative gap
    two = np.array([[[0.0, 0.0, 0.0, 0.2]]])
    assert closest_gaps(two, two + np.array([0.1, 0.0, 0.0, 0.0]))[0] == pytest.approx(-0.3)
    with pytest.raises(DataError, match=r"\(T, S, 4\)"):
        closest_gaps(np.zeros((2, 3, 3)), np.zeros((2, 3, 4)))
    with pytest.raises(DataError, match="as many robot as human frames"):
        closest_gaps(np.zeros((2, 3, 4)), np.zeros((3, 3, 4)))


def _write(
    path: Path,
    planner: str = "iplanner_ni",
    forecasts: bool = True,
    actions: list[str] = ACTIONS,
    metrics: dict | None = None,
    scenario: str = "s1",
) -> dict:
    """A short log with known values (forecasts over ``actions``; ``metrics`` as the
    episode's metrics message, none when None); returns them."""
    meta = {"scenario": scenario, "planner": planner, "speed": "medium", "noise": 0.02, "seed": 4}
    t_robot = np.round(np.arange(0.0, 3.0 + 1e-9, 0.1), 10)
    qd = np.stack([np.sin(t_robot), np.cos(t_robot), 0.5 * t_robot], 1)  # (T, 3)
    plans = [  # t, feasible, wait_s, bound per waypoint, confidence
        (0.0, True, 0.0, [1e-4, 3e-3, 0.0], 0.95),
        (0.5, False, 0.4, [0.2, 0.01, 0.05], 0.95),
        (1.0, True, 0.0, [1e-30, 2e-7, 1e-8], 0.99),
    ]
    events = [
        (0.2, "fetch_started", {"block": 0}),
        (0.8, "picked", {"block": 0}),
        (1.1, "human_take_started", {"block": 1}),
        (1.6, "delivered", {"block": 0}),
        (2.2, "human_took", {"block": 1}),
        (2.5, "human_take_started", {"block": 0}),  # not finished when the log ends
    ]
    weights = [[1.0, 0.0, 0.0], [0.2, 0.1, 0.7], [0.0, 0.9, 0.1]]
    if actions != ACTIONS:
        weights = np.random.default_rng(0).dirichlet(np.ones(len(actions)), 3).tolist()
    with EpisodeWriter(path, metadata=meta) as log:
        for i, t in enumerate(t_robot):
            log.robot_state(float(t), np.zeros(3), qd[i], ["a", "b", "c"])
            if i % 5 == 0:
                robot = np.array([[0.0, 0.0, 0.1 * t, 0.05], [0.3, 0.0, 0.0, 0.05]])
                human = np.array([[0.5, 0.0, 0.0, 0.1], [0.0, 0.4, 0.3 * t, 0.1]])
                log.scene(float(t), robot, human)
        for t, feasible, wait_s, bound, conf in plans:
            times = t + np.array([0.0, 0.5, 1.0])
            log.plan(t, times, np.zeros((3, 3)), feasible, wait_s, 10.0)
            log.collision_bound(t, times, np.array(bound), conf)
        if forecasts:
            for k, w in enumerate(weights):
                mean = np.zeros((len(actions), 2, 2, 3))
                log.forecast(0.5 * k, np.array(w), mean, np.ones_like(mean) * 1e-3, actions, 0.1)
        for t, kind, detail in events:
            log.task_event(t, kind, detail)
        if metrics is not None:
            log.metrics(3.0, metrics)
    return {"t_robot": t_robot, "qd": qd, "plans": plans, "weights": weights, "meta": meta}


def test_the_timeline_holds_what_the_log_was_given(tmp_path: Path) -> None:
    path = tmp_path / "ep.mcap"
    given = _write(path)
    tl = episode_timeline(path)
    np.testing.assert_allclose(tl.robot_t, given["t_robot"])
    np.testing.assert_allclose(tl.speed, np.linalg.norm(given["qd"], axis=1), rtol=1e-12)
    np.testing.assert_allclose(tl.plan_t, [0.0, 0.5, 1.0])
    np.testing.assert_allclose(tl.max_bound, [3e-3, 0.2, 2e-7])  # NaN waypoint left out
    np.testing.assert_allclose(tl.limit, [0.05, 0.05, 0.01], rtol=1e-12)
    assert tl.feasible.tolist() == [True, False, True]
    assert tl.waits == [(0.5, pytest.approx(0.9))]
    assert tl.action_names == tuple(ACTIONS)
    np.testing.assert_allclose(tl.weights, given["weights"])
    np.testing.assert_allclose(tl.forecast_t, [0.0, 0.5, 1.0])
    assert tl.reaches[0] == (1.1, 2.2, "take_1")
    assert tl.reaches[1][0] == 2.5 and math.isnan(tl.reaches[1][1])
    assert tl.robot_events == [(0.8, "picked", 0), (1.6, "delivered", 0)]
    # the scene's sphere gap, computed here by hand for t = 0 (robot sphere 2 at x 0.3 and
    # the person's sphere 1 at x 0.5: 0.2 - 0.05 - 0.1) and t = 0.5
    assert tl.gap_m[0] == pytest.approx(0.05)
    assert tl.gap_m[1] == pytest.approx(
        min(
            0.2 - 0.15,
            math.dist((0.0, 0.0, 0.05), (0.0, 0.4, 0.15)) - 0.15,
        )
    )
    assert tl.end_t == pytest.approx(3.0)
    # the planner as the tables name it, and the tracker noise the file name carries
    assert tl.title == "I-Planner, NI · s1 · medium speed · noise 2 cm · seed 4"
    assert tl.scenario == "s1"
    assert tl.complete and not tl.notes


def test_the_figure_is_drawn_and_itomp_says_why_it_has_no_forecasts(tmp_path: Path) -> None:
    path = tmp_path / "ep.mcap"
    _write(path, planner="itomp", forecasts=False)
    tl = episode_timeline(path)
    assert tl.forecast_t.size == 0 and tl.notes == ["no forecasts: itomp has no predictor"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = plot_episode_timeline(tl, tmp_path / "plots" / "ep.png")
    img = matplotlib.image.imread(out)
    assert img.shape[0] >= 700 and img.shape[1] >= 800 and img[..., :3].std() > 0.05
    assert timeline_path(path) == tmp_path / "ep.png"


def _figures(monkeypatch: pytest.MonkeyPatch) -> list:
    """The Figures the timeline module makes from now on."""
    import iplanner_torch.eval.timeline as timeline

    made = []

    class Recorded(timeline.Figure):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(timeline, "Figure", Recorded)
    return made


def test_the_distance_panel_names_the_episodes_own_minimum(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The panel marked "least 11.7 cm at 3.6 s (scene samples)" while the run's table said
    10.9 cm (eval/min_distance, at the metric samples): both are now named, apart."""
    figures = _figures(monkeypatch)
    path = tmp_path / "ep.mcap"
    _write(path, metrics={"eval/min_distance": 0.031, "eval/smoothness": 1.0})
    tl = episode_timeline(path)
    assert tl.min_distance_m == pytest.approx(0.031)
    plot_episode_timeline(tl, tmp_path / "ep.png")
    dist = figures[-1].axes[0]
    texts = [t.get_text() for t in dist.get_legend().get_texts()]
    i = int(np.nanargmin(tl.gap_m))
    least = f"least sampled {100 * tl.gap_m[i]:.1f} cm at {tl.scene_t[i]:.1f} s"
    assert least in texts
    assert "closest distance (scene samples, every 0.5 s)" in texts
    minimum = next(t for t in texts if t.startswith("episode minimum"))
    assert minimum.startswith("episode minimum 3.1 cm") and "eval/min_distance" in minimum
    line = next(ln for ln in dist.get_lines() if ln.get_label() == minimum)
    assert line.get_ydata()[0] == pytest.approx(3.1)  # drawn where the metric says
    # a log without its metrics message (cut short) draws the samples alone
    bare = tmp_path / "bare.mcap"
    _write(bare)
    assert math.isnan(episode_timeline(bare).min_distance_m)
    plot_episode_timeline(bare, tmp_path / "bare.png")
    texts = [t.get_text() for t in figures[-1].axes[0].get_legend().get_texts()]
    assert not any(t.startswith("episode minimum") for t in texts)


def test_every_action_has_its_own_colour_and_legends_stand_beside_the_panels(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With the reaching predictor's ten actions `idle` and `return` had the same colour (nine
    colours, by index modulo nine); the collision bound's legend covered plans near the
    floor."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import to_hex

    from iplanner_torch.eval.timeline import action_colours

    figures = _figures(monkeypatch)
    actions = ["idle", *(f"reach_{i}" for i in range(8)), "return"]
    path = tmp_path / "ep.mcap"
    _write(path, actions=actions)
    plot_episode_timeline(path, tmp_path / "ep.png")
    fig = figures[-1]
    dist, bound, act, _ = fig.axes
    colours = {ln.get_label(): to_hex(ln.get_color()) for ln in act.get_lines()}
    assert set(actions) <= set(colours)
    assert len({colours[a] for a in actions}) == len(actions)
    assert to_hex("tab:red") not in {colours[a] for a in actions}  # red is the waits'
    for n in (3, 10, 18, 30):
        assert len({to_hex(c) for c in action_colours(n)}) == n
    renderer = FigureCanvasAgg(fig).get_renderer()
    for ax in (dist, bound, act):
        legend = ax.get_legend()
        assert legend is not None
        box, area = legend.get_window_extent(renderer), ax.get_window_extent(renderer)
        assert box.x0 >= area.x1 and box.x1 <= fig.bbox.x1 + 1  # beside it, in the figure


def test_logs_with_nothing_to_draw_are_refused(tmp_path: Path) -> None:
    full = tmp_path / "ep.mcap"
    _write(full)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[:200])  # before the first chunk closes
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(DataError, match="nothing|no robot, scene, plan or forecast"):
            episode_timeline(cut)
    foreign = write_foreign_mcap(tmp_path / "other.mcap")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(DataError, match="not an episode log"):
            plot_episode_timeline(foreign, tmp_path / "other.png")
    assert not (tmp_path / "other.png").exists()


def test_a_log_cut_short_is_drawn_as_far_as_it_goes(tmp_path: Path) -> None:
    full = tmp_path / "ep.mcap"
    with EpisodeWriter(full, metadata={"planner": "iplanner_ni"}, chunk_size=512) as log:
        for i in range(200):
            log.robot_state(0.04 * i, np.zeros(2), np.ones(2) * i, ["a", "b"])
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 4])  # within the data section
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tl = episode_timeline(cut)
    assert not tl.complete and 0 < tl.robot_t.size < 200
    np.testing.assert_allclose(tl.speed, np.sqrt(2) * np.arange(tl.robot_t.size), rtol=1e-12)
    plot_episode_timeline(tl, tmp_path / "cut.png")
    assert (tmp_path / "cut.png").stat().st_size > 0


def test_an_interrupted_episode_says_where_it_stopped(tmp_path: Path) -> None:
    """A whole log whose episode was stopped by Ctrl-C: its title names the stop."""
    path = tmp_path / "stopped.mcap"
    with pytest.raises(KeyboardInterrupt):
        with EpisodeWriter(path, metadata={"planner": "itomp", "seed": 1}) as log:
            for i in range(30):
                log.robot_state(0.1 * i, np.zeros(2), np.ones(2), ["a", "b"])
            raise KeyboardInterrupt
    tl = episode_timeline(path)
    assert tl.complete and tl.title == "ITOMP · seed 1  (interrupted at t = 2.9 s: no metrics)"
    _write(tmp_path / "whole.mcap")
    assert "interrupted" not in episode_timeline(tmp_path / "whole.mcap").title


def _script():
    sys.path.insert(0, str(SCRIPTS))
    try:
        spec = importlib.util.spec_from_file_location("plot_episode", SCRIPTS / "plot_episode.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
        return mod
    finally:
        sys.path.remove(str(SCRIPTS))


def test_the_script_draws_beside_the_logs_and_keeps_what_exists(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    run = tmp_path / "run" / "episodes"
    run.mkdir(parents=True)
    _write(run / "a.mcap")
    _write(run / "b.mcap", planner="itomp", forecasts=False)
    (run / "notes.mcap").write_text("version https://git-lfs.github.com/spec/v1\n")
    main = _script().main
    monkeypatch.setattr(sys, "argv", ["plot_episode.py", str(tmp_path / "run")])
    main()
    out = capsys.readouterr()
    assert (run / "a.png").is_file() and (run / "b.png").is_file()
    assert "left out 1" in out.err and "notes.mcap" in out.err
    before = (run / "a.png").read_bytes()
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2 and "--force" in capsys.readouterr().err
    assert (run / "a.png").read_bytes() == before
    monkeypatch.setattr(sys, "argv", ["plot_episode.py", str(run / "notes.mcap")])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2 and "no timeline plot drawn" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:.*not an iplanner episode log")
def test_the_experiment_draws_each_log_and_names_those_it_cannot(tmp_path: Path) -> None:
    from iplanner_torch.cli.experiment import write_timelines
    from iplanner_torch.errors import DataWarning

    _write(tmp_path / "a.mcap")
    write_foreign_mcap(tmp_path / "b.mcap")
    with pytest.warns(DataWarning, match=r"no timeline plot for 1 log\(s\): b.mcap"):
        written = write_timelines(sorted(tmp_path.glob("*.mcap")), progress=False)
    assert written == [tmp_path / "a.png"] and not (tmp_path / "b.png").exists()


def test_shared_axes_hold_every_timeline(tmp_path: Path) -> None:
    """The common ranges against the series' own extremes, found here with plain max/min."""
    from dataclasses import replace

    from iplanner_torch.eval.timeline import SharedAxes, shared_axes

    _write(tmp_path / "a.mcap", metrics={"eval/min_distance": 0.031})
    a = episode_timeline(tmp_path / "a.mcap")
    b = replace(
        a,
        speed=np.append(3.0 * a.speed, np.nan),
        robot_t=np.append(a.robot_t, 3.1),
        gap_m=np.append(a.gap_m + 0.4, [np.nan, np.inf]),
        min_distance_m=float("nan"),
        end_t=7.0,
    )
    axes = shared_axes([a, b])
    top = max(float(np.nanmax(a.speed)), float(np.nanmax(3.0 * a.speed)))
    assert axes.speed == pytest.approx(1.05 * top)
    values = [100.0 * g for g in list(a.gap_m) + list(a.gap_m + 0.4) + [0.031]]
    lo, hi = min(values + [0.0]), max(values + [0.0])
    assert lo == 0.0  # every gap is positive here: 0 (touching) is held all the same
    pad = 0.05 * (hi - lo)
    assert axes.distance_cm == pytest.approx((lo - pad, hi + pad))
    assert axes.end_t == 7.0
    # an overlap below 0 is held too
    c = replace(a, gap_m=np.array([-0.02, 0.5]), min_distance_m=-0.03)
    assert shared_axes([c]).distance_cm == pytest.approx((-3.0 - 2.65, 50.0 + 2.65))
    # nothing finite to share: each figure's own ranges
    empty = replace(a, gap_m=np.zeros(0), speed=np.full(3, np.nan), min_distance_m=np.nan)
    assert shared_axes([empty]) == SharedAxes(end_t=a.end_t)
    assert shared_axes([]) == SharedAxes()
    # an arm that never moved: no speed range, one of 1 cm about a constant distance
    still = replace(a, gap_m=np.array([0.0]), speed=np.zeros(4), min_distance_m=np.nan)
    assert shared_axes([still]).speed is None
    assert shared_axes([still]).distance_cm == (-1.0, 1.0)


def test_the_figure_takes_the_shared_ranges(tmp_path: Path, monkeypatch) -> None:
    from iplanner_torch.errors import ConfigError
    from iplanner_torch.eval.timeline import SharedAxes

    figures = _figures(monkeypatch)
    _write(tmp_path / "a.mcap")
    tl = episode_timeline(tmp_path / "a.mcap")
    plot_episode_timeline(tl, tmp_path / "own.png")
    own = figures[-1].axes
    assert own[3].get_xlim() == pytest.approx((0.0, 3.0))
    axes = SharedAxes(end_t=7.5, distance_cm=(-4.0, 90.0), speed=6.0)
    plot_episode_timeline(tl, tmp_path / "shared.png", axes)
    dist, _, _, speed = figures[-1].axes
    assert dist.get_ylim() == pytest.approx((-4.0, 90.0))
    assert speed.get_ylim() == pytest.approx((0.0, 6.0))
    assert speed.get_xlim() == pytest.approx((0.0, 7.5))
    # a shared time axis shorter than the episode does not cut it
    plot_episode_timeline(tl, tmp_path / "short.png", SharedAxes(end_t=1.0))
    assert figures[-1].axes[3].get_xlim() == pytest.approx((0.0, 3.0))
    with pytest.raises(ConfigError, match="expected axes a SharedAxes or None, got dict"):
        plot_episode_timeline(tl, tmp_path / "bad.png", {"speed": 1.0})


def test_the_axes_are_shared_within_each_scenario(tmp_path: Path) -> None:
    from dataclasses import replace

    from iplanner_torch.eval.timeline import shared_axes, shared_axes_by_scenario

    _write(tmp_path / "a.mcap")
    a = episode_timeline(tmp_path / "a.mcap")
    b = replace(a, end_t=9.0, speed=2.0 * a.speed)
    c = replace(a, scenario="other", end_t=4.0)
    got = shared_axes_by_scenario([a, c, b])
    assert got[0] == got[2] == shared_axes([a, b]) and got[0].end_t == 9.0
    assert got[1] == shared_axes([c]) and got[1].end_t == 4.0
    assert shared_axes_by_scenario([]) == []


@pytest.mark.filterwarnings("ignore:.*not an iplanner episode log")
def test_the_experiments_figures_share_their_axes(tmp_path: Path, monkeypatch) -> None:
    """Every figure of a scenario gets the ranges of all its logs, drawn here or in workers;
    another scenario's logs have their own."""
    from concurrent.futures import ThreadPoolExecutor

    from iplanner_torch.cli.experiment import write_timelines
    from iplanner_torch.errors import DataWarning
    from iplanner_torch.eval.timeline import shared_axes

    figures = _figures(monkeypatch)
    _write(tmp_path / "a.mcap", metrics={"eval/min_distance": -0.01})
    _write(tmp_path / "b.mcap", planner="itomp", forecasts=False)
    write_foreign_mcap(tmp_path / "c.mcap")
    _write(tmp_path / "d.mcap", scenario="s2")
    logs = sorted(tmp_path.glob("*.mcap"))
    want = shared_axes(episode_timeline(p) for p in logs[:2])
    own = shared_axes([episode_timeline(logs[3])])
    assert own.distance_cm[0] > -1.0 > want.distance_cm[0]  # a's minimum is not s2's
    for executor in (None, ThreadPoolExecutor(2)):
        figures.clear()
        for png in tmp_path.glob("*.png"):  # drawn afresh each time (kept ones: the next test)
            png.unlink()
        with pytest.warns(DataWarning, match=r"no timeline plot for 1 log\(s\): c.mcap"):
            written = write_timelines(logs, progress=False, executor=executor)
        assert written == [tmp_path / f"{n}.png" for n in "abd"]
        assert len(figures) == 3
        by_title = {f._suptitle.get_text(): f for f in figures}
        for fig in figures:
            axes = own if "s2" in fig._suptitle.get_text() else want
            assert fig.axes[0].get_ylim() == pytest.approx(axes.distance_cm)
            assert fig.axes[3].get_ylim() == pytest.approx((0.0, axes.speed))
            assert fig.axes[3].get_xlim() == pytest.approx((0.0, axes.end_t))
        assert sum("s2" in t for t in by_title) == 1


def test_the_stamp_goes_into_the_png_and_back(tmp_path: Path) -> None:
    """What a figure was drawn from is read back from its PNG text, exactly; anything else
    (no stamp, another format, not a PNG, cut short, missing) reads as no stamp."""
    import json

    from iplanner_torch.eval.timeline import (
        STAMP_KEY,
        TIMELINE_FORMAT,
        SharedAxes,
        TimelineExtremes,
        TimelineStamp,
        log_fingerprint,
        read_timeline_stamp,
        shared_axes,
        timeline_extremes,
    )

    log = tmp_path / "a.mcap"
    _write(log, metrics={"eval/min_distance": 0.031})
    tl = episode_timeline(log)
    axes = SharedAxes(end_t=7.25, distance_cm=(-1.0 / 3.0, 90.1), speed=6.0)
    png = plot_episode_timeline(log, tmp_path / "a.png", axes)
    stamp = read_timeline_stamp(png)
    assert stamp == TimelineStamp(timeline_extremes(tl), axes, log_fingerprint(log))
    assert stamp.axes.distance_cm[0] == -1.0 / 3.0  # to the last bit
    assert stamp.source[0] == "a.mcap" and stamp.source[1] == log.stat().st_size
    # the extremes against the series, here with plain max/min
    gaps = [100.0 * g for g in tl.gap_m] + [3.1]
    assert stamp.extremes == TimelineExtremes(
        "s1", 3.0, (min(gaps), max(gaps)), float(max(tl.speed))
    )
    assert shared_axes([tl]) == shared_axes([tl, tl])
    # drawn from a Timeline: no source unless given
    assert read_timeline_stamp(plot_episode_timeline(tl, tmp_path / "t.png")).source is None
    got = read_timeline_stamp(plot_episode_timeline(tl, tmp_path / "u.png", source=log))
    assert got.source == log_fingerprint(log) and got.axes == SharedAxes()
    # a log that is not there: the read's DataError, no figure; a source gone since: no source
    with pytest.raises(DataError, match="no such episode log"):
        plot_episode_timeline(tmp_path / "gone.mcap", tmp_path / "gone.png")
    assert not (tmp_path / "gone.png").exists()
    got = plot_episode_timeline(tl, tmp_path / "v.png", source=tmp_path / "gone.mcap")
    assert read_timeline_stamp(got).source is None
    # not stamps
    raw = json.loads(stamp.to_json())
    assert TimelineStamp.from_json(json.dumps(raw)) == stamp
    for bad in (
        {**raw, "format": TIMELINE_FORMAT + 1},
        {**raw, "axes": {**raw["axes"], "speed": "fast"}},
        {**raw, "axes": {**raw["axes"], "distance_cm": [1.0]}},
        {**raw, "source": ["a.mcap", 1.5, 2]},
        {k: v for k, v in raw.items() if k != "extremes"},
    ):
        assert TimelineStamp.from_json(json.dumps(bad)) is None
    assert TimelineStamp.from_json("not json") is None
    assert TimelineStamp.from_json("[1, 2]") is None
    from matplotlib.figure import Figure

    fig = Figure()
    fig.savefig(tmp_path / "plain.png")
    assert read_timeline_stamp(tmp_path / "plain.png") is None
    fig.savefig(tmp_path / "other.png", metadata={STAMP_KEY: "{}"})
    assert read_timeline_stamp(tmp_path / "other.png") is None
    data = png.read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: data.index(STAMP_KEY.encode()) + 10])
    assert read_timeline_stamp(tmp_path / "cut.png") is None
    (tmp_path / "text.png").write_text("hello")
    assert read_timeline_stamp(tmp_path / "text.png") is None
    assert read_timeline_stamp(tmp_path / "missing.png") is None


def test_a_resumed_run_keeps_the_figures_whose_log_and_axes_did_not_change(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """write_timelines again over the same logs reads and draws nothing; a new log that
    widens its scenario's axes redraws that scenario's figures only; a log written again, a
    figure without a stamp and a damaged figure are drawn again."""
    import os

    import iplanner_torch.eval.timeline as timeline
    from iplanner_torch.cli.experiment import write_timelines
    from iplanner_torch.eval.timeline import read_timeline_stamp, shared_axes

    figures = _figures(monkeypatch)
    reads: list[str] = []
    real_read = timeline.episode_timeline

    def counted(episode):
        reads.append(Path(episode).name)
        return real_read(episode)

    monkeypatch.setattr(timeline, "episode_timeline", counted)

    def drawn() -> list[str]:
        """The titles of the figures drawn, and the logs read, since the last call."""
        names = sorted(f._suptitle.get_text() for f in figures) + sorted(reads)
        figures.clear()
        reads.clear()
        return names

    _write(tmp_path / "a.mcap")
    _write(tmp_path / "b.mcap", planner="itomp", forecasts=False)
    _write(tmp_path / "d.mcap", scenario="s2")
    logs = [tmp_path / f"{n}.mcap" for n in "abd"]
    pngs = [tmp_path / f"{n}.png" for n in "abd"]
    assert write_timelines(logs, progress=False) == pngs
    assert len(drawn()) == 6  # three read, three drawn
    before = {p: p.read_bytes() for p in pngs}
    # 1. nothing changed: nothing read, nothing drawn, every figure as it was
    assert write_timelines(logs, progress=False) == pngs
    assert drawn() == [] and all(p.read_bytes() == b for p, b in before.items())
    # 2. a new s1 episode that came closer: s1's three figures on the new axes, s2's kept
    _write(tmp_path / "c.mcap", metrics={"eval/min_distance": -0.2})
    logs.insert(2, tmp_path / "c.mcap")
    pngs.insert(2, tmp_path / "c.png")
    assert write_timelines(logs, progress=False) == pngs
    got = drawn()  # c read; a and b read again by plot_episode_timeline for the new axes
    assert sum("s1" in t for t in got) == 3 and got[3:] == ["a.mcap", "b.mcap", "c.mcap"]
    want = shared_axes(real_read(p) for p in logs[:3])
    assert want.distance_cm[0] < -20.0
    for p in pngs[:3]:
        assert read_timeline_stamp(p).axes == want
    assert pngs[3].read_bytes() == before[pngs[3]]
    # in workers the same: nothing left to do
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(2) as pool:
        assert write_timelines(logs, progress=False, executor=pool) == pngs
    assert drawn() == []
    # 3. a log written again (another modification time), a figure without a stamp, a
    # damaged figure: those three drawn, the fourth kept
    st = logs[0].stat()
    os.utime(logs[0], ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    from matplotlib.figure import Figure

    Figure().savefig(pngs[1])
    pngs[3].write_bytes(pngs[3].read_bytes()[:100])
    assert write_timelines(logs, progress=False) == pngs
    got = drawn()
    assert len(got) == 6 and got[3:] == ["a.mcap", "b.mcap", "d.mcap"]
    assert read_timeline_stamp(pngs[1]) is not None and read_timeline_stamp(pngs[3]) is not None
