"""The checks a certificate is made of, each a pure function of the samples it is given.

* `check_structural`: conditions (i)–(iii) of Proposition 3 (J_d skew, R_d ≻ 0, ∇²H_d ≻ 0,
  H_d(x*) = 0, ∇H_d(x*) = 0, H_d > 0 off x*);
* `check_dissipation`: eq. damping_assign_relax_tilde on the samples with H_d ≥ a level;
* `local_stability`: eigenvalues of the true closed loop's Jacobian at x*;
* `face_samples` and `boundary_min`: the minimum of a Lyapunov function (``H_d`` and ``grad_H_d``:
  H_d, or LQR's δᵀSδ) on the faces of a box, which bounds a sublevel set that stays inside it
  (`idapbc_pin.certificate.region`);
* `settled_equilibrium`: where the true closed loop settles, simulated.
"""

from __future__ import annotations

import math

import numpy as np

from ..model.angles import wrap_angles
from ..sim.integrate import simulate
from ..sim.metrics import SUCCESS_WINDOW, settled, success
from ..sim.states import uniform_states
from .result import Dissipation, Equilibrium, LocalStability, Structural
from .terms import ClosedLoopTerms, _f64, eigenvalues_at_target, hessians

__all__ = ["boundary_min", "check_dissipation", "check_structural", "face_samples", "local_stability", "settled_equilibrium"]


def check_structural(ctrl, system, terms: ClosedLoopTerms, n_hessian: int) -> Structural:
    """Conditions (i)–(iii) on the samples ``terms.x`` (N, n); ∇²H_d on the first `n_hessian`.

    They are properties of the weights, so they are checked in float64 (``ctrl.in_float64()``
    where the controller has it): a float32 network rounds an R_d whose eigenvalues span more
    than ~10⁷ into an indefinite matrix."""
    exact = ctrl.in_float64() if hasattr(ctrl, "in_float64") else ctrl
    x, J = terms.x, terms.J
    R = terms.R if exact is ctrl else _f64(exact.R_d(x))
    ctrl = exact
    x_star = _f64(system.x_star)
    H_star = float(_f64(ctrl.H_d(x_star[None])).ravel()[0])
    g_star = float(np.linalg.norm(_f64(ctrl.grad_H_d(x_star[None])).ravel()))
    sub = x[: min(int(n_hessian), x.shape[0])]
    hess, hess_source = hessians(ctrl, sub)
    dist2 = ((x - x_star) ** 2).sum(axis=1)
    return Structural(
        max_J_skew_error=float(np.abs(J + np.swapaxes(J, 1, 2)).max()),
        max_J=float(np.abs(J).max()),
        min_eig_R=float(np.linalg.eigvalsh(0.5 * (R + np.swapaxes(R, 1, 2)))[:, 0].min()),
        max_R_asymmetry=float(np.abs(R - np.swapaxes(R, 1, 2)).max()),
        min_eig_hessian=float(np.linalg.eigvalsh(hess)[:, 0].min()),
        n_hessian=int(sub.shape[0]),
        hessian_source=hess_source,
        H_at_target=H_star,
        grad_norm_at_target=g_star,
        min_H_off_target=float(terms.H.min()),
        min_H_over_dist2=float((terms.H / np.maximum(dist2, 1e-300)).min()),
        median_H=float(np.median(terms.H)),
        median_grad_norm=float(np.median(np.linalg.norm(terms.dH, axis=1))),
    )


def check_dissipation(t: ClosedLoopTerms, level: float) -> Dissipation:
    """The dissipation inequality on the samples with H_d ≥ `level` (0: every sample)."""
    sel = t.H >= level
    margin = t.margin[sel]
    if not margin.size:
        return Dissipation(level, 0, math.nan, math.nan, None, math.nan)
    k = int(np.argmin(margin))
    return Dissipation(
        level=float(level),
        n_checked=int(sel.sum()),
        fraction_satisfied=float(np.mean(margin > 0)),
        worst_margin=float(margin[k]),
        worst_state=t.x[sel][k].tolist(),
        fraction_literal_sign=float(np.mean(t.margin_literal_sign[sel] > 0)),
    )


def local_stability(ctrl, system) -> LocalStability:
    """Eigenvalues of the true closed loop's Jacobian at x* (see `eigenvalues_at_target`)."""
    eig, source = eigenvalues_at_target(ctrl, system)
    return LocalStability([[float(z.real), float(z.imag)] for z in eig], float(np.max(eig.real)), source)


def face_samples(lo: np.ndarray, hi: np.ndarray, n_per_face: int, rng) -> list[tuple[int, float, np.ndarray]]:
    """`n_per_face` uniform samples on each of the 2n faces of the box [lo, hi]:
    [(coordinate i, its value on the face, (n_per_face, n) points)], faces lo_0, hi_0, lo_1, …"""
    n = lo.size
    faces = []
    for i in range(n):
        for side in (lo[i], hi[i]):
            pts = lo + (hi - lo) * rng.random((n_per_face, n))
            pts[:, i] = side
            faces.append((i, side, pts))
    return faces


def boundary_min(ctrl, lo: np.ndarray, hi: np.ndarray, faces) -> tuple[float, np.ndarray]:
    """min of ``ctrl.H_d`` on the faces of the box [lo, hi]: the best of each face's samples
    (`face_samples`), refined by L-BFGS-B on that face with ``ctrl.grad_H_d``; -> (value, (n,) state)."""
    from scipy.optimize import minimize

    n, n_per_face = lo.size, faces[0][2].shape[0]
    H = _f64(ctrl.H_d(np.concatenate([p for _, _, p in faces]))).reshape(len(faces), n_per_face)
    best_val, best_x = math.inf, None
    for (i, side, pts), h in zip(faces, H):
        k = int(np.argmin(h))
        x0, v0 = pts[k].copy(), float(h[k])
        free = np.array([j != i for j in range(n)])

        def fun(z, i=i, side=side):
            x = np.empty(n)
            x[free], x[i] = z, side
            val = float(_f64(ctrl.H_d(x[None])).ravel()[0])
            grad = _f64(ctrl.grad_H_d(x[None])).ravel()[free]
            return val, grad

        try:
            res = minimize(fun, x0[free], jac=True, method="L-BFGS-B", bounds=list(zip(lo[free], hi[free])), options={"maxiter": 200})
            if np.isfinite(res.fun) and res.fun < v0:
                x0[free], v0 = res.x, float(res.fun)
        except (ValueError, FloatingPointError):  # keep the sampled minimum
            pass
        if v0 < best_val:
            best_val, best_x = v0, x0
    return best_val, best_x


def settled_equilibrium(ctrl, system, n_each: int, T: float, dt: float | None, seed: int, limits: bool = True) -> Equilibrium:
    """Simulate `n_each` states near x* and `n_each` in the half box (effort limits applied unless
    `limits` is False); where do they settle?"""
    x_star = _f64(system.x_star)
    lo, hi = (_f64(b) for b in system.domain)
    half_width = 0.5 * (hi - lo)
    near = uniform_states(system, n_each, (x_star - 0.05 * half_width, x_star + 0.05 * half_width), seed)
    far = uniform_states(system, n_each, "half", seed + 1)
    traj = simulate(system, ctrl, np.concatenate([near, far]), T=T, dt=dt, limits=limits)
    window = traj.t >= traj.t[-1] - SUCCESS_WINDOW - 1e-9
    dx = wrap_angles(traj.x[:, window] - x_star, system.angle_mask).mean(axis=1)  # (N, n) x̄_k − x*
    still = settled(traj)
    offsets = np.linalg.norm(dx, axis=1)
    near_ok = still[:n_each]
    x_bar = (x_star + dx[:n_each][near_ok].mean(axis=0)).tolist() if near_ok.any() else None
    offset = float(np.linalg.norm(np.asarray(x_bar) - x_star)) if x_bar is not None else math.nan
    return Equilibrium(
        n_near=n_each,
        n_half_box=n_each,
        n_settled=int(still.sum()),
        n_success=int(success(traj, system).sum()),
        x_bar=x_bar,
        offset=offset,
        max_offset=float(offsets[still].max()) if still.any() else math.nan,
        T=float(T),
    )
