#!/usr/bin/env python
"""Timeline plots of episode logs already written (``iplanner-experiment`` draws them itself
unless ``run.timeline_plots=false``).

Usage::

    python scripts/plot_episode.py <run dir, episodes folder or .mcap> [...] [--out DIR] [--force]
        [--own-axes]

Draws, for each ``*.mcap`` episode log given or found below the folders given, the four panels
of :func:`iplanner_torch.eval.timeline.plot_episode_timeline` (closest robot-person distance,
each plan's collision bound against ``1 - confidence``, the forecast action probabilities with
the person's real reaches, the arm's speed; waits shaded) into ``<log stem>.png`` beside the
log, or into ``--out``. The figures of a scenario share their time, distance and arm-speed
axes (those that hold its logs given, as ``iplanner-experiment`` draws a run's), unless
``--own-axes``. An existing PNG is replaced only with ``--force``. A log cut short is drawn
as far as it goes; a file that is not an episode log is named and left out (exit 2 when
nothing could be drawn).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from _report import fail, main_guard

from iplanner_torch.errors import DataError, DataWarning
from iplanner_torch.eval.report import episode_logs
from iplanner_torch.eval.timeline import (
    episode_timeline,
    plot_episode_timeline,
    shared_axes_by_scenario,
    timeline_path,
)


def _logs(paths: list[Path]) -> list[Path]:
    out: list[Path] = []
    for p in paths:
        if p.is_dir():
            found = episode_logs(p)
            if not found:
                fail(f"no .mcap episode logs below {p}")
            out += found
        elif p.is_file():
            out.append(p)
        else:
            fail(f"no such file or folder: {p}")
    return out


@main_guard
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", type=Path, nargs="+", help="run folders or .mcap logs")
    parser.add_argument("--out", type=Path, help="folder for the PNGs (default: beside each log)")
    parser.add_argument("--force", action="store_true", help="replace existing PNGs")
    parser.add_argument(
        "--own-axes",
        action="store_true",
        help="each figure on its own axes (default: those of its scenario's logs given)",
    )
    args = parser.parse_args()
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        fail(f"--out must be a folder: {args.out} is a file")
    logs = _logs(args.paths)
    targets = [
        (log, args.out / f"{log.stem}.png" if args.out else timeline_path(log)) for log in logs
    ]
    seen: dict[Path, Path] = {}
    for log, png in targets:
        if png in seen:
            fail(f"{seen[png]} and {log} would both be drawn into {png}: give them apart")
        seen[png] = log
    existing = [str(png) for _, png in targets if png.exists()]
    if existing and not args.force:
        fail(
            f"{len(existing)} PNG(s) exist, e.g. {existing[0]}: pass --force to replace them, "
            "or --out <folder>"
        )
    timelines, skipped = [], []
    for log, png in targets:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                timelines.append((episode_timeline(log), png, log))
            except DataError as exc:
                skipped.append(f"{log} ({exc})")
                continue
        for w in caught:
            if issubclass(w.category, DataWarning):
                print(f"warning: {log.name}: {str(w.message).splitlines()[0]}", file=sys.stderr)
    shared = (
        [None] * len(timelines)
        if args.own_axes
        else shared_axes_by_scenario([tl for tl, _, _ in timelines])
    )
    written = 0
    for (tl, png, log), axes in zip(timelines, shared):
        plot_episode_timeline(tl, png, axes, source=log)
        written += 1
        print(png)
    if skipped:
        print(f"left out {len(skipped)}: " + "; ".join(skipped), file=sys.stderr)
    if not written:
        fail("no timeline plot drawn")


if __name__ == "__main__":
    main()
