"""Closed-loop simulation with the true plant as the judge, the metrics of DESIGN §4, LQR, ROA.

A controller is any callable ``ctrl(x) -> u`` with x = (q, p) of shape (N, n) and u of shape
(N, m), float64. `simulate` integrates the *true plant* in (q, v),

    q̇ = v,    v̇ = forward_dynamics(q, v, B u),    u = sat(ctrl(x(q, v))),  x = (q, M(q) v),

where forward_dynamics is Pinocchio's ``aba`` plus joint damping for URDF robots and the closed
form for the paper's analytic systems: the model a controller was trained on never judges it
(STYLE §6). Everything is batched over initial states; states that blow up are frozen and flagged,
never allowed to put NaN into the rest of the batch.

The metrics (`success`, `settling_time`, `equilibrium_offset`, `peak_input`) are pure functions of
a `Trajectory`; `roa` runs several controllers from the very same uniform initial states and
tabulates them (DESIGN §4, "How we measure").
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from ..control.linear import lqr
from .states import evaluation_box, half_box, uniform_states

__all__ = [
    "DIVERGENCE_BOUND",
    "SUCCESS_TOL",
    "SUCCESS_WINDOW",
    "ControllerScore",
    "LQRController",
    "RoaResult",
    "Trajectory",
    "equilibrium_offset",
    "evaluation_box",
    "half_box",
    "in_target_box",
    "peak_input",
    "roa",
    "settled",
    "settling_time",
    "simulate",
    "success",
    "uniform_states",
    "wrap_angles",
]

#: A state whose |q| or |v| exceeds this (rad, m, rad/s, m/s) counts as diverged and is frozen.
DIVERGENCE_BOUND = 1e6
#: DESIGN §4: success is judged over the last SUCCESS_WINDOW seconds ...
SUCCESS_WINDOW = 2.0
#: ... against the box ‖q − q*‖∞ ≤ SUCCESS_TOL (angles wrapped), ‖v‖∞ ≤ SUCCESS_TOL.
SUCCESS_TOL = 0.05

#: Threads for Pinocchio's ``abaInParallel`` / ``rneaInParallel``. One: measured on the 2-core
#: machine with other work running (load 4–7), 2 OpenMP threads made a 1000-state acrobot ROA 6.7×
#: slower (129 s vs 19 s); on an idle machine 2 threads gain at most ~2× on the Pinocchio calls.
DEFAULT_THREADS = 1

Controller = Callable[[np.ndarray], np.ndarray]


# ====================================================================== trajectory
@dataclass(frozen=True, eq=False)
class Trajectory:
    """A batch of closed-loop trajectories sampled at common times.

    Attributes
    ----------
    t : (T_k,) sample times, s (t[0] = 0, t[-1] = T).
    x : (N, T_k, n) states (q, p), p = M(q) v.
    q : (N, T_k, nq) positions, rad or m (a view of ``x[..., :nq]``).
    v : (N, T_k, nq) velocities, rad/s or m/s.
    u : (N, T_k, m) applied inputs (after saturation), N·m or N.
    diverged : (N,) bool; a diverged row is frozen at its last finite state within the bound
        (state and input then repeat that last value).
    """

    t: np.ndarray
    x: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    diverged: np.ndarray

    @property
    def n_states(self) -> int:
        """Number of trajectories N."""
        return int(self.x.shape[0])


# ====================================================================== the judge
class _Judge:
    """The true plant in (q, v), batched: accelerations and momenta.

    URDF plants (``system.plant`` with ``.model``) use Pinocchio's ``abaInParallel`` and
    ``rneaInParallel`` (on a gravity-free copy of the model, whose RNEA at zero velocity is M(q)a)
    over a ``ModelPool``; every other system uses its own ``forward_dynamics`` and ``state_from``.
    """

    def __init__(self, system, threads: int | None = None):
        self.system = system
        self.nq = int(system.nq)
        self.B = np.asarray(system.B, float)
        plant = getattr(system, "plant", None)
        self.pinocchio = hasattr(plant, "model") and hasattr(plant, "config")
        if self.pinocchio:
            import pinocchio as pin

            self._pin = pin
            self.threads = int(threads or DEFAULT_THREADS)
            model = plant.model
            free = model.copy()
            free.gravity = pin.Motion.Zero()
            self._pool = pin.ModelPool(model, self.threads)
            self._free_pool = pin.ModelPool(free, self.threads)
            self._config = plant.config
            self._damping = np.asarray(plant.damping, float)

    def accel(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """v̇ of the true plant: (N, nq) ×3 -> (N, nq), tau on every joint."""
        if not self.pinocchio:
            return np.asarray(self.system.forward_dynamics(q, v, tau), float).reshape(q.shape)
        if q.shape[0] == 0:
            return np.zeros_like(q)
        tau = tau - self._damping * v  # aba ignores model.damping (DESIGN §2)
        qc = np.asfortranarray(self._config(q).T)
        a = self._pin.abaInParallel(self.threads, self._pool, qc, np.asfortranarray(v.T), np.asfortranarray(tau.T))
        return np.array(a).reshape(q.shape[1], q.shape[0]).T

    def state(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """x = (q, M(q) v): (N, nq) ×2 -> (N, n)."""
        if not self.pinocchio:
            return np.asarray(self.system.state_from(q, v), float).reshape(q.shape[0], 2 * self.nq)
        if q.shape[0] == 0:
            return np.zeros((0, 2 * self.nq))
        qc = np.asfortranarray(self._config(q).T)
        zeros = np.zeros((v.shape[1], v.shape[0]), order="F")
        p = self._pin.rneaInParallel(self.threads, self._free_pool, qc, zeros, np.asfortranarray(v.T))
        return np.concatenate([q, np.array(p).reshape(q.shape[1], q.shape[0]).T], axis=1)


def _out_of_bounds(q: np.ndarray, v: np.ndarray, bound: float) -> np.ndarray:
    """(N,) bool: a component of q (N, nq) or v (N, nq) is non-finite or beyond `bound`."""
    ok = np.all(np.isfinite(q) & (np.abs(q) <= bound), axis=1) & np.all(np.isfinite(v) & (np.abs(v) <= bound), axis=1)
    return ~ok


def _vector_field(judge: _Judge, ctrl: Controller, saturation, bound: float, q_star: np.ndarray, m: int):
    """The closed loop in (q, v) with sanitised inputs.

    Returns ``rhs(q, v) -> (q̇, v̇, u, x, bad)``: rows that are non-finite or beyond `bound`, or for
    which the controller or the plant returns non-finite values, are flagged ``bad`` and evaluated
    at (q*, 0) instead (their results are meaningless and get discarded), so the controller never
    sees a non-finite state and no NaN reaches the other rows.
    """
    sat = None if saturation is None else np.broadcast_to(np.asarray(saturation, float), (m,))
    if sat is not None and np.any(~(sat > 0)):
        raise ValueError(f"saturation must be positive (max |u| per input), got {saturation!r}")

    def rhs(q, v):
        N = q.shape[0]
        bad = _out_of_bounds(q, v, bound)
        if bad.any():
            q, v = q.copy(), v.copy()
            q[bad], v[bad] = q_star, 0.0
        x = judge.state(q, v)
        u = np.asarray(ctrl(x), dtype=float)
        if u.size != N * m:
            raise ValueError(f"the controller returned shape {u.shape} for {N} states; expected ({N}, {m})")
        u = u.reshape(N, m).copy()
        bad |= ~np.all(np.isfinite(u), axis=1)
        u[bad] = 0.0
        if sat is not None:
            u = np.clip(u, -sat, sat)
        a = judge.accel(q, v, u @ judge.B.T)
        bad |= ~np.all(np.isfinite(a), axis=1)
        a[bad] = 0.0
        return v, a, u, x, bad

    return rhs


# ====================================================================== integrators
def _rk4_advance(rhs, q, v, first, n_steps: int, h: float, bound: float):
    """`n_steps` classical RK4 steps of size h; rows that go bad are frozen at their last good state.

    ``first`` = (q̇, v̇, bad) at (q, v), already evaluated for the record. Returns (q, v, bad).
    """
    q, v = q.copy(), v.copy()
    bad_all = first[2].copy()
    live = np.flatnonzero(~bad_all)
    k1q, k1v = first[0][live], first[1][live]
    for step in range(n_steps):
        if live.size == 0:
            break
        q0, v0 = q[live], v[live]
        if step > 0:
            k1q, k1v, _, _, b1 = rhs(q0, v0)
        else:
            b1 = np.zeros(live.size, bool)
        k2q, k2v, _, _, b2 = rhs(q0 + 0.5 * h * k1q, v0 + 0.5 * h * k1v)
        k3q, k3v, _, _, b3 = rhs(q0 + 0.5 * h * k2q, v0 + 0.5 * h * k2v)
        k4q, k4v, _, _, b4 = rhs(q0 + h * k3q, v0 + h * k3v)
        qn = q0 + (h / 6.0) * (k1q + 2.0 * k2q + 2.0 * k3q + k4q)
        vn = v0 + (h / 6.0) * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        bad = b1 | b2 | b3 | b4 | _out_of_bounds(qn, vn, bound)
        ok = live[~bad]
        q[ok], v[ok] = qn[~bad], vn[~bad]
        bad_all[live[bad]] = True
        live = ok
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


# ====================================================================== simulate
def _as_batch(x, n: int, what: str) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    x = x[None] if x.ndim == 1 else x
    if x.ndim != 2 or x.shape[1] != n:
        raise ValueError(f"{what} must have shape (N, {n}) or ({n},), got {np.shape(x)}")
    return x


def simulate(
    system,
    ctrl: Controller,
    x0,
    T: float = 20.0,
    dt: float = 0.01,
    method: str = "rk4",
    saturation=None,
    record_every: int = 1,
    *,
    bound: float = DIVERGENCE_BOUND,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    threads: int | None = None,
) -> Trajectory:
    """Closed loop of the true plant from a batch of initial states.

    Parameters
    ----------
    system : `idapbc_pin.System` (or any object with ``nq, n, m, B, x_star, split, state_from,
        forward_dynamics`` and ``plant``).
    ctrl : callable (N, n) -> (N, m): the control law u(x), x = (q, p).
    x0 : (N, n) or (n,) initial states (q, p).
    T : horizon, s; must be a multiple of `dt`.
    dt : step of the fixed-step RK4 (s); for ``"rk45"`` the initial step and, with
        `record_every`, the sampling grid.
    method : ``"rk4"`` (classical fixed step, the default) or ``"rk45"`` (adaptive
        Dormand–Prince 5(4) with a step size shared by the batch, tolerances `rtol`, `atol`; a
        state that needs a step below dt/100 is flagged diverged).
    saturation : None, or max |u| per input (scalar or (m,)); the input is clipped.
    record_every : record every this many steps of `dt` (the final time is always recorded).
    bound : a state with |q| or |v| above this, or non-finite, is frozen and flagged diverged.
    threads : Pinocchio threads for URDF plants (default `DEFAULT_THREADS`).

    Returns
    -------
    Trajectory with t (T_k,), x (N, T_k, n), q and v (N, T_k, nq), u (N, T_k, m), diverged (N,).
    """
    if method not in ("rk4", "rk45"):
        raise ValueError(f"method must be 'rk4' or 'rk45', got {method!r}")
    if not (dt > 0 and T >= 0 and math.isfinite(T)):
        raise ValueError(f"need dt > 0 and a finite T ≥ 0, got T={T!r}, dt={dt!r}")
    n_steps = int(round(T / dt))
    if abs(n_steps * dt - T) > 1e-9 * max(1.0, T):
        raise ValueError(f"T={T} is not a multiple of dt={dt}")
    record_every = int(record_every)
    if record_every < 1:
        raise ValueError(f"record_every must be ≥ 1, got {record_every}")

    nq, n, m = int(system.nq), int(system.n), int(system.m)
    x0 = _as_batch(x0, n, "x0")
    N = x0.shape[0]
    x_star = np.asarray(system.x_star, float)
    q_star = x_star[:nq]

    judge = _Judge(system, threads)
    rhs = _vector_field(judge, ctrl, saturation, bound, q_star, m)

    # initial (q, v); unusable initial states are diverged from the start
    bad0 = ~np.all(np.isfinite(x0), axis=1)
    x_init = np.where(bad0[:, None], x_star, x0)
    q, v = (np.asarray(a, float).reshape(N, nq) for a in system.split(x_init))
    bad0 |= _out_of_bounds(q, v, bound)
    q[bad0], v[bad0] = q_star, 0.0

    rec_steps = list(range(0, n_steps + 1, record_every))
    if rec_steps[-1] != n_steps:
        rec_steps.append(n_steps)
    K = len(rec_steps)
    X = np.empty((N, K, n))
    V = np.empty((N, K, nq))
    U = np.empty((N, K, m))
    diverged = bad0.copy()
    x_last = np.where(bad0[:, None], x_star, x0).copy()
    u_last = np.zeros((N, m))
    h_adapt = dt

    for r, step in enumerate(rec_steps):
        live = np.flatnonzero(~diverged)
        if live.size:
            dq, dv, u, x, b = rhs(q[live], v[live])
            x_last[live] = x
            u_last[live[~b]] = u[~b]
            diverged[live[b]] = True
            live, dq, dv = live[~b], dq[~b], dv[~b]
        X[:, r], V[:, r], U[:, r] = x_last, v, u_last
        if r == K - 1:
            break
        if not live.size:  # everything diverged: the rest of the record is frozen
            X[:, r + 1 :], V[:, r + 1 :], U[:, r + 1 :] = x_last[:, None], v[:, None], u_last[:, None]
            break
        first = (dq, dv, np.zeros(live.size, bool))
        n_sub = rec_steps[r + 1] - step
        if method == "rk4":
            qn, vn, b = _rk4_advance(rhs, q[live], v[live], first, n_sub, dt, bound)
        else:
            qn, vn, b, h_adapt = _rk45_advance(rhs, q[live], v[live], first, n_sub * dt, h_adapt, 1e-2 * dt, bound, rtol, atol)
        q[live[~b]], v[live[~b]] = qn[~b], vn[~b]
        diverged[live[b]] = True

    t = np.asarray(rec_steps, float) * dt
    return Trajectory(t=t, x=X, q=X[..., :nq], v=V, u=U, diverged=diverged)


# ====================================================================== metrics (DESIGN §4)
def wrap_angles(dq, angle_mask) -> np.ndarray:
    """Wrap the angle components of a difference to (−π, π].

    Parameters
    ----------
    dq : (..., k) differences (rad on angles, anything elsewhere).
    angle_mask : (k,) bool, True on angle components (e.g. ``system.angle_mask`` for x − x*,
        ``system.angle_mask[:nq]`` for q − q*).

    Returns
    -------
    (..., k) copy with the masked components in (−π, π].
    """
    dq = np.array(dq, dtype=float, copy=True)
    mask = np.asarray(angle_mask, bool)
    if mask.shape != dq.shape[-1:]:
        raise ValueError(f"angle_mask has shape {mask.shape}, expected ({dq.shape[-1]},)")
    dq[..., mask] = math.pi - np.mod(math.pi - dq[..., mask], 2.0 * math.pi)
    return dq


def _window(t: np.ndarray, window: float) -> np.ndarray:
    return t >= t[-1] - window - 1e-9 * max(1.0, abs(t[-1]))


def in_target_box(traj: Trajectory, system, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(N, T_k) bool: ‖wrap(q − q*)‖∞ ≤ tol and ‖v‖∞ ≤ tol at each sample (rad or m, per s)."""
    nq = system.nq
    dq = wrap_angles(traj.q - np.asarray(system.x_star)[:nq], np.asarray(system.angle_mask)[:nq])
    return (np.abs(dq).max(axis=-1) <= tol) & (np.abs(traj.v).max(axis=-1) <= tol)


def success(traj: Trajectory, system, window: float = SUCCESS_WINDOW, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(N,) bool: inside the target box (see `in_target_box`) at every sample of the last `window`
    seconds, and not diverged (DESIGN §4)."""
    box = in_target_box(traj, system, tol)[:, _window(traj.t, window)]
    return box.all(axis=1) & ~traj.diverged


def settled(traj: Trajectory, window: float = SUCCESS_WINDOW, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(N,) bool: at rest (‖v‖∞ ≤ tol) over the last `window` seconds and not diverged, wherever
    that is (a controller may settle at a wrong equilibrium)."""
    still = np.abs(traj.v[:, _window(traj.t, window)]).max(axis=-1) <= tol
    return still.all(axis=1) & ~traj.diverged


def settling_time(traj: Trajectory, system, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(N,) seconds: the first sample time after which the state stays in the target box until the
    end; nan if it is not in the box at the end or the row diverged."""
    box = in_target_box(traj, system, tol)
    stays = np.flip(np.logical_and.accumulate(np.flip(box, axis=1), axis=1), axis=1)
    first = np.argmax(stays, axis=1)
    out = traj.t[first].astype(float)
    out[~stays[:, -1] | traj.diverged] = np.nan
    return out


def equilibrium_offset(traj: Trajectory, system, window: float = SUCCESS_WINDOW) -> np.ndarray:
    """(N,) ‖x̄ − x*‖₂ with x̄ the mean of x = (q, p) over the last `window` seconds (angle
    components of x − x* wrapped sample by sample before averaging); nan for diverged rows."""
    dx = wrap_angles(traj.x[:, _window(traj.t, window)] - np.asarray(system.x_star), system.angle_mask)
    out = np.linalg.norm(dx.mean(axis=1), axis=-1)
    out[traj.diverged] = np.nan
    return out


def peak_input(traj: Trajectory) -> np.ndarray:
    """(N,) max over time and inputs of |u| (N·m or N) along each trajectory."""
    if traj.u.shape[1] == 0 or traj.u.shape[2] == 0:
        return np.zeros(traj.u.shape[0])
    return np.abs(traj.u).max(axis=(1, 2))


# ====================================================================== LQR baseline
class LQRController:
    """LQR on the linearisation at x*: u = u* − K wrap(x − x*), x = (q, p) (DESIGN §4 baseline).

    u* = −(gᵀg)⁻¹gᵀ f(x*) is the input that holds x* (zero for every robot whose target is an
    open-loop equilibrium; 0.5625 N for the paper's mass-spring-damper at q* = 0.5, which without it
    would settle 0.38 away from x*).

    Parameters
    ----------
    system : the `System`; ``system.linearization()`` gives A = ∂f/∂x(x*) and g(x*).
    Q : (n, n) state weight (default I).
    R : (m, m) input weight (default I).

    Attributes
    ----------
    K : (m, n) gain; S : (n, n) Riccati solution; A : (n, n); Bx : (n, m) = g(x*);
    u_star : (m,) equilibrium input; eigenvalues : (n,) complex, eig(A − Bx K), all with
    negative real parts.
    """

    def __init__(self, system, Q=None, R=None):
        A, Bx = system.linearization()
        A, Bx = np.asarray(A, float), np.asarray(Bx, float)
        n, m = Bx.shape
        Q = np.eye(n) if Q is None else np.asarray(Q, float)
        R = np.eye(m) if R is None else np.asarray(R, float)
        self.K, self.S = lqr(A, Bx, Q, R)
        self.A, self.Bx, self.Q, self.R = A, Bx, Q, R
        self.eigenvalues = np.linalg.eigvals(A - Bx @ self.K)
        self.x_star = np.asarray(system.x_star, float).copy()
        self.angle_mask = np.asarray(system.angle_mask, bool).copy()
        f_star = np.asarray(system.f(self.x_star), float)
        self.u_star = -np.linalg.lstsq(Bx, f_star, rcond=None)[0]

    def __call__(self, x) -> np.ndarray:
        """u = u* − K wrap(x − x*): (N, n) -> (N, m) (or (n,) -> (m,))."""
        x = np.asarray(x, dtype=float)
        delta = wrap_angles(x - self.x_star, self.angle_mask)
        return self.u_star - delta @ self.K.T

    def __repr__(self) -> str:
        return f"LQRController(n={self.K.shape[1]}, m={self.K.shape[0]}, max Re λ={self.eigenvalues.real.max():.4g})"


# ====================================================================== ROA
def _median(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else math.nan


@dataclass(frozen=True, eq=False)
class ControllerScore:
    """One controller's results on the ROA states (per-state arrays (N,), summaries as properties).

    Attributes
    ----------
    name : controller name.
    success : (N,) bool, DESIGN §4 criterion.
    settling_time : (N,) s, nan where never settled.
    offset : (N,) ‖x̄ − x*‖ over the last window; nan where diverged.
    settled : (N,) bool, at rest over the last window (anywhere).
    peak_input : (N,) max |u|.
    diverged : (N,) bool.
    wall_time : simulation wall time, s.
    """

    name: str
    success: np.ndarray
    settling_time: np.ndarray
    offset: np.ndarray
    settled: np.ndarray
    peak_input: np.ndarray
    diverged: np.ndarray
    wall_time: float

    @property
    def success_rate(self) -> float:
        """Fraction of states that succeed."""
        return float(self.success.mean()) if self.success.size else math.nan

    @property
    def median_settling_time(self) -> float:
        """Median settling time of the successes, s (nan if none)."""
        return _median(self.settling_time[self.success])

    @property
    def median_offset(self) -> float:
        """Median equilibrium offset of the trajectories that settle (at rest over the last window)."""
        return _median(self.offset[self.settled])

    @property
    def median_peak_input(self) -> float:
        """Median peak |u| over all states."""
        return _median(self.peak_input)

    @property
    def n_diverged(self) -> int:
        """Number of diverged states."""
        return int(self.diverged.sum())


@dataclass(frozen=True, eq=False)
class RoaResult:
    """ROA estimate of several controllers from the same uniform initial states.

    Attributes
    ----------
    system : system name.
    box : (lo, hi) evaluation box, each (n,).
    box_name : ``"domain"``, ``"half"`` or ``"custom"``.
    x0 : (N, n) initial states.
    T, dt : horizon and step, s.
    seed : seed of the states.
    scores : {controller name: ControllerScore}, in the order given.
    """

    system: str
    box: tuple[np.ndarray, np.ndarray]
    box_name: str
    x0: np.ndarray
    T: float
    dt: float
    seed: int
    scores: Mapping[str, ControllerScore]

    def __getitem__(self, name: str) -> ControllerScore:
        return self.scores[name]

    def table(self) -> str:
        """The scores side by side, one row per controller."""
        head = (
            f"ROA of {self.system}: {self.x0.shape[0]} states uniform in the {self.box_name} box "
            f"(seed {self.seed}), T = {self.T:g} s, dt = {self.dt:g} s"
        )
        cols = f"{'controller':<16}{'success':>9}{'settle s':>10}{'offset':>10}{'peak |u|':>10}{'diverged':>10}{'wall s':>9}"
        rows = [head, cols, "-" * len(cols)]
        for s in self.scores.values():
            rows.append(
                f"{s.name:<16}{100 * s.success_rate:>8.1f}%{s.median_settling_time:>10.2f}{s.median_offset:>10.2e}"
                f"{s.median_peak_input:>10.3g}{s.n_diverged:>10d}{s.wall_time:>9.1f}"
            )
        rows.append("settle, offset, peak |u|: medians over successes, settled states, all states")
        return "\n".join(rows)


def roa(
    system,
    controllers: Mapping[str, Controller],
    n: int = 200,
    box="domain",
    seed: int = 0,
    T: float = 20.0,
    dt: float = 0.01,
    *,
    method: str = "rk4",
    saturation=None,
    threads: int | None = None,
) -> RoaResult:
    """Region-of-attraction estimate: every controller from the very same `n` uniform states.

    Parameters
    ----------
    system : the `System`.
    controllers : {name: ctrl}, ctrl (N, n) -> (N, m).
    n : number of initial states.
    box : ``"domain"``, ``"half"`` or (lo, hi) (see `evaluation_box`).
    seed : seed of the uniform states.
    T, dt, method, saturation, threads : passed to `simulate`.

    Returns
    -------
    RoaResult (``.table()`` prints it).
    """
    lo, hi = evaluation_box(system, box)
    x0 = uniform_states(system, n, (lo, hi), seed)
    scores = {}
    for name, ctrl in controllers.items():
        t0 = time.perf_counter()
        traj = simulate(system, ctrl, x0, T=T, dt=dt, method=method, saturation=saturation, threads=threads)
        wall = time.perf_counter() - t0
        scores[name] = ControllerScore(
            name=name,
            success=success(traj, system),
            settling_time=settling_time(traj, system),
            offset=equilibrium_offset(traj, system),
            settled=settled(traj),
            peak_input=peak_input(traj),
            diverged=traj.diverged.copy(),
            wall_time=wall,
        )
    box_name = box if isinstance(box, str) else "custom"
    return RoaResult(
        system=getattr(system, "name", type(system).__name__),
        box=(lo, hi),
        box_name=box_name,
        x0=x0,
        T=float(T),
        dt=float(dt),
        seed=int(seed),
        scores=dict(scores),
    )
