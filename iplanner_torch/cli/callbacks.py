"""Hydra callbacks: gather a sweep's episode logs into one table and plots when it ends."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

#: columns a sweep may vary, in the order they are preferred for the sweep plots
SWEEP_COLUMNS = ("noise", "confidence", "speed", "seed")


def gather_episode_logs(root: Path, out_dir: Path) -> list[Path]:
    """Read every ``*.mcap`` below ``root`` and write the combined report into ``out_dir``.

    Returns:
        The written files (``results.csv``, ``results.md``, PNGs), or [] when no logs exist.
    """
    from iplanner_torch.eval.report import gather_results, report_groups, write_sweep_report

    logs = sorted(root.glob("**/episodes/*.mcap"))
    if not logs:
        return []
    df = gather_results(logs)
    group_by = report_groups(df)
    sweep = next(
        (
            c
            for c in SWEEP_COLUMNS
            if c in df.columns and df[c].nunique() > 1 and df[c].dtype.kind in "fi"
        ),
        None,
    )
    return write_sweep_report(df, out_dir, group_by=group_by, sweep=sweep)


class GatherSweepResults(Callback):
    """At the end of a multirun, write ``<sweep dir>/summary/results.{csv,md}`` and plots."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir))
        written = gather_episode_logs(sweep_dir, sweep_dir / "summary")
        if written:
            print(f"sweep summary: {sweep_dir / 'summary' / 'results.md'} ({len(written)} files)")
