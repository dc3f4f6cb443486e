"""Index maps between flat vectors and structured matrices: skew-symmetric and lower triangular.

The networks output flat vectors; these maps place them in matrices whose structure holds for any
entries: ``skew(v) = A - Aᵀ`` (A strictly upper triangular with entries v) is exactly skew, and
``lower_tri(v)`` is lower triangular. Both are one matrix product with a cached 0/±1 basis, so
they work batched over any leading shape and under every autograd mode.
"""

from __future__ import annotations

import functools

import torch
from torch import Tensor

__all__ = ["lower_tri", "n_lower", "n_skew", "skew", "unskew"]


def n_skew(n: int) -> int:
    """Number of free entries of an n×n skew matrix, n(n-1)/2."""
    return n * (n - 1) // 2


def n_lower(n: int) -> int:
    """Number of entries of an n×n lower-triangular matrix (diagonal included), n(n+1)/2."""
    return n * (n + 1) // 2


@functools.lru_cache(maxsize=None)
def _skew_basis(n: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """E (n(n-1)/2, n²) with ``v @ E = vec(A - Aᵀ)``, A strictly upper with entries v (row-major)."""
    i, j = torch.triu_indices(n, n, offset=1)
    k = torch.arange(i.numel())
    E = torch.zeros(i.numel(), n, n, dtype=dtype)
    E[k, i, j] = 1.0
    E[k, j, i] = -1.0
    return E.reshape(-1, n * n).to(device)


@functools.lru_cache(maxsize=None)
def _lower_basis(n: int, strict: bool, dtype: torch.dtype, device: torch.device) -> Tensor:
    """E (k, n²) with ``v @ E = vec(L)``, L lower triangular with entries v (row-major).

    ``strict=False``: the first n entries of v are the diagonal, then the strict lower part
    (k = n(n+1)/2). ``strict=True``: strict lower part only (k = n(n-1)/2).
    """
    i, j = torch.tril_indices(n, n, offset=-1)
    if not strict:
        d = torch.arange(n)
        i, j = torch.cat([d, i]), torch.cat([d, j])
    E = torch.zeros(i.numel(), n, n, dtype=dtype)
    E[torch.arange(i.numel()), i, j] = 1.0
    return E.reshape(-1, n * n).to(device)


def skew(v: Tensor, n: int) -> Tensor:
    """Skew-symmetric matrices from their strictly-upper entries.

    Parameters
    ----------
    v : Tensor, shape (..., n(n-1)/2)
        Entries A[i, j], i < j, in row-major order (``torch.triu_indices(n, n, 1)``).
    n : int

    Returns
    -------
    Tensor, shape (..., n, n)
        ``A - Aᵀ``; exactly skew (J + Jᵀ = 0 in floating point).
    """
    if v.shape[-1] != n_skew(n):
        raise ValueError(f"skew: expected last dimension {n_skew(n)} for n={n}, got {v.shape[-1]}")
    return (v @ _skew_basis(n, v.dtype, v.device)).reshape(*v.shape[:-1], n, n)


def unskew(J: Tensor) -> Tensor:
    """Inverse of :func:`skew`: the strictly-upper entries of J, shape (..., n(n-1)/2)."""
    n = J.shape[-1]
    i, j = torch.triu_indices(n, n, offset=1, device=J.device)
    return J[..., i, j]


def lower_tri(v: Tensor, n: int, strict: bool = False) -> Tensor:
    """Lower-triangular matrices from their entries.

    Parameters
    ----------
    v : Tensor, shape (..., n(n+1)/2) or (..., n(n-1)/2) when ``strict``
        ``strict=False``: the n diagonal entries first, then the strict lower part in row-major
        order (``torch.tril_indices(n, n, -1)``). ``strict=True``: the strict lower part only.
    n : int

    Returns
    -------
    Tensor, shape (..., n, n)
    """
    k = n_skew(n) if strict else n_lower(n)
    if v.shape[-1] != k:
        raise ValueError(f"lower_tri: expected last dimension {k} for n={n}, got {v.shape[-1]}")
    return (v @ _lower_basis(n, strict, v.dtype, v.device)).reshape(*v.shape[:-1], n, n)
