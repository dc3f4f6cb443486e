"""Torque plans by iterative LQR within box limits, batched over many problems: `ILQRSettings`,
`ilqr_plans`.

A plan is a piecewise-constant input over K knots of dt seconds, planned in z = (q, v) on the plant
the stage plans with (`System.forward_dynamics`: Pinocchio's pooled ABA with joint damping, or the
closed form). Each problem minimises

    Σ_k dt (½ q δ_kᵀ Q δ_k + ½ σ_k δ_kᵀ E δ_k + ½ r ‖u_k/ū‖² + ½ ρ ‖e(q_k)/h‖² + ½ ρ_v ‖e_v(v_k)/v̄‖²) + ½ δ_Kᵀ E δ_K,

    δ = wrap(z − z*),  z* = (q*, 0),

with |u_i| ≤ ū_i, Q = diag(1/s²) (s: the training box's half-widths, the momenta's divided by the
diagonal of M(q*)) and the end cost E = w S_z + b Q: S_z = Tᵀ S T is the Riccati matrix S of LQR at
x* in these coordinates (T = diag(I, M(q*)), ∂(q, p)/∂(q, v) at rest), what a stabilising feedback
pays from the end state on, and b Q (`end_box`) pins every coordinate, the speeds too, which S_z
weighs little. By default q = 0: a plan only has to end where the feedback law after it takes over,
and a running state cost pulls a swing towards x* too early. σ_k = 1/`settle` over the plan's last
`settle` seconds (0 before them, and by default): the end cost is then paid per second there too, so
that the plan arrives early and rests at x* with inputs near zero, and the law after it takes over
without a jump. The rail term keeps a cart on its rail: e is
how far each linear coordinate lies beyond its URDF limits pulled in by `rail_margin` of the range
(`sim.metrics.rail_limits`; zero inside them, and for angles), h the range's half-width, ρ `rail`.
The speed term keeps each motor within its rated speed: e_v is how far each actuated joint's speed
lies beyond its URDF `<limit velocity>` v̄ pulled in by `speed_margin` of it
(`sim.metrics.speed_limits`; zero inside, for the joints the input does not drive, and without a
limit), ρ_v `speed`. A plan that whirls a motor at several times its rated speed cannot run on the
robot, and a state feedback read from such plans drives the robot there too. Both terms are summed
over every knot, the last included.

The map over a knot is RK4 with `substeps` steps on ż = (v, a(q, v, B u)). Its Jacobians come from
the continuous field's Jacobian at the knot's start, J = ∂ż/∂z and ∂ż/∂u (central differences of the
forward dynamics, one batched call), as A = exp(J dt) and B = ∫exp(J s) ds ∂ż/∂u by their Taylor
series to 4th order; the line search judges every step on the true rollout, so an approximate
Jacobian costs iterations, never accuracy.

The solver is iLQR (Li & Todorov 2004) with Levenberg-Marquardt regularisation per problem (μ·BᵀB
on Q_uu and Q_ux for the step only; the value's V_x, V_xx come from the plain terms, as in Tassa,
Erez & Todorov 2012: folded into the value, μ makes V_xx indefinite and the pass refuses) and the
box limits enforced by clamping in the backward pass (clamped inputs get no feedback: the simplest
form of Tassa, Mansard & Todorov 2014). The line search tries every step size of `alphas` for every
problem in one batched rollout; a problem that took no step keeps its Jacobians for the next pass
(its plan is unchanged, and so are they). All problems advance together in arrays (N, ...), each
with its own regularisation and acceptance, so a problem's plan does not depend on the others in
the batch beyond floating-point rounding. The last backward pass gives the feedback gains a plan is tracked
with (`plans.TrackThenLaw`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.angles import wrap_angles
from ..sim.metrics import rail_limits, speed_limits

__all__ = ["ILQRSettings", "SPEED_WEIGHT", "field_jacobians", "ilqr_plans", "plan_cost", "plan_weights", "rollout"]

#: ρ_v of the speed term where a stage bounds its plans by the motors' rated speeds (`speed_limits` of its config).
SPEED_WEIGHT = 1e3

#: Relative step of the central differences of the forward dynamics.
_FD = 1e-6
#: A backward pass's Q_uu (regularised) counts as singular where λ_min ≤ this × λ_max: two inputs that
#: act alike, or one that acts on nothing, with no input cost. Its problem then takes no step and its
#: μ grows, as for an indefinite Q_uu; a plan that never steps stays its warm start, at its own cost.
_QUU_RTOL = 1e-14


@dataclass(frozen=True)
class ILQRSettings:
    """The iLQR solve of a batch of plans.

    Attributes
    ----------
    iterations : iLQR iterations (backward pass, batched line search).
    substeps : RK4 steps per knot of the plant's rollout.
    q : weight of the running state cost ½ δᵀQδ.
    r : weight of the input's ‖u/ū‖² against the state's cost.
    terminal : weight w of the end state's ½ δᵀS_zδ.
    alphas : step sizes the line search tries, largest first.
    mu0 : initial Levenberg-Marquardt regularisation of the step (μ I added to V_xx in Q_uu, Q_ux).
    rail : weight ρ of the rail term (module docstring); 0 leaves it out.
    rail_margin : share of a rail's range its limits are pulled in by, on each side.
    speed : weight ρ_v of the speed term (module docstring); 0 (the default) leaves it out.
    speed_margin : share of a speed limit it is pulled in by.
    end_box : weight b of the end cost's b Q term (module docstring).
    settle : seconds at the plan's end over which the end cost is also paid per second; 0: none.
    """

    iterations: int = 12
    substeps: int = 1
    q: float = 0.0
    r: float = 0.01
    terminal: float = 10.0
    alphas: tuple = (1.0, 0.3, 0.1)
    mu0: float = 1e-3
    rail: float = 1e3
    rail_margin: float = 0.1
    speed: float = 0.0
    speed_margin: float = 0.1
    end_box: float = 0.0
    settle: float = 0.0


def _accel(system, z, u):
    """v̇ = a(q, v, B u): z (N, 2 nq), u (N, m) -> (N, nq)."""
    nq = system.nq
    return system.forward_dynamics(z[:, :nq], z[:, nq:], u @ np.asarray(system.B, float).T)


def _field(system, z, u):
    """ż = (v, a(q, v, B u)): (N, 2 nq), (N, m) -> (N, 2 nq)."""
    return np.concatenate([z[:, system.nq :], _accel(system, z, u)], axis=1)


def _step(system, z, u, h):
    """One RK4 step of length h (s) with u held: (N, 2 nq) -> (N, 2 nq)."""
    k1 = _field(system, z, u)
    k2 = _field(system, z + 0.5 * h * k1, u)
    k3 = _field(system, z + 0.5 * h * k2, u)
    k4 = _field(system, z + h * k3, u)
    return z + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)


def rollout(system, z0: np.ndarray, U: np.ndarray, dt: float, substeps: int) -> np.ndarray:
    """States (N, K + 1, 2 nq) of the plant from z0 (N, 2 nq) under the held inputs U (N, K, m), knots of dt s.
    A non-finite state is replaced by 1e6 (its cost is then infinite)."""
    h = dt / substeps
    Z = np.empty((U.shape[0], U.shape[1] + 1, z0.shape[1]))
    Z[:, 0] = z = z0
    for k in range(U.shape[1]):
        for _ in range(substeps):
            z = _step(system, z, U[:, k], h)
        z = np.where(np.isfinite(z), z, 1e6)
        Z[:, k + 1] = z
    return Z


def field_jacobians(system, z: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """∂ż/∂z (N, 2 nq, 2 nq) and ∂ż/∂u (N, 2 nq, m) at (z, u), by central differences of the forward
    dynamics (every perturbed state in one batched call)."""
    N, n = z.shape
    nq, m = system.nq, u.shape[1]
    hz = _FD * np.maximum(1.0, np.abs(z))  # (N, n)
    hu = _FD * np.maximum(1.0, np.abs(u))  # (N, m)
    Ez = np.eye(n)[None] * hz[:, :, None]  # (N, n, n): row i perturbs coordinate i
    Eu = np.eye(m)[None] * hu[:, :, None]
    zs = np.concatenate([z[:, None] + Ez, z[:, None] - Ez, np.repeat(z[:, None], 2 * m, 1)], axis=1)
    us = np.concatenate([np.repeat(u[:, None], 2 * n, 1), u[:, None] + Eu, u[:, None] - Eu], axis=1)
    a = _accel(system, zs.reshape(-1, n), us.reshape(-1, m)).reshape(N, 2 * (n + m), nq)
    da_dz = ((a[:, :n] - a[:, n : 2 * n]) / (2 * hz[:, :, None])).transpose(0, 2, 1)  # (N, nq, n)
    da_du = ((a[:, 2 * n : 2 * n + m] - a[:, 2 * n + m :]) / (2 * hu[:, :, None])).transpose(0, 2, 1)  # (N, nq, m)
    J = np.zeros((N, n, n))
    J[:, :nq, nq:] = np.eye(nq)
    J[:, nq:] = da_dz
    G = np.zeros((N, n, m))
    G[:, nq:] = da_du
    return J, G


def _knot_jacobians(system, z, u, dt):
    """A = exp(J dt) (N, n, n) and B = ∫₀^dt exp(J s) ds G (N, n, m) by their Taylor series to 4th order."""
    J, G = field_jacobians(system, z, u)
    Jdt = J * dt
    eye = np.broadcast_to(np.eye(z.shape[1]), Jdt.shape)
    P, A, Phi, fact = eye, eye.copy(), eye.copy(), 1.0
    for i in range(1, 5):
        P = P @ Jdt
        fact *= i
        A = A + P / fact
        Phi = Phi + P / (fact * (i + 1))
    return A, dt * Phi @ G


def plan_weights(system, S: np.ndarray, settings: ILQRSettings, bound: np.ndarray):
    """(q Q (n, n), the end cost E (n, n), r/ū² (m,)) of the cost in z = (q, v) (module docstring)."""
    nq = system.nq
    lo, hi = (np.asarray(b, float) for b in system.domain)
    M_star = np.asarray(system.mass_matrix(np.asarray(system.x_star, float)[:nq][None]), float)[0]
    half = np.maximum(0.5 * (hi - lo), 1e-9)
    half[nq:] = half[nq:] / np.maximum(np.diag(M_star), 1e-12)
    T = np.eye(2 * nq)
    T[nq:, nq:] = M_star
    Q = np.diag(1.0 / half**2)
    return settings.q * Q, settings.terminal * (T.T @ np.asarray(S, float) @ T) + settings.end_box * Q, settings.r / np.maximum(bound, 1e-9) ** 2


def settle_weights(K: int, dt: float, settle: float) -> np.ndarray:
    """σ_k (K,) of the module docstring: 1/settle on the knots that start within the last `settle`
    seconds of K knots of dt s, 0 before them (all 0 when settle is 0)."""
    if settle <= 0:
        return np.zeros(K)
    return np.where(np.arange(K) * dt >= K * dt - settle - 1e-9, 1.0 / settle, 0.0)


def _state_limits(system, settings: ILQRSettings):
    """(lower (n,), upper (n,), weight (n,)) over z = (q, v) of the rail and speed terms (module
    docstring): the limits pulled in by their margins (∓∞ where there is none) and the weight per
    coordinate; None when no coordinate has a limit or both terms are off."""
    lower, upper = rail_limits(system)
    rail = np.isfinite(lower) & np.isfinite(upper) & (upper > lower) & (settings.rail > 0)
    half = np.where(rail, 0.5 * (upper - lower), 1.0)
    pull = settings.rail_margin * 2 * half
    limit = speed_limits(system)
    speed = np.isfinite(limit) & (settings.speed > 0)
    vmax = np.where(speed, limit, 1.0)
    if not (rail.any() or speed.any()):
        return None
    top = np.where(speed, (1.0 - settings.speed_margin) * vmax, np.inf)
    hi = np.concatenate([np.where(rail, upper - pull, np.inf), top])
    lo = np.concatenate([np.where(rail, lower + pull, -np.inf), -top])
    weight = np.concatenate([np.where(rail, settings.rail / half**2, 0.0), np.where(speed, settings.speed / vmax**2, 0.0)])
    return lo, hi, weight


def _limit_terms(Z, limits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rail and speed terms at states Z (..., n) in (q, v): their value ½ Σ w_i e_i² (...), w the
    weights of `_state_limits` (ρ/h², ρ_v/v̄²), gradient w e and Hessian diagonal (w where e ≠ 0), both (..., n)."""
    lower, upper, weight = limits
    e = np.maximum(Z - upper, 0.0) + np.minimum(Z - lower, 0.0)  # zero where there is no rail (limits ∓∞)
    grad = weight * e
    return 0.5 * (e * grad).sum(-1), grad, np.where(e != 0.0, weight, 0.0)


def _error(system, Z):
    nq = system.nq
    z_star = np.concatenate([np.asarray(system.x_star, float)[:nq], np.zeros(nq)])
    return wrap_angles(Z - z_star, np.asarray(system.angle_mask, bool))


def plan_cost(system, Z: np.ndarray, U: np.ndarray, Q, Sz, r_scaled, dt, limits=None, sigma=None) -> np.ndarray:
    """The plans' costs (N,) for states Z (N, K + 1, n) in (q, v) and inputs U (N, K, m) (module
    docstring; Sz: the end cost E); `limits`: `_state_limits`'s triple, or None for no rail or speed term; `sigma`: the
    `settle_weights` (K,), or None for none."""
    d = _error(system, Z)
    run = 0.5 * dt * (np.einsum("nki,ij,nkj->n", d[:, :-1], Q, d[:, :-1]) + np.einsum("nki,i,nki->n", U, r_scaled, U))
    if sigma is not None and np.any(sigma):
        run = run + 0.5 * dt * np.einsum("k,nki,ij,nkj->n", sigma, d[:, :-1], Sz, d[:, :-1])
    if limits is not None:
        run = run + dt * _limit_terms(Z, limits)[0].sum(1)
    cost = run + 0.5 * np.einsum("ni,ij,nj->n", d[:, -1], Sz, d[:, -1])
    return np.where(np.isfinite(cost), cost, np.inf)


def ilqr_plans(system, x0: np.ndarray, U0: np.ndarray, bound: np.ndarray, horizon: float, S: np.ndarray,
               settings: ILQRSettings = ILQRSettings()) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Plans within ±bound (m,) from the starts x0 (N, n) = (q, p), warm-started at U0 (N, K, m), K
    knots over `horizon` s; S (n, n): LQR's Riccati matrix in (q, p). Returns (U (N, K, m), the
    planned states Z (N, K + 1, n) in (q, v), the feedback gains (N, K, m, n) on wrap(z − Z_k), the
    costs (N,)). A problem whose rollout blows up gets an infinite cost and takes no step (numpy's
    overflow warnings of its rows are silenced)."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _solve(system, x0, U0, bound, horizon, S, settings)


def _solve(system, x0, U0, bound, horizon, S, settings):
    """`ilqr_plans`' iterations."""
    N, K, m = U0.shape
    dt = horizon / K
    Q, Sz, r_scaled = plan_weights(system, S, settings, bound)
    limits = _state_limits(system, settings)
    sigma = settle_weights(K, dt, settings.settle)
    q0, v0 = system.split(x0)
    U = np.clip(U0, -bound, bound)
    Z = rollout(system, np.concatenate([q0, v0], axis=1), U, dt, settings.substeps)
    n = Z.shape[2]
    cost = plan_cost(system, Z, U, Q, Sz, r_scaled, dt, limits, sigma)
    mu = np.full(N, settings.mu0)
    alphas = np.asarray(settings.alphas)
    L = len(alphas)
    A, B = np.empty((N, K, n, n)), np.empty((N, K, n, m))
    moved = np.ones(N, bool)  # problems whose plan changed since their Jacobians were computed
    for it in range(settings.iterations + 1):  # the last pass only gives the gains of the final plan
        if moved.any():  # a problem that took no step keeps its Jacobians: the same rows give the same arrays
            Am, Bm = _knot_jacobians(system, Z[moved, :-1].reshape(-1, n), U[moved].reshape(-1, m), dt)
            A[moved], B[moved] = Am.reshape(-1, K, n, n), Bm.reshape(-1, K, n, m)
        kff, gains, ok = _backward(system, Z, U, A, B, Q, Sz, r_scaled, dt, mu, bound, limits, sigma)
        if it == settings.iterations:
            break
        # batched line search: every problem tries every alpha in one rollout
        rep = lambda a: np.repeat(a[:, None], L, 1).reshape((N * L,) + a.shape[1:])  # noqa: E731
        Zn, Un = _forward(system, rep(Z), rep(U), (alphas[None, :, None, None] * kff[:, None]).reshape(N * L, K, m), rep(gains), bound, dt, settings.substeps)
        cn = plan_cost(system, Zn, Un, Q, Sz, r_scaled, dt, limits, sigma).reshape(N, L)
        best = np.argmin(cn, axis=1)
        better = ok & (cn[np.arange(N), best] < cost)
        idx = (np.arange(N) * L + best)[better]
        Z[better], U[better], cost[better] = Zn[idx], Un[idx], cn[better, best[better]]
        moved = better
        mu = np.where(better, np.maximum(mu / 4.0, 1e-8), np.minimum(mu * 10.0, 1e8))
    return U, Z, gains, cost


def _backward(system, Z, U, A, B, Q, Sz, r_scaled, dt, mu, bound, limits=None, sigma=None):
    """The backward pass: feed-forward k (N, K, m), gains (N, K, m, n), and which problems' passes
    stayed positive definite (N,). Inputs whose step lands beyond the limit are clamped there and
    get no feedback. `limits`: `_state_limits`'s triple, or None; `sigma`: `settle_weights` (K,), or None."""
    N, K, m = U.shape
    n = Z.shape[2]
    d = _error(system, Z)
    Vx = d[:, -1] @ Sz
    Vxx = np.broadcast_to(Sz, (N, n, n)).copy()
    if limits is not None:  # the rail and speed terms' gradient and Hessian diagonal (× dt) at every knot, the last included
        _, g, h = _limit_terms(Z, limits)
        lx, lxx = dt * g, dt * h  # (N, K + 1, n)
        Vx += lx[:, -1]
        Vxx[:, range(n), range(n)] += lxx[:, -1]
    kff, gains = np.zeros((N, K, m)), np.zeros((N, K, m, n))
    ok = np.ones(N, bool)
    R = np.diag(r_scaled) * dt
    reg = mu[:, None, None] * np.eye(n)
    for k in range(K - 1, -1, -1):
        Ak, Bk = A[:, k], B[:, k]
        At, Bt = np.swapaxes(Ak, 1, 2), np.swapaxes(Bk, 1, 2)
        Qk = Q if sigma is None or not sigma[k] else Q + sigma[k] * Sz
        Qx, Qxx = dt * d[:, k] @ Qk, np.broadcast_to(dt * Qk, (N, n, n))
        if limits is not None:
            Qxx = Qxx.copy()
            Qx = Qx + lx[:, k]
            Qxx[:, range(n), range(n)] += lxx[:, k]
        Qx = Qx + np.einsum("nij,nj->ni", At, Vx)
        Qu = dt * U[:, k] * r_scaled + np.einsum("nij,nj->ni", Bt, Vx)
        Qxx = Qxx + At @ Vxx @ Ak
        Quu = R + Bt @ Vxx @ Bk
        Qux = Bt @ Vxx @ Ak
        Quu = 0.5 * (Quu + np.swapaxes(Quu, 1, 2))
        Quu_r = Quu + Bt @ reg @ Bk  # the step from the regularised terms, the value from the plain ones (Tassa et al. 2012)
        Qux_r = Qux + Bt @ reg @ Ak
        finite = np.isfinite(Quu_r).all((1, 2)) & np.isfinite(Qux_r).all((1, 2)) & np.isfinite(Qu).all(1) & np.isfinite(Qx).all(1)
        Quu, Qux = np.where(finite[:, None, None], Quu, np.eye(m)), np.where(finite[:, None, None], Qux, 0.0)
        Quu_r, Qux_r = np.where(finite[:, None, None], Quu_r, np.eye(m)), np.where(finite[:, None, None], Qux_r, 0.0)
        Qu, Qx, Qxx = np.where(finite[:, None], Qu, 0.0), np.where(finite[:, None], Qx, 0.0), np.where(finite[:, None, None], Qxx, 0.0)
        lam = np.linalg.eigvalsh(Quu_r)
        pd = lam[:, 0] > _QUU_RTOL * np.abs(lam[:, -1])  # singular or indefinite: no step (μ grows)
        ok &= pd & finite  # a problem whose pass broke down takes no step this iteration
        Quu_r = np.where(pd[:, None, None], Quu_r, np.eye(m))  # its step is not taken; any invertible Quu will do
        inv = _inverse(Quu_r)
        target = U[:, k] - np.einsum("nij,nj->ni", inv, Qu)
        clamped = (target > bound) | (target < -bound)
        kk = np.clip(target, -bound, bound) - U[:, k]
        KK = np.where(clamped[:, :, None], 0.0, -inv @ Qux_r)
        kff[:, k], gains[:, k] = kk, KK
        KKt = np.swapaxes(KK, 1, 2)
        Vx = Qx + np.einsum("nij,nj->ni", KKt, np.einsum("nij,nj->ni", Quu, kk) + Qu) + np.einsum("nji,nj->ni", Qux, kk)
        Vxx = Qxx + KKt @ Quu @ KK + KKt @ Qux + np.swapaxes(Qux, 1, 2) @ KK
        Vxx = 0.5 * (Vxx + np.swapaxes(Vxx, 1, 2))
    return kff, gains, ok


def _inverse(M: np.ndarray) -> np.ndarray:
    """Inverses (N, m, m) of the symmetric matrices M (N, m, m) whose λ_min > `_QUU_RTOL`·λ_max:
    numpy's LU, or where it meets a zero pivot all the same, the eigendecomposition (which cannot)."""
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:
        lam, V = np.linalg.eigh(M)
        return (V / lam[:, None, :]) @ np.swapaxes(V, 1, 2)


def _forward(system, Z, U, kff, gains, bound, dt, substeps):
    """Roll the updated policy u_k = clip(U_k + k_k + K_k wrap(z_k − Z_k)) out on the plant."""
    N, K, m = U.shape
    h = dt / substeps
    Zn, Un = np.empty_like(Z), np.empty_like(U)
    Zn[:, 0] = z = Z[:, 0]
    mask = np.asarray(system.angle_mask, bool)
    for k in range(K):
        u = np.clip(U[:, k] + kff[:, k] + np.einsum("nij,nj->ni", gains[:, k], wrap_angles(z - Z[:, k], mask)), -bound, bound)
        Un[:, k] = u = np.where(np.isfinite(u), u, 0.0)
        for _ in range(substeps):
            z = _step(system, z, u, h)
        Zn[:, k + 1] = z = np.where(np.isfinite(z), z, 1e6)
    return Zn, Un
