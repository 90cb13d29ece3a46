"""Files written whole or not at all."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path


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
