"""A library of short plans from postures all round the circle, read at the nearest point: `horizon_nominals`, `nominals_law`.

A tracking law (`TrackingLaw`) reads one nominal plan by the state. From a posture far from that
plan's path it steers back to the path first, then follows it, which is slow. A library plans from
many starts instead, each with a short horizon:

1. **Starts**: the resting posture and `size` postures at rest with every angle from the full circle
   (`sim.states.circle_states`, a seed of their own), and `moving` states anywhere with every speed
   up to its joint's rating (`sim.states.moving_states`, seed + 1), and `released` states as the
   uptime test's reset drive leaves them (`sim.drive.drive_release_states`, seed + 2): a robot
   released at speed reads knots of a plan that starts moving, not one that brakes to rest first.
2. **Plans**: from each start, iLQR plans of the first of `horizons` s within `share` of the effort
   limits (`ilqr.ilqr_plans`, all starts and warm starts in one batch), warm-started from
   ±sinusoids of `WARM_PERIOD` at four phases and two amplitudes and `WARM_RANDOM` random steps.
   Their cost (`LIBRARY_COST`) prices time: a running cost on the state and a light one on the
   input, the end pinned on every coordinate and reached `settle` s before the end. Each plan is
   tracked by its own iLQR gains and caught by `catch` (the swing-up stage's teacher); of a start's
   plans that hold at x* over `judge_T` and swing up by themselves (their last state within the
   training box's angles of x*: `tracks.reaches`; with `tip`, the tip's normalised height at
   least `tip` there; only plans that end so are rolled out), the cheapest is its nominal. A plan
   that leaves the swing-up to the catch would pull the law's nearest knots towards where it ends,
   away from x*. The swing converges in a few tens of iterations, the pin at x* takes more: with
   `refine`, where no plan of a start ends with its tip at `tip`, its `REFINE_KEEP` cheapest are
   solved that many iterations further (a start with a plan that ends up keeps its plans as
   solved). The starts left without a nominal are planned again with each further horizon in
   turn, without `tip` and `refine`: a robot with long, heavy links cannot swing up from most
   postures in the time a small one needs, and the library would otherwise cover few of them.
3. **The law**: each nominal with its time-varying LQR gains (`tracks.tvlqr_gains`) in x = (q, p)
   (`tracks.tracking_law`), every knot of every nominal in one `TrackingLaw`. The law is the same
   kind as any tracking law (the same arrays, the same export); it reads the nearest point over all
   the knots.

The starts are planned in chunks of `CHUNK` over `workers` processes; the chunks and their order fix
the result, the number of workers only the time.

`paths_law` builds the same kind of law from recorded closed-loop paths instead of fresh plans (the
reach stage's labels: plans tracked and caught, sampled every knot): each path with the gains of a
time-varying LQR along it, every point of every path read at the nearest point, a funnel library
(Tedrake et al. 2010, LQR-trees; Reist, Preiskorn & Tedrake 2016, simulation-based LQR-trees).
"""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
from tqdm.auto import tqdm

from .._parallel import process_map
from ..control.baseline import LQRController
from ..sim.drive import drive_release_states
from ..sim.integrate import simulate
from ..sim.leaderboard import tip_share
from ..sim.metrics import holds
from ..sim.states import circle_states, moving_states
from .ilqr import ILQRSettings, ilqr_plans
from .plans import PLAN_STEP, TrackThenLaw, plan_bound
from .tracking_law import TrackingLaw
from .tracks import ALPHAS, KNOT, reaches, sound, tracking_law, tvlqr_gains, warm_starts

__all__ = ["CHUNK", "LIBRARY_COST", "REFINE_KEEP", "RETRY_SEED", "WARM_PERIOD", "WARM_RANDOM", "horizon_nominals", "library_nominals", "library_starts", "nominals_law",
           "paths_law"]

#: The library's plan cost (`ilqr.ILQRSettings` fields): time priced above torque, at rest at x* at the end.
LIBRARY_COST = {"q": 1.0, "r": 1.0, "end_box": 1000.0, "settle": 0.3}
#: Period (s) of the sinusoidal warm starts, and the number of random ones, per start.
WARM_PERIOD, WARM_RANDOM = 1.0, 2
#: Starts planned together in one batch (one worker job).
CHUNK = 16
#: Seed offset of each further horizon's warm starts (`horizon_nominals`).
RETRY_SEED = 1000
#: Plans of each start (its cheapest) that the refining iterations solve further (`library_nominals`' `refine`).
REFINE_KEEP = 2


def library_starts(system, size: int, seed: int, moving: int = 0, released: int = 0) -> np.ndarray:
    """(size + 1 + moving + released, n) states (q, p): the resting posture, then `size` postures at
    rest with every angle from the full circle (`circle_states` with `seed`), then `moving` states
    anywhere with every speed up to its joint's URDF rating (`moving_states` with seed + 1), then
    `released` states as the uptime test's reset drive leaves them (`drive_release_states` with
    seed + 2)."""
    starts = [circle_states(system, int(size) + 1, seed)]
    if int(moving) > 0:
        starts.append(moving_states(system, int(moving), seed + 1))
    if int(released) > 0:
        starts.append(drive_release_states(system, int(released), seed + 2))
    return np.concatenate(starts)


def _chunk_nominals(job) -> list:
    """Worker: (system, catch, starts (S, n), horizon, share, iterations, refine, tip, judge_T, seed,
    speed) -> for each start, (U (K, m), Z (K + 1, n) in (q, v)) of its cheapest plan that holds and
    reaches, or None (refine: further iterations of the `REFINE_KEEP` cheapest plans of each start
    none of whose plans ends with the tip at `tip` (every start where tip is 0); tip:
    the tip's normalised height each plan must end at, 0 for none; speed: ρ_v of `ilqr`'s speed
    term, 0 for none)."""
    system, catch, starts, horizon, share, iterations, refine, tip, judge_T, seed, speed = job
    bound = share * plan_bound(system)
    K = max(1, int(round(horizon / KNOT)))
    W = warm_starts(K, bound, seed, periods=(WARM_PERIOD,), n_random=WARM_RANDOM)
    w = len(W)
    x0 = np.repeat(starts, w, axis=0)
    settings = ILQRSettings(iterations=iterations, alphas=ALPHAS, speed=speed, **LIBRARY_COST)
    S = LQRController(system).S
    U, Z, gains, cost = ilqr_plans(system, x0, np.tile(W, (len(starts), 1, 1)), bound, K * KNOT, S, settings)
    short = np.zeros(len(starts), bool) if refine <= 0 else np.ones(len(starts), bool) if tip <= 0 else \
        (tip_share(system, Z[:, -1, :system.nq]) < tip).reshape(len(starts), w).all(axis=1)
    if short.any():  # where 40 iterations leave every plan of a start short of the pin at x*, its cheapest are solved further
        first = np.argsort(cost.reshape(len(starts), w), axis=1, kind="stable")[:, :REFINE_KEEP] + w * np.arange(len(starts))[:, None]
        best = np.sort(first[short], axis=1).ravel()
        U[best], Z[best], gains[best], cost[best] = ilqr_plans(system, x0[best], U[best], bound, K * KNOT, S, replace(settings, iterations=refine))
    ends = reaches(system, Z[:, -1]) & sound(Z)  # the plan itself swings up; a plan that leaves it to the catch is no library entry
    if tip > 0:  # and ends up: a plan cut short of its pin would leave the last of the swing-up to the catch
        ends &= tip_share(system, Z[:, -1, :system.nq]) >= tip
    held = np.zeros(len(x0), bool)
    rows = np.flatnonzero(ends)  # only these are judged: a row's rollout does not depend on the others (to the last bits, `simulate`)
    if rows.size:
        tracked = TrackThenLaw(U[rows], Z[rows], gains[rows], KNOT, catch, system)
        held[rows] = holds(simulate(system, tracked, x0[rows], T=judge_T, dt=PLAN_STEP, stop_settled=True), system)
    out = []
    for s in range(len(starts)):
        rows = [i for i in range(s * w, (s + 1) * w) if held[i]]
        best = min(rows, key=lambda i: (cost[i], i)) if rows else None
        out.append(None if best is None else (U[best], Z[best]))
    return out


def library_nominals(system, catch, starts: np.ndarray, horizon: float, share: float, iterations: int, judge_T: float, seed: int,
                     workers: int = 1, progress: str | None = None, speed: float = 0.0, refine: int = 0, tip: float = 0.0) -> list:
    """Step 2 of the module docstring: for each start of `starts` (S, n), its nominal (U, Z), or None
    where no plan holds; chunks of `CHUNK` starts in `workers` processes (0: one per core);
    `progress`: the label of a bar over the chunks (None: no bar)."""
    chunks = [starts[i: i + CHUNK] for i in range(0, len(starts), CHUNK)]
    jobs = [(system, catch, c, float(horizon), float(share), int(iterations), int(refine), float(tip), float(judge_T), int(seed) + k, float(speed)) for k, c in enumerate(chunks)]
    bar = tqdm(total=len(jobs), desc=progress, unit="chunk", disable=progress is None, dynamic_ncols=True, file=sys.stderr)
    out = []
    for found in process_map(_chunk_nominals, jobs, workers):
        out += found
        bar.update(1)
    bar.close()
    return out


def horizon_nominals(system, catch, starts: np.ndarray, horizons, share: float, iterations: int, judge_T: float, seed: int,
                     workers: int = 1, progress: str | None = None, speed: float = 0.0, refine: int = 0,
                     tip: float = 0.0) -> tuple[list, list[int]]:
    """Step 2 of the module docstring over several horizons: every start of `starts` (S, n) planned
    with horizons[0] s, then the starts still without a nominal with each further horizon in turn
    (pass j drawing warm starts from seed + `RETRY_SEED`·j). `refine` and `tip` apply to the first
    horizon's plans only: a longer plan is a start's fallback where the robot cannot swing up in
    the first, and its loose end leaves a few knots to the catch rather than the start uncovered.
    Returns (for each start its nominal (U, Z) or None; for each start the index of the horizon
    that gave it, or −1)."""
    out, passes = [None] * len(starts), [-1] * len(starts)
    for j, horizon in enumerate(horizons):
        todo = [s for s, nominal in enumerate(out) if nominal is None]
        if not todo:
            break
        found = library_nominals(system, catch, starts[todo], horizon, share, iterations, judge_T, seed + RETRY_SEED * j, workers,
                                 None if progress is None else f"{progress} ({horizon:g} s)", speed, refine if j == 0 else 0, tip if j == 0 else 0.0)
        for s, nominal in zip(todo, found):
            if nominal is not None:
                out[s], passes[s] = nominal, j
    return out, passes


def nominals_law(system, nominals: list, box: np.ndarray, speed_weight: float) -> TrackingLaw | None:
    """Step 3 of the module docstring: every knot of the `nominals` [(U, Z)] with its time-varying LQR
    gains in one `TrackingLaw` with the kept `box` (n,), the nearest-point distance weighing momenta
    `speed_weight` / M_ii(q*); None where there is no nominal."""
    if not nominals:
        return None
    return TrackingLaw.join([tracking_law(system, U, Z, tvlqr_gains(system, U, Z), speed_weight, box) for U, Z in nominals])


def paths_law(system, X: np.ndarray, U: np.ndarray, speed_weight: float, box: np.ndarray) -> TrackingLaw:
    """One `TrackingLaw` over recorded paths: X (P, L, n) states in x = (q, p) every `KNOT` seconds and
    U (P, L, m) the inputs applied from each (N·m or N); each path's last state ends its plan. Each
    path gets the gains of a time-varying LQR along it (`tracks.tvlqr_gains`, its inputs taken as
    held over each knot), all read at the nearest point with momenta weighted
    `speed_weight` / M_ii(q*) and the kept `box` (n,) (∞: every state is the law's)."""
    X, U = np.asarray(X, dtype=np.float64), np.asarray(U, dtype=np.float64)
    nq = system.nq
    laws = []
    for x, u in zip(X, U):
        v = np.linalg.solve(system.mass_matrix(x[:, :nq]), x[:, nq:, None])[..., 0]
        Z = np.concatenate([x[:, :nq], v], axis=1)
        laws.append(tracking_law(system, u[:-1], Z, tvlqr_gains(system, u[:-1], Z), speed_weight, box))
    return TrackingLaw.join(laws)
