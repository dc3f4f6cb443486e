"""How many swing-up starts each of several laws holds at x*: the one helper of the swing-up stage's
judgements (its gate, its tracking laws, its manoeuvre)."""

from __future__ import annotations

import numpy as np
import torch

from .._parallel import process_map
from ..sim.integrate import simulate
from ..sim.metrics import holds
from .plans import PLAN_STEP


def _holds_job(job) -> int:
    """Worker: (system, law, x0, T) -> how many of the starts x0 it holds."""
    system, law, x0, T = job
    torch.set_num_threads(1)
    return int(holds(simulate(system, law, x0, T=T, dt=PLAN_STEP), system).sum())


def count_holds(system, laws: list, x0: np.ndarray, config) -> list[int]:
    """For each law of `laws` ((N, n) -> (N, m); a stateful one is used once), how many of the starts
    x0 (N, n) it holds at x* over `config.judge_T` (`sim.metrics.holds`: the law held at 500 Hz,
    with the effort limits), in `config.workers` processes or Ray tasks (`config.ray`)."""
    return list(process_map(_holds_job, [(system, law, x0, config.judge_T) for law in laws], config.workers, config.ray))
