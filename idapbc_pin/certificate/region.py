"""The certified set: the largest sublevel set {V < c} in the verification box on which V decreases
along the true closed loop, outside a core certified by the linearisation, with a stated confidence.

V is any convex function with its minimum 0 at x* and the ``H_d`` / ``grad_H_d`` interface: the
run's H_d, or LQR's δᵀSδ (`idapbc_pin.certificate.baseline`). The true loop is the controller as
deployed (outer law included) on the controller's model, its input clipped to the effort limits:
ẋ = F(x) = f(x) + g(x)·sat(u(x)), V̇ = ∇Vᵀ F.

1. **Faces.** c ≤ min of V on the faces of V_box (sampled, refined per face): V convex, the set then
   lies inside V_box.
2. **Core.** Near x*, V ≈ ½δᵀPδ (P = ∇²V(x*)) and F ≈ Aδ (A = ∂F/∂x(x*)), so V̇ ≈ −½δᵀQδ with
   Q = −(PA + AᵀP). When Q ≻ 0 the linearisation makes V decrease near x* (Lyapunov's indirect
   method); the core is the largest ellipsoid level, within 5 % of the training box's half-widths,
   on whose shells (and every smaller one) V̇ ≤ ½·(−½δᵀQδ) and V is within 10 % of ½δᵀPδ.
   Samples inside the core are not tested.
3. **Search.** Uniform samples of {V < c} (rejection from a frame that holds it, `set_frame`); each sample
   outside the core with V̇ ≥ 0 lowers c to its V, until a round has none. Then a counter-example
   search: projected ascent on V̇/V from the worst samples, inside {core ≤ V < c}; a point with
   V̇ ≥ 0 lowers c again, and the search repeats.
4. **Confidence.** With c fixed, N ≥ ln(R/β)/ε fresh i.i.d. samples of the set; if all pass, the
   share of the set (outside the core) where V does not decrease is ≤ ε with confidence ≥ 1 − β.
   A failure lowers c and draws N fresh samples again, at most R rounds (hence R in the bound:
   a union over the rounds).

A sampled statement, not a proof: a thin region where V̇ ≥ 0 may hold less than ε of the set.
"""

from __future__ import annotations

import math

import numpy as np

from .checks import boundary_min, face_samples
from .result import Confidence, Region
from .terms import _f64, hessians
from .vbox import sample_set, set_frame, zero_failure_samples

__all__ = ["TrueLoop", "certified_region", "counterexamples", "covered_share", "linear_core"]

#: Rounds of the confidence draw (a failure lowers c and draws again); enters the bound as ln(R/β).
CONFIDENCE_ROUNDS = 3


class TrueLoop:
    """The true closed loop F(x) = f(x) + g(x)·sat(u(x)) of `law` on `system`: (N, n) -> (N, n).

    law : callable (N, n) -> (N, m), the controller as deployed.  bound : None or (m,) input bound.
    """

    def __init__(self, system, law, bound=None):
        self.system, self.law = system, law
        self.bound = None if bound is None else _f64(bound)

    def __call__(self, x) -> np.ndarray:
        x = np.atleast_2d(_f64(x))
        u = _f64(self.law(x)).reshape(x.shape[0], -1)
        if self.bound is not None:
            u = np.clip(u, -self.bound, self.bound)
        return _f64(self.system.f(x)) + np.einsum("nim,nm->ni", _f64(self.system.g(x)), u)

    def jacobian_at(self, x_star, h: float = 1e-6) -> np.ndarray:
        """(n, n) ∂F/∂x at x* by central differences."""
        x_star = _f64(x_star)
        E = h * np.eye(x_star.size)
        return ((self(x_star + E) - self(x_star - E)) / (2 * h)).T


def _rate(fn, loop, x) -> np.ndarray:
    """(N,) V̇ = ∇V(x)ᵀ F(x)."""
    return np.einsum("ni,ni->n", _f64(fn.grad_H_d(x)).reshape(x.shape), loop(x))


def _value(fn, x) -> np.ndarray:
    return _f64(fn.H_d(x)).reshape(x.shape[0])


def linear_core(fn, loop, x_star, half_width, rng, n_dirs: int = 256, levels: int = 13) -> tuple[float, float]:
    """The core level c₀ certified by the linearisation (module doc, step 2) and λ_min of Q's
    P-normalised form (the linear decay rate of V, 1/s; ≤ 0: the linearisation certifies nothing
    and c₀ = 0). half_width : (n,) the training box's half-widths."""
    x_star = _f64(x_star)
    P = hessians(fn, x_star[None])[0][0]
    A = loop.jacobian_at(x_star)
    Q = -(P @ A + A.T @ P)
    w, U = np.linalg.eigh(0.5 * (P + P.T))
    if w.min() <= 0:
        return 0.0, -math.inf
    P_inv_half = U @ np.diag(w ** -0.5) @ U.T
    rate = float(np.linalg.eigvalsh(P_inv_half @ (0.5 * (Q + Q.T)) @ P_inv_half).min())
    if rate <= 0:
        return 0.0, rate
    P_inv = np.linalg.inv(P)
    top = float(np.min((0.05 * _f64(half_width)) ** 2 / (2 * np.diag(P_inv))))
    d = rng.standard_normal((n_dirs, x_star.size))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    core = 0.0
    for level in top * np.logspace(-(levels - 1) / 2, 0, levels):
        delta = math.sqrt(2 * level) * d @ P_inv_half
        x = x_star + delta
        quad = 0.5 * np.einsum("ni,ij,nj->n", delta, P, delta)
        lin = -0.5 * np.einsum("ni,ij,nj->n", delta, Q, delta)
        ok = np.all(_rate(fn, loop, x) <= 0.5 * lin) and np.all(np.abs(_value(fn, x) - quad) <= 0.1 * quad)
        if not ok:
            break
        core = 0.9 * level
    return core, rate


def _project(fn, x, x_star, c: float) -> np.ndarray:
    """Pull each row of x with V ≥ c back along the ray from x* to V = c·(1 − 1e-9) (bisection)."""
    V = _value(fn, x)
    out = V >= c
    if not out.any():
        return x
    delta = x[out] - x_star
    t_lo, t_hi = np.zeros(delta.shape[0]), np.ones(delta.shape[0])
    for _ in range(40):
        t = 0.5 * (t_lo + t_hi)
        inside = _value(fn, x_star + t[:, None] * delta) < c * (1 - 1e-9)
        t_lo, t_hi = np.where(inside, t, t_lo), np.where(inside, t_hi, t)
    x = x.copy()
    x[out] = x_star + t_lo[:, None] * delta
    return x


def counterexamples(fn, loop, starts, c: float, core: float, x_star, lo, hi, steps: int = 30, lr: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Projected ascent on r(x) = V̇/V from `starts` (K, n), kept in {V < c} ∩ [lo, hi].

    Gradients by central differences (one batch of K·(2n + 1) states a step), steps in the box's
    units, normalised, shrinking linearly. Returns the violations found (V̇ ≥ 0 outside the core),
    each moved down its ray from x* to the lowest violating point (`_lowest_on_rays`): (k, n) and
    their V (k,), empty when none was found.
    """
    x_star, lo, hi = _f64(x_star), _f64(lo), _f64(hi)
    width = hi - lo
    x = np.array(starts, float)
    K, n = x.shape
    h = 1e-5 * width
    offsets = np.concatenate([np.zeros((1, n)), np.diag(h), -np.diag(h)])  # (2n + 1, n)
    found_x, found_V = [], []
    for step in range(steps):
        probe = (x[:, None, :] + offsets[None]).reshape(-1, n)
        V = _value(fn, probe).reshape(K, 2 * n + 1)
        r = (_rate(fn, loop, probe).reshape(K, 2 * n + 1)) / np.maximum(V, 1e-300)
        V0, r0 = V[:, 0], r[:, 0]
        bad = (r0 >= 0) & (V0 >= core) & (V0 < c)
        if bad.any():
            found_x.append(x[bad].copy())
            found_V.append(V0[bad])
        grad = (r[:, 1 : n + 1] - r[:, n + 1 :]) / (2 * h)
        g = grad * width
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)
        x = np.clip(x + lr * (1 - step / steps) * g * width, lo, hi)
        x = _project(fn, x, x_star, c)
    if not found_x:
        return np.empty((0, n)), np.empty(0)
    return _lowest_on_rays(fn, loop, np.concatenate(found_x), core, x_star)


def _lowest_on_rays(fn, loop, x, core: float, x_star, k: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Each violating state moved to the violating point of lowest V on its ray from x* (a grid of
    `k` points x* + t(x − x*), t ∈ (0, 1]): a violation found at the top of the set then lowers c
    to the bottom of the region it lies in. -> (states (K, n), their V (K,))."""
    t = np.arange(1, k + 1) / k
    pts = (x_star + t[None, :, None] * (x - x_star)[:, None, :]).reshape(-1, x.shape[1])
    V, _, bad = _violations(fn, loop, pts, core)
    V, bad = V.reshape(x.shape[0], k), bad.reshape(x.shape[0], k)
    first = np.argmax(bad, axis=1)  # the last grid point (t = 1) violates, so every row has one
    rows = np.arange(x.shape[0])
    return pts.reshape(x.shape[0], k, -1)[rows, first], V[rows, first]


def _violations(fn, loop, x, core: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V, V̇, failing mask) at samples x: a sample fails where V̇ ≥ 0 (or is not finite) outside the core."""
    V, Vd = _value(fn, x), _rate(fn, loop, x)
    return V, Vd, (~(Vd < 0)) & (V >= core)


def certified_region(
    fn, loop, x_star, vbox, tbox, rng, *,
    epsilon: float = 1e-3, beta: float = 1e-6, n_search: int = 20000, n_starts: int = 32,
    rounds: int = 8, per_face: int = 256,
) -> Region:
    """The certified set {V < c} of `fn` along `loop` in the verification box (module doc).

    Parameters
    ----------
    fn : V with ``H_d`` (N,) and ``grad_H_d`` (N, n) (and optionally ``hess_H_d``).
    loop : `TrueLoop`.  x_star : (n,).
    vbox, tbox : (lo, hi) of the verification box and of the training box X.
    rng : numpy Generator (every draw).  epsilon, beta : the confidence statement.
    n_search : samples of each search round.  n_starts : starts of the counter-example search.
    rounds : search rounds at most.  per_face : samples per face of V_box.
    """
    x_star = _f64(x_star)
    vlo, vhi = (_f64(b) for b in vbox)
    tlo, thi = (_f64(b) for b in tbox)
    c_bnd, x_bnd = boundary_min(fn, vlo, vhi, face_samples(vlo, vhi, per_face, rng))
    core, decay = linear_core(fn, loop, x_star, 0.5 * (thi - tlo), rng)
    c, n_viol, n_cex, c_viol = c_bnd, 0, 0, math.inf
    for _ in range(rounds):
        if not c > core:
            break
        x, _ = sample_set(fn, c, set_frame(fn, c, x_star, vlo, vhi, rng), n_search, rng)
        V, Vd, bad = _violations(fn, loop, x, core)
        if bad.any():
            c_viol = min(c_viol, float(V[bad].min()))
            c, n_viol = float(V[bad].min()), n_viol + int(bad.sum())
            continue
        out = V >= core
        worst = np.argsort(-(Vd[out] / np.maximum(V[out], 1e-300)))[:n_starts]
        _, cV = counterexamples(fn, loop, x[out][worst], c, core, x_star, vlo, vhi)
        if cV.size:
            c_viol = min(c_viol, float(cV.min()))
            c, n_cex = float(cV.min()), n_cex + int(cV.size)
            continue
        break
    c, confidence, covered, share_v = _confidence(fn, loop, x_star, c, core, (vlo, vhi), (tlo, thi), rng, epsilon, beta)
    return Region(
        c=float(c), core=float(core), linear_decay=float(decay), c_boundary=float(c_bnd), boundary_state=x_bnd.tolist(),
        c_violation=float(c_viol), n_violations=n_viol, n_counterexamples=n_cex,
        covered_fraction=covered, verification_share=share_v, confidence=confidence,
    )


def covered_share(fn, c: float, frame, x, draws: int, tbox, rng) -> float:
    """vol({V < c} ∩ X)/vol(X) from the set's samples x (`sample_set`, `draws` frame draws) and as
    many uniform samples of X: whichever estimate has the smaller relative variance, (1 − p)/k for
    k hits of p = k/draws (the frame's, good for a set small in X; the uniform one, exact for a set
    that holds X)."""
    tlo, thi = tbox
    k_frame = int(np.all((x >= tlo) & (x <= thi), axis=1).sum())
    by_frame = frame.volume * k_frame / draws / float(np.prod(thi - tlo))
    n = max(int(x.shape[0]), 1)
    k_box = int((_value(fn, tlo + (thi - tlo) * rng.random((n, tlo.size))) < c).sum())
    if k_box == 0 or (k_frame > 0 and (1 - k_frame / draws) / k_frame < (1 - k_box / n) / k_box):
        return float(by_frame)
    return k_box / n


def _confidence(fn, loop, x_star, c, core, vbox, tbox, rng, epsilon, beta):
    """Step 4 of the module doc -> (final c, Confidence, covered share of X, share of V_box); the
    shares are 0 unless the last round passed."""
    vlo, vhi = vbox
    need = zero_failure_samples(epsilon, beta / CONFIDENCE_ROUNDS)
    failures, passed, k = 0, False, 0
    covered = share_v = 0.0
    for k in range(1, CONFIDENCE_ROUNDS + 1):
        if not c > core:
            break
        frame = set_frame(fn, c, x_star, vlo, vhi, rng)
        x, draws = sample_set(fn, c, frame, need, rng)
        share_v = frame.volume * x.shape[0] / draws / float(np.prod(vhi - vlo))
        V, _, bad = _violations(fn, loop, x, core)
        if x.shape[0] < need:
            break
        if not bad.any():
            passed, covered = True, covered_share(fn, c, frame, x, draws, tbox, rng)
            break
        failures += int(bad.sum())
        c = float(V[bad].min())
    return (c, Confidence(epsilon=float(epsilon), beta=float(beta), samples=int(need), rounds=k, failures=failures, passed=passed),
            float(covered) if passed else 0.0, float(share_v) if passed else 0.0)
