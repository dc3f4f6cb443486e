"""Interval enclosures of the true closed loop and of V̇ over boxes of states: what
`idapbc_pin.certificate.verified` bounds.

For a batch of boxes X (an `Interval` of shape (N, n)) they return intervals that contain, for every
state in each box, the value in exact arithmetic of:

* the open loop f(x) (`plant_enclosure`): the paper's mass-spring-damper and its two-coordinate
  mechanical plants in closed form, and a URDF plant's chain of joints by interval kinematics
  (`chain_enclosure.ChainEnclosure`);
* ∇H_d(x) and f̃_d(x) = (J_d − R_d)∇H_d of the controller as deployed (`FlowEnclosure`, formula for
  formula the numpy `DesiredFlow`, its float32 or float64 weights taken exactly in float64);
* the true loop F = f + g·sat(u), u = (gᵀg)⁻¹gᵀ(f̃_d − f), and V̇ = ∇Vᵀ F, for H_d (`flow_rate`) and
  for LQR's δᵀSδ (`lqr_rate`). Where no box state saturates, F = (I − Π)f + Πf̃_d with Π = g(gᵀg)⁻¹gᵀ
  is used: the same field, with f entering once.

Given a jet of the boxes (`jet.Jet.variables`) in place of the boxes, each returns its jet: the
value's enclosure and its gradient's over the box, for the mean-value forms of the verifier. Where
an outer law takes over (outside `networks_box`), or the governor may act (`quiet_rows`), the
loop's rate is left unbounded: those boxes are decided by V's value alone.
"""

from __future__ import annotations

import numpy as np

from ..control.desired_flow import DesiredFlow
from ..control.speed_governor import SPEED_START
from ..model.analytic import CosCoupledPlant, MassSpringDamperPlant
from ..recovery.box_law import BoxFallback
from .chain_enclosure import ChainEnclosure
from .interval import Interval
from .jet import Jet, concat, stack, where

__all__ = ["FlowEnclosure", "NoEnclosure", "enclosable", "flow_rate", "lqr_rate", "loop_field", "lqr_field", "networks_box", "plant_enclosure", "quadratic_rate",
           "quiet_rows"]


class NoEnclosure(Exception):
    """The loop has a part without an interval form here (the reason is the message)."""


def _msd(plant: MassSpringDamperPlant, X: Interval) -> Interval:
    """The mass-spring-damper: (p, (−(k + ½q²)q − b p²(1 + |p|))/m)."""
    q, p = X[:, 0], X[:, 1]
    spring = (q.square() * 0.5 + plant.k) * q
    friction = p.square() * (p.abs() + 1.0) * plant.b
    acc = (-(spring + friction)) * Interval.point(plant.m).reciprocal()
    return stack([p, acc], axis=1)


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
    return stack([v1, v2, *pdot], axis=1)


def networks_box(fallback, outermost: bool = True) -> np.ndarray | str:
    """Half-widths (n,) of the box |wrap(x − x*)| ≤ r in which the deployed input is the learned
    law's, through every outer law nested in `fallback` (∞: no outer law), or why none is known.
    An outermost `BoxFallback` may scale the learned law inside (`_outer` encloses that)."""
    if fallback is None:
        return np.array(np.inf)
    if isinstance(fallback, BoxFallback):
        if fallback.inside_ramp[1] > 0:
            return "no interval form of the outer law's ramped inside gain"
        if fallback.inside_gain != 1.0 and not outermost:
            return "no interval form of a scaled inside gain within another outer law"
        return np.asarray(fallback.half, np.float64)
    if hasattr(fallback, "box") and hasattr(fallback, "law"):  # a kept-box law around the run's own outer law
        inner = networks_box(getattr(fallback, "inner", None), outermost=False)
        return inner if isinstance(inner, str) else np.minimum(np.asarray(fallback.box, np.float64), inner)
    if isinstance(getattr(fallback, "inner", None), np.ndarray) and not getattr(fallback, "residual", False):
        return np.asarray(fallback.inner, np.float64)  # a recovery law: the networks' inside its inner box
    return f"no interval form of the outer law {type(fallback).__name__}"


def enclosable(system, fallback=None) -> str | None:
    """None when the loop of `system` (with the outer law `fallback`) has an interval form here, else why not."""
    plant = getattr(system, "plant", system)
    if not isinstance(plant, (MassSpringDamperPlant, CosCoupledPlant)) and not hasattr(plant, "chain"):
        return f"no interval form of the {type(plant).__name__} plant"
    box = networks_box(fallback)
    return box if isinstance(box, str) else None


def plant_enclosure(system, X):
    """f over the boxes X (N, n) -> (N, n) (or their jets)."""
    if isinstance(system.plant, MassSpringDamperPlant):
        return _msd(system.plant, X)
    if isinstance(system.plant, CosCoupledPlant):
        return _cos_coupled(system.plant, X)
    if hasattr(system.plant, "chain"):
        return ChainEnclosure(system.plant.chain(), system.plant.damping)(X)
    raise NoEnclosure(enclosable(system))


def quiet_rows(system, governor, X: Interval, f: Interval) -> np.ndarray:
    """(N,) bool: boxes on which the speed and energy governor (`SpeedGovernor`, or None) provably
    leaves the input alone: every rated joint below `SPEED_START` of its rating (v = f's first nq
    rows) and E_g below E* + `ENERGY_MARGIN`·ΔE."""
    N = X.shape[0]
    if governor is None:
        return np.ones(N, bool)
    if not hasattr(system.plant, "chain"):
        return np.zeros(N, bool)  # no interval form of E_g here: the governor may act anywhere
    nq = system.nq
    rating = np.asarray(governor.rating, np.float64)
    v = f[:, :nq]
    rated = np.isfinite(rating)
    quiet = np.all(np.where(rated, np.maximum(np.abs(v.lo), np.abs(v.hi)) < SPEED_START * np.where(rated, rating, 1.0), True), axis=1)
    rows = np.asarray(governor.energy_rows)
    M, U = ChainEnclosure(system.plant.chain(), system.plant.damping).mass_and_potential(X[:, :nq])
    vr = v[:, rows]
    kinetic = ((vr[:, :, None] * M[:, rows][:, :, rows]) * vr[:, None, :]).sum(-1).sum(-1) * 0.5
    E = kinetic + U
    return quiet & (E.hi < governor.e_star + governor.energy_margin * governor.delta_e)


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
        g = concat(parts, axis=1) @ self.W_in.T - self.g0
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
            entries = concat([diag, r_o], axis=1)
            entries = entries if s is None else entries * s
        else:
            at = np.asarray(fl.r_at_target, np.float64)
            diag = (r_d + (np.asarray(fl.log_d0, np.float64) - at[:n])).exp()
            step = r_o - at[n:]
            step = step if s is None else step * s[n:]
            low = step + np.asarray(fl.l0, np.float64)
            entries = concat([diag, low], axis=1)
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


def _value(t) -> Interval:
    """The value enclosure of an `Interval` or a first-order `Jet`."""
    return t.val if isinstance(t, Jet) else t


def _unbounded(like):
    """(−∞, ∞) in the type and shape of `like`."""
    if isinstance(like, Jet):
        return Jet(_unbounded(like.val), _unbounded(like.grad))
    return Interval(np.full(like.shape, -np.inf), np.full(like.shape, np.inf))


def _meet_rows(use: np.ndarray, a, b):
    """b, met with a on the rows of `use` (both enclose the same function there, so do their gradients)."""
    if isinstance(b, Jet):
        return Jet(_meet_rows(use, a.val, b.val), _meet_rows(use, a.grad, b.grad))
    m = use.reshape(use.shape + (1,) * (b.lo.ndim - 1))
    return Interval(np.where(m, np.maximum(a.lo, b.lo), b.lo), np.where(m, np.minimum(a.hi, b.hi), b.hi))


def _loop(g: np.ndarray, f, u, bound, target=None, exact=None):
    """F = f + g·sat(u) over the boxes; ``target`` (the same field where u is the learned law and is
    not clipped, Πf̃_d + (I − Π)f) is intersected in on the rows of ``exact`` where u stays within the bound."""
    uv = _value(u)
    if bound is None:
        sat, free = u, np.ones(uv.shape[0], bool)
    else:
        b = np.asarray(bound, np.float64)
        sat = u.clip(-b, b)
        free = np.all((uv.lo >= -b) & (uv.hi <= b), axis=1)
    F = f + sat @ g.T
    if target is None:
        return F
    return _meet_rows(free & exact, target, F)


def _outer(fallback, X, u):
    """The deployed input over the boxes given the learned law's u: a `BoxFallback`'s linear law
    where a box lies outside the training box, the hull of both where it straddles a face (its jet's
    gradient unbounded there: the law switches). -> (u, rows where it is the learned law alone)."""
    d = X - fallback.x_star
    dv = _value(d)
    half = np.asarray(fallback.half, np.float64)
    out = np.any((dv.lo > half) | (dv.hi < -half), axis=1)
    inside = np.all((dv.lo >= -half) & (dv.hi <= half), axis=1)
    lin = d @ (-np.asarray(fallback.K, np.float64)).T + np.asarray(fallback.u_star, np.float64)
    if fallback.inside_gain != 1.0:
        u = (u - fallback.u_star) * float(fallback.inside_gain) + np.asarray(fallback.u_star, np.float64)
    uv, lv = _value(u), _value(lin)
    hull = Interval(np.minimum(uv.lo, lv.lo), np.maximum(uv.hi, lv.hi))
    mixed = Jet(hull, _unbounded(u.grad)) if isinstance(u, Jet) else hull
    return where(out, lin, where(inside, u, mixed)), inside & (fallback.inside_gain == 1.0)


def _inside(fallback, X) -> np.ndarray:
    """(N,) bool: boxes inside `networks_box` (the learned law acts alone there)."""
    box = networks_box(fallback)
    d = _value(X) - fallback.x_star if fallback is not None else None
    if d is None or not np.isfinite(box).any():
        return np.ones(X.shape[0], bool)
    return np.all((d.lo >= -box) & (d.hi <= box), axis=1)


def loop_field(system, enclosure: FlowEnclosure, g_pinv, bound, fallback, X, governor=None):
    """(F, keep, H_d, ∇H_d, tangent) over the boxes X (or their jets): F the deployed law's true loop
    (outer law `fallback`, `governor`), keep (N,) the boxes where F is that loop's field (elsewhere
    an outer law other than a `BoxFallback`, or the governor, may act, and F is not it); tangent
    (N,) bool: see `FlowEnclosure.value_and_grad`."""
    f = plant_enclosure(system, X)
    H, grad, f_d, tangent = enclosure.f_d(X)
    g_pinv, g = np.asarray(g_pinv, np.float64), _input_matrix(system)
    u = (f_d - f) @ g_pinv.T
    if isinstance(fallback, BoxFallback):
        u, learned = _outer(fallback, X, u)
        alone = np.ones(X.shape[0], bool)
    else:
        learned = alone = _inside(fallback, X)
    Pi = g @ g_pinv
    target = f @ (np.eye(Pi.shape[0]) - Pi).T + f_d @ Pi.T
    F = _loop(g, f, u, bound, target, learned)
    return F, alone & quiet_rows(system, governor, _value(X), _value(f)), H, grad, tangent


def flow_rate(system, enclosure: FlowEnclosure, g_pinv, bound, fallback, X, governor=None):
    """(H_d, ∇H_d, Ḣ_d = ∇H_dᵀF, tangent) over the boxes X (or their jets) along `loop_field`'s F;
    Ḣ_d is unbounded on the boxes where F is not the deployed loop's."""
    F, keep, H, grad, tangent = loop_field(system, enclosure, g_pinv, bound, fallback, X, governor)
    rate = (grad * F).sum(-1)
    return H, grad, where(keep, rate, _unbounded(rate)), tangent


def _quadratic_form(W: np.ndarray, d: Interval, dm: np.ndarray) -> Interval:
    """dᵀWd over the boxes d (N, n) with centres dm (N, n), W symmetric, met from two forms: the
    expansion about dm, q(dm) + 2dmᵀW(d − dm) + (d − dm)ᵀW(d − dm) (tight to second order in the
    box's width), and W's eigen-form Σ μ_i (u_iᵀd)², each square's exact range (tight where W is
    dominated by a few directions, as −(Q + KᵀRK) of a high-gain loop is)."""
    e = d - dm
    cm = Interval.point(dm)
    expansion = (cm @ W * cm).sum(-1) + ((cm @ (2.0 * W)) * e).sum(-1) + (e @ W * e).sum(-1)
    mu, U = np.linalg.eigh(W)
    z = d @ U
    # eigh's rounding: W = U diag(μ) Uᵀ + E with ‖E‖₂ ≤ tol, so dᵀWd lies within tol·‖d‖² of the eigen-form
    tol = 1e3 * np.finfo(np.float64).eps * max(1.0, float(np.abs(mu).max()))
    tol += float(np.linalg.norm(U @ np.diag(mu) @ U.T - W, 2))
    eigen = (z.square() * mu).sum(-1).widen(tol * d.square().sum(-1).hi)
    return Interval(np.maximum(expansion.lo, eigen.lo), np.minimum(expansion.hi, eigen.hi))


def quadratic_rate(P: np.ndarray, x_star: np.ndarray, field, A: np.ndarray, X: Interval):
    """(V, ∇V, V̇, tangent: all True) over the boxes X (N, n) for V = δᵀPδ along the field
    ``field(X) -> (F, keep)`` (of boxes or their jets; V̇ unbounded where not keep).

    V̇ = δᵀ(PA + AᵀP)δ + 2δᵀP r(x), with r = F − Aδ the field's remainder beyond the point matrix A
    (any A: an identity; A = the loop's linearisation at x* makes r second order): the quadratic
    term is enclosed by its expansion about each box's centre m, and r by its mean-value form
    r(m) + (∂F/∂x(X) − A)(X − m) (`jet.Jet`), met with its direct enclosure. The tighter of this and
    the direct ∇Vᵀ F is kept."""
    P, A = np.asarray(P, np.float64), np.asarray(A, np.float64)
    x_star = np.asarray(x_star, np.float64)
    N = X.shape[0]
    m = X.mid
    F, keep = field(Jet.variables(Interval.concat([X, Interval.point(m)], axis=0)))
    keep = keep[:N]
    d, dm = X - x_star, m - x_star
    grad = d @ (2.0 * P)
    direct = (grad * F.val[:N]).sum(-1)
    r_direct = F.val[:N] - d @ A.T
    r_mid = F.val[N:] - Interval.point(dm) @ A.T
    slope = F.grad[:N] - A
    r = r_mid + (slope * (X - m)[:, None, :]).sum(-1)
    r = Interval(np.maximum(r.lo, r_direct.lo), np.minimum(r.hi, r_direct.hi))
    W = P @ A
    split = _quadratic_form(W + W.T, d, dm) + ((d @ (2.0 * P)) * r).sum(-1)
    rate = Interval(np.maximum(direct.lo, split.lo), np.minimum(direct.hi, split.hi))
    return _quadratic_form(P, d, dm), grad, where(keep, rate, _unbounded(rate)), np.ones(N, bool)


def lqr_field(system, lqr, bound, X):
    """(F, keep: all True) over the boxes X (or their jets): the loop of u = sat(u* − Kδ) (`LQRController`)."""
    d = X - np.asarray(lqr.x_star, np.float64)
    u = d @ (-np.asarray(lqr.K, np.float64)).T + np.asarray(lqr.u_star, np.float64)
    return _loop(_input_matrix(system), plant_enclosure(system, X), u, bound), np.ones(X.shape[0], bool)


def lqr_rate(system, lqr, S: np.ndarray, bound, X: Interval):
    """(V, ∇V, V̇, tangent: all True, V is convex) over the boxes X for V = δᵀSδ along
    u = sat(u* − Kδ) (`LQRController`; `quadratic_rate` about the loop's linearisation)."""
    A, B = system.linearization()
    return quadratic_rate(S, lqr.x_star, lambda Y: lqr_field(system, lqr, bound, Y), A - B @ np.asarray(lqr.K, np.float64), X)
