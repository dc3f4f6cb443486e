"""The cores this process may use, and an ordered map over worker processes or Ray tasks.

`process_map` gives exactly what a loop over the same jobs gives (each job is the same computation
in another process, or as a Ray task on a local instance or a cluster), so the number of workers
and the back-end change the time, never a result. Each worker (and each Ray task) limits itself to
one thread in every OpenMP / BLAS pool (threadpoolctl) and in torch: workers that keep the parent's
thread pools oversubscribe the cores and can run slower than one process. Each job travels as plain
pickle bytes: `concurrent.futures` would otherwise pickle torch tensors with torch.multiprocessing's
reductions, which move the caller's own tensors to shared memory. Ray is an optional extra
(`import_ray`); `init_ray` starts or joins it, for `process_map` and the batch alike.
"""

from __future__ import annotations

import contextlib
import os
import pickle
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Callable, Iterator, Sequence

from .errors import IdapbcError

__all__ = ["MAX_AUTO_WORKERS", "THREAD_ENV", "JobPool", "available_cores", "import_ray", "init_ray", "process_map", "ray_map", "resolve_workers",
           "stop_with_parent", "thread_env"]

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


def _limit_threads() -> None:
    """One thread in torch and in every native thread pool of this process."""
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(1)
    threadpool_limits(1)


def _one_thread(parent: int) -> None:
    """Worker initialiser: `_limit_threads` and `stop_with_parent`."""
    _limit_threads()
    stop_with_parent(parent)


def _call(fn_and_job: tuple[Callable, bytes]):
    fn, job = fn_and_job
    return fn(pickle.loads(job))


def process_map(fn: Callable, jobs: Sequence, workers: int, ray: str | None = None) -> Iterator:
    """``fn(job)`` for each of `jobs`, yielded in the jobs' order as each becomes available; with
    `workers` == 1 (or a single job) in this process, else in at most `workers` processes of the
    platform's default start method (`fn` must be a module-level function and the jobs must
    pickle); `workers` 0 means one per core (`resolve_workers`). With `ray` (``"auto"`` or a
    cluster address) every job is a Ray task instead (`ray_map`). Closing the iterator early cancels
    the jobs not yet started."""
    if ray:
        yield from ray_map(fn, jobs, ray, workers)
        return
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


# ------------------------------------------------------------------------------------ Ray
def import_ray():
    """The `ray` module, or an `IdapbcError` with the install hint when it is not installed."""
    try:
        import ray
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[0] == "ray":
            raise IdapbcError("Ray is not installed. Fix: pip install 'idapbc-pin[ray]'") from None
        raise
    return ray


def init_ray(ray, address: str, workers: int | None) -> None:
    """Start a local Ray instance (``"auto"`` without ``$RAY_ADDRESS``; `workers` CPUs, else every
    available core) or join a cluster (`address`, or ``$RAY_ADDRESS`` for ``"auto"``); a failure
    raises a one-line `IdapbcError`. `ray`: the module (`import_ray`)."""
    try:
        if address == "auto" and not os.environ.get("RAY_ADDRESS"):
            ray.init(address="local", num_cpus=workers or available_cores(), include_dashboard=False, log_to_driver=False)
        else:  # a cluster: the given address, or $RAY_ADDRESS (set by `ray job submit`) for "auto"
            ray.init(address=None if address == "auto" else address, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise IdapbcError(
            f"cannot start or join Ray at '{address}': {first}. Fix: check the address with `ray status` on the head node "
            "(HOST:6379 from a node, ray://HOST:10001 from outside); a cluster with token authentication (the default of recent "
            "`ray start`) also needs RAY_AUTH_MODE=token and its token on this machine."
        ) from None


def _ray_call(fn: Callable, job: bytes) -> bytes:
    """Ray task: `THREAD_ENV` (for pools loaded later) and `_limit_threads`, then ``fn(job)``, as plain
    pickle bytes both ways (a result comes back as a loop's would: writable arrays, not views of
    Ray's object store)."""
    os.environ.update(THREAD_ENV)
    _limit_threads()
    return pickle.dumps(fn(pickle.loads(job)))


def ray_map(fn: Callable, jobs: Sequence, address: str, workers: int = 0) -> Iterator:
    """`process_map` over Ray tasks (one CPU each, one thread: `THREAD_ENV` in their workers'
    environment, `_ray_call`): ``fn(job)`` for each of `jobs`, yielded in the jobs' order. Ray is
    started or joined at `address` (`init_ray`) unless this process is already connected; an instance started here serves every later map and stops when
    the process exits (or at ``ray.shutdown()``). `workers` ≥ 1: at most that many tasks in flight
    (and the CPUs of a local instance started here); 0: as many as Ray schedules. Closing the
    iterator early cancels the tasks not yet finished."""
    ray = import_ray()
    if not jobs:
        return
    if not ray.is_initialized():
        init_ray(ray, address, workers or None)
    remote = ray.remote(num_cpus=1, max_retries=0, runtime_env={"env_vars": dict(THREAD_ENV)})(_ray_call)
    blobs = [pickle.dumps(job) for job in jobs]
    refs = [remote.remote(fn, blob) for blob in blobs[: workers if workers >= 1 else len(blobs)]]
    done = 0
    try:
        while done < len(blobs):
            result = _ray_get(ray, refs[done])
            done += 1
            if len(refs) < len(blobs):
                refs.append(remote.remote(fn, blobs[len(refs)]))
            yield pickle.loads(result)
    finally:
        _cancel(ray, refs[done:])


def _cancel(ray, refs: list) -> None:
    """Cancel the tasks of `refs` that have not finished (a running one is interrupted as Ctrl-C
    would); a finished task is left alone (Ray may fail on cancelling one)."""
    if refs:
        _, running = ray.wait(refs, num_returns=len(refs), timeout=0)
        for ref in running:
            ray.cancel(ref)


def _ray_get(ray, ref):
    """``ray.get(ref)``; an exception the task raised is raised again as itself (not wrapped in
    Ray's `RayTaskError`), so that callers see what a loop would raise."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        cause = getattr(exc, "cause", None)
        if isinstance(cause, BaseException):
            raise cause from None
        raise
