"""The batch directory: which one a batch runs in, its lock, and its ``batch.json``.

``batch.json`` holds the pipeline's path and hash, the smoke flag, the job names, whether every
job is done (``complete``), a random ``token`` (by which a Ray worker knows it sees this
directory) and one entry per invocation (when, how long, which executor, which jobs ran, were
skipped or failed). Re-running the same command picks the latest unfinished batch of the same
pipeline, so a batch killed at any moment resumes.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import os
import shutil
import socket
import uuid
from pathlib import Path

from .._io import write_json
from ..errors import IdapbcError
from ._files import read_json_or_none, timestamp
from .pipeline import Pipeline

__all__ = ["choose_batch_dir", "lock", "open_batch", "record_invocation"]


def choose_batch_dir(pipeline: Pipeline, out=None, resume=None) -> Path:
    """The directory a batch of `pipeline` runs in.

    resume : an existing batch directory (it must hold batch.json). out : a new directory, or a
    batch directory to resume. Neither: the latest unfinished ``runs/batch-*`` of this pipeline
    with the same smoke flag, else a new ``runs/batch-<stamp>`` (``runs`` of the working directory),
    created here, empty, so that two batches started in the same second cannot both pick it (the
    second gets ``batch-<stamp>-1``).
    """
    if resume is not None:
        path = Path(resume)
        if not (path / "batch.json").is_file():
            raise IdapbcError(f"'{path}' is not a batch directory (no batch.json). Fix: pass a directory made by `idapbc-pin batch`.")
        return path
    if out is not None:
        path = Path(out)
        if path.exists() and any(path.iterdir()) and not (path / "batch.json").is_file():
            raise IdapbcError(f"'{path}' exists and is not a batch directory (no batch.json). Fix: pass a new directory, or a batch directory to resume.")
        return path
    parent = Path("runs")
    latest = None
    for meta_path in sorted(parent.glob("batch-*/batch.json")):
        meta = read_json_or_none(meta_path) or {}
        if meta.get("pipeline") == str(pipeline.path) and bool(meta.get("smoke")) == pipeline.smoke and not meta.get("complete"):
            latest = meta_path.parent
    if latest is not None:
        return latest
    parent.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    for k in range(1000):
        path = parent / (f"batch-{stamp}-{k}" if k else f"batch-{stamp}")
        try:
            path.mkdir()  # atomic: of two batches that chose this name, one gets FileExistsError
        except FileExistsError:
            continue
        return path
    raise IdapbcError(f"cannot create a new batch directory under '{parent}' (1000 names taken). Fix: pass --out DIR.")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def lock(batch_dir: Path):
    """Hold ``batch_dir/.lock`` (host and pid) while the body runs; a lock whose process is gone is taken over."""
    path = batch_dir / ".lock"
    me = f"{socket.gethostname()} {os.getpid()}"
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            break
        except FileExistsError:
            host, _, pid = path.read_text().partition(" ")
            alive = host == socket.gethostname() and pid.isdigit() and _pid_alive(int(pid))
            if alive:
                raise IdapbcError(f"another batch is running in '{batch_dir}' (pid {pid}). Fix: wait for it, or pass another --out DIR.") from None
            path.unlink(missing_ok=True)  # stale: its process is gone
    else:  # pragma: no cover
        raise IdapbcError(f"cannot lock '{batch_dir}'. Fix: remove {path}.")
    with os.fdopen(fd, "w") as fh:
        fh.write(me)
    try:
        yield
    finally:
        path.unlink(missing_ok=True)


def open_batch(batch_dir: Path, pipeline: Pipeline) -> dict:
    """Start an invocation in `batch_dir`: write batch.json (new, or updated) and a copy of the
    pipeline file as ``pipeline.toml``; returns batch.json's content.

    A batch directory of another pipeline file is refused.
    """
    meta = read_json_or_none(batch_dir / "batch.json") or {"created": timestamp(), "token": uuid.uuid4().hex, "invocations": []}
    if meta.get("pipeline") not in (None, str(pipeline.path)):
        raise IdapbcError(f"'{batch_dir}' holds a batch of '{meta['pipeline']}', not '{pipeline.path}'. Fix: pass another --out DIR.")
    meta.update(pipeline=str(pipeline.path), pipeline_sha256=pipeline.sha256, smoke=pipeline.smoke, jobs=pipeline.names, complete=False)
    write_json(batch_dir / "batch.json", meta)
    shutil.copyfile(pipeline.path, batch_dir / "pipeline.toml")
    return meta


def record_invocation(batch_dir: Path, meta: dict, complete: bool, invocation: dict) -> None:
    """Append `invocation` to batch.json's invocations and set its ``complete`` flag.

    meta : batch.json as `open_batch` wrote it (used when the file cannot be read back).
    """
    meta = read_json_or_none(batch_dir / "batch.json") or meta
    meta["complete"] = complete
    meta["invocations"] = [*meta.get("invocations", []), invocation]
    write_json(batch_dir / "batch.json", meta)
