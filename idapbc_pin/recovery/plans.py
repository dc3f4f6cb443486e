"""Open-loop torque plans within the effort limits: `PlanSettings`, `PlanThenLaw`, `search_plan`,
`plan_bound`.

Where a saturated law loses a state, a short plan may still bring it to x*: piecewise-constant
inputs over `knots` intervals of the first `horizon` seconds, then a feedback law (saturated LQR)
takes over. The plan is found by a cross-entropy search (Rubinstein 1999): `population` plans per
iteration drawn around a mean, the best eighth refits the mean and spread, `iterations` times. A
plan is scored by the distance to x* after `score_T` seconds (wrapped angle errors plus 0.3 × the
speeds; a diverged rollout scores 1e3). Plans are per state and open loop: they are the labels a
recovery law is fitted to (`recovery.stage`), and a lower bound on what the limited actuator can
do (`benchmarks/bench_recoverable.py`). An input without an effort limit is planned within
LQR's largest demand on the training box instead (`plan_bound`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..control.baseline import LQRController
from ..model.angles import wrap_angles
from ..sim.integrate import simulate

__all__ = ["PLAN_STEP", "PlanSettings", "PlanThenLaw", "plan_bound", "planning_system", "search_plan", "search_plans"]

#: The control period of a plan and of the law after it, s: the judge's (the law held at 500 Hz).
PLAN_STEP = 0.002


@dataclass(frozen=True)
class PlanSettings:
    """The cross-entropy search of one plan.

    Attributes
    ----------
    horizon : length of the plan, s; the feedback law acts after it.
    knots : pieces of the piecewise-constant plan.
    population : plans simulated per iteration.
    iterations : cross-entropy iterations.
    score_T : simulated time of a plan's score, s.
    """

    horizon: float = 2.0
    knots: int = 20
    population: int = 48
    iterations: int = 8
    score_T: float = 6.0


class PlanThenLaw:
    """u = plan[:, :, k] during tick k·PLAN_STEP < horizon (one plan per row of the batch), then
    `law`; the judge's effort limits saturate both. Called once per tick by `simulate` with the law
    held (its default), which advances the tick: use a fresh instance per simulation.

    plan : (N, m, knots) inputs, N·m or N.
    """

    def __init__(self, plan: np.ndarray, horizon: float, law):
        self.plan, self.horizon, self.law, self.tick = plan, horizon, law, 0

    def __call__(self, x):
        k = int(self.tick * PLAN_STEP * self.plan.shape[2] / self.horizon)
        self.tick += 1
        if k < self.plan.shape[2]:
            return self.plan[:, :, k].copy()
        return self.law(x)


def plan_bound(system) -> np.ndarray:
    """ū (m,) of the plans and of a recovery law, N·m or N: the effort limit of each input, and for an
    input without one the largest |u| that LQR (Q = I, R = I) asks in the training box,
    |u*_i| + Σ_j |K_ij| s_j with s_j the box's larger extent from x* along j (a linear law peaks at
    a corner; equal to that peak for a box centred on x* with u* = 0, a bound above it otherwise).
    A robot given no limits (the paper's built-in systems) still gets plans of the size its own
    linear law uses."""
    effort = np.asarray(system.effort, dtype=np.float64)
    if np.isfinite(effort).all():
        return effort
    lqr = LQRController(system)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in system.domain)
    x_star = np.asarray(system.x_star, dtype=np.float64)
    reach = np.abs(np.atleast_1d(lqr.u_star)) + np.abs(lqr.K) @ np.maximum(hi - x_star, x_star - lo)
    return np.where(np.isfinite(effort), effort, reach)


def planning_system(system):
    """`system` with every effort limit finite: its own limits, `plan_bound` where it has none (the
    same object when every input is limited). Plans, labels and the recovery law's fit use it."""
    bound = plan_bound(system)
    return system if np.array_equal(bound, system.effort) else replace(system, effort=bound)


def _score(system, traj) -> np.ndarray:
    d = wrap_angles(traj.x[:, -1] - system.x_star, system.angle_mask)[:, : system.nq]
    return np.where(traj.diverged, 1e3, np.abs(d).sum(1) + 0.3 * np.abs(traj.v[:, -1]).sum(1))


def search_plan(system, law, x0: np.ndarray, bound: np.ndarray, settings: PlanSettings, rng: np.random.Generator) -> np.ndarray:
    """The best (1, m, knots) plan found for the start state x0 (n,) within ±bound (m,), then `law`."""
    return search_plans(system, law, x0[None], bound, settings, [rng])


def search_plans(system, law, x0: np.ndarray, bound: np.ndarray, settings: PlanSettings, rngs) -> np.ndarray:
    """The best plans (S, m, knots) for the start states x0 (S, n) within ±bound (m,), then `law`.

    One cross-entropy search per start, all S advanced together: each iteration simulates the
    S·population candidates in one batch (the per-tick cost of `simulate` is mostly fixed, so S
    starts cost far less than S calls). Start s draws only from ``rngs[s]``, in the same order as a
    search of that start alone, and its elite statistics are its own, so the plans are those of S
    separate searches (bit for bit wherever the feedback law's arithmetic does not depend on the
    batch: numpy's matrix product may round a row differently in a batch of another size; no
    difference was seen on batches of whole populations, `benchmarks/bench_plans.py`).
    """
    S, P, n_elite = len(x0), settings.population, settings.population // 8
    lo, hi = -bound[:, None], bound[:, None]
    mean = np.zeros((S, system.m, settings.knots))
    std = np.broadcast_to(bound[:, None], mean.shape).copy()
    best, best_cost = mean.copy(), np.full(S, np.inf)
    for _ in range(settings.iterations):
        plans = np.stack([np.clip(mean[s] + std[s] * rngs[s].standard_normal((P,) + mean.shape[1:]), lo, hi) for s in range(S)])
        starts = np.repeat(x0, P, 0)
        traj = simulate(system, PlanThenLaw(plans.reshape((S * P,) + mean.shape[1:]), settings.horizon, law), starts, T=settings.score_T, dt=PLAN_STEP)
        cost = _score(system, traj).reshape(S, P)
        for s in range(S):
            elite = plans[s][np.argsort(cost[s])[:n_elite]]
            if cost[s].min() < best_cost[s]:
                best[s], best_cost[s] = plans[s][np.argmin(cost[s])], float(cost[s].min())
            mean[s], std[s] = elite.mean(0), elite.std(0) + 0.04 * bound[:, None]
    return best
