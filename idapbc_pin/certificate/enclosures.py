"""Interval enclosures of the true closed loop and of V̇ over boxes of states: what
`idapbc_pin.certificate.verified` bounds.

For a batch of boxes X (an `Interval` of shape (N, n)) they return intervals that contain, for every
state in each box, the value in exact arithmetic of:

* the open loop f(x), for plants written in closed form (`plant_enclosure`: the paper's
  mass-spring-damper and its two-coordinate mechanical plants); a URDF plant has no interval form
  here (Pinocchio computes in floating point);
* ∇H_d(x) and f̃_d(x) = (J_d − R_d)∇H_d of the controller as deployed (`FlowEnclosure`, formula for
  formula the numpy `DesiredFlow`, its float32 or float64 weights taken exactly in float64);
* the true loop F = f + g·sat(u), u = (gᵀg)⁻¹gᵀ(f̃_d − f), and V̇ = ∇Vᵀ F, for H_d (`flow_rate`) and
  for LQR's δᵀSδ (`lqr_rate`). Where no box state saturates, F = (I − Π)f + Πf̃_d with Π = g(gᵀg)⁻¹gᵀ
  is used: the same field, with f entering once.
"""

from __future__ import annotations

import numpy as np

from ..control.desired_flow import DesiredFlow
from ..model.analytic import CosCoupledPlant, MassSpringDamperPlant
from ..recovery.box_law import BoxFallback
from .interval import Interval

__all__ = ["FlowEnclosure", "NoEnclosure", "enclosable", "flow_rate", "lqr_rate", "plant_enclosure"]


class NoEnclosure(Exception):
    """The loop has a part without an interval form here (the reason is the message)."""


def _msd(plant: MassSpringDamperPlant, X: Interval) -> Interval:
    """The mass-spring-damper: (p, (−(k + ½q²)q − b p²(1 + |p|))/m)."""
    q, p = X[:, 0], X[:, 1]
    spring = (q.square() * 0.5 + plant.k) * q
    friction = p.square() * (p.abs() + 1.0) * plant.b
    acc = (-(spring + friction)) * Interval.point(plant.m).reciprocal()
    return Interval.stack([p, acc], axis=1)


def _cos_coupled(plant: CosCoupledPlant, X: Interval) -> Interval:
    """M(q) = diag(d) + k cos(aᵀq)(E₁₂ + E₂₁), U = Σ cᵢ(1 + cos qᵢ): v = M⁻¹p and
    ṗⱼ = −k aⱼ sin(aᵀq) v₁v₂ + cⱼ sin qⱼ (`model.analytic`, `model._mechanics`)."""
    q, p = X[:, :2], X[:, 2:]
    s = q @ plant.a[:, None]
    kc, ks = s.cos()[:, 0] * plant.k, s.sin()[:, 0] * plant.k
    d1, d2 = plant.diag
    inv_det = (kc.square() * -1.0 + Interval.point(d1) * d2).meet((1 - 1e-12) * (d1 * d2 - plant.k**2)).reciprocal()  # det ≥ d₁d₂ − k² > 0
    p1, p2 = p[:, 0], p[:, 1]
    v1 = (p1 * d2 - kc * p2) * inv_det
    v2 = (p2 * d1 - kc * p1) * inv_det
    sq = q.sin()
    vv = v1 * v2
    pdot = [ks * vv * (-plant.a[j]) + sq[:, j] * plant.c[j] for j in range(2)]
    return Interval.stack([v1, v2, *pdot], axis=1)


def enclosable(system, fallback=None) -> str | None:
    """None when the loop of `system` (with the outer law `fallback`) has an interval form here, else why not."""
    plant = getattr(system, "plant", system)
    if not isinstance(plant, (MassSpringDamperPlant, CosCoupledPlant)):
        return f"no interval form of the {type(plant).__name__} plant (the closed-form paper plants have one)"
    if fallback is not None and not isinstance(fallback, BoxFallback):
        return f"no interval form of the outer law {type(fallback).__name__}"
    if fallback is not None and fallback.inside_ramp[1] > 0:
        return "no interval form of the outer law's ramped inside gain"
    return None


def plant_enclosure(system, X: Interval) -> Interval:
    """f over the boxes X (N, n) -> (N, n)."""
    if isinstance(system.plant, MassSpringDamperPlant):
        return _msd(system.plant, X)
    if isinstance(system.plant, CosCoupledPlant):
        return _cos_coupled(system.plant, X)
    raise NoEnclosure(enclosable(system))


def _mlp(net, U: Interval) -> Interval:
    """An `Mlp` of the flow over boxes of its input."""
    last = len(net.weights) - 1
    for k, (W, b) in enumerate(zip(net.weights, net.biases)):
        U = U @ np.asarray(W, np.float64).T
        U = U if b is None else U + np.asarray(b, np.float64)
        if k < last:
            U = U.tanh() if net.activation == "tanh" else U.softplus()
    return U


class FlowEnclosure:
    """∇H_d, H_d and f̃_d of a `DesiredFlow` over boxes of states (module doc)."""

    def __init__(self, flow: DesiredFlow):
        self.flow = flow
        f64 = lambda a: None if a is None else np.asarray(a, np.float64)  # noqa: E731
        self.x_star, self.x_scale = f64(flow.x_star), f64(flow.x_scale)
        self.inv_scale = Interval.point(self.x_scale).reciprocal()  # 1/x_scale, rounded outward
        self.W_in, self.b_in = f64(flow.icnn_in[0]), f64(flow.icnn_in[1])
        self.W_z = [f64(W) for W in flow.icnn_z]
        self.out, self.h0, self.g0 = f64(flow.icnn_out), f64(flow.icnn_h0), f64(flow.icnn_g0)
        self.map, self.eps, self.P = f64(flow.icnn_map), float(flow.eps), f64(flow.P)
        self.depth, self.width = len(flow.icnn_x), self.out.shape[0]

    def _icnn(self, d: Interval):
        u = d * self.inv_scale if self.map is None else d @ self.map.T
        inputs = u @ self.W_in + self.b_in
        z, slopes = None, []
        for k in range(self.depth):
            a = inputs[:, k * self.width : (k + 1) * self.width]
            a = a if k == 0 else z @ self.W_z[k - 1].T + a
            z, slope = a.softplus(), a.expit()
            slopes.append(slope)
        s = (z @ self.out[:, None])[:, 0] - self.h0 - (u @ self.g0[:, None])[:, 0] + (d.square() * self.eps).sum(-1)
        return s, slopes

    def value_and_grad(self, X: Interval) -> tuple[Interval, Interval, np.ndarray]:
        """H_d (N,), ∇H_d (N, n) over the boxes X (N, n), and ``tangent`` (N,) bool: for a point box,
        H_d's tangent plane there bounds H_d from below everywhere. s = D + ε‖δ‖² is convex (the
        stored Ĥ(0), ∇Ĥ(0) only add an affine term), and ψ is convex, so this holds in the free form
        (H_d = s) and, in the anchored form, where s ≥ 0 (ψ non-decreasing there; rounding in the
        stored constants can make s dip below 0 near x*)."""
        d = X - self.x_star
        s, slopes = self._icnn(d)
        delta, parts = Interval.point(self.out), [None] * self.depth
        for k in range(self.depth - 1, -1, -1):
            parts[k] = slopes[k] * delta
            if k > 0:
                delta = parts[k] @ self.W_z[k - 1]
        g = Interval.concat(parts, axis=1) @ self.W_in.T - self.g0
        dD = g * self.inv_scale if self.map is None else g @ self.map
        ds = dD + d * (2 * self.eps)
        if self.P is None:
            return s, ds, np.ones(X.shape[0], bool)
        quad = (d @ self.P * d).sum(-1) * 0.5
        return quad + s.psi(), d @ self.P + ds * s.ratio_one_plus()[:, None], s.lo >= 0

    def _J(self, u: Interval) -> Interval:
        fl = self.flow
        v = _mlp(fl.j_net, u)
        if fl.j0 is not None:
            v = v - np.asarray(fl.j_at_target, np.float64)
        K = (v @ np.asarray(fl.skew_basis, np.float64)).reshape(-1, fl.n, fl.n)
        return K if fl.j0 is None else K + np.asarray(fl.j0, np.float64)

    def _L(self, u: Interval) -> Interval:
        fl, n = self.flow, self.flow.n
        out = _mlp(fl.r_net, u)
        r_d, r_o = out[:, :n], out[:, n:]
        s = None if fl.row_scale is None else np.asarray(fl.row_scale, np.float64)
        if fl.l0 is None:
            diag = r_d.softplus()
            entries = Interval.concat([diag, r_o], axis=1)
            entries = entries if s is None else entries * s
        else:
            at = np.asarray(fl.r_at_target, np.float64)
            diag = (r_d + (np.asarray(fl.log_d0, np.float64) - at[:n])).exp()
            step = r_o - at[n:]
            step = step if s is None else step * s[n:]
            low = step + np.asarray(fl.l0, np.float64)
            entries = Interval.concat([diag, low], axis=1)
        return (entries @ np.asarray(fl.lower_basis, np.float64)).reshape(-1, n, n)

    def f_d(self, X: Interval) -> tuple[Interval, Interval, Interval, np.ndarray]:
        """(H_d (N,), ∇H_d (N, n), f̃_d (N, n), tangent (N,)) over the boxes X (N, n) (`value_and_grad`)."""
        fl = self.flow
        H, grad, tangent = self.value_and_grad(X)
        u = (X - self.x_star) * self.inv_scale
        if fl.input_bound is not None:
            b = float(fl.input_bound)
            u = u.clip(-b, b)
        col = grad[:, None, :]
        L = self._L(u)
        Lt_col = (L.swap(1, 2) * col).sum(-1)
        f_d = (self._J(u) * col).sum(-1) - (L * Lt_col[:, None, :]).sum(-1)
        if fl.rho:
            f_d = f_d - (Interval.point(np.asarray(fl.S, np.float64)) * float(fl.rho) * col).sum(-1)
        return H, grad, f_d, tangent


def _input_matrix(system) -> np.ndarray:
    """g (n, m), constant for every system here (g = [0; B])."""
    return np.asarray(system.g(np.asarray(system.x_star, float)), np.float64)


def _loop(g: np.ndarray, f: Interval, u: Interval, bound, target: Interval | None = None, exact=None) -> Interval:
    """F = f + g·sat(u) over the boxes; ``target`` (the same field where u is the learned law and is
    not clipped, Πf̃_d + (I − Π)f) is intersected in on the rows of ``exact`` where u stays within the bound."""
    if bound is None:
        sat, free = u, np.ones(u.shape[0], bool)
    else:
        b = np.asarray(bound, np.float64)
        sat = u.clip(-b, b)
        free = np.all((u.lo >= -b) & (u.hi <= b), axis=1)
    F = f + sat @ g.T
    if target is None:
        return F
    use = (free & exact)[:, None]
    return Interval(np.where(use, np.maximum(target.lo, F.lo), F.lo), np.where(use, np.minimum(target.hi, F.hi), F.hi))


def _outer(fallback, X: Interval, u: Interval) -> tuple[Interval, np.ndarray]:
    """The deployed input over the boxes given the learned law's u: a `BoxFallback`'s linear law
    where a box lies outside the training box, the hull of both where it straddles a face.
    -> (u, rows where it is the learned law alone)."""
    if fallback is None:
        return u, np.ones(u.shape[0], bool)
    d = X - fallback.x_star
    half = np.asarray(fallback.half, np.float64)
    out = np.any((d.lo > half) | (d.hi < -half), axis=1)
    inside = np.all((d.lo >= -half) & (d.hi <= half), axis=1)
    lin = d @ (-np.asarray(fallback.K, np.float64)).T + np.asarray(fallback.u_star, np.float64)
    if fallback.inside_gain != 1.0:
        u = (u - fallback.u_star) * float(fallback.inside_gain) + np.asarray(fallback.u_star, np.float64)
    lo = np.where(out[:, None], lin.lo, np.where(inside[:, None], u.lo, np.minimum(u.lo, lin.lo)))
    hi = np.where(out[:, None], lin.hi, np.where(inside[:, None], u.hi, np.maximum(u.hi, lin.hi)))
    return Interval(lo, hi), inside & (fallback.inside_gain == 1.0)


def flow_rate(system, enclosure: FlowEnclosure, g_pinv, bound, fallback, X: Interval):
    """(H_d, ∇H_d, Ḣ_d = ∇H_dᵀF, tangent) over the boxes X, F the deployed law's true loop (outer law
    `fallback`); tangent (N,) bool: see `FlowEnclosure.value_and_grad`."""
    f = plant_enclosure(system, X)
    H, grad, f_d, tangent = enclosure.f_d(X)
    g_pinv, g = np.asarray(g_pinv, np.float64), _input_matrix(system)
    u, learned = _outer(fallback, X, (f_d - f) @ g_pinv.T)
    Pi = g @ g_pinv
    target = f @ (np.eye(Pi.shape[0]) - Pi).T + f_d @ Pi.T
    F = _loop(g, f, u, bound, target, learned)
    return H, grad, (grad * F).sum(-1), tangent


def lqr_rate(system, lqr, S: np.ndarray, bound, X: Interval):
    """(V, ∇V, V̇, tangent: all True, V is convex) over the boxes X for V = δᵀSδ along u = sat(u* − Kδ) (`LQRController`)."""
    d = X - np.asarray(lqr.x_star, np.float64)
    S = np.asarray(S, np.float64)
    grad = d @ (2.0 * S)
    V = (d @ S * d).sum(-1)
    f = plant_enclosure(system, X)
    u = d @ (-np.asarray(lqr.K, np.float64)).T + np.asarray(lqr.u_star, np.float64)
    F = _loop(_input_matrix(system), f, u, bound)
    return V, grad, (grad * F).sum(-1), np.ones(X.shape[0], bool)
