#!/usr/bin/env python
"""Benchmark of the human motion predictor: speed, training time, held-out quality.

Figures (``run(quick) -> dict``):

* ``prediction.single_ms``: median time of one forecast (one window, all actions, 1 s horizon,
  10 joints), reference: the same forecast through GPyTorch's own prediction path.
* ``prediction.batch1024_per_s``: windows per second for a batch of 1024, same reference.
* ``training.full_dataset_s``: ``train_predictor`` on the default reaching dataset (8 targets x
  30 reaches; quick mode: 8 x 4, flagged ``"quick": true``).
* ``prediction.mhd_1s_cm``, ``prediction.class_precision``, ``prediction.coverage95``: from
  :func:`evaluate_prediction` on held-out demonstrations.

Usage::

    python scripts/bench_prediction.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch
from _timing import median_seconds

from iplanner_torch.data.reaching import ReachingCfg, reaching_demonstrations
from iplanner_torch.data.windows import WindowCfg, build_windows, split_by_demonstration
from iplanner_torch.eval.prediction import evaluate_prediction
from iplanner_torch.prediction.predictor import HumanMotionPredictor, PredictorCfg, gp_inputs
from iplanner_torch.prediction.training import TrainerCfg, train_predictor


def _median_ms(fn, repeats: int, warmup: int = 3) -> float:
    return 1e3 * median_seconds(fn, repeats, warmup=warmup)


def _gpytorch_forecast(
    pred: HumanMotionPredictor, f_prev: torch.Tensor, progress: torch.Tensor
) -> None:
    """The reference path: every action's GP through GPyTorch (plus the classifier)."""
    pred.action_weights(f_prev, progress)
    x = gp_inputs(f_prev, pred.num_joints, pred.cfg.gp_input)
    for a in range(pred.num_actions):
        reg = pred.model_for(int(progress[0]), a)
        if reg is not None:
            for s in range(0, x.shape[0], 32):  # GPyTorch builds (C, b, b) covariances
                reg.predict_gpytorch(x[s : s + 32])


def training_inputs(quick: bool, predictor_cfg: PredictorCfg | None = None) -> tuple:
    """What the benchmark trains on: ``(training windows, validation windows, held-out
    demonstrations, window settings, predictor settings)``, from the synthetic reaching set
    (8 targets x 30 reaches; ``quick``: 8 x 4 and a smaller predictor budget). Also the
    trainings of ``bench_sweep.py``."""
    rc = ReachingCfg(reaches_per_target=4 if quick else 30)
    demos = [
        d
        for t in range(rc.n_targets)
        for r in range(rc.reaches_per_target)
        for d in reaching_demonstrations(rc, t, r)
    ]
    fractions = (0.5, 0.25, 0.25) if quick else (0.8, 0.1, 0.1)
    train, val, test = split_by_demonstration(demos, fractions, seed=0)
    wc = WindowCfg()
    w_train, w_val = build_windows(train, wc), build_windows(val, wc)
    cfg = predictor_cfg or PredictorCfg()
    if quick:
        cfg = replace(
            cfg,
            svgp=replace(cfg.svgp, max_steps=40),
            classifier_max_train=400,
            ivm_max_import=20,
            ivm_candidates=32,
        )
    return w_train, w_val, test, wc, cfg


def run(quick: bool = False, *, predictor_cfg: PredictorCfg | None = None) -> dict[str, dict]:
    """Train, time and evaluate the predictor on synthetic reaching data (one torch thread)."""
    torch.set_num_threads(1)
    w_train, w_val, test, wc, cfg = training_inputs(quick, predictor_cfg)
    out: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        path = train_predictor(
            (w_train, w_val),
            predictor_cfg=cfg,
            trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False),
            out_dir=Path(tmp),
            progress=False,
        )
        train_s = time.perf_counter() - t0
        pred = HumanMotionPredictor.load(path)
    out["training.full_dataset_s"] = {
        "value": train_s,
        "unit": "s",
        "quick": quick,
        "n_windows": len(w_train),
        "n_gps": len(pred.gps)
        + len({id(r) for r in pred.pooled.values()} - {id(r) for r in pred.gps.values()}),
        "goal": "< 600 s on the full default dataset",
    }
    w_test = build_windows(test, wc)
    one_f, one_p = w_test.f_prev[:1], w_test.progress[:1]
    reps = 10 if quick else 50
    fast = _median_ms(lambda: pred.predict(one_f, one_p), reps)
    ref = _median_ms(lambda: _gpytorch_forecast(pred, one_f, one_p), reps)
    out["prediction.single_ms"] = {
        "value": fast,
        "unit": "ms",
        "reference": ref,
        "reference_name": "GPyTorch prediction path",
        "ratio": ref / fast,
        "goal": "< 5 ms",
    }
    idx = torch.arange(1024) % len(w_test)
    bf, bp = w_test.f_prev[idx], torch.zeros(1024, dtype=torch.int64)
    fast_b = _median_ms(lambda: pred.predict(bf, bp), 3 if quick else 7, warmup=1)
    ref_b = _median_ms(lambda: _gpytorch_forecast(pred, bf, bp), 1 if quick else 3, warmup=1)
    out["prediction.batch1024_per_s"] = {
        "value": 1024 / (fast_b / 1e3),
        "unit": "windows/s",
        "reference": 1024 / (ref_b / 1e3),
        "reference_name": "GPyTorch prediction path",
        "ratio": ref_b / fast_b,
    }
    res = evaluate_prediction(pred, w_test)
    out["prediction.mhd_1s_cm"] = {
        "value": 100 * res["mhd_1s"],
        "unit": "cm",
        "moving_only": 100 * res["mhd_1s_moving"],
        "goal": "<= 7",
    }
    out["prediction.class_precision"] = {
        "value": res["class_precision"],
        "unit": "fraction",
        "confident_share": res["class_confident"],
        "goal": ">= 0.90",
    }
    out["prediction.coverage95"] = {
        "value": res["coverage95"],
        "unit": "fraction",
        "coverage90": res["coverage90"],
        "coverage99": res["coverage99"],
        "goal": "0.90 .. 0.99",
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (CI smoke)")
    args = ap.parse_args()
    print(json.dumps(run(args.quick), indent=2))


if __name__ == "__main__":
    main()
