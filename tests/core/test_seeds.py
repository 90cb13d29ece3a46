"""derive_seed: streams of other seeds, tags or indices share no seed; bad keys refused."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from iplanner_torch.checks import MAX_SEED
from iplanner_torch.errors import ConfigError
from iplanner_torch.seeds import PLANNER_COLD_START, PLANNER_FRESH, SVGP_MINIBATCHES, derive_seed


def test_streams_of_neighbouring_seeds_tags_and_indices_share_no_seed() -> None:
    """``seed + index`` gives episode s at index i + 1 the seed of episode s + 1 at index i;
    derived seeds of 50 seeds x 3 tags x 50 indices are all distinct, and so are keys of
    other lengths whose trailing zeros ``SeedSequence`` alone would not tell apart."""
    tags = (PLANNER_COLD_START, PLANNER_FRESH, SVGP_MINIBATCHES)
    seeds = [derive_seed(s, t, i) for s in range(50) for t in tags for i in range(50)]
    assert len(set(seeds)) == len(seeds)
    assert all(0 <= s < 2**63 for s in seeds)
    short = {derive_seed(3, PLANNER_FRESH), derive_seed(3, PLANNER_FRESH, 0)}
    assert len(short | {derive_seed(3, PLANNER_FRESH, 0, 0)}) == 3
    # torch takes them, and two neighbouring streams draw differently
    a = torch.randn(4, generator=torch.Generator().manual_seed(derive_seed(0, PLANNER_FRESH, 1)))
    b = torch.randn(4, generator=torch.Generator().manual_seed(derive_seed(1, PLANNER_FRESH, 0)))
    assert not torch.equal(a, b)


def test_derived_seeds_do_not_depend_on_the_process() -> None:
    """The same arguments give the same seed in another interpreter (another hash seed)."""
    code = (
        "from iplanner_torch.seeds import derive_seed;"
        "print(derive_seed(7, 101, 3), derive_seed(4294967295, 201, 0))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        env={"PYTHONHASHSEED": "123", "PATH": ""},
    ).stdout.split()
    assert [int(v) for v in out] == [derive_seed(7, 101, 3), derive_seed(MAX_SEED, 201, 0)]


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((-1, PLANNER_FRESH, 0), "seed"),
        ((MAX_SEED + 1, PLANNER_FRESH, 0), "seed"),
        ((0, 0, 0), "tag"),
        ((0, PLANNER_FRESH, -1), "key"),
        ((0, PLANNER_FRESH, 1.5), "key"),
    ],
)
def test_bad_seeds_tags_and_keys_are_refused(args: tuple, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        derive_seed(*args)
