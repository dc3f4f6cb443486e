"""Linear-quadratic regulator and the LQR anchor of the desired closed loop.

At the target x* the linearised matching problem of IDA-PBC always has an exact solution when the
linearisation ``(A, B)`` is stabilisable (DESIGN §2, "Local exactness: an LQR anchor"): take the
LQR closed loop ``A_cl = A - B K``, a matrix ``P ≻ 0`` with ``A_clᵀ P + P A_cl = -Q' ≺ 0`` and

    Z = A_cl P⁻¹,   J = (Z - Zᵀ)/2 (skew),   R = -(Z + Zᵀ)/2 = ½ P⁻¹ Q' P⁻¹ ≻ 0,

so that ``A_cl = (J - R) P`` exactly. Networks J_d, R_d, H_d taking the values J, R and Hessian P at
x* (`nets.build_nets`, anchored forms) have a closed loop ẋ = (J_d - R_d) ∇H_d whose linearisation
at x* *is* the LQR loop; and since ``g⊥ B = 0``, ``g⊥ (A_cl - A) = -g⊥ B K = 0``, i.e. the
mismatch Jacobian ∂μ/∂x(x*) vanishes exactly.

Controllability (whether an anchor exists at all) lives in `controllability`; its names are
re-exported here.

Everything here is numpy float64 and free of the rest of the package.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg as sla

from ..model._matrices import _PD_RTOL, _as_matrix, _check_system, _is_spd, _sym
from ..model.controllability import controllability_rank, is_stabilisable, uncontrollable_eigenvalues

__all__ = [
    "LinearAnchor",
    "controllability_rank",
    "fastest_pole",
    "is_stabilisable",
    "lqr",
    "lqr_anchor",
    "uncontrollable_eigenvalues",
]


def fastest_pole(A: np.ndarray) -> float:
    """max |λ(A)| of a square matrix A (n, n), in 1/s for a state matrix: the stiffest mode."""
    return float(np.abs(np.linalg.eigvals(A)).max())


# --------------------------------------------------------------------------------------------
# LQR
# --------------------------------------------------------------------------------------------
def _fmt_eigs(lam: np.ndarray) -> str:
    return ", ".join(f"{z.real:+.4g}{z.imag:+.4g}j" if abs(z.imag) > 0 else f"{z.real:+.4g}" for z in lam)


def lqr(A, B, Q, R) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time infinite-horizon LQR: minimise ∫ xᵀQx + uᵀRu dt for ẋ = Ax + Bu.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
    Q : array_like, shape (n, n)
        State weight, symmetric positive semidefinite.
    R : array_like, shape (m, m)
        Input weight, symmetric positive definite.

    Returns
    -------
    K : np.ndarray, shape (m, n)
        Gain of u = -K x, ``K = R⁻¹ Bᵀ S``.
    S : np.ndarray, shape (n, n)
        Stabilising solution of ``AᵀS + SA - SBR⁻¹BᵀS + Q = 0`` (symmetric, ⪰ 0); it satisfies
        ``A_clᵀS + S A_cl = -(Q + KᵀRK)`` with ``A_cl = A - BK`` Hurwitz.

    Raises
    ------
    ValueError
        If shapes are inconsistent, R is not positive definite, Q is not symmetric PSD, (A, B) is
        not stabilisable (the message lists the unstable uncontrollable modes), or the Riccati
        equation has no stabilising solution.
    """
    A, B = _check_system(A, B)
    n, m = B.shape
    Q = _as_matrix("Q", Q, (n, n))
    R = _as_matrix("R", R, (m, m))
    if not np.allclose(Q, Q.T, rtol=1e-10, atol=1e-12 * max(1.0, np.abs(Q).max())):
        raise ValueError("Q must be symmetric")
    if not np.allclose(R, R.T, rtol=1e-10, atol=1e-12 * max(1.0, np.abs(R).max())):
        raise ValueError("R must be symmetric")
    Q, R = _sym(Q), _sym(R)
    if not _is_spd(R):
        raise ValueError("R must be symmetric positive definite (every input must cost something)")
    if np.linalg.eigvalsh(Q).min() < -1e-10 * max(1.0, np.abs(Q).max()):
        raise ValueError("Q must be symmetric positive semidefinite")

    bad = uncontrollable_eigenvalues(A, B)
    bad = bad[bad.real >= 0.0]
    if bad.size:
        raise ValueError(
            f"(A, B) is not stabilisable: the mode(s) {_fmt_eigs(bad)} of A are not in the "
            f"stable half-plane and no input reaches them (controllable subspace has dimension "
            f"{controllability_rank(A, B)} of {n}). Check the actuated joints (B) and the target "
            f"state x*; no linear feedback, hence no IDA-PBC anchor, stabilises this target."
        )
    try:
        S = sla.solve_continuous_are(A, B, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(
            f"the Riccati equation has no stabilising solution ({exc}); (A, B) is stabilisable, "
            f"so check that Q makes (Q, A) detectable (e.g. Q positive definite)"
        ) from exc
    S = _sym(S)
    K = np.linalg.solve(R, B.T @ S)
    lam = np.linalg.eigvals(A - B @ K)
    if not (np.all(np.isfinite(S)) and np.all(lam.real < 0.0)):
        raise ValueError(
            f"LQR closed loop A - BK is not Hurwitz (eigenvalues {_fmt_eigs(lam)}): (A, B) is "
            f"numerically close to unstabilisable, or (Q, A) has undetectable modes on the "
            f"imaginary axis; use Q positive definite"
        )
    return K, S


# --------------------------------------------------------------------------------------------
# LQR anchor
# --------------------------------------------------------------------------------------------
def _readonly(M: np.ndarray) -> np.ndarray:
    M = np.array(M, dtype=np.float64, copy=True)
    M.setflags(write=False)
    return M


@dataclass(frozen=True)
class LinearAnchor:
    """Linear port-Hamiltonian form ``A_cl = (J - R) P`` of an LQR closed loop (read-only arrays).

    Attributes
    ----------
    P : np.ndarray, shape (n, n)
        Symmetric positive definite; the Hessian of H_d at x* (H_d ≈ ½ δᵀPδ, δ = x - x*).
    J : np.ndarray, shape (n, n)
        Skew-symmetric; J_d(x*).
    R : np.ndarray, shape (n, n)
        Symmetric positive definite; R_d(x*) (with ρ = 0).
    K : np.ndarray, shape (m, n)
        LQR gain, u = -K δ.
    A_cl : np.ndarray, shape (n, n)
        ``A - B K`` (Hurwitz), equal to ``(J - R) P`` up to rounding.
    """

    P: np.ndarray
    J: np.ndarray
    R: np.ndarray
    K: np.ndarray
    A_cl: np.ndarray

    @property
    def n(self) -> int:
        """State dimension."""
        return int(self.P.shape[0])

    @property
    def eigenvalues(self) -> np.ndarray:
        """Closed-loop eigenvalues ``eig(A_cl)``, shape (n,), complex."""
        return np.linalg.eigvals(self.A_cl)


def lqr_anchor(
    A,
    B,
    Q=None,
    R_u=None,
    P_mode: Literal["riccati", "lyapunov"] = "riccati",
    scale: float | Literal["unit"] | None = None,
    Q_lyap=None,
) -> LinearAnchor:
    """Exact pH anchor ``(P, J, R)`` of the LQR loop of the linearisation (A, B) at x*.

    Steps: ``K, S = lqr(A, B, Q, R_u)``; ``A_cl = A - BK``; ``P`` with
    ``A_clᵀP + PA_cl = -Q'``; ``Z = A_cl P⁻¹``, ``J = (Z - Zᵀ)/2``, ``R = -(Z + Zᵀ)/2``.
    Then ``(J - R) P = Z P = A_cl`` and ``R = ½ P⁻¹Q'P⁻¹ ≻ 0`` when ``Q' ≻ 0``.

    Parameters
    ----------
    A : array_like, shape (n, n)
        ∂f/∂x at x* (for x* an assignable equilibrium).
    B : array_like, shape (n, m)
        g(x*).
    Q : array_like, shape (n, n), optional
        LQR state weight; identity by default.
    R_u : array_like, shape (m, m), optional
        LQR input weight; identity by default.
    P_mode : {"riccati", "lyapunov"}
        ``"riccati"`` (default): ``P = S``, the Riccati solution, for which
        ``Q' = Q + KᵀR_uK``. ``"lyapunov"``: P solves ``A_clᵀP + PA_cl = -Q`` (``Q' = Q``); it can be
        badly conditioned (cartpole with Q = I: λ(P) from 0.11 to 565).
    scale : float, "unit" or None
        Rescales P (and hence divides J and R by the same factor; A_cl = (J - R)P is invariant, so is
        the closed loop). A float c > 0 uses ``cP``; ``"unit"`` normalises ``λ_max(P) = 1`` so that
        H_d ≈ ½δᵀPδ ≤ ½‖δ‖²; ``None`` keeps P as solved. H_d's scale is otherwise free (DESIGN §2,
        lesson 3), so this only sets the units of H_d and of the energy levels ε.

    Q_lyap : array_like, shape (n, n), optional
        ``P_mode="lyapunov"`` only: the Q' of the Lyapunov equation, decoupled from the LQR weight Q
        (the loop A_cl is the same; only the shape of H_d ≈ ½δᵀPδ changes). E.g. diag(1/half-width²)
        of the training box gives a P better conditioned in box units than Q' = I.

    Returns
    -------
    LinearAnchor

    Raises
    ------
    ValueError
        Unstabilisable (A, B) (see :func:`lqr`), a bad ``P_mode``/``scale``, or ``Q'`` singular
        (λ_min ≤ 1e-12·λ_max: then R is only semidefinite and cannot anchor R_d).
    """
    A, B = _check_system(A, B)
    n, m = B.shape
    Q = np.eye(n) if Q is None else _as_matrix("Q", Q, (n, n))
    R_u = np.eye(m) if R_u is None else _as_matrix("R_u", R_u, (m, m))
    K, S = lqr(A, B, Q, R_u)
    A_cl = A - B @ K
    P = _scaled(_energy_hessian(A_cl, K, S, Q, R_u, P_mode, Q_lyap), scale)
    if not _is_spd(P, _PD_RTOL):
        raise ValueError(
            f"P is not positive definite (P_mode={P_mode!r}, λ_min = "
            f"{np.linalg.eigvalsh(P).min():.3g}); use Q positive definite"
        )
    J, R = _ph_split(A_cl, P)
    return LinearAnchor(P=_readonly(P), J=_readonly(J), R=_readonly(R), K=_readonly(K), A_cl=_readonly(A_cl))


def _energy_hessian(A_cl, K, S, Q, R_u, P_mode: str, Q_lyap) -> np.ndarray:
    """P (n, n), the Hessian of H_d at x* before scaling: symmetric, A_clᵀP + PA_cl = −Q' with Q' ≻ 0.

    ``"riccati"``: P = S, Q' = Q + KᵀR_uK; ``"lyapunov"``: A_clᵀP + PA_cl = −Q' with Q' = Q_lyap or Q.
    """
    n = A_cl.shape[0]
    if P_mode == "riccati":
        P, Q_eff = S, Q + K.T @ R_u @ K
    elif P_mode == "lyapunov":
        # solve_continuous_lyapunov(a, q) solves a X + X aᴴ = q.
        Q_eff = Q if Q_lyap is None else _as_matrix("Q_lyap", Q_lyap, (n, n))
        P = sla.solve_continuous_lyapunov(A_cl.T, -_sym(Q_eff))
    else:
        raise ValueError(f"P_mode must be 'riccati' or 'lyapunov', got {P_mode!r}")
    if not _is_spd(_sym(Q_eff), _PD_RTOL):
        name = "Q + KᵀR_uK" if P_mode == "riccati" else "Q"
        raise ValueError(
            f"Q' = {name} is singular (P_mode={P_mode!r}), so R = ½P⁻¹Q'P⁻¹ would not be positive "
            f"definite; use Q positive definite"
        )
    return _sym(P)


def _scaled(P: np.ndarray, scale: float | Literal["unit"] | None) -> np.ndarray:
    """cP for `lqr_anchor`'s ``scale``: c = scale, c = 1/λ_max(P) for ``"unit"``, P itself for None."""
    if scale is None:
        return P
    if isinstance(scale, str):
        if scale != "unit":
            raise ValueError(f"scale must be a positive float, 'unit' or None, got {scale!r}")
        c = 1.0 / np.linalg.eigvalsh(P).max()
    else:
        c = float(scale)
        if not (np.isfinite(c) and c > 0.0):
            raise ValueError(f"scale must be positive, got {scale!r}")
    return c * P


def _ph_split(A_cl: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J, R), both (n, n): the skew and the negated symmetric part of Z = A_cl P⁻¹, so A_cl = (J − R)P."""
    # Z = A_cl P⁻¹, computed as (P⁻¹ A_clᵀ)ᵀ with P symmetric.
    Z = sla.solve(P, A_cl.T, assume_a="pos").T
    J = 0.5 * (Z - Z.T)
    R = -0.5 * (Z + Z.T)
    if not _is_spd(R):
        raise ValueError(
            f"R = ½P⁻¹Q'P⁻¹ is numerically not positive definite (λ_min = "
            f"{np.linalg.eigvalsh(R).min():.3g}, cond(P) = {np.linalg.cond(P):.3g}); try "
            f"P_mode='riccati' or a better scaled Q"
        )
    return J, R
