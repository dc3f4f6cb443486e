"""Controllability of a linearisation ``ẋ = A x + B u``: the controllable subspace (an orthogonal
staircase), its dimension, the modes no input reaches, and stabilisability.

Everything here is numpy float64 and free of the rest of the package.
"""

from __future__ import annotations

import numpy as np

from ._matrices import _check_system

__all__ = ["controllability_rank", "is_stabilisable", "uncontrollable_eigenvalues"]

_RTOL = 1e-10
"""Default relative tolerance of the controllability staircase (see :func:`controllability_rank`)."""


def _orth(W: np.ndarray, tol: float) -> np.ndarray:
    """Orthonormal basis (columns) of the range of ``W``, singular values ≤ ``tol`` dropped."""
    if W.shape[1] == 0:
        return W
    U, s, _ = np.linalg.svd(W, full_matrices=False)
    return U[:, : int(np.sum(s > tol))]


def _controllable_basis(A: np.ndarray, B: np.ndarray, rtol: float) -> np.ndarray:
    """Orthonormal basis ``V`` (n, r) of the controllable subspace span{B, AB, A²B, …}.

    Orthogonal staircase (block Arnoldi) reduction: each step maps only the directions found in the
    previous step through A, re-orthogonalises twice against the basis so far, and keeps singular
    values above ``rtol·‖A‖₂``. The first block is thresholded relative to ‖B‖₂, so the result is
    invariant to the scaling of the inputs. Unlike the rank of the Krylov matrix [B, AB, …], whose
    columns grow like ‖A‖ᵏ, every block here is of order one.
    """
    n = A.shape[0]
    V = _orth(B, rtol * max(np.linalg.norm(B, 2), np.finfo(float).tiny))
    tol_a = rtol * max(np.linalg.norm(A, 2), np.finfo(float).tiny)
    new = V
    while new.shape[1] > 0 and V.shape[1] < n:
        W = A @ new
        for _ in range(2):  # classical Gram-Schmidt, twice is enough
            W = W - V @ (V.T @ W)
        new = _orth(W, tol_a)
        V = np.hstack([V, new])
    return V[:, :n]


def controllability_rank(A, B, rtol: float = _RTOL) -> int:
    """Dimension of the controllable subspace of ``ẋ = A x + B u``.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
    rtol : float
        Relative tolerance: a new direction counts when its singular value exceeds ``rtol·‖A‖₂``
        (``rtol·‖B‖₂`` for the first block). Couplings weaker than that are treated as absent.

    Returns
    -------
    int
        The rank of [B, AB, …, Aⁿ⁻¹B], computed by an orthogonal staircase reduction (robust
        where the plain Krylov matrix is badly scaled). ``n`` means (A, B) is controllable.
    """
    A, B = _check_system(A, B)
    return int(_controllable_basis(A, B, rtol).shape[1])


def uncontrollable_eigenvalues(A, B, rtol: float = _RTOL) -> np.ndarray:
    """Eigenvalues of A that no input can move (the uncontrollable modes).

    With V an orthonormal basis of the (A-invariant) controllable subspace and W of its orthogonal
    complement, ``[V W]ᵀ A [V W] = [[A_cc, A_cu], [0, A_uu]]``; the uncontrollable modes are
    ``eig(A_uu)``.

    Returns
    -------
    np.ndarray, shape (n - controllability_rank(A, B),), complex
    """
    A, B = _check_system(A, B)
    V = _controllable_basis(A, B, rtol)
    n, r = A.shape[0], V.shape[1]
    if r == n:
        return np.zeros(0, dtype=complex)
    Qfull, _ = np.linalg.qr(np.hstack([V, np.eye(n)]))
    W = Qfull[:, r:n]
    W = W - V @ (V.T @ W)
    W, _ = np.linalg.qr(W)
    return np.linalg.eigvals(W.T @ A @ W).astype(complex)


def is_stabilisable(A, B, rtol: float = _RTOL, margin: float = 0.0) -> bool:
    """True when every uncontrollable mode of (A, B) has real part < ``-margin``."""
    lam = uncontrollable_eigenvalues(A, B, rtol)
    return bool(np.all(lam.real < -margin))
