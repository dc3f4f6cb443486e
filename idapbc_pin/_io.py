"""Atomic file writes: a temp file in the same folder, fsync, then os.replace.

A reader never sees a half-written file, and a crash leaves the previous version (DESIGN: run
directories are never corrupted).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write_bytes", "write_json"]


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write `data` to `path` atomically; creates the parent folder; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_json(path, obj, *, sort_keys: bool = True, default=None, allow_nan: bool = True) -> Path:
    """`obj` as indented JSON, written atomically."""
    text = json.dumps(obj, indent=2, sort_keys=sort_keys, default=default, allow_nan=allow_nan) + "\n"
    return atomic_write_bytes(path, text.encode())
