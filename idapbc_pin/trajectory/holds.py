"""How many swing-up starts each of several laws holds at x*: the one helper of every judgement of
plan-based laws from rest (the swing-up stage's gate, the tracking laws, the manoeuvre), with the
median settling time over the starts, the first start's settling time and, on request, its
RealAIGym v2 score."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from .._parallel import process_map
from ..errors import IdapbcError
from ..sim.integrate import simulate
from ..sim.leaderboard import row_score
from ..sim.metrics import holds, settling_time
from .plans import PLAN_STEP

__all__ = ["Judged", "count_holds", "judge_starts"]


class Judged(NamedTuple):
    """One law judged from a set of starts: `held` of them held at x*; the first start's settling
    time `rest_time` (s; nan: not settled) and v2 score `rest_score` (nan: not asked for, or a
    system without a URDF tip); `median_time`, the median settling time over all starts (s; a start
    not settled counts as ∞)."""

    held: int
    rest_time: float
    rest_score: float
    median_time: float = math.inf


def _first_score(system, traj) -> float:
    """The v2 score of the first row of `traj`; nan for a built-in analytic system (no tip)."""
    try:
        return float(row_score(system, traj, 0).score)
    except IdapbcError:
        return math.nan


def _holds_job(job) -> Judged:
    """Worker: (system, law, x0, T, score) -> its `Judged`."""
    system, law, x0, T, score = job
    torch.set_num_threads(1)
    traj = simulate(system, law, x0, T=T, dt=PLAN_STEP, stop_settled=not score)  # a row settled in the success box holds
    times = settling_time(traj, system)
    return Judged(int(holds(traj, system).sum()), float(times[0]), _first_score(system, traj) if score else math.nan,
                  float(np.median(np.where(np.isnan(times), np.inf, times))))


def judge_starts(system, laws: list, x0: np.ndarray, config, score: bool = False) -> list[Judged]:
    """For each law of `laws` ((N, n) -> (N, m); a stateful one is used once), how many of the starts
    x0 (N, n) it holds at x* over `config.judge_T` (`sim.metrics.holds`: the law held at 500 Hz,
    with the effort limits), the time (s) from which the first start stays in the success box
    (`sim.metrics.settling_time`; nan where it is not there at the end), the median of those times
    over all starts (∞ for a start not there at the end) and, with `score`, the
    first start's v2 score (`sim.leaderboard.row_score`), in `config.workers` processes or Ray
    tasks (`config.ray`)."""
    return list(process_map(_holds_job, [(system, law, x0, config.judge_T, bool(score)) for law in laws], config.workers, config.ray))


def count_holds(system, laws: list, x0: np.ndarray, config) -> list[int]:
    """`judge_starts`' counts of held starts alone."""
    return [judged.held for judged in judge_starts(system, laws, x0, config)]
