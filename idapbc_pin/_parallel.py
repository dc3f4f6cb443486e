"""The cores this process may use, and an ordered map over worker processes.

`process_map` gives exactly what a loop over the same jobs gives (each job is the same computation
in another process), so the number of workers changes the time, never a result. Each worker limits
itself to one thread in every OpenMP / BLAS pool (threadpoolctl) and in torch: workers that keep
the parent's thread pools oversubscribe the cores and can run slower than one process. Each job
travels as plain pickle bytes: `concurrent.futures` would otherwise pickle torch tensors with
torch.multiprocessing's reductions, which move the caller's own tensors to shared memory.
"""

from __future__ import annotations

import contextlib
import os
import pickle
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Callable, Iterator, Sequence

__all__ = ["MAX_AUTO_WORKERS", "THREAD_ENV", "JobPool", "available_cores", "process_map", "resolve_workers", "stop_with_parent", "thread_env"]

#: Environment of worker processes: one OpenMP / MKL / BLAS thread each (set before they import numpy or torch).
THREAD_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}

#: Most worker processes that "one per core" starts (each holds torch and Pinocchio, ~0.3 GB).
MAX_AUTO_WORKERS = 16


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS tells it, else the CPU count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover (not Linux)
        return os.cpu_count() or 1


def resolve_workers(workers: int) -> int:
    """Worker processes for `workers`: itself when ≥ 1, else (0) one per available core, at most
    MAX_AUTO_WORKERS."""
    return int(workers) if workers >= 1 else max(1, min(available_cores(), MAX_AUTO_WORKERS))


@contextlib.contextmanager
def thread_env():
    """Set `THREAD_ENV` for the processes started inside the block (they read it as they load their
    thread pools); restore the environment after."""
    old = {k: os.environ.get(k) for k in THREAD_ENV}
    os.environ.update(THREAD_ENV)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


#: How often a worker checks that the process that started it is alive (s), and how long it lets an
#: interrupted job wind down (save its checkpoint, write its record) before it exits (s).
PARENT_POLL = 0.5
PARENT_GRACE = 10.0


def stop_with_parent(parent: int) -> None:
    """Worker initialiser: once the process `parent` (the one that started this worker) is gone,
    interrupt this worker as Ctrl-C would (SIGINT), then exit after `PARENT_GRACE` s if it is still
    running. A driver killed on its own (SIGTERM, SIGKILL) would otherwise leave its workers
    training on, and writing into folders a new run of the same batch uses."""
    import signal
    import threading
    import time

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL)
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(PARENT_GRACE)
        os._exit(1)

    threading.Thread(target=watch, name="stop-with-parent", daemon=True).start()


def _one_thread(parent: int) -> None:
    """Worker initialiser: one thread in torch and in every native thread pool of this process, and
    `stop_with_parent`."""
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(1)
    threadpool_limits(1)
    stop_with_parent(parent)


def _call(fn_and_job: tuple[Callable, bytes]):
    fn, job = fn_and_job
    return fn(pickle.loads(job))


def process_map(fn: Callable, jobs: Sequence, workers: int) -> Iterator:
    """``fn(job)`` for each of `jobs`, yielded in the jobs' order as each becomes available; with
    `workers` == 1 (or a single job) in this process, else in at most `workers` processes of the
    platform's default start method (`fn` must be a module-level function and the jobs must
    pickle); `workers` 0 means one per core (`resolve_workers`). Closing the iterator early cancels
    the jobs not yet started."""
    workers = resolve_workers(workers)
    if workers <= 1 or len(jobs) <= 1:
        yield from map(fn, jobs)
        return
    pool = ProcessPoolExecutor(min(workers, len(jobs)), initializer=_one_thread, initargs=(os.getpid(),))
    try:
        yield from pool.map(_call, [(fn, pickle.dumps(job)) for job in jobs])
    finally:
        pool.shutdown(cancel_futures=True)


class JobPool:
    """Jobs handed out one at a time, each ``fn(job)`` in a worker process (as `process_map`'s), for
    callers whose next jobs depend on earlier results: ``with JobPool(workers) as pool: future =
    pool.submit(fn, job)``. With `workers` 1 each job runs in this process as it is submitted (its
    future is already done) unless `processes`; 0 means one per core. Leaving the block cancels the
    jobs not started and stops the ones still running."""

    def __init__(self, workers: int, *, processes: bool = False):
        self.workers = resolve_workers(workers)
        self._pool, self._futures = None, []
        if self.workers > 1 or processes:  # `processes`: worker processes even for one worker (work beside this process's)
            self._pool = ProcessPoolExecutor(self.workers, initializer=_one_thread, initargs=(os.getpid(),))

    def submit(self, fn: Callable, job) -> Future:
        if self._pool is not None:
            future = self._pool.submit(_call, (fn, pickle.dumps(job)))
            self._futures.append(future)
            return future
        future = Future()
        try:
            future.set_result(fn(job))
        except Exception as exc:  # noqa: BLE001 (handed to the caller through the future, as a worker's would be)
            future.set_exception(exc)
        return future

    def __enter__(self) -> "JobPool":
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is None:
            return
        if all(f.done() for f in self._futures):
            self._pool.shutdown(cancel_futures=True)
            return
        # jobs still running that nobody will read (an error or Ctrl-C in the caller): stop them
        processes = list(getattr(self._pool, "_processes", {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
