"""Closed-loop simulation of the true plant: the vector field, RK4 and RK45 steps, `simulate`.

A controller is any callable ``ctrl(x) -> u`` with x = (q, p) of shape (N, n) and u of shape
(N, m), float64. `simulate` integrates the *true plant* in (q, v),

    q̇ = v,    v̇ = forward_dynamics(q, v, B u),    u = sat(ctrl(x(q, v))),  x = (q, M(q) v),

with sat the clip to the actuators' effort limits (and an optional saturation, see
`idapbc_pin.sim.limits`). By default the law runs as a robot runs it, as a digital controller: u is
computed once at the start of each step of dt from the state there and held over the step (a zero-order
hold at 1/dt Hz; `hold=False` evaluates it at every RK4 stage instead, a continuous-time law).

forward_dynamics is the judge's (`idapbc_pin.sim.judge`): the model a controller was
trained on never judges it (STYLE §6). Everything is batched over initial states; states that blow
up are frozen and flagged, never allowed to put NaN into the rest of the batch.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .judge import Judge
from .limits import input_limits
from .step import judge_step
from .stops import Stops
from .terminal import terminal_set
from .trajectory import Trajectory

__all__ = ["DIVERGENCE_BOUND", "Controller", "loop_terminal_set", "simulate"]

#: A state whose |q| or |v| exceeds this (rad, m, rad/s, m/s) counts as diverged and is frozen.
DIVERGENCE_BOUND = 1e6

#: A control law: (N, n) states (q, p) -> (N, m) inputs.
Controller = Callable[[np.ndarray], np.ndarray]


# ====================================================================== the vector field
def _out_of_bounds(q: np.ndarray, v: np.ndarray, bound: float) -> np.ndarray:
    """(N,) bool: a component of q (N, nq) or v (N, nq) is non-finite or beyond `bound`."""
    if float(np.vdot(q, q)) + float(np.vdot(v, v)) <= bound * bound:  # every row within bound (NaN, ∞ fail): two products
        return np.zeros(q.shape[0], bool)
    ok = (np.abs(q) <= bound).all(axis=1) & (np.abs(v) <= bound).all(axis=1)  # NaN compares False, so |NaN| and ∞ fail too
    return ~ok


def _vector_field(judge: Judge, ctrl: Controller, bound, bound_q: float, q_star: np.ndarray, m: int):
    """The closed loop in (q, v) with sanitised inputs, clipped to ±`bound` ((m,) or None).

    Returns ``rhs(q, v, held=None) -> (q̇, v̇, u, x, bad)`` with u the applied (clipped) input: rows
    that are non-finite or beyond `bound_q`, or for which the controller or the plant returns
    non-finite values, are flagged ``bad`` and evaluated at (q*, 0) instead (their results are
    meaningless and get discarded), so the controller never sees a non-finite state and no NaN reaches
    the other rows. With ``held`` (N, m), an input already applied (clipped, finite) is held: the
    controller is not called and x is None.
    """
    bound_q, bound = float(bound_q), (None if bound is None else np.asarray(bound, float))

    def rhs(q, v, held=None):
        N = q.shape[0]
        bad = _out_of_bounds(q, v, bound_q)
        any_bad = bool(bad.any())  # the row-wise repairs below run only where a row is bad (rare)
        if any_bad:
            q, v = q.copy(), v.copy()
            q[bad], v[bad] = q_star, 0.0
        if held is not None:
            x, u = None, held
        else:
            x = judge.state(q, v)
            u = np.asarray(ctrl(x), dtype=float)
            if u.size != N * m:
                raise ValueError(f"the controller returned shape {u.shape} for {N} states; expected ({N}, {m})")
            u = u.reshape(N, m).copy()
            if any_bad or not np.isfinite(u).all():
                bad |= ~np.all(np.isfinite(u), axis=1)
                u[bad] = 0.0
                any_bad = True
            if bound is not None:
                u = np.clip(u, -bound, bound)
        a = judge.accel(q, v, u @ judge.B.T)
        if any_bad or not np.isfinite(a).all():
            bad |= ~np.all(np.isfinite(a), axis=1)
            a[bad] = 0.0
        return v, a, u, x, bad

    return rhs


# ====================================================================== integrators
def _rk4_advance(rhs, q, v, first, n_steps: int, h: float, bound: float, hold: bool = False):
    """`n_steps` classical RK4 steps of size h; rows that go bad are frozen at their last good state.

    ``first`` = (q̇, v̇, bad, u) at (q, v), already evaluated for the record. With `hold`, the input
    of each step's first stage is held over its other stages (zero-order hold over the step).
    Returns (q, v, bad).
    """
    q, v = q.copy(), v.copy()
    bad_all = first[2].copy()
    live = np.flatnonzero(~bad_all)
    whole = live.size == q.shape[0]  # every row live: no gathering and scattering (the same values)
    k1q, k1v, u1 = (first[0], first[1], first[3]) if whole else (first[0][live], first[1][live], first[3][live])
    for step in range(n_steps):
        if live.size == 0:
            break
        q0, v0 = (q, v) if whole else (q[live], v[live])
        if step > 0:
            k1q, k1v, u1, _, b1 = rhs(q0, v0)
        else:
            b1 = np.zeros(live.size, bool)
        held = u1 if hold else None
        k2q, k2v, _, _, b2 = rhs(q0 + 0.5 * h * k1q, v0 + 0.5 * h * k1v, held)
        k3q, k3v, _, _, b3 = rhs(q0 + 0.5 * h * k2q, v0 + 0.5 * h * k2v, held)
        k4q, k4v, _, _, b4 = rhs(q0 + h * k3q, v0 + h * k3v, held)
        qn = q0 + (h / 6.0) * (k1q + 2.0 * k2q + 2.0 * k3q + k4q)
        vn = v0 + (h / 6.0) * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        bad = b1 | b2 | b3 | b4 | _out_of_bounds(qn, vn, bound)
        if whole and not bad.any():
            q, v = qn, vn
            continue
        ok = live[~bad]
        q[ok], v[ok] = qn[~bad], vn[~bad]
        bad_all[live[bad]] = True
        live, whole = ok, False
    return q, v, bad_all


# Dormand–Prince 5(4) tableau (the vector field is autonomous: the nodes c_i are not needed).
_DP_A = [
    [],
    [1 / 5],
    [3 / 40, 9 / 40],
    [44 / 45, -56 / 15, 32 / 9],
    [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729],
    [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656],
    [35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84],
]
_DP_B5 = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0])
_DP_B4 = np.array([5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40])


def _rk45_advance(rhs, q, v, first, span: float, h0: float, h_min: float, bound: float, rtol: float, atol: float):
    """Integrate over `span` seconds with Dormand–Prince 5(4), one step size shared by the batch.

    The step is accepted when the largest per-row RMS error (scaled by atol + rtol·|y|) is ≤ 1.
    A row whose stages go bad (non-finite, beyond `bound`) rejects the step. Once the step has
    shrunk to h_min = dt/100, rows still failing the error test are declared diverged and
    frozen (a motion that needs steps that short, e.g. a blow-up at 1e3 rad/s, is not a stabilised
    trajectory), and the others go on.
    Returns (q, v, bad) and the last accepted step size.
    """
    nq = q.shape[1]
    y = np.concatenate([q, v], axis=1)
    bad_all = first[2].copy()
    live = np.flatnonzero(~bad_all)
    k_first = np.concatenate([first[0], first[1]], axis=1)[live]
    t, h = 0.0, min(h0, span)

    def f(Y):
        dq, dv, _, _, b = rhs(Y[:, :nq], Y[:, nq:])
        return np.concatenate([dq, dv], axis=1), b

    k_first = (k_first, np.zeros(live.size, bool))
    while t < span * (1.0 - 1e-12) and live.size:
        h_free = h  # the step the error control proposes, before clipping to the span
        h = min(h, span - t)
        y0 = y[live]
        if k_first is None:
            k_first = f(y0)
        K = [k_first[0]]
        b_any = k_first[1].copy()
        for i in range(1, 7):
            yi = y0 + h * sum(a * K[j] for j, a in enumerate(_DP_A[i]) if a != 0.0)
            ki, bi = f(yi)
            K.append(ki)
            b_any |= bi
        y5 = y0 + h * sum(b * k for b, k in zip(_DP_B5, K) if b != 0.0)
        err = h * sum((b5 - b4) * k for b5, b4, k in zip(_DP_B5, _DP_B4, K) if b5 != b4)
        scale = atol + rtol * np.maximum(np.abs(y0), np.abs(y5))
        b_any |= _out_of_bounds(y5[:, :nq], y5[:, nq:], bound)
        with np.errstate(invalid="ignore", over="ignore"):
            e_row = np.sqrt(np.mean((err / scale) ** 2, axis=1))
        e_row[b_any | ~np.isfinite(e_row)] = np.inf
        e_max = float(e_row.max())
        if e_max > 1.0 and h > h_min:  # reject: shrink and retry from the same state
            h = max(h_min, h * (max(0.1, 0.9 * e_max**-0.2) if np.isfinite(e_max) else 0.1))
            continue
        # accept (at h_min: rows that still fail the error test diverge, the others go on)
        ok = e_row <= 1.0
        y[live[ok]] = y5[ok]
        bad_all[live[~ok]] = True
        live = live[ok]
        t += h
        k_first = None
        e_ok = float(e_row[ok].max()) if ok.any() else 0.0
        grow = min(5.0, 0.9 * e_ok**-0.2) if e_ok > 0 else 5.0
        h = max(h_min, h * grow, h_free if h < h_free else 0.0)
    return y[:, :nq], y[:, nq:], bad_all, h


def _stepper(rhs, method: str, dt: float, bound: float, rtol: float, atol: float, hold: bool):
    """``advance(q, v, first, n_sub) -> (q, v, bad)``: `n_sub` steps of dt of the chosen method
    (RK45 carries its adapted step size from one call to the next; it never holds the input)."""
    if method == "rk4":
        return lambda q, v, first, n_sub: _rk4_advance(rhs, q, v, first, n_sub, dt, bound, hold)
    h_adapt = dt

    def advance(q, v, first, n_sub):
        nonlocal h_adapt
        q, v, bad, h_adapt = _rk45_advance(rhs, q, v, first, n_sub * dt, h_adapt, 1e-2 * dt, bound, rtol, atol)
        return q, v, bad

    return advance


# ====================================================================== simulate
def _as_batch(x, n: int, what: str) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    x = x[None] if x.ndim == 1 else x
    if x.ndim != 2 or x.shape[1] != n:
        raise ValueError(f"{what} must have shape (N, {n}) or ({n},), got {np.shape(x)}")
    return x


def _record_steps(T: float, dt: float, method: str, record_every, hold: bool) -> list[int]:
    """The steps of dt at which the record samples, 0 … T/dt (the last always); checks the grid."""
    if method not in ("rk4", "rk45"):
        raise ValueError(f"method must be 'rk4' or 'rk45', got {method!r}")
    if hold and method != "rk4":
        raise ValueError("hold=True needs the fixed-step method='rk4'; pass hold=False with method='rk45' (a continuous-time law)")
    if not (dt > 0 and T >= 0 and math.isfinite(T)):
        raise ValueError(f"need dt > 0 and a finite T ≥ 0, got T={T!r}, dt={dt!r}")
    n_steps = int(round(T / dt))
    if abs(n_steps * dt - T) > 1e-9 * max(1.0, T):
        raise ValueError(f"T={T} is not a multiple of dt={dt}")
    record_every = int(record_every)
    if record_every < 1:
        raise ValueError(f"record_every must be ≥ 1, got {record_every}")
    steps = list(range(0, n_steps + 1, record_every))
    if steps[-1] != n_steps:
        steps.append(n_steps)
    return steps


def _initial_state(system, x0: np.ndarray, bound: float):
    """(q, v) (N, nq) each from x0 (N, n), and (N,) bool: unusable (non-finite or beyond `bound`)
    initial states, diverged from the start and set to (q*, 0)."""
    N, nq = x0.shape[0], int(system.nq)
    x_star = np.asarray(system.x_star, float)
    bad = ~np.all(np.isfinite(x0), axis=1)
    x_init = np.where(bad[:, None], x_star, x0)
    q, v = (np.asarray(a, float).reshape(N, nq) for a in system.split(x_init))
    bad |= _out_of_bounds(q, v, bound)
    q[bad], v[bad] = x_star[:nq], 0.0
    return q, v, bad


def _step_map(rhs, dt: float, bound: float, hold: bool):
    """One RK4 step of dt of the loop, (q, v (N, nq)) -> (q', v', bad (N,)), for `terminal_set`."""

    def step(q, v):
        dq, dv, u, _, bad = rhs(q, v)
        qn, vn, bad_n = _rk4_advance(rhs, q, v, (dq, dv, bad, u), 1, dt, bound, hold)
        return qn, vn, bad | bad_n

    return step


def loop_terminal_set(system, ctrl: Controller, dt: float | None = None, *, saturation=None, limits: bool = True, hold: bool = True,
                      bound: float = DIVERGENCE_BOUND, threads: int | None = None):
    """The `TerminalSet` (`idapbc_pin.sim.terminal`) of `ctrl`'s loop as `simulate` integrates it
    with RK4 (same arguments; dt None: `judge_step`'s for a 20 s horizon), or None where it has
    none; `simulate(stop_converged=True)` stops rollouts in it."""
    nq, m = int(system.nq), int(system.m)
    dt = judge_step(system, {"ctrl": ctrl}, 20.0, dt)
    clip = input_limits(system, limits, saturation).bound
    rhs = _vector_field(Judge(system, threads), ctrl, clip, bound, np.asarray(system.x_star, float)[:nq], m)
    return terminal_set(system, _step_map(rhs, dt, bound, hold))


def _record(rhs, advance, q, v, x_last, diverged, steps: list[int], m: int, settle: Stops | None = None):
    """Sample the closed loop at `steps`, advancing the live rows in between.

    q, v (N, nq) and x_last (N, n) are updated in place; returns X (N, K, n), V (N, K, nq),
    U (N, K, m) and diverged (N,), rows frozen at their last good sample once they go bad, or (with
    `settle`) once their verdict is known (`Stops`; not flagged).
    """
    N, K = q.shape[0], len(steps)
    X, V, U = np.empty((N, K, x_last.shape[1])), np.empty((N, K, q.shape[1])), np.empty((N, K, m))
    diverged = diverged.copy()
    u_last = np.zeros((N, m))
    for r, step in enumerate(steps):
        live = np.flatnonzero(~diverged if settle is None else ~diverged & ~settle.done)
        if live.size:
            dq, dv, u, x, b = rhs(q[live], v[live])
            x_last[live] = x
            if b.any():
                u_last[live[~b]] = u[~b]
                diverged[live[b]] = True
                live, dq, dv, u = live[~b], dq[~b], dv[~b], u[~b]
            else:
                u_last[live] = u
            if settle is not None and step >= settle.first:
                go_on = ~settle.stop(q, v, x_last, live)
                live, dq, dv, u = live[go_on], dq[go_on], dv[go_on], u[go_on]
        X[:, r], V[:, r], U[:, r] = x_last, v, u_last
        if settle is not None and settle.left.any():  # rows that left the box: NaN from the next sample on
            x_last[settle.left], v[settle.left], u_last[settle.left] = np.nan, np.nan, np.nan
        if r == K - 1:
            break
        if not live.size or (settle is not None and settle.decided()):  # every row diverged or stopped, or enough stopped
            X[:, r + 1 :], V[:, r + 1 :], U[:, r + 1 :] = x_last[:, None], v[:, None], u_last[:, None]
            X[live, r + 1 :], V[live, r + 1 :], U[live, r + 1 :] = np.nan, np.nan, np.nan  # rows still moving: undecided
            break
        qn, vn, b = advance(q[live], v[live], (dq, dv, np.zeros(live.size, bool), u), steps[r + 1] - step)
        if b.any():
            q[live[~b]], v[live[~b]] = qn[~b], vn[~b]
            diverged[live[b]] = True
        else:
            q[live], v[live] = qn, vn
    return X, V, U, diverged


def simulate(
    system,
    ctrl: Controller,
    x0,
    T: float = 20.0,
    dt: float | None = None,
    method: str = "rk4",
    saturation=None,
    record_every: int = 1,
    *,
    limits: bool = True,
    hold: bool = True,
    bound: float = DIVERGENCE_BOUND,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    threads: int | None = None,
    stop_settled: bool = False,
    stop_converged: bool | Controller = False,
    stop_outside=None,
    stop_from: float = 0.0,
    enough_settled: int | None = None,
) -> Trajectory:
    """Closed loop of the true plant from a batch of initial states.

    Parameters
    ----------
    system : `idapbc_pin.System` (or any object with ``nq, n, m, B, x_star, split, state_from,
        forward_dynamics`` and ``plant``).
    ctrl : callable (N, n) -> (N, m): the control law u(x), x = (q, p).
    x0 : (N, n) or (n,) initial states (q, p).
    T : horizon, s; must be a multiple of `dt`.
    dt : step of the fixed-step RK4 and, with `hold`, the control period (s); for ``"rk45"`` the
        initial step and, with `record_every`, the sampling grid. None (the default): 2 ms (a 500 Hz
        controller), or shorter where the loop linearised at x* is stiffer
        (`idapbc_pin.sim.step.judge_step`).
    method : ``"rk4"`` (classical fixed step, the default) or ``"rk45"`` (adaptive
        Dormand–Prince 5(4) with a step size shared by the batch, tolerances `rtol`, `atol`; a
        state that needs a step below dt/100 is flagged diverged).
    saturation : None, or max |u| per input (scalar or (m,)); the input is clipped to it (and to
        the effort limits, whichever is smaller).
    limits : clip the input to the system's effort limits ``system.effort`` (DESIGN §4; the
        default); False lifts them (a system without ``effort`` is unlimited either way).
    hold : evaluate the law once per step of dt, at its start, and hold the input over the step's
        RK4 stages (the default: a digital controller at 1/dt Hz, as on a robot and as MuJoCo steps
        with an applied force); False evaluates it at every stage (a continuous-time law; needed
        with ``"rk45"``).
    record_every : record every this many steps of `dt` (the final time is always recorded).
    bound : a state with |q| or |v| above this, or non-finite, is frozen and flagged diverged.
    threads : Pinocchio threads for URDF plants (default `DEFAULT_THREADS`).
    stop_settled : stop integrating a row once it has been in the success box at every sample of
        the last `SUCCESS_WINDOW` seconds; its record holds that sample from then on, so `success`
        reads True for it (settling time and peak input are those up to then): for callers that
        need the success verdict only (gates, the ROA radius). The batch shrinks as rows stop, so
        the other rows agree with a run without the stop to the last bits (BLAS rounds a row
        differently in another batch; a lone row is evaluated beside a copy of itself).
    stop_converged : stop integrating a row once it enters the loop's terminal set
        (`idapbc_pin.sim.terminal`: inside the success box, and the loop lowers a quadratic
        Lyapunov function there at every step, checked on samples), with ``converged`` True: its
        record holds that sample from then on, so `success` and `settling_time` read what the full
        horizon gives, its equilibrium offset is 0 (its limit is x*) and its peak input is that up
        to then. For a law that does not depend on time, with ``"rk4"`` (else no stop); the rows
        stopped this way are in the same batch-size caveat as `stop_settled`'s. A controller
        instead of True: the terminal set of that law's loop, for a `ctrl` that acts as that law
        from `stop_from` on (a plan followed by a feedback law); `ctrl` itself is then never probed.
    stop_outside : None, or a box (lo, hi) (n,) each of x = (q, p): a row is integrated no further
        once a sample leaves it (angles wrapped about x*), and its record holds NaN from the next
        sample on, so `success` reads False for it. For callers that need "succeeds without
        leaving the box" only (`idapbc_pin.evaluation.invariance.box_invariant_share`).
    stop_from : the stops above apply from this time on (s); the record up to it is that of the
        full horizon, bit for bit.
    enough_settled : with `stop_settled` or `stop_converged`, stop the whole batch once this many
        rows have stopped (for a caller that needs a count of successes only: the ROA radius's
        probes); the rows still moving then hold NaN in the rest of their record, so `success`
        reads False for them.

    Returns
    -------
    Trajectory with t (T_k,), x (N, T_k, n), q and v (N, T_k, nq), u (N, T_k, m) (the applied,
    clipped input), diverged (N,), converged (N,) (all False without `stop_converged`).
    """
    nq, n, m = int(system.nq), int(system.n), int(system.m)
    x0 = _as_batch(x0, n, "x0")
    dt = judge_step(system, {"ctrl": ctrl}, T, dt)
    steps = _record_steps(T, dt, method, record_every, hold)
    x_star = np.asarray(system.x_star, float)
    clip = input_limits(system, limits, saturation).bound
    rhs = _vector_field(Judge(system, threads), ctrl, clip, bound, x_star[:nq], m)
    terminal = None
    if stop_converged is not False and method == "rk4":  # the terminal set of ctrl's loop, or of the law ctrl turns into
        terminal = loop_terminal_set(system, ctrl if stop_converged is True else stop_converged, dt, saturation=saturation,
                                     limits=limits, hold=hold, bound=bound, threads=threads)
    settle = Stops.build(system, x0.shape[0], steps, dt, stop_settled, terminal, enough_settled, stop_outside, stop_from)
    if settle is not None:
        rhs = settle.batch_of_one_padded(rhs)
    q, v, bad0 = _initial_state(system, x0, bound)
    x_last = np.where(bad0[:, None], x_star, x0).copy()
    X, V, U, diverged = _record(rhs, _stepper(rhs, method, dt, bound, rtol, atol, hold), q, v, x_last, bad0, steps, m, settle)
    converged = settle.converged & ~diverged if settle is not None else np.zeros(x0.shape[0], bool)
    return Trajectory(t=np.asarray(steps, float) * dt, x=X, q=X[..., :nq], v=V, u=U, diverged=diverged, converged=converged)
