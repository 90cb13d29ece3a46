"""Seeds of independent streams of draws derived from one user seed.

``seed + i`` is no way to give draws their own stream: episode ``s`` at step ``i + 1`` would
draw what episode ``s + 1`` draws at step ``i``. :func:`derive_seed` hashes the user seed with
a stream tag and the stream's own indices through numpy's ``SeedSequence``, so that streams
of different seeds, tags or indices do not share draws (up to hash collisions of 63 bits).

``SeedSequence`` reads ``[s, t]`` and ``[s, t, 0]`` alike (it drops trailing zeros), so the
number of keys is hashed too.
"""

from __future__ import annotations

import numpy as np

from iplanner_torch.checks import integer
from iplanner_torch.checks import seed as check_seed

#: stream tags (the first key after the seed); one per kind of draw
PLANNER_COLD_START = 101  # a solve's initial trajectories (no warm start), key: the cycle
PLANNER_FRESH = 102  # a warm-started cycle's fresh trajectories, key: the cycle
SVGP_MINIBATCHES = 201  # the SVGP's minibatches of one training round, key: the round


def derive_seed(seed: int, tag: int, *keys: int) -> int:
    """A 63-bit seed for the stream ``(tag, *keys)`` of the user seed ``seed``.

    Args:
        seed: the user's seed, an integer in [0, 2^32 - 1].
        tag: the kind of draw (a module constant such as :data:`PLANNER_FRESH`), >= 1.
        keys: the stream's indices (e.g. a replanning cycle), each an integer >= 0.

    Returns:
        An integer in [0, 2^63 - 1], for ``torch.Generator.manual_seed`` or
        ``numpy.random.default_rng``; the same arguments give the same seed on every machine.

    Raises:
        ConfigError: when ``seed``, ``tag`` or a key is not such an integer.
    """
    parts = [check_seed(seed), integer("tag", tag, minimum=1)]
    parts += [len(keys)] + [integer("key", k, minimum=0) for k in keys]
    words = np.random.SeedSequence(parts).generate_state(2, np.uint32)
    return (int(words[0]) << 31) | (int(words[1]) >> 1)
