"""Hydra callbacks: gather a sweep's episode logs into one table and plots when it ends."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

#: numeric columns a sweep may vary, in the order they are preferred as the x axis of the
#: sweep plots (the other swept settings lay out their panels; seeds are repeats, not a
#: setting, and are never plotted against)
SWEEP_COLUMNS = ("noise", "dropout", "confidence")


def episode_report(df: Any, out_dir: Path, baseline: str = "itomp") -> list[Path]:
    """Write the report of per-episode results ``df`` into ``out_dir``.

    The summary keeps every setting that takes several values apart
    (:func:`~iplanner_torch.eval.report.report_groups`); the sweep plots put the first of
    :data:`SWEEP_COLUMNS` that varies on their x axis; the paired section compares each
    planner with ``baseline``.

    Returns:
        The written files (``results.csv``, ``results.md``, PNGs).
    """
    from iplanner_torch.eval.report import report_groups, write_sweep_report

    sweep = next(
        (
            c
            for c in SWEEP_COLUMNS
            if c in df.columns and df[c].nunique() > 1 and df[c].dtype.kind in "fi"
        ),
        None,
    )
    return write_sweep_report(
        df, out_dir, group_by=report_groups(df), sweep=sweep, baseline=baseline
    )


def gather_episode_logs(root: Path, out_dir: Path) -> list[Path]:
    """Read every ``*.mcap`` below ``root`` (in numbered order) and report them into
    ``out_dir`` (:func:`episode_report`).

    Returns:
        The written files, or [] when no logs exist.
    """
    from iplanner_torch.eval.report import gather_results

    if not any(root.rglob("*.mcap")):
        return []
    return episode_report(gather_results(root), out_dir)  # gather_results keeps numbered order


class GatherSweepResults(Callback):
    """At the end of a multirun, write ``<sweep dir>/summary/results.{csv,md}`` and plots."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir))
        written = gather_episode_logs(sweep_dir, sweep_dir / "summary")
        if written:
            print(f"sweep summary: {sweep_dir / 'summary' / 'results.md'} ({len(written)} files)")
