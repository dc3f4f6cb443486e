"""Worker processes (`idapbc_pin._parallel`): what a loop gives, in the same order, one thread each.

Claims:
* `process_map` yields fn(job) in the jobs' order, the same with 1 or 2 workers;
* each worker runs with one thread in torch and in every native pool (OpenBLAS, OpenMP), so that N
  workers use N cores (forked workers that kept the parent's pools were slower, two on 2 cores,
  than one process);
* "0 workers" means one per available core, never fewer than 1 or more than MAX_AUTO_WORKERS.
"""

from __future__ import annotations

import os
import time

import numpy as np

from idapbc_pin._parallel import MAX_AUTO_WORKERS, available_cores, process_map, resolve_workers


def _square_and_pid(k: int) -> tuple[int, int]:
    return k * k, os.getpid()


def _threads(_) -> list[int]:
    import torch
    from threadpoolctl import threadpool_info

    return [torch.get_num_threads()] + [pool["num_threads"] for pool in threadpool_info()]


def test_process_map_yields_what_a_loop_gives_in_the_jobs_order():
    jobs = list(range(7))
    alone = [v for v, _ in process_map(_square_and_pid, jobs, 1)]
    pooled = list(process_map(_square_and_pid, jobs, 2))
    assert alone == [v for v, _ in pooled] == [k * k for k in jobs]
    assert {pid for _, pid in pooled} != {os.getpid()}  # they ran elsewhere


def test_each_worker_has_one_thread_in_torch_and_in_every_native_pool():
    np.ones((64, 64)) @ np.ones((64, 64))  # the caller's pools are loaded (and may hold several threads)
    for counts in process_map(_threads, [0, 1], 2):
        assert counts and set(counts) == {1}


def test_zero_workers_means_one_per_available_core():
    assert resolve_workers(3) == 3
    assert resolve_workers(0) == max(1, min(available_cores(), MAX_AUTO_WORKERS))


def _sleep_then_pid(seconds: float) -> int:
    import time

    time.sleep(seconds)
    return os.getpid()


def test_a_job_pool_runs_inline_with_one_worker_elsewhere_when_asked_and_stops_what_nobody_reads():
    from idapbc_pin._parallel import JobPool

    with JobPool(1) as pool:
        future = pool.submit(_square_and_pid, 3)
        assert future.done() and future.result() == (9, os.getpid())  # in this process, done at once
    with JobPool(1, processes=True) as pool:
        assert pool.submit(_square_and_pid, 4).result()[1] != os.getpid()  # one worker process: beside this one
    started = time.perf_counter()
    with JobPool(1, processes=True) as pool:
        slow = pool.submit(_sleep_then_pid, 30.0)
        while not slow.running():
            time.sleep(0.05)
    assert time.perf_counter() - started < 20.0  # leaving the block stopped the job nobody waited for
