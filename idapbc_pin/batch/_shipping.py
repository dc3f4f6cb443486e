"""Job directories shipped as tar.gz bytes, for workers that do not share the batch's filesystem.

A Ray node of a cluster may not see the driver's batch directory. The driver writes a random
``token`` into ``batch.json``; a worker that does not find that token next to its job directory runs
the job in a temporary folder and returns the folder as an archive (`pack_dir`), which the driver
unpacks into the job directory (`unpack_dir`).
"""

from __future__ import annotations

import io
import tarfile
from pathlib import Path

from ._files import read_json_or_none

__all__ = ["pack_dir", "sees_batch_dir", "unpack_dir"]


def sees_batch_dir(job_dir: Path, token: str | None) -> bool:
    """Whether ``job_dir/../batch.json`` holds `token` (always true for `token` None: a local executor)."""
    if token is None:
        return True
    meta = read_json_or_none(job_dir.parent / "batch.json") or {}
    return meta.get("token") == token


def pack_dir(directory: Path) -> bytes:
    """The contents of `directory` as tar.gz bytes (paths relative to it)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        tar.add(directory, arcname=".")
    return buf.getvalue()


def unpack_dir(data: bytes, directory: Path) -> None:
    """Extract `pack_dir`'s bytes into `directory` (created; the ``data`` filter where Python has it)."""
    directory.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        if hasattr(tarfile, "data_filter"):
            tar.extractall(directory, filter="data")
        else:  # pragma: no cover (Python < 3.10.12 / 3.11.4)
            tar.extractall(directory)
