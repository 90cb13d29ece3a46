"""Shared parts of the scripts that write an ``experiments/<name>/README.md`` from a run."""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import pandas as pd


def commit_short() -> str:
    """The short hash of HEAD ('' outside a git checkout)."""
    return subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()


def parse_report_args(description: str, default_command: str) -> argparse.Namespace:
    """The arguments every report script takes: the run folder (``run_dir``), the command that
    made the run (``--command``) and a note placed above the tables (``--note``)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--command", default=default_command)
    parser.add_argument("--note", default="")
    return parser.parse_args()


def write_readme(
    out: Path,
    *,
    title: str,
    command: str,
    report: str,
    episodes: pd.DataFrame,
    note: str,
    body: list[str],
) -> Path:
    """Write ``out/results.csv`` (the episode rows) and ``out/README.md``.

    The README is the title, the command, the report command, the commit and machine, the
    episode count, the note (if any), then ``body`` (Markdown lines).
    """
    out.mkdir(parents=True, exist_ok=True)
    episodes.to_csv(out / "results.csv", index=False)
    lines = [
        f"# {title}",
        "",
        f"Command: `{command}`  ",
        f"Report: `{report}`  ",
        f"Commit: {commit_short()}. Machine: the 2-core CPU, no GPU. {len(episodes)} episodes.",
        "",
    ]
    if note:
        lines += [note, ""]
    (out / "README.md").write_text("\n".join(lines + body))
    print(f"wrote {out / 'README.md'}")
    return out / "README.md"
