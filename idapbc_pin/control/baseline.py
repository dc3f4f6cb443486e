"""The LQR baseline every learned controller is compared with (DESIGN §4)."""

from __future__ import annotations

import numpy as np

from ..model.angles import wrap_angles
from .linear import lqr

__all__ = ["LQRController", "equilibrium_input"]


def equilibrium_input(system) -> np.ndarray:
    """u* = −(gᵀg)⁻¹gᵀ f(x*) (m,): the input that holds x* (least squares on g(x*))."""
    Bx = np.asarray(system.linearization()[1], float)
    f_star = np.asarray(system.f(np.asarray(system.x_star, float)), float)
    return -np.linalg.lstsq(Bx, f_star, rcond=None)[0]


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
        self.u_star = equilibrium_input(system)

    def __call__(self, x) -> np.ndarray:
        """u = u* − K wrap(x − x*): (N, n) -> (N, m) (or (n,) -> (m,))."""
        x = np.asarray(x, dtype=float)
        delta = wrap_angles(x - self.x_star, self.angle_mask)
        return self.u_star - delta @ self.K.T

    def __repr__(self) -> str:
        return f"LQRController(n={self.K.shape[1]}, m={self.K.shape[0]}, max Re λ={self.eigenvalues.real.max():.4g})"
