"""Desired interconnection J_d(x) = skew(NN_J(u)) ∈ 𝔰𝔬(n): J_d + J_dᵀ = 0 for any weights
(paper §IV-A, condition (i)); anchored on J0, J_d(x*) = J0."""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from .layers import _as_buffer, _factory, _metric, _mlp, _StateNet
from .structure import n_skew, skew

__all__ = ["InterconnectionNet"]


class InterconnectionNet(_StateNet):
    """Desired interconnection J_d: ℝⁿ → 𝔰𝔬(n), skew-symmetric for any weights.

    * free form (``J0=None``):  J_d(x) = skew(NN_J(u));
    * anchored form:            J_d(x) = J0 + skew(NN_J(u) - NN_J(0)),  so J_d(x*) = J0 exactly.

    NN_J is an MLP n → [width]×depth → n(n-1)/2 with smooth activations; skew(v) = A - Aᵀ,
    A strictly upper triangular with entries v.

    Parameters
    ----------
    x_star : Tensor, shape (n,)
    width, depth : int
    J0 : Tensor or array, shape (n, n), optional
        Skew anchor (``LinearAnchor.J``); it is re-skewed, ½(J0 - J0ᵀ), to remove rounding.
    activation : {"tanh", "softplus"}
    out_scale : float
        Multiplies the last layer's initial weights (0: start at J_d ≡ J0, resp. ≡ skew(bias=0)).
    x_scale : Tensor, shape (n,), optional
    input_bound : float, optional
        b > 0: the network sees u clamped to [−b, b], so outside that box (b = 1: the training box)
        it keeps its boundary values; the structure holds for any input.
    metric : Tensor, shape (n,), optional
        s > 0: the network's skew part is S skew(·) S, S = diag(s) (J_d in box units z = x/s).
    """

    def __init__(
        self,
        x_star: Tensor,
        width: int = 64,
        depth: int = 2,
        *,
        J0: Tensor | None = None,
        activation: str = "tanh",
        out_scale: float = 1.0,
        x_scale: Tensor | None = None,
        metric: Tensor | None = None,
        input_bound: float | None = None,
    ):
        super().__init__(x_star, x_scale, input_bound)
        n = self.n
        if n < 2:
            raise ValueError("InterconnectionNet needs n ≥ 2")
        fk = _factory(x_star)
        self.net = _mlp(n, width, depth, n_skew(n), activation, out_scale, fk, out_bias=J0 is None)
        s = _metric(metric, x_star)
        self.register_buffer("metric", None if s is None else torch.outer(s, s))
        if J0 is None:
            self.register_buffer("J0", None)
        else:
            J0 = _as_buffer("J0", J0, x_star, (n, n))
            asym = (J0 + J0.T).abs().max()
            if asym > 1e-8 * max(1.0, float(J0.abs().max())):
                raise ValueError(f"J0 must be skew-symmetric (max |J0 + J0ᵀ| = {float(asym):.3g})")
            self.register_buffer("J0", 0.5 * (J0 - J0.T))

    @property
    def form(self) -> Literal["free", "anchored"]:
        return "free" if self.J0 is None else "anchored"

    def forward(self, x: Tensor, v0: Tensor | None = None) -> Tensor:
        """J_d(x): (N, n) → (N, n, n), skew-symmetric. ``v0``: the MLP at x*, if cached."""
        v = self.net(self._u(x))
        if self.J0 is None:
            return self._scaled(skew(v, self.n))
        v0 = self.net(torch.zeros_like(self.x_star)) if v0 is None else v0
        return self.J0 + self._scaled(skew(v - v0, self.n))

    def _scaled(self, K: Tensor) -> Tensor:
        """S K S with S = diag(metric) (box units), or K."""
        return K if self.metric is None else K * self.metric
