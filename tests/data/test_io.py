"""Demonstration files: round trips, joint selection, each bad-file error, LEGO recording."""

from __future__ import annotations

import gc
import json
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.io import (
    demonstration_files,
    demonstration_names,
    load_demonstration,
    load_demonstrations,
    load_lego_assembly,
    lost_joints,
    save_demonstration,
)
from iplanner_torch.data.skeleton import JOINT_NAMES
from iplanner_torch.errors import ConfigError, DataError, DataWarning

LEGO = Path(__file__).resolve().parents[3] / "shared" / "data" / "lego_assembly_3d"


def _demo(t: int = 12, seed: int = 0) -> Demonstration:
    rng = np.random.default_rng(seed)
    clean = rng.normal(size=(t, len(JOINT_NAMES), 3)).astype(np.float32)
    pos = clean + 0.01
    pos[3, 2] = np.nan
    pos[4:6, 9] = np.nan
    return Demonstration(
        positions=pos,
        labels=np.r_[np.zeros(4), np.ones(t - 6), 2 * np.ones(2)].astype(int),
        fps=15.0,
        joint_names=JOINT_NAMES,
        action_names=("idle", "reach_0", "return"),
        timestamps=np.arange(t) / 15.0 + 100.0,
        name="d",
        metadata={"target": 3, "speed": 0.5, "note": "x"},
        clean_positions=clean,
    )


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_round_trip_keeps_nan_and_metadata(tmp_path, suffix):
    d = _demo()
    save_demonstration(d, tmp_path / f"a{suffix}")
    (e,) = load_demonstrations(tmp_path / f"a{suffix}")
    np.testing.assert_array_equal(e.positions, d.positions)  # bit-identical, NaN where NaN
    assert np.isnan(e.positions[3, 2]).all() and np.isnan(e.positions[4:6, 9]).all()
    np.testing.assert_array_equal(e.clean_positions, d.clean_positions)
    np.testing.assert_array_equal(e.labels, d.labels)
    np.testing.assert_array_equal(e.timestamps, d.timestamps)
    assert e.joint_names == d.joint_names and e.action_names == d.action_names
    assert e.fps == 15.0 and e.metadata == d.metadata and e.name == "a"


def test_folder_is_sorted_and_readme_ignored(tmp_path):
    for name in ("b.npz", "a.csv", "sub/c.npz"):
        save_demonstration(_demo(), tmp_path / name)
    (tmp_path / "README.md").write_text("hello")
    names = [d.name for d in load_demonstrations(tmp_path)]
    assert names == ["a", "b", "sub/c"]  # named by path in the folder, without the suffix


def test_joint_subset_one_wrist(tmp_path):
    d = _demo()
    save_demonstration(d, tmp_path / "a.npz")
    (e,) = load_demonstrations(tmp_path, joints=["right_hand"])
    assert e.joint_names == ("right_hand",) and e.positions.shape == (12, 1, 3)
    np.testing.assert_array_equal(e.positions[:, 0], d.positions[:, 9])
    np.testing.assert_array_equal(e.clean_positions[:, 0], d.clean_positions[:, 9])


def test_csv_saved_with_a_byte_order_mark_reads_the_same(tmp_path):
    """Spreadsheet programs prefix UTF-8 CSVs with a byte-order mark, which used to hide the
    '#' header line."""
    d = _demo()
    save_demonstration(d, tmp_path / "a.csv")
    bom = tmp_path / "b.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + (tmp_path / "a.csv").read_bytes())
    a, b = load_demonstrations(tmp_path / "a.csv")[0], load_demonstrations(bom)[0]
    np.testing.assert_array_equal(a.positions, b.positions)
    assert (a.fps, a.action_names, a.joint_names) == (b.fps, b.action_names, b.joint_names)


def test_csv_without_header_needs_fps(tmp_path):
    p = tmp_path / "raw.csv"
    p.write_text("right_hand_x,right_hand_y,right_hand_z\n0,0,0\n1,,2\n")
    with pytest.raises(DataError, match="'fps' missing"):
        load_demonstrations(p)
    (d,) = load_demonstrations(p, fps=30.0)
    assert d.fps == 30.0 and d.action_names == ("unlabelled",) and d.labels.tolist() == [0, 0]
    assert np.isnan(d.positions[1, 0, 1])


def _npz(path: Path, **override) -> Path:
    d = _demo()
    arrays = {
        "positions": d.positions,
        "labels": d.labels,
        "joint_names": np.array(d.joint_names),
        "action_names": np.array(d.action_names),
        "fps": np.array(15.0),
        "metadata": np.array(json.dumps({})),
    }
    arrays.update(override)
    arrays = {k: v for k, v in arrays.items() if v is not None}
    np.savez(path, **arrays)
    return path


def test_error_wrong_shape(tmp_path):
    p = _npz(tmp_path / "x.npz", positions=np.zeros((12, 10, 2), np.float32))
    with pytest.raises(DataError, match=r"x\.npz: field 'positions' must be \(T, K, 3\)"):
        load_demonstrations(p)


def test_error_joint_count_mismatch(tmp_path):
    p = _npz(tmp_path / "x.npz", joint_names=np.array(["a", "b"]))
    with pytest.raises(DataError, match="x.npz: field 'joint_names' has 2 names"):
        load_demonstrations(p)


def test_error_unknown_joint(tmp_path):
    p = _npz(tmp_path / "x.npz")
    with pytest.raises(DataError, match=r"x\.npz: no joint\(s\) \['left_wrist'\] in the file"):
        load_demonstrations(p, joints=["left_wrist"])


def test_error_labels_out_of_range(tmp_path):
    p = _npz(tmp_path / "x.npz", labels=np.full(12, 3))
    with pytest.raises(DataError, match="x.npz: field 'labels' out of range"):
        load_demonstrations(p)


def test_error_labels_wrong_length(tmp_path):
    p = _npz(tmp_path / "x.npz", labels=np.zeros(5, int))
    with pytest.raises(DataError, match=r"field 'labels' must be \(12,\)"):
        load_demonstrations(p)


def test_error_non_monotonic_timestamps(tmp_path):
    ts = np.arange(12) / 15.0
    ts[5] = ts[3]
    p = _npz(tmp_path / "x.npz", timestamps=ts)
    with pytest.raises(
        DataError,
        match=r"x.npz: field 'timestamps' must be finite and strictly "
        r"increasing; frame 5 \(counting from 0\) has t = 0.2 s after 0.266667",
    ):
        load_demonstrations(p)
    ts[5] = np.nan
    p = _npz(tmp_path / "y.npz", timestamps=ts)
    with pytest.raises(DataError, match=r"y.npz: .*; frame 5 \(counting from 0\) has t = nan"):
        load_demonstrations(p)


def test_error_timestamps_that_disagree_with_fps(tmp_path):
    """Frames are used at 1 / fps: timestamps spaced otherwise (30 Hz under fps 15) are refused;
    a few ms of jitter is not."""
    p = _npz(tmp_path / "x.npz", timestamps=np.arange(12) / 30.0)
    with pytest.raises(DataError, match=r"x\.npz: field 'timestamps' is spaced 0\.03333 s apart"):
        load_demonstrations(p)
    jitter = np.arange(12) / 15.0 + np.random.default_rng(0).uniform(-0.002, 0.002, 12)
    assert len(load_demonstrations(_npz(tmp_path / "y.npz", timestamps=jitter))) == 1


def test_error_nan_in_clean_positions(tmp_path):
    clean = _demo().clean_positions.copy()
    clean[4, 6, 0] = np.nan
    p = _npz(tmp_path / "x.npz", clean_positions=clean)
    with pytest.raises(
        DataError, match=r"x\.npz: field 'clean_positions' has 1 NaN .*frame 4, joint 'left_hand'"
    ):
        load_demonstrations(p)


def test_error_empty_files(tmp_path):
    (tmp_path / "e.npz").write_bytes(b"")
    with pytest.raises(DataError, match="e.npz: empty file"):
        load_demonstrations(tmp_path / "e.npz")
    p = _npz(
        tmp_path / "z.npz", positions=np.zeros((0, 10, 3), np.float32), labels=np.zeros(0, int)
    )
    with pytest.raises(DataError, match="z.npz: empty file"):
        load_demonstrations(p)
    (tmp_path / "e.csv").write_text("# {}\n")
    with pytest.raises(DataError, match="e.csv: empty file"):
        load_demonstrations(tmp_path / "e.csv")


def test_error_corrupt_file(tmp_path):
    """A damaged archive is refused, and the file it opened is closed (numpy's ``np.load`` of
    a path left it open: a ResourceWarning at the next garbage collection)."""
    (tmp_path / "c.npz").write_bytes(b"PK\x03\x04 this is not a zip archive")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(DataError, match="c.npz: not a valid NPZ demonstration file: corrupt"):
            load_demonstrations(tmp_path / "c.npz")
        gc.collect()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]
    (tmp_path / "c.csv").write_text("t,label,a_x,a_y,a_z\n0,0,1,2,abc\n")
    with pytest.raises(DataError, match="c.csv: line 2: unreadable or corrupt CSV row"):
        load_demonstrations(tmp_path / "c.csv", fps=10)


def test_error_garbage_npz_never_suggests_unpickling(tmp_path):
    rng = np.random.default_rng(3)
    (tmp_path / "g.npz").write_bytes(rng.integers(0, 256, 200, dtype=np.uint8).tobytes())
    np.save(tmp_path / "single.npy", np.zeros(3))
    (tmp_path / "single.npy").rename(tmp_path / "n.npz")  # an .npy array, not an archive
    _npz(tmp_path / "o.npz", metadata=np.array([{"subject": 1}], dtype=object))
    cases = [
        ("g.npz", "g.npz: not a valid NPZ demonstration file: not a zip archive"),
        ("n.npz", "n.npz: not a valid NPZ demonstration file: not a zip archive"),
        ("o.npz", "o.npz: not a valid NPZ demonstration file: field 'metadata' holds pickled"),
    ]
    for name, message in cases:
        with pytest.raises(DataError, match=message) as info:
            load_demonstrations(tmp_path / name)
        assert "allow_pickle" not in str(info.value) and "pickle.load" not in str(info.value)


def test_error_ragged_csv_row_names_its_line(tmp_path):
    p = tmp_path / "r.csv"
    # line 1 JSON header, 2 column header, 3 a frame, 4 blank, 5 a frame missing a cell
    p.write_text('# {"fps": 10}\nt,label,a_x,a_y,a_z\n0,0,1,2,3\n\n0.1,0,1,2\n0.2,0,1,2,3\n')
    with pytest.raises(DataError, match=r"r\.csv: line 5: 4 cells, but the header row \(line 2\)"):
        load_demonstrations(p)
    p.write_text("a_x,a_y,a_z\n1,2,3\n1,2,3,4\n")
    with pytest.raises(DataError, match=r"r\.csv: line 3: 4 cells, .* has 3 columns"):
        load_demonstrations(p, fps=10)


def test_error_inf_positions(tmp_path):
    pos = _demo().positions.copy()
    pos[7, 3, 1] = np.inf
    pos[9, 0, 0] = -np.inf
    p = _npz(tmp_path / "x.npz", positions=pos)
    with pytest.raises(
        DataError,
        match=r"x\.npz: field 'positions' has 2 Inf value\(s\), the first at frame 7, "
        r"joint 'waist'",
    ):
        load_demonstrations(p)
    clean = _demo().clean_positions.copy()
    clean[2, 9, 2] = np.inf
    p = _npz(tmp_path / "y.npz", clean_positions=clean)
    with pytest.raises(DataError, match=r"y\.npz: field 'clean_positions' has 1 Inf .*frame 2, "
                       r"joint 'right_hand'"):  # fmt: skip
        load_demonstrations(p)
    c = tmp_path / "z.csv"
    c.write_text("a_x,a_y,a_z\n1,2,3\n1,inf,3\n-inf,2,3\n")
    with pytest.raises(
        DataError,
        match=r"z\.csv: field 'positions' has 2 Inf .*frame 1, joint 'a'; mark a lost joint "
        r"with NaN \(an empty CSV cell\), never Inf",
    ):
        load_demonstrations(c, fps=10)
    with pytest.raises(DataError, match=r"x\.npz: .*joint 'waist'; mark a lost joint with NaN, "):
        load_demonstrations(tmp_path / "x.npz")  # no CSV cell in an NPZ file


def test_error_coordinates_beyond_the_limit(tmp_path):
    """Millimetres, or a corrupted sample, are refused before they train or forecast."""
    from iplanner_torch.types import MAX_POSITION_M

    pos = _demo().positions.copy()
    pos[4, 2, 0] = 1e30
    pos[5, 2, 0] = -2 * MAX_POSITION_M
    p = _npz(tmp_path / "x.npz", positions=pos)
    with pytest.raises(
        DataError, match=r"x\.npz: field 'positions' has 2 coordinate\(s\) beyond 100 m, the "
        r"first at frame 4, joint '.*': \[1\.0000.*e\+30, .*metres"
    ):  # fmt: skip
        load_demonstrations(p)
    ok = _demo().positions.copy()
    ok[4, 2, 0] = MAX_POSITION_M  # the limit itself is taken
    ok[6, 1, :] = np.nan  # and lost joints are not coordinates
    load_demonstrations(_npz(tmp_path / "ok.npz", positions=ok))
    c = tmp_path / "mm.csv"
    c.write_text("a_x,a_y,a_z\n1,2,3\n1200,-150,3\n")
    with pytest.raises(DataError, match=r"mm\.csv: field .positions. has 2 coordinate.*frame 1"):
        load_demonstrations(c, fps=10)


def test_joint_lost_in_every_frame_is_kept_and_reported(tmp_path):
    pos = _demo().positions.copy()
    pos[:, 0, 1] = np.nan  # head lost in every frame (one coordinate is enough)
    pos[:5, 9] = np.nan  # right hand lost only in some frames
    (d,) = load_demonstrations(_npz(tmp_path / "x.npz", positions=pos))
    assert lost_joints(d) == ("head",)
    assert lost_joints(_demo()) == ()


def test_error_nothing_observed(tmp_path):
    pos = np.full((12, len(JOINT_NAMES), 3), np.nan, np.float32)
    p = _npz(tmp_path / "x.npz", positions=pos, clean_positions=None)
    with pytest.raises(DataError, match=r"x\.npz: field 'positions' is NaN in every frame for "
                       r"every joint \['head', 'neck'"):  # fmt: skip
        load_demonstrations(p)
    pos = _demo().positions.copy()
    pos[:, 9] = np.nan  # right hand lost in every frame: fine, until it is the only joint
    p = _npz(tmp_path / "y.npz", positions=pos)
    assert len(load_demonstrations(p)) == 1
    with pytest.raises(DataError, match=r"y\.npz: .* every joint \['right_hand'\]"):
        load_demonstrations(p, joints=["right_hand"])


def test_error_joint_names_differ_between_files(tmp_path):
    save_demonstration(_demo(), tmp_path / "a.npz")
    save_demonstration(_demo(), tmp_path / "b.npz")
    other = _demo().select_joints(["right_hand", "head", "neck"])
    save_demonstration(other, tmp_path / "c.csv")
    save_demonstration(_demo(), tmp_path / "d.npz")
    with pytest.raises(DataError) as info:
        load_demonstrations(tmp_path)
    msg = str(info.value)
    assert msg.startswith(f"{tmp_path / 'c.csv'}: field 'joint_names' ['right_hand', 'head', ")
    assert str(list(JOINT_NAMES)) in msg and f"of {tmp_path / 'a.npz'}" in msg
    demos = load_demonstrations(tmp_path, joints=["head", "right_hand"])
    assert [d.joint_names for d in demos] == [("head", "right_hand")] * 4


def test_demonstration_files_match_the_loader(tmp_path):
    for name in ("b.npz", "a.csv", "sub/c.npz"):
        save_demonstration(_demo(), tmp_path / name)
    (tmp_path / "README.md").write_text("hello")
    files = demonstration_files(tmp_path)
    assert files == [tmp_path / "a.csv", tmp_path / "b.npz", tmp_path / "sub" / "c.npz"]
    names = [f.relative_to(tmp_path).with_suffix("").as_posix() for f in files]
    assert [d.name for d in load_demonstrations(tmp_path)] == names
    assert demonstration_names(tmp_path, files) == names
    assert demonstration_files(tmp_path / "b.npz") == [tmp_path / "b.npz"]
    (tmp_path / "none").mkdir()
    assert demonstration_files(tmp_path / "none") == []
    with pytest.raises(DataError, match="no such file or folder"):
        demonstration_files(tmp_path / "missing")


def test_lego_loader_errors_give_a_hint(tmp_path):
    with pytest.raises(DataError, match=r"missing: no such file or folder .*set data\.path="):
        load_lego_assembly(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match=r"no trial \.txt files found .*data\.path="):
        load_lego_assembly(tmp_path / "empty")
    row = " ".join(["0.1"] * 17 + ["inf"])
    (tmp_path / "trial1.txt").write_text(f"{' '.join(['0.1'] * 18)}\n{row}\n")
    with pytest.raises(
        DataError,
        match=r"trial1\.txt: line 2, number 18 \(right_shoulder z\): 'inf' is infinite: mark a "
        r"lost joint with NaN \('nan' in the text\), never Inf \(1 such value",
    ):
        load_lego_assembly(tmp_path / "trial1.txt")
    blind = " ".join(["nan"] * 18)
    (tmp_path / "trial2.txt").write_text(f"{blind}\n{blind}\n")
    with pytest.raises(DataError, match=r"trial2\.txt: field 'positions' is NaN in every frame "
                       r"for every joint \['left_shoulder'"):  # fmt: skip
        load_lego_assembly(tmp_path / "trial2.txt")
    lost = " ".join(["0.1"] * 15 + ["nan"] * 3)  # the right shoulder alone is never seen
    (tmp_path / "trial3.txt").write_text(f"{lost}\n{lost}\n")
    assert len(load_lego_assembly(tmp_path / "trial3.txt")) == 1


def test_error_missing_key(tmp_path):
    p = _npz(tmp_path / "x.npz", labels=None)
    with pytest.raises(DataError, match="x.npz: missing key 'labels'"):
        load_demonstrations(p)


def test_error_fps_contradiction_and_missing_folder(tmp_path):
    p = _npz(tmp_path / "x.npz")
    with pytest.raises(DataError, match="field 'fps' is 15.0, but fps=30"):
        load_demonstrations(p, fps=30.0)
    with pytest.raises(DataError, match="no such file or folder"):
        load_demonstrations(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="no .npz or .csv"):
        load_demonstrations(tmp_path / "empty")


def test_single_file_loader_rejects_unknown_suffix(tmp_path):
    (tmp_path / "x.txt").write_text("1")
    with pytest.raises(DataError, match="unknown suffix '.txt'"):
        load_demonstration(tmp_path / "x.txt")


@pytest.mark.skipif(not LEGO.is_dir(), reason="LEGO assembly recording not present")
def test_lego_assembly_loader():
    demos = load_lego_assembly(LEGO, fps=30.0)
    assert len(demos) == 20
    assert sum(d.num_frames for d in demos) == 20494
    d = demos[0]
    assert d.name == "Task1/Human1/trial1" and d.fps == 30.0
    assert d.joint_names == (
        "left_shoulder", "left_elbow", "left_hand", "right_shoulder", "right_elbow", "right_hand"
    )  # fmt: skip
    raw = np.loadtxt(LEGO / "Task1/Human1/trial1.txt")
    np.testing.assert_allclose(d.positions[0, 2], raw[0, 0:3], rtol=1e-6)  # left wrist
    np.testing.assert_allclose(d.positions[0, 3], raw[0, 15:18], rtol=1e-6)  # right shoulder
    assert d.action_names == ("unlabelled",) and (d.labels == 0).all()
    nan_demo = next(x for x in demos if x.name == "Task3/Human2/trial2")
    assert np.isnan(nan_demo.positions).sum() == 12
    upper = np.linalg.norm(d.positions[:, 1] - d.positions[:, 0], axis=1)
    assert upper.std() < 1e-4  # fixed-length arm model upstream


def _csv(path: Path, header: str, columns: str = "a_x,a_y,a_z", row: str = "1,2,3") -> Path:
    path.write_text(f"{header}\n{columns}\n{row}\n{row}\n")
    return path


@pytest.mark.parametrize(
    ("columns", "message"),
    [
        (  # clean columns for joint a only
            "a_x,a_y,a_z,b_x,b_y,b_z,clean_a_x,clean_a_y,clean_a_z",
            r"x\.csv: missing column\(s\) \['clean_b_x', 'clean_b_y', 'clean_b_z'\] of field "
            r"'clean_positions': the header row \(line 2\)",
        ),
        (  # clean columns for joint b only (were ignored without a word)
            "a_x,a_y,a_z,b_x,b_y,b_z,clean_b_x,clean_b_y,clean_b_z",
            r"x\.csv: missing column\(s\) \['clean_a_x', 'clean_a_y', 'clean_a_z'\]",
        ),
        (  # clean columns of a joint that has no position columns (were ignored)
            "a_x,a_y,a_z,clean_a_x,clean_a_y,clean_a_z,clean_c_x",
            r"x\.csv: column\(s\) \['clean_c_x'\] of field 'clean_positions' \(header row, "
            r"line 2\) match no joint of the position columns \['a'\]",
        ),
        ("a_x,a_y,a_z,b_y,b_z", r"x\.csv: missing column 'b_x'"),  # b was dropped silently
        ("t,a_x,a_y,a_z,t", r"x\.csv: column 't' appears twice in the header row \(line 2\)"),
    ],
)
def test_error_csv_columns(tmp_path, columns, message):
    row = ",".join(["1"] * len(columns.split(",")))
    p = _csv(tmp_path / "x.csv", '# {"fps": 15}', columns, row)
    with pytest.raises(DataError, match=message):
        load_demonstrations(p)


def test_error_csv_header_comment_must_be_an_object(tmp_path):
    p = _csv(tmp_path / "x.csv", "# [1,2]")
    with pytest.raises(
        DataError,
        match=r"x\.csv: field 'header' .* the header comment must be a JSON object, got array",
    ):
        load_demonstrations(p)


@pytest.mark.parametrize(
    ("header", "message"),
    [
        ('{"fps": "fast"}', "field 'fps' must be a real number, got 'fast'"),
        ('{"fps": "15"}', "field 'fps' must be a real number, got '15'"),
        ('{"fps": true}', "field 'fps' must be a real number, got True"),
        ('{"fps": [15]}', r"field 'fps' must be a real number, got \[15\]"),
        ('{"fps": 15, "metadata": [1,2]}', r"field 'metadata' must be a JSON object, got array"),
        ('{"fps": 15, "metadata": "ab"}', "field 'metadata' must be a JSON object, got string"),
        ('{"fps": 15, "action_names": "ab"}', "field 'action_names' .* JSON array of strings"),
        ('{"fps": 15, "action_names": 5}', "field 'action_names' .* JSON array of strings"),
        ('{"fps": 15, "action_names": ["a", 1]}', "field 'action_names' .* array of strings"),
    ],
)
def test_error_csv_header_field_types(tmp_path, header, message):
    p = _csv(tmp_path / "x.csv", f"# {header}")
    with pytest.raises(DataError, match=rf"x\.csv: {message}"):
        load_demonstrations(p)


def test_csv_header_null_counts_as_absent(tmp_path):
    p = _csv(tmp_path / "x.csv", '# {"fps": null, "action_names": null, "metadata": null}')
    (d,) = load_demonstrations(p, fps=20.0)
    assert d.fps == 20.0 and d.action_names == ("unlabelled",) and d.metadata == {}
    with pytest.raises(DataError, match=r"x\.csv: field 'fps' missing"):
        load_demonstrations(p)


@pytest.mark.parametrize(
    ("fps", "message"),
    [
        (np.array([15.0, 15.0]), r"must be a scalar, got an array of shape \(2,\)"),
        (np.array("abc"), "must be a real number, got 'abc'"),
        (np.array(True), "must be a real number, got True"),
        (np.array(15 + 1j), r"must be a real number, got \(15\+1j\)"),
    ],
)
def test_error_npz_fps_not_a_number(tmp_path, fps, message):
    p = _npz(tmp_path / "x.npz", fps=fps)
    with pytest.raises(DataError, match=rf"x\.npz: field 'fps' {message}"):
        load_demonstrations(p)


@pytest.mark.parametrize("value", [0, -5, "NaN", "Infinity", "-Infinity", "1e400"])
@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_error_fps_must_be_finite_and_positive(tmp_path, suffix, value):
    if suffix == ".npz":
        p = _npz(tmp_path / "x.npz", fps=np.array(float(value)))
    else:
        p = _csv(tmp_path / "x.csv", f'# {{"fps": {value}}}')
    with pytest.raises(DataError, match=rf"x\{suffix}: field 'fps' must be finite and > 0, got"):
        load_demonstrations(p)


def test_error_loader_fps_must_be_finite(tmp_path):
    p = _csv(tmp_path / "x.csv", "")
    with pytest.raises(DataError, match=r"x\.csv: field 'fps' must be finite and > 0, got inf"):
        load_demonstrations(p, fps=float("inf"))
    (tmp_path / "trial1.txt").write_text(" ".join(["0.1"] * 18) + "\n")
    with pytest.raises(DataError, match="fps must be finite and > 0, got inf"):
        load_lego_assembly(tmp_path / "trial1.txt", fps=float("inf"))


@pytest.mark.parametrize(
    ("metadata", "message"),
    [
        (np.array("[1,2]"), r"field 'metadata' must be a JSON object, got array \[1, 2\]"),
        (np.array("5"), "field 'metadata' must be a JSON object, got number 5"),
        (np.array(5), r"field 'metadata' must be a JSON object stored as one string, got shape"),
        (np.array(["{}", "{}"]), r"field 'metadata' must be .* one string, got shape \(2,\)"),
    ],
)
def test_error_npz_metadata_must_be_an_object(tmp_path, metadata, message):
    p = _npz(tmp_path / "x.npz", metadata=metadata)
    with pytest.raises(DataError, match=rf"x\.npz: {message}"):
        load_demonstrations(p)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"joint_names": np.arange(10)}, r"field 'joint_names' must be a 1-D array of strings"),
        ({"joint_names": np.array([JOINT_NAMES])}, r"field 'joint_names' .* got shape \(1, 10\)"),
        ({"action_names": np.array([0, 1, 2])}, r"field 'action_names' must be a 1-D array of"),
        ({"timestamps": np.array(["a"] * 12)}, r"field 'timestamps' must be real numbers"),
        ({"timestamps": np.arange(12) + 0j}, r"field 'timestamps' .* got dtype complex128"),
        ({"clean_positions": np.full((12, 10, 3), "a")}, r"field 'clean_positions' must be float"),
    ],
)
def test_error_npz_field_types(tmp_path, override, message):
    p = _npz(tmp_path / "x.npz", **override)
    with pytest.raises(DataError, match=rf"x\.npz: {message}"):
        load_demonstrations(p)


@pytest.mark.parametrize(
    ("header", "label", "message"),
    [
        (
            '{"fps": 15, "action_names": ["a", "b"]}',
            "1e30",
            r"line 4: field 'labels' out of range: 1e30, expected -1 \(unlabelled\) or 0\.\.1",
        ),
        ('{"fps": 15}', "-5", r"line 4: field 'labels' out of range: -5, expected -1"),
        ('{"fps": 15}', "inf", "line 4: field 'labels' must be integers in every row, got 'inf'"),
        ('{"fps": 15}', "", "line 4: field 'labels' must be integers in every row, got ''"),
        # without action_names a label names action_0 .. action_<label>: a bound, not 20001
        ('{"fps": 15}', "20000", "line 4: field 'labels' is 20000, but without 'action_names'"),
    ],
)
def test_error_csv_label_shows_the_value_and_line(tmp_path, header, label, message):
    p = tmp_path / "x.csv"
    p.write_text(f"# {header}\nlabel,a_x,a_y,a_z\n0,1,2,3\n{label},1,2,3\n")
    with pytest.raises(DataError, match=rf"x\.csv: {message}") as info:
        load_demonstrations(p)
    assert "9223372036854775808" not in str(info.value)


def test_error_npz_damaged_compressed_data(tmp_path):
    d = _demo()
    p = tmp_path / "x.npz"
    np.savez_compressed(p, positions=d.positions, labels=d.labels, fps=np.array(15.0))
    raw = bytearray(p.read_bytes())
    raw[60:90] = bytes(b ^ 0xFF for b in raw[60:90])  # inside the first member's deflate data
    p.write_bytes(bytes(raw))
    with pytest.raises(DataError, match=r"x\.npz: not a valid NPZ demonstration file: corrupt"):
        load_demonstrations(p)


def test_error_pickled_npz_field_is_not_reported_as_corrupt(tmp_path):
    p = _npz(tmp_path / "o.npz", metadata=np.array([{"subject": 1}], dtype=object))
    with pytest.raises(DataError) as info:
        load_demonstrations(p)
    assert str(info.value).startswith(
        f"{p}: not a valid NPZ demonstration file: field 'metadata' holds pickled"
    )


def test_error_unreadable_npz(tmp_path, monkeypatch):
    p = _npz(tmp_path / "x.npz")
    real_open = open

    def no_access(file, *args, **kwargs):
        if Path(file) == p:
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr("builtins.open", no_access)
    with pytest.raises(DataError, match=r"x\.npz: unreadable NPZ file \(.*Permission denied"):
        load_demonstrations(p)


_CSV_JOINTS = ("torso", "left_hand", "right_hand")
_CSV_HEADER = '# {"fps": 15.0, "action_names": ["idle", "reach"]}'


def _user_csv(path: Path, first: tuple[str, ...], header: str = _CSV_HEADER) -> Path:
    """A 10-frame CSV at 15 Hz whose columns are ``first`` (``t`` the time, any other 1), then
    3 joints' positions."""
    cols = [*first] + [f"{j}_{a}" for j in _CSV_JOINTS for a in "xyz"]
    rows = [
        ",".join([f"{i / 15:.6f}" if c == "t" else "1" for c in first] + ["0.1"] * 9)
        for i in range(10)
    ]
    path.write_text("\n".join([header, ",".join(cols), *rows]) + "\n")
    return path


@pytest.mark.parametrize(
    ("first", "message"),
    [
        (("t", "lable"), r"unknown column\(s\) 'lable' \(did you mean 'label'\?\)"),  # was all 0
        (("time", "label"), r"unknown column\(s\) 'time' \(did you mean 't'\?\)"),  # was dropped
        (("Label",), r"unknown column\(s\) 'Label' \(did you mean 'label'\?\)"),
        (("t", "label", "subject"), r"unknown column\(s\) 'subject' in the header row"),
        (("t", "label", ""), r"unknown column\(s\) '' \(an unnamed column: a trailing comma\?\)"),
        (("_x",), r"unknown column\(s\) '_x' in"),  # a joint needs a name
    ],
)
def test_error_csv_unknown_column_is_named(tmp_path, first, message):
    p = _user_csv(tmp_path / "my.csv", first)
    with pytest.raises(DataError, match=rf"my\.csv: {message}") as info:
        load_demonstrations(p)
    assert "line 2); the accepted columns are t (seconds), label (int action index)" in str(
        info.value
    )
    assert "clean_<joint>_x" in str(info.value)


def test_csv_without_label_column_but_named_actions_is_unlabelled(tmp_path):
    p = _user_csv(tmp_path / "my.csv", ("t",))
    with pytest.warns(DataWarning, match=r"my\.csv: no 'label' column, but the header comment "):
        (d,) = load_demonstrations(p)
    assert d.action_names == ("idle", "reach") and (d.labels == -1).all()  # never action 0
    q = _user_csv(tmp_path / "q.csv", ("t",), header='# {"fps": 15.0}')
    (e,) = load_demonstrations(q)  # no names either: the single action "unlabelled", as before
    assert e.action_names == ("unlabelled",) and (e.labels == 0).all()


@pytest.mark.parametrize("fps", [[15.0], (15.0,), True, np.bool_(True), "15", np.array([15.0])])
def test_error_loader_fps_argument_not_a_number(tmp_path, fps):
    p = _csv(tmp_path / "x.csv", "")  # states no fps: the argument would be used
    with pytest.raises(
        DataError,
        match=r"x\.csv: field 'fps' \(the loader's fps= argument\) must be one real number",
    ):
        load_demonstrations(p, fps=fps)
    with pytest.raises(DataError, match=r"the loader's fps= argument\) must be one real number"):
        load_demonstration(p, fps=fps)
    (tmp_path / "trial1.txt").write_text(" ".join(["0.1"] * 18) + "\n")
    with pytest.raises(DataError, match=r"fps= argument\) must be one real number"):
        load_lego_assembly(tmp_path / "trial1.txt", fps=fps)


def test_loader_fps_argument_numbers_are_accepted(tmp_path):
    p = _csv(tmp_path / "x.csv", "")
    for fps in (20, 20.0, np.float32(20.0), np.int64(20)):
        (d,) = load_demonstrations(p, fps=fps)
        assert d.fps == 20.0 and type(d.fps) is float


@pytest.mark.parametrize(
    ("joints", "message"),
    [
        (
            "right_hand",
            r"must be a list of joint names, got the single string 'right_hand'; pass a list: "
            r"joints=\['right_hand'\]",
        ),
        (["right_hand", "right_hand"], r"names joint\(s\) \['right_hand'\] more than once"),
        ([], r"must be a non-empty list of unique joint names, got an empty one"),
        ((), r"must be a non-empty list of unique joint names, got an empty one"),
        ([1], r"must hold joint names \(strings\), got \[1\]"),
        (5, r"must be a non-empty list of unique joint names, got 5"),
    ],
)
def test_error_loader_joints_argument(tmp_path, joints, message):
    p = _user_csv(tmp_path / "my.csv", ("t", "label"))
    with pytest.raises(ConfigError, match=rf"^joints= {message}"):
        load_demonstrations(p, joints=joints)
    with pytest.raises(ConfigError, match=rf"^joints= {message}"):
        load_demonstration(p, joints=joints)
    with pytest.raises(ConfigError, match=rf"^joints= {message}"):  # checked before the files
        load_demonstrations(tmp_path / "absent", joints=joints)


def test_error_loader_joints_not_in_the_file(tmp_path):
    """Joints asked for that the file does not have are named with the file's joints."""
    p = _user_csv(tmp_path / "my.csv", ("t", "label"))
    with pytest.raises(DataError, match=r"my\.csv: no joint\(s\) \['nope'\] in the file, which "
                       r"was asked to give them \(joints=\); its joints \(field 'joint_names'\): "
                       rf"{re.escape(str(list(_CSV_JOINTS)))}$"):  # fmt: skip
        load_demonstration(p, joints=[_CSV_JOINTS[0], "nope"])


def test_csv_numbers_read_back_bit_identical(tmp_path):
    """CSV cells are the shortest text of each float32 value, not 6 significant digits."""
    g = np.random.default_rng(5)
    bits = g.integers(0, 2**32, size=3000, dtype=np.uint64).astype(np.uint32)
    values = bits.view(np.float32)
    values = values[np.isfinite(values) & (np.abs(values) <= 100.0)][:600]
    pos = np.concatenate([[1.2345678, 1e-8, -0.0, 99.999994], values]).astype(np.float32)
    pos = pos[: len(pos) // 3 * 3].reshape(-1, 1, 3)  # (T, 1, 3)
    d = Demonstration(
        positions=pos, labels=np.zeros(len(pos), int), fps=10.0, joint_names=("a",),
        action_names=("idle",),
    )  # fmt: skip
    path = save_demonstration(d, tmp_path / "x.csv")
    assert path.read_text().splitlines()[2].split(",")[2:] == ["1.2345678", "1e-08", "-0.0"]
    e = load_demonstration(path)
    np.testing.assert_array_equal(e.positions.view(np.uint32), pos.view(np.uint32))


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_metadata_nan_and_infinities_are_strict_json(tmp_path, suffix):
    d = _demo()
    d.metadata = {"noise": float("nan"), "far": [np.inf, -np.inf], "a": np.float32("nan")}
    path = save_demonstration(d, tmp_path / f"x{suffix}")
    if suffix == ".csv":
        text = path.read_text().splitlines()[0][1:]
    else:
        with np.load(path) as z:
            text = str(z["metadata"])

    def refuse(token: str) -> None:
        raise ValueError(f"not strict JSON: {token}")

    json.loads(text, parse_constant=refuse)
    meta = load_demonstration(path).metadata
    assert math.isnan(meta["noise"]) and meta["far"] == [math.inf, -math.inf]
    assert math.isnan(meta["a"])


def test_metadata_with_bare_nan_tokens_of_earlier_files_still_reads(tmp_path):
    p = tmp_path / "old.csv"
    p.write_text('# {"fps": 10.0, "metadata": {"noise": NaN, "far": Infinity}}\nt,a_x,a_y,a_z\n'
                 "0,1,2,3\n")  # fmt: skip
    meta = load_demonstration(p).metadata
    assert math.isnan(meta["noise"]) and meta["far"] == math.inf
    p = _npz(tmp_path / "old.npz", metadata=np.array('{"noise": NaN, "far": -Infinity}'))
    meta = load_demonstration(p).metadata
    assert math.isnan(meta["noise"]) and meta["far"] == -math.inf


@pytest.mark.parametrize(
    ("suffix", "joints", "actions", "message"),
    [
        (".csv", ("a,b", "c"), ("idle",), r"joint_names entry 'a,b': it holds a comma"),
        (".csv", ("clean_hand", "c"), ("idle",),
         r"joint_names entry 'clean_hand': it is 'clean' or starts with 'clean_'"),
        (".csv", ("clean", "c"), ("idle",), r"joint_names entry 'clean': it is 'clean' or"),
        (".csv", ("left hand ", "c"), ("idle",),
         r"joint_names entry 'left hand ': it starts or ends with white space"),
        (".csv", ("", "c"), ("idle",), r"joint_names entry '': it is empty"),
        (".csv", ("a\nb", "c"), ("idle",), r"joint_names entry 'a\\nb': it holds a line break"),
        (".csv", ("a", 3), ("idle",), r"joint_names entry 3: it is not a string"),
        (".npz", ("a", "b\x00"), ("idle",),
         r"joint_names entry 'b\\x00': it ends in a NUL character"),
        (".npz", ("a", "b"), ("idle", None), r"action_names entry None: it is not a string"),
        (".npz", ("a", "a"), ("idle",), r"joint_names \['a'\] named more than once"),
        (".csv", ("a", "b"), (), r"empty action_names"),
    ],
)  # fmt: skip
def test_save_refuses_names_its_loader_cannot_read_back(
    tmp_path, suffix, joints, actions, message
):
    d = Demonstration(
        positions=np.zeros((3, 2, 3)), labels=np.zeros(3, int), fps=10.0, joint_names=joints,
        action_names=actions,
    )  # fmt: skip
    out = tmp_path / "new" / f"x{suffix}"
    with pytest.raises(DataError, match=rf"x\{suffix}: cannot save {message}"):
        save_demonstration(d, out)
    assert not out.parent.exists()  # nothing written


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_save_refuses_metadata_that_is_not_json(tmp_path, suffix):
    cycle: list = []
    cycle.append(cycle)
    deep: dict = {}
    for _ in range(100_000):
        deep = {"x": deep}
    for metadata, why in (
        ({"s": {1, 2}}, "Object of type set"),
        ({"o": object()}, "Object of type object"),
        ({"c": cycle}, "nested too deep|Circular reference"),
        (deep, "nested too deep"),
    ):
        d = _demo()
        d.metadata = metadata
        with pytest.raises(
            DataError, match=rf"x\{suffix}: metadata is not JSON-serialisable \(({why})"
        ):
            save_demonstration(d, tmp_path / "new" / f"x{suffix}")
    assert not (tmp_path / "new").exists()


def test_error_json_nested_too_deep(tmp_path):
    deep = "[" * 100_000 + "]" * 100_000
    p = tmp_path / "deep.csv"
    p.write_text(f"# {deep}\nt,a_x,a_y,a_z\n0,1,2,3\n")
    with pytest.raises(DataError, match=r"deep\.csv: field 'header' .* is invalid \(nested too"):
        load_demonstration(p, fps=10.0)
    p = _npz(tmp_path / "deep.npz", metadata=np.array(deep))
    with pytest.raises(DataError, match=r"deep\.npz: field 'metadata' is not valid JSON \(nested"):
        load_demonstration(p)


def test_error_folder_or_no_joints_is_named(tmp_path):
    (tmp_path / "demos").mkdir()
    with pytest.raises(DataError, match=r"demos: is a folder; load_demonstration reads one"):
        load_demonstration(tmp_path / "demos")
    p = _npz(
        tmp_path / "x.npz",
        positions=np.zeros((5, 0, 3), np.float32),
        labels=np.zeros(5, int),
        joint_names=np.array([], dtype=str),
    )
    with pytest.raises(DataError, match=r"x\.npz: field 'positions' has no joints \(K=0\)"):
        load_demonstration(p)


@pytest.mark.parametrize("path", [None, 3, b"demo.npz", ["demo.npz"]])
def test_a_path_argument_that_is_not_a_path_is_a_data_error(path) -> None:
    """None raised a raw TypeError from pathlib."""
    with pytest.raises(DataError, match="expected path a file path .* of a demonstration"):
        load_demonstration(path)
    with pytest.raises(DataError, match="expected path a file or folder path .* demonstrations"):
        load_demonstrations(path)


@pytest.mark.parametrize("where", ["mid-number", "after-a-comma"])
def test_a_csv_cut_short_drops_its_last_row_with_a_warning(tmp_path, where):
    """Our writer ends every file with a line break; a last row without one may be cut (mid
    number: a wrong value; just after a comma: an empty cell read as NaN) and is dropped."""
    d = _demo()
    path = save_demonstration(d, tmp_path / "a.csv")
    text = path.read_text()
    assert text.endswith("\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_demonstration(path).num_frames == 12  # a whole file: no warning
    end = len(text) - 4 if where == "mid-number" else text.rstrip("\n").rfind(",") + 1
    path.write_text(text[:end])
    with pytest.warns(DataWarning, match=r"a\.csv: last line has no line terminator: the file"):
        e = load_demonstration(path)
    assert e.num_frames == 11
    np.testing.assert_array_equal(e.positions, d.positions[:11])


@pytest.mark.skipif(not LEGO.is_dir(), reason="LEGO assembly recording not present")
def test_a_lego_trial_cut_short_drops_its_last_row_with_a_warning(tmp_path):
    src = sorted(LEGO.rglob("*.txt"))[0]
    text = src.read_text()
    assert text.endswith("\n")  # every trial of the recording ends with a line break
    (whole,) = load_lego_assembly(src, fps=30.0)
    cut = tmp_path / "trial1.txt"
    cut.write_text(text[:-9])  # the last 8 characters and the line break: 0.8410000205 -> 0.841
    with pytest.warns(DataWarning, match=r"trial1\.txt: last line has no line terminator"):
        (e,) = load_lego_assembly(cut, fps=30.0)
    assert e.num_frames == whole.num_frames - 1
    np.testing.assert_array_equal(e.positions, whole.positions[:-1])


def _lego_row(value: str = "0.1", at: int = 0, count: int = 18) -> str:
    """A LEGO trial line of ``count`` entries, ``value`` at ``at`` (0-based), 0.1 elsewhere."""
    return " ".join(value if i == at else "0.1" for i in range(count))


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_lego_trial_errors_name_the_file_line(tmp_path, newline):
    """Errors counted numpy's data rows from 0 (blank and '#' lines left out): text on file
    line 7 was 'row 6', a short line 5 'row 5' after two comment lines."""
    good = _lego_row()
    head = ["# recorded with a Kinect", "# camera frame", good, "", good, "\t" + good]
    p = tmp_path / "trial1.txt"
    p.write_text(newline.join([*head, _lego_row("abc", at=5), good]) + newline)
    with pytest.raises(DataError, match=r"trial1\.txt: line 7, number 6: 'abc' is not a number$"):
        load_lego_assembly(p)
    p.write_text(newline.join([*head, _lego_row(count=17), good]) + newline)
    with pytest.raises(DataError, match=r"trial1\.txt: line 7: 17 numbers, expected 18 \(x, y, z"):
        load_lego_assembly(p)
    p.write_text(newline.join([good, "0.1 " + _lego_row(count=18)]) + newline)
    with pytest.raises(DataError, match=r"trial1\.txt: line 2: 19 numbers, expected 18"):
        load_lego_assembly(p)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        (
            ",".join(["0.1"] * 18),
            r"line 2, number 1: '0\.1,0\.1,.*\.\.\. is not a number \(numbers",
        ),
        (_lego_row("0.1;", at=3), r"line 2, number 4: '0\.1;' is not a number \(numbers are sep"),
        (_lego_row("1_0", at=2), r"line 2, number 3: '1_0' is not a number$"),  # float() reads it
        (_lego_row("\u0661", at=0), r"line 2, number 1: '\u0661' is not a number$"),
        ("0.1", r"line 2: 1 number, expected 18"),
        (_lego_row("-inf", at=4), r"line 2, number 5 \(right_hand y\): '-inf' is infinite: mark"),
        (_lego_row("1e400", at=0), r"line 2, number 1 \(left_hand x\): '1e400' overflows: it is"),
        (_lego_row("512.3", at=17), r"line 2, number 18 \(right_shoulder z\): '512\.3' is beyond"),
    ],
)
def test_lego_trial_refuses_what_it_refused(tmp_path, line, message):
    """Commas, semicolons, text, wrong counts, Inf and millimetres stay refused, each with the
    file line and the entry's place in it."""
    p = tmp_path / "trial1.txt"
    p.write_text(f"{_lego_row()}\n{line}\n")
    with pytest.raises(DataError, match=rf"trial1\.txt: {message}"):
        load_lego_assembly(p)


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_lego_trial_reads_what_numpy_read(tmp_path, newline):
    """Tabs and spaces, blank lines, '#' comments (whole lines and line ends), NaN and any line
    ending: the table numpy.loadtxt (the reference) reads from the same text."""
    rng = np.random.default_rng(0)
    x = rng.normal(scale=0.5, size=(6, 18))
    x[2, 3:6] = np.nan
    rows = ["\t".join(repr(float(v)) for v in r) for r in x]
    lines = ["# trial 1", rows[0], "", rows[1] + "  # note", *rows[2:4], "   ", *rows[4:]]
    p = tmp_path / "trial1.txt"
    p.write_text(newline.join(lines) + newline)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (d,) = load_lego_assembly(p)
    ref = np.loadtxt(p, ndmin=2).reshape(-1, 6, 3)  # (T, 6, 3) in LEGO_JOINTS order
    order = [4, 2, 0, 5, 3, 1]  # LEGO_JOINTS (left hand ...) -> left shoulder, left elbow ...
    np.testing.assert_array_equal(d.positions, ref[:, order].astype(np.float32))
    assert d.num_frames == 6 and np.isnan(d.positions).sum() == 3


def test_a_lego_trial_with_a_byte_order_mark_reads_as_without(tmp_path):
    """A UTF-8 byte-order mark before the first number (a file saved by Notepad or Excel) is
    dropped, as the CSV reader drops it: it was refused as ``'\\ufeff0.1' is not a number``."""
    rows = [_lego_row("0.25", at=i) for i in range(3)]
    plain, marked = tmp_path / "a" / "trial1.txt", tmp_path / "b" / "trial1.txt"
    for p, head in ((plain, b""), (marked, b"\xef\xbb\xbf")):
        p.parent.mkdir()
        p.write_bytes(head + ("\n".join(rows) + "\n").encode())
    (d,) = load_lego_assembly(marked)
    (ref,) = load_lego_assembly(plain)
    np.testing.assert_array_equal(d.positions, ref.positions)
    assert d.num_frames == 3


def test_a_binary_lego_trial_is_named_not_echoed(tmp_path):
    """Random bytes saved as a trial gave a 'no line terminator' warning and then echoed the
    bytes as a number that is not one; a comment in another encoding still reads."""
    import warnings

    p = tmp_path / "trial1.txt"
    p.write_bytes(b"0.1 \x00\xff\xfe junk" * 20)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning before the error
        with pytest.raises(DataError, match=r"trial1\.txt: not a text file \(a NUL byte at "
                           r"byte 4\); a LEGO trial holds lines of 18 numbers$"):  # fmt: skip
            load_lego_assembly(p)
    p.write_bytes("# Gr\u00f6\u00dfe in cm\n".encode("latin-1") + (_lego_row() + "\n").encode())
    (d,) = load_lego_assembly(p)
    assert d.num_frames == 1


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n"])
def test_an_empty_lego_trial_names_itself_once(tmp_path, text):
    """It read '.../b_bad.txt: unreadable LEGO trial (.../b_bad.txt: empty file)'."""
    p = tmp_path / "b_bad.txt"
    p.write_text(text)
    with pytest.raises(DataError, match=r"b_bad\.txt: empty file \(no rows of numbers\)") as info:
        load_lego_assembly(p)
    assert str(info.value).count("b_bad.txt") == 1 and "unreadable" not in str(info.value)


def test_a_lego_trial_cut_after_a_comment_loses_no_row(tmp_path):
    p = tmp_path / "trial1.txt"
    p.write_text(f"{_lego_row()}\n{_lego_row()}\n# end")  # a comment is no row to distrust
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (d,) = load_lego_assembly(p)
    assert d.num_frames == 2
    p.write_text(f"{_lego_row()}\n{_lego_row()}")
    with pytest.warns(DataWarning, match=r"trial1\.txt: last line has no line terminator"):
        (d,) = load_lego_assembly(p)
    assert d.num_frames == 1


@pytest.mark.skipif(not LEGO.is_dir(), reason="LEGO assembly recording not present")
def test_lego_recording_reads_as_numpy_reads_it():
    """The line parser gives numpy.loadtxt's numbers, bit for bit, on every trial."""
    demos = load_lego_assembly(LEGO, fps=30.0)
    for f, d in zip(sorted(LEGO.rglob("*.txt")), demos, strict=True):
        raw = np.loadtxt(f, ndmin=2).reshape(-1, 6, 3)  # (T, 6, 3)
        np.testing.assert_array_equal(d.positions, raw[:, [4, 2, 0, 5, 3, 1]].astype(np.float32))


def test_csv_overflowing_cell_says_it_overflows(tmp_path):
    """'1e400' read as Inf and was told to use an empty cell, as if it were a lost joint."""
    c = tmp_path / "z.csv"
    c.write_text("t,a_x,a_y,a_z\n0,1,2,3\n0.1,1,1e400,3\n")
    with pytest.raises(
        DataError,
        match=r"z\.csv: line 3, column 'a_y': '1e400' overflows: it is beyond the largest float",
    ):
        load_demonstrations(c, fps=10)
    c.write_text("t,a_x,a_y,a_z\n0,1,2,3\n0.1,1,2,1e39\n")  # beyond float32: was an Inf
    with pytest.raises(DataError, match=r"z\.csv: field 'positions' has 1 coordinate\(s\) beyond"):
        load_demonstrations(c, fps=10)


def test_demonstrations_in_sub_folders_are_named_by_their_path(tmp_path):
    """Task1/Human1/trial2.csv and Task5/Human1/trial2.csv were both 'trial2'."""
    for name in ("Task1/Human1/trial2.csv", "Task5/Human1/trial2.npz", "flat.csv"):
        save_demonstration(_demo(), tmp_path / name)
    names = [d.name for d in load_demonstrations(tmp_path)]
    assert names == ["Task1/Human1/trial2", "Task5/Human1/trial2", "flat"]
    assert [d.name for d in load_demonstrations(tmp_path / "Task1")] == ["Human1/trial2"]
    assert load_demonstrations(tmp_path / "Task1/Human1/trial2.csv")[0].name == "trial2"
    assert load_demonstration(tmp_path / "Task1/Human1/trial2.csv").name == "trial2"
    lego = tmp_path / "lego" / "Task1" / "Human1"
    lego.mkdir(parents=True)
    (lego / "trial2.txt").write_text(_lego_row() + "\n")
    assert load_lego_assembly(tmp_path / "lego")[0].name == "Task1/Human1/trial2"  # the same


def test_two_files_of_one_name_are_refused(tmp_path):
    save_demonstration(_demo(), tmp_path / "sub" / "a.csv")
    save_demonstration(_demo(), tmp_path / "sub" / "a.npz")
    with pytest.raises(
        DataError, match=r"sub[/\\]a\.csv and .*sub[/\\]a\.npz would both be demonstration 'sub/a'"
    ):
        load_demonstrations(tmp_path)


def test_csv_hash_line_after_the_header_row_is_refused(tmp_path):
    """A '# pause' note among the frames was joined into the JSON header ('Extra data')."""
    p = tmp_path / "x.csv"
    p.write_text('# {"fps": 10}\nt,a_x,a_y,a_z\n0,1,2,3\n# pause\n0.1,1,2,3\n')
    with pytest.raises(
        DataError,
        match=r"x\.csv: line 4: a '#' line after the header row \(line 2\); '#' lines are read "
        "only at the top",
    ):
        load_demonstrations(p)


def test_csv_header_names_the_comment_line_that_is_not_json(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text('# {"fps": 10}\n\n# recorded by Bob\nt,a_x,a_y,a_z\n0,1,2,3\n0.1,1,2,3\n')
    with pytest.raises(
        DataError,
        match=r"x\.csv: field 'header' \(# JSON comment\) is invalid: line 3 '# recorded by "
        r"Bob' is not JSON \(Extra data at column 3\); the 2 '#' lines at the top \(lines 1-3\)",
    ):
        load_demonstrations(p)
    p.write_text('# exported by hand\n# {"fps": 10}\nt,a_x,a_y,a_z\n0,1,2,3\n')
    with pytest.raises(DataError, match=r"is invalid: line 1 '# exported by hand' is not JSON"):
        load_demonstrations(p)
    p.write_text('# {"fps": 10,\n#  "metadata": {"subject": 3}}\nt,a_x,a_y,a_z\n0,1,2,3\n')
    (d,) = load_demonstrations(p)  # a JSON object over several lines still reads
    assert d.fps == 10 and d.metadata == {"subject": 3}


@pytest.mark.parametrize(("header", "line"), [("", 1), ('# {"fps": 10}\n', 2)])
def test_csv_without_a_column_header_row_says_so(tmp_path, header, line):
    """A first row of numbers was listed, number by number, as unknown columns."""
    p = tmp_path / "x.csv"
    p.write_text(header + "\n".join(",".join(["0.1"] * 30) for _ in range(3)) + "\n")
    with pytest.raises(
        DataError,
        match=rf"x\.csv: line {line} holds numbers, not column names: the first line .*must "
        r"name the columns \(see datasets/README\.md\)$",
    ) as info:
        load_demonstrations(p, fps=10)
    assert len(str(info.value)) < len(str(p)) + 160


def test_timestamps_are_checked_by_their_median_spacing_within_the_tolerance(tmp_path):
    """The spacing test takes the median, so one pause does not refuse a 15 Hz file (its mean
    spacing is 1.7 frames; the pause warns as a gap); 12 Hz under fps 15 (20 % off) is refused;
    two equal times are not increasing."""
    ts = np.arange(12) / 15.0
    ts[8:] += 1.0  # a 1 s pause after frame 7
    with pytest.warns(DataWarning, match="from frame 7 to frame 8"):
        (d,) = load_demonstrations(_npz(tmp_path / "pause.npz", timestamps=ts))
    np.testing.assert_array_equal(d.timestamps, ts)
    with pytest.raises(DataError, match=r"slow\.npz: field 'timestamps' is spaced 0\.08333 s"):
        load_demonstrations(_npz(tmp_path / "slow.npz", timestamps=np.arange(12) / 12.0))
    same = np.arange(12) / 15.0
    same[3] = same[2]
    with pytest.raises(DataError, match=r"same\.npz: .*strictly increasing; frame 3 \(counting "
                       r"from 0\) has t = 0\.133333 s after 0\.133333 s"):  # fmt: skip
        load_demonstrations(_npz(tmp_path / "same.npz", timestamps=same))


def test_csv_labels_without_action_names_name_one_action_per_label(tmp_path):
    """Labels 0 and 1 without names in the header: actions action_0 and action_1 (the largest
    label + 1 of them), and the labels kept."""
    p = tmp_path / "x.csv"
    p.write_text('# {"fps": 15.0}\nt,label,a_x,a_y,a_z\n0,0,1,2,3\n0.0666667,1,1,2,3\n')
    (d,) = load_demonstrations(p)
    assert d.action_names == ("action_0", "action_1") and d.labels.tolist() == [0, 1]


def _lego_tree(root: Path, rows: list[str]) -> Path:
    """``root/Task1/Human2/trial3.txt`` holding ``rows``."""
    trial = root / "Task1" / "Human2" / "trial3.txt"
    trial.parent.mkdir(parents=True)
    trial.write_text("\n".join(rows) + "\n")
    return trial


def test_lego_metadata_names_task_human_and_trial_from_the_folders(tmp_path):
    _lego_tree(tmp_path, [_lego_row()] * 3)
    (d,) = load_lego_assembly(tmp_path, fps=30.0)
    assert d.name == "Task1/Human2/trial3"
    assert (d.metadata["task"], d.metadata["human"]) == ("Task1", "Human2")


def test_a_lego_trial_with_one_coordinate_lost_everywhere_is_refused(tmp_path):
    """Every joint has a NaN coordinate in every frame (only x lost): no joint is ever
    observed, as when all of them are NaN."""
    row = " ".join("nan" if i % 3 == 0 else "0.1" for i in range(18))
    _lego_tree(tmp_path, [row] * 3)
    with pytest.raises(DataError, match=r"trial3\.txt: field 'positions' is NaN in every frame "
                       r"for every joint"):  # fmt: skip
        load_lego_assembly(tmp_path, fps=30.0)


@pytest.mark.parametrize(
    ("names", "match"),
    [
        (["idle", "idle", "reach"], r"names \['idle'\] more than once"),
        (["idle", "", "reach"], "holds an empty name"),
        (["idle", "  ", "reach"], "holds an empty name"),
    ],
)
def test_action_names_given_twice_or_empty_are_refused(tmp_path, names, match):
    """Duplicate joint names were refused but duplicate or empty action names loaded: two
    labels of one name are one action to a reader and two to the predictor."""
    p = _npz(tmp_path / "x.npz", action_names=np.array(names))
    with pytest.raises(DataError, match=rf"x\.npz: field 'action_names' {match}"):
        load_demonstrations(p)
    header = "# " + json.dumps({"fps": 15.0, "action_names": names})
    c = _csv(tmp_path / "y.csv", header, "t,label,a_x,a_y,a_z", "0.0,0,1,2,3")
    with pytest.raises(DataError, match=rf"y\.csv: field 'action_names' {match}"):
        load_demonstrations(c)
