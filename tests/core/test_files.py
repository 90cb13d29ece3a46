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


def test_json_text_is_standard_json() -> None:
    """Result files are standard JSON: NaN and infinities become null (Python wrote NaN and
    Infinity literals, which JavaScript's JSON.parse refuses: comparison.json of every main
    job had them), numpy and torch numbers become numbers, nested containers keep shape."""
    import json
    import math

    import numpy as np
    import torch

    from iplanner_torch.files import json_text

    value = {
        "nan": math.nan, "inf": -math.inf, "np": np.float32(1.5), "np_nan": np.float64("nan"),
        "t": torch.tensor([1.0, math.inf]), "nested": [(1, "a"), {"x": math.nan}], "none": None,
        "flag": True, "path": Path("a/b"),
    }  # fmt: skip

    def strict(token: str) -> None:
        raise ValueError(f"non-standard JSON literal {token}")

    back = json.loads(json_text(value, default=str, indent=1), parse_constant=strict)
    assert back == {
        "nan": None, "inf": None, "np": 1.5, "np_nan": None, "t": [1.0, None],
        "nested": [[1, "a"], {"x": None}], "none": None, "flag": True, "path": "a/b",
    }  # fmt: skip
    with pytest.raises(ValueError, match="non-standard JSON literal NaN"):
        json.loads(json.dumps({"a": math.nan}), parse_constant=strict)  # what json.dumps wrote


def test_checkpoint_load_errors_read_in_one_line(tmp_path: Path) -> None:
    """torch's weights-only refusal is several lines of advice: a pickled class is named as
    such (refused, not run), a damaged file by its cause, each in one line."""
    import os

    import torch

    from iplanner_torch.errors import checkpoint_load_error

    class Runs:
        def __reduce__(self):
            return (os.getcwd, ())

    torch.save({"x": Runs()}, tmp_path / "obj.pt")
    torch.save({"x": torch.zeros(2)}, tmp_path / "ok.pt")
    good = (tmp_path / "ok.pt").read_bytes()
    (tmp_path / "cut.pt").write_bytes(b"\xef" + good[1:200])
    said = {}
    for name in ("obj", "cut"):
        with pytest.raises(Exception) as e:  # noqa: PT011 - torch's own error types vary
            torch.load(tmp_path / f"{name}.pt", weights_only=True)
        said[name] = checkpoint_load_error(e.value)
    assert said["obj"][0] and "objects other than tensors" in said["obj"][1]
    assert "GLOBAL" in said["obj"][1] and "\n" not in said["obj"][1]
    assert not said["cut"][0] and "\n" not in said["cut"][1]
    assert torch.load(tmp_path / "ok.pt", weights_only=True)["x"].shape == (2,)
