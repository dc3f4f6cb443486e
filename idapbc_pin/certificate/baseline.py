"""The LQR baseline's certified share: the same sampled sublevel test on LQR's own Lyapunov function.

DESIGN §4 ("Certificate"): for the LQR baseline u = sat(u* − Kδ) (`LQRController`, Q = I, R = I)
the quadratic function

    V(x) = δᵀSδ,    δ = wrap(x − x*),    S the Riccati solution of the LQR design,

is checked exactly as H_d is for Neural IDA-PBC: on the same domain samples, V̇ = 2δᵀS(f + g u)
along the true nonlinear closed loop (the effort limits applied when they are), the smallest V
of a sample with V̇ ≥ 0 (none tolerated: LQR has no set E), the minimum of V on the box faces by
the same face search (`boundary_min` on the same face samples), and the share of the domain
samples inside {V < c}. On the linearisation V̇ = −δᵀ(Q + KᵀRK)δ < 0 everywhere; the nonlinear
plant and the limits are what shrink the set. A sampled certificate, not a proof.
"""

from __future__ import annotations

import numpy as np

from ..control.baseline import LQRController
from ..model.angles import wrap_angles
from .checks import boundary_min, check_sublevel
from .result import BaselineCertificate
from .terms import _f64

__all__ = ["QuadraticLyapunov", "certify_baseline"]


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


def certify_baseline(system, x: np.ndarray, lo: np.ndarray, hi: np.ndarray, faces, bound=None) -> BaselineCertificate:
    """The sampled sublevel test of LQR's V = δᵀSδ on the true closed loop of `system`.

    Parameters
    ----------
    system : the `System` (linearisation, f, g); the LQR baseline is designed on it (Q = I, R = I).
    x : (N, n) the domain samples.  lo, hi : (n,) the box.
    faces : the face samples (`face_samples`), the same as the run certificate's.
    bound : None or (m,) input bound (+inf where none): V̇ along f + g·sat(u).
    """
    lqr = LQRController(system)
    V_fn = QuadraticLyapunov(lqr.S, system.x_star, system.angle_mask)
    u_law = _f64(lqr(x)).reshape(x.shape[0], -1)
    u = u_law if bound is None else np.clip(u_law, -_f64(bound), _f64(bound))
    x_dot = _f64(system.f(x)) + np.einsum("nim,nm->ni", _f64(system.g(x)), u)
    V = V_fn.H_d(x)
    V_dot = np.einsum("ni,ni->n", V_fn.grad_H_d(x), x_dot)
    c_bnd, x_bnd = boundary_min(V_fn, lo, hi, faces)
    return BaselineCertificate(
        controller="LQR",
        function="V = δᵀSδ, δ = wrap(x − x*), S the Riccati solution (Q = I, R = I)",
        n_samples=int(x.shape[0]),
        limits_applied=bound is not None,
        saturated_fraction=float(np.mean(np.any(u != u_law, axis=1))),
        max_real=float(np.max(lqr.eigenvalues.real)),
        sublevel=check_sublevel(V, V_dot, 0.0, 0.0, c_bnd, x_bnd),
    )
