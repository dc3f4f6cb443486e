"""Lenient reads and timestamps for the files of a batch directory.

A batch resumes by reading what an earlier, possibly killed, invocation left behind: a ``job.json``
that is missing or damaged simply means "run that job again", and a ``batch.json`` that cannot be
read is one that belongs to no batch. `read_json_or_none` is that reading (through
`idapbc_pin._io.read_json`, the one JSON reader); files whose damage must be reported are read
with `read_json` itself, or through `idapbc_pin.run`.
"""

from __future__ import annotations

import datetime as _dt

from .._io import read_json
from ..errors import IdapbcError

__all__ = ["read_json_or_none", "timestamp"]


def read_json_or_none(path):
    """The JSON value in `path`, or None when the file is missing or cannot be read."""
    try:
        return read_json(path)
    except IdapbcError:
        return None


def timestamp() -> str:
    """The local time to the second, ISO 8601 (``2024-05-01T12:30:00``)."""
    return _dt.datetime.now().isoformat(timespec="seconds")
