"""The terminal set of a sampled-data closed loop: a neighbourhood of x* that a rollout, once inside,
never leaves and in which it converges to x*, so `simulate` can stop it with its verdict known.

The loop as `simulate` integrates it is a map F of one step of dt on z = (wrap(q − q*), v): the RK4
step with the law held over it and the input clipped to its bound. With A = ∂F/∂z(0) (central
differences of F itself) Schur stable, P ≻ 0 solves AᵀPA − P = −W, W = diag(1/tol²) the success
box's scale, and V(z) = zᵀPz falls by at least the factor 1 − r per step under A, r = λ_min(P⁻¹W).
The terminal set is {V ≤ c}:

* it lies in the success box ‖wrap(q − q*)‖∞ ≤ tol, ‖v‖∞ ≤ tol: c ≤ tol² / (P⁻¹)_ii for every i
  (the largest |z_i| on the ellipsoid is √(c (P⁻¹)_ii));
* one step of F itself lowers V by at least the factor 1 − r/2 at every sample of the ellipsoid's
  shells V = c·4⁻ᵏ, k = 0 … 6 (`DIRECTIONS` directions each): inputs, clipping and the nonlinear
  remainder included. The remainder of a smooth F shrinks quadratically towards x*, so half the
  linear margin at the outer shell leaves more than half on the inner ones. Where a shell fails, c
  shrinks by 4, at most `SHRINKS` times.

A rollout that enters the set stays in the success box for good and tends to x*: its success, its
settling time and its limit (x*) are known. Like the certificate's linear core, the decrease is
checked on samples, not proved by a bound. The law must not depend on time (a plan does).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg

from ..model.angles import wrap_angles
from .metrics import SUCCESS_TOL

__all__ = ["TerminalSet", "terminal_set"]

#: Directions sampled on each shell of the decrease check, shells V = c·4⁻ᵏ (k = 0 … SHELLS − 1), and
#: how often c may shrink by 4 before the loop gets no terminal set.
DIRECTIONS, SHELLS, SHRINKS = 256, 7, 6

#: Central-difference step of ∂F/∂z (rad, m, rad/s, m/s), and the largest |F(0)| (x* must be a fixed point).
_FD_STEP, _FIXED_TOL = 1e-6, 1e-9

#: One step of the loop: (q (N, nq), v (N, nq)) -> (q', v', bad (N,) bool).
StepMap = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class TerminalSet:
    """{z : zᵀPz ≤ c}, z = (wrap(q − q*), v), of one closed loop (module doc).

    P : (2nq, 2nq), 1/(rad², m², (rad/s)², (m/s)²) by component.  c : the level.  q_star : (nq,).
    angle_mask : (nq,) bool, the angle components of q.
    """

    P: np.ndarray
    c: float
    q_star: np.ndarray
    angle_mask: np.ndarray

    def value(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """V = zᵀPz for q, v (N, nq): (N,)."""
        z = np.concatenate([wrap_angles(q - self.q_star, self.angle_mask), v], axis=1)
        return np.einsum("ni,ij,nj->n", z, self.P, z)

    def contains(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N,) bool: the states (q, v) (N, nq) lie in the set."""
        return self.value(q, v) <= self.c


def _jacobian(step: StepMap, q_star: np.ndarray, mask: np.ndarray) -> np.ndarray | None:
    """A = ∂F/∂z at z = 0 (2nq, 2nq) by central differences, or None when x* is not a fixed point
    of F or a perturbed state goes bad."""
    nq = q_star.size
    E = _FD_STEP * np.eye(2 * nq)
    Z = np.concatenate([np.zeros((1, 2 * nq)), E, -E])
    qn, vn, bad = step(q_star + Z[:, :nq], Z[:, nq:].copy())
    if bad.any():
        return None
    F = np.concatenate([wrap_angles(qn - q_star, mask), vn], axis=1)
    if np.abs(F[0]).max() > _FIXED_TOL:
        return None
    return ((F[1 : 2 * nq + 1] - F[2 * nq + 1 :]) / (2 * _FD_STEP)).T


def _shell_states(P: np.ndarray, c: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """States z (SHELLS·DIRECTIONS, 2nq) on the shells zᵀPz = c·4⁻ᵏ, and their levels."""
    n = P.shape[0]
    d = rng.standard_normal((DIRECTIONS, n))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    L = np.linalg.cholesky(P)
    unit = scipy.linalg.solve_triangular(L, d.T, lower=True, trans="T").T  # uᵀPu = 1
    levels = np.repeat(c * 4.0 ** -np.arange(SHELLS), DIRECTIONS)
    return np.sqrt(levels)[:, None] * np.tile(unit, (SHELLS, 1)), levels


def terminal_set(system, step: StepMap, tol: float = SUCCESS_TOL, seed: int = 0) -> TerminalSet | None:
    """The terminal set of the loop whose one-step map is `step` (module doc), or None where the loop
    linearised at x* is not Schur stable, x* is not its fixed point, or no level passes."""
    nq = int(system.nq)
    q_star = np.asarray(system.x_star, float)[:nq]
    mask = np.asarray(system.angle_mask, bool)[:nq]
    A = _jacobian(step, q_star, mask)
    if A is None or not np.all(np.isfinite(A)) or np.abs(np.linalg.eigvals(A)).max() >= 1.0:
        return None
    W = np.eye(2 * nq) / tol**2
    P = scipy.linalg.solve_discrete_lyapunov(A.T, W)
    P = 0.5 * (P + P.T)
    if np.linalg.eigvalsh(P).min() <= 0:
        return None
    rate = float(scipy.linalg.eigh(W, P, eigvals_only=True).min())
    c = float(np.min(tol**2 / np.diag(np.linalg.inv(P))))
    rng = np.random.default_rng(seed)
    for _ in range(SHRINKS + 1):
        z, levels = _shell_states(P, c, rng)
        qn, vn, bad = step(q_star + z[:, :nq], z[:, nq:].copy())
        zn = np.concatenate([wrap_angles(qn - q_star, mask), vn], axis=1)
        after = np.einsum("ni,ij,nj->n", zn, P, zn)
        if not bad.any() and np.all(after <= (1.0 - 0.5 * rate) * levels):
            return TerminalSet(P=P, c=c, q_star=q_star, angle_mask=mask)
        c /= 4.0
    return None
