#!/usr/bin/env python
"""Prediction quality versus input noise and human speed, with and without NI (fig.
result_prediction).

For every tracker noise sigma and speed, a reaching dataset is generated, split by
demonstration, a predictor is trained with each noisy-input mode (``none``, ``simple``, and
``nigp`` with ``--nigp``) and evaluated on the held-out demonstrations with
:func:`iplanner_torch.eval.prediction.evaluate_prediction`. Writes ``results.csv``,
``prediction_vs_noise.png`` and ``README.md`` into the output folder.

Usage::

    python scripts/prediction_vs_noise.py [--quick] [--nigp] [--out DIR]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import pandas as pd
import torch

from iplanner_torch.data.reaching import ReachingCfg, reaching_demonstrations
from iplanner_torch.data.windows import WindowCfg, build_windows, split_by_demonstration
from iplanner_torch.eval.prediction import evaluate_prediction
from iplanner_torch.prediction.predictor import HumanMotionPredictor, PredictorCfg
from iplanner_torch.prediction.svgp import SVGPCfg
from iplanner_torch.prediction.training import TrainerCfg, train_predictor

SPEEDS = {"slow": 0.5, "medium": 1.0, "fast": 2.0}
METRICS = ("class_precision", "reg_precision", "reg_accuracy", "mhd_1s", "coverage95")


def sweep(
    noises: list[float],
    speeds: list[str],
    modes: list[str],
    *,
    n_targets: int,
    reaches: int,
    max_steps: int,
    seed: int = 0,
) -> pd.DataFrame:
    """Train and evaluate one predictor per (noise, speed, mode); one row each."""
    rows = []
    for noise in noises:
        for speed in speeds:
            rc = ReachingCfg(
                n_targets=n_targets,
                reaches_per_target=reaches,
                noise_sigma=noise,
                speeds=(SPEEDS[speed],),
                seed=seed,
            )
            demos = [
                d
                for t in range(n_targets)
                for r in range(reaches)
                for d in reaching_demonstrations(rc, t, r)
            ]
            train, _, test = split_by_demonstration(demos, (0.75, 0.0, 0.25), seed=seed)
            wc = WindowCfg(stride=2)
            w_train, w_test = build_windows(train, wc), build_windows(test, wc)
            for mode in modes:
                svgp = SVGPCfg(
                    noisy_input=mode,
                    input_noise_sigma=max(noise, 1e-3),
                    max_steps=max_steps,
                    nigp_iterations=1,
                    seed=seed,
                )
                cfg = replace(
                    PredictorCfg(seed=seed),
                    svgp=svgp,
                    classifier_max_train=600,
                    ivm_max_import=30,
                    ivm_candidates=32,
                )
                t0 = time.perf_counter()
                with tempfile.TemporaryDirectory() as tmp:
                    path = train_predictor(
                        w_train,
                        predictor_cfg=cfg,
                        trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False),
                        out_dir=Path(tmp),
                        progress=False,
                    )
                    pred = HumanMotionPredictor.load(path)
                res = evaluate_prediction(pred, w_test)
                rows.append(
                    {
                        "noise_sigma": noise,
                        "speed": speed,
                        "mode": mode,
                        "train_s": time.perf_counter() - t0,
                        **res,
                    }
                )
                print(
                    f"noise={noise:.3f} speed={speed} mode={mode}: "
                    + ", ".join(f"{k}={res[k]:.4g}" for k in METRICS),
                    flush=True,
                )
    return pd.DataFrame(rows)


def plot(df: pd.DataFrame, path: Path) -> None:
    """One panel per metric: value versus noise, one line per (mode, speed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(METRICS), figsize=(4 * len(METRICS), 3.4))
    for ax, metric in zip(axes, METRICS):
        for (mode, speed), g in df.groupby(["mode", "speed"]):
            g = g.sort_values("noise_sigma")
            ax.plot(
                100 * g["noise_sigma"],
                g[metric],
                marker="o",
                ls="-" if mode != "none" else "--",
                label=f"{mode}, {speed}",
            )
        ax.set_xlabel("input noise sigma [cm]")
        ax.set_title(metric)
        if metric == "reg_accuracy":
            ax.set_yscale("log")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sweep (12 fits)")
    ap.add_argument("--nigp", action="store_true", help="also the per-point NIGP correction")
    ap.add_argument("--out", type=Path, default=Path("experiments/prediction_vs_noise"))
    args = ap.parse_args()
    torch.set_num_threads(max(1, torch.get_num_threads()))
    modes = ["none", "simple"] + (["nigp"] if args.nigp else [])
    if args.quick:
        kw = dict(
            noises=[0.0, 0.02, 0.04],
            speeds=["medium", "fast"],
            n_targets=2,
            reaches=4,
            max_steps=10,
        )
    else:
        kw = dict(
            noises=[0.0, 0.01, 0.02, 0.04],
            speeds=list(SPEEDS),
            n_targets=4,
            reaches=8,
            max_steps=30,
        )
    t0 = time.perf_counter()
    df = sweep(modes=modes, **kw)
    args.out.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out / "results.csv", index=False)
    plot(df, args.out / "prediction_vs_noise.png")
    try:
        commit = (
            subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True
            ).stdout.strip()
            or "uncommitted"
        )
    except OSError:
        commit = "unknown"
    cols = ["noise_sigma", "speed", "mode", *METRICS]
    table = (
        "| "
        + " | ".join(cols)
        + " |\n|"
        + "---|" * len(cols)
        + "\n"
        + "\n".join(
            "| "
            + " | ".join(f"{r[c]:.4g}" if isinstance(r[c], float) else str(r[c]) for c in cols)
            + " |"
            for _, r in df.iterrows()
        )
    )
    cmd = "python scripts/prediction_vs_noise.py " + " ".join(sys.argv[1:])
    (args.out / "README.md").write_text(
        "# Prediction quality versus input noise and speed (paper fig. result_prediction)\n\n"
        f"Command: `{cmd.strip()}`  \nCommit: {commit}  \n"
        f"Run time: {time.perf_counter() - t0:.0f} s on the CPU.\n\n"
        f"Sweep: {kw}; modes {modes}. Metrics as in `iplanner_torch/eval/prediction.py`:\n"
        "classification precision on confident frames, regression precision "
        "[m^2 s], regression accuracy [m^6 s], MHD of the moving hand over 1 s [m], share of "
        "held-out joints inside the 95 % ellipsoid of the top action.\n\n"
        f"{table}\n\n![plot](prediction_vs_noise.png)\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
