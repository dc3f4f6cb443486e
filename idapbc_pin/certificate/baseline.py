"""The LQR baseline's certified share: the same sampled sublevel test on LQR's own Lyapunov function.

DESIGN §4 ("Certificate"): for the LQR baseline u = sat(u* − Kδ) (`LQRController`, Q = I, R = I)
the quadratic function

    V(x) = δᵀSδ,    δ = wrap(x − x*),    S the Riccati solution of the LQR design,

is certified exactly as H_d is for Neural IDA-PBC (`idapbc_pin.certificate.region`): in the same
verification box, with V̇ = 2δᵀS(f + g u) along the true nonlinear closed loop (the effort limits
applied when they are), the same face search, core, counter-example search and confidence draw.
On the linearisation V̇ = −δᵀ(Q + KᵀRK)δ < 0 everywhere; the nonlinear plant and the limits are
what shrink the set. A sampled certificate, not a proof.
"""

from __future__ import annotations

import numpy as np

from ..control.baseline import LQRController
from ..model.angles import wrap_angles
from .region import TrueLoop, certified_region
from .result import BaselineCertificate
from .terms import _f64

__all__ = ["QuadraticLyapunov", "certify_baseline", "ellipsoid_share", "loop_quadratic"]


class QuadraticLyapunov:
    """V(x) = δᵀSδ with δ = wrap(x − x*), exposing the ``H_d`` / ``grad_H_d`` interface of the face search.

    S : (n, n) symmetric positive definite; x_star : (n,); angle_mask : (n,) bool (wrapped components).
    """

    def __init__(self, S, x_star, angle_mask):
        self.S = _f64(S)
        self.x_star = _f64(x_star)
        self.angle_mask = np.asarray(angle_mask, bool)

    def delta(self, x) -> np.ndarray:
        """δ = wrap(x − x*): (N, n) -> (N, n)."""
        return wrap_angles(np.atleast_2d(_f64(x)) - self.x_star, self.angle_mask)

    def H_d(self, x) -> np.ndarray:
        """V(x): (N, n) -> (N,)."""
        d = self.delta(x)
        return np.einsum("ni,ij,nj->n", d, self.S, d)

    def grad_H_d(self, x) -> np.ndarray:
        """∇V = 2Sδ: (N, n) -> (N, n) (wrapping has unit derivative away from the seam)."""
        return 2.0 * self.delta(x) @ self.S

    def hess_H_d(self, x) -> np.ndarray:
        """∇²V = 2S: (N, n) -> (N, n, n)."""
        return np.broadcast_to(2.0 * self.S, (np.atleast_2d(x).shape[0],) + self.S.shape).copy()


def loop_quadratic(A: np.ndarray, half: np.ndarray) -> np.ndarray:
    """P (n, n) of V = δᵀPδ for a loop with linearisation A (Hurwitz) at x*: AᵀP + PA = −D⁻², D the
    box's half-widths `half` (n,), so every coordinate's share of the decrease is weighed in the
    box's own units. A quadratic fitted to the loop itself, for the loop as deployed."""
    from scipy.linalg import solve_continuous_lyapunov

    A = _f64(A)
    if np.max(np.linalg.eigvals(A).real) >= 0:
        raise ValueError("the loop's linearisation is not Hurwitz: no quadratic Lyapunov function")
    P = solve_continuous_lyapunov(A.T, -np.diag(1.0 / _f64(half) ** 2))
    return 0.5 * (P + P.T)


def ellipsoid_share(P: np.ndarray, c: float, half: np.ndarray, samples: int = 400_000, seed: int = 0) -> float:
    """The share of the box x* ± half (n,) inside {δᵀPδ < c}: ω_n c^{n/2} / √det P over the box's
    volume (ω_n the unit ball's volume) for an ellipsoid inside the box, else the share of
    `samples` uniform states of the box (seed `seed`)."""
    from math import gamma, pi

    P, half = _f64(P), _f64(half)
    n = half.size
    if c <= 0:
        return 0.0
    reach = np.sqrt(c * np.diag(np.linalg.inv(P)))
    if np.any(reach > half):
        d = np.random.default_rng(seed).uniform(-half, half, (int(samples), n))
        return float(np.mean(np.einsum("ni,ij,nj->n", d, P, d) < c))
    ball = pi ** (n / 2) / gamma(n / 2 + 1)
    return float(ball * c ** (n / 2) / np.sqrt(np.linalg.det(P)) / np.prod(2 * half))


def certify_baseline(system, vbox, tbox, rng, bound=None, share_bound: float = 1e-3, beta: float = 1e-6) -> BaselineCertificate:
    """The certified set of LQR's V = δᵀSδ on the true closed loop of `system` (`certified_region`).

    Parameters
    ----------
    system : the `System` (linearisation, f, g); the LQR baseline is designed on it (Q = I, R = I).
    vbox, tbox : (lo, hi) of the verification box and of the training box.
    rng : numpy Generator.  bound : None or (m,) input bound (+inf where none): V̇ along f + g·sat(u).
    share_bound, beta : ε and β of the confidence statement.
    """
    lqr = LQRController(system)
    V_fn = QuadraticLyapunov(lqr.S, system.x_star, system.angle_mask)
    region = certified_region(V_fn, TrueLoop(system, lqr, bound), system.x_star, vbox, tbox, rng, epsilon=share_bound, beta=beta)
    return BaselineCertificate(
        controller="LQR",
        function="V = δᵀSδ, δ = wrap(x − x*), S the Riccati solution (Q = I, R = I)",
        limits_applied=bound is not None,
        max_real=float(np.max(lqr.eigenvalues.real)),
        sublevel=region,
    )
