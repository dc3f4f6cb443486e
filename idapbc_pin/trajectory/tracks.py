"""Tracking laws from the resting posture: nominal swing-ups planned within the limits, tracked by a
time-varying LQR read at the nearest point (`TrackingLaw`): `tracking_laws`.

1. **Nominals.** iLQR plans (`ilqr.ilqr_plans`) of `SwingUpConfig.horizon` seconds from the exact
   resting posture, with the inputs held to `track_share` of the effort limits (the rest is left to
   the feedback), warm-started from `WARM_PERIODS` sinusoids at four phases and two amplitudes and
   from `WARM_RANDOM` random steps of 0.2 s (with `speed_limits`, each motor's planned speed bounded by
   its URDF rating: `ilqr`'s speed term). Their cost is `SETTLED`: a running cost on the state
   and a stiff one on the input, the end pinned on every coordinate and reached `settle` seconds
   before the end, so that a nominal swings up with little torque and speed, and rests at x* when
   the run's law takes over (the costs of the RealAIGym leaderboard's score). Each plan is tracked
   by its own iLQR gains, each input held over its knot as the solver rolled the plan out, and
   caught by the teacher (the run's law with energy pumping outside the training box's angles);
   those whose planned states stay finite and bounded (`sound`) and that hold at x* over `judge_T` are the nominals: first those that end within the training
   box's angles (`reaches`: the plan itself swings up), then those the catch swings up after the
   horizon, cheapest first within each. Where none holds, the plans are solved again with the plain end cost (`PLAIN`: no running
   state cost, a plan only has to end where the catch takes over).
2. **Gains.** Along each of the first `NOMINALS` nominals, the gains of a discrete time-varying LQR on
   the plan's knots (`tvlqr_gains`: state weight `TRACK_Q` on positions, a tenth of it on speeds,
   input weight `TRACK_R`, LQR's Riccati matrix at the end), mapped from z = (q, v) to the run's
   x = (q, p).
3. **Choice.** Each nominal, at every control tick (`dense_plan`: the motion within a knot is no
   error then), with each weight of `SPEED_WEIGHTS` on the speeds in the nearest-point distance
   (positions weigh 1), is judged from `gate_states` near-resting starts of its own seed
   (`plan_seed` + 500): the `tracks` laws that hold the most go to the swing-up gate
   (`swing_stage.swing_gate`), which judges them beside the fitted laws on states of its own.
"""

from __future__ import annotations

import numpy as np

from ..control.baseline import LQRController
from ..model.angles import wrap_angles
from ..sim.integrate import DIVERGENCE_BOUND, simulate
from ..sim.metrics import holds
from ..sim.states import resting_states
from .holds import count_holds
from .ilqr import SPEED_WEIGHT, ILQRSettings, _knot_jacobians, ilqr_plans, plan_weights, rollout
from .plans import PLAN_STEP, TrackThenLaw, plan_bound
from .tracking_law import TrackingLaw

__all__ = ["NOMINALS", "SPEED_WEIGHTS", "dense_plan", "nominal_plans", "nominals", "reaches", "sound", "tracking_law", "tracking_laws", "tvlqr_gains", "warm_starts"]

#: Knot of a nominal plan, s.
KNOT = 0.02
#: Periods (s) of the sinusoidal warm starts, and the number of random ones.
WARM_PERIODS = (0.6, 0.8, 1.0, 1.2, 1.5, 2.0, 2.5, 3.0)
WARM_RANDOM = 16
#: The tracking LQR's weights: positions (per rad² or m², speeds a tenth), inputs (per (N·m)² or N²).
TRACK_Q, TRACK_R = 10.0, 1.0
#: Weights of the speeds in the nearest-point distance tried per nominal (positions: 1).
SPEED_WEIGHTS = (0.1, 0.3, 1.0)
#: Nominals (the cheapest that hold) each tried with every speed weight.
NOMINALS = 3
#: Step sizes of the nominals' line search: down to 0.003, since a swing-up's cost is far from quadratic.
ALPHAS = (1.0, 0.5, 0.25, 0.1, 0.03, 0.01, 0.003)
#: The nominals' cost (`ilqr.ILQRSettings`' fields): the settled one, and the plain end cost where no
#: settled plan holds.
SETTLED = {"q": 1.0, "r": 300.0, "end_box": 1000.0, "settle": 0.3}
PLAIN = {}


def warm_starts(K: int, bound: np.ndarray, seed: int, periods: tuple = WARM_PERIODS, n_random: int = WARM_RANDOM) -> np.ndarray:
    """(S, K, m) warm starts: ±sinusoids of `periods` (s) at four phases and two amplitudes, and
    `n_random` random piecewise-constant inputs of 10 knots, all within ±bound."""
    t = np.arange(K) * KNOT
    starts = [a * bound * np.sin(2 * np.pi * t / period + phase)[:, None]
              for period in periods for phase in (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi) for a in (1.0, 0.5)]
    rng = np.random.default_rng(seed)
    for _ in range(n_random):
        steps = np.repeat(rng.uniform(-1.0, 1.0, size=(K // 10 + 1, bound.size)), 10, axis=0)[:K]
        starts.append(steps * bound)
    return np.stack(starts)


def nominal_plans(system, teacher, x_rest: np.ndarray, config) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Plans from the resting state x_rest (n,) that the teacher's catch turns into a hold at x*:
    [(U (K, m), Z (K + 1, n) in (q, v), cost)], cheapest first (step 1 of the module docstring)."""
    bound = config.track_share * plan_bound(system)
    K = max(1, int(round(config.horizon / KNOT)))
    W = warm_starts(K, bound, config.plan_seed)
    x0 = np.repeat(np.atleast_2d(x_rest), len(W), axis=0)
    for cost_terms in (SETTLED, PLAIN):
        settings = ILQRSettings(iterations=config.track_iterations, alphas=ALPHAS, speed=SPEED_WEIGHT if config.speed_limits else 0.0, **cost_terms)
        U, Z, gains, cost = ilqr_plans(system, x0, W, bound, K * KNOT, LQRController(system).S, settings)
        tracked = TrackThenLaw(U, Z, gains, KNOT, teacher, system, hold=True)  # each input held over its knot, as the plan was rolled out
        held = holds(simulate(system, tracked, x0, T=config.judge_T, dt=PLAN_STEP, stop_settled=False), system) & sound(Z)
        reach = reaches(system, Z[:, -1])
        cheapest = [i for i in np.argsort(cost, kind="stable") if held[i]]
        order = [i for i in cheapest if reach[i]] + [i for i in cheapest if not reach[i]]
        if order:
            break
    return [(U[i], Z[i], float(cost[i])) for i in order]


def sound(Z: np.ndarray) -> np.ndarray:
    """(N,) bool: every planned state of Z (N, K + 1, n) is finite and within the simulator's
    divergence bound (`sim.integrate.DIVERGENCE_BOUND`). iLQR can return a rollout that blew up
    (states of 1e55), whose inputs, clipped to the limits, still leave a catch that swings up by
    itself to hold: no plan, and its time-varying LQR overflows."""
    Z = np.asarray(Z, dtype=np.float64)
    return (np.isfinite(Z) & (np.abs(Z) <= DIVERGENCE_BOUND)).all(axis=(1, 2))


def reaches(system, z_end: np.ndarray) -> np.ndarray:
    """(N,) bool: the plans' last states z_end (N, n) in (q, v) have every angle within the training
    box's half-width of x*'s: the plan itself swings up, rather than leaving the swing-up to the
    catch after its horizon."""
    nq = system.nq
    lo, hi = (np.asarray(b, float)[:nq] for b in system.domain)
    half = 0.5 * (hi - lo)
    mask = np.asarray(system.angle_mask, bool)[:nq]
    d = wrap_angles(np.asarray(z_end, float)[:, :nq] - np.asarray(system.x_star, float)[:nq], mask)
    return (np.abs(d) <= half)[:, mask].all(axis=1)


def tvlqr_gains(system, U: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Gains (K, m, n) of the discrete time-varying LQR along a plan U (K, m), Z (K + 1, n) in
    z = (q, v): u_k = U_k + G_k (z − Z_k), minimising Σ (δzᵀQδz + δuᵀRδu) KNOT + δz_Kᵀ S_z δz_K with
    Q = diag(TRACK_Q on positions, TRACK_Q/10 on speeds), R = TRACK_R·I and S_z LQR's Riccati matrix
    at x* in z (`ilqr.plan_weights`)."""
    nq, (K, m) = system.nq, U.shape
    A, B = _knot_jacobians(system, Z[:-1], U, KNOT)
    Q = np.diag(np.r_[np.full(nq, TRACK_Q), np.full(nq, 0.1 * TRACK_Q)]) * KNOT
    R = TRACK_R * KNOT * np.eye(m)
    P = plan_weights(system, LQRController(system).S, ILQRSettings(), plan_bound(system))[1]
    G = np.empty((K, m, 2 * nq))
    for k in range(K - 1, -1, -1):
        gain = np.linalg.solve(R + B[k].T @ P @ B[k], B[k].T @ P @ A[k])
        P = Q + A[k].T @ P @ (A[k] - B[k] @ gain)
        P = 0.5 * (P + P.T)
        G[k] = -gain
    return G


def dense_plan(system, U: np.ndarray, Z: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plan U (K, m), Z (K + 1, n), G (K, m, n) at every control tick (`PLAN_STEP`) instead of
    every knot: each knot's motion under its held input rolled out from the knot's state, the input
    and gains repeated: (U (K·r, m), Z (K·r + 1, n), G (K·r, m, n)), r = KNOT / PLAN_STEP. Read
    from the nearest point, a fast plan's own motion within a knot is then no error."""
    r = int(round(KNOT / PLAN_STEP))
    inside = rollout(system, Z[:-1], np.repeat(U[:, None, :], r, axis=1), PLAN_STEP, 1)[:, :r]
    return np.repeat(U, r, axis=0), np.concatenate([inside.reshape(-1, Z.shape[1]), Z[-1:]]), np.repeat(G, r, axis=0)


def tracking_law(system, U: np.ndarray, Z: np.ndarray, G: np.ndarray, speed_weight: float, box: np.ndarray, dense: bool = False) -> TrackingLaw:
    """The `TrackingLaw` of a plan U (K, m), Z (K + 1, n) and its gains G (K, m, n) on z = (q, v),
    mapped to x = (q, p = M(q) v): X_k = (q_k, M(q_k) v_k) and K_k = G_k Φ_k⁻¹, Φ_k = ∂x/∂z at Z_k
    (∂(M v)/∂q by central differences of M); the distance weighs positions 1 and momenta
    `speed_weight` / M_ii(q*). `dense`: the nominal at every control tick (`dense_plan`)."""
    if dense:
        U, Z, G = dense_plan(system, U, Z, G)
    nq = system.nq
    q, v = Z[:-1, :nq], Z[:-1, nq:]
    M = system.mass_matrix(q)
    h = 1e-6
    dMv = np.stack([(system.mass_matrix(q + h * e) - system.mass_matrix(q - h * e)) @ v[..., None] for e in np.eye(nq)], axis=-1)[:, :, 0] / (2 * h)
    M_inv = np.linalg.inv(M)
    Phi_inv = np.zeros((len(q), 2 * nq, 2 * nq))
    Phi_inv[:, :nq, :nq] = np.eye(nq)
    Phi_inv[:, nq:, :nq] = -M_inv @ dMv
    Phi_inv[:, nq:, nq:] = M_inv
    x_star = np.asarray(system.x_star, dtype=np.float64)
    M_star = np.diag(system.mass_matrix(x_star[None, :nq])[0])
    weight = np.r_[np.ones(nq), speed_weight / M_star]
    return TrackingLaw(np.concatenate([q, np.einsum("kij,kj->ki", M, v)], axis=1), U.copy(), G @ Phi_inv, weight, x_star,
                       np.asarray(system.effort, dtype=np.float64), np.asarray(system.angle_mask, dtype=bool), np.asarray(box, dtype=np.float64))


def nominals(system, catch, config, count: int = NOMINALS) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Steps 1 and 2 of the module docstring: the first `count` plans from the exact resting posture
    that `catch` (the stage's `PumpThenRun`) turns into a hold at x*, cheapest first, each as
    (U (K, m), Z (K + 1, n) in (q, v), its tracking gains G (K, m, n) on z − Z_k)."""
    found = nominal_plans(system, catch, resting_states(system, 1)[0], config)[:count]
    return [(U, Z, tvlqr_gains(system, U, Z)) for U, Z, _ in found]


def tracking_laws(system, teacher, plans: list, box: np.ndarray, config, progress: bool = False) -> tuple[list[TrackingLaw], dict]:
    """Step 3 of the module docstring for `system` (the plans' plant), the run's law `teacher` (its
    outer law wrapped by each tracking law) and the first `NOMINALS` of the `nominals` `plans`, with
    the kept `box` (n,): (the `config.tracks` laws that hold the most, most first; {"nominals": how
    many plans were tried, "held": holds of each law tried (nominal, speed weight), "states"})."""
    plans = plans[:NOMINALS]
    laws = [tracking_law(system, U, Z, G, w, box, dense=True).with_inner(teacher.fallback) for U, Z, G in plans for w in SPEED_WEIGHTS]
    x0 = resting_states(system, config.gate_states, config.plan_seed + 500)
    held = count_holds(system, [teacher.with_fallback(law) for law in laws], x0, config)
    best = sorted(range(len(laws)), key=lambda i: -held[i])[: config.tracks]
    info = {"nominals": len(plans), "held": held, "states": len(x0)}
    if progress:
        print(f"swing-up tracking laws: the first {len(plans)} nominal plans from rest, each tracked from the nearest point with "
              f"{len(SPEED_WEIGHTS)} speed weights, hold {', '.join(map(str, held)) or 'none'} of {len(x0)} near-resting starts", flush=True)
    return [laws[i].with_inner(None) for i in best], info
