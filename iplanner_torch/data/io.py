"""Demonstration files: NPZ and CSV, loading with validation, and the LEGO assembly recording.

The formats are documented in ``datasets/README.md``. In short:

* **NPZ** (one demonstration per file): ``positions`` (T, K, 3) float, ``labels`` (T,) int,
  ``joint_names`` (K,) str, ``action_names`` (A,) str, ``fps`` scalar, optional
  ``timestamps`` (T,) float seconds, optional ``clean_positions`` (T, K, 3) float, optional
  ``metadata`` (a JSON object as a string). Saved without pickling. Those are the only keys
  (:data:`NPZ_KEYS`): any other (``timestamp``, a misspelt ``clean_position``) is an error
  naming it, never dropped silently.
* **CSV** (one demonstration per file): optional header comment lines starting with ``#``
  at the top, whose text after the ``#`` joined together is a JSON object with ``fps``,
  ``action_names`` and ``metadata``; then a column header row
  ``t,label,<joint>_x,<joint>_y,<joint>_z,...`` (joint-major; a first row of numbers is
  refused), optionally followed by ``clean_<joint>_x,...`` columns; then one row per frame (a
  ``#`` line among them is an error naming its line, never joined into the header). Those
  are the only column forms: any other column (``time``, a misspelt ``lable``) is an error,
  never dropped silently. An empty cell is NaN (a lost joint). Without the JSON
  header, ``fps`` must be given to the loader and actions are named ``action_0 ...``; ``t`` is
  optional. Without a ``label`` column every frame is labelled 0 with the single action name
  ``unlabelled`` when the header names no actions; when it names actions (``action_names``),
  every frame is labelled -1 (unlabelled, no training windows) with a
  :class:`~iplanner_torch.errors.DataWarning`, never silently the first action.

Metadata is written as strict JSON: a NaN or infinite number in it is written as the string
``"nan"``, ``"inf"`` or ``"-inf"`` and read back as the float (so is such a string; files of
earlier versions with bare ``NaN`` / ``Infinity`` tokens read as before). CSV numbers are
written in the shortest form that reads back to the same value (float32 positions to the same
float32), so a saved demonstration loads bit-identical.

Field types are checked on loading: ``fps`` is one real number (not a string or a boolean),
finite and > 0; ``metadata`` is a JSON object; names are strings; ``timestamps`` are numbers;
``clean_positions`` are floats. In the CSV header comment ``fps``, ``action_names`` (a JSON array
of strings) and ``metadata`` are each optional, and a ``null`` value counts as absent; the clean
columns, when present, cover every joint's three axes. Without ``action_names`` the CSV labels
name ``action_0 .. action_<largest label>``, at most :data:`MAX_IMPLICIT_ACTIONS` actions.

A demonstration read from a folder is named by its path there without the suffix
(``Task1/Human1/trial2``, as LEGO trials are; a file directly in the folder by its stem), so
files of one stem in different sub-folders stay apart; two files of one name (``a.csv``
beside ``a.npz``) are an error. LEGO trial errors name the file line a text editor shows.

Timestamps must be strictly increasing with a median spacing of 1 / fps (within
:data:`TIMESTAMP_TOLERANCE`); a single step that strays from 1 / fps by more than
:data:`GAP_TOLERANCE` of a frame (a pause, a dropped frame) loads with a
:class:`~iplanner_torch.errors.DataWarning` naming the frames and the step, since the frames
are used at 1 / fps.

A CSV or LEGO trial file whose last line has no line terminator may have been cut short (a
copy or a recording stopped mid-write: ``0.841`` of ``0.8410000205``); that last row is
dropped with a :class:`~iplanner_torch.errors.DataWarning` naming the file (every file the
writers here and the recording write ends with a line break). A folder named
``<name>.partial-<pid>`` is an unfinished generation's temporary folder and is never read.
"""

from __future__ import annotations

import difflib
import json
import math
import numbers
import re
import tokenize
import warnings
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from iplanner_torch import checks
from iplanner_torch.checks import path_argument
from iplanner_torch.checks import short_repr as _show
from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.errors import ConfigError, DataError, DataWarning
from iplanner_torch.files import whole_file
from iplanner_torch.types import MAX_POSITION_M

SUFFIXES: tuple[str, ...] = (".npz", ".csv")
_REQUIRED_NPZ = ("positions", "labels", "joint_names", "action_names")
#: Every key an NPZ demonstration may hold (:func:`save_demonstration` writes them all, but
#: ``clean_positions`` only when there are some); the loader refuses any other.
NPZ_KEYS: tuple[str, ...] = (
    *_REQUIRED_NPZ,
    "fps",
    "timestamps",
    "clean_positions",
    "metadata",
)
_AXES = ("x", "y", "z")
#: The first bytes of a zip archive (an NPZ file is one): a local file header or an empty one.
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")
#: A CSV without ``action_names`` names actions ``action_0 .. action_<largest label>``; a larger
#: largest label is an error (a stray huge label would otherwise allocate that many names).
MAX_IMPLICIT_ACTIONS = 10_000
_JSON_TYPES = {dict: "object", list: "array", str: "string", bool: "boolean", type(None): "null"}
#: The CSV column forms the loader accepts (for error messages).
_CSV_COLUMN_FORMS = (
    "t (seconds), label (int action index), <joint>_x, <joint>_y, <joint>_z, "
    "clean_<joint>_x, clean_<joint>_y, clean_<joint>_z"
)
#: A generator writes a dataset folder ``<name>`` into ``<name>.partial-<pid>`` beside it first
#: (:func:`iplanner_torch.data.dataset_card.staged_dataset`); such a folder is never read.
PARTIAL_MARK = ".partial-"
_PARTIAL_NAME = re.compile(r".+" + re.escape(PARTIAL_MARK) + r"\d+")
#: Text of the warning for a last line without a line terminator.
CUT_LAST_LINE = (
    "last line has no line terminator: the file may be cut short; its last row is dropped"
)
#: Likely meanings of unknown CSV columns, offered as a hint (besides close spellings).
_CSV_COLUMN_HINTS = {
    "time": "t",
    "timestamp": "t",
    "timestamps": "t",
    "labels": "label",
    "action": "label",
    "actions": "label",
}


def _json_type(value: Any) -> str:
    """The JSON type name of a value ``json.loads`` returned (``number`` for int and float)."""
    return _JSON_TYPES.get(type(value), "number")


def _fps_field(path: Path, value: Any) -> float:
    """The frame rate [Hz] a file states: one real number, finite and > 0.

    Args:
        path: the file (for the message).
        value: the NPZ array or the JSON value.

    Raises:
        DataError: for an array that is not a scalar, a non-number (string, boolean, list ...),
            or a value that is not finite or not > 0.
    """
    if isinstance(value, np.ndarray):
        if value.ndim != 0:
            raise DataError(
                f"{path}: field 'fps' must be a scalar, got an array of shape {value.shape}"
            )
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataError(f"{path}: field 'fps' must be a real number, got {_show(value)}")
    try:
        fps = float(value)
    except OverflowError:  # a JSON integer beyond float range
        fps = math.inf
    if not (math.isfinite(fps) and fps > 0):
        raise DataError(f"{path}: field 'fps' must be finite and > 0, got {_show(value)}")
    return fps


def _metadata_field(path: Path, value: Any) -> dict[str, Any]:
    """``value`` (parsed JSON) when it is a JSON object; a DataError otherwise."""
    if not isinstance(value, dict):
        raise DataError(
            f"{path}: field 'metadata' must be a JSON object, got {_json_type(value)} "
            f"{_show(value)}"
        )
    return value


def _names_field(path: Path, key: str, value: np.ndarray) -> tuple[str, ...]:
    """The names an NPZ string array holds: (N,) unicode (a 0-d one is one name)."""
    arr = np.asarray(value)
    if arr.ndim > 1 or arr.dtype.kind != "U":
        raise DataError(
            f"{path}: field {key!r} must be a 1-D array of strings, got shape {arr.shape} "
            f"and dtype {arr.dtype}"
        )
    return tuple(str(s) for s in np.atleast_1d(arr))


#: How metadata writes the numbers JSON has no literal for (read back by :func:`_from_json`).
_NONFINITE_TEXT = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def _jsonable(obj: Any) -> Any:
    """``obj`` with numpy values, tuples and paths made JSON types, and NaN / +-inf floats
    written as ``"nan"`` / ``"inf"`` / ``"-inf"`` (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.ndarray, np.generic)):
        return _jsonable(obj.tolist())
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return "nan" if math.isnan(obj) else ("inf" if obj > 0 else "-inf")
    return obj


def _from_json(obj: Any) -> Any:
    """Inverse of :func:`_jsonable` on parsed metadata: ``"nan"`` / ``"inf"`` / ``"-inf"``
    strings back to floats, recursively."""
    if isinstance(obj, dict):
        return {k: _from_json(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_from_json(v) for v in obj]
    if isinstance(obj, str):
        return _NONFINITE_TEXT.get(obj, obj)
    return obj


#: why JSON holding an integer of more digits than Python's int() reads (4300) is refused
_LONG_INTEGER = "an integer of too many digits to read, a corrupted number"


def _parse_json(path: Path, field: str, text: str) -> Any:
    """``text`` parsed as JSON, with metadata's NaN and infinities decoded.

    Raises:
        DataError: naming ``path`` and ``field`` when it is not valid JSON, is nested too
            deep to decode, or holds an integer too long to read.
    """
    try:
        return _from_json(json.loads(text))
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: field {field} is not valid JSON ({exc})") from exc
    except ValueError as exc:  # an integer of more digits than int() reads
        raise DataError(f"{path}: field {field} is not valid JSON ({_LONG_INTEGER})") from exc
    except RecursionError as exc:
        raise DataError(f"{path}: field {field} is not valid JSON (nested too deep)") from exc


def _metadata_json(path: Path, metadata: Any) -> str:
    """The strict JSON text of a demonstration's metadata.

    Raises:
        DataError: when it is not a dict or holds values JSON cannot hold (a set, an object,
            a cycle, nesting too deep), naming ``path``.
    """
    if not isinstance(metadata, dict):
        raise DataError(f"{path}: metadata must be a dict, got {_show(metadata)}")
    try:
        return json.dumps(_jsonable(metadata), allow_nan=False)
    except (TypeError, ValueError, RecursionError) as exc:
        why = "nested too deep" if isinstance(exc, RecursionError) else str(exc)
        raise DataError(f"{path}: metadata is not JSON-serialisable ({why})") from exc


def _name_problem(name: Any, suffix: str, joint: bool) -> str | None:
    """Why the loader of ``suffix`` files could not read ``name`` back, or None.

    A CSV joint name becomes the columns ``<name>_x, _y, _z``, which the loader splits on
    commas, strips of white space, and takes for clean positions when they start with
    ``clean_``; lines end at line breaks. An NPZ name is a numpy string, which drops
    trailing NUL characters.
    """
    if not isinstance(name, str):
        return "is not a string"
    if suffix == ".npz":
        return "ends in a NUL character" if name.endswith("\x00") else None
    if not joint:
        return None  # CSV action names are JSON strings in the header comment
    if not name:
        return "is empty"
    if "," in name:
        return "holds a comma (the CSV separator)"
    if name != name.strip():
        return "starts or ends with white space (stripped from CSV columns)"
    if "".join(name.splitlines()) != name:
        return "holds a line break"
    if name == "clean" or name.startswith("clean_"):
        return "is 'clean' or starts with 'clean_' (the CSV clean-position columns)"
    return None


def _check_names(path: Path, demo: Demonstration) -> None:
    """Raise a DataError naming the first joint or action name the loader of ``path``'s
    format could not read back (or a joint named twice, or no action names)."""
    for field, names, joint in (
        ("joint_names", demo.joint_names, True),
        ("action_names", demo.action_names, False),
    ):
        for name in names:
            problem = _name_problem(name, path.suffix, joint)
            if problem:
                raise DataError(
                    f"{path}: cannot save {field} entry {_show(name)}: it {problem}; the "
                    f"{path.suffix} loader could not read it back"
                )
    twice = sorted({j for j in demo.joint_names if demo.joint_names.count(j) > 1})
    if twice:
        raise DataError(f"{path}: cannot save joint_names {twice} named more than once")
    if not demo.action_names:
        raise DataError(f"{path}: cannot save empty action_names (the loader needs one)")


def _csv_numbers(x: np.ndarray) -> np.ndarray:
    """(T, D) cells of a float array: the shortest text that reads back to the same value of
    its dtype (float32 or float64), empty for NaN."""
    cells = np.asarray(x).astype(str)
    cells[np.isnan(x)] = ""
    return cells


def save_demonstration(demo: Demonstration, path: str | Path) -> Path:
    """Write ``demo`` to ``path``; the suffix (``.npz`` or ``.csv``) picks the format.

    Args:
        demo: the demonstration (NaN joints are written as NaN / empty cells).
        path: destination file; parent folders are created.

    Returns:
        The path written.

    Raises:
        DataError: for an unknown suffix, a joint or action name the loader of that format
            could not read back (not a string; for CSV a joint name that is empty, holds a
            comma or a line break, starts or ends with white space, or starts with
            ``clean_``), a joint named twice, no action names, or metadata that is not
            JSON-serialisable; nothing is written then.
        OSError: when the file cannot be written (no permission, disk full). The file is
            written whole or not at all (:func:`iplanner_torch.files.whole_file`): a write
            that fails or is interrupted leaves an earlier file at ``path`` as it was.
    """
    path = Path(path)
    if path.suffix not in SUFFIXES:
        raise DataError(f"{path}: unknown suffix {path.suffix!r}, expected one of {SUFFIXES}")
    _check_names(path, demo)
    meta = _metadata_json(path, demo.metadata)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".npz":
        arrays: dict[str, np.ndarray] = {
            "positions": demo.positions.astype(np.float32),
            "labels": demo.labels.astype(np.int64),
            "joint_names": np.array(demo.joint_names, dtype=np.str_),
            "action_names": np.array(demo.action_names, dtype=np.str_),
            "fps": np.array(float(demo.fps)),
            "timestamps": np.asarray(demo.timestamps, dtype=np.float64),
            "metadata": np.array(meta),
        }
        if demo.clean_positions is not None:
            arrays["clean_positions"] = demo.clean_positions.astype(np.float32)
        # written through a handle: np.savez given a path would append ".npz" to the
        # temporary name
        with whole_file(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    elif path.suffix == ".csv":
        header = {
            "fps": float(demo.fps),
            "action_names": list(demo.action_names),
            "metadata": json.loads(meta),
        }
        cols = ["t", "label"] + [f"{j}_{a}" for j in demo.joint_names for a in _AXES]
        t = demo.num_frames
        blocks = [demo.positions.reshape(t, -1)]  # (T, 3K)
        if demo.clean_positions is not None:
            cols += [f"clean_{j}_{a}" for j in demo.joint_names for a in _AXES]
            blocks.append(demo.clean_positions.reshape(t, -1))
        cells = _csv_numbers(np.concatenate(blocks, axis=1))  # (T, 3K or 6K)
        lines = ["# " + json.dumps(header), ",".join(cols)]
        for ts, label, row in zip(np.asarray(demo.timestamps), demo.labels, cells, strict=True):
            lines.append(",".join([repr(float(ts)), str(int(label)), *row]))
        with whole_file(path) as tmp:
            tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _check_npz_keys(path: Path, keys: Sequence[str]) -> None:
    """Raise a DataError naming the keys of ``path`` that are none of :data:`NPZ_KEYS` (a
    misspelt ``timestamp`` must not leave the frames timed at 1 / fps by default), with a
    close accepted spelling as a hint and the accepted keys listed."""
    unknown = [k for k in keys if k not in NPZ_KEYS]
    if not unknown:
        return
    shown = []
    for k in unknown:
        hint = next(iter(difflib.get_close_matches(k.lower(), NPZ_KEYS, n=1, cutoff=0.6)), None)
        shown.append(f"{k!r}" + (f" (did you mean {hint!r}?)" if hint else ""))
    raise DataError(
        f"{path}: unknown key(s) {', '.join(shown)}; the accepted keys are "
        f"{', '.join(map(repr, NPZ_KEYS))} (see datasets/README.md): rename or remove the "
        "others, which are never dropped silently"
    )


def _read_npz(path: Path) -> dict[str, Any]:
    if path.stat().st_size == 0:
        raise DataError(f"{path}: empty file")
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise DataError(f"{path}: unreadable NPZ file ({exc})") from exc
    if magic not in _ZIP_MAGIC:
        # np.load would fall back to unpickling and suggest allow_pickle: never load pickles
        raise DataError(f"{path}: not a valid NPZ demonstration file: not a zip archive")
    try:
        # the file opened here, so that it is closed when the archive is damaged (np.load
        # given a path leaves its own file open when the zip cannot be read)
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            _check_npz_keys(path, z.files)  # before reading: an unknown key is never read
            data = {}
            for k in z.files:
                try:
                    data[k] = z[k]
                except MemoryError:  # numpy allocates the shape the header declares, first
                    raise DataError(
                        f"{path}: not a valid NPZ demonstration file: field {k!r} declares an "
                        "array too large to allocate (a damaged header)"
                    ) from None
                except ValueError as exc:
                    if "allow_pickle" not in str(exc):
                        raise
                    raise DataError(
                        f"{path}: not a valid NPZ demonstration file: field {k!r} holds pickled "
                        "Python objects (store strings as numpy unicode arrays)"
                    ) from None
    except DataError:
        raise
    except (
        zipfile.BadZipFile,
        zlib.error,  # a compressed member whose data is damaged
        ValueError,
        OSError,
        EOFError,
        NotImplementedError,  # an unsupported compression method
        RuntimeError,  # an encrypted member
        # an array header numpy cannot parse or use: unbalanced brackets, a shape of no
        # integers or beyond int64
        SyntaxError,
        tokenize.TokenError,
        TypeError,
        OverflowError,
    ) as exc:
        raise DataError(f"{path}: not a valid NPZ demonstration file: corrupt ({exc})") from exc
    for key in _REQUIRED_NPZ:
        if key not in data:
            raise DataError(f"{path}: missing key {key!r} (has {sorted(data)})")
    out: dict[str, Any] = {
        "positions": data["positions"],
        "labels": data["labels"],
        "joint_names": _names_field(path, "joint_names", data["joint_names"]),
        "action_names": _names_field(path, "action_names", data["action_names"]),
        "fps": _fps_field(path, data["fps"]) if "fps" in data else None,
        "timestamps": data.get("timestamps"),
        "clean_positions": data.get("clean_positions"),
        "metadata": {},
    }
    if "metadata" in data:
        meta = np.asarray(data["metadata"])
        if meta.ndim != 0 or meta.dtype.kind != "U":
            raise DataError(
                f"{path}: field 'metadata' must be a JSON object stored as one string, got "
                f"shape {meta.shape} and dtype {meta.dtype}"
            )
        parsed = _parse_json(path, "'metadata'", str(meta))
        out["metadata"] = _metadata_field(path, parsed)
    return out


def _header_json_error(
    path: Path, comment: list[tuple[int, str]], exc: json.JSONDecodeError
) -> str:
    """The message for a CSV header comment that is not JSON: with several ``#`` lines, which
    of them the JSON breaks on (a note line among them, say)."""
    if len(comment) == 1:
        return f"{path}: field 'header' (# JSON comment) is invalid ({exc})"
    start = 0
    for n, text in comment:  # the line holding the error's position (the last at the end)
        if exc.pos < start + len(text) or n == comment[-1][0]:
            break
        start += len(text)
    return (
        f"{path}: field 'header' (# JSON comment) is invalid: line {n} {_show('#' + text)} is "
        f"not JSON ({exc.msg} at column {exc.pos - start + 2}); the {len(comment)} '#' lines "
        f"at the top (lines {comment[0][0]}-{comment[-1][0]}) are joined into one JSON object, "
        "so a note among them must go (or move into the object's 'metadata')"
    )


def _read_csv_header(path: Path, comment: list[tuple[int, str]]) -> dict[str, Any]:
    """The CSV header comment as a dict with ``fps`` (float or None), ``action_names`` (a list
    of str or None) and ``metadata`` (a dict); ``null`` values count as absent.

    Args:
        path: the file (for messages).
        comment: (line number, text after the ``#``) of each ``#`` line at the top of the file.
    """
    header: Any = {}
    if comment:
        try:
            header = json.loads("".join(text for _, text in comment))
        except json.JSONDecodeError as exc:
            raise DataError(_header_json_error(path, comment, exc)) from exc
        except ValueError as exc:  # an integer of more digits than int() reads
            raise DataError(
                f"{path}: field 'header' (# JSON comment) is invalid ({_LONG_INTEGER})"
            ) from exc
        except RecursionError as exc:
            raise DataError(
                f"{path}: field 'header' (# JSON comment) is invalid (nested too deep)"
            ) from exc
    if not isinstance(header, dict):
        raise DataError(
            f"{path}: field 'header' (# JSON comment) is invalid: the header comment must be "
            f"a JSON object, got {_json_type(header)} {_show(header)}"
        )
    fps = header.get("fps")
    names = header.get("action_names")
    meta = header.get("metadata")
    try:
        meta = _from_json(meta)
    except RecursionError as exc:
        raise DataError(
            f"{path}: field 'metadata' in the header comment is nested too deep"
        ) from exc
    if names is not None and not (
        isinstance(names, list) and all(isinstance(n, str) for n in names)
    ):
        raise DataError(
            f"{path}: field 'action_names' in the header comment must be a JSON array of "
            f"strings, got {_show(names)}"
        )
    return {
        "fps": None if fps is None else _fps_field(path, fps),
        "action_names": names,
        "metadata": {} if meta is None else _metadata_field(path, meta),
    }


def _csv_column_known(c: str) -> bool:
    """Whether ``c`` is one of the CSV column forms: ``t``, ``label``, ``<joint>_<axis>`` or
    ``clean_<joint>_<axis>`` (a joint name is not empty)."""
    if c in ("t", "label"):
        return True
    joint = c[:-2] if c[-2:] in ("_x", "_y", "_z") else ""
    return joint not in ("", "clean")


def _check_csv_columns(path: Path, cols: list[str], header_line: int) -> None:
    """Raise a DataError naming the header row's columns of no accepted form (a misspelt
    ``label`` column must not leave every frame labelled by default)."""
    unknown = [c for c in cols if not _csv_column_known(c)]
    if not unknown:
        return
    shown = []
    for c in dict.fromkeys(unknown):
        hint = _CSV_COLUMN_HINTS.get(c.lower()) or next(
            iter(difflib.get_close_matches(c.lower(), ("t", "label"), n=1, cutoff=0.6)), None
        )
        if not c:
            shown.append("'' (an unnamed column: a trailing comma?)")
        else:
            shown.append(f"{c!r}" + (f" (did you mean {hint!r}?)" if hint else ""))
    raise DataError(
        f"{path}: unknown column(s) {', '.join(shown)} in the header row (line {header_line}); "
        f"the accepted columns are {_CSV_COLUMN_FORMS}: rename or remove the others"
    )


def _is_number(text: str) -> bool:
    """Whether ``text`` is one number as the loaders read it: a decimal or ``nan`` / ``inf``
    / ``infinity`` of ASCII characters (no ``1_000``, no other scripts' digits), white space
    around it allowed."""
    if not text.isascii() or "_" in text:
        return False
    try:
        float(text)
    except ValueError:
        return False
    return True


#: why a number read as an infinity that does not spell one (``1e400``) is refused
_OVERFLOWS = (
    f"overflows: it is beyond the largest float (+-{np.finfo(np.float64).max:.4g}), a "
    "corrupted number"
)


def _is_infinity(text: str) -> bool:
    """Whether ``text`` spells an infinity (``inf``, ``-Infinity`` ...) rather than a number
    too large for a float (``1e400``)."""
    return text.strip().lstrip("+-").lower() in ("inf", "infinity")


def _drop_cut_last_line(
    path: Path, text: str, is_row: Any = None, *, stacklevel: int = 4
) -> list[str]:
    """The lines of ``text``, without the last one when it has no line terminator and holds a
    row (not blank; ``is_row(line)`` when given), with a :class:`DataWarning` naming ``path``.

    Every file our writers and the LEGO recording write ends with a line break, so a last row
    without one may have been cut mid-number (``0.841`` of ``0.8410000205``) or after a comma
    (an empty cell, read as NaN) and is not trusted. ``stacklevel`` is the warning's (default:
    the caller of :func:`load_demonstration`).
    """
    lines = text.splitlines()
    if not lines or text.endswith(("\n", "\r")):
        return lines
    last = lines[-1]
    if not last.strip() or (is_row is not None and not is_row(last)):
        return lines
    warnings.warn(f"{path}: {CUT_LAST_LINE}", DataWarning, stacklevel=stacklevel)
    return lines[:-1]


def _read_csv(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark (Excel) is dropped
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: unreadable CSV file ({exc})") from exc
    lines = _drop_cut_last_line(path, text, is_row=lambda ln: not ln.startswith("#"))
    body = [(n, ln) for n, ln in enumerate(lines, 1) if ln.strip()]  # blank lines skipped
    top = next((i for i, (_, ln) in enumerate(body) if not ln.startswith("#")), len(body))
    comment = [(n, ln[1:]) for n, ln in body[:top]]  # the '#' lines at the top: the header
    body = body[top:]
    if not body:
        raise DataError(f"{path}: empty file (no header row, no frames)")
    header = _read_csv_header(path, comment)
    header_line, header_row = body[0]
    cols = [c.strip() for c in header_row.split(",")]
    if any(cols) and all(not c or _is_number(c) for c in cols):
        raise DataError(
            f"{path}: line {header_line} holds numbers, not column names: the first line "
            f"{'after the # header comment ' if comment else ''}must name the columns (see "
            "datasets/README.md)"
        )
    _check_csv_columns(path, cols, header_line)
    rows = body[1:]
    late = next((n for n, ln in rows if ln.startswith("#")), None)
    if late is not None:
        raise DataError(
            f"{path}: line {late}: a '#' line after the header row (line {header_line}); '#' "
            "lines are read only at the top of the file, as the JSON header comment: remove "
            "it (a note belongs in the header comment's 'metadata')"
        )
    if not rows:
        raise DataError(f"{path}: empty file (a header row but no frames)")
    table = np.empty((len(rows), len(cols)), dtype=np.float64)
    for i, (n, row) in enumerate(rows):
        cells = row.split(",")
        if len(cells) != len(cols):
            raise DataError(
                f"{path}: line {n}: {len(cells)} cells, but the header row (line {header_line}) "
                f"has {len(cols)} columns"
            )
        try:
            table[i] = [float(c) if c.strip() else np.nan for c in cells]
        except ValueError as exc:
            raise DataError(f"{path}: line {n}: unreadable or corrupt CSV row ({exc})") from exc
    for i, j in zip(*np.nonzero(np.isinf(table)), strict=True):
        text = rows[i][1].split(",")[j].strip()
        if not _is_infinity(text):
            raise DataError(
                f"{path}: line {rows[i][0]}, column {cols[j]!r}: {_show(text)} {_OVERFLOWS} "
                "(positions are metres, times seconds)"
            )
    col: dict[str, int] = {}
    for i, c in enumerate(cols):
        if c in col:
            raise DataError(
                f"{path}: column {c!r} appears twice in the header row (line {header_line})"
            )
        col[c] = i

    def cell(i: int, name: str) -> str:
        """The text of column ``name`` in frame row ``i`` (as written in the file)."""
        return rows[i][1].split(",")[col[name]].strip()

    joints: list[str] = []
    for c in cols:
        if c.endswith("_x") and not c.startswith("clean_"):
            joints.append(c[:-2])
    for c in cols:
        if c[-2:] in ("_y", "_z") and not c.startswith("clean_") and c[:-2] not in joints:
            raise DataError(f"{path}: missing column '{c[:-2]}_x'")
    for j in joints:
        for a in _AXES:
            if f"{j}_{a}" not in col:
                raise DataError(f"{path}: missing column '{j}_{a}'")
    if not joints:
        raise DataError(f"{path}: missing key 'positions' (no <joint>_x columns)")
    t = table.shape[0]
    pos = np.stack([table[:, [col[f"{j}_{a}"] for a in _AXES]] for j in joints], axis=1)
    clean = None
    clean_cols = [c for c in cols if c.startswith("clean_")]
    if clean_cols:
        want = [f"clean_{j}_{a}" for j in joints for a in _AXES]
        missing = [c for c in want if c not in col]
        if missing:
            raise DataError(
                f"{path}: missing column(s) {missing} of field 'clean_positions': the header "
                f"row (line {header_line}) has clean columns for some joints only; give "
                "clean_<joint>_x,_y,_z for every joint or for none"
            )
        extra = [c for c in clean_cols if c not in set(want)]
        if extra:
            raise DataError(
                f"{path}: column(s) {extra} of field 'clean_positions' (header row, line "
                f"{header_line}) match no joint of the position columns {joints}"
            )
        clean = np.stack(
            [table[:, [col[f"clean_{j}_{a}"] for a in _AXES]] for j in joints], axis=1
        )
    names = header["action_names"]
    if "label" in col:
        lab = table[:, col["label"]]
        bad = ~np.isfinite(lab) | (lab != np.round(lab))
        if bad.any():
            i = int(np.argmax(bad))
            raise DataError(
                f"{path}: line {rows[i][0]}: field 'labels' must be integers in every row, "
                f"got {cell(i, 'label')!r}"
            )
        if names is None:
            if lab.max() >= MAX_IMPLICIT_ACTIONS:
                i = int(np.argmax(lab))
                raise DataError(
                    f"{path}: line {rows[i][0]}: field 'labels' is {cell(i, 'label')}, but "
                    "without 'action_names' in the header comment the actions are action_0 .. "
                    f"action_<largest label>, at most {MAX_IMPLICIT_ACTIONS}; name the actions "
                    "in the header comment"
                )
            names = [f"action_{i}" for i in range(max(int(lab.max()) + 1, 1))]
        if not names:
            raise DataError(f"{path}: field 'action_names' is empty")
        bad = (lab < -1) | (lab >= len(names))
        if bad.any():  # checked as floats: a huge label must not wrap around in int64
            i = int(np.argmax(bad))
            raise DataError(
                f"{path}: line {rows[i][0]}: field 'labels' out of range: {cell(i, 'label')}, "
                f"expected -1 (unlabelled) or 0..{len(names) - 1}"
            )
        labels = lab.astype(np.int64)
    elif names is None:
        labels = np.zeros(t, dtype=np.int64)
        names = ["unlabelled"]
    else:
        # the header names actions: label 0 is a real action, so no frame may default to it
        labels = np.full(t, -1, dtype=np.int64)
        warnings.warn(
            f"{path}: no 'label' column, but the header comment names actions {names}: every "
            "frame is unlabelled (-1) and gives no training window; add a label column of "
            "action indices to use the file for training",
            DataWarning,
            stacklevel=3,  # the caller of load_demonstration
        )
    return {
        "positions": pos,
        "labels": labels,
        "joint_names": tuple(joints),
        "action_names": tuple(names),
        "fps": header["fps"],
        "timestamps": table[:, col["t"]] if "t" in col else None,
        "clean_positions": clean,
        "metadata": header["metadata"],
    }


#: how far the median timestamp spacing may stray from 1 / fps (relative)
TIMESTAMP_TOLERANCE = 0.05
#: how far one timestamp step may stray from 1 / fps (in frames) before it is a gap that warns:
#: half a frame, far above clock jitter (a 15 fps file jittering by 2 ms strays 0.03 frame),
#: and below a dropped frame (a step of 2 / fps strays one frame)
GAP_TOLERANCE = 0.5


#: How each file format marks a lost joint (for the message refusing an Inf).
_LOST_JOINT_MARK = {
    ".csv": "NaN (an empty CSV cell)",
    ".npz": "NaN",
}


def _check_coordinates(path: Path, field: str, pos: np.ndarray, joints: Sequence[str]) -> None:
    """Raise when ``pos`` ((T, K, 3) [m]) holds +-Inf (a lost joint is NaN, never Inf) or a
    coordinate beyond :data:`~iplanner_torch.types.MAX_POSITION_M` (other units, or junk).

    Check the values as the file holds them, before any cast to float32 (which would turn a
    value beyond float32's range into an Inf the file does not hold).
    """
    inf = np.isinf(pos)
    if inf.any():
        t, k, _ = np.argwhere(inf)[0]
        mark = _LOST_JOINT_MARK.get(path.suffix, "NaN")
        raise DataError(
            f"{path}: field {field!r} has {int(inf.sum())} Inf value(s), the first at frame {t}, "
            f"joint {joints[k]!r}; mark a lost joint with {mark}, never Inf"
        )
    with np.errstate(invalid="ignore"):  # NaN compares False: lost joints pass
        huge = np.abs(pos) > MAX_POSITION_M
    if huge.any():
        t, k, _ = np.argwhere(huge)[0]
        raise DataError(
            f"{path}: field {field!r} has {int(huge.sum())} coordinate(s) beyond "
            f"{MAX_POSITION_M:g} m, the first at frame {t}, joint {joints[k]!r}: "
            f"{pos[t, k].tolist()}; positions are metres (convert other units first)"
        )


def lost_joints(demo: Demonstration) -> tuple[str, ...]:
    """The joints of ``demo`` that are lost (NaN in a coordinate) in every frame."""
    lost = np.isnan(demo.positions).any(axis=-1).all(axis=0)  # (K,)
    return tuple(j for j, gone in zip(demo.joint_names, lost, strict=True) if gone)


def _warn_timestamp_gaps(path: Path, steps: np.ndarray, fps: float) -> None:
    """Warn (:class:`DataWarning`, at the caller of :func:`load_demonstration`) when a step
    of ``steps`` (the (T - 1,) timestamp differences [s]) strays from 1 / ``fps`` by more than
    :data:`GAP_TOLERANCE` of a frame, naming the first such step's frames and size."""
    off = np.abs(steps * fps - 1.0) > GAP_TOLERANCE
    if not off.any():
        return
    k = int(np.argmax(off)) + 1  # the frame after the first stray step
    step = float(steps[k - 1])
    warnings.warn(
        f"{path}: field 'timestamps' steps {step:.4g} s ({step * fps:.3g} frames) from frame "
        f"{k - 1} to frame {k} (counting from 0), but fps {fps:g} means {1.0 / fps:.4g} s; "
        f"{int(off.sum())} step(s) stray from 1 / fps by more than {GAP_TOLERANCE:g} frame "
        "(a pause, or dropped frames). The frames are used at 1 / fps, so a window across a "
        "gap joins motion from either side of it as if no time passed",
        DataWarning,
        stacklevel=4,  # the caller of load_demonstration
    )


def _validate(path: Path, raw: dict[str, Any], fps: float | None) -> Demonstration:
    pos = np.asarray(raw["positions"])
    joints = raw["joint_names"]
    if pos.ndim != 3 or pos.shape[2] != 3:
        raise DataError(f"{path}: field 'positions' must be (T, K, 3), got {pos.shape}")
    if not np.issubdtype(pos.dtype, np.floating):
        raise DataError(f"{path}: field 'positions' must be float, got {pos.dtype}")
    t, k = pos.shape[:2]
    if t == 0:
        raise DataError(f"{path}: empty file (field 'positions' has 0 frames)")
    if k == 0:
        raise DataError(f"{path}: field 'positions' has no joints (K=0): nothing to learn from")
    if len(joints) != k:
        raise DataError(
            f"{path}: field 'joint_names' has {len(joints)} names, positions has K={k}"
        )
    if len(set(joints)) != len(joints):
        raise DataError(f"{path}: field 'joint_names' has duplicates: {joints}")
    labels = np.asarray(raw["labels"])
    if labels.shape != (t,):
        raise DataError(f"{path}: field 'labels' must be ({t},), got {labels.shape}")
    if not np.issubdtype(labels.dtype, np.integer):
        raise DataError(f"{path}: field 'labels' must be integer, got {labels.dtype}")
    n_act = len(raw["action_names"])
    if n_act == 0:
        raise DataError(f"{path}: field 'action_names' is empty")
    actions = list(raw["action_names"])
    twice = sorted({a for a in actions if actions.count(a) > 1})
    if twice:
        # two labels of one name would be one action to a reader and two to the predictor
        raise DataError(f"{path}: field 'action_names' names {twice} more than once: {actions}")
    if any(not str(a).strip() for a in actions):
        raise DataError(f"{path}: field 'action_names' holds an empty name: {actions}")
    if labels.size and (labels.min() < -1 or labels.max() >= n_act):
        raise DataError(
            f"{path}: field 'labels' out of range: values in [{labels.min()}, {labels.max()}], "
            f"expected -1 (unlabelled) or 0..{n_act - 1}"
        )
    file_fps = raw["fps"]
    if file_fps is None and fps is None:
        raise DataError(
            f"{path}: field 'fps' missing; pass fps= to the loader (+data.fps=<Hz> on the "
            "command line)"
        )
    if file_fps is not None and fps is not None and not np.isclose(file_fps, fps):
        raise DataError(f"{path}: field 'fps' is {file_fps}, but fps={fps} was requested")
    the_fps = float(file_fps if file_fps is not None else fps)
    if not (math.isfinite(the_fps) and the_fps > 0):
        raise DataError(f"{path}: field 'fps' must be finite and > 0, got {the_fps}")
    if t >= 2 and not math.isfinite((t - 1) / the_fps):  # fps=1e-308: times overflow
        raise DataError(
            f"{path}: field 'fps' is {the_fps:g} Hz: the time of frame {t - 1}, "
            f"{t - 1} / fps, is beyond float range"
        )
    ts = raw["timestamps"]
    if ts is not None:
        if np.asarray(ts).dtype.kind not in "iuf":
            raise DataError(
                f"{path}: field 'timestamps' must be real numbers [s], got dtype "
                f"{np.asarray(ts).dtype}"
            )
        ts = np.asarray(ts, dtype=np.float64)
        if ts.shape != (t,):
            raise DataError(f"{path}: field 'timestamps' must be ({t},), got {ts.shape}")
        if not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
            bad = ~np.isfinite(ts)
            if bad.any():
                k = int(np.argmax(bad))
                where = f"frame {k} (counting from 0) has t = {ts[k]}"
            else:
                k = int(np.argmax(np.diff(ts) <= 0)) + 1
                where = f"frame {k} (counting from 0) has t = {ts[k]:g} s after {ts[k - 1]:g} s"
            raise DataError(
                f"{path}: field 'timestamps' must be finite and strictly increasing; {where}"
            )
    clean = raw["clean_positions"]
    if clean is not None and np.shape(clean) != pos.shape:
        raise DataError(
            f"{path}: field 'clean_positions' must be {pos.shape}, got {np.shape(clean)}"
        )
    if clean is not None and not np.issubdtype(np.asarray(clean).dtype, np.floating):
        raise DataError(
            f"{path}: field 'clean_positions' must be float, got {np.asarray(clean).dtype}"
        )
    _check_coordinates(path, "positions", pos, joints)  # before the cast: 1e39 is no Inf
    pos = pos.astype(np.float32)  # within MAX_POSITION_M now: no overflow
    if clean is not None:
        clean = np.asarray(clean)
        _check_coordinates(path, "clean_positions", clean, joints)
        clean = clean.astype(np.float32)
        nan = np.isnan(clean)
        if nan.any():  # the noise-free training targets: nothing to impute them from
            t_nan, k_nan, _ = np.argwhere(nan)[0]
            raise DataError(
                f"{path}: field 'clean_positions' has {int(nan.sum())} NaN value(s), the first "
                f"at frame {t_nan}, joint {joints[k_nan]!r}; the noise-free positions must be "
                "complete (leave the field out when there are none)"
            )
    if ts is not None and t >= 2:
        steps = np.diff(ts)
        spacing = float(np.median(steps))
        if abs(spacing * the_fps - 1.0) > TIMESTAMP_TOLERANCE:
            raise DataError(
                f"{path}: field 'timestamps' is spaced {spacing:.4g} s apart (median), but fps "
                f"{the_fps:g} means {1.0 / the_fps:.4g} s; the frames are used at 1 / fps"
            )
        _warn_timestamp_gaps(path, steps, the_fps)
    return Demonstration(
        positions=pos,
        labels=labels,
        fps=the_fps,
        joint_names=joints,
        action_names=raw["action_names"],
        timestamps=ts,
        name=path.stem,
        metadata=raw["metadata"],
        clean_positions=clean,
    )


def _fps_argument(path: Path, fps: Any, name: str = "field 'fps'") -> float | None:
    """The loader's ``fps=`` argument checked: None, or one real number, finite and > 0 [Hz].

    Args:
        path: the file or folder loaded (for the message).
        fps: the argument.
        name: what the argument stands for, for the message.

    Raises:
        DataError: naming ``path`` and the argument, for a boolean, a string, a sequence or any
            other non-number, or a value that is not finite or not > 0.
    """
    if fps is None:
        return None
    if isinstance(fps, bool) or not isinstance(fps, numbers.Real):
        raise DataError(
            f"{path}: {name} (the loader's fps= argument) must be one real number [Hz], not "
            f"a boolean, a string or a sequence; got {_show(fps)}"
        )
    try:
        value = float(fps)
    except OverflowError:  # an int beyond float range
        value = math.inf
    if not (math.isfinite(value) and value > 0):
        raise DataError(
            f"{path}: {name} must be finite and > 0, got {_show(fps)} (the loader's fps= argument)"
        )
    return value


def _joints_argument(joints: Any) -> tuple[str, ...] | None:
    """The loader's ``joints=`` argument checked: None, or a non-empty sequence of unique
    joint names.

    Raises:
        ConfigError: naming the argument, for a single string, a non-sequence, an empty
            sequence, a name that is not a string, or a name given twice.
    """
    if joints is None:
        return None
    if isinstance(joints, str):
        raise ConfigError(
            f"joints= must be a list of joint names, got the single string {joints!r}; pass a "
            f"list: joints=[{joints!r}]"
        )
    try:
        names = tuple(joints)
    except TypeError:
        raise ConfigError(
            f"joints= must be a non-empty list of unique joint names, got {_show(joints)}"
        ) from None
    if not names:
        raise ConfigError(
            "joints= must be a non-empty list of unique joint names, got an empty one (pass "
            "joints=None to keep every joint)"
        )
    bad = [j for j in names if not isinstance(j, str)]
    if bad:
        raise ConfigError(f"joints= must hold joint names (strings), got {_show(bad)}")
    twice = sorted({j for j in names if names.count(j) > 1})
    if twice:
        raise ConfigError(
            f"joints= names joint(s) {twice} more than once, got {list(names)}; select each "
            "joint once"
        )
    return names


def load_demonstration(
    path: str | Path, *, fps: float | None = None, joints: Sequence[str] | None = None
) -> Demonstration:
    """Load and validate one NPZ or CSV demonstration file (see :func:`load_demonstrations`)."""
    path = path_argument(path, "of a demonstration")
    fps = _fps_argument(path, fps)
    joints = _joints_argument(joints)
    if checks.is_dir(path, "the path of a file or folder"):
        raise DataError(
            f"{path}: is a folder; load_demonstration reads one .npz or .csv file "
            "(load_demonstrations reads every file below a folder)"
        )
    if not path.is_file():
        raise DataError(f"{path}: no such file")
    if path.suffix == ".npz":
        raw = _read_npz(path)
    elif path.suffix == ".csv":
        raw = _read_csv(path)
    else:
        raise DataError(f"{path}: unknown suffix {path.suffix!r}, expected one of {SUFFIXES}")
    demo = _validate(path, raw, fps)
    if joints is not None:
        missing = [j for j in joints if j not in demo.joint_names]
        if missing:
            raise DataError(
                f"{path}: no joint(s) {missing} in the file, which was asked to give them "
                f"(joints=); its joints (field 'joint_names'): {list(demo.joint_names)}"
            )
        demo = demo.select_joints(list(joints))
    if len(lost_joints(demo)) == demo.num_joints:
        raise DataError(
            f"{path}: field 'positions' is NaN in every frame for every joint "
            f"{list(demo.joint_names)}: nothing observed to learn from"
        )
    return demo


def demonstration_files(path: str | Path) -> list[Path]:
    """The demonstration files :func:`load_demonstrations` reads from ``path``, in its order.

    Args:
        path: one ``.npz`` / ``.csv`` file, or a folder searched recursively for them.

    Returns:
        ``[path]`` for a file; a folder's ``.npz`` and ``.csv`` files in sorted path order
        (empty when it has none), except those in an unfinished generation's temporary
        folder (``<name>.partial-<pid>``: :func:`is_partial_folder`).

    Raises:
        DataError: when ``path`` does not exist, or is (or lies in) such a temporary folder.
    """
    path = Path(path)
    if is_partial_folder(path) or is_partial_folder(path.parent):
        raise DataError(
            f"{path}: an unfinished generation's temporary folder (interrupted, or still "
            "running), not a dataset; delete it and generate the dataset anew"
        )
    if checks.is_dir(path, "the path of a file or folder"):
        return sorted(
            p
            for p in path.rglob("*")
            if p.suffix in SUFFIXES
            and p.is_file()
            and not any(is_partial_folder(d) for d in p.relative_to(path).parents)
        )
    if path.exists():
        return [path]
    raise DataError(f"{path}: no such file or folder")


def demonstration_names(path: str | Path, files: Sequence[Path]) -> list[str]:
    """The name of each demonstration file :func:`load_demonstrations` reads from ``path``:
    its path relative to the folder, without the suffix, with ``/`` between folders
    (``Task1/Human1/trial2``), as :func:`load_lego_assembly` names trials; a file directly in
    the folder (or ``path`` itself) is named by its stem.

    Args:
        path: the folder (or file) loaded.
        files: its demonstration files (:func:`demonstration_files`).

    Raises:
        DataError: naming both files when two would get the same name (``a.csv`` beside
            ``a.npz``): splits and held-out records refer to demonstrations by name.
    """
    root = Path(path) if Path(path).is_dir() else Path(path).parent
    seen: dict[str, Path] = {}
    for f in files:
        name = "/".join(f.relative_to(root).with_suffix("").parts)
        if name in seen:
            raise DataError(
                f"{path}: {seen[name]} and {f} would both be demonstration {name!r} (splits "
                "and held-out records name demonstrations by path without the suffix); keep "
                "one of them, or rename the other"
            )
        seen[name] = f
    return list(seen)


def is_partial_folder(path: str | Path) -> bool:
    """Whether ``path`` is named as an unfinished generation's temporary folder
    (``<name>.partial-<pid>``: :data:`PARTIAL_MARK`)."""
    return _PARTIAL_NAME.fullmatch(Path(path).name) is not None


def load_demonstrations(
    path: str | Path, *, fps: float | None = None, joints: Sequence[str] | None = None
) -> list[Demonstration]:
    """Load every demonstration under ``path``.

    Args:
        path: one ``.npz`` / ``.csv`` file, or a folder searched recursively for them (other
            files, e.g. a README, are ignored); files are taken in sorted path order.
        fps: frame rate [Hz] for files that do not state one, one finite number > 0 (not a
            boolean or a sequence); a file stating another rate is an error.
        joints: keep only these joints, in this order: a non-empty list of unique names (e.g.
            ``["right_hand"]``, not the string ``"right_hand"``); without it every file must
            have the same joint names in the same order.

    Returns:
        The demonstrations; NaN joints are kept as NaN. Each is named by its file's path
        relative to ``path`` (its parent for a file), without the suffix:
        ``Task1/Human1/trial2`` (:func:`demonstration_names`).

    Raises:
        DataError: naming the file and the field: no files, unreadable or corrupt file, empty
            file, missing key, wrong shape, a ragged CSV row (with its line number), Inf
            positions, every joint NaN in every frame, label out of range, non-increasing
            timestamps, unknown joint name in ``joints``, joint names differing between files,
            fps missing or contradicting ``fps``, an ``fps`` argument that is not one finite
            number > 0, a CSV column of no accepted form (named, with the accepted forms), a
            CSV whose first row holds numbers rather than column names, a ``#`` line after a
            CSV's column header row, a CSV cell overflowing a float (``1e400``), an NPZ key
            of no accepted field (named, with the accepted keys :data:`NPZ_KEYS`), timestamps
            whose median spacing is not 1 / fps, two files that would get the same name
            (both named); also for a ``path`` that is not a str or os.PathLike, or that the
            system cannot look up (a name too long).
        ConfigError: for a ``joints`` argument that is not a non-empty sequence of unique
            names (a single string included).

    Warns:
        DataWarning: for a CSV without a ``label`` column whose header names actions (every
            frame is then unlabelled, -1); for a CSV whose last line has no line terminator
            (it may be cut short: that row is dropped); for timestamps with a gap, a step
            that strays from 1 / fps by more than :data:`GAP_TOLERANCE` of a frame (a pause,
            a dropped frame: 2 / fps), naming the first such step's frames and size and the
            count. The file loads with its timestamps as they are, but the frames are used
            at 1 / fps, so a window across the gap joins motion from both sides of it. Clock
            jitter within half a frame does not warn; the LEGO recording states no times.
    """
    path = path_argument(path, "of demonstrations", kind="file or folder path")
    fps = _fps_argument(path, fps)
    joints = _joints_argument(joints)
    files = demonstration_files(path)
    if not files:
        raise DataError(f"{path}: no .npz or .csv demonstration files in this folder")
    names = demonstration_names(path, files)
    demos = [load_demonstration(f, fps=fps, joints=joints) for f in files]
    for d, name in zip(demos, names, strict=True):
        d.name = name
    for f, d in zip(files, demos, strict=True):
        if d.joint_names != demos[0].joint_names:
            raise DataError(
                f"{f}: field 'joint_names' {list(d.joint_names)} differ from "
                f"{list(demos[0].joint_names)} of {files[0]}; every file needs the same joints "
                "in the same order (or select common ones: joints=, data.windows.joints=[...])"
            )
    return demos


#: Column order of the LEGO assembly recording (18 numbers per row).
LEGO_JOINTS: tuple[str, ...] = (
    "left_hand",
    "right_hand",
    "left_elbow",
    "right_elbow",
    "left_shoulder",
    "right_shoulder",
)
#: The K axis of loaded LEGO demonstrations (the order of :data:`skeleton.JOINT_NAMES`).
LEGO_OUTPUT_JOINTS: tuple[str, ...] = (
    "left_shoulder",
    "left_elbow",
    "left_hand",
    "right_shoulder",
    "right_elbow",
    "right_hand",
)


#: Numbers in a row of the LEGO assembly recording: x, y, z of each of :data:`LEGO_JOINTS`.
_LEGO_NUMBERS = 3 * len(LEGO_JOINTS)


def _check_lego_row(path: Path, line: int, row: list[str]) -> None:
    """Raise a DataError for the first entry of ``row`` (the white-space separated entries of
    file line ``line``) that is not a number, else for a count other than 18."""
    for m, text in enumerate(row, 1):
        if not _is_number(text):
            sep = "," in text or ";" in text
            raise DataError(
                f"{path}: line {line}, number {m}: {_show(text)} is not a number"
                + (" (numbers are separated by spaces or tabs, not , or ;)" if sep else "")
            )
    if len(row) != _LEGO_NUMBERS:
        raise DataError(
            f"{path}: line {line}: {len(row)} number{'s' if len(row) != 1 else ''}, expected "
            f"{_LEGO_NUMBERS} (x, y, z of {', '.join(LEGO_JOINTS)})"
        )


def _read_lego_trial(path: Path) -> np.ndarray:
    """The numbers of one LEGO trial file, (T, 18) float64 (x, y, z of :data:`LEGO_JOINTS`).

    Read as ``numpy.loadtxt`` read it: entries separated by white space, blank lines skipped,
    ``#`` starts a comment to the end of the line, ``nan`` for a lost joint, a leading UTF-8
    byte-order mark dropped (as the CSV reader drops it); a last line
    without a line terminator is dropped with a :class:`DataWarning`. Errors name the file
    line a text editor shows and the entry's place in it.

    Raises:
        DataError: for an unreadable file, a binary one (a NUL byte), an entry that is not a
            number (``abc``, ``1,2``), a line of other than 18 numbers, no rows at all, or a
            value that is infinite or beyond :data:`~iplanner_torch.types.MAX_POSITION_M`
            (other units, or junk).
    """
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: unreadable LEGO trial ({exc})") from exc
    nul = raw.find(b"\x00")
    if nul >= 0:  # binary content (text has no NUL): named, not echoed to the terminal
        raise DataError(
            f"{path}: not a text file (a NUL byte at byte {nul}); a LEGO trial holds lines "
            f"of {_LEGO_NUMBERS} numbers"
        )
    # a byte-order mark (a file saved by Windows Notepad or Excel) is dropped; a byte that is
    # not UTF-8 (a comment in another encoding) is replaced
    text = raw.decode("utf-8-sig", errors="replace")
    tokens: list[str] = []
    line_of: list[int] = []  # the file line (1-based) of each row
    lines = _drop_cut_last_line(  # stacklevel 4: the caller of load_lego_assembly
        path, text, is_row=lambda ln: bool(ln.partition("#")[0].strip()), stacklevel=4
    )
    for n, ln in enumerate(lines, 1):
        if "#" in ln:
            ln = ln[: ln.index("#")]
        row = ln.split()
        if not row:
            continue
        if len(row) != _LEGO_NUMBERS or "_" in ln or not ln.isascii():
            _check_lego_row(path, n, row)  # float() reads 1_0 and other scripts' digits
        tokens.extend(row)
        line_of.append(n)
    if not line_of:
        raise DataError(f"{path}: empty file (no rows of numbers)")
    try:
        flat = np.fromiter(map(float, tokens), dtype=np.float64, count=len(tokens))
    except ValueError:
        for i, n in enumerate(line_of):  # find the entry float() refused
            _check_lego_row(path, n, tokens[i * _LEGO_NUMBERS : (i + 1) * _LEGO_NUMBERS])
        raise
    table = flat.reshape(-1, _LEGO_NUMBERS)  # (T, 18)
    with np.errstate(invalid="ignore"):  # NaN compares False: lost joints pass
        bad = np.abs(table) > MAX_POSITION_M  # Inf included
    if bad.any():
        i, j = divmod(int(np.argmax(bad)), _LEGO_NUMBERS)  # the first in file order
        entry = tokens[i * _LEGO_NUMBERS + j]
        where = (
            f"{path}: line {line_of[i]}, number {j + 1} ({LEGO_JOINTS[j // 3]} "
            f"{_AXES[j % 3]}): {_show(entry)}"
        )
        count = (
            f"{int(bad.sum())} such value(s) in the trial: infinite or beyond {MAX_POSITION_M:g} m"
        )
        if not np.isinf(table[i, j]):
            why = (
                f"is beyond {MAX_POSITION_M:g} m: positions are metres (convert other units first)"
            )
        elif _is_infinity(entry):
            why = "is infinite: mark a lost joint with NaN ('nan' in the text), never Inf"
        else:
            why = _OVERFLOWS
        raise DataError(f"{where} {why} ({count})")
    return table


def load_lego_assembly(path: str | Path, *, fps: float = 30.0) -> list[Demonstration]:
    """Load the real LEGO assembly recording (``Task*/Human*/trial*.txt``, 18 numbers a row).

    The wrists are mapped to our ``*_hand`` joints. Positions stay in the camera frame
    (metres): they are not in the table frame, so use them for motion, not for placement.
    There are no action labels: every frame has label 0 of the single action
    ``"unlabelled"``. NaN values are kept.

    Args:
        path: the recording's folder (searched recursively for ``*.txt``) or one trial file.
        fps: the frame rate, which the recording does not state (the camera usually runs at
            30 fps).

    Returns:
        One demonstration per trial, named ``Task1/Human1/trial1`` etc., in sorted order.

    A trial is read line by line: numbers separated by spaces or tabs, blank lines skipped,
    ``#`` starting a comment, ``nan`` for a lost joint. Errors name the file line a text editor
    shows: ``line 7, number 6: 'abc' is not a number``, ``line 5: 17 numbers, expected 18``.

    Raises:
        DataError: when nothing is found, a file is empty or not a (T, 18) table of numbers
            (text, commas or semicolons, another count on a line), holds an infinite value or
            one beyond :data:`~iplanner_torch.types.MAX_POSITION_M` (other units), has no
            joint observed in any frame, or ``fps`` is not one finite number > 0.

    Warns:
        DataWarning: for a trial file whose last line has no line terminator (it may be cut
            short: that row is dropped).
    """
    path = Path(path)
    if checks.is_dir(path, "the path of a file or folder"):
        files = sorted(p for p in path.rglob("*.txt") if p.is_file())
        root = path
    elif path.is_file():
        files, root = [path], path.parent
    else:
        raise DataError(
            f"{path}: no such file or folder (the LEGO assembly recording; a relative path is "
            "taken from the current directory: run from the project root or set "
            "data.path=<folder holding Task*/Human*/trial*.txt>)"
        )
    if not files:
        raise DataError(
            f"{path}: no trial .txt files found (expected Task*/Human*/trial*.txt; set "
            "data.path=<folder> to the recording)"
        )
    fps = _fps_argument(path, fps, "fps")
    if fps is None:
        raise DataError(f"{path}: the fps= argument is required (the recording states none)")
    order = [LEGO_JOINTS.index(j) for j in LEGO_OUTPUT_JOINTS]
    demos = []
    for f in files:
        table = _read_lego_trial(f)  # (T, 18)
        pos = table.reshape(-1, 6, 3)[:, order]  # (T, 6, 3)
        if np.isnan(pos).any(axis=-1).all():  # as load_demonstrations refuses such a file
            raise DataError(
                f"{f}: field 'positions' is NaN in every frame for every joint "
                f"{list(LEGO_OUTPUT_JOINTS)}: nothing observed to learn from"
            )
        rel = f.relative_to(root).with_suffix("")
        parts = rel.parts
        demos.append(
            Demonstration(
                positions=pos,
                labels=np.zeros(pos.shape[0], dtype=np.int64),
                fps=fps,
                joint_names=LEGO_OUTPUT_JOINTS,
                action_names=("unlabelled",),
                name="/".join(parts),
                metadata={
                    "source": "intelligent-control-lab/Human_Assembly_Data",
                    "frame": "camera",
                    "file": str(rel),
                    "task": parts[-3] if len(parts) >= 3 else "",
                    "human": parts[-2] if len(parts) >= 2 else "",
                },
            )
        )
    return demos
