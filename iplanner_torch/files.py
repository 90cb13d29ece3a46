"""Files written whole or not at all."""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any


@contextmanager
def whole_file(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` for the block to write; it replaces ``path`` in one
    step (``os.replace``) when the block ends without an error.

    A run killed, interrupted or out of disk while writing leaves ``path`` as it was (the
    earlier file, or none) rather than cut short; when the block raises, the temporary file is
    removed and the error goes on. The temporary name is unique (``.<name>.<random>.tmp`` in
    the same folder, so the replacement stays on one file system), so two processes writing
    the same file do not write into each other's; the last to finish wins.

    Args:
        path: the file to write; its folder must exist.

    Yields:
        The temporary path (no file there yet: the block creates it).
    """
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    tmp.unlink()  # the block creates it: a writer that refuses existing files works too
    try:
        yield tmp
        tmp.replace(path)
    except BaseException:
        with suppress(OSError):
            tmp.unlink()
        raise


def _plain(value: Any, default: Callable[[Any], Any]) -> Any:
    """``value`` as JSON types, a non-finite float as None (numpy and torch scalars and arrays
    through their ``tolist``, anything else through ``default``)."""
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _plain(v, default) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v, default) for v in value]
    if hasattr(value, "tolist"):  # numpy or torch: a scalar or an array
        return _plain(value.tolist(), default)
    return _plain(default(value), default)


def json_text(value: Any, *, default: Callable[[Any], Any] = float, **kwargs: Any) -> str:
    """Standard JSON of ``value``: NaN and infinities written as ``null`` (Python's own
    ``NaN`` / ``Infinity`` literals are refused by JavaScript's, jq's strict and most other
    parsers), numpy and torch numbers as numbers, other objects through ``default``;
    ``kwargs`` go to :func:`json.dumps` (``indent``, ``sort_keys``)."""
    return json.dumps(_plain(value, default), allow_nan=False, **kwargs)
