"""What a dataset generator returns, the README (dataset card) it writes beside the files, and
clearing a folder of an earlier generated dataset before writing a new one."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from iplanner_torch.data.io import demonstration_files
from iplanner_torch.errors import ConfigError, DataError

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


def is_dataset_card(path: str | Path) -> bool:
    """Whether ``path`` is a file written by :func:`write_dataset_card`."""
    path = Path(path)
    try:
        head = path.read_text(errors="replace")[:4096]
    except OSError:
        return False
    return path.is_file() and CARD_MARK in head


def prepare_dataset_folder(out_dir: str | Path, *, overwrite: bool) -> tuple[Path, ...]:
    """Make ``out_dir`` ready for a generator: refuse, or clear an earlier generated dataset.

    An earlier dataset is the demonstration files the loader would read from the folder
    (``.npz`` / ``.csv``, sub-folders included) and its dataset card (``README.md``); writing
    a new one over it would mix old and new files. Nothing else in the folder is touched.

    Args:
        out_dir: the folder a generator is about to write (need not exist).
        overwrite: delete the earlier demonstration files and dataset card instead of refusing.

    Returns:
        The files deleted (empty when there was nothing to clear).

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
    removed = [*files, card] if card.exists() else files
    for f in removed:
        f.unlink()
    return tuple(removed)
