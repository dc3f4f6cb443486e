"""Input-convex neural network Ĥ (Amos, Xu, Kolter 2017) with an explicit gradient and an exact
Bregman divergence at 0: the convex core of the desired energy H_d (`energy.EnergyNet`)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .layers import _Cached, softplus

__all__ = ["ICNN"]


def _inv_softplus(y: Tensor) -> Tensor:
    """softplus⁻¹(y) = log(eʸ - 1) = y + log(1 - e⁻ʸ), y > 0."""
    return y + torch.log(-torch.expm1(-y))


class ICNN(_Cached):
    """Input-convex neural network Ĥ: ℝⁿ → ℝ (Amos, Xu, Kolter 2017), smooth.

    ``z₁ = σ(W_x⁰u + b⁰)``, ``z_{k+1} = σ(W_z^{k+} z_k + W_x^k u + b^k)`` (k = 1 … depth-1),
    ``Ĥ(u) = w_out⁺·z_depth [+ w_xᵀu + b]``, with σ = :func:`softplus` (convex, non-decreasing,
    C^∞) and ``W⁺ = softplus(Ŵ) > 0`` elementwise. Non-negativity is a reparametrisation, not a
    clamp, so Ĥ is convex in u for every value of the raw weights Ŵ.

    Parameters
    ----------
    n : int
        Input dimension.
    width, depth : int
        Hidden width and number of hidden layers (≥ 1).
    affine_out : bool
        Include the affine output term w_xᵀu + b (default). :class:`EnergyNet` drops it: its
        Bregman form cancels every affine function, so those weights would get no gradient.
    dtype, device : optional
        Factory arguments of the parameters.

    Notes
    -----
    Initialisation: W_x, b as ``nn.Linear`` (uniform ±1/√fan_in); the positive weights start at
    ``U(0.2, 1.8)/width`` (through softplus⁻¹), so a hidden unit's input has the mean of one unit's
    output and the depth neither blows up nor vanishes at initialisation (cf. Hoedt & Klambauer 2023).
    """

    _CACHES = ("_pos_cache",)  # W⁺ = softplus(Ŵ) per layer, without autograd (`_positive`)

    def __init__(self, n: int, width: int, depth: int, *, affine_out: bool = True, dtype=None, device=None):
        super().__init__()
        if depth < 1 or width < 1 or n < 1:
            raise ValueError(f"n, width, depth must be ≥ 1, got {n}, {width}, {depth}")
        fk = {"dtype": dtype, "device": device}
        self.n, self.width, self.depth = n, width, depth
        self.x_layers = nn.ModuleList([nn.Linear(n, width, **fk) for _ in range(depth)])
        self.z_raw = nn.ParameterList([nn.Parameter(self._pos_init((width, width), fk)) for _ in range(depth - 1)])
        self.out_raw = nn.Parameter(self._pos_init((width,), fk))
        self.out_x = nn.Linear(n, 1, **fk) if affine_out else None

    def _pos_init(self, shape: tuple[int, ...], fk: dict) -> Tensor:
        w = torch.empty(shape, **fk).uniform_(0.2, 1.8) / self.width
        return _inv_softplus(w)

    def _positive(self, k: int | None) -> Tensor:
        """W⁺ = softplus(Ŵ) of z-layer k (None: the output weights).

        Without autograd the result is cached until the raw weight changes (its version counter):
        softplus of a width × width matrix per call dominated the run-time controller.
        """
        raw = self.out_raw if k is None else self.z_raw[k]
        if torch.is_grad_enabled() and raw.requires_grad:
            return softplus(raw)
        cache = self.__dict__.setdefault("_pos_cache", {})
        key = (k, raw._version, raw.data_ptr())
        if key not in cache:
            cache.clear() if len(cache) > 4 * (self.depth + 1) else None
            cache[key] = softplus(raw.detach())
        return cache[key]

    def _pre(self, u: Tensor) -> list[Tensor]:
        """Pre-activations a_k(u), k = 0 … depth-1, each (..., width)."""
        pre = [self.x_layers[0](u)]
        for k in range(1, self.depth):
            pre.append(softplus(pre[-1]) @ self._positive(k - 1).T + self.x_layers[k](u))
        return pre

    def _affine(self, u: Tensor) -> Tensor | float:
        return 0.0 if self.out_x is None else self.out_x(u).squeeze(-1)

    def _grad(self, pre: list[Tensor]) -> Tensor:
        """∇_uĤ from the pre-activations by an explicit backward pass, (..., n)."""
        delta = self._positive(None)  # ∂Ĥ/∂z_depth, (width,)
        g = 0.0 if self.out_x is None else self.out_x.weight[0]
        for k in range(self.depth - 1, -1, -1):
            s = delta * torch.sigmoid(pre[k])  # ∂Ĥ/∂a_k, (..., width)
            g = g + s @ self.x_layers[k].weight
            if k > 0:
                delta = s @ self._positive(k - 1)
        return g

    def forward(self, u: Tensor) -> Tensor:
        """Ĥ(u): (..., n) → (...)."""
        return softplus(self._pre(u)[-1]) @ self._positive(None) + self._affine(u)

    def value_and_grad(self, u: Tensor) -> tuple[Tensor, Tensor]:
        """Ĥ(u) (...) and ∇Ĥ(u) (..., n), the gradient by an explicit backward pass.

        The gradient is an ordinary differentiable expression of u and the weights (no nested
        ``autograd.grad``), so it can be differentiated again in any mode and also works under
        ``torch.no_grad``.
        """
        pre = self._pre(u)
        return softplus(pre[-1]) @ self._positive(None) + self._affine(u), self._grad(pre)

    def bregman(self, u: Tensor) -> Tensor:
        """Bregman divergence at 0: D(u) = Ĥ(u) - Ĥ(0) - ∇Ĥ(0)ᵀu ≥ 0, shape (...).

        Computed by propagating differences from u = 0: with a_k⁰ = a_k(0),
        ``Δa_k = W_x^k u + W_z^{k+} Δz_{k-1}``, ``Δz_k = σ(a_k⁰ + Δa_k) - σ(a_k⁰)``, and
        ``Ĥ(u) - Ĥ(0) = w_out⁺·Δz_depth + w_xᵀu``. At u = 0 every Δ is exactly 0, so D(0) = 0 in
        floating point (not only up to ε_mach·|Ĥ|), which keeps H_d(x*) = 0 and the anchored
        ∇²H_d(x*) = P exact for weights of any size. Same cost as one forward pass.
        """
        pre0 = self._pre(u.new_zeros(self.n))
        g0 = self._grad(pre0)  # (n,)
        dz = None
        for k in range(self.depth):
            da = u @ self.x_layers[k].weight.T
            if k > 0:
                da = da + dz @ self._positive(k - 1).T
            dz = softplus(pre0[k] + da) - softplus(pre0[k])
        lin = 0.0 if self.out_x is None else u @ self.out_x.weight[0]
        return dz @ self._positive(None) + lin - u @ g0
