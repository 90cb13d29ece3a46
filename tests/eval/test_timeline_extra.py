"""A timeline stamp nested too deep for the JSON parser is no stamp (the figure is drawn
again), as malformed JSON is: it used to escape as a RecursionError."""

from __future__ import annotations

from pathlib import Path

from iplanner_torch.eval.timeline import STAMP_KEY, TimelineStamp, read_timeline_stamp

DEEP = "[" * 100_000 + "]" * 100_000


def test_a_stamp_nested_too_deep_is_none(tmp_path: Path) -> None:
    assert TimelineStamp.from_json(DEEP) is None
    assert TimelineStamp.from_json('{"format": ' + DEEP + "}") is None
    from matplotlib.figure import Figure

    png = tmp_path / "deep.png"
    Figure().savefig(png, metadata={STAMP_KEY: DEEP})
    assert read_timeline_stamp(png) is None
