"""Run-directory files: atomic writes, one to-JSON conversion, and one reader that names damage.

Writes go to a temp file in the same folder, are fsynced, then `os.replace`d: a reader never sees a
half-written file, and a crash leaves the previous version. Reads of JSON files that a run or batch
directory holds go through `read_json`, and of .npz files through `read_npz`, which turn a missing,
truncated or garbled file into one `IdapbcError` line naming the file and the fix.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from .errors import IdapbcError

__all__ = ["DamagedFileError", "atomic_write_bytes", "finite_or_none", "read_json", "read_npz", "to_json", "write_json"]


class DamagedFileError(IdapbcError):
    """A file of a run or batch directory exists but cannot be read (truncated, garbled, non-finite)."""


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


def finite_or_none(v):
    """A float, or None for None, NaN, ±inf and values that are not numbers."""
    if v is None or isinstance(v, (bool, np.bool_)):
        return None if v is None else float(v)
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def to_json(obj):
    """`obj` with numpy scalars and arrays as Python values, tuples as lists, paths as strings and
    non-finite floats as None (JSON has no NaN): the one conversion every JSON file goes through."""
    if isinstance(obj, dict):
        return {str(k): to_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set)):
        return [to_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_json(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return finite_or_none(obj)
    if isinstance(obj, os.PathLike):
        return str(obj)
    if hasattr(obj, "tolist"):  # torch tensors and other array-likes
        return to_json(obj.tolist())
    return obj


def write_json(path, obj, *, sort_keys: bool = True) -> Path:
    """`to_json(obj)` as indented JSON, written atomically; returns the path."""
    text = json.dumps(to_json(obj), indent=2, sort_keys=sort_keys, allow_nan=False, default=str) + "\n"
    return atomic_write_bytes(path, text.encode())


def read_json(path, *, fix: str = "restore it from a backup, or delete the run directory and train again"):
    """The JSON value in `path`; a missing or unreadable file raises one `IdapbcError` line.

    fix : what the user should do when the file is damaged (ends the error's `Fix:` sentence).
    """
    path = Path(path)
    if not path.is_file():
        raise IdapbcError(f"'{path}' is missing. Fix: {fix}.")
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DamagedFileError(f"{path} is damaged ({reason}). Fix: {fix}.") from None


def read_npz(path, build, *, fix: str):
    """`build(arrays)` on the arrays of the existing .npz file `path`, read without pickles; a
    truncated or garbled file, or one `build` refuses (ValueError, KeyError), raises one
    `DamagedFileError` line ending with `fix`. Callers check that the file exists first, since what a
    missing file means is theirs to say."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as arrays:
            return build(arrays)
    except (ValueError, KeyError, OSError, zipfile.BadZipFile, EOFError) as exc:
        reason = str(exc).splitlines()[0][:100] if str(exc) else type(exc).__name__
        raise DamagedFileError(f"{path} is damaged ({reason}). Fix: {fix}.") from None
