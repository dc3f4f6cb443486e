"""The recovery stage's finished chunks of labels, kept in the run directory until the stage ends:
`ChunkStore`.

A labelling step splits its starts into fixed chunks (`stage.LABEL_CHUNKS`); each chunk's result
(labels X (K, n), U (K, m), and how many starts the teacher and the plans brought to x*) is written
atomically to ``recovery-chunks/<step>-<k>.npz`` as it arrives, under a key that hashes the chunk's
start states and the settings that made it. The stage is deterministic (same run, same config, same
machine), so a stage started again after a kill asks for the same chunks and reads each one that is
already there instead of planning it again: a kill loses at most the chunks under way. A file whose
key does not match, or that cannot be read, is planned again. `clear` removes the folder once the
stage has saved its law.
"""

from __future__ import annotations

import hashlib
import io
import shutil
from pathlib import Path

import numpy as np

from .._io import atomic_write_bytes

__all__ = ["CHUNKS_DIR", "ChunkStore", "chunk_key"]

#: Folder of the finished chunks inside the run directory.
CHUNKS_DIR = "recovery-chunks"


def chunk_key(x0: np.ndarray, *settings) -> str:
    """A hex digest of the chunk's start states x0 (S, n) and the repr of each setting that made it."""
    h = hashlib.sha256(np.ascontiguousarray(x0, dtype=np.float64).tobytes())
    for s in settings:
        h.update(repr(s).encode())
    return h.hexdigest()


class ChunkStore:
    """The finished chunks of one run directory (`run_dir` None: a store that keeps nothing)."""

    def __init__(self, run_dir: str | Path | None):
        self.folder = None if run_dir is None else Path(run_dir) / CHUNKS_DIR

    def _path(self, step: str, k: int) -> Path:
        return self.folder / f"{step}-{k}.npz"

    def read(self, step: str, k: int, key: str):
        """(X, U, teacher successes, plan successes) of chunk k of `step` saved under `key`, or None."""
        if self.folder is None or not self._path(step, k).is_file():
            return None
        try:
            with np.load(self._path(step, k), allow_pickle=False) as z:
                if str(z["key"]) != key:
                    return None
                return np.asarray(z["X"], np.float64), np.asarray(z["U"], np.float64), int(z["taught"]), int(z["recovered"])
        except (OSError, ValueError, KeyError):  # a damaged chunk is planned again
            return None

    def write(self, step: str, k: int, key: str, part) -> None:
        """Save chunk k of `step`: part = (X, U, teacher successes, plan successes), atomically."""
        if self.folder is None:
            return
        self.folder.mkdir(exist_ok=True)
        buf = io.BytesIO()
        np.savez(buf, key=np.asarray(key), X=part[0], U=part[1], taught=np.asarray(part[2]), recovered=np.asarray(part[3]))
        atomic_write_bytes(self._path(step, k), buf.getvalue())

    def clear(self) -> None:
        """Remove every saved chunk."""
        if self.folder is not None and self.folder.is_dir():
            shutil.rmtree(self.folder, ignore_errors=True)
