"""How many swing-up starts each of several laws holds at x*: the one helper of the swing-up stage's
judgements (its gate, its tracking laws, its manoeuvre), with the settling time of the first start."""

from __future__ import annotations

import numpy as np
import torch

from .._parallel import process_map
from ..sim.integrate import simulate
from ..sim.metrics import holds, settling_time
from .plans import PLAN_STEP


def _holds_job(job) -> tuple[int, float]:
    """Worker: (system, law, x0, T) -> (how many of the starts x0 it holds, the settling time of x0[0], s)."""
    system, law, x0, T = job
    torch.set_num_threads(1)
    traj = simulate(system, law, x0, T=T, dt=PLAN_STEP)
    return int(holds(traj, system).sum()), float(settling_time(traj, system)[0])


def judge_starts(system, laws: list, x0: np.ndarray, config) -> list[tuple[int, float]]:
    """For each law of `laws` ((N, n) -> (N, m); a stateful one is used once), how many of the starts
    x0 (N, n) it holds at x* over `config.judge_T` (`sim.metrics.holds`: the law held at 500 Hz,
    with the effort limits), and the time (s) from which the first start stays in the success box
    (`sim.metrics.settling_time`; nan where it is not there at the end), in `config.workers`
    processes or Ray tasks (`config.ray`)."""
    return list(process_map(_holds_job, [(system, law, x0, config.judge_T) for law in laws], config.workers, config.ray))


def count_holds(system, laws: list, x0: np.ndarray, config) -> list[int]:
    """`judge_starts`' counts of held starts alone."""
    return [held for held, _ in judge_starts(system, laws, x0, config)]
