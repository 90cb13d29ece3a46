"""What a dataset generator returns, and the README (dataset card) it writes beside the files."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path


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


def write_dataset_card(
    summary: DatasetSummary,
    *,
    title: str,
    facts: Sequence[tuple[str, str]],
    command: str,
) -> Path:
    """Write ``summary.out_dir / README.md``: a table of facts, counts, cost and the command.

    Args:
        summary: the generated dataset.
        title: the card's heading.
        facts: (name, value) rows (actions, fps, noise, seed ...).
        command: how to regenerate the dataset.

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
        "Generated; do not edit by hand. File format: see `datasets/README.md` of the project.",
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
    path = summary.out_dir / "README.md"
    path.write_text("\n".join(lines))
    return path
