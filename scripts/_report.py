"""Shared parts of the scripts that write an ``experiments/<name>/README.md`` from a run."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pandas as pd


def commit_short() -> str:
    """The short hash of HEAD ('' outside a git checkout)."""
    return subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()


def fail(message: str) -> None:
    """Print ``error: message`` on standard error and exit with code 2."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def parse_report_args(
    description: str, default_command: str, default_out: Path
) -> argparse.Namespace:
    """The arguments every report script takes: the run folder (``run_dir``, checked to be a
    folder), the command that made the run (``--command``), a note placed above the tables
    (``--note``), the record folder (``--out``) and ``--force`` to replace its README."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--command", default=default_command)
    parser.add_argument("--note", default="")
    parser.add_argument(
        "--out", type=Path, default=default_out, help=f"record folder (default {default_out})"
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace an existing README.md and results.csv there (records hold hand-written "
        "sections: regenerate into another --out and merge by hand instead)",
    )
    args = parser.parse_args()
    if not args.run_dir.is_dir():
        fail(f"{args.run_dir}: not a folder (give the run's output folder)")
    return args


def complete_rows(df: pd.DataFrame, path: Path, metric: str) -> pd.DataFrame:
    """``df`` when every row has its ``metric``; an error naming the incomplete rows (a run
    stopped while writing) otherwise."""
    if metric not in df.columns:
        fail(f"{path}: no {metric!r} column; is this an episode results file?")
    bad = df[metric].isna()
    if bool(bad.any()):
        fail(
            f"{path}: {int(bad.sum())} of {len(df)} episode row(s) lack {metric!r} (rows "
            f"{[int(i) + 2 for i in df.index[bad]]} of the file; was the run stopped?)"
        )
    return df


def write_readme(
    out: Path,
    *,
    title: str,
    command: str,
    report: str,
    episodes: pd.DataFrame,
    note: str,
    body: list[str],
    force: bool = False,
) -> Path:
    """Write ``out/results.csv`` (the episode rows) and ``out/README.md``.

    The README is the title, the command, the report command, the commit and machine, the
    episode count, the note (if any), then ``body`` (Markdown lines). An existing README is
    replaced only with ``force``.
    """
    if (out / "README.md").exists() and not force:
        fail(
            f"{out / 'README.md'} exists and may hold hand-written sections; pass --force to "
            "replace it, or --out <another folder>"
        )
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
