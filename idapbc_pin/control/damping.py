"""Desired damping R_d(x) = L(x)L(x)ᵀ + ρS, L lower triangular with a positive diagonal: R_d ≻ 0
for any weights (paper §IV-A, condition (i); DESIGN §2: the paper's sym(NN) + ρI is not positive
definite for all weights). Anchored on R0, R_d(x*) = R0 when ρ = 0."""

from __future__ import annotations

import copy
import math
from typing import Literal

import torch
from torch import Tensor

from .layers import _as_buffer, _factory, _metric, _mlp, _StateNet, softplus
from .structure import lower_tri, n_lower

__all__ = ["DampingNet"]


class DampingNet(_StateNet):
    """Desired damping R_d: ℝⁿ → 𝕊ⁿ₊₊,  R_d(x) = L(x)L(x)ᵀ + ρS.

    L(x) is lower triangular with a positive diagonal, hence invertible, so L Lᵀ ≻ 0 for any
    weights even with ρ = 0. One MLP n → [width]×depth → n(n+1)/2 gives (r_d (n), r_o (n(n-1)/2)):

    * free form (``R0=None``):  diag L = softplus(r_d(u)), strict lower L = r_o(u);
    * anchored form:            diag L = exp(log d0 + r_d(u) - r_d(0)),
                                strict lower L = L0 + r_o(u) - r_o(0),
      with L0 + diag(d0) = chol(R0), so R_d(x*) = R0 exactly when ρ = 0.

    S is the damping-injection pattern (DESIGN §2 lesson 2): ``"full"`` → I (the paper's ρI), or
    ``"actuated"`` → diag(mask), damping only the actuated momentum rows, which the input can
    reach. ρ ≥ 0 is a buffer ("extra damping", paper Fig. ii), changed after training with
    :meth:`with_rho`.

    Parameters
    ----------
    x_star : Tensor, shape (n,)
    width, depth : int
    R0 : Tensor or array, shape (n, n), optional
        Symmetric positive-definite anchor (``LinearAnchor.R``); selects the anchored form.
    rho : float
        ρ ≥ 0 (default 0).
    pattern : {"full", "actuated"}
    actuated : Tensor of bool, shape (n,), optional
        Required for ``pattern="actuated"``: True on the state rows of actuated momenta.
    activation : {"tanh", "softplus"}
    out_scale : float
        Multiplies the last layer's initial weights (0: start at R_d ≡ R0 in the anchored form).
    x_scale : Tensor, shape (n,), optional
    input_bound : float, optional
        b > 0: the network sees u clamped to [−b, b], so outside that box (b = 1: the training box)
        it keeps its boundary values; the structure holds for any input.
    metric : Tensor, shape (n,), optional
        s > 0: row i of the network's part of L is multiplied by s_i, so R_d = S L_z L_zᵀ S
        (R_d in box units z = x/s); the anchored diagonal is relative and stays unscaled.

    Notes
    -----
    Positive definiteness of L Lᵀ is exact in exact arithmetic; numerically σ_min(R_d) can still be
    tiny (an L with large off-diagonal entries is ill-conditioned). A guaranteed floor is
    ρ·λ_min(S), i.e. ρ for ``pattern="full"``; the paper's damping-floor loss f_sd2 watches
    :meth:`min_eig`.
    """

    def __init__(
        self,
        x_star: Tensor,
        width: int = 64,
        depth: int = 2,
        *,
        R0: Tensor | None = None,
        rho: float = 0.0,
        pattern: Literal["full", "actuated"] = "full",
        actuated: Tensor | None = None,
        activation: str = "tanh",
        out_scale: float = 1.0,
        x_scale: Tensor | None = None,
        metric: Tensor | None = None,
        input_bound: float | None = None,
    ):
        super().__init__(x_star, x_scale, input_bound)
        fk = _factory(x_star)
        n = self.n
        self.net = _mlp(n, width, depth, n_lower(n), activation, out_scale, fk, out_bias=R0 is None)
        s = _metric(metric, x_star)
        if s is None:
            self.register_buffer("row_scale", None)
        else:
            rows, _ = torch.tril_indices(n, n, offset=-1, device=s.device)
            self.register_buffer("row_scale", torch.cat([s, s[rows]]))  # (diag, strict lower) entries of L
        self.register_buffer("S", self._pattern(pattern, actuated, x_star))
        self.pattern = pattern
        self.register_buffer("rho", self._check_rho(rho, fk))
        if R0 is None:
            self.register_buffer("log_d0", None)
            self.register_buffer("L0", None)
        else:
            R0 = _as_buffer("R0", R0, x_star.double(), (n, n))  # factor in float64, then cast:
            C, info = torch.linalg.cholesky_ex(0.5 * (R0 + R0.T))  # an ill-conditioned R0 can fail in float32
            if info != 0:
                raise ValueError("R0 must be symmetric positive definite")
            C = C.to(x_star.dtype)
            self.register_buffer("log_d0", torch.log(torch.diagonal(C)).clone())
            i, j = torch.tril_indices(n, n, offset=-1, device=C.device)
            self.register_buffer("L0", C[i, j].clone())

    @staticmethod
    def _pattern(pattern: str, actuated: Tensor | None, x_star: Tensor) -> Tensor:
        n = x_star.shape[0]
        if pattern == "full":
            return torch.eye(n, dtype=x_star.dtype, device=x_star.device)
        if pattern == "actuated":
            if actuated is None:
                raise ValueError("pattern='actuated' needs the boolean mask `actuated` of shape (n,)")
            mask = torch.as_tensor(actuated, device=x_star.device)
            if mask.dtype != torch.bool or tuple(mask.shape) != (n,):
                raise ValueError(f"`actuated` must be a bool tensor of shape ({n},)")
            return torch.diag(mask.to(x_star.dtype))
        raise ValueError(f"pattern must be 'full' or 'actuated', got {pattern!r}")

    @staticmethod
    def _check_rho(rho: float, fk: dict) -> Tensor:
        rho = float(rho)
        if not (math.isfinite(rho) and rho >= 0.0):
            raise ValueError(f"rho must be finite and ≥ 0, got {rho}")
        return torch.tensor(rho, **fk)

    @property
    def form(self) -> Literal["free", "anchored"]:
        return "free" if self.L0 is None else "anchored"

    def cholesky_factor(self, x: Tensor, out0: Tensor | None = None) -> Tensor:
        """L(x): (N, n) → (N, n, n), lower triangular with a positive diagonal.

        ``out0`` = the MLP at x* (anchored form), if the caller has it cached.
        """
        n = self.n
        out = self.net(self._u(x))
        r_d, r_o = out[..., :n], out[..., n:]
        s = self.row_scale
        if self.L0 is None:
            entries = torch.cat([softplus(r_d), r_o], dim=-1)
            return lower_tri(entries if s is None else entries * s, n)
        out0 = self.net(torch.zeros_like(self.x_star)) if out0 is None else out0
        diag = torch.exp(self.log_d0 + r_d - out0[:n])  # relative: needs no scaling
        step = r_o - out0[n:]
        low = self.L0 + (step if s is None else step * s[n:])
        return lower_tri(torch.cat([diag, low], dim=-1), n)

    def forward(self, x: Tensor) -> Tensor:
        """R_d(x) = L Lᵀ + ρS: (N, n) → (N, n, n), symmetric positive definite."""
        L = self.cholesky_factor(x)
        return L @ L.transpose(-1, -2) + self.rho * self.S

    def min_eig(self, x: Tensor) -> Tensor:
        """σ_min(R_d(x)) = λ_min (R_d symmetric), shape (N,), via ``torch.linalg.eigvalsh``."""
        return torch.linalg.eigvalsh(self(x))[..., 0]

    def with_rho(self, rho: float) -> "DampingNet":
        """A copy with ρ replaced, sharing every parameter (and the MLP) with ``self``.

        ``self`` is unchanged; training either module trains both. The copy's ``state_dict``
        carries the new ρ.
        """
        new = copy.copy(self)
        new._buffers = dict(self._buffers)  # own buffer table: setting ρ must not touch self
        new.rho = self._check_rho(rho, {"dtype": self.rho.dtype, "device": self.rho.device})
        return new
