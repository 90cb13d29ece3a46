"""Damaged demonstration files and paths that raised untyped errors: each a DataError now."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.io import (
    load_demonstration,
    load_demonstrations,
    load_lego_assembly,
    save_demonstration,
)
from iplanner_torch.errors import DataError

_LONG = "9" * 5000  # more digits than int() reads (4300): json.loads raised a ValueError


def _saved(path: Path) -> Path:
    """A 6-frame, 2-joint demonstration saved to ``path``."""
    demo = Demonstration(
        positions=np.arange(36, dtype=np.float32).reshape(6, 2, 3) / 10,
        labels=np.zeros(6, dtype=np.int64),
        fps=15.0,
        joint_names=("a", "b"),
        action_names=("idle",),
    )
    return save_demonstration(demo, path)


def test_json_integer_of_too_many_digits(tmp_path):
    p = _saved(tmp_path / "m.npz")
    arrays = dict(np.load(p))
    arrays["metadata"] = np.array('{"subject": ' + _LONG + "}")
    np.savez(p, **arrays)
    with pytest.raises(
        DataError, match=r"m\.npz: field 'metadata' is not valid JSON \(an integer of too many"
    ):
        load_demonstration(p)
    c = tmp_path / "h.csv"
    c.write_text('# {"fps": ' + _LONG + "}\nlabel,a_x,a_y,a_z\n0,1,2,3\n")
    with pytest.raises(
        DataError, match=r"h\.csv: field 'header' \(# JSON comment\) is invalid \(an integer"
    ):
        load_demonstration(c)


def _npz_with_positions_header(path: Path, header: str) -> Path:
    """``path`` rewritten with the ``.npy`` header of its positions replaced by ``header``
    (the zip itself intact: its checksums match the damaged member)."""
    with zipfile.ZipFile(_saved(path)) as z:
        members = {name: z.read(name) for name in z.namelist()}
    text = header.ljust(118) + "\n"
    members["positions.npy"] = (
        b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode() + bytes(2000)
    )
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


@pytest.mark.parametrize(
    ("descr", "shape", "raised"),
    [
        ("'<f4'", "(6, 2, 3", "tokenize.TokenError"),
        ("'<,4'", "(6, 2, 3)", "SyntaxError"),
        ("'<f4'", "(True,)", "TypeError"),
        ("'<f4'", "(100000000000000000000000000000, 3)", "OverflowError"),
        ("'<f4'", "(100000000000, 100000, 3)", "MemoryError"),
    ],
)
def test_npz_array_header_that_numpy_cannot_use(tmp_path, descr, shape, raised):
    header = f"{{'descr': {descr}, 'fortran_order': False, 'shape': {shape}, }}"
    p = _npz_with_positions_header(tmp_path / "x.npz", header)
    with pytest.raises(DataError, match=r"x\.npz: not a valid NPZ demonstration file: "):
        load_demonstration(p)  # raised the error of the second column


@pytest.mark.parametrize("loader", [load_demonstration, load_demonstrations, load_lego_assembly])
def test_a_path_the_system_cannot_look_up(tmp_path, loader):
    text = "t,label,a_x,a_y,a_z\n" + "0,0,1,2,3," * 40  # a file's text passed as its path
    for path in (tmp_path / ("x" * 300 + ".csv"), text):
        with pytest.raises(DataError, match=r"cannot look up this path \(File name too long\)"):
            loader(path)  # raised OSError


@pytest.mark.parametrize("in_file", [True, False])
def test_a_frame_rate_so_small_that_frame_times_overflow(tmp_path, in_file):
    """fps=1e-308 is finite and > 0, but (T - 1) / fps is not: the frame times, computed
    when the file gives none, were infinite (with numpy's RuntimeWarning)."""
    p = _saved(tmp_path / "m.npz")
    arrays = {k: v for k, v in np.load(p).items() if k not in ("timestamps", "fps")}
    if in_file:
        arrays["fps"] = np.array(1e-308)
    np.savez(p, **arrays)
    with pytest.raises(DataError, match=r"fps' is 1e-308 Hz: the time of frame 5"):
        load_demonstration(p, fps=None if in_file else 1e-308)
    if not in_file:  # a slow rate whose frame times are finite is fine
        demo = load_demonstration(p, fps=1e-3)
        assert demo.timestamps[-1] == pytest.approx(5e3)
