"""Batched algebra of a mechanical port-Hamiltonian system, shared by every back-end.

State x = (q, p) with p = M(q) v. H(q, p) = ½ pᵀ M(q)⁻¹ p + U(q) and, with joint damping D,

    q̇ = ∂H/∂p = v,          ṗ = −∂H/∂q − D v = ½ [vᵀ M_i v]_i − ∇U − D v,

where M_i = ∂M/∂q_i. A back-end supplies, per state, M⁻¹, W = [M_1 v, …, M_n v] (column j is
M_j v), Φ_ij = vᵀ M_ij v (M_ij = ∂²M/∂q_i∂q_j) and the gradient and Hessian of U; this module
turns them into f and ∂f/∂x (DESIGN §2). All arrays carry a leading batch dimension N.
"""

from __future__ import annotations

import numpy as np

__all__ = ["mechanical_f", "mechanical_jacobian"]


def mechanical_f(v: np.ndarray, W: np.ndarray, grad_U: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """Open-loop vector field f(x) = (v, ½ Wᵀv − ∇U − D v).

    Parameters
    ----------
    v : (N, nv) velocities M⁻¹p.
    W : (N, nv, nv) with W[:, :, j] = (∂M/∂q_j) v.
    grad_U : (N, nv) ∇U(q) (generalised gravity), N·m or N.
    damping : (nv,) joint damping coefficients (diagonal of D).

    Returns
    -------
    (N, 2 nv) array (q̇, ṗ).
    """
    p_dot = 0.5 * np.einsum("nkj,nk->nj", W, v) - grad_U - damping * v
    return np.concatenate([v, p_dot], axis=1)


def mechanical_jacobian(
    M_inv: np.ndarray,
    v: np.ndarray,
    W: np.ndarray,
    Phi: np.ndarray,
    hess_U: np.ndarray,
    damping: np.ndarray,
) -> np.ndarray:
    """∂f/∂x of the mechanical vector field, exact given exact inputs.

    Parameters
    ----------
    M_inv : (N, nv, nv) M(q)⁻¹.
    v : (N, nv) velocities.
    W : (N, nv, nv) W[:, :, j] = (∂M/∂q_j) v.
    Phi : (N, nv, nv) Φ_ij = vᵀ (∂²M/∂q_i∂q_j) v at fixed v.
    hess_U : (N, nv, nv) ∂²U/∂q².
    damping : (nv,) diagonal of D.

    Returns
    -------
    (N, 2 nv, 2 nv) Jacobian [[∂q̇/∂q, ∂q̇/∂p], [∂ṗ/∂q, ∂ṗ/∂p]] with p held fixed in ∂/∂q.
    """
    dv_dq = -M_inv @ W  # v = M⁻¹p, ∂v/∂q_j = −M⁻¹ M_j v
    dv_dp = M_inv
    Wt = np.swapaxes(W, 1, 2)
    D = damping[:, None]
    dpdot_dq = Wt @ dv_dq + 0.5 * Phi - hess_U - D * dv_dq
    dpdot_dp = Wt @ dv_dp - D * dv_dp
    top = np.concatenate([dv_dq, dv_dp], axis=2)
    bottom = np.concatenate([dpdot_dq, dpdot_dp], axis=2)
    return np.concatenate([top, bottom], axis=1)
