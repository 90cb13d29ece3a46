"""Demonstration files: NPZ keys of no known field, gaps between timestamps, and saves that
fail mid-write."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.io import (
    NPZ_KEYS,
    load_demonstration,
    load_demonstrations,
    load_lego_assembly,
    save_demonstration,
)
from iplanner_torch.errors import DataError, DataWarning

ROOT = Path(__file__).resolve().parents[2]
LEGO = ROOT.parent / "shared" / "data" / "lego_assembly_3d"


def _demo(t: int = 12, *, clean: bool = True, seed: int = 0) -> Demonstration:
    """A ``t``-frame, 2-joint demonstration at 15 fps."""
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(t, 2, 3)).astype(np.float32)
    return Demonstration(
        positions=pos,
        labels=np.zeros(t, dtype=np.int64),
        fps=15.0,
        joint_names=("a", "b"),
        action_names=("idle",),
        timestamps=np.arange(t) / 15.0,
        metadata={"seed": seed},
        clean_positions=pos + 0.5 if clean else None,
    )


def _npz(path: Path, timestamps: np.ndarray | None = None, **extra: np.ndarray) -> Path:
    """A demonstration written with numpy.savez (as a user would), plus ``extra`` keys."""
    d = _demo(12 if timestamps is None else len(timestamps))
    arrays = {
        "positions": d.positions,
        "labels": d.labels,
        "joint_names": np.array(d.joint_names),
        "action_names": np.array(d.action_names),
        "fps": np.array(15.0),
        "metadata": np.array(json.dumps({})),
    }
    if timestamps is not None:
        arrays["timestamps"] = timestamps
    np.savez(path, **arrays, **extra)
    return path


def _no_data_warning(load, *args, **kwargs):
    """``load(*args, **kwargs)`` with any DataWarning raised as an error."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        return load(*args, **kwargs)


# ------------------------------------------------------------------ NPZ keys of no field


@pytest.mark.parametrize(
    ("key", "hint"),
    [
        ("timestamp", "timestamps"),  # was dropped: the times became arange(T) / fps
        ("clean_position", "clean_positions"),  # was dropped: clean_positions None
        ("subject", None),
    ],
)
def test_npz_key_of_no_field_is_refused_naming_it(tmp_path, key, hint):
    p = _npz(tmp_path / "x.npz", **{key: np.arange(12) / 15.0})
    with pytest.raises(DataError, match=rf"x\.npz: unknown key\(s\) '{key}'") as info:
        load_demonstration(p)
    message = str(info.value)
    if hint:
        assert f"did you mean {hint!r}?" in message
    for accepted in NPZ_KEYS:
        assert repr(accepted) in message  # the accepted keys are listed
    assert "never dropped" in message or "rename or remove" in message


@pytest.mark.parametrize("clean", [True, False])
def test_every_key_save_demonstration_writes_is_accepted(tmp_path, clean):
    path = save_demonstration(_demo(clean=clean), tmp_path / "d.npz")
    with np.load(path) as z:
        written = set(z.files)
    assert written <= set(NPZ_KEYS)
    assert {"metadata", "timestamps", "fps"} <= written
    e = _no_data_warning(load_demonstration, path)
    assert (e.clean_positions is not None) == clean


# ------------------------------------------------------------------ gaps between timestamps


@pytest.mark.parametrize(
    ("make", "frame", "step"),
    [
        (lambda ts: ts.__setitem__(slice(40, None), ts[40:] + 100.0), 40, "100.1"),
        (lambda ts: ts.__setitem__(slice(20, None), ts[20:] + 1 / 15.0), 20, "0.1333"),
    ],
    ids=["jump_of_100_s", "one_dropped_frame"],
)
def test_a_gap_between_timestamps_warns_naming_frame_and_size(tmp_path, make, frame, step):
    """Frames are used at 1 / fps: a step of another size (a pause, a dropped frame) loads,
    with a DataWarning naming where and how large (the median check alone missed it)."""
    ts = np.arange(60) / 15.0
    make(ts)
    p = _npz(tmp_path / "gap.npz", timestamps=ts)
    with pytest.warns(DataWarning, match=rf"gap\.npz: field 'timestamps' steps {step} s") as rec:
        (d,) = load_demonstrations(p)
    message = str(rec[0].message)
    assert f"from frame {frame - 1} to frame {frame}" in message
    assert "1 step(s)" in message and "0.06667 s" in message
    np.testing.assert_array_equal(d.timestamps, ts)  # the times kept as the file has them


def test_a_step_far_shorter_than_one_frame_warns_too(tmp_path):
    ts = np.arange(30) / 15.0
    ts[10:] -= 0.6 / 15.0  # frame 10 comes 0.4 frame after frame 9
    with pytest.warns(DataWarning, match=r"steps 0\.02667 s .*from frame 9 to frame 10") as rec:
        load_demonstration(_npz(tmp_path / "short.npz", timestamps=ts))
    assert rec[0].filename == __file__  # the warning points at the caller of the loader


def test_a_csv_gap_warns_as_well(tmp_path):
    d = _demo(30)
    d.timestamps = d.timestamps.copy()
    d.timestamps[12:] += 2.0
    path = save_demonstration(d, tmp_path / "gap.csv")
    with pytest.warns(DataWarning, match=r"gap\.csv: .*from frame 11 to frame 12"):
        e = load_demonstration(path)
    np.testing.assert_array_equal(e.timestamps, d.timestamps)


def test_jitter_within_the_tolerance_gives_no_warning(tmp_path):
    """Steps off 1 / fps by less than half a frame are jitter, not gaps."""
    rng = np.random.default_rng(0)
    ts = np.arange(200) / 15.0 + rng.uniform(-0.2, 0.2, 200) / 15.0
    _no_data_warning(load_demonstration, _npz(tmp_path / "j.npz", timestamps=ts))
    _no_data_warning(load_demonstration, _npz(tmp_path / "none.npz"))  # arange(T) / fps


@pytest.mark.skipif(not (ROOT / "datasets" / "reaching").is_dir(), reason="no shipped set")
def test_the_shipped_datasets_load_without_a_data_warning():
    for folder in sorted((ROOT / "datasets").iterdir()):
        if folder.is_dir():
            assert _no_data_warning(load_demonstrations, folder)


@pytest.mark.skipif(not LEGO.is_dir(), reason="no LEGO recording")
def test_the_lego_recording_loads_without_a_data_warning():
    assert len(_no_data_warning(load_lego_assembly, LEGO)) > 0


# ------------------------------------------------------------------ saves that fail mid-write

_FAIL_MID_WRITE = """
import resource, signal, sys
import numpy as np
from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.io import save_demonstration

rng = np.random.default_rng(1)
big = Demonstration(
    positions=rng.normal(size=(3000, 2, 3)).astype(np.float32),
    labels=np.zeros(3000, dtype=np.int64), fps=15.0, joint_names=("a", "b"),
    action_names=("idle",),
)
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (2048, 2048))  # the disk is full after 2 KiB
try:
    save_demonstration(big, sys.argv[1])
except OSError as exc:
    print("failed:", exc)
    sys.exit(3)
sys.exit(0)
"""


def _run_with_full_disk(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )


@pytest.mark.skipif(sys.platform == "win32", reason="RLIMIT_FSIZE is POSIX")
@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_a_save_that_fails_mid_write_keeps_the_old_file(tmp_path, suffix):
    path = save_demonstration(_demo(), tmp_path / f"good{suffix}")
    before = path.read_bytes()
    old = load_demonstration(path)
    done = _run_with_full_disk(_FAIL_MID_WRITE, str(path))
    assert done.returncode == 3, done.stdout + done.stderr  # the save failed, with OSError
    assert path.read_bytes() == before  # was cut to 2 KiB of the new file
    new = load_demonstration(path)
    np.testing.assert_array_equal(new.positions, old.positions)
    np.testing.assert_array_equal(new.clean_positions, old.clean_positions)
    np.testing.assert_array_equal(new.timestamps, old.timestamps)
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temporary left


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_a_save_writes_exactly_the_path_given(tmp_path, suffix):
    """The temporary file is written through a handle: numpy adds no second '.npz'."""
    path = save_demonstration(_demo(), tmp_path / f"x{suffix}")
    assert path == tmp_path / f"x{suffix}"
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"x{suffix}"]
    save_demonstration(_demo(seed=4), path)  # overwrites in one step
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"x{suffix}"]
    assert load_demonstration(path).metadata == {"seed": 4}
