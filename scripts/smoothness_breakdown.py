#!/usr/bin/env python
"""Where the roughness of a run's episodes comes from: waits, and the executed plans.

Usage::

    python scripts/smoothness_breakdown.py <run dir or .mcap> [--settle 1.0] [--near 0.1]
        [--episodes]

Reads every ``*.mcap`` episode log under the run folder (or the one log given; not those a
resumed run set aside in ``interrupted/``) and prints, per scenario, swept setting (speed,
noise, confidence, when they vary, and in a multirun folder each command-line override its
jobs differ in, e.g. ``planner.itomp_spread_mps``, as ``iplanner-evaluate
evaluate.mode=episode`` keeps them apart) and planner, the means of
:func:`iplanner_torch.eval.smoothness.episode_breakdown`:

- ``smoothness_log``: the paper's smoothness of the logged robot states (``eval/smoothness``
  itself in logs written at the metric rate, the default, whose metadata names ``log_hz``;
  earlier logs hold 14.3 Hz samples, which give lower values: compare planners there, not
  absolute values);
- ``waits``: plans that stopped to wait;
- ``wait_time`` / ``wait_share``: the share of the time, and of ``int sum_i qdd_i^2 dt``, in
  the wait windows (a wait's stop and the start after it, ``--settle`` seconds);
- ``outside_waits``: the smoothness of the time outside them;
- ``plan_executed``: the mean ``sum_i qdd_i^2`` of the plans' own waypoints over the parts
  that ran before the next plan took over;
- ``plan_change``: the median, over successive plans, of the largest joint difference
  between a plan and the one before it where both run [rad]: how far replanning moves the
  path;
- ``near_limit_time`` / ``near_limit_share``: the share of the time, and of the integral,
  while plans ran whose collision bound passed ``--near`` of the confidence limit (empty for
  logs without bounds).

``--episodes`` prints one row per episode as well. Logs that cannot be split, and truncated
or damaged logs (read only up to their last complete chunk) and those of episodes interrupted
before their end (``Episode.interrupted``) unless ``--include-incomplete``, are left out and
named.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import pandas as pd
from _report import fail, main_guard

from iplanner_torch.cli.callbacks import split_columns, sweep_overrides
from iplanner_torch.errors import DataError, DataWarning
from iplanner_torch.eval.report import SWEPT_SETTINGS, episode_logs, report_groups, to_markdown
from iplanner_torch.eval.smoothness import episode_breakdown
from iplanner_torch.recording import read_episode

COLUMNS = {
    "smoothness_log": "smoothness",
    "waits": "waits",
    "wait_time": "wait_time_share",
    "wait_share": "wait_share",
    "outside_waits": "smoothness_outside",
    "plan_executed": "plan_executed",
    "plan_change": "plan_change",
    "near_limit_time": "near_limit_time_share",
    "near_limit_share": "near_limit_share",
}


@main_guard
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, help="run folder, or one .mcap episode log")
    parser.add_argument("--settle", type=float, default=1.0, help="seconds after a wait")
    parser.add_argument(
        "--near", type=float, default=0.1, help="share of the confidence limit a plan is near"
    )
    parser.add_argument("--episodes", action="store_true", help="one row per episode too")
    parser.add_argument(
        "--include-incomplete",
        action="store_true",
        help="count truncated, damaged or interrupted logs too (what was read of them)",
    )
    args = parser.parse_args()
    if not (math.isfinite(args.settle) and args.settle >= 0.0):
        fail(f"--settle must be a number of seconds >= 0, got {args.settle}")
    if not (math.isfinite(args.near) and 0.0 < args.near <= 1.0):
        fail(f"--near must be a share of the confidence limit in (0, 1], got {args.near}")
    if not args.run_dir.exists():
        fail(f"no *.mcap episode logs: {args.run_dir} not found")
    paths = [args.run_dir] if args.run_dir.is_file() else episode_logs(args.run_dir)
    if not paths:
        fail(f"no *.mcap episode logs under {args.run_dir}")
    rows = []
    skipped = []
    for path in paths:
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", DataWarning)
                ep = read_episode(path)
            if not ep.complete and not args.include_incomplete:
                skipped.append(f"{path}: truncated or damaged (--include-incomplete counts it)")
                continue
            if ep.interrupted and not args.include_incomplete:
                skipped.append(
                    f"{path}: the episode was interrupted before its end (--include-incomplete "
                    "counts it)"
                )
                continue
            for w in caught:
                print(f"warning: {w.message}", file=sys.stderr)
            b = episode_breakdown(ep, settle_s=args.settle, near_fraction=args.near)
        except DataError as exc:  # a log cut short (an interrupted run): left out, named
            text = str(exc)  # most name the file already
            skipped.append(text if text.startswith(f"{path}: ") else f"{path}: {text}")
            continue
        meta = ep.metadata
        row = {key: meta.get(key) for key in ("scenario", *SWEPT_SETTINGS, "planner", "seed")}
        row["path"] = str(path)  # places the episode in its sweep job (sweep_overrides)
        row.update({col: getattr(b, attr) for col, attr in COLUMNS.items()})
        rows.append(row)
    for line in skipped:
        print(f"skipped {line}", file=sys.stderr)
    if not rows:
        fail(f"none of the {len(paths)} log(s) in {args.run_dir} could be split")
    df = pd.DataFrame(rows)
    swept: list[str] = []
    if args.run_dir.is_dir():  # a multirun folder: the overrides its jobs differ in
        df, swept = sweep_overrides(df, args.run_dir)
    df = df.drop(columns="path")
    if args.episodes:
        print(to_markdown(df))
        print()
    df = df.dropna(axis=1, how="all")
    groups = list(report_groups(df))  # swept speeds, noises, confidences are kept apart
    extra = split_columns(df, tuple(groups), swept)  # as episode_report: before the planner
    groups = [*groups[:-1], *extra, groups[-1]]
    by = df.groupby(groups, sort=False, dropna=False)  # a log outside the jobs is kept too
    means = by[[c for c in COLUMNS if c in df.columns]].mean().reset_index()  # all-NaN dropped
    means.insert(len(groups), "episodes", by.size().values)
    print(to_markdown(means))


if __name__ == "__main__":
    main()
