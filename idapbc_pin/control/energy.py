"""Desired energy H_d with the paper's conditions (i)–(iii) by construction (paper §IV-A).

H_d is shaped from the Bregman divergence of an `ICNN` at x*, so that H_d(x*) = 0, ∇H_d(x*) = 0,
H_d > 0 elsewhere and ∇²H_d ≻ 0, exactly, without the paper's inner argmin (which is only
approximate and drifts; DESIGN §2 lesson 4). Anchored on P, ∇²H_d(x*) = P.
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from .icnn import ICNN
from .layers import _as_buffer, _factory, _StateNet, psi

__all__ = ["EnergyNet"]


class EnergyNet(_StateNet):
    """Desired energy H_d: ℝⁿ → ℝ≥0 satisfying the paper's (i)–(iii) exactly, for any weights.

    With Ĥ the :class:`ICNN` of u = (x - x*)/x_scale (or W(x − x*), see ``input_map``) and its
    Bregman divergence at x*,

        D(x) = Ĥ(u) - Ĥ(0) - ∇_uĤ(0)ᵀu  ≥ 0    (convex, D(x*) = 0, ∇D(x*) = 0),

    * free form (``P=None``):   H_d(x) = D(x) + ε‖x - x*‖²;
      ∇²H_d ⪰ 2εI ≻ 0 everywhere, H_d ≥ ε‖x - x*‖² > 0 for x ≠ x*.
    * anchored form (``P`` given): H_d(x) = ½δᵀPδ + ψ(D(x) + ε‖δ‖²), δ = x - x*, ψ(s) = s - log(1+s);
      convex (ψ convex non-decreasing on s ≥ 0, its argument convex), ∇²H_d ⪰ P ≻ 0, and, as
      ψ'(0) = 0 and ∇D(x*) = 0, ∇²H_d(x*) = P exactly.

    Parameters
    ----------
    x_star : Tensor, shape (n,)
        Target state x*; sets dtype and device.
    width, depth : int
        ICNN size.
    P : Tensor or array, shape (n, n), optional
        Symmetric positive-definite anchor (``LinearAnchor.P``); selects the anchored form.
    eps : float
        ε ≥ 0 (> 0 required in the free form). Default 1e-3: a curvature floor 2ε well below the
        ICNN's initial curvature (≈ 0.05–0.1 per unit u² for width 64) that keeps H_d strictly
        convex and radially unbounded where the softplus units saturate. In the anchored form it
        only adds a term of order ‖δ‖⁴ (ψ ≈ s²/2); 0 is allowed there.
    x_scale : Tensor, shape (n,), optional
        Input normalisation of the ICNN (the ε and P terms are in x).
    input_map : Tensor, shape (n, n), optional
        W: the ICNN sees u = W(x − x*) instead of (x − x*)/x_scale, and ∇D = Wᵀ∇_uD. With W = S P
        (S = diag of the box half-widths; `TrainConfig.energy_input = "anchor"`) the network part of
        the anchored flow, (J0 − R0)∇ψ = A_cl P⁻¹∇ψ, becomes A_cl S ∇_uψ: bounded by the anchor's
        scale over the box however badly conditioned P is. Convexity and (i)–(iii) hold for any W
        (a convex function of a linear map is convex; D(x*) = 0, ∇D(x*) = 0 still).

    Notes
    -----
    ∇_uĤ(0) comes from :meth:`ICNN.bregman`, an explicit differentiable expression of the weights:
    training differentiates through it (second order in the weights, third order with the Jacobian
    of (J_d - R_d)∇H_d), with no nested ``autograd.grad`` inside ``forward``. The ICNN has no
    affine output term here (the Bregman form cancels it).
    """

    def __init__(
        self,
        x_star: Tensor,
        width: int = 64,
        depth: int = 2,
        *,
        P: Tensor | None = None,
        eps: float = 1e-3,
        x_scale: Tensor | None = None,
        input_map: Tensor | None = None,
    ):
        super().__init__(x_star, x_scale)
        fk = _factory(x_star)
        n = self.n
        self.icnn = ICNN(n, width, depth, affine_out=False, **fk)
        if not eps >= 0:
            raise ValueError(f"eps must be ≥ 0, got {eps}")
        if P is None:
            if not eps > 0:
                raise ValueError("the free (Bregman) form needs eps > 0 for strict convexity")
            self.register_buffer("P", None)
        else:
            P = _as_buffer("P", P, x_star, (n, n))
            P = 0.5 * (P + P.T)
            if torch.linalg.cholesky_ex(P).info != 0:
                raise ValueError("P must be symmetric positive definite")
            self.register_buffer("P", P)
        self.register_buffer("eps", torch.tensor(float(eps), **fk))
        self.register_buffer("input_map", None if input_map is None else _as_buffer("input_map", input_map, x_star, (n, n)))

    def _u(self, x: Tensor) -> Tensor:
        """The ICNN's input: u = W(x − x*) with `input_map` W, else (x − x*)/x_scale."""
        u = super()._u(x)
        return u if self.input_map is None else (x - self.x_star) @ self.input_map.T

    def _to_x(self, g: Tensor) -> Tensor:
        """Chain rule back to x: ∇_x = Wᵀ∇_u, (..., n)."""
        return g / self.x_scale if self.input_map is None else g @ self.input_map

    @property
    def form(self) -> Literal["bregman", "anchored"]:
        """``"anchored"`` when built with P, else ``"bregman"`` (free form)."""
        return "bregman" if self.P is None else "anchored"

    def bregman(self, x: Tensor) -> Tensor:
        """D(x) = Ĥ(u) - Ĥ(0) - ∇_uĤ(0)ᵀu ≥ 0, shape (N,). Exactly 0, with zero gradient, at x*."""
        return self.icnn.bregman(self._u(x))

    def forward(self, x: Tensor) -> Tensor:
        """H_d(x): (N, n) → (N,)."""
        D = self.bregman(x)
        delta = x - self.x_star
        s = D + self.eps * (delta * delta).sum(-1)
        if self.P is None:
            return s
        return 0.5 * ((delta @ self.P) * delta).sum(-1) + psi(s)

    def value_and_grad_explicit(self, x: Tensor, at_target: tuple[Tensor, Tensor] | None = None) -> tuple[Tensor, Tensor]:
        """H_d(x) (N,) and ∇H_d(x) (N, n) with no autograd: the ICNN's explicit backward pass.

        ∇D = (∇_uĤ(u) − ∇_uĤ(0)) / x_scale; free form ∇H_d = ∇D + 2εδ; anchored
        ∇H_d = Pδ + ψ'(s)(∇D + 2εδ) with ψ'(s) = s/(1 + s). The fast path of the run-time
        controller (one state per control period); equal to `value_and_grad` to rounding.
        ``at_target`` = (Ĥ(0), ∇Ĥ(0)) if the caller has them cached.
        """
        u = self._u(x)
        h0, g0 = self.icnn.value_and_grad(u.new_zeros(self.n)) if at_target is None else at_target
        h, g = self.icnn.value_and_grad(u)
        delta = x - self.x_star
        D = h - h0 - u @ g0  # rounding-level error near x* (the exact form is `bregman`)
        dD = self._to_x(g - g0)
        s = D + self.eps * (delta * delta).sum(-1)
        ds = dD + 2 * self.eps * delta
        if self.P is None:
            return s, ds
        H = 0.5 * ((delta @ self.P) * delta).sum(-1) + psi(s)
        return H, delta @ self.P + (s / (1 + s)).unsqueeze(-1) * ds

    def value_and_grad(self, x: Tensor, create_graph: bool = False) -> tuple[Tensor, Tensor]:
        """H_d(x) (N,) and ∇H_d(x) (N, n) via ``torch.autograd.grad`` of the sum.

        ``create_graph=True`` keeps the graph, so ∇H_d can be differentiated again w.r.t. x
        (Jacobian of the closed loop) and the weights (training). If ``x`` already requires grad
        it is used as is (the result then depends on x through the graph); otherwise a detached
        leaf copy is used. Works under ``torch.no_grad``.
        """
        with torch.enable_grad():
            if not x.requires_grad:
                x = x.detach().requires_grad_(True)
            H = self(x)
            (g,) = torch.autograd.grad(H.sum(), x, create_graph=create_graph)
        return (H if create_graph else H.detach()), g

    def grad(self, x: Tensor, create_graph: bool = False) -> Tensor:
        """∇H_d(x), shape (N, n); see :meth:`value_and_grad`."""
        return self.value_and_grad(x, create_graph)[1]
