#!/usr/bin/env python
"""The CUDA paths against the same code on the CPU, measured in the same run.

Every figure is a CUDA time (or rate) with its CPU reference beside it; ``ratio`` is CPU time
over CUDA time (> 1: the GPU is faster). The CPU side runs with one torch thread, as the
episodes do (``EpisodeCfg.torch_threads``); ``--cpu-threads N`` changes that. Figures:

- ``gpu.fk.<robot>.spheres[_backward]_<B>x20_ms``: the robot's spheres at B x 20
  configurations (forward; forward and backward), B = 1024 and 16384 (``--quick``: 1024).
- ``gpu.replan.cycle_b<B>_ms``: one warm-started replanning cycle of the KUKA iiwa
  (``scripts/bench_planning.py``'s cycle), B = 8, 64 and 512 trajectories.
- ``gpu.training_s``: training the predictor (``scripts/bench_prediction.py``'s data).
- ``gpu.prediction.single_ms`` and ``gpu.prediction.batch<N>_per_s``: forecasts of one window
  and of N windows by that predictor.
- ``gpu.sim.realtime_factor_<planner>``: closed-loop episodes of the iiwa delivery scene
  with the planner, the robot model and the predictor on the device (``run_episode``), for
  ITOMP and the I-Planner NI with the predictor trained above.

Each check also compares the CUDA result with the CPU one (``max_abs_diff``), so that a fast
but wrong path shows. Without CUDA the script stops with exit code 2; ``--device cpu`` runs it
on the CPU against itself, as a smoke test.

Usage::

    python scripts/bench_gpu.py [--quick] [--only fk,replan,prediction,sim]
        [--json experiments/bench/gpu.json --force] [--cpu-threads 1] [--device cuda]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _report import commit_short, fail, refuse_stored_json  # noqa: E402
from bench_robot import _median_ms  # noqa: E402

from iplanner_torch.errors import ConfigError  # noqa: E402
from iplanner_torch.types import resolve_device, torch_threads  # noqa: E402

CPU = torch.device("cpu")
AREAS = ("fk", "replan", "prediction", "sim")


def _figure(value: float, unit: str, ref: float, *, rate: bool = False, **extra) -> dict:
    """A figure with its CPU reference; ratio = CPU time / CUDA time (rates: CUDA / CPU)."""
    ratio = value / ref if rate else ref / value
    return {
        "value": value,
        "unit": unit,
        "reference": ref,
        "reference_name": "CPU, same run",
        "ratio": ratio,
        **extra,
    }


def bench_fk(cuda: torch.device, quick: bool) -> dict[str, dict]:
    from iplanner_torch.robot.model import RobotModel

    out: dict[str, dict] = {}
    reps = 3 if quick else 20
    for name in ("kuka_iiwa14", "fetch"):
        devs = {"cpu": CPU, "cuda": cuda}
        models = {k: RobotModel.load(name, device=d) for k, d in devs.items()}
        gen = torch.Generator().manual_seed(0)
        for b in (1024,) if quick else (1024, 16384):
            q = models["cpu"].q_home + 0.5 * torch.randn(
                b, 20, models["cpu"].num_joints, generator=gen
            )  # (B, W, J)
            qs = {"cpu": q, "cuda": q.to(cuda)}
            times: dict[str, dict[str, float]] = {"fwd": {}, "bwd": {}}
            for key, dev in devs.items():
                m, x = models[key], qs[key]

                def fwd(m=m, x=x) -> torch.Tensor:
                    with torch.no_grad():
                        return m.sphere_centers(x)

                def bwd(m=m, x=x) -> None:
                    y = x.detach().requires_grad_(True)
                    m.sphere_centers(y).square().sum().backward()

                times["fwd"][key] = _median_ms(fwd, dev, reps, 2)
                times["bwd"][key] = _median_ms(bwd, dev, reps, 2)
            with torch.no_grad():
                diff = (
                    (
                        models["cuda"].sphere_centers(qs["cuda"]).cpu()
                        - models["cpu"].sphere_centers(q)
                    )
                    .abs()
                    .max()
                    .item()
                )
            for key, label in (("fwd", ""), ("bwd", "_backward")):
                out[f"gpu.fk.{name}.spheres{label}_{b}x20_ms"] = _figure(
                    times[key]["cuda"], "ms", times[key]["cpu"], max_abs_diff_m=diff
                )
    return out


def bench_replan(cuda: torch.device, quick: bool) -> dict[str, dict]:
    from bench_planning import _cycle_times, synthetic_forecast

    from iplanner_torch.robot.model import RobotModel

    out: dict[str, dict] = {}
    fc = synthetic_forecast()
    repeats = 3 if quick else 10
    for b in (8, 64, 512):
        res = {}
        for key, dev in (("cpu", CPU), ("cuda", cuda)):
            robot = RobotModel.load("kuka_iiwa14", device=dev)
            reps = max(2, repeats // 3) if (key == "cpu" and b == 512) else repeats
            res[key] = _cycle_times(robot, b, fc.to(dev), reps)
        out[f"gpu.replan.cycle_b{b}_ms"] = _figure(
            res["cuda"]["cycle_ms"],
            "ms",
            res["cpu"]["cycle_ms"],
            collision_ms=res["cuda"]["collision_ms"],
            optimiser_ms=res["cuda"]["optimiser_ms"],
            feasible_rate=res["cuda"]["feasible_rate"],
            feasible_rate_cpu=res["cpu"]["feasible_rate"],
        )
    return out


def bench_prediction(cuda: torch.device, quick: bool, tmp: Path) -> tuple[dict, dict]:
    """Training and forecasts; returns the figures and the two trained checkpoints' paths."""
    from bench_prediction import training_inputs

    from iplanner_torch.data.windows import build_windows
    from iplanner_torch.prediction.predictor import HumanMotionPredictor
    from iplanner_torch.prediction.training import TrainerCfg, train_predictor

    w_train, w_val, test, wc, cfg = training_inputs(quick)
    secs, paths = {}, {}
    for key, acc in (("cpu", "cpu"), ("device", cuda.type)):
        t0 = time.perf_counter()
        paths[key] = train_predictor(
            (w_train, w_val),
            predictor_cfg=cfg,
            trainer_cfg=TrainerCfg(accelerator=acc, tensorboard=False),
            out_dir=tmp / key,
            progress=False,
        )
        secs[key] = time.perf_counter() - t0
    out = {"gpu.training_s": _figure(secs["device"], "s", secs["cpu"], n_windows=len(w_train))}
    pred_cpu = HumanMotionPredictor.load(paths["cpu"])
    pred_gpu = HumanMotionPredictor.load(paths["cpu"]).to(cuda)
    w_test = build_windows(test, wc)
    reps = 10 if quick else 50
    f1, p1 = w_test.f_prev[:1], w_test.progress[:1]
    t_cpu = _median_ms(lambda: pred_cpu.predict(f1, p1), CPU, reps, 2)
    t_gpu = _median_ms(lambda: pred_gpu.predict(f1.to(cuda), p1.to(cuda)), cuda, reps, 2)
    out["gpu.prediction.single_ms"] = _figure(t_gpu, "ms", t_cpu)
    for n in (1024, 8192):
        idx = torch.arange(n) % len(w_test)
        f, p = w_test.f_prev[idx], torch.zeros(n, dtype=torch.int64)
        fg, pg = f.to(cuda), p.to(cuda)
        r = 2 if quick else 5
        t_cpu = _median_ms(lambda f=f, p=p: pred_cpu.predict(f, p), CPU, r, 1)
        t_gpu = _median_ms(lambda fg=fg, pg=pg: pred_gpu.predict(fg, pg), cuda, r, 1)
        a, g = pred_cpu.predict(f, p), pred_gpu.predict(fg, pg)
        diff = (g.mean.cpu() - a.mean).abs().max().item()
        wdiff = (g.weights.cpu() - a.weights).abs().max().item()
        out[f"gpu.prediction.batch{n}_per_s"] = _figure(
            n / (t_gpu / 1e3),
            "windows/s",
            n / (t_cpu / 1e3),
            rate=True,
            max_abs_diff_mean_m=diff,
            max_abs_diff_weights=wdiff,
        )
    return out, paths


def bench_sim(cuda: torch.device, quick: bool, predictor_path: Path) -> dict[str, dict]:
    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import CONF_DIR, instantiate
    from iplanner_torch.eval.episode import EpisodeCfg, run_episode
    from iplanner_torch.planning.replanner import PlannerCfg
    from iplanner_torch.prediction.predictor import HumanMotionPredictor
    from iplanner_torch.robot.model import RobotModel

    warnings.filterwarnings("ignore", message="replanning cycle")
    node = OmegaConf.load(Path(CONF_DIR) / "planner" / "itomp.yaml")
    planner = instantiate(node, PlannerCfg, name="planner")
    cfg = EpisodeCfg(max_duration_s=4.0 if quick else 20.0, planner=planner)
    out: dict[str, dict] = {}
    for kind in ("itomp", "iplanner_ni"):
        m: dict[str, dict] = {}
        for key, dev in (("cpu", CPU), ("cuda", cuda)):
            robot = RobotModel.load("kuka_iiwa14", device=dev)
            pred = None
            if kind != "itomp":
                pred = HumanMotionPredictor.load(predictor_path)
                pred = pred.to(dev) if dev.type == "cuda" else pred
            m[key] = run_episode(
                cfg, robot=robot, predictor=pred, planner_kind=kind, writer_path=None, seed=0
            ).metrics
        rtf = {d: float(m[d]["sim/realtime_factor"]) for d in m}
        solve = {d: float(m[d]["plan/mean_solve_ms"]) for d in m}
        out[f"gpu.sim.realtime_factor_{kind}"] = _figure(
            rtf["cuda"],
            "sim s / wall s",
            rtf["cpu"],
            rate=True,
            sim_seconds=cfg.max_duration_s,
            mean_solve_ms=solve["cuda"],
            mean_solve_ms_cpu=solve["cpu"],
            closest_cm={d: 100 * float(m[d]["eval/min_distance"]) for d in m},
        )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="reduced sizes")
    parser.add_argument("--json", type=Path, default=None, help="write the figures as JSON")
    parser.add_argument("--force", action="store_true", help="replace an existing --json")
    parser.add_argument("--cpu-threads", type=int, default=1, help="torch threads (>= 1)")
    parser.add_argument(
        "--only",
        default="fk,replan,prediction,sim",
        help="comma-separated: fk, replan, prediction, sim",
    )
    parser.add_argument(
        "--device",
        default="cuda",
        help="the device measured against the CPU (default cuda; 'cpu' runs the script as a "
        "smoke test, its ratios near 1)",
    )
    args = parser.parse_args(argv)
    if args.cpu_threads < 1:
        parser.error(f"--cpu-threads must be >= 1, got {args.cpu_threads}")
    areas = [a.strip() for a in args.only.split(",") if a.strip()]
    bad = [a for a in areas if a not in AREAS]
    if bad or not areas:
        what = f"unknown area(s) {', '.join(bad)}" if bad else "no area"
        parser.error(f"--only {args.only!r}: {what}; the areas are {', '.join(AREAS)}")
    if args.json is not None and args.json.is_dir():
        parser.error(f"--json {args.json} is a folder; give the JSON file to write")
    if "sim" in areas and "prediction" not in areas:  # sim runs the predictor prediction trains
        parser.error(f"--only {args.only!r}: the sim area needs the prediction area; add it")
    refuse_stored_json(args.json, args.force)
    try:
        cuda = resolve_device(args.device)
    except ConfigError as err:
        fail(f"--device {args.device}: {err}")
    torch.manual_seed(0)
    figures: dict[str, dict] = {}
    failed: list[str] = []
    with torch_threads(args.cpu_threads), tempfile.TemporaryDirectory() as tmp:
        predictor_path = None
        for area in AREAS:
            if area not in areas:
                continue
            print(f"[{area}] running ...", flush=True)
            t0 = time.perf_counter()
            try:
                if area == "fk":
                    figures.update(bench_fk(cuda, args.quick))
                elif area == "replan":
                    figures.update(bench_replan(cuda, args.quick))
                elif area == "prediction":
                    f, paths = bench_prediction(cuda, args.quick, Path(tmp))
                    figures.update(f)
                    predictor_path = paths["cpu"]
                elif predictor_path is None:
                    print("[sim] needs the prediction area's predictor: skipped", flush=True)
                    continue
                else:
                    figures.update(bench_sim(cuda, args.quick, predictor_path))
            except Exception:  # noqa: BLE001 - report and go on with the other areas
                import traceback

                traceback.print_exc()
                failed.append(area)
                continue
            print(f"[{area}] done in {time.perf_counter() - t0:.1f} s", flush=True)
    width = max((len(k) for k in figures), default=10)
    print(f"\n{'figure'.ljust(width)}  {str(cuda):>11}  {'cpu':>11}  unit            speed-up")
    for name, fig in figures.items():
        sp = fig["ratio"]
        print(
            f"{name.ljust(width)}  {fig['value']:11.4g}  {fig['reference']:11.4g}  "
            f"{fig['unit']:<14}  {sp:.3g}x"
        )
    if args.json is not None and not figures:
        print(f"error: no figure was produced; {args.json} not written", file=sys.stderr)
        return 2
    if args.json is not None:
        meta = {
            "command": "python scripts/bench_gpu.py " + " ".join(argv or sys.argv[1:]),
            "commit": commit_short() or "unknown",
            "torch": torch.__version__,
            "device": str(cuda),
            "cuda": torch.cuda.get_device_name(0) if cuda.type == "cuda" else None,
            "cpu": platform.processor() or platform.machine(),
            "cpu_threads": args.cpu_threads,
            "failed_areas": failed,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2, default=str) + "\n")
        args.json.with_suffix(".meta.json").write_text(json.dumps(meta, indent=2) + "\n")
        print(f"\nwrote {args.json}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
