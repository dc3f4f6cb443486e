"""Neural networks for the desired closed loop ẋ = (J_d(x) - R_d(x)) ∇H_d(x)  (paper §IV-A).

Each function has its structure *by construction*, for every value of the weights (the structural
conditions (i)–(iii) of the paper's Proposition 3, label ``prop:vanishing_mu``):

* :class:`InterconnectionNet` — J_d(x) = skew(NN_J(u)) ∈ 𝔰𝔬(n): J_d + J_dᵀ = 0.
* :class:`DampingNet` — R_d(x) = L(x)L(x)ᵀ + ρS with L lower triangular with a positive diagonal:
  R_d ≻ 0 (DESIGN §2; the paper's sym(NN) + ρI is not PD for all weights).
* :class:`EnergyNet` — H_d from an input-convex network (:class:`ICNN`, Amos et al. 2017) shaped so
  that H_d(x*) = 0, ∇H_d(x*) = 0, H_d > 0 elsewhere and ∇²H_d ≻ 0, exactly, without the paper's
  inner argmin (which is only approximate and drifts; DESIGN §2 lesson 4).

Two forms of each (chosen by passing anchors or not):

* free form (the paper's, with the exact Bregman shift for H_d);
* anchored form (DESIGN §2 "Local exactness: an LQR anchor"): given (P, J0, R0) from
  :func:`idapbc_pin.control.linear.lqr_anchor`, ∇²H_d(x*) = P, J_d(x*) = J0, R_d(x*) = R0 (ρ = 0), so the
  closed-loop Jacobian at x* is (J0 - R0)P = A - BK, the LQR loop, for any weights.

Conventions: states x have shape (N, n) (any leading batch shape works), x* has shape (n,). The
inner networks see the normalised, centred input ``u = (x - x*) / x_scale`` (x_scale: (n,), e.g.
the half-widths of the training box; ones by default). Every module takes its dtype and device
from ``x_star``; all constants are registered buffers, so ``state_dict`` round-trips through
``torch.save`` / ``torch.load(weights_only=True)``. Only torch (and numpy for anchors given as
arrays): no other module of the package is imported.
"""

from __future__ import annotations

import copy
import functools
import math
from typing import Literal

import numpy as np
import torch
from torch import Tensor, nn

__all__ = [
    "DampingNet",
    "EnergyNet",
    "ICNN",
    "InterconnectionNet",
    "lower_tri",
    "n_lower",
    "n_skew",
    "psi",
    "skew",
    "softplus",
    "unskew",
]


# --------------------------------------------------------------------------------------------
# Index maps: vectors <-> skew / lower-triangular matrices
# --------------------------------------------------------------------------------------------
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


class _Softplus(torch.autograd.Function):
    """softplus(x) = log(1 + eˣ), exact and C^∞ for every x, differentiable to any order.

    ``F.softplus`` switches to the identity above ``threshold=20``: a jump of 2·10⁻⁹ in value and
    slope there, which breaks convexity and the exactness of ∇H_d(x*) at the 10⁻⁹ level.
    Forward: relu(x) + log1p(e^{-|x|}) (no overflow); backward: g·sigmoid(x), itself made of
    differentiable ops, so double and triple backward work; forward mode and ``torch.func``
    transforms (grad, jacrev, jacfwd, hessian, vmap) work too.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(x: Tensor) -> Tensor:
        return torch.relu(x) + torch.log1p(torch.exp(-x.abs()))

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:
        ctx.save_for_backward(inputs[0])
        ctx.save_for_forward(inputs[0])

    @staticmethod
    def backward(ctx, g: Tensor) -> Tensor:
        (x,) = ctx.saved_tensors
        return g * torch.sigmoid(x)

    @staticmethod
    def jvp(ctx, t: Tensor) -> Tensor:
        (x,) = ctx.saved_tensors
        return t * torch.sigmoid(x)


def softplus(x: Tensor) -> Tensor:
    """Smooth softplus log(1 + eˣ), derivative sigmoid(x), for any x (see :class:`_Softplus`).

    Without autograd (inference) the same formula runs directly: `autograd.Function.apply` costs
    ~0.5 ms per call in Python overhead, which dominated the run-time controller.
    """
    if not (torch.is_grad_enabled() and x.requires_grad) and not torch._C._functorch.is_functorch_wrapped_tensor(x):
        return torch.relu(x) + torch.log1p(torch.exp(-x.abs()))
    return _Softplus.apply(x)


def psi(s: Tensor) -> Tensor:
    """ψ(s) = s - log(1 + s): convex, increasing on s ≥ 0, ψ(0) = ψ'(0) = 0, ψ''(0) = 1.

    Grows linearly for large s (ψ'(s) = s/(1+s) → 1), quadratically near 0 (ψ ≈ s²/2).
    """
    return s - torch.log1p(s)


# --------------------------------------------------------------------------------------------
# Shared plumbing
# --------------------------------------------------------------------------------------------
def _factory(x_star: Tensor) -> dict:
    if not (isinstance(x_star, Tensor) and x_star.ndim == 1 and x_star.is_floating_point()):
        raise ValueError("x_star must be a 1-D floating-point tensor of shape (n,)")
    return {"dtype": x_star.dtype, "device": x_star.device}


def _metric(metric, x_star: Tensor) -> Tensor | None:
    """Box half-widths s (n,) > 0 as a tensor like x_star, or None."""
    if metric is None:
        return None
    s = _as_buffer("metric", metric, x_star, x_star.shape)
    if not (s > 0).all():
        raise ValueError("metric must be positive")
    return s


def _as_buffer(name: str, M, like: Tensor, shape: tuple[int, ...]) -> Tensor:
    if isinstance(M, np.ndarray):
        M = np.array(M, dtype=np.float64)  # writable copy (LinearAnchor arrays are read-only)
    M = torch.as_tensor(M, dtype=like.dtype, device=like.device).detach().clone()
    if tuple(M.shape) != shape:
        raise ValueError(f"{name} must have shape {shape}, got {tuple(M.shape)}")
    if not torch.isfinite(M).all():
        raise ValueError(f"{name} has non-finite entries")
    return M


def _activation(name: str) -> nn.Module:
    acts = {"tanh": nn.Tanh, "softplus": _SoftplusModule}
    if name not in acts:
        raise ValueError(f"activation must be one of {sorted(acts)}, got {name!r}")
    return acts[name]()


class _SoftplusModule(nn.Module):
    def forward(self, x: Tensor) -> Tensor:
        return softplus(x)


def _mlp(
    n_in: int,
    width: int,
    depth: int,
    n_out: int,
    activation: str,
    out_scale: float,
    fk: dict,
    out_bias: bool = True,
) -> nn.Sequential:
    """MLP n_in → [width]×depth → n_out, smooth activations, PyTorch default init.

    The last layer's weights (and bias) are multiplied by ``out_scale`` at initialisation
    (``0`` starts the network at a constant output, i.e. an anchored net at its anchor).
    ``out_bias=False`` drops the last bias (anchored nets use NN(u) - NN(0), which cancels it).
    """
    if depth < 1 or width < 1:
        raise ValueError(f"width and depth must be ≥ 1, got width={width}, depth={depth}")
    layers: list[nn.Module] = []
    d = n_in
    for _ in range(depth):
        layers += [nn.Linear(d, width, **fk), _activation(activation)]
        d = width
    last = nn.Linear(d, n_out, bias=out_bias, **fk)
    with torch.no_grad():
        last.weight.mul_(out_scale)
        if out_bias:
            last.bias.mul_(out_scale)
    layers.append(last)
    return nn.Sequential(*layers)


class _StateNet(nn.Module):
    """Holds x* (n,) and x_scale (n,); maps x to the inner input u = (x - x*)/x_scale."""

    def __init__(self, x_star: Tensor, x_scale: Tensor | None):
        super().__init__()
        fk = _factory(x_star)
        n = x_star.shape[0]
        self.n = n
        self.register_buffer("x_star", x_star.detach().clone())
        scale = torch.ones(n, **fk) if x_scale is None else _as_buffer("x_scale", x_scale, x_star, (n,))
        if not (scale > 0).all():
            raise ValueError("x_scale must be positive")
        self.register_buffer("x_scale", scale)

    def _u(self, x: Tensor) -> Tensor:
        if x.shape[-1] != self.n:
            raise ValueError(f"expected states with last dimension n={self.n}, got shape {tuple(x.shape)}")
        return (x - self.x_star) / self.x_scale


# --------------------------------------------------------------------------------------------
# ICNN
# --------------------------------------------------------------------------------------------
def _inv_softplus(y: Tensor) -> Tensor:
    """softplus⁻¹(y) = log(eʸ - 1) = y + log(1 - e⁻ʸ), y > 0."""
    return y + torch.log(-torch.expm1(-y))


class ICNN(nn.Module):
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


# --------------------------------------------------------------------------------------------
# H_d
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# J_d
# --------------------------------------------------------------------------------------------
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
    ):
        super().__init__(x_star, x_scale)
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


# --------------------------------------------------------------------------------------------
# R_d
# --------------------------------------------------------------------------------------------
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
    ):
        super().__init__(x_star, x_scale)
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
