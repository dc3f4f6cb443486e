"""Checks and small helpers for dense matrices (`controllability`, `idapbc_pin.control.linear`), numpy float64."""

from __future__ import annotations

import numpy as np


def _as_matrix(name: str, M, shape: tuple[int | None, int | None]) -> np.ndarray:
    """``M`` as a finite float64 2-D array of the given shape (``None`` = any size)."""
    M = np.atleast_2d(np.asarray(M, dtype=np.float64))
    if M.ndim != 2 or any(s is not None and s != t for s, t in zip(shape, M.shape)):
        want = "×".join("?" if s is None else str(s) for s in shape)
        raise ValueError(f"{name} must have shape ({want}), got {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} has non-finite entries")
    return M


def _check_system(A, B) -> tuple[np.ndarray, np.ndarray]:
    A = _as_matrix("A", A, (None, None))
    n = A.shape[0]
    if A.shape != (n, n):
        raise ValueError(f"A must be square, got {A.shape}")
    B = np.asarray(B, dtype=np.float64)
    if B.ndim == 1:
        B = B[:, None]
    B = _as_matrix("B", B, (n, None))
    return A, B


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)


def _is_spd(M: np.ndarray, rtol: float = 0.0) -> bool:
    """Symmetric M with λ_min(M) > rtol·λ_max(M) (and a Cholesky factor)."""
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return False
    lam = np.linalg.eigvalsh(M)
    return bool(lam[0] > rtol * lam[-1])


_PD_RTOL = 1e-12
"""An anchor P or R with λ_min ≤ _PD_RTOL·λ_max is treated as singular."""
