"""whole_file: a file replaced in one step, or left as it was."""

from __future__ import annotations

from pathlib import Path

import pytest

from iplanner_torch.files import whole_file


def test_the_block_s_file_replaces_the_earlier_one(tmp_path: Path) -> None:
    path = tmp_path / "results.csv"
    path.write_text("earlier\n")
    with whole_file(path) as tmp:
        assert tmp.parent == tmp_path and tmp != path and not tmp.exists()
        tmp.write_text("new\n")
        assert path.read_text() == "earlier\n"  # not before the block ends
    assert path.read_text() == "new\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.csv"]


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_a_block_that_fails_leaves_the_earlier_file(tmp_path: Path, error) -> None:
    path = tmp_path / "run_inputs.json"
    path.write_text("{}")
    with pytest.raises(type(error)), whole_file(path) as tmp:
        tmp.write_text('{"half": ')
        raise error
    assert path.read_text() == "{}"
    assert [p.name for p in tmp_path.iterdir()] == ["run_inputs.json"]  # no temporary left


def test_no_earlier_file_and_a_failed_block_leave_none(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError), whole_file(tmp_path / "a.ckpt"):
        raise RuntimeError("before writing")
    assert list(tmp_path.iterdir()) == []
    with whole_file(tmp_path / "a.ckpt") as one, whole_file(tmp_path / "a.ckpt") as two:
        assert one != two  # two writers of the same file write apart
        one.write_text("1")
        two.write_text("2")
    assert (tmp_path / "a.ckpt").read_text() == "1"  # the last to finish (the outer block)
