"""`compare_laws`: the one helper every gate uses to judge candidate laws from the same states.

A gate (after training, in the recovery stage, after rollout epochs) simulates several laws from the
same fresh states on the true plant with its effort limits and keeps the best. Each run here is a
(law, x0) pair; the runs go to worker processes or Ray tasks (`idapbc_pin._parallel.process_map`:
the count and the back-end change the time, never a verdict) and come back in order.
"""

from __future__ import annotations

from typing import Callable, Iterator, Sequence

import numpy as np
import torch

from .._parallel import process_map
from .integrate import simulate
from .metrics import success

__all__ = ["compare_laws"]


def _judge(job) -> tuple[np.ndarray, np.ndarray | None]:
    """Worker: job = (system, law, x0, T, dt, box, stop_settled) -> ((N,) bool success, (N,) bool
    left `box` at one of the samples, or None without a box)."""
    system, law, x0, T, dt, box, stop_settled = job
    torch.set_num_threads(1)
    traj = simulate(system, law, x0, T=T, dt=dt, limits=True, stop_settled=stop_settled, stop_converged=stop_settled)
    return success(traj, system), (None if box is None else box.outside(traj.x).any(axis=1))


def compare_laws(
    system,
    runs: Sequence[tuple[Callable, np.ndarray]],
    *,
    T: float = 20.0,
    dt: float,
    workers: int = 1,
    ray: str | None = None,
    box=None,
    stop_settled: bool = True,
) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
    """The success of each (law, x0) of `runs` on `system` with its effort limits (DESIGN §4).

    system : the true plant; law : a controller (N, n) -> (N, m); x0 : (N, n) start states.
    workers, ray : worker processes (0: one per core) or, with ray (``"auto"`` or an address), Ray
    tasks (`process_map`).
    T, dt : horizon and RK4 step, s. box : an object with ``outside(x) -> (N, K) bool`` (a
    `BoxFallback`); with it each run also says which trajectories left that box at a sample.
    stop_settled : a row that has rested in the success box for the success window, or has entered
    its loop's terminal set, is integrated no further (its verdict is known then; `simulate`); False
    integrates every row for the whole horizon. The laws must not depend on time.

    Yields, in the order of `runs` as each finishes: ((N,) bool success, (N,) bool left or None).
    """
    jobs = [(system, law, x0, T, dt, box, stop_settled) for law, x0 in runs]
    yield from process_map(_judge, jobs, workers, ray)
