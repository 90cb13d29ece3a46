import numpy as np
import pytest

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.eval.prediction_sweep import resample_speed


def _demo(t: int = 31) -> Demonstration:
    frames = np.arange(t, dtype=np.float32)
    clean = np.zeros((t, 2, 3), dtype=np.float32)
    clean[:, 0, 0] = 0.01 * frames  # linear in time
    clean[:, 1, 2] = 0.001 * frames**2  # quadratic in time
    return Demonstration(
        positions=clean + 0.5,
        clean_positions=clean,
        labels=(frames >= 15).astype(np.int64),
        fps=15.0,
        joint_names=("a", "b"),
        action_names=("idle", "move"),
        name="d",
    )


def test_resample_speed_matches_the_time_scaled_motion() -> None:
    demo = _demo()
    fast = resample_speed(demo, 2.0)
    assert fast.num_frames == 16
    k = np.arange(16, dtype=np.float64) * 2.0  # original frame index of each new frame
    np.testing.assert_allclose(fast.clean_positions[:, 0, 0], 0.01 * k, atol=1e-6)
    np.testing.assert_allclose(fast.clean_positions[:, 1, 2], 0.001 * k**2, atol=1e-6)
    # observed positions start as the clean motion (noise is added separately)
    np.testing.assert_array_equal(fast.positions, fast.clean_positions)
    np.testing.assert_array_equal(fast.labels, (k >= 15).astype(np.int64))
    slow = resample_speed(demo, 0.5)
    assert slow.num_frames == 61
    # between frames, linear interpolation of the quadratic: exact at even new frames
    np.testing.assert_allclose(slow.clean_positions[::2, 1, 2], demo.clean_positions[:, 1, 2])


def test_resample_speed_errors() -> None:
    with pytest.raises(ConfigError, match="speed factor"):
        resample_speed(_demo(), 0.0)
    demo = _demo()
    demo.clean_positions = None
    with pytest.raises(DataError, match="clean_positions"):
        resample_speed(demo, 2.0)


def test_noise_sweep_rows_noise_levels_and_shared_noise(monkeypatch, tmp_path) -> None:
    """One row per (predictor, noise, speed); each predictor sees the same noisy replay; at
    noise 0 the replay is the clean motion with nothing lost, above it the added noise has
    the asked standard deviation; the report holds every row."""
    import pandas as pd

    import iplanner_torch.eval.prediction as prediction_module
    from iplanner_torch.eval.prediction_sweep import prediction_vs_noise, write_noise_report

    seen: list[tuple[object, list[Demonstration]]] = []

    def spy(predictor, demos):
        seen.append((predictor, demos))
        err = np.concatenate([(d.positions - d.clean_positions).ravel() for d in demos])
        lost = np.isnan(err)
        return {
            "frames": sum(d.num_frames for d in demos),
            "lost_share": float(lost.mean()),
            "noise_std": float(err[~lost].std()),
        }

    monkeypatch.setattr(prediction_module, "evaluate_prediction", spy)
    demos = [_demo(3001), _demo(1801)]
    predictors = {"p1": object(), "p2": object()}
    df = prediction_vs_noise(
        predictors,
        demos,
        noises=(0.0, 0.02),
        speeds=("slow", "fast"),
        dropout_rate=0.05,
        seed=3,
        progress=False,
    )
    assert len(df) == 2 * 2 * 2
    combos = set(zip(df["predictor"], df["noise"], df["speed"], strict=True))
    assert combos == {(p, n, s) for p in predictors for n in (0.0, 0.02) for s in ("slow", "fast")}
    for (_, noise), g in df.groupby(["speed", "noise"]):
        assert len(g) == 2
        assert g["frames"].nunique() == 1 and g["noise_std"].nunique() == 1
        if noise == 0.0:
            assert (g["lost_share"] == 0.0).all() and (g["noise_std"] == 0.0).all()
        else:
            assert g["noise_std"].iloc[0] == pytest.approx(0.02, rel=0.05)
            assert 0.03 < g["lost_share"].iloc[0] < 0.07  # about dropout_rate of joint-frames
    slow_frames = df[df["speed"] == "slow"]["frames"].iloc[0]
    fast_frames = df[df["speed"] == "fast"]["frames"].iloc[0]
    assert (slow_frames, fast_frames) == (6001 + 3601, 1501 + 901)
    for i in range(0, len(seen), 2):  # p1 then p2 at each (speed, noise): the same replay
        (p1, a), (p2, b) = seen[i], seen[i + 1]
        assert p1 is predictors["p1"] and p2 is predictors["p2"]
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x.positions, y.positions)
    for kwargs, message in (
        ({"speeds": ("brisk",)}, r"^speeds: unknown \['brisk'\]"),
        ({"speeds": ()}, r"^speeds: expected at least one value, got \[\]"),
        ({"noises": ()}, r"^noises: expected at least one value"),
        ({"noises": (0.01, -1.0, float("nan"), float("inf"))},
         r"^noises: expected finite noise levels >= 0 \[m\], got \[-1.0, nan, inf\]"),
    ):  # fmt: skip
        with pytest.raises(ConfigError, match=message):
            prediction_vs_noise(predictors, demos, progress=False, **kwargs)
    with pytest.raises(ConfigError, match=r"^compare: expected at least one value"):
        prediction_vs_noise({}, demos, progress=False)
    with pytest.raises(DataError, match="no held-out"):
        prediction_vs_noise(predictors, [], progress=False)
    df["mhd_1s"] = 0.1
    written = write_noise_report(df, tmp_path / "report", command="iplanner-evaluate x")
    assert [p.name for p in written] == [
        "prediction_vs_noise.csv",
        "prediction_vs_noise.png",
        "README.md",
    ]
    pd.testing.assert_frame_equal(pd.read_csv(written[0]), df, check_dtype=False)
    readme = written[2].read_text()
    assert "iplanner-evaluate x" in readme
    assert readme.count("\n| p1 |") + readme.count("\n| p2 |") == len(df)


def test_noise_plot_shows_predictors_with_equal_curves_and_keeps_its_legend_off_the_data(
    tmp_path, monkeypatch
) -> None:
    """iplanner_no_ni's curves lay exactly under iplanner_ni's (the same line style and
    marker, only the colour apart), so half the legend was invisible, and the legend stood
    over a data point of the first panel."""
    import matplotlib.pyplot as plt
    import pandas as pd
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import to_hex

    from iplanner_torch.eval.prediction_sweep import PLOTTED, write_noise_report

    made = []
    real = plt.subplots

    def spy(*args, **kwargs):
        fig, axes = real(*args, **kwargs)
        made.append(fig)
        return fig, axes

    monkeypatch.setattr(plt, "subplots", spy)
    rows = [
        {"predictor": name, "noise": noise, "speed": speed,
         **{m: 0.1 + noise + 0.01 * k for m in PLOTTED}}
        for name in ("iplanner_no_ni", "iplanner_ni")
        for k, speed in enumerate(("slow", "medium", "fast"))
        for noise in (0.0, 0.01, 0.02)
    ]  # fmt: skip
    write_noise_report(pd.DataFrame(rows), tmp_path)
    (fig,) = made
    for ax in fig.axes:
        lines = {ln.get_label(): ln for ln in ax.get_lines()}
        assert len(lines) == 6
        for speed in ("slow", "medium", "fast"):
            a, b = lines[f"I-Planner, no NI, {speed}"], lines[f"I-Planner, NI, {speed}"]
            np.testing.assert_array_equal(a.get_ydata(), b.get_ydata())  # the same values
            assert a.get_linestyle() != b.get_linestyle() and a.get_marker() != b.get_marker()
            assert to_hex(a.get_color()) == to_hex(b.get_color())  # colour: the speed
            assert {str(a.get_markerfacecolor()), str(b.get_markerfacecolor())} >= {"none"}
            assert b.get_markersize() > a.get_markersize()  # the one on top rings the other
    (legend,) = fig.legends
    assert len(legend.get_texts()) == 6
    renderer = FigureCanvasAgg(fig).get_renderer()
    box = legend.get_window_extent(renderer)
    assert box.x1 <= fig.bbox.x1 + 1
    for ax in fig.axes:
        area = ax.get_window_extent(renderer)
        assert box.x0 >= area.x1 or box.x1 <= area.x0  # beside every panel, over none
