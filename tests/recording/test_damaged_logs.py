"""read_episode on damaged or malformed logs: a DataError naming the file, or a prefix of the
messages with a DataWarning; never a bare exception or silently lost messages."""

from __future__ import annotations

import json
import struct
import warnings
from pathlib import Path

import pytest
from mcap.writer import Writer

from iplanner_torch.errors import DataError, DataWarning
from iplanner_torch.recording import EpisodeWriter, read_episode
from iplanner_torch.recording.reader import metadata_crc

_CHUNK, _DATA_END = 0x06, 0x0F


def _plain_mcap(path: Path, messages: list[tuple[str, bytes]], record: dict | None) -> Path:
    """An MCAP file of the plain mcap writer: the episode metadata record ``record`` (none when
    None) and ``messages`` on JSON channels of their topics."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        if record is not None:
            w.add_metadata("iplanner.episode", record)
        schema = w.register_schema("x", "jsonschema", b"{}")
        ids: dict[str, int] = {}
        for i, (topic, data) in enumerate(messages):
            if topic not in ids:
                ids[topic] = w.register_channel(topic, "json", schema)
            w.add_message(ids[topic], log_time=i, data=data, publish_time=i)
        w.finish()
    return path


def _four_states(path: Path) -> Path:
    """A log of four robot states (q = 0, 1, 2, 3), one per 64-byte chunk (after the /tf)."""
    with EpisodeWriter(path, metadata={}, chunk_size=64) as log:
        for i in range(4):
            log.robot_state(0.1 * i, [float(i)], [0.0], ["a"])
    return path


def _record(offset: str = "0") -> dict[str, str]:
    return {
        "json": "{}",
        "time_offset_ns": offset,
        "value_codec": "2",
        "crc32": str(metadata_crc("{}", offset, "2")),
    }


def test_a_chunk_of_unknown_compression_without_checksum_stops_the_read(tmp_path: Path):
    """A chunk whose compression name ("zstd") and checksum field (0: none written) were
    damaged was taken as uncompressed by the mcap reader: its messages vanished and the log
    read as complete, without a warning. It now ends the read there, with a warning."""
    path = _four_states(tmp_path / "chunk.mcap")
    blob = bytearray(path.read_bytes())
    at, chunks = 8, []
    while blob[at] != _DATA_END:
        if blob[at] == _CHUNK:
            chunks.append(at)
        at += 9 + struct.unpack_from("<Q", blob, at + 1)[0]
    at = chunks[2]  # the chunk of q = 1 (after the /tf and the q = 0 ones)
    # opcode, length, start and end times, uncompressed size: then the crc and "zstd"
    assert blob[at + 37 : at + 45] == b"\x04\x00\x00\x00zstd"
    blob[at + 33 : at + 37] = bytes(4)
    blob[at + 41 : at + 45] = b"zstx"
    path.write_bytes(bytes(blob))
    with pytest.warns(DataWarning) as caught:
        ep = read_episode(path)
    assert [str(w.message) for w in caught] == [
        f"{path}: episode log is truncated or damaged (the chunks hold 4 messages, the "
        "summary counts 5; read record by record: a chunk has unknown compression 'zstx'); "
        "read 2 messages from its complete chunks"
    ]
    assert not ep.complete and ep.robot_q()[1].tolist() == [[0.0]]


@pytest.mark.parametrize(
    ("message", "error"),
    [
        (("/robot/joint_state", b'{"t": 1%s, "joint_names": ["a"], "position": [1.0], '
          b'"velocity": [0.0]}' % (b"0" * 400)), "/robot/joint_state: OverflowError"),
        (("/planner/bound", b'{"t": 0.0, "times": [1%s], "bound": [0.0], "confidence": 0.9, '
          b'"max_bound": 0.0}' % (b"0" * 400)), "/planner/bound: OverflowError"),
        (("/tf", b'{"timestamp": {"sec": 1%s, "nsec": 0}, "parent_frame_id": "world", '
          b'"child_frame_id": "t", "translation": {"x": 0, "y": 0, "z": 0}, '
          b'"rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}' % (b"0" * 400)), "/tf: OverflowError"),
    ],
    ids=["time", "array_value", "stamp"],
)  # fmt: skip
def test_an_integer_too_large_for_a_float_is_a_data_error(
    tmp_path: Path, message: tuple[str, bytes], error: str
) -> None:
    """A 401-digit integer where a number belongs raised a bare OverflowError."""
    path = _plain_mcap(tmp_path / "big.mcap", [message], _record())
    with pytest.raises(DataError, match=rf"big.mcap: cannot decode a message on {error}"):
        read_episode(path)


@pytest.mark.parametrize(
    "offset", ["1" + "0" * 400, "-5", str(2**64)], ids=["401_digits", "negative", "2^64"]
)
def test_a_time_offset_out_of_range_is_a_bad_metadata_record(tmp_path: Path, offset: str):
    """A metadata record (with a matching checksum) whose time offset does not fit a log time
    raised a bare OverflowError on the first /tf message, or read negative offsets as given."""
    tf = (
        b'{"timestamp": {"sec": 0, "nsec": 0}, "parent_frame_id": "world", "child_frame_id": '
        b'"t", "translation": {"x": 0, "y": 0, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0, '
        b'"w": 1}}'
    )
    path = _plain_mcap(tmp_path / "offset.mcap", [("/tf", tf)], _record(offset))
    with pytest.raises(
        DataError,
        match=r"offset.mcap: bad episode metadata record: time_offset_ns .* is not in "
        r"\[0, 2\^64 - 1\]",
    ):
        read_episode(path)


def test_a_huge_sphere_count_is_a_data_error_not_an_allocation(tmp_path: Path) -> None:
    """A scene entity naming 10^11 sphere rows (one drawn) made the reader allocate them: a
    bare MemoryError (smaller counts took gigabytes)."""
    sphere = {
        "pose": {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"w": 1}},
        "size": {"x": 0.2},
    }
    entity = {
        "id": "robot",
        "timestamp": {"sec": 0, "nsec": 0},
        "metadata": [
            {"key": "sphere_count", "value": "99999999999"},
            {"key": "sphere_rows", "value": "0"},
        ],
        "spheres": [sphere],
    }
    data = json.dumps({"deletions": [], "entities": [entity]}).encode()
    path = _plain_mcap(tmp_path / "scene.mcap", [("/scene", data)], _record())
    with pytest.raises(
        DataError,
        match=r"scene.mcap: cannot decode a message on /scene: .*scene entity 'robot': "
        r"sphere_count '99999999999' is more than 1048576 rows",
    ):
        read_episode(path)


def test_accessors_of_messages_not_decoded_name_the_file(tmp_path: Path) -> None:
    """Without the episode metadata record (another program's file, or one whose record was
    lost) the messages are kept as dicts: the accessors raised a bare KeyError."""
    state = b'{"t": 0.0, "joint_names": ["a"], "position": [1.0], "velocity": [0.0]}'
    metrics = b'{"t": 1.0, "metrics": {"x": 1.0}}'
    path = _plain_mcap(
        tmp_path / "anon.mcap",
        [("/robot/joint_state", state), ("/episode/metrics", metrics)],
        record=None,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        ep = read_episode(path)
    assert ep.frames["/robot/joint_state"]["message"].iloc[0]["position"] == [1.0]
    for accessor, topic in (("robot_q", "/robot/joint_state"), ("metrics", "/episode/metrics")):
        with pytest.raises(
            DataError,
            match=rf"anon.mcap: the messages on {topic} are not decoded \(no iplanner.episode "
            rf"metadata record",
        ):
            getattr(ep, accessor)()


@pytest.mark.parametrize("sec", ['"1"', "[1, 2]"])
def test_a_stamp_that_is_not_a_number_is_a_data_error(tmp_path: Path, sec: str) -> None:
    """A /tf stamp whose sec was a string or a list was repeated 10^9 times (gigabytes, or a
    bare MemoryError) before the sum failed."""
    tf = (
        b'{"timestamp": {"sec": %s, "nsec": 0}, "parent_frame_id": "world", "child_frame_id": '
        b'"t", "translation": {"x": 0, "y": 0, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0, '
        b'"w": 1}}' % sec.encode()
    )
    path = _plain_mcap(tmp_path / "stamp.mcap", [("/tf", tf)], _record())
    with pytest.raises(
        DataError, match=r"stamp.mcap: cannot decode a message on /tf: .*sec and nsec must be n"
    ):
        read_episode(path)


def _chunks(blob: bytes) -> list[tuple[int, int]]:
    """(offset, length) of every chunk record of a log."""
    at, chunks = 8, []
    while blob[at] != _DATA_END:
        n = 9 + struct.unpack_from("<Q", blob, at + 1)[0]
        if blob[at] == _CHUNK:
            chunks.append((at, n))
        at += n
    return chunks


@pytest.mark.parametrize(
    ("damage", "held", "q"),
    [("removed", 4, [[0.0], [2.0], [3.0]]), ("repeated", 6, [[0.0], [1.0], [1.0], [2.0], [3.0]])],
)
def test_a_removed_or_repeated_chunk_makes_the_log_incomplete(
    tmp_path: Path, damage: str, held: int, q: list
) -> None:
    """A chunk cut out or written twice keeps its own checksum, so the sequential read that
    follows the summary's failure read every chunk and called the log complete; the summary's
    statistics count other messages than were read, and the log is incomplete now."""
    path = _four_states(tmp_path / "log.mcap")
    blob = path.read_bytes()
    at, n = _chunks(blob)[2]  # the chunk of q = 1
    if damage == "repeated":
        path.write_bytes(blob[: at + n] + blob[at:])
    else:
        path.write_bytes(blob[:at] + blob[at + n :])
    with pytest.warns(DataWarning, match=f"the chunks hold {held} messages, the summary counts 5"):
        ep = read_episode(path)
    assert not ep.complete and ep.robot_q()[1].tolist() == q


def test_a_huge_length_field_is_named_in_the_warning(tmp_path: Path) -> None:
    """A chunk's compressed-size field set to 2^63 - 1 made the mcap library fail with
    "OverflowError: byte string is too large": the warning now says a length field is
    damaged."""
    path = _four_states(tmp_path / "log.mcap")
    blob = bytearray(path.read_bytes())
    at, _ = _chunks(bytes(blob))[-1]
    # opcode, length, start and end times, uncompressed size, crc, compression: then the size
    size_at = at + 37 + 4 + struct.unpack_from("<I", blob, at + 37)[0]
    struct.pack_into("<Q", blob, size_at, 2**63 - 1)
    path.write_bytes(bytes(blob))
    with pytest.warns(DataWarning) as caught:
        ep = read_episode(path)
    text = str(caught[0].message)
    assert "OverflowError: a length field declares more bytes than can be read (damaged)" in text
    assert not ep.complete and ep.robot_q()[1].tolist() == [[0.0], [1.0], [2.0]]


def test_scene_sphere_rows_must_increase() -> None:
    """A damaged entity naming one sphere row twice ("0,0") is refused, as a decreasing list
    is; increasing rows within the count pass."""
    from iplanner_torch.recording.reader import SPHERE_COUNT_KEY, SPHERE_ROWS_KEY, _sphere_slots

    def entity(rows: str) -> dict:
        meta = [{"key": SPHERE_COUNT_KEY, "value": "3"}, {"key": SPHERE_ROWS_KEY, "value": rows}]
        return {"id": "robot", "metadata": meta}

    assert _sphere_slots(entity("0,2"), 2) == (3, [0, 2])
    for rows in ("0,0", "2,1", "0,3"):
        with pytest.raises(ValueError, match="are not 2 increasing rows"):
            _sphere_slots(entity(rows), 2)


@pytest.mark.parametrize("keep", [0.3, 0.99, 0.999])
def test_a_log_cut_short_says_so_in_words_of_its_own(tmp_path: Path, keep: float) -> None:
    """A cut whose last byte before the would-be footer happened to read as a footer's
    opcode sent the summary check to a random offset: the warning said "OSError: [Errno 22]
    Invalid argument", and other cuts the mcap library's "EndOfFile" or struct's "unpack
    requires a buffer of 8 bytes". Now: no closing magic bytes, the last record cut short."""
    whole = _four_states(tmp_path / "whole.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: int(len(whole) * keep)])
    with pytest.warns(DataWarning) as caught:
        read_episode(cut)
    (text,) = [str(w.message) for w in caught]
    assert "no closing magic bytes: the file ends before its footer" in text
    for library_word in ("Errno", "EndOfFile", "unpack", "OSError"):
        assert library_word not in text, text


def test_a_footer_that_points_outside_the_file_is_named(tmp_path: Path) -> None:
    path = _four_states(tmp_path / "far.mcap")
    blob = bytearray(path.read_bytes())
    footer = len(blob) - 8 - 29  # opcode 0x02, length, summary start, offset start, crc
    assert blob[footer] == 0x02
    blob[footer + 9 : footer + 17] = (2**50).to_bytes(8, "little")
    path.write_bytes(bytes(blob))
    with pytest.warns(DataWarning, match=r"places the summary section at byte 1125899906842624"):
        ep = read_episode(path)
    assert ep.robot_q()[1].shape[0] >= 1  # every record still read, in order
