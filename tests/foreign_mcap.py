"""A complete MCAP file of another program, for the tests of how episode readers and reports
treat it (``tests/conftest.py`` puts this folder on ``sys.path``)."""

from __future__ import annotations

import json
from pathlib import Path

from mcap.writer import Writer


def write_foreign_mcap(path: Path) -> Path:
    """Write ``path``: the mcap package's own writer, a JSON channel ``/odom`` with 3 messages
    and a ``camera`` metadata record, but no ``iplanner.episode`` metadata record."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("pose", "jsonschema", b"{}")
        channel = w.register_channel("/odom", "json", schema)
        for i in range(3):
            w.add_message(channel, log_time=i, data=json.dumps({"x": i}).encode(), publish_time=i)
        w.add_metadata("camera", {"model": "x"})
        w.finish()
    return path
