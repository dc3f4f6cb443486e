"""Where the jobs of a batch run: in this process, in local worker processes, or as Ray tasks.

All three run the same `run_job`, with one torch thread (and one OpenMP / MKL / BLAS thread) per
job, so N workers use N cores and the same seeds give the same results whichever runs them. A
worker that dies (killed, out of memory, segfault) fails its job only: the driver writes that
job's ``job.json``. A driver that dies on its own (SIGTERM or SIGKILL to it alone) takes its local
workers with it: each interrupts its job as Ctrl-C would (`idapbc_pin._parallel.stop_with_parent`).
Ray is an optional extra, imported and started or joined as for every other fan-out
(`idapbc_pin._parallel.import_ray`, `init_ray`); a remote node that cannot see the batch directory
ships its job directory back as an archive (`idapbc_pin.batch._shipping`).
"""

from __future__ import annotations

import multiprocessing
import os
import shutil
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from .._io import write_json
from .._parallel import THREAD_ENV, available_cores, import_ray, init_ray, stop_with_parent, thread_env
from ._shipping import unpack_dir
from .job import run_job
from .pipeline import Job
from .progress import Tracker
from .record import crash_record

__all__ = ["THREAD_ENV", "describe_executor", "import_ray", "run_jobs"]

def _local_workers(workers: int | None, n_jobs: int) -> int:
    """Jobs at a time on this machine: `workers`, else one per core and at most one per job."""
    return workers or max(1, min(available_cores(), n_jobs))


def describe_executor(workers: int | None, ray: str | None, n_jobs: int) -> str:
    """``"ray ADDRESS"``, ``"in-process"`` or ``"N worker processes"``: what `run_jobs` will use."""
    n_workers = _local_workers(workers, n_jobs)
    return f"ray {ray}" if ray else ("in-process" if n_workers == 1 else f"{n_workers} worker processes")


def run_jobs(jobs: list[Job], batch_dir: Path, tracker: Tracker, workers: int | None, ray: str | None, token: str) -> None:
    """Run `jobs` into ``batch_dir/<job name>``, reporting each start and end to `tracker`.

    workers : jobs at a time (None: one per core, at most one per job; with Ray, the cluster's
        CPUs). ray : None (local), ``"auto"`` or a cluster address. token : the batch's token
        (``batch.json``), by which a Ray worker knows whether it sees the batch directory.
    """
    if not jobs:
        return
    n_workers = _local_workers(workers, len(jobs))
    if ray:
        _run_ray(jobs, batch_dir, tracker, ray, workers, token)
    elif n_workers == 1:  # one job at a time: its recover stage may take every core
        for job in jobs:
            tracker.started(job)
            tracker.finished(job, run_job(job, batch_dir / job.name, recover_workers=0))
    else:
        _run_pool(jobs, batch_dir, tracker, n_workers)


def _record_crash(job: Job, batch_dir: Path, message: str) -> dict:
    record = crash_record(job, message)
    (batch_dir / job.name).mkdir(parents=True, exist_ok=True)
    write_json(batch_dir / job.name / "job.json", record)
    return record


def _run_pool(jobs: list[Job], batch_dir: Path, tracker: Tracker, workers: int) -> None:
    """Spawned worker processes, at most `workers` jobs in flight; a dead worker fails its jobs only."""
    queue = list(jobs)
    ctx = multiprocessing.get_context("spawn")
    with thread_env():  # inherited by the spawned workers before they import torch
        while queue:
            pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=stop_with_parent, initargs=(os.getpid(),))
            inflight = {}
            broken = False
            try:
                while (queue and not broken) or inflight:
                    while queue and not broken and len(inflight) < workers:
                        job = queue.pop(0)
                        inflight[pool.submit(run_job, job, str(batch_dir / job.name))] = job
                        tracker.started(job)
                    done, _ = wait(inflight, return_when=FIRST_COMPLETED)
                    for fut in done:
                        job = inflight.pop(fut)
                        try:
                            record = fut.result()
                        except KeyboardInterrupt:
                            raise
                        except Exception as exc:  # BrokenProcessPool: the worker died
                            broken = True
                            record = _record_crash(job, batch_dir, f"worker process died ({type(exc).__name__}: {exc}); the job's files may be incomplete")
                        tracker.finished(job, record)
            finally:
                pool.shutdown(wait=True, cancel_futures=True)


def _run_ray(jobs: list[Job], batch_dir: Path, tracker: Tracker, address: str, workers: int | None, token: str) -> None:
    """Ray tasks (num_cpus=1 each) running the same `run_job`; results that a remote node wrote
    into its own temporary folder come back as an archive and are unpacked here."""
    ray = import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        init_ray(ray, address, workers)
    try:
        limit = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        remote = ray.remote(num_cpus=1, max_retries=0)(run_job)
        queue, inflight = list(jobs), {}
        try:
            while queue or inflight:
                while queue and len(inflight) < limit:
                    job = queue.pop(0)
                    inflight[remote.remote(job, str(batch_dir / job.name), token)] = job
                    tracker.started(job)
                ready, _ = ray.wait(list(inflight), num_returns=1)
                for ref in ready:
                    job = inflight.pop(ref)
                    try:
                        record = ray.get(ref)
                    except Exception as exc:  # the worker died, or the task raised past run_job
                        record = _record_crash(job, batch_dir, f"Ray task failed ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})")
                    archive = record.pop("_archive", None)
                    if archive is not None:
                        shutil.rmtree(batch_dir / job.name, ignore_errors=True)
                        unpack_dir(archive, batch_dir / job.name)
                    tracker.finished(job, record)
        except KeyboardInterrupt:
            for ref in inflight:
                ray.cancel(ref, force=True)
            raise
    finally:
        if started_here:
            ray.shutdown()
