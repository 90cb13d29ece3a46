"""What a dataset generator returns, the README (dataset card) it writes beside the files,
checking a folder for an earlier generated dataset, and writing a new one through a temporary
sibling folder so that an interrupted or failed generation leaves the folder as it was."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from iplanner_torch.data.io import PARTIAL_MARK, demonstration_files
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.interrupts import interrupts_deferred

#: The dataset card's file name, in the dataset folder.
CARD_NAME = "README.md"
#: The line under the card's heading that marks a README as a generated dataset card.
CARD_MARK = "Generated; do not edit by hand."
#: The line that opens the card's JSON block of generator settings.
SETTINGS_MARK = "Generator settings (JSON):"


@dataclass(frozen=True, kw_only=True)
class DatasetSummary:
    """Counts and costs of one generated dataset.

    Attributes:
        out_dir: the folder written.
        files: the demonstration files, in generation order.
        n_demonstrations: number of demonstrations (files).
        n_frames: frames over all demonstrations.
        seconds: wall-clock generation time [s].
        bytes_on_disk: total size of the demonstration files [bytes].
    """

    out_dir: Path
    files: tuple[Path, ...]
    n_demonstrations: int
    n_frames: int
    seconds: float
    bytes_on_disk: int

    @classmethod
    def of_files(
        cls, out_dir: Path, files: Sequence[Path], n_frames: int, seconds: float
    ) -> DatasetSummary:
        """The summary of the demonstration ``files`` just written into ``out_dir``: their
        count and total size are read from the list and the disk."""
        return cls(
            out_dir=out_dir,
            files=tuple(files),
            n_demonstrations=len(files),
            n_frames=n_frames,
            seconds=seconds,
            bytes_on_disk=sum(f.stat().st_size for f in files),
        )


def generator_settings(cfg: Any) -> dict[str, Any]:
    """A generator config dataclass as the JSON-plain dict the card keeps (tuples as lists)."""
    return json.loads(json.dumps(dataclasses.asdict(cfg), default=str))


def write_dataset_card(
    summary: DatasetSummary,
    *,
    title: str,
    facts: Sequence[tuple[str, str]],
    command: str,
    settings: dict[str, Any] | None = None,
) -> Path:
    """Write ``summary.out_dir / README.md``: a table of facts, counts, cost and the command.

    Args:
        summary: the generated dataset.
        title: the card's heading.
        facts: (name, value) rows (actions, fps, noise, seed ...).
        command: how to regenerate the dataset.
        settings: the generator's settings (:func:`generator_settings`), kept as a JSON block
            that :func:`read_generator_settings` reads back.

    Returns:
        The README path.
    """
    rows = [
        ("demonstrations", str(summary.n_demonstrations)),
        ("frames", str(summary.n_frames)),
        *facts,
        ("generation time", f"{summary.seconds:.2f} s"),
        ("size on disk", f"{summary.bytes_on_disk / 1e6:.2f} MB"),
    ]
    lines = [
        f"# {title}",
        "",
        f"{CARD_MARK} File format: see `datasets/README.md` of the project.",
        "",
        "| field | value |",
        "|---|---|",
        *(f"| {k} | {v} |" for k, v in rows),
        "",
        "Regenerate with:",
        "",
        "```",
        command,
        "```",
        "",
    ]
    if settings is not None:
        lines += [SETTINGS_MARK, "", "```json", json.dumps(settings, indent=2), "```", ""]
    path = summary.out_dir / CARD_NAME
    path.write_text("\n".join(lines))
    return path


def read_generator_settings(folder: str | Path) -> dict[str, Any] | None:
    """The generator settings a dataset folder's card keeps, or None.

    None when the folder has no generated dataset card, or a card written before the cards
    kept their settings.

    Raises:
        DataError: when the card has a settings block that does not read as a JSON object
            (edited by hand, or nested too deep to decode), naming the card and what is
            wrong.
    """
    card = Path(folder) / CARD_NAME
    if not is_dataset_card(card):
        return None
    text = card.read_text(errors="replace")
    _, mark, rest = text.partition(SETTINGS_MARK)
    if not mark:
        return None
    _, fence, body = rest.partition("```json")
    block, end, _ = body.partition("```")
    fix = (
        "repair it, or generate the dataset anew (iplanner-data generate data.path=<folder> "
        "data.overwrite=true)"
    )
    if not (fence and end):
        raise DataError(f"{card}: the {SETTINGS_MARK!r} block has no ```json ... ``` fence; {fix}")
    try:
        settings = json.loads(block)
    except json.JSONDecodeError as err:
        raise DataError(
            f"{card}: the generator settings block is not valid JSON ({err.msg} at line "
            f"{err.lineno}, column {err.colno} of the block); {fix}"
        ) from err
    except RecursionError as err:
        raise DataError(
            f"{card}: the generator settings block is not valid JSON (nested too deep); {fix}"
        ) from err
    if not isinstance(settings, dict):
        raise DataError(
            f"{card}: the generator settings block holds a {type(settings).__name__}, not a "
            f"JSON object; {fix}"
        )
    return settings


def read_card_counts(folder: str | Path) -> dict[str, int] | None:
    """The demonstration and frame counts a dataset folder's card records, or None.

    Returns:
        ``{"demonstrations": n, "frames": t}`` from the card's table (a count the card lacks,
        or one edited into something other than an integer, is left out); None without a
        generated dataset card.
    """
    card = Path(folder) / CARD_NAME
    if not is_dataset_card(card):
        return None
    counts: dict[str, int] = {}
    for line in card.read_text(errors="replace").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 2 and cells[0] in ("demonstrations", "frames") and cells[1].isdigit():
            counts.setdefault(cells[0], int(cells[1]))
    return counts


def card_mismatch(folder: str | Path, n_demonstrations: int, n_frames: int) -> str | None:
    """How the demonstrations read from ``folder`` differ from what its card records (files
    removed, added or replaced since generation), or None when they agree or there is no
    card to compare with."""
    counts = read_card_counts(folder)
    if not counts:
        return None
    found = {"demonstrations": n_demonstrations, "frames": n_frames}
    if all(counts[k] == found[k] for k in counts):
        return None
    card = ", ".join(f"{v} {k}" for k, v in counts.items())
    read = ", ".join(f"{found[k]} {k}" for k in counts)
    return (
        f"{Path(folder) / CARD_NAME} records {card} but the folder holds {read}: files were "
        "removed, added or replaced since it was generated"
    )


def is_dataset_card(path: str | Path) -> bool:
    """Whether ``path`` is a file written by :func:`write_dataset_card`."""
    path = Path(path)
    try:
        head = path.read_text(errors="replace")[:4096]
    except OSError:
        return False
    return path.is_file() and CARD_MARK in head


def check_dataset_folder(out_dir: str | Path, *, overwrite: bool) -> tuple[Path, ...]:
    """Check that a generator may write ``out_dir``, and say what a new dataset replaces there.

    An earlier dataset is the demonstration files the loader would read from the folder
    (``.npz`` / ``.csv``, sub-folders included) and its dataset card (``README.md``); writing
    a new one over it would mix old and new files. Nothing is deleted here: pass the result as
    ``replace=`` to the generator, which deletes them only once the new dataset is complete.

    Args:
        out_dir: the folder a generator is about to write (need not exist).
        overwrite: replace an earlier dataset instead of refusing.

    Returns:
        The earlier demonstration files and dataset card (empty when there are none).

    Raises:
        ConfigError: when the folder holds demonstration files and ``overwrite`` is false, or
            holds a ``README.md`` that is not a dataset card (it would be overwritten).
    """
    out_dir = Path(out_dir)
    if not out_dir.exists():
        return ()
    if not out_dir.is_dir():
        raise ConfigError(f"{out_dir}: not a folder; choose another data.path")
    files = demonstration_files(out_dir)
    card = out_dir / CARD_NAME
    if card.exists() and not is_dataset_card(card):
        raise ConfigError(
            f"{card} is not a dataset card and generating would overwrite it; choose another "
            "data.path"
        )
    if files and not overwrite:
        raise ConfigError(
            f"{out_dir} already holds {len(files)} demonstration file(s) from an earlier run; "
            "pass data.overwrite=true to replace them (only demonstration files and the dataset "
            "card are deleted) or choose another data.path"
        )
    if not files:
        return ()
    return (*files, card) if card.exists() else tuple(files)


def prepare_dataset_folder(out_dir: str | Path, *, overwrite: bool) -> tuple[Path, ...]:
    """:func:`check_dataset_folder`, then delete what it returns at once.

    Prefer passing :func:`check_dataset_folder`'s result as a generator's ``replace=``, which
    keeps the earlier dataset until the new one is complete.

    Returns:
        The files deleted (empty when there was nothing to clear).

    Raises:
        ConfigError: as :func:`check_dataset_folder`.
    """
    removed = check_dataset_folder(out_dir, overwrite=overwrite)
    for f in removed:
        f.unlink()
    return removed


def partial_folder(out_dir: str | Path) -> Path:
    """The temporary sibling folder a generation of ``out_dir`` by this process writes:
    ``<name>.partial-<pid>`` beside it (same file system, so moving its files is atomic).
    The loader never reads it (:func:`iplanner_torch.data.io.demonstration_files`)."""
    out_dir = Path(os.path.abspath(out_dir))  # "." and "a/.." get their real name
    return out_dir.parent / f"{out_dir.name}{PARTIAL_MARK}{os.getpid()}"


@contextmanager
def staged_dataset(out_dir: str | Path) -> Iterator[Path]:
    """A fresh :func:`partial_folder` for a generator to write a whole dataset into.

    When the block raises or is interrupted, the folder is deleted (best effort) and
    ``out_dir`` is left as it was; on success the caller moves the files into place with
    :func:`finish_staged_dataset`.

    Yields:
        The temporary folder (created, empty).
    """
    staging = partial_folder(out_dir)
    if staging.exists():  # left by an earlier process with the same id (killed outright)
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    try:
        yield staging
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def finish_staged_dataset(
    summary: DatasetSummary, out_dir: str | Path, *, replace: Sequence[Path] = ()
) -> DatasetSummary:
    """Move a complete dataset written into a :func:`staged_dataset` folder into ``out_dir``.

    Every file of ``summary.out_dir`` moves into ``out_dir`` (a rename each, a same-named file
    replaced, the dataset card last; the whole folder at once when ``out_dir`` does not
    exist), then the files of ``replace`` (an earlier dataset's, :func:`check_dataset_folder`)
    that were not replaced are deleted and the temporary folder is removed. Ctrl-C and SIGTERM
    wait until this is done, so an interrupt never leaves old and new files mixed.

    Args:
        summary: the dataset as written into the temporary folder.
        out_dir: the destination folder.
        replace: files in ``out_dir`` to delete.

    Returns:
        ``summary`` with the files' final paths.
    """
    staging, out_dir = summary.out_dir, Path(out_dir)
    moved = 0
    with interrupts_deferred():
        try:
            if not out_dir.exists() and _rename_folder(staging, out_dir):
                moved = len(summary.files)
            else:
                written = set()
                # the card last: a folder with a new card holds the whole new set
                for f in sorted(staging.rglob("*"), key=lambda f: (f.name == CARD_NAME, f)):
                    if f.is_file():
                        dest = out_dir / f.relative_to(staging)
                        dest.parent.mkdir(parents=True, exist_ok=True)
                        shutil.move(f, dest)  # a rename replacing dest (across devices a copy)
                        written.add(dest)
                        moved += 1
                for f in replace:
                    if f not in written:
                        f.unlink(missing_ok=True)
                shutil.rmtree(staging)
        except BaseException:
            if not moved:  # out_dir untouched: the earlier dataset is kept as it was
                shutil.rmtree(staging, ignore_errors=True)
            raise
    return dataclasses.replace(
        summary,
        out_dir=out_dir,
        files=tuple(out_dir / f.relative_to(staging) for f in summary.files),
    )


def _rename_folder(src: Path, dest: Path) -> bool:
    """Rename folder ``src`` to ``dest`` in one step; False when ``dest`` appeared meanwhile
    (another process generating the same missing dataset finished first)."""
    try:
        os.replace(src, dest)
    except OSError:
        if dest.is_dir():
            return False
        raise
    return True
