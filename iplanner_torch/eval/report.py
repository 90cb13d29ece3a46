"""Tables and plots of closed-loop sweeps, and the paper's numbers to compare with.

Per-episode results come from episode logs (``.mcap``, read with
:func:`~iplanner_torch.recording.reader.read_episode`), JSON files or dicts; one row per
episode holds the episode's metadata (flattened with ``.``) and its metrics, whose ``eval/``
prefix is dropped (``eval/smoothness`` -> ``smoothness``). Group keys default to the metadata
keys ``scenario`` and ``planner``.

Every table counts its episodes the same way: ``episodes`` (all of them), ``contact_free``
(episodes whose contact is known and none occurred: the robot's and the person's sphere models
never overlapped, ``min_distance > 0``, a stricter test than MuJoCo's contacts),
``contact_unknown`` (episodes whose contact is unknown, e.g. read from a log truncated before
its metrics; counted neither as contact-free nor as contact), when the results have a
``completed`` column, ``completed`` (episodes known to have finished their tasks before their
time ran out; an unfinished episode has no efficiency), and, when they have MuJoCo's own
count (``sim/contacts``), ``touched`` (episodes with a MuJoCo robot-human contact).

Units are SI throughout, including the paper's table (its centimetres are stored as metres),
except in :func:`comparison_table`, which shows the paper's units (cm, ms).
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
import reprlib
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from iplanner_torch.errors import ConfigError, DataError, DataWarning
from iplanner_torch.files import whole_file
from iplanner_torch.recording.reader import EPISODE_METADATA_NAME, Episode, read_episode

__all__ = [
    "DEFAULT_METRICS",
    "DISPLAY_SCALE",
    "PLANNERS",
    "PAPER_SCENARIOS",
    "gather_results",
    "summary_table",
    "in_display_units",
    "comparison_table",
    "paired_differences",
    "paired_table",
    "paired_skip_note",
    "plot_paired",
    "TABLE_COLUMNS",
    "episode_contact",
    "incomplete_logs_note",
    "overrun_note",
    "to_markdown",
    "format_table",
    "print_table",
    "comparison_key",
    "plot_comparison",
    "spread_note",
    "plot_sweep",
    "write_sweep_report",
    "report_groups",
    "ordered_values",
    "natural_key",
    "PLANNER_ORDER",
    "SPEED_ORDER",
    "paper_table_simulation",
    "side_by_side",
]

#: Whether a larger value of a metric is the better one (the paired tables' ``better`` count):
#: farther from the person and more efficient, but smoother, less jerky, a closer forecast and
#: a faster prediction are smaller.
HIGHER_IS_BETTER: dict[str, bool] = {
    "min_distance": True,
    "body_distance": True,
    "efficiency": True,
    "smoothness": False,
    "jerkiness": False,
    "mhd": False,
    "prediction_ms": False,
}

#: Metrics summarised by default, in display order, with their axis labels (in the units
#: they are shown in: see :data:`DISPLAY_SCALE`).
DEFAULT_METRICS: dict[str, str] = {
    "smoothness": "smoothness [rad²/s⁴]",
    "jerkiness": "jerkiness [rad²/s⁴]",
    "min_distance": "closest distance [cm]",
    "efficiency": "efficiency (alone / with robot)",
    "mhd": "prediction MHD [cm]",
    "prediction_ms": "prediction time [ms]",
}

#: Metrics that plots and ``results.md`` show in other units than their ``results.csv``
#: columns (SI, as :func:`summary_table` returns them): metric -> (unit, factor from SI).
#: Distances are shown in cm, as the comparison table and the paper give them.
DISPLAY_SCALE: dict[str, tuple[str, float]] = {
    "min_distance": ("cm", 100.0),
    "body_distance": ("cm", 100.0),
    "mhd": ("cm", 100.0),
}


def _shown(metric: str, values: Any) -> Any:
    """``values`` of ``metric`` in the units plots and ``results.md`` show it in."""
    return values * DISPLAY_SCALE[metric][1] if metric in DISPLAY_SCALE else values


def in_display_units(summary: pd.DataFrame) -> pd.DataFrame:
    """:func:`summary_table`'s output in the units of :data:`DISPLAY_SCALE`: each such
    metric's ``<m>_mean`` and ``<m>_std`` scaled and renamed ``<m> <unit>_mean`` and
    ``<m> <unit>_std`` (so :func:`to_markdown` heads the column ``min_distance cm``); the
    other columns as they are."""
    out = summary.copy()
    renames = {}
    for m, (unit, _) in DISPLAY_SCALE.items():
        for part in ("mean", "std"):
            col = f"{m}_{part}"
            if col in out.columns:
                out[col] = _shown(m, pd.to_numeric(out[col], errors="coerce"))
                renames[col] = f"{m} {unit}_{part}"
    return out.rename(columns=renames)


#: Columns of :func:`comparison_table` in the paper's units: metric -> (header, scale from SI).
#: ``distance cm`` is the closest distance of the sphere models (the paper's metric); ``body
#: cm`` the closest of the robot's MuJoCo geoms to the person's capsules (``sim/body_distance``).
TABLE_COLUMNS: dict[str, tuple[str, float]] = {
    "prediction_ms": ("pred. ms", 1.0),
    "mhd": ("MHD cm", 100.0),
    "smoothness": ("smoothness", 1.0),
    "jerkiness": ("jerkiness", 1.0),
    "min_distance": ("distance cm", 100.0),
    "body_distance": ("body cm", 100.0),
    "efficiency": ("efficiency", 1.0),
    "waits": ("waits", 1.0),
}

#: Planner keys and the paper's names for them.
PLANNERS: dict[str, str] = {
    "itomp": "ITOMP",
    "iplanner_no_ni": "I-Planner, no NI",
    "iplanner_ni": "I-Planner, NI",
}

#: Display order of the planners (the paper's three, the I-Planner on a constant-velocity
#: forecast, then the two references: the oracle bound and the robot that ignores the person).
PLANNER_ORDER: tuple[str, ...] = (*PLANNERS, "iplanner_cv", "oracle", "blind")
#: The human speeds in their natural order; summary rows and plots follow it.
SPEED_ORDER: tuple[str, ...] = ("slow", "medium", "fast")

#: Paper table performance: scenario key -> (label, arrangement, task order, confidence).
PAPER_SCENARIOS: dict[str, tuple[str, str, str, float]] = {
    "arrangements_1": ("Different Arrangements (1)", "1x4", "(0,1)->(2,3)", 0.95),
    "arrangements_2": ("Different Arrangements (2)", "2x2", "(1,5)->(2,6)", 0.95),
    "arrangements_3": ("Different Arrangements (3)", "2x4", "(0,4)->(1,5)->(2,6)->(3,7)", 0.95),
    "temporal_coherence_1": ("Temporal Coherence (1)", "1x4", "0->1->2->3", 0.95),
    "temporal_coherence_2": ("Temporal Coherence (2)", "1x4", "random", 0.95),
    "temporal_coherence_3": ("Temporal Coherence (3)", "1x4", "(0,2)->(1,3)", 0.95),
    "confidence_level_1": ("Confidence Level (1)", "1x4", "0->(1,2)->3", 0.90),
    "confidence_level_2": ("Confidence Level (2)", "1x4", "0->(1,2)->3", 0.95),
    "confidence_level_3": ("Confidence Level (3)", "1x4", "0->(1,2)->3", 0.99),
}

# Paper table performance_simulation, row by row: prediction time [ms] (None: N/A), MHD [cm]
# (None: N/A), smoothness, jerkiness, distance [cm], efficiency; planners in PLANNERS order.
_PAPER_SIM_ROWS: dict[str, tuple[tuple[float | None, ...], ...]] = {
    "arrangements_1": (
        (None, None, 2.96, 5.23, 3.2, 1.2),
        (52.0, 6.7, 1.08, 1.52, 6.7, 1.6),
        (58.5, 7.2, 0.92, 1.03, 8.1, 1.7),
    ),
    "arrangements_2": (
        (None, None, 5.78, 7.19, 2.3, 1.1),
        (72.4, 6.2, 1.04, 1.60, 8.2, 1.6),
        (70.8, 7.0, 0.84, 1.32, 10.7, 1.6),
    ),
    "arrangements_3": (
        (None, None, 4.82, 6.82, 1.6, 1.2),
        (169.0, 10.4, 1.15, 1.30, 6.2, 1.6),
        (150.0, 12.6, 1.02, 1.20, 8.9, 1.6),
    ),
    "temporal_coherence_1": (
        (None, None, 1.79, 3.22, 6.0, 1.3),
        (52.1, 4.3, 0.65, 1.56, 9.3, 1.5),
        (48.9, 5.2, 0.62, 1.53, 9.7, 1.5),
    ),
    "temporal_coherence_2": (
        (None, None, 5.49, 7.30, 2.0, 1.0),
        (105.0, 8.2, 1.21, 1.28, 8.8, 1.6),
        (110.0, 9.9, 1.08, 1.10, 9.9, 1.6),
    ),
    "temporal_coherence_3": (
        (None, None, 3.12, 3.18, 8.0, 1.3),
        (51.7, 6.8, 1.00, 1.20, 12.1, 1.5),
        (60.0, 8.2, 0.79, 0.93, 13.2, 1.5),
    ),
    "confidence_level_1": (
        (None, None, 2.90, 3.40, 7.2, 1.2),
        (47.2, 7.9, 1.17, 1.58, 9.5, 1.6),
        (52.1, 9.1, 1.08, 1.32, 10.2, 1.7),
    ),
    "confidence_level_2": (
        (None, None, 3.12, 3.80, 10.3, 1.2),
        (50.7, 7.9, 1.28, 1.71, 13.3, 1.6),
        (48.2, 9.1, 1.20, 1.66, 14.1, 1.8),
    ),
    "confidence_level_3": (
        (None, None, 3.76, 4.33, 13.0, 1.2),
        (155.0, 7.9, 1.40, 1.90, 16.2, 1.7),
        (129.0, 9.1, 1.35, 1.73, 17.7, 1.8),
    ),
}

_METRIC_PREFIX = "eval/"


# ---------------------------------------------------------------------------------------------
# Gathering


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{key}."))
        elif isinstance(v, list | tuple):
            out[key] = str(tuple(v))
        else:
            out[key] = v
    return out


def _metric_name(key: str) -> str:
    return key[len(_METRIC_PREFIX) :] if key.startswith(_METRIC_PREFIX) else key


def _row_of_dict(d: Mapping[str, Any]) -> dict[str, Any]:
    if "metadata" in d and "metrics" in d:  # {"metadata": {...}, "metrics": {...}} form
        row = _flatten(d["metadata"])
        row.update({_metric_name(k): v for k, v in _flatten(d["metrics"]).items()})
        return row
    return {_metric_name(k): v for k, v in _flatten(d).items()}


def _read_log(p: Path) -> Episode:
    """:func:`read_episode` of ``p``, refusing another program's MCAP file
    (:attr:`Episode.foreign <iplanner_torch.recording.reader.Episode>`) with a DataError instead
    of its warning; the reader's other warnings are passed on."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ep = read_episode(p)
    if ep.foreign:
        raise DataError(
            f"{p}: not an iplanner episode log (a valid MCAP file with no "
            f"{EPISODE_METADATA_NAME} metadata record: written by another program?)"
        )
    for w in caught:
        warnings.warn(w.message, w.category, stacklevel=3)
    return ep


def _row_of_path(p: Path) -> dict[str, Any]:
    if p.suffix == ".mcap":
        ep = _read_log(p)
        row = _flatten(ep.metadata)
        row.update({_metric_name(k): v for k, v in _flatten(ep.metrics()).items()})
        row["complete"] = ep.complete
        row["interrupted"] = ep.interrupted
    elif p.suffix == ".json":
        try:
            record = json.loads(p.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise DataError(f"{p}: not valid JSON: {err}") from err
        if not isinstance(record, dict):
            raise DataError(f"{p}: expected a JSON object of metrics, got {type(record).__name__}")
        if "metadata" in record and "metrics" in record:  # the {"metadata", "metrics"} form
            for key in ("metadata", "metrics"):
                if not isinstance(record[key], dict):
                    raise DataError(
                        f"{p}: expected {key!r} to be a JSON object, got "
                        f"{type(record[key]).__name__}"
                    )
        row = _row_of_dict(record)
    else:
        raise DataError(
            f"{p}: expected a .mcap episode log, a .json result file or a results .csv"
        )
    row["path"] = str(p)
    return row


def _short_rows(p: Path, text: str) -> str:
    """``text`` of the results CSV ``p``, checked for rows whose cells do not match its header.

    Rows with fewer cells than the header (which pandas would fill with NaN unsaid): a last
    row cut short (no line end: the writer stopped inside it, so even its last cell may be
    cut) is left out, other short rows are kept with their missing cells read as missing;
    each with a :class:`DataWarning`. Rows with more cells than the header (a note typed after
    the last cell) cannot be assigned to columns, and pandas would read the first column as
    the index and shift every other one place left: they are refused, unless their extra
    cells are all empty (a trailing separator, which loses nothing).

    Raises:
        DataError: on a row with more non-empty cells than the header, naming the file rows,
            or a header of one cell holding ``;`` or a tab (a file saved with another
            separator than ``,``).
    """
    reader = csv.reader(io.StringIO(text))
    try:
        records = [(reader.line_num, row) for row in reader]
    except csv.Error:
        return text  # pandas names the fault
    records = [(n, row) for n, row in records if row]  # blank lines are skipped
    if not records:
        return text
    header = records[0][1]
    if len(header) == 1 and any(sep in header[0] for sep in (";", "\t")):
        sep = "';'" if ";" in header[0] else "a tab"
        raise DataError(
            f"{p}: not a comma-separated results CSV: its header is one cell holding {sep} "
            "(saved by a spreadsheet with another separator?); save it with ',' as the "
            "separator and '.' as the decimal point"
        )
    if len(records) < 2:
        return text
    width = len(header)
    long = [n for n, row in records[1:] if len(row) > width and any(c for c in row[width:])]
    if long:
        raise DataError(
            f"{p}: {len(long)} row(s) have more cells than the header's {width} (file rows "
            f"{long[:5]}{' ...' if len(long) > 5 else ''}), so their cells cannot be assigned "
            "to columns; remove the extra cells (e.g. a note typed after the last one)"
        )
    short = [(n, len(row)) for n, row in records[1:] if len(row) < width]
    if short and short[-1][0] == records[-1][0] and not text.endswith(("\n", "\r")):
        line, cells = short.pop()
        warnings.warn(
            f"{p}: the last row (file row {line}) is cut short ({cells} of {width} cells and "
            "no line end: the file was being written); left out",
            DataWarning,
            stacklevel=4,
        )
        text = "".join(io.StringIO(text).readlines()[: records[-2][0]])
    if short:
        warnings.warn(
            f"{p}: {len(short)} row(s) have fewer cells than the header's {width} (file rows "
            f"{[n for n, _ in short[:5]]}); their missing cells are read as missing",
            DataWarning,
            stacklevel=4,
        )
    return text


def _rows_of_csv(p: Path) -> list[dict[str, Any]]:
    """The rows of a results CSV (an experiment's episode rows, ``eval/<name>`` columns, or a
    gathered table, ``<name>`` columns), in file order, named as :func:`gather_results`
    names them; an empty cell is NaN, and so is a metric cell (a ``stage/name`` column or one
    of :data:`DEFAULT_METRICS`) that is not a number, with a :class:`DataWarning` naming the
    file rows; so are the cells missing from a row shorter than the header, while a last row
    cut short by a stopped writer is left out, and a row longer than the header is refused
    (:func:`_short_rows`). No ``path`` column is added (a row is not the CSV's episode; the
    CSV's own ``path`` column, if any, is kept)."""
    try:
        text = p.read_text(encoding="utf-8-sig")
        text = _short_rows(p, text)
        # index_col=False: never take the first column as the index (which shifts the others)
        df = pd.read_csv(io.StringIO(text), index_col=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
        raise DataError(f"{p}: not a readable results CSV: {err}") from err
    for col in df.columns:  # metric columns: a cell that is not a number is read as missing
        if not _is_metric_column(col):
            continue
        values = pd.to_numeric(df[col], errors="coerce")
        bad = values.isna() & df[col].notna()
        if bool(bad.any()):
            rows = [int(i) + 2 for i in df.index[bad][:5]]
            warnings.warn(
                f"{p}: {int(bad.sum())} value(s) of {col!r} are not numbers (file rows "
                f"{rows}); read as missing",
                DataWarning,
                stacklevel=3,
            )
        df[col] = values
    return [_row_of_dict(r) for r in df.to_dict("records")]


#: the folder of a run where a resumed run keeps the logs of the episodes that were cut
#: short (``iplanner-experiment run.resume=true``); folder reads leave it out
INTERRUPTED_DIR = "interrupted"


def episode_logs(folder: Path) -> list[Path]:
    """Every ``*.mcap`` below ``folder`` in numbered order (:func:`natural_key`), but for those
    in an :data:`INTERRUPTED_DIR` folder: logs of episodes that were run again."""
    folder = Path(folder)
    return sorted(
        (
            f
            for f in folder.rglob("*.mcap")
            if INTERRUPTED_DIR not in f.relative_to(folder).parts[:-1]
        ),
        key=natural_key,
    )


def _rows_of_folder(folder: Path) -> list[dict[str, Any]]:
    """The rows of every episode log below ``folder`` (:func:`episode_logs`); a file that
    cannot be read or is not an episode log is left out, and all such files are named in one
    :class:`DataWarning`."""
    rows, skipped = [], []
    for f in episode_logs(folder):
        try:
            rows.append(_row_of_path(f))
        except DataError as err:
            skipped.append(str(err))
    if skipped:
        listed = "; ".join(skipped[:5]) + (
            f"; and {len(skipped) - 5} more" if len(skipped) > 5 else ""
        )
        warnings.warn(
            f"{folder}: left out {len(skipped)} of its {len(rows) + len(skipped)} .mcap "
            f"file(s), which are not readable episode logs: {listed}",
            DataWarning,
            stacklevel=3,
        )
    return rows


def natural_key(path: str | Path) -> tuple[Any, ...]:
    """Sort key that orders numbered names by number (``multirun/2`` before ``multirun/10``)."""
    parts = re.split(r"(\d+)", str(path))
    return tuple((0, int(t), "") if t.isdigit() else (1, 0, t) for t in parts)


def gather_results(items: Iterable[Mapping[str, Any] | str | Path] | str | Path) -> pd.DataFrame:
    """One row per episode: metadata (scenario keys) and metrics.

    Args:
        items: result dicts (flat, or ``{"metadata": ..., "metrics": ...}``), paths of
            ``.mcap`` episode logs, ``.json`` result files or results ``.csv`` files (every
            row; an empty cell is NaN), or folders (searched recursively for ``*.mcap``), or
            one such path.

    Returns:
        DataFrame, one row per episode, metric columns without the ``eval/`` prefix (so an
        experiment's ``results.csv`` and a table gathered from it read alike); rows read from
        episode logs and JSON files have a ``path`` column. The log metadata's
        ``tracker_noise`` and ``human_speed`` repeat ``noise`` and ``speed``
        (:data:`METADATA_ALIASES`) and are left out where they agree with them.

    Raises:
        DataError: on a missing or unreadable file given by its path, an ``.mcap`` file that
            is not an episode log (not MCAP, or another program's MCAP file), or a results CSV
            with rows longer than its header or another separator than ``,``.

    Warns:
        DataWarning: for the ``*.mcap`` files found in a folder that cannot be read or are not
            episode logs (e.g. a Git LFS pointer never fetched, another program's MCAP file):
            they are left out, named in one warning per folder. A truncated episode log is
            still read (what it holds; see
            :func:`~iplanner_torch.recording.reader.read_episode`). Also for metric values
            (``stage/name`` keys and :data:`DEFAULT_METRICS`) that are not numbers: they are
            read as missing, one warning per metric naming the files or rows.
    """
    if isinstance(items, str | Path):
        items = [items]
    rows: list[dict[str, Any]] = []
    for item in items:
        if isinstance(item, Mapping):
            rows.append(_row_of_dict(item))
            continue
        p = Path(item)
        if p.is_dir():
            rows.extend(_rows_of_folder(p))
        elif p.is_file() and p.suffix == ".csv":
            rows.extend(_rows_of_csv(p))
        elif p.is_file():
            rows.append(_row_of_path(p))
        else:
            raise DataError(f"{p}: no such result file or folder")
    return _numeric_metrics(_drop_aliases(pd.DataFrame.from_records(rows)))


def _is_metric_column(col: Any) -> bool:
    """A metric column: a ``stage/name`` one or one of :data:`DEFAULT_METRICS`."""
    return "/" in str(col) or _metric_name(str(col)) in DEFAULT_METRICS


#: the episode columns (as :func:`gather_results` names them) that count or measure something
#: that cannot be negative: a negative value is read as missing, with a warning
NON_NEGATIVE: frozenset[str] = frozenset(
    {
        "smoothness", "jerkiness", "efficiency", "mhd", "mhd_count", "prediction_ms",
        "task_time_s", "human_alone_s", "contact", "completed", "sim/duration_s",
        "sim/realtime_factor", "sim/contacts", "sim/contact_steps", "plan/cycles",
        "plan/overruns", "plan/cut_short", "plan/waits", "plan/wait_s", "plan/evasions",
        "plan/escapes", "plan/emergencies", "plan/stall_cycles", "plan/mean_solve_ms",
        "task/deferred_fetches", "task/held_s",
    }
)  # fmt: skip
#: columns read as numbers beside the metric columns: the episode's flags
_FLAG_COLUMNS = ("contact", "completed")


def _where(df: pd.DataFrame, bad: pd.Series) -> str:
    """The first rows of ``bad`` (their ``path`` where they have one), for a warning."""
    where = (
        [str(v) for v in df.loc[bad, "path"][:3]]
        if "path" in df.columns
        else [f"row {int(i)}" for i in df.index[bad][:3]]
    )
    return ", ".join(where) + (" ..." if int(bad.sum()) > 3 else "")


def _numeric_metrics(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with every metric column (:func:`_is_metric_column`) and the ``contact`` and
    ``completed`` flags read as numbers: a value that is not a number (a string, a list, a
    dict from a result dict or JSON file) becomes NaN, and so does a negative value of a
    :data:`NON_NEGATIVE` column, with one :class:`DataWarning` per column naming the rows
    (their ``path`` where they have one), so that no mean or count silently leaves it out
    or takes it in."""
    for col in df.columns:
        if not (_is_metric_column(col) or col in _FLAG_COLUMNS):
            continue
        values = df[col]
        if not pd.api.types.is_numeric_dtype(values):
            values = pd.to_numeric(df[col], errors="coerce")
            bad = values.isna() & df[col].notna()
            if bool(bad.any()):
                warnings.warn(
                    f"{int(bad.sum())} value(s) of {col!r} are not numbers ({_where(df, bad)}"
                    f": e.g. {reprlib.repr(df.loc[bad, col].iloc[0])}); read as missing",
                    DataWarning,
                    stacklevel=3,
                )
        if _metric_name(str(col)) in NON_NEGATIVE and not pd.api.types.is_bool_dtype(values):
            negative = values < 0
            if bool(negative.any()):
                warnings.warn(
                    f"{int(negative.sum())} value(s) of {col!r} are negative "
                    f"({_where(df, negative)}: e.g. {values[negative].iloc[0]!r}), which it "
                    "cannot be; read as missing",
                    DataWarning,
                    stacklevel=3,
                )
                values = values.mask(negative)
        df[col] = values
    return df


#: metadata keys an episode log also holds under a second name, with the same value (alias ->
#: the name the tables use); :func:`gather_results` keeps one column of each pair
METADATA_ALIASES: dict[str, str] = {"tracker_noise": "noise", "human_speed": "speed"}


def _drop_aliases(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` without the :data:`METADATA_ALIASES` columns that repeat their named column (a
    value in every row where both have one, and the same); an alias that differs is kept."""
    for alias, name in METADATA_ALIASES.items():
        if alias not in df.columns or name not in df.columns:
            continue
        a, n = df[alias], df[name]
        both = a.notna() & n.notna()
        same = [x == y for x, y in zip(a[both], n[both])]
        if all(same):
            df = df.assign(**{name: n.where(n.notna(), a)}).drop(columns=alias)
    return df


# ---------------------------------------------------------------------------------------------
# Tables


def _check_columns(df: pd.DataFrame, cols: Sequence[str], what: str) -> None:
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise ConfigError(f"{what} {missing} not in the results' columns {list(df.columns)}")


def _default_metrics(df: pd.DataFrame, exclude: Sequence[str]) -> list[str]:
    known = [m for m in DEFAULT_METRICS if m in df.columns]
    if known:
        return known
    skip = set(exclude) | {"contact", "seed", "complete", "completed"}
    return [c for c in df.columns if c not in skip and pd.api.types.is_numeric_dtype(df[c])]


def ordered_values(column: str, values: Iterable[Any]) -> list[Any]:
    """The distinct ``values`` of a group column in display order.

    Speeds run slow, medium, fast; planners follow :data:`PLANNER_ORDER`; numbers ascend;
    anything else keeps its order of first appearance (e.g. the paper's scenario order).
    Values outside a known order follow it, in order of first appearance.
    """
    distinct = list({_hashable(v): v for v in values}.values())
    known = {"speed": SPEED_ORDER, "human_speed": SPEED_ORDER, "planner": PLANNER_ORDER}.get(
        column
    )
    if known is not None:
        rank = {v: i for i, v in enumerate(known)}
        return sorted(distinct, key=lambda v: rank.get(v, len(rank)))
    if distinct and all(
        isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
        for v in distinct
    ):
        return sorted(distinct, key=lambda v: (math.isnan(float(v)), float(v)))
    return distinct


def _sort_groups(df: pd.DataFrame, group_by: Sequence[str]) -> pd.DataFrame:
    """Rows of ``df`` sorted by ``group_by`` in the display order of :func:`ordered_values`."""
    if df.empty:
        return df
    keys = {}
    for c in group_by:
        rank = {_hashable(v): i for i, v in enumerate(ordered_values(c, df[c]))}
        keys[f"__rank_{c}"] = [rank[_hashable(v)] for v in df[c]]
    ranked = df.assign(**keys)
    return ranked.sort_values(list(keys), kind="stable").drop(columns=list(keys))


def _hashable(v: Any) -> Any:
    # NaN != NaN: one key for every missing value
    return "__nan__" if isinstance(v, float) and math.isnan(v) else v


def episode_contact(df: pd.DataFrame) -> pd.Series:
    """Per episode, whether the robot touched the person: 1.0 contact, 0.0 none, NaN unknown.

    The ``contact`` column decides where it holds a value; otherwise ``min_distance`` does
    (``<= 0``: contact). An episode with neither (a log truncated before its metrics, a NaN
    distance) is unknown, never a contact.
    """
    state = pd.Series(math.nan, index=df.index, dtype=float)
    if "min_distance" in df.columns:
        d = pd.to_numeric(df["min_distance"], errors="coerce")
        state = state.mask(d.notna(), (d <= 0).astype(float))
    if "contact" in df.columns:
        c = pd.to_numeric(df["contact"], errors="coerce")
        state = state.mask(c.notna(), (c > 0).astype(float))
    return state


#: the column of MuJoCo robot-human contacts per episode (the simulation's own count)
MUJOCO_CONTACTS = "sim/contacts"


def _episode_counts(
    g: pd.DataFrame, with_completed: bool, with_touched: bool = False
) -> dict[str, int]:
    """``episodes``, ``contact_free``, ``contact_unknown`` (and ``completed``, and
    ``touched``: episodes with a MuJoCo robot-human contact) of one group."""
    contact = episode_contact(g)
    counts = {
        "episodes": len(g),
        "contact_free": int((contact == 0).sum()),
        "contact_unknown": int(contact.isna().sum()),
    }
    if with_completed:
        counts["completed"] = int((pd.to_numeric(g["completed"], errors="coerce") > 0).sum())
    if with_touched:
        counts["touched"] = int((pd.to_numeric(g[MUJOCO_CONTACTS], errors="coerce") > 0).sum())
    return counts


def _has_touched(df: pd.DataFrame) -> bool:
    """Whether ``df`` counts MuJoCo contacts for at least one episode."""
    return MUJOCO_CONTACTS in df.columns and bool(
        pd.to_numeric(df[MUJOCO_CONTACTS], errors="coerce").notna().any()
    )


def incomplete_logs_note(df: pd.DataFrame) -> str:
    """A sentence naming how many episodes came from truncated or damaged logs, and how many
    were interrupted before their end ('' if none).

    Args:
        df: per-episode results (:func:`gather_results`; its ``complete`` column is False for
            a log read only up to its last complete chunk, its ``interrupted`` column True for
            a whole log of an episode stopped by Ctrl-C or an error).
    """
    if "complete" not in df.columns:
        return ""
    cut = df["complete"].eq(False)
    stopped = df["interrupted"].eq(True) & ~cut if "interrupted" in df.columns else cut & False
    bad = int(cut.sum())
    if bad + int(stopped.sum()) == 0:
        return ""
    unknown = int(episode_contact(df[cut | stopped]).isna().sum())
    what = [f"truncated or damaged episode logs: {bad} of {len(df)}"] if bad else []
    if stopped.any():
        what.append(f"episodes interrupted before their end: {int(stopped.sum())} of {len(df)}")
    them = "them" if len(what) == 1 else "those"
    return (
        f"{'; '.join(what)}; the contact of {unknown} of {them} is unknown (counted in "
        "contact_unknown, not in contact_free)."
    )


def overrun_note(df: pd.DataFrame) -> str:
    """A sentence naming, per planner, the replanning solves that overran their wall-clock
    budget, and the slowest episode's realtime factor; then one naming the solves stopped at
    their budget (``ReplannerCfg.stop_at_budget``); '' when there are neither.

    The episode loop counts an overrun (``plan/overruns``) but adopts the plan at its
    simulated time all the same, as if the planner were faster than the machine that ran
    it. The note puts that next to the table, since few readers look for it in the CSV.

    Args:
        df: per-episode results (:func:`gather_results`) with a ``planner`` column; uses
            ``plan/overruns``, ``plan/cut_short``, ``plan/cycles``, ``plan/mean_solve_ms``
            and ``sim/realtime_factor`` where present (NaN entries are skipped).
    """
    if "planner" not in df.columns:
        return ""
    cut_parts = _solve_counts(df, "plan/cut_short")
    cut = (
        "Solves stopped iterating at their budget (planner.replanner.stop_at_budget; "
        "plan/cut_short): " + ", ".join(cut_parts) + "."
        if cut_parts
        else ""
    )
    parts = _solve_counts(df, "plan/overruns", mean_solve=True)
    if not parts:
        return cut
    note = "replanning solves over their wall-clock budget: " + ", ".join(parts) + "."
    rt = _numeric(df, "sim/realtime_factor").dropna()
    if len(rt) and float(rt.min()) < 1.0:
        note += f" The slowest episode ran at {float(rt.min()):.2f}x real time."
    note += (
        " Each of those plans was adopted on time all the same, as if the planner were "
        "faster (plan/overruns, plan/mean_solve_ms, sim/realtime_factor in results.csv)."
    )
    return f"{note} {cut}" if cut else note


def _numeric(g: pd.DataFrame, col: str) -> pd.Series:
    """``g[col]`` as numbers (NaN where absent or not a number)."""
    if col not in g.columns:
        return pd.Series(math.nan, index=g.index)
    return pd.to_numeric(g[col], errors="coerce")


def _solve_counts(df: pd.DataFrame, column: str, *, mean_solve: bool = False) -> list[str]:
    """Per planner with a positive sum of the solve counter ``column``: ``"<planner> <n>"``,
    then `` of <cycles>`` where ``plan/cycles`` is known and, with ``mean_solve``, the
    cycle-weighted mean of ``plan/mean_solve_ms`` (NaN entries are skipped); [] without the
    column."""
    if column not in df.columns:
        return []
    parts = []
    for planner in ordered_values("planner", df["planner"].dropna().unique()):
        g = df[df["planner"] == planner]
        n = int(_numeric(g, column).sum(skipna=True))
        if n <= 0:
            continue
        cycles = _numeric(g, "plan/cycles")
        part = f"{planner} {n}"
        if cycles.notna().any():
            part += f" of {int(cycles.sum(skipna=True))}"
        solve = _numeric(g, "plan/mean_solve_ms")
        both = cycles.notna() & solve.notna() & (cycles > 0)
        if mean_solve and both.any():
            mean_ms = float((solve[both] * cycles[both]).sum() / cycles[both].sum())
            part += f" (mean solve {mean_ms:.0f} ms)"
        parts.append(part)
    return parts


#: episode settings a run or sweep may vary; summaries keep their values apart
SWEPT_SETTINGS = ("speed", "noise", "dropout", "confidence")

#: axis labels of the swept settings, with units
SETTING_LABELS: dict[str, str] = {
    "noise": "tracker noise [m]",
    "dropout": "tracker dropout (share of joint-frames lost)",
    "confidence": "confidence level",
    "speed": "human speed",
}

#: scenario settings that one scenario name may be run with in several ways (an override of
#: ``scenario.arrangement`` keeps the name); summaries keep their values apart
SCENARIO_SETTINGS = ("arrangement", "task_order")


def _varies_within_scenario(df: pd.DataFrame, column: str) -> bool:
    """Whether ``column`` takes more than one value within a scenario of ``df`` (within
    ``df`` when it has no ``scenario`` column)."""
    if "scenario" not in df.columns:
        return df[column].nunique(dropna=True) > 1
    per = df.groupby("scenario", sort=False, dropna=False)[column].nunique(dropna=True)
    return bool((per > 1).any())


def report_groups(df: pd.DataFrame) -> tuple[str, ...]:
    """Grouping columns for a summary of ``df``: ``scenario``, each of
    :data:`SCENARIO_SETTINGS` that takes more than one value under one scenario name (a
    scenario run in two arrangements or task orders gives two rows; settings that come with
    the scenario name add no column), ``robot`` and each of :data:`SWEPT_SETTINGS` that takes
    more than one value (so results of two robots, a speed response or a sweep are never
    averaged over their settings), then ``planner``; only the columns present."""
    layout = [c for c in SCENARIO_SETTINGS if c in df.columns and _varies_within_scenario(df, c)]
    swept = [
        c for c in ("robot", *SWEPT_SETTINGS) if c in df.columns and df[c].nunique(dropna=True) > 1
    ]
    groups = tuple(c for c in ("scenario", *layout, *swept, "planner") if c in df.columns)
    return groups or ("planner",)


def summary_table(
    df: pd.DataFrame,
    group_by: Sequence[str] = ("scenario", "planner"),
    metrics: Sequence[str] | None = None,
) -> pd.DataFrame:
    """Mean and standard deviation of each metric per group, with counts.

    Args:
        df: per-episode results (:func:`gather_results`).
        group_by: grouping columns.
        metrics: metric columns (default: those of :data:`DEFAULT_METRICS` present, else every
            numeric column).

    Returns:
        One row per group, in display order (:func:`ordered_values`: speeds slow to fast,
        numbers ascending, planners in :data:`PLANNER_ORDER`, other keys in order of first
        appearance): the group keys, ``episodes``, ``contact_free`` and ``contact_unknown``
        (:func:`episode_contact` 0 and NaN: an episode of unknown contact is not
        contact-free), ``completed`` (episodes with ``completed > 0``; only when ``df`` has
        that column), ``touched`` (episodes with ``sim/contacts > 0``, MuJoCo's robot-human
        contacts; only when ``df`` has that column) and ``<metric>_mean``, ``<metric>_std``
        (sample std; NaN for a single episode). NaN values are left out of means.

    Raises:
        ConfigError: when a group or metric column is missing.
    """
    group_by = list(group_by)
    _check_columns(df, group_by, "group columns")
    metrics = list(metrics) if metrics is not None else _default_metrics(df, group_by)
    _check_columns(df, metrics, "metric columns")

    def stats(g: pd.DataFrame) -> dict[str, float]:
        row = {}
        for m in metrics:
            v = pd.to_numeric(g[m], errors="coerce")
            row[f"{m}_mean"] = float(v.mean())
            row[f"{m}_std"] = float(v.std(ddof=1)) if v.notna().sum() > 1 else math.nan
        return row

    return _per_group(df, group_by, stats)


def _per_group(
    df: pd.DataFrame, group_by: list[str], columns: Callable[[pd.DataFrame], dict[str, float]]
) -> pd.DataFrame:
    """One row per group of ``df``, in display order: the group keys, the episode counts
    (:func:`_episode_counts`) and ``columns(group)``."""
    rows = []
    with_completed, with_touched = "completed" in df.columns, _has_touched(df)
    for keys, g in df.groupby(group_by, sort=False, dropna=False):
        keys = keys if isinstance(keys, tuple) else (keys,)
        row: dict[str, Any] = dict(zip(group_by, keys))
        row.update(_episode_counts(g, with_completed, with_touched))
        row.update(columns(g))
        rows.append(row)
    return _sort_groups(pd.DataFrame.from_records(rows), group_by).reset_index(drop=True)


def paired_differences(
    df: pd.DataFrame,
    metric: str,
    *,
    baseline: str = "itomp",
    group_by: Sequence[str] = ("scenario",),
    pair_on: Sequence[str] = ("seed",),
    level: float = 0.95,
) -> pd.DataFrame:
    """Each planner against ``baseline`` on ``metric``, episode by episode.

    Episodes of a planner and of the baseline that agree in ``group_by`` and ``pair_on`` (the
    same scenario and seed: the same person, noise and task order) form a pair, and the
    differences ``planner - baseline`` are summarised. Pairing removes what the seeds share,
    so a difference shows up with fewer episodes than when comparing the two means.

    Args:
        df: per-episode results (:func:`gather_results`), with a ``planner`` column.
        metric: the metric column (e.g. ``min_distance``).
        baseline: the planner the others are compared with.
        group_by: the columns that define a comparison (one row per group and planner).
        pair_on: the columns that identify an episode within a group.
        level: confidence level of the interval, in (0, 1).

    Returns:
        One row per group and planner other than the baseline, in display order: the group
        keys, ``planner``, ``pairs`` (pairs where both values are known), ``mean_diff``,
        ``ci_low``, ``ci_high`` (Student-t interval of the mean difference; NaN for fewer than
        two pairs), ``p_value`` (two-sided paired t-test; NaN for fewer than two pairs; when
        every difference is the same, 1 if it is 0 and 0 otherwise) and ``better`` (pairs
        where the planner did better than the baseline: a difference > 0 where a larger value
        is better, < 0 where a smaller one is, :data:`HIGHER_IS_BETTER`; ties are not counted;
        NaN for a metric not in that table).

    Raises:
        ConfigError: when a column is missing, ``baseline`` has no episodes, ``level`` is not
            in (0, 1), or an episode appears twice in a group.
    """
    from scipy import stats

    group_by, pair_on = list(group_by), list(pair_on)
    _check_columns(df, [*group_by, *pair_on, "planner", metric], "columns")
    if not 0.0 < level < 1.0:
        raise ConfigError(f"expected level in (0, 1), got {level!r}")
    if not (df["planner"] == baseline).any():
        raise ConfigError(f"no episodes of the baseline planner {baseline!r}")
    keys = [*group_by, *pair_on]
    dup = df.duplicated([*keys, "planner"], keep=False)
    if bool(dup.any()):
        first = df.loc[dup, [*keys, "planner"]].iloc[0].to_dict()
        raise ConfigError(f"episode {first} appears more than once; pairs need one each")
    values = df.assign(_v=pd.to_numeric(df[metric], errors="coerce"))
    base = values[values["planner"] == baseline][[*keys, "_v"]]
    rows = []
    others = values[values["planner"] != baseline]
    for group, g in others.groupby([*group_by, "planner"], sort=False, dropna=False):
        pairs = g[[*keys, "_v"]].merge(base, on=keys, suffixes=("", "_base"))
        d = (pairs["_v"] - pairs["_v_base"]).dropna().to_numpy(dtype=float)
        n = len(d)
        row: dict[str, Any] = dict(zip([*group_by, "planner"], group))
        row.update(pairs=n, mean_diff=float(d.mean()) if n else math.nan)
        lo = hi = p = math.nan
        if n >= 2:
            se = float(d.std(ddof=1)) / math.sqrt(n)
            if se > 0.0:
                half = float(stats.t.ppf(0.5 + level / 2.0, n - 1)) * se
                lo, hi = row["mean_diff"] - half, row["mean_diff"] + half
                p = float(2.0 * stats.t.sf(abs(row["mean_diff"]) / se, n - 1))
            else:  # every difference is the same
                lo = hi = row["mean_diff"]
                p = 1.0 if row["mean_diff"] == 0.0 else 0.0
        higher = HIGHER_IS_BETTER.get(metric)
        better = math.nan if higher is None else int(((d > 0) if higher else (d < 0)).sum())
        row.update(ci_low=lo, ci_high=hi, p_value=p, better=better)
        rows.append(row)
    columns = [*group_by, "planner", "pairs", "mean_diff", "ci_low", "ci_high", "p_value"]
    columns.append("better")
    if not rows:
        return pd.DataFrame(columns=columns)
    out = pd.DataFrame.from_records(rows, columns=columns)
    return _sort_groups(out, [*group_by, "planner"]).reset_index(drop=True)


def _metric_column(df: pd.DataFrame, metric: str) -> str | None:
    """The column of ``metric``: itself, or a ``stage/metric`` column (``plan/waits``)."""
    if metric in df.columns:
        return metric
    return next((str(c) for c in df.columns if str(c).endswith("/" + metric)), None)


def comparison_table(df: pd.DataFrame, group_by: Sequence[str] | None = None) -> pd.DataFrame:
    """The console table of a run: per group, the episode counts and the paper's metrics.

    Shared by ``iplanner-experiment`` and ``iplanner-evaluate evaluate.mode=episode`` so that
    both print the same columns in the same units.

    Args:
        df: per-episode results (:func:`gather_results`).
        group_by: grouping columns (default :func:`report_groups`: settings that take several
            values are kept apart, never averaged over).

    Returns:
        One row per group in display order: the group keys, ``episodes``, ``contact_free``,
        ``contact_unknown``, ``completed``, ``touched`` (as in :func:`summary_table`), then
        the mean over episodes of each :data:`TABLE_COLUMNS` metric under its header, in the
        paper's units (``MHD cm``, ``distance cm``, ``body cm``, ``pred. ms``; NaN where no
        episode has it).

    Raises:
        ConfigError: when a group column is missing.
    """
    group_by = list(report_groups(df) if group_by is None else group_by)
    _check_columns(df, group_by, "group columns")

    def means(g: pd.DataFrame) -> dict[str, float]:
        row = {}
        for metric, (header, scale) in TABLE_COLUMNS.items():
            col = _metric_column(g, metric)
            mean = pd.to_numeric(g[col], errors="coerce").mean() if col else math.nan
            row[header] = float(mean) * scale
        return row

    return _per_group(df, group_by, means)


def _fmt(v: Any, digits: int) -> str:
    """``v`` for a table: floats to ``digits`` significant digits, those of magnitude 1 and
    above with their trailing zeros (-1.00, not -1, which reads as a count or a sentinel;
    1.80 beside 1.79) and those of 10^digits and above as whole numbers (2520, not 2.52e+03);
    smaller ones as short as they are (a setting such as 0.95 or 0.1 stays as written)."""
    if isinstance(v, bool | np.bool_):
        return str(bool(v))
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        x = float(v)
        if math.isnan(x):
            return "–"
        if math.isinf(x):
            return str(x)
        text = f"{x:#.{digits}g}" if abs(x) >= 1.0 else f"{x:.{digits}g}"
        if "e+" in text:  # 10^digits and above (999.6 too, which rounds up to it)
            return f"{x:.0f}"
        return text[:-1] if text.endswith(".") else text
    return str(v)


def _display_frame(df: pd.DataFrame, digits: int) -> tuple[list[str], list[list[str]], list[bool]]:
    """Header, string cells and right-alignment flags; ``x_mean``/``x_std`` pairs merged."""
    cols = list(df.columns)
    header: list[str] = []
    getters = []
    numeric: list[bool] = []
    for c in cols:
        if c.endswith("_std") and f"{c[:-4]}_mean" in cols:
            continue
        if c.endswith("_mean") and f"{c[:-5]}_std" in cols:
            base = c[:-5]

            def get(r: pd.Series, base: str = base) -> str:
                m, s = r[f"{base}_mean"], r[f"{base}_std"]
                if isinstance(s, float) and math.isnan(s):
                    return _fmt(m, digits)
                return f"{_fmt(m, digits)} ± {_fmt(s, digits)}"

            header.append(base)
            getters.append(get)
            numeric.append(True)
        else:
            header.append(str(c))
            getters.append(lambda r, c=c: _fmt(r[c], digits))
            numeric.append(pd.api.types.is_numeric_dtype(df[c]) and df[c].dtype != bool)
    cells = [[g(r) for g in getters] for _, r in df.iterrows()]
    return header, cells, numeric


def to_markdown(df: pd.DataFrame, digits: int = 3) -> str:
    """A GitHub-flavoured Markdown table (``x_mean``/``x_std`` shown as "mean ± std").

    Args:
        df: any table, e.g. :func:`summary_table`'s.
        digits: significant digits of floats.
    """
    header, cells, numeric = _display_frame(df, digits)

    def esc(s: str) -> str:
        return s.replace("|", "\\|")

    lines = ["| " + " | ".join(esc(h) for h in header) + " |"]
    lines.append("| " + " | ".join("---:" if n else ":---" for n in numeric) + " |")
    lines.extend("| " + " | ".join(esc(c) for c in row) + " |" for row in cells)
    return "\n".join(lines) + "\n"


def format_table(df: pd.DataFrame, digits: int = 3) -> str:
    """Plain-text table with aligned columns (numbers right-aligned) for the console."""
    header, cells, numeric = _display_frame(df, digits)
    widths = [max([len(h)] + [len(r[i]) for r in cells]) for i, h in enumerate(header)]

    def line(values: list[str]) -> str:
        return "  ".join(
            v.rjust(w) if n else v.ljust(w) for v, w, n in zip(values, widths, numeric)
        ).rstrip()

    out = [line(header), "  ".join("-" * w for w in widths)]
    out.extend(line(r) for r in cells)
    return "\n".join(out) + "\n"


def print_table(df: pd.DataFrame, digits: int = 3) -> None:
    """Print :func:`format_table` of ``df``."""
    print(format_table(df, digits), end="")


#: one line per column of :func:`comparison_table` that needs saying, for the console
_CONSOLE_KEY: dict[str, str] = {
    "contact_free": "episodes whose sphere models never overlapped",
    "contact_unknown": "episodes whose contact is unknown",
    "completed": "episodes that finished their tasks",
    "touched": "episodes with a MuJoCo robot-human contact",
    "pred. ms": "wall-clock time of one forecast [ms]",
    "MHD cm": "forecast hand path over 1 s against the true one [cm]",
    "smoothness": "squared joint accelerations summed over joints, mean over time [rad²/s⁴]",
    "jerkiness": "their peak over time [rad²/s⁴] (lower is smoother for both)",
    "distance cm": "closest distance of the sphere models [cm]; below 0 they overlapped",
    "body cm": "closest distance of the MuJoCo geoms [cm]",
    "efficiency": "the person's task time alone over that with the robot (> 1: it helps)",
    "waits": "plans per episode that stopped and waited for the person",
}


def comparison_key(table: pd.DataFrame) -> str:
    """The key printed under :func:`comparison_table` on the console: one line for each of
    its columns that :data:`_CONSOLE_KEY` explains, in the table's order, and what ``–``
    means (``results.md`` has the same in :data:`COMPARISON_NOTE`). ``""`` for a table with
    none of those columns."""
    cols = [c for c in table.columns if c in _CONSOLE_KEY]
    if not cols:
        return ""
    width = max(len(c) for c in cols)
    lines = [f"  {c:<{width}}  {_CONSOLE_KEY[c]}" for c in cols]
    head = "key (episode counts, then means over episodes; – where none has a value):"
    return "\n".join([head, *lines])


# ---------------------------------------------------------------------------------------------
# Plots


def _label(metric: str) -> str:
    return DEFAULT_METRICS.get(metric, metric)


#: How to read a metric's axis, in a plot's title: which way is better, what a line means.
READING_HINTS: dict[str, str] = {
    "smoothness": "lower is smoother",
    "jerkiness": "lower is smoother; a peak of squared accelerations, not a jerk",
    "efficiency": "above 1 (dashed): the robot helps",
    "min_distance": "below 0 (dashed): the sphere models overlapped",
    "body_distance": "below 0: the bodies overlapped",
    "mhd": "lower is a better forecast",
}


def _reading_hint(metric: str) -> str:
    """`` (<hint>)`` for a metric of :data:`READING_HINTS` (by its name without its stage
    prefix), else ``""``."""
    hint = READING_HINTS.get(metric.split("/")[-1])
    return f" ({hint})" if hint else ""


def _reference_line(ax: Any, metric: str) -> None:
    """A dashed line at the value a metric is read against: 1 for efficiency (alone as fast
    as with the robot), 0 for the closest distance (touching); none for the others."""
    level = {"efficiency": 1.0, "min_distance": 0.0}.get(metric.split("/")[-1])
    if level is not None:
        ax.axhline(level, color="0.4", lw=0.9, ls="--", zorder=0.5)


def _from_zero(ax: Any) -> None:
    """Let the y axis include 0 (a narrow autoscaled range made a few percent of noise look
    like a trend)."""
    lo, hi = ax.get_ylim()
    if lo > 0:
        ax.set_ylim(0.0, hi)
    elif hi < 0:
        ax.set_ylim(lo, 0.0)


def _pooled_note(pooled: Sequence[str], what: str) -> str:
    """The title's words on the settings a bar or point averages over: their differences are
    in its spread, not episode-to-episode scatter alone."""
    if not pooled:
        return ""
    names = ", ".join(pooled)
    return (
        f"\naveraged over {names}: each {what} pools every {names}, so its spread holds "
        f"their differences too (the sweep_* plots keep them apart)"
    )


def spread_note(
    counts: Sequence[int] | np.ndarray, *, item: str = "bar", spread: str = "whiskers"
) -> str:
    """The line under a bar chart's title saying what a bar and its whisker are (``item``
    "point" and ``spread`` "bands" for a line plot's).

    Args:
        counts: episodes with a value behind each bar (any order).
        item: what one mean is drawn as.
        spread: what its spread is drawn as.

    Returns:
        e.g. ``"mean of 3 episodes per bar, whiskers ± 1 std within min-max"`` (the whiskers of
        :func:`plot_comparison`: one standard deviation each way, cut at the least and the
        largest value of the bar's episodes); a bar of one episode has no whisker (a standard
        deviation of one value is undefined, not 0), which the note says.
    """
    n = [int(c) for c in np.asarray(counts).ravel() if int(c) > 0]
    if not n:
        return "no values"
    lo, hi = min(n), max(n)
    many = f"{lo}-{hi}" if lo != hi else f"{lo}"
    if hi == 1:
        return f"one episode per {item} (no spread to show)"
    note = f"mean of {many} episodes per {item}, {spread} ± 1 std within min-max"
    return note + (f" (none for a {item} of one episode)" if lo == 1 else "")


def _spread(values: pd.Series) -> tuple[float, float, float]:
    """``(mean, lower, upper)`` of ``values`` (NaN left out): the mean and one sample standard
    deviation below and above it, cut at the least and largest value (so the spread of a
    metric that cannot be negative never reaches below 0, nor below any episode's value);
    ``lower``/``upper`` NaN for fewer than two values."""
    v = values.dropna().to_numpy(dtype=float)
    if v.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(v.mean())
    if v.size < 2:
        return mean, math.nan, math.nan
    std = float(v.std(ddof=1))
    # min(..., mean): the mean of equal values may round a hair below their least value
    low = min(max(mean - std, float(v.min())), mean)
    return mean, low, max(min(mean + std, float(v.max())), mean)


#: Colours of the planners in every plot (matplotlib's tab10, by :data:`PLANNER_ORDER`), so
#: that a planner keeps its colour whichever others a plot shows; other hues (a labelled run
#: ``itomp@spread`` next to ITOMP, a speed) take the spare ones.
PLANNER_COLOURS: dict[str, str] = {p: f"C{i}" for i, p in enumerate(PLANNER_ORDER)}
_SPARE_COLOURS = ("C6", "C7", "C8", "C9", "#aec7e8", "#ffbb78", "#98df8a", "#ff9896")


def hue_colours(values: Sequence[Any]) -> dict[Any, str]:
    """A colour for each of ``values`` (planner keys, or other hues), in order: a planner,
    or a labelled run of one (``iplanner_ni@held``), takes :data:`PLANNER_COLOURS`'s unless
    an earlier value took it; the rest take spare colours in turn."""
    out: dict[Any, str] = {}
    used: set[str] = set()
    for v in dict.fromkeys(values):
        key = str(v)
        c = PLANNER_COLOURS.get(key) or PLANNER_COLOURS.get(key.split("@")[0])
        if c is not None and c not in used:
            out[v] = c
            used.add(c)
    spare = iter([c for c in _SPARE_COLOURS if c not in used])
    for v in dict.fromkeys(values):
        if v not in out:
            out[v] = next(spare, None) or _SPARE_COLOURS[len(out) % len(_SPARE_COLOURS)]
    return out


def _legend_outside(ax: Any, **kwargs: Any) -> Any:
    """A legend to the right of ``ax``, outside its plotting area (so it covers no bar, line
    or marker); ``fig.tight_layout()`` then makes room for it."""
    return ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, **kwargs)


def plot_comparison(
    df: pd.DataFrame,
    out_dir: str | Path,
    metrics: Sequence[str] = ("smoothness", "jerkiness", "min_distance", "efficiency"),
    group_by: tuple[str, str] = ("scenario", "planner"),
    pooled: Sequence[str] = (),
) -> list[Path]:
    """Grouped bar charts of each metric: groups on x, one bar per planner.

    A bar is the mean over its episodes; its whisker spans one sample standard deviation
    below and above the mean, cut at the least and the largest value of those episodes, so
    the whisker of a metric that cannot be negative (smoothness, jerkiness, efficiency, MHD)
    never reaches below 0, and a closest distance's reaches below 0 only when an episode's
    did. The title's second line says how many episodes a bar averages (:func:`spread_note`);
    a bar of one episode has no whisker. The x axis is labelled with the grouping column
    (its unit for a swept setting, :data:`SETTING_LABELS`) and the legend stands outside the
    plotting area. Distances are drawn in cm (:data:`DISPLAY_SCALE`).

    Args:
        df: per-episode results.
        out_dir: folder for ``compare_<metric>.png`` (created).
        metrics: metrics to plot; those absent from ``df``, or without a value in any
            episode (e.g. efficiency when no episode finished its tasks), are skipped: no
            file is written for them.
        group_by: ``(x-axis column, bar column)``.
        pooled: other columns whose values a bar averages over (e.g. the speeds and noises of
            a sweep charted by confidence); the title says so.

    Returns:
        The written PNG paths (only those written).
    """
    x_col, bar_col = group_by
    _check_columns(df, [x_col, bar_col], "group columns")
    out_dir = Path(out_dir)
    xs = ordered_values(x_col, df[x_col])
    bars = ordered_values(bar_col, df[bar_col])
    paths = []
    for m in metrics:
        if m not in df.columns:
            continue
        v = df.assign(_v=_shown(m, pd.to_numeric(df[m], errors="coerce")))
        if not v["_v"].notna().any():
            continue  # nothing to draw: no empty chart
        groups = {
            (_hashable(x), _hashable(b)): g["_v"]
            for (x, b), g in v.groupby([x_col, bar_col], sort=False, dropna=False)
        }
        # the bars each group has (labelled runs: each label's planners under its own group),
        # side by side and centred on the group, so no group keeps slots for absent bars
        present = {
            _hashable(x): [
                b
                for b in bars
                if (g := groups.get((_hashable(x), _hashable(b)))) is not None and g.notna().any()
            ]
            for x in xs
        }
        per_group = max([1, *(len(v) for v in present.values())])
        fig = Figure(figsize=(max(6.0, 1.1 * len(xs) * per_group * 0.45 + 2), 4.2))
        ax = fig.add_subplot()
        width = 0.8 / per_group
        counts = []
        colours = hue_colours(bars)
        for b in bars:
            pos, spreads = [], []
            for i, x in enumerate(xs):
                here = present[_hashable(x)]
                g = groups.get((_hashable(x), _hashable(b)))
                counts.append(int(g.notna().sum()) if g is not None else 0)
                if b not in here:
                    continue
                pos.append(i - 0.5 * width * len(here) + width * (here.index(b) + 0.5))
                spreads.append(_spread(g))
            if not pos:
                continue
            means, lows, highs = (np.asarray(c, dtype=float) for c in zip(*spreads))
            ax.bar(
                np.asarray(pos),
                means,
                width,
                yerr=np.vstack([means - lows, highs - means]),  # NaN (one episode): none
                capsize=3,
                label=PLANNERS.get(str(b), str(b)),
                color=colours[b],
            )
        ax.set_xticks(np.arange(len(xs)))
        ax.set_xticklabels(
            [str(x) for x in xs],
            rotation=25 if len(xs) > 3 else 0,
            ha="right" if len(xs) > 3 else "center",
        )
        ax.set_xlabel(SETTING_LABELS.get(x_col, x_col))
        ax.set_ylabel(_label(m))
        ax.set_title(
            f"{_label(m).split(' [')[0]} by {x_col} and {bar_col}{_reading_hint(m)}\n"
            + spread_note(counts)
            + _pooled_note(pooled, "bar"),
            fontsize="medium",
        )
        _reference_line(ax, m)
        ax.grid(axis="y", alpha=0.3)
        _legend_outside(ax, title=bar_col, fontsize="small")
        fig.tight_layout()
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / f"compare_{m}.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        paths.append(path)
    return paths


def plot_paired(
    table: pd.DataFrame,
    metric: str,
    out_path: str | Path,
    level: float = 0.95,
    baseline: str = "itomp",
) -> Path:
    """Forest plot of :func:`paired_differences`: one row per group and planner, the mean
    difference from the baseline with its interval, and a line at 0 (no difference).

    Args:
        table: the output of :func:`paired_differences` (its group columns are those before
            ``planner``).
        metric: the metric it compares (for the axis label; a distance's differences are
            drawn in cm, :data:`DISPLAY_SCALE`).
        out_path: PNG path (its folder is created).
        level: the intervals' confidence level (for the axis label).
        baseline: the planner the differences are taken from (named in the axis label, e.g.
            "planner minus ITOMP").

    Returns:
        ``out_path``.
    """
    _check_columns(table, ["planner", "mean_diff", "ci_low", "ci_high"], "paired columns")
    groups = list(table.columns[: list(table.columns).index("planner")])

    def setting(column: str, value: Any) -> str:  # "noise 0.02": which number is which
        text = _fmt(value, 3)
        return text if column == "scenario" else f"{column} {text}"

    labels = [
        ", ".join(
            [*(setting(c, r[c]) for c in groups), PLANNERS.get(str(r.planner), str(r.planner))]
        )
        for _, r in table.iterrows()
    ]
    y = np.arange(len(table))[::-1]
    fig = Figure(figsize=(7.0, 1.2 + 0.32 * max(1, len(table))))
    ax = fig.add_subplot()
    mean = _shown(metric, table["mean_diff"].to_numpy(dtype=float))
    lo = mean - _shown(metric, table["ci_low"].to_numpy(dtype=float))
    hi = _shown(metric, table["ci_high"].to_numpy(dtype=float)) - mean
    by_planner = hue_colours(list(table.planner))
    colours = [by_planner[p] for p in table.planner]
    for yi, m, a, b, c in zip(y, mean, lo, hi, colours):
        err = None if np.isnan(a) else [[a], [b]]  # fewer than two pairs: the point only
        ax.errorbar(m, yi, xerr=err, fmt="o", color=c, capsize=3)
    ax.axvline(0.0, color="0.4", lw=1, ls="--")
    ax.set_yticks(y)
    ax.set_yticklabels(labels, fontsize="small")
    base = PLANNERS.get(baseline, baseline)
    ax.set_xlabel(f"{_label(metric)}: planner minus {base}, {100 * level:g}% interval")
    pairs = table["pairs"] if "pairs" in table.columns else None
    counted = "" if pairs is None else f" ({int(pd.to_numeric(pairs).sum())} pairs of episodes)"
    ax.set_title(f"{_label(metric).split(' [')[0]}, paired by seed{counted}", fontsize="medium")
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=110, bbox_inches="tight")
    return out_path


def plot_sweep(
    df: pd.DataFrame,
    x: str,
    y: str,
    hue: str,
    out_path: str | Path,
    *,
    facet_col: str | None = None,
    facet_row: str | None = None,
    pooled: Sequence[str] = (),
) -> Path:
    """Line plot of ``y`` against a swept parameter ``x``, one line per hue.

    A line joins the means over the episodes at each ``x``; its band spans one sample
    standard deviation below and above, cut at the least and the largest episode value (so a
    metric that cannot be negative never gets a band below 0). The legend stands to the right
    of the top-right panel, outside the plotting area. Distances are drawn in cm
    (:data:`DISPLAY_SCALE`).

    With ``facet_col`` (and ``facet_row``) the figure holds one panel per value (pair of
    values) of those columns, sharing both axes, so a sweep over several settings is shown
    without averaging over them (e.g. ``x="noise"``, ``facet_col="speed"``,
    ``facet_row="confidence"``). Every planner keeps one colour across the panels.

    Args:
        df: per-episode results.
        x: swept column (e.g. ``"confidence"``, ``"noise"``), numeric.
        y: metric column.
        hue: column naming the lines (e.g. ``"planner"``).
        out_path: PNG to write (parent created).
        facet_col: column whose values lay out the panels left to right, or None.
        facet_row: column whose values lay out the panels top to bottom, or None.
        pooled: other columns whose values a point averages over; the title says so.

    Returns:
        ``out_path``.

    Raises:
        ConfigError: when a named column is missing.
    """
    facets = [c for c in (facet_row, facet_col) if c is not None]
    _check_columns(df, [x, y, hue, *facets], "columns")
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    v = df.assign(_y=_shown(y, pd.to_numeric(df[y], errors="coerce")))
    rows = ordered_values(facet_row, v[facet_row]) if facet_row else [None]
    cols = ordered_values(facet_col, v[facet_col]) if facet_col else [None]
    hues = ordered_values(hue, v[hue])
    fig = Figure(figsize=(max(6.4, 3.6 * len(cols) + 1.0), max(4.2, 2.9 * len(rows) + 0.8)))
    axes = fig.subplots(len(rows), len(cols), sharex=True, sharey=True, squeeze=False)
    name = _label(y).split(" [")[0]
    counts: list[int] = []  # episodes with a value behind each point
    for i, rv in enumerate(rows):
        for k, cv in enumerate(cols):
            ax = axes[i][k]
            panel = v
            if facet_row:
                panel = panel[panel[facet_row].map(_hashable) == _hashable(rv)]
            if facet_col:
                panel = panel[panel[facet_col].map(_hashable) == _hashable(cv)]
            colours = hue_colours(hues)
            for h in hues:
                g = panel[panel[hue] == h]
                if not g["_y"].notna().any():  # no value (ITOMP has no MHD): no line, no label
                    continue
                points = sorted(
                    ((float(xv), *_spread(gy)) for xv, gy in g.groupby(x)["_y"]),
                    key=lambda p: p[0],
                )
                counts += [int(gy.notna().sum()) for _, gy in g.groupby(x)["_y"]]
                xs, mean, low, high = (np.asarray(c, dtype=float) for c in zip(*points))
                low = np.where(np.isnan(low), mean, low)  # one episode: no band
                high = np.where(np.isnan(high), mean, high)
                label = PLANNERS.get(str(h), str(h))
                ax.plot(xs, mean, marker="o", color=colours[h], label=label)
                ax.fill_between(xs, low, high, color=colours[h], alpha=0.2, lw=0)
            title = ", ".join(
                f"{c} {val}" for c, val in ((facet_row, rv), (facet_col, cv)) if c is not None
            )
            if title:
                ax.set_title(title, fontsize="medium")
            _reference_line(ax, y)
            ax.grid(alpha=0.3)
            if i == len(rows) - 1:
                ax.set_xlabel(SETTING_LABELS.get(x, x))
            if k == 0:
                ax.set_ylabel(_label(y))
    # ticks at the swept values, written as given (0.02, not 0.0200 between 0.0025-steps
    # whose labels ran into each other); slanted when there are many
    swept = sorted({float(xv) for xv in pd.to_numeric(v[x], errors="coerce").dropna()})
    if 0 < len(swept) <= 12:
        for ax in axes[-1]:
            ax.set_xticks(swept, [f"{xv:g}" for xv in swept])
            if len(swept) > 4:
                ax.tick_params(axis="x", labelrotation=35)
    _from_zero(axes[0][0])  # (shared y: one call sets every panel)
    _legend_outside(axes[0][-1], title=hue, fontsize="small")
    fig.suptitle(
        f"{name} against {x}"
        + (f" by {' and '.join(facets)}" if facets else "")
        + _reading_hint(y)
        + "\n"
        + spread_note(counts, item="point", spread="bands")
        + _pooled_note(pooled, "point"),
        fontsize="medium",
    )
    fig.tight_layout()
    fig.savefig(out_path, dpi=110, bbox_inches="tight")
    return out_path


#: Metrics compared seed by seed in a report's "Paired by seed" section.
PAIRED_METRICS = ("min_distance", "smoothness")


def paired_table(
    df: pd.DataFrame,
    metrics: Sequence[str] = PAIRED_METRICS,
    *,
    group_by: Sequence[str] = ("scenario",),
    baseline: str = "itomp",
) -> pd.DataFrame:
    """:func:`paired_differences` of each of ``metrics`` present in ``df``, stacked.

    Returns:
        The group columns, ``planner``, ``metric`` (the metric's column name), then the
        columns of :func:`paired_differences`; one block of rows per metric, in the order of
        ``metrics``. Empty when none of ``metrics`` is in ``df``.

    Raises:
        ConfigError: as :func:`paired_differences`.
    """
    parts = [
        paired_differences(df, m, group_by=group_by, baseline=baseline).assign(metric=m)
        for m in metrics
        if m in df.columns
    ]
    cols = [*group_by, "planner", "metric", "pairs", "mean_diff", "ci_low", "ci_high"]
    cols += ["p_value", "better"]
    if not parts:
        return pd.DataFrame(columns=cols)
    return pd.concat(parts, ignore_index=True)[cols]


def paired_skip_note(df: pd.DataFrame, group_by: Sequence[str], baseline: str = "itomp") -> str:
    """Why a report has no seed-by-seed comparison although it could have one ('' if it has
    one, or has nothing to compare).

    A report compares each planner with ``baseline`` seed by seed when ``group_by`` holds
    ``planner`` and ``df`` holds the baseline and another planner; the comparison needs at
    least two seeds shared by the baseline and another planner in one group (one seed gives
    a difference but no interval).

    Args:
        df: per-episode results.
        group_by: the report's groups (those other than ``planner`` define a comparison).
        baseline: the planner the others are compared with.

    Returns:
        One line, e.g. ``"paired comparison skipped: needs at least 2 seeds shared by
        itomp@spread and another planner in one setting; found 1"``, or ''.
    """
    head = "paired comparison skipped: "
    if "planner" in group_by and "planner" in df.columns and not (df["planner"] == baseline).any():
        # labelled runs rename the baseline (itomp@iiwa): say so instead of nothing
        labelled = sorted(
            {str(p) for p in df["planner"].dropna() if str(p).startswith(f"{baseline}@")}
        )
        if labelled:
            return head + (
                f"no planner is named {baseline} (the labelled runs name it "
                f"{', '.join(labelled)}); choose one with evaluate.baseline=<name>"
            )
    if (
        "planner" not in group_by
        or "planner" not in df.columns
        or not (df["planner"] == baseline).any()
        or df["planner"].dropna().nunique() < 2
    ):
        return ""
    if "seed" not in df.columns:
        return head + "the results have no seed column to pair episodes on"
    keys = [c for c in group_by if c != "planner" and c in df.columns]
    rows = df[df["planner"].notna() & df["seed"].notna()]
    base = rows[rows["planner"] == baseline][[*keys, "seed"]].drop_duplicates()
    others = rows[rows["planner"] != baseline][[*keys, "planner", "seed"]].drop_duplicates()
    shared = others.merge(base, on=[*keys, "seed"])
    most = int(shared.groupby([*keys, "planner"], dropna=False).size().max()) if len(shared) else 0
    if most >= 2:
        return ""
    where = "in one setting" if keys else "in the results"
    return head + (
        f"needs at least 2 seeds shared by {baseline} and another planner {where}; found {most}"
    )


def _paired_section(
    df: pd.DataFrame,
    group_by: Sequence[str],
    out_dir: Path | None = None,
    baseline: str = "itomp",
    draw: list[tuple[Path, Callable[[], object]]] | None = None,
) -> tuple[list[str], list[Path]]:
    """Markdown lines comparing each planner with ``baseline`` seed by seed
    (:func:`paired_table`), grouped like the summary, and, with ``out_dir``, the names of a
    ``paired_<metric>.png`` forest plot of each metric (:func:`plot_paired`), whose drawing
    is appended to ``draw`` (path, call) when given; nothing without the baseline and another
    planner, and a line saying why (:func:`paired_skip_note`) when they share fewer than two
    seeds."""
    skipped = paired_skip_note(df, group_by, baseline)
    if skipped:
        return ["", "## Paired by seed", "", skipped[0].upper() + skipped[1:] + "."], []
    if (
        "planner" not in group_by
        or "seed" not in df.columns
        or not (df["planner"] == baseline).any()
        or df["planner"].nunique() < 2
    ):
        return [], []
    lines = ["", "## Paired by seed", ""]
    try:
        table = paired_table(
            df, group_by=[c for c in group_by if c != "planner"], baseline=baseline
        )
    except ConfigError as err:  # e.g. two episodes of one planner and seed in a group
        return lines + [f"Not computed: {err}."], []
    if table.empty:
        return [], []
    plots = []
    if out_dir is not None:
        for m in dict.fromkeys(table["metric"]):
            part = table[table["metric"] == m].drop(columns="metric")
            png = out_dir / f"paired_{m}.png"
            plots.append(png)
            if draw is not None:
                draw.append((png, partial(plot_paired, part, str(m), png, baseline=baseline)))
    name = "ITOMP" if baseline == "itomp" else f"`{baseline}`"
    lines += [
        f"Each planner minus {name} in the same setting and seed (same person, noise and task "
        "order), in the units of the mean ± std table: mean difference with its 95% "
        "Student-t interval, the paired t-test's p-value, and `better`, the seeds where the "
        "planner did better (a larger distance or efficiency, a smoother or less jerky "
        "trajectory; ties not counted).",
        "",
        to_markdown(_paired_in_display_units(table)),
    ]
    if plots:
        lines += ["", "Plots: " + ", ".join(f"`{p.name}`" for p in plots) + "."]
    return lines, plots


def _paired_in_display_units(table: pd.DataFrame) -> pd.DataFrame:
    """:func:`paired_table`'s rows of each :data:`DISPLAY_SCALE` metric with their
    differences scaled and the metric named with its unit (``min_distance cm``)."""
    out = table.copy()
    for m, (unit, _) in DISPLAY_SCALE.items():
        rows = out["metric"] == m
        if rows.any():
            for c in ("mean_diff", "ci_low", "ci_high"):
                out.loc[rows, c] = _shown(m, pd.to_numeric(out.loc[rows, c], errors="coerce"))
            out.loc[rows, "metric"] = f"{m} {unit}"
    return out


#: what the columns of :func:`comparison_table` are, as ``results.md`` says above the table
COMPARISON_NOTE = (
    "The table `iplanner-experiment` and `iplanner-evaluate evaluate.mode=episode` print: "
    "episode counts, then means over episodes in the paper's units: `pred. ms` prediction "
    "time [ms]; `MHD cm` prediction MHD [cm]; `smoothness`, `jerkiness` [rad²/s⁴]; "
    "`distance cm` the closest distance of the sphere models [cm] (`min_distance`); `body cm` "
    "the closest of the robot's MuJoCo geoms to the person's capsules [cm]; `efficiency` "
    "(alone / with robot; finished episodes only); `waits` the planner's waits per episode; "
    "– where no episode has a value."
)


def write_sweep_report(
    df: pd.DataFrame,
    out_dir: str | Path,
    group_by: Sequence[str] = ("scenario", "planner"),
    sweep: str | None = None,
    baseline: str = "itomp",
) -> list[Path]:
    """Write ``results.csv`` (per episode), ``results.md`` (summary) and the PNGs.

    ``results.md`` holds, under "Comparison", the table the console of ``iplanner-experiment``
    and ``iplanner-evaluate evaluate.mode=episode`` prints (:func:`comparison_table` by
    ``group_by``: the same columns, in the paper's units), then, under "Mean ± std", the
    :func:`summary_table` (with standard deviations; distances in cm,
    :func:`in_display_units`). It also compares each planner
    with ``baseline`` seed by seed ("Paired by seed", :func:`paired_differences`, with
    ``paired_<metric>.png`` forest plots) when the results hold the baseline, another planner
    and two seeds they share, and says why not when they hold the baseline and another
    planner but share fewer seeds (:func:`paired_skip_note`).

    Args:
        df: per-episode results.
        out_dir: output folder (created).
        group_by: summary groups; the last two also lay out the bar charts (x, bars).
        sweep: a swept numeric column: adds ``sweep_<metric>.png`` for each metric, one line
            per ``group_by[-1]`` value; the other group columns that take several values
            (up to two; the last two of them when there are more) lay out its panels
            (:func:`plot_sweep`). No sweep plot is written when ``sweep`` takes one value
            in every panel.
        baseline: the planner of the paired comparison (ITOMP unless given).

    Returns:
        Every written path.

    Raises:
        DataError: when ``df`` holds no episode, ``out_dir`` is a file, or its
            ``results.csv`` or ``results.md`` a folder (nothing is written then). The tables
            are built before ``results.csv`` and ``results.md`` are written, so an error
            while building them leaves the earlier ones as they were.

    Warns:
        DataWarning: naming each plot that could not be drawn or saved (a folder in its
            place, a full disk, a plotting error), once the tables are written; the other
            plots are still drawn, and the returned paths leave it out.
    """
    out_dir = Path(out_dir)
    if len(df) == 0:
        raise DataError(
            f"{out_dir}: no episode to report (the results hold no rows: no readable episode "
            "log, or none with its metrics); nothing was written"
        )
    if out_dir.exists() and not out_dir.is_dir():
        raise DataError(f"{out_dir}: not a folder; the report needs a folder to write into")
    written = [out_dir / "results.csv", out_dir / "results.md"]
    for p in written:
        if p.exists() and not p.is_file():
            raise DataError(
                f"{p}: a folder where the report writes its file; nothing was written: move "
                "it away or give another output folder"
            )
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = summary_table(df, group_by)
    notes = [n for n in (incomplete_logs_note(df), overrun_note(df)) if n]
    md = ["# Results", "", f"{len(df)} episodes.", ""] + [x for n in notes for x in (n, "")]
    legend = [
        "`contact_free`: episodes whose contact is known and none occurred (the robot's and "
        "the person's sphere models never overlapped: `min_distance` > 0, stricter than a "
        "MuJoCo contact)",
        "`contact_unknown`: episodes whose contact is unknown",
    ]
    if "completed" in summary.columns:
        legend.append("`completed`: episodes known to have finished their tasks")
    if "touched" in summary.columns:
        legend.append("`touched`: episodes with a MuJoCo robot-human contact")
    units = [DEFAULT_METRICS[m] for m in DEFAULT_METRICS if f"{m}_mean" in summary.columns]
    md += ["; ".join(legend) + ".", ""]
    md += ["## Comparison", "", COMPARISON_NOTE, "", to_markdown(comparison_table(df, group_by))]
    md += ["## Mean ± std", ""]
    md += ["Means over episodes ± sample std: " + "; ".join(units) + ".", ""] if units else []
    md += [to_markdown(in_display_units(summary))]
    # each plot is drawn on its own: one that cannot be drawn or saved (a folder in its
    # place, a full disk, a plotting error) is named in one warning at the end, the others
    # are still drawn, and the tables are written all the same
    failed: list[str] = []
    draw: list[tuple[Path, Callable[[], object]]] = []
    paired_md, _ = _paired_section(df, group_by, out_dir, baseline, draw)
    paired: list[Path] = []
    for png, call in draw:  # first, so that results.md names only the paired plots drawn
        _draw_plot(png, call, paired, failed)
    if paired_md and paired_md[-1].startswith("Plots: "):
        names = ", ".join(f"`{p.name}`" for p in paired)
        paired_md = paired_md[:-2] + (["", f"Plots: {names}."] if paired else [])
    md += paired_md
    # both once every table is built, each replacing its file in one step: a full disk or
    # an interrupt leaves the earlier table (an experiment's record of its episodes) whole
    with whole_file(written[0]) as tmp:
        df.to_csv(tmp, index=False)
    with whole_file(written[1]) as tmp:
        tmp.write_text("\n".join(md) + "\n")
    written += paired

    def varies(c: str) -> bool:
        return c in df.columns and df[c].nunique(dropna=True) > 1

    if len(group_by) >= 2:
        pooled = [c for c in group_by[:-2] if varies(c)]
        for m in ("smoothness", "jerkiness", "min_distance", "efficiency"):
            call = partial(
                plot_comparison, df, out_dir, metrics=(m,),
                group_by=(group_by[-2], group_by[-1]), pooled=pooled,
            )  # fmt: skip
            _draw_plot(out_dir / f"compare_{m}.png", call, written, failed)
    if sweep is not None:
        others = [c for c in group_by[:-1] if c != sweep and varies(c)]
        facets = others[-2:]
        pooled = [c for c in others if c not in facets]
        row, col = ([None, *facets])[-2:] if facets else (None, None)
        panels = df.groupby(facets, dropna=False)[sweep] if facets else [(None, df[sweep])]
        # with x values that only ever change with the panel (e.g. one confidence per
        # scenario) there is no line to draw
        if max(x.nunique() for _, x in panels) >= 2:
            for m in _default_metrics(df, list(group_by) + [sweep]):
                if not pd.to_numeric(df[m], errors="coerce").notna().any():
                    continue  # no value to draw (e.g. efficiency when no episode finished)
                png = out_dir / f"sweep_{m}.png"
                call = partial(
                    plot_sweep, df, sweep, m, group_by[-1], png, facet_col=col,
                    facet_row=row, pooled=pooled,
                )  # fmt: skip
                _draw_plot(png, call, written, failed)
    if failed:
        warnings.warn(
            f"{out_dir}: {len(failed)} plot(s) not written: {'; '.join(failed)}; "
            "results.csv and results.md are",
            DataWarning,
            stacklevel=2,
        )
    return written


def _draw_plot(
    png: Path, call: Callable[[], object], written: list[Path], failed: list[str]
) -> None:
    """Run ``call`` (it draws ``png``, or returns several paths); add what it wrote to
    ``written``, or ``"<name> (<error>)"`` to ``failed`` when it raises."""
    try:
        out = call()
    except Exception as exc:  # noqa: BLE001 - a plot never costs the tables (see caller)
        failed.append(f"{png.name} ({type(exc).__name__}: {exc})")
        return
    written.extend(out if isinstance(out, list) else [Path(out)])  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------
# The paper's numbers


def paper_table_simulation() -> pd.DataFrame:
    """The paper's table performance_simulation, one row per scenario and planner.

    Columns: ``scenario`` (key of :data:`PAPER_SCENARIOS`), ``label`` (the paper's), the
    scenario's ``arrangement``, ``task_order`` and ``confidence`` (table performance),
    ``planner`` (key of :data:`PLANNERS`), ``prediction_ms``, ``mhd`` [m], ``smoothness``,
    ``jerkiness``, ``min_distance`` [m], ``efficiency``. N/A entries are NaN.
    """
    rows = []
    for scen, planner_rows in _PAPER_SIM_ROWS.items():
        label, arrangement, order, conf = PAPER_SCENARIOS[scen]
        for planner, vals in zip(PLANNERS, planner_rows):
            pred_ms, mhd_cm, smooth, jerk, dist_cm, eff = (
                math.nan if v is None else float(v) for v in vals
            )
            rows.append(
                {
                    "scenario": scen,
                    "label": label,
                    "arrangement": arrangement,
                    "task_order": order,
                    "confidence": conf,
                    "planner": planner,
                    "prediction_ms": pred_ms,
                    "mhd": mhd_cm / 100.0,
                    "smoothness": smooth,
                    "jerkiness": jerk,
                    "min_distance": dist_cm / 100.0,
                    "efficiency": eff,
                }
            )
    return pd.DataFrame.from_records(rows)


def side_by_side(
    ours: pd.DataFrame,
    paper: pd.DataFrame | None = None,
    on: Sequence[str] = ("scenario", "planner"),
    metrics: Sequence[str] = (
        "prediction_ms",
        "mhd",
        "smoothness",
        "jerkiness",
        "min_distance",
        "efficiency",
    ),
) -> pd.DataFrame:
    """Our means next to the paper's numbers, per scenario and planner.

    Args:
        ours: per-episode results, or a :func:`summary_table` (its ``<metric>_mean`` columns).
        paper: the paper's table (default :func:`paper_table_simulation`).
        on: key columns present in both.
        metrics: metrics to compare; those missing on our side are skipped.

    Returns:
        The keys, then ``<metric> (ours)`` and ``<metric> (paper)`` per metric, for every key
        combination of ``ours`` (paper values NaN where the paper has no such row).
    """
    paper = paper_table_simulation() if paper is None else paper
    on = list(on)
    _check_columns(ours, on, "key columns")
    _check_columns(paper, on, "key columns")
    ours_means: dict[str, pd.Series] = {}
    for m in metrics:
        if f"{m}_mean" in ours.columns:
            ours_means[m] = ours.groupby(on, sort=False)[f"{m}_mean"].mean()
        elif m in ours.columns:
            ours_means[m] = (
                pd.to_numeric(ours[m], errors="coerce")
                .groupby([ours[c] for c in on], sort=False)
                .mean()
            )
    if not ours_means:
        raise ConfigError(f"none of the metrics {list(metrics)} is in {list(ours.columns)}")
    left = pd.DataFrame({f"{m} (ours)": s for m, s in ours_means.items()}).reset_index()
    right_cols = [m for m in ours_means if m in paper.columns]
    right = paper[on + right_cols].rename(columns={m: f"{m} (paper)" for m in right_cols})
    merged = left.merge(right, on=on, how="left")
    order = on + [c for m in ours_means for c in (f"{m} (ours)", f"{m} (paper)") if c in merged]
    return merged[order]
