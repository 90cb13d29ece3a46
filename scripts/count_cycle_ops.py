#!/usr/bin/env python
"""Count the tensor operations of one warm replanning cycle, by the line that issues them.

On CUDA each operation that is not a view is a kernel launch, and at the planner's sizes the
launches, not the arithmetic, set a cycle's time (``experiments/bench/README.md``, GPU
section); on the CPU each one costs its dispatch. This counts them on any device: the cycle of
``scripts/bench_planning.py`` (KUKA iiwa, W = 20, A = 10, synthetic forecast), after a cold
solve and three warm cycles, under a ``TorchDispatchMode`` that records each operation with
the innermost ``iplanner_torch`` line above it (backward operations included).

Usage::

    python scripts/count_cycle_ops.py [--trajectories 8] [--robot kuka_iiwa14] [--top 20]
"""

from __future__ import annotations

import argparse
import collections
import sys
import traceback
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _report import fail  # noqa: E402

#: operations that make views (no kernel, no copy)
VIEWS = frozenset(
    "view slice select unsqueeze squeeze expand permute detach _unsafe_view t transpose "
    "as_strided alias _reshape_alias".split()
)


class _Counter(TorchDispatchMode):
    """Counts every dispatched operation by (name, innermost iplanner_torch line)."""

    def __init__(self) -> None:
        super().__init__()
        self.counts: collections.Counter[tuple[str, str]] = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        frames = [f for f in traceback.extract_stack() if "iplanner_torch" in f.filename]
        where = "?"
        if frames:
            f = frames[-1]
            where = f"{f.filename.split('iplanner_torch/')[-1]}:{f.lineno}"
        self.counts[(func.overloadpacket.__name__, where)] += 1
        return func(*args, **(kwargs or {}))


def count(robot_name: str, trajectories: int) -> collections.Counter[tuple[str, str]]:
    """``{(operation, file:line): count}`` of one warm cycle."""
    from bench_planning import started_replanner, synthetic_forecast

    from iplanner_torch.robot.model import RobotModel

    forecast = synthetic_forecast()
    rp = started_replanner(RobotModel.load(robot_name), trajectories, forecast)[0]
    t = 0.5
    for _ in range(3):
        rp.step(t, rp.command(t)[0], forecast, forecast_t0=t)
        t += 0.5
    q = rp.command(t)[0]
    mode = _Counter()
    with mode:
        rp.step(t, q, forecast, forecast_t0=t)
    return mode.counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trajectories", type=int, default=8, help="B (>= 1)")
    parser.add_argument("--robot", default="kuka_iiwa14", help="kuka_iiwa14 or fetch")
    parser.add_argument("--top", type=int, default=20, help="source lines to list (>= 0)")
    args = parser.parse_args(argv)
    if args.trajectories < 1:
        parser.error(f"--trajectories must be >= 1, got {args.trajectories}")
    if args.top < 0:
        parser.error(f"--top must be >= 0, got {args.top}")
    from iplanner_torch.errors import ConfigError

    torch.set_num_threads(1)
    try:
        counts = count(args.robot, args.trajectories)
    except ConfigError as err:
        text = str(err)
        fail(f"--robot {args.robot}: {text.split(': ', 1)[-1]}" if "robot" in text else text)
    total = sum(counts.values())
    by_line: collections.Counter[str] = collections.Counter()
    for (name, where), n in counts.items():
        if name not in VIEWS:
            by_line[where] += n
    launches = sum(by_line.values())
    print(f"one warm cycle, {args.robot}, B = {args.trajectories}: {total} operations, "
          f"{launches} of them not views (kernel launches on CUDA)")  # fmt: skip
    for where, n in by_line.most_common(args.top):
        print(f"{n:7d}  {where}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
