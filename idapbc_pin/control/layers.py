"""Building blocks of the structured networks: a smooth softplus, ψ, the MLP builder, `_StateNet`.

Conventions shared by every network of this subpackage: states x have shape (N, n) (any leading
batch shape works), x* has shape (n,). The inner networks see the normalised, centred input
``u = (x - x*) / x_scale`` (x_scale: (n,), e.g. the half-widths of the training box; ones by
default). Every module takes its dtype and device from ``x_star``; all constants are registered
buffers, so ``state_dict`` round-trips through ``torch.save`` / ``torch.load(weights_only=True)``.
Only torch (and numpy for anchors given as arrays): no other subpackage is imported.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

__all__ = ["psi", "softplus"]


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

    @classmethod
    def apply(cls, x: Tensor) -> Tensor:
        """`autograd.Function.apply` without its argument binding where no functorch transform is
        active: with a `setup_context`, torch binds the arguments through `inspect.signature` at
        every call (a visible share of a fast-preset epoch), which a one-argument forward does not need."""
        if torch._C._are_functorch_transforms_active():
            return super().apply(x)
        return super(torch.autograd.Function, cls).apply(x)  # torch._C._FunctionBase.apply, bound to cls


def softplus(x: Tensor) -> Tensor:
    """Smooth softplus log(1 + eˣ), derivative sigmoid(x), for any x (see :class:`_Softplus`).

    Without autograd (inference) the same formula runs directly: the Python overhead of
    `autograd.Function.apply` would dominate the run-time controller.
    """
    if not (torch.is_grad_enabled() and x.requires_grad) and not torch._C._functorch.is_functorch_wrapped_tensor(x):
        return torch.relu(x) + torch.log1p(torch.exp(-x.abs()))
    return _Softplus.apply(x)


def psi(s: Tensor) -> Tensor:
    """ψ(s) = s - log(1 + s): convex, increasing on s ≥ 0, ψ(0) = ψ'(0) = 0, ψ''(0) = 1.

    Grows linearly for large s (ψ'(s) = s/(1+s) → 1), quadratically near 0 (ψ ≈ s²/2).
    """
    return s - torch.log1p(s)


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


class _Cached(nn.Module):
    """A module that keeps run-time caches of tensors in its ``__dict__`` (outside the state dict),
    named in ``_CACHES``. Moving or casting it (``.to``, ``.cpu``, ``.double``) drops them, since they
    hold tensors of the old device and dtype (a run trained on a GPU is simulated on the CPU), and a
    pickled copy (sent to a worker process, or `copy.deepcopy`) leaves them behind."""

    _CACHES: tuple[str, ...] = ()

    def _drop_caches(self) -> None:
        for name in self._CACHES:
            self.__dict__.pop(name, None)

    def _apply(self, fn, *args, **kwargs):
        self._drop_caches()
        return super()._apply(fn, *args, **kwargs)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in self._CACHES}


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
    """Holds x* (n,) and x_scale (n,); maps x to the inner input u = (x - x*)/x_scale.

    ``input_bound`` b > 0 clamps u to [−b, b] (b = 1: the training box when x_scale holds its
    half-widths), so the network keeps its boundary values outside instead of extrapolating.
    """

    def __init__(self, x_star: Tensor, x_scale: Tensor | None, input_bound: float | None = None):
        super().__init__()
        fk = _factory(x_star)
        n = x_star.shape[0]
        self.n = n
        self.register_buffer("x_star", x_star.detach().clone())
        scale = torch.ones(n, **fk) if x_scale is None else _as_buffer("x_scale", x_scale, x_star, (n,))
        if not (scale > 0).all():
            raise ValueError("x_scale must be positive")
        self.register_buffer("x_scale", scale)
        if input_bound is not None and not input_bound > 0:
            raise ValueError(f"input_bound must be > 0, got {input_bound}")
        self.register_buffer("input_bound", None if input_bound is None else torch.tensor(float(input_bound), **fk))

    def _u(self, x: Tensor) -> Tensor:
        if x.shape[-1] != self.n:
            raise ValueError(f"expected states with last dimension n={self.n}, got shape {tuple(x.shape)}")
        u = (x - self.x_star) / self.x_scale
        return u if self.input_bound is None else u.clamp(-self.input_bound, self.input_bound)
