"""Shared parts of the scripts: their error reporting (:func:`fail`, :func:`main_guard`), and
what the scripts that write an ``experiments/<name>/README.md`` from a run have in common."""

from __future__ import annotations

import argparse
import functools
import subprocess
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import pandas as pd

from iplanner_torch.errors import IPlannerError
from iplanner_torch.eval.report import SWEPT_SETTINGS

ROOT = Path(__file__).resolve().parents[1]

#: settings of an episode row besides its scenario, planner and seed (a sweep may vary them)
SETTINGS = ("robot", *SWEPT_SETTINGS)

T = TypeVar("T")


def commit_short() -> str:
    """The short hash of the repository's HEAD ('' outside a git checkout)."""
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=False,
        ).stdout.strip()
    except OSError:
        return ""


def fail(message: str) -> NoReturn:
    """Print ``error: message`` on standard error and exit with code 2."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def read_results(path: Path) -> pd.DataFrame:
    """The rows of one results CSV (:func:`~iplanner_torch.eval.report.gather_results`), all
    of them: a row the reader would leave out or fill in (a last row cut short by an
    interrupted run, a row with fewer cells than the header) ends the script with
    :func:`fail` instead of its warning, since a record must not lose an episode. Other
    warnings are passed on."""
    import warnings

    from iplanner_torch.errors import DataWarning
    from iplanner_torch.eval.report import gather_results

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        df = gather_results(path)
    for w in caught:
        text = str(w.message)
        if issubclass(w.category, DataWarning) and ("cut short" in text or "fewer cells" in text):
            fail(f"DataError: {text.rsplit(';', 1)[0]}; a record needs every row whole")
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return df


def machine_text() -> str:
    """The machine this report is made on, in words: its CPU cores and its GPU, if any (the
    episodes' own machine is not recorded in their rows)."""
    import os

    import torch

    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU"
    return f"{os.cpu_count()}-core CPU, {gpu} (where this report was made)"


def refuse_existing(paths: Iterable[Path | None], force: bool, instead: str) -> None:
    """Exit 2 (one ``error:`` line) naming the files of ``paths`` that exist, unless ``force``:
    ``<files> exist(s): pass --force to replace, or <instead>``."""
    existing = [str(p) for p in paths if p is not None and p.exists()]
    if existing and not force:
        fail(f"{' and '.join(existing)} exist(s): pass --force to replace, or {instead}")


def refuse_unwritable(path: Path) -> None:
    """Exit 2 (one ``error:`` line) when ``path`` could not be written: its nearest existing
    folder is a file, or not writable. Checked before a long run, whose figures would
    otherwise only reach the terminal."""
    import os

    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        fail(f"cannot write {path}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        fail(f"cannot write {path}: {folder} is not writable")


def refuse_stored_json(json_path: Path | None, force: bool) -> None:
    """Exit 2 (one ``error:`` line) when ``json_path`` or its ``.meta.json`` exists and
    ``force`` is not given (a benchmark record is replaced only on purpose), or when it
    could not be written (:func:`refuse_unwritable`)."""
    if json_path is None:
        return
    refuse_unwritable(json_path)
    if force:
        return
    existing = [p for p in (json_path, json_path.with_suffix(".meta.json")) if p.exists()]
    if existing:
        fail(
            f"{' and '.join(map(str, existing))} exist{'s' if len(existing) == 1 else ''} "
            "(stored results); pass --force to replace, or --json <another file>"
        )


def main_guard(main: Callable[..., T]) -> Callable[..., T]:
    """``main`` reporting :class:`~iplanner_torch.errors.IPlannerError` and ``OSError`` as
    ``error: <Type>: message`` on standard error with exit code 2 (no traceback)."""

    @functools.wraps(main)
    def guarded(*args: Any, **kwargs: Any) -> T:
        try:
            return main(*args, **kwargs)
        except (IPlannerError, OSError) as err:
            fail(f"{type(err).__name__}: {str(err).rstrip()}")

    return guarded


def parse_report_args(
    description: str, default_command: str, default_out: Path
) -> argparse.Namespace:
    """The arguments every report script takes: the run folder (``run_dir``, checked to be a
    folder), the command that made the run (``--command``), a note placed above the tables
    (``--note``), the record folder (``--out``, checked not to be a file) and ``--force`` to
    replace its README.md and results.csv."""
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
    if args.out.exists() and not args.out.is_dir():
        fail(f"--out must be a folder: {args.out} is a file")
    return args


def require_columns(df: pd.DataFrame, path: Path, columns: Sequence[str]) -> None:
    """An error naming the ``columns`` that ``df`` (read from ``path``) lacks, if any."""
    missing = [c for c in columns if c not in df.columns]
    if missing:
        fail(
            f"{path}: no {', '.join(map(repr, missing))} column{'s' if len(missing) > 1 else ''}"
            "; is this an episode results file?"
        )


def numeric_column(df: pd.DataFrame, path: Path, column: str) -> pd.DataFrame:
    """``df`` with ``column`` (if it has one) as numbers; an error naming the rows whose cell
    is not a number otherwise."""
    if column not in df.columns:
        return df
    values = pd.to_numeric(df[column], errors="coerce")
    bad = values.isna() & df[column].notna()
    if bool(bad.any()):
        rows = [int(i) + 2 for i in df.index[bad][:5]]
        fail(
            f"{path}: {int(bad.sum())} {column!r} value(s) are not numbers "
            f"({list(df.loc[bad, column][:5])} in rows {rows} of the file)"
        )
    df[column] = values
    return df


def single_setting(df: pd.DataFrame, where: Path, columns: Sequence[str]) -> None:
    """An error naming the values when any of ``columns`` (those ``df`` has) takes more than
    one value: the report covers one setting."""
    many = [
        f"{c} ({', '.join(str(v) for v in sorted(df[c].dropna().unique(), key=str))})"
        for c in columns
        if c in df.columns and df[c].nunique(dropna=True) > 1
    ]
    if many:
        fail(
            f"{where}: episode rows of more than one {'; '.join(many)}; this report covers "
            "one: give a run folder of one setting"
        )


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
    episode count, the note (if any), then ``body`` (Markdown lines). An existing README or
    results.csv is replaced only with ``force``.
    """
    existing = [p for p in (out / "README.md", out / "results.csv") if p.exists()]
    if existing and not force:
        fail(
            f"{' and '.join(map(str, existing))} exist{'s' if len(existing) == 1 else ''} "
            "(a record may hold hand-written sections); pass --force to replace, or --out "
            "<another folder>"
        )
    out.mkdir(parents=True, exist_ok=True)
    episodes.to_csv(out / "results.csv", index=False)
    lines = [
        f"# {title}",
        "",
        f"Command: `{command}`  ",
        f"Report: `{report}`  ",
        f"Commit: {commit_short()}. Machine: {machine_text()}. {len(episodes)} episodes.",
        "",
    ]
    if note:
        lines += [note, ""]
    (out / "README.md").write_text("\n".join(lines + body))
    print(f"wrote {out / 'README.md'}")
    return out / "README.md"
