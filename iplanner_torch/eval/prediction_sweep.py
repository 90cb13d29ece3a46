"""Prediction quality against input noise and human speed (paper fig. result_prediction).

:func:`prediction_vs_noise` takes held-out demonstrations that carry their clean motion
(``Demonstration.clean_positions``, as the synthetic generator writes them), replays that
motion at each speed (time resampled by the speed factor, as the paper synthesises fast and
slow motion) and re-noises it at each sensor noise level with the same Kinect-like model as the
generator (Gaussian noise per coordinate and bursts of lost joints); each predictor is then
scored by :func:`iplanner_torch.eval.prediction.evaluate_prediction` against the clean future.
:func:`write_noise_report` writes the CSV, one plot per metric (one line per predictor and
speed) and a README.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.reaching import add_tracker_noise
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.eval.report import PLANNERS
from iplanner_torch.files import whole_file

#: predictor names as the plots give them (the planners' display names; the baseline's own)
_NAMES = {**PLANNERS, "constant_velocity": "constant velocity"}

#: human speed names and their time-scaling factors (> 1: faster)
SPEEDS: dict[str, float] = {"slow": 0.5, "medium": 1.0, "fast": 2.0}

#: metrics plotted by :func:`write_noise_report`: column -> (axis label, scale)
PLOTTED: dict[str, tuple[str, float]] = {
    "class_precision": ("classification precision", 1.0),
    "reg_precision": ("regression precision [m^2 s] (lower is better)", 1.0),
    "reg_accuracy": ("regression accuracy [m^6 s] (lower is better)", 1.0),
    "mhd_1s": ("hand MHD over 1 s [cm]", 100.0),
    "coverage95": ("share inside the 95 % ellipsoids", 1.0),
}
#: plotted metrics drawn on a log scale: the determinants of reg_accuracy span orders of
#: magnitude between predictors (a constant-velocity forecast's against a learned one's)
LOG_SCALE = ("reg_accuracy",)


def resample_speed(demo: Demonstration, factor: float) -> Demonstration:
    """The demonstration replayed ``factor`` times faster (linear interpolation in time).

    Args:
        demo: a demonstration with ``clean_positions`` (T, K, 3).
        factor: speed factor (> 0; 2 halves the duration).

    Returns:
        A demonstration at the same fps whose clean and observed positions are the resampled
        clean motion (noise is added separately); labels take the nearest frame.

    Raises:
        DataError: when the demonstration has no clean positions.
    """
    if factor <= 0:
        raise ConfigError(f"speed factor must be > 0, got {factor}")
    clean = getattr(demo, "clean_positions", None)
    if clean is None:
        raise DataError(f"{demo.name}: no clean_positions to replay (synthetic data has them)")
    clean = np.asarray(clean, dtype=np.float64)
    t_old = np.arange(clean.shape[0], dtype=np.float64)
    t_new = np.arange(0.0, t_old[-1] + 1e-9, factor)
    flat = clean.reshape(clean.shape[0], -1)
    out = np.stack([np.interp(t_new, t_old, flat[:, j]) for j in range(flat.shape[1])], axis=1)
    out = out.reshape(len(t_new), *clean.shape[1:]).astype(np.float32)
    labels = np.asarray(demo.labels)[np.clip(np.rint(t_new).astype(int), 0, len(t_old) - 1)]
    return replace(
        demo,
        positions=out.copy(),
        clean_positions=out,
        labels=labels,
        timestamps=None,
        name=f"{demo.name}@x{factor:g}",
    )


def check_sweep_grid(
    predictors: Sequence[str], noises: Sequence[float], speeds: Sequence[str]
) -> None:
    """Check a noise sweep's grid before any work: at least one predictor, noise level and
    speed; noise levels finite and >= 0 [m]; speeds named in :data:`SPEEDS`.

    Raises:
        ConfigError: naming ``compare``, ``noises`` or ``speeds`` and what is wrong.
    """
    for key, values in (("compare", predictors), ("noises", noises), ("speeds", speeds)):
        if len(values) == 0:
            raise ConfigError(f"{key}: expected at least one value, got []")
    bad_noise = [n for n in noises if not 0 <= float(n) < math.inf]
    if bad_noise:
        raise ConfigError(f"noises: expected finite noise levels >= 0 [m], got {bad_noise}")
    bad = [s for s in speeds if s not in SPEEDS]
    if bad:
        raise ConfigError(f"speeds: unknown {bad}; expected some of {sorted(SPEEDS)}")


def check_clean_positions(demos: Sequence[Demonstration]) -> None:
    """Check that every demonstration has ``clean_positions`` to re-noise.

    Raises:
        DataError: naming how many lack them and the first few; recorded data (such as the
            LEGO recording) has only the tracked positions, with their own noise.
    """
    lacking = [d.name for d in demos if getattr(d, "clean_positions", None) is None]
    if lacking:
        raise DataError(
            f"{len(lacking)} of the {len(demos)} held-out demonstrations have no "
            f"clean_positions to re-noise (first: {lacking[:3]}); the noise sweep needs "
            "noise-free motion, which synthetic datasets (data=reaching, data=tasks) record "
            "and recordings do not"
        )


def prediction_vs_noise(
    predictors: Mapping[str, Any],
    demos: Sequence[Demonstration],
    *,
    noises: Sequence[float] = (0.0, 0.01, 0.02, 0.04),
    speeds: Sequence[str] = ("slow", "medium", "fast"),
    dropout_rate: float = 0.005,
    seed: int = 0,
    progress: bool = True,
) -> pd.DataFrame:
    """Evaluate every predictor at every (noise, speed) on re-noised held-out motion.

    Args:
        predictors: name -> :class:`~iplanner_torch.prediction.predictor.HumanMotionPredictor`.
        demos: held-out demonstrations with clean positions.
        noises: sensor noise standard deviations [m].
        speeds: names from :data:`SPEEDS`.
        dropout_rate: share of lost joint-frames added with the noise (0 at noise 0).
        seed: noise seed (the same noise for every predictor).
        progress: show a progress bar.

    Returns:
        One row per (predictor, noise, speed) with the metrics of ``evaluate_prediction``.

    Raises:
        ConfigError: for an empty or bad grid (:func:`check_sweep_grid`).
        DataError: without held-out demonstrations, or when one has no ``clean_positions``.
    """
    from tqdm.auto import tqdm

    from iplanner_torch.eval.prediction import evaluate_prediction

    check_sweep_grid(list(predictors), noises, speeds)
    if not demos:
        raise DataError("no held-out demonstrations to evaluate")
    check_clean_positions(demos)
    rows: list[dict[str, Any]] = []
    grid = [(s, n) for s in speeds for n in noises]
    for speed, noise in tqdm(grid, desc="noise sweep", disable=not progress):
        rng = np.random.default_rng([seed, int(round(noise * 1e6)), int(SPEEDS[speed] * 100)])
        noisy = []
        for demo in demos:
            d = resample_speed(demo, SPEEDS[speed])
            pos = add_tracker_noise(
                d.clean_positions,
                rng,
                sigma=noise,
                dropout_rate=dropout_rate if noise > 0 else 0.0,
            )
            noisy.append(replace(d, positions=pos))
        for name, predictor in predictors.items():
            metrics = evaluate_prediction(predictor, noisy)
            rows.append({"predictor": name, "noise": noise, "speed": speed, **metrics})
    return pd.DataFrame(rows)


#: line style, marker and whether the marker is filled of each predictor, in the order they
#: first appear: overlapping curves of two predictors both show (a dashed line with hollow,
#: larger markers over a solid one with filled markers)
PREDICTOR_STYLES: tuple[tuple[str, str, bool], ...] = (
    ("-", "o", True),
    ("--", "s", False),
    (":", "^", True),
    ("-.", "D", False),
)


def write_noise_report(df: pd.DataFrame, out_dir: str | Path, command: str = "") -> list[Path]:
    """Write ``prediction_vs_noise.csv``, ``prediction_vs_noise.png`` and ``README.md``.

    The figure has one panel per plotted metric (:data:`PLOTTED`), the metric against the
    input noise [cm]: one line per predictor and speed, the speed in its colour and the
    predictor in its line style and marker (:data:`PREDICTOR_STYLES`; hollow markers for
    every other predictor), so that two predictors with the same values both show. One
    legend for all panels stands to the right of them, outside the plotting areas.

    Args:
        df: the rows of :func:`prediction_vs_noise` (``predictor``, ``noise`` [m],
            ``speed`` and the metric columns).
        out_dir: the folder (created).
        command: the command line, quoted in the README.

    Returns:
        The written paths: the CSV, the PNG and the README.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [out_dir / "prediction_vs_noise.csv"]
    with whole_file(written[0]) as tmp:  # an earlier table survives a failed write whole
        df.to_csv(tmp, index=False)
    metrics = [m for m in PLOTTED if m in df.columns]
    fig, axes = plt.subplots(
        1, len(metrics), figsize=(4.2 * len(metrics) + 2.0, 3.6), squeeze=False,
        layout="constrained",
    )  # fmt: skip
    names = list(dict.fromkeys(df["predictor"]))
    speeds = [sp for sp in SPEEDS if sp in set(df["speed"])]
    speeds += [sp for sp in dict.fromkeys(df["speed"]) if sp not in speeds]
    for ax, metric in zip(axes[0], metrics):
        label, scale = PLOTTED[metric]
        for i, name in enumerate(names):
            ls, marker, filled = PREDICTOR_STYLES[i % len(PREDICTOR_STYLES)]
            for k, speed in enumerate(speeds):
                g = df[(df["predictor"] == name) & (df["speed"] == speed)].sort_values("noise")
                if g.empty:
                    continue
                colour = f"C{k}"
                ax.plot(
                    g["noise"] * 100,
                    g[metric] * scale,
                    ls=ls,
                    marker=marker,
                    color=colour,
                    markerfacecolor=colour if filled else "none",
                    markersize=5 if filled else 8,
                    label=f"{_NAMES.get(str(name), name)}, {speed}",
                )
        ax.set_xlabel("input noise sigma [cm]")
        ax.set_ylabel(label)
        if metric in LOG_SCALE and bool((df[metric] > 0).all()):
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right center", fontsize="small")
    fig.suptitle(
        "Forecast quality against tracker noise (colour: human speed; line style: predictor)",
        fontsize="medium",
    )
    png = out_dir / "prediction_vs_noise.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    written.append(png)
    lines = ["# Prediction versus input noise and human speed", ""]
    if command:
        lines += ["Command:", "", f"    {command}", ""]
    lines += ["![prediction vs noise](prediction_vs_noise.png)", ""]
    cols = ["predictor", "speed", "noise", *metrics]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    for _, r in df[cols].iterrows():
        cells = [f"{v:.4g}" if isinstance(v, float) else str(v) for v in r.tolist()]
        lines.append("| " + " | ".join(cells) + " |")
    readme = out_dir / "README.md"
    with whole_file(readme) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    written.append(readme)
    return written
