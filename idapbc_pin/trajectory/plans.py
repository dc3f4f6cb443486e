"""Torque plans within the effort limits: `PlanSettings`, `PlanThenLaw`, `TrackThenLaw`,
`plan_candidates`, `search_plans`, `plan_bound`.

Where a saturated law loses a state, a short plan may still bring it to x*: inputs over the first
`horizon` seconds, then a feedback law takes over. Two searches find them (`PlanSettings.method`):

* ``"ilqr"`` (the default): iterative LQR on the model's exact derivatives (`trajectory.ilqr`), with
  knots of `knot_step` seconds, from ten warm starts per state (the feedback law's own failed
  inputs, no input, and swings at ±ū of four periods), all states and warm starts solved together.
  The cost prices the distance to x* along the way (`q`) and pins the end (`end_box`), beside the
  end cost of LQR's Riccati matrix: with the end cost alone, the solves from starts far from x* stall
  where the pendulums hang. The line search tries six step sizes down to 0.01, and a chain of three
  joints gets more iterations (`PlanSettings.iterations`).
  Each candidate runs as a time-varying LQR along its planned trajectory (`TrackThenLaw`), which
  absorbs the model's coarser integration; with `hold`, the tracked input is computed at each
  knot's start and held over the knot, the policy the solver's line search rolled out (its gains are
  those of the knot-to-knot map); the judge keeps the best candidate that reaches x*.
* ``"cem"``: a cross-entropy search (Rubinstein 1999) of piecewise-constant open-loop inputs over
  `knots` intervals: `population` plans per iteration drawn around a mean, the best eighth refits
  the mean and spread, `iterations` times, each plan scored by the distance to x* after `score_T`
  seconds (wrapped angle errors plus 0.3 × the speeds; a diverged rollout scores 1e3). It needs
  hundreds of rollouts per plan; kept for comparison (`benchmarks/bench_plans.py`) and for
  `benchmarks/bench_recoverable.py`.

Plans are per state: they are the labels a recovery law is fitted to (`recovery.stage`), and a lower
bound on what the limited actuator can do. An input without an effort limit is planned within LQR's
largest demand on the training box instead (`plan_bound`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..control.baseline import LQRController
from ..errors import IdapbcError
from ..model.angles import wrap_angles
from ..sim.integrate import simulate
from .ilqr import SPEED_WEIGHT, ILQRSettings, ilqr_plans

__all__ = ["METHODS", "PLAN_STEP", "PlanSettings", "PlanThenLaw", "TrackThenLaw", "plan_bound", "plan_candidates", "planning_system", "search_plan", "search_plans"]

#: Periods (s) of the swings ±ū sin(2π t / period) that warm-start the iLQR solves (`_warm_starts`).
PERIODS = (3.0, 2.0, 1.5, 1.0)
#: Searches of a plan (`PlanSettings.method`).
METHODS = ("ilqr", "cem")

#: The control period of a plan and of the law after it, s: the judge's (the law held at 500 Hz).
PLAN_STEP = 0.002
#: Step sizes of the line search of the reach plans, largest first.
REACH_ALPHAS = (1.0, 0.5, 0.25, 0.1, 0.03, 0.01)
#: iLQR iterations of a reach plan when `PlanSettings.ilqr_iterations` is 0: (at most two joints, three or more).
AUTO_ITERATIONS = (30, 100)


@dataclass(frozen=True)
class PlanSettings:
    """The search of the plans.

    Attributes
    ----------
    method : ``"ilqr"`` (iterative LQR from warm starts, tracked) or ``"cem"`` (cross-entropy search).
    horizon : length of the plan, s; the feedback law acts after it.
    knot_step : ilqr: length of a knot, s (a multiple of PLAN_STEP).
    ilqr_iterations : ilqr: iterations of each solve; 0: `AUTO_ITERATIONS` by the number of joints.
    substeps : ilqr: RK4 steps of the model per knot.
    q : ilqr: weight of the running state cost (`ilqr.ILQRSettings.q`).
    end_box : ilqr: weight of the end cost's box term (`ilqr.ILQRSettings.end_box`).
    alphas : ilqr: step sizes of the line search, largest first.
    hold : ilqr: track each candidate with its input held over each knot (`TrackThenLaw`).
    speed_limits : ilqr: bound each actuated joint's planned speed by its URDF `<limit velocity>`
        (the speed term of `ilqr`, weight `ilqr.SPEED_WEIGHT`).
    knots : cem: pieces of the piecewise-constant plan.
    population : cem: plans simulated per iteration.
    iterations : cem: cross-entropy iterations.
    score_T : cem: simulated time of a plan's score, s.
    """

    method: str = "ilqr"
    horizon: float = 2.0
    knot_step: float = 0.02
    ilqr_iterations: int = 0
    substeps: int = 1
    q: float = 1.0
    end_box: float = 100.0
    alphas: tuple = REACH_ALPHAS
    hold: bool = True
    speed_limits: bool = False
    knots: int = 20
    population: int = 48
    iterations: int = 8
    score_T: float = 6.0

    def __post_init__(self):
        ticks = self.knot_step / PLAN_STEP
        if (self.method not in METHODS or not (self.horizon > 0 and ticks >= 1 and abs(ticks - round(ticks)) < 1e-9)
                or min(self.knots, self.population, self.iterations, self.substeps) < 1 or self.ilqr_iterations < 0
                or min(self.q, self.end_box) < 0 or not self.alphas or not all(0 < a <= 1 for a in self.alphas)):
            raise IdapbcError(f"bad plan setting: method must be one of {', '.join(METHODS)}, horizon > 0, knot_step a multiple of "
                              f"{PLAN_STEP} s, knots, population, iterations and substeps ≥ 1, ilqr_iterations, q and end_box ≥ 0, "
                              "alphas step sizes in (0, 1]. Fix: pass valid values.")

    def solver(self, system) -> ILQRSettings:
        """The `ILQRSettings` of the solves for `system`: this plan's iterations (`AUTO_ITERATIONS`
        by its joints when 0), substeps, running cost, end box, step sizes and speed term."""
        its = self.ilqr_iterations or AUTO_ITERATIONS[int(system.nq > 2)]
        return ILQRSettings(iterations=its, substeps=self.substeps, q=self.q, end_box=self.end_box, alphas=tuple(self.alphas),
                            speed=SPEED_WEIGHT if self.speed_limits else 0.0)

    @property
    def ilqr_knots(self) -> int:
        """Knots of an iLQR plan: horizon / knot_step, rounded up."""
        return max(1, int(np.ceil(self.horizon / self.knot_step - 1e-9)))


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



class TrackThenLaw:
    """u = U[:, k] + gains[:, k] wrap(z − Z[:, k]), z = (q, v), during knot k (of `knot_step` s) of
    a plan: a time-varying LQR along the planned trajectory (`ilqr.ilqr_plans`); then `law`. The
    judge's effort limits saturate both. Called once per tick by `simulate` with the law held (its
    default), which advances the tick: use a fresh instance per simulation.

    U (N, K, m) inputs, Z (N, K + 1, n) planned states in (q, v), gains (N, K, m, n); `system`
    splits the states (q, p) the judge passes into (q, v). `hold`: the input is computed at the first
    tick of each knot and held over the knot, as the solver rolled the plan out (else at every tick,
    against Z[:, k] all knot long, so the plan's own motion within a knot reads as an error).
    """

    def __init__(self, U, Z, gains, knot_step: float, law, system, hold: bool = False):
        self.U, self.Z, self.gains, self.law, self.system, self.tick = U, Z, gains, law, system, 0
        self.per_knot = int(round(knot_step / PLAN_STEP))
        self.mask = np.asarray(system.angle_mask, bool)
        self.hold, self._held = bool(hold), None

    @property
    def horizon(self) -> float:
        """Length of the plan, s."""
        return self.U.shape[1] * self.per_knot * PLAN_STEP

    def __call__(self, x):
        k, within = divmod(self.tick, self.per_knot)
        self.tick += 1
        if k < self.U.shape[1]:
            if self.hold and within and self._held is not None:
                return self._held.copy()
            z = np.concatenate(self.system.split(x), axis=1)
            u = self.U[:, k] + np.einsum("nij,nj->ni", self.gains[:, k], wrap_angles(z - self.Z[:, k], self.mask))
            self._held = u
            return u.copy() if self.hold else u
        return self.law(x)


def _warm_starts(failed_u: np.ndarray, bound: np.ndarray, K: int, knot_step: float) -> list[np.ndarray]:
    """Warm starts (S, K, m) of the iLQR solves from the feedback law's inputs (S, T, m) of its
    failed rollouts (held every PLAN_STEP): those inputs at the knots, no input, and swings
    ±ū sin(2π t / period) of each period in PERIODS. Each solve ends in the local minimum its warm
    start leads to, and which one brings a start to x* varies from start to start: diversity is
    what the candidates buy."""
    S, m = failed_u.shape[0], bound.size
    ticks = np.minimum(np.arange(K) * int(round(knot_step / PLAN_STEP)), failed_u.shape[1] - 1)
    t = np.arange(K) * knot_step
    starts = [np.clip(failed_u[:, ticks], -bound, bound), np.zeros((S, K, m))]
    for period in PERIODS:
        swing = np.broadcast_to(bound * np.sin(2 * np.pi * t / period)[:, None], (S, K, m))
        starts += [swing.copy(), -swing]
    return starts


def plan_candidates(system, x0: np.ndarray, failed_u: np.ndarray, bound: np.ndarray, settings: PlanSettings):
    """iLQR candidates for the starts x0 (S, n) that a feedback law lost, from its inputs failed_u
    (S, T, m) there: (starts (S·C, n), U (S·C, K, m), Z (S·C, K + 1, n) in (q, v), gains (S·C, K, m, n)), the
    C warm starts of `_warm_starts` for start s at rows s, S + s, 2S + s, … . S: LQR's Riccati matrix
    weighs the end state."""
    K = settings.ilqr_knots
    W = _warm_starts(failed_u, bound, K, settings.knot_step)
    starts = np.concatenate([x0] * len(W))
    S = LQRController(system).S
    U, Z, gains, _ = ilqr_plans(system, starts, np.concatenate(W), bound, K * settings.knot_step, S, settings.solver(system))
    return starts, U, Z, gains
