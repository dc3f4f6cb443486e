"""The three networks of the desired closed loop ẋ = (J_d(x) − R_d(x))∇H_d(x) (paper §IV-A, eq.
CLPH) in one torch module, `IdaPbcNets`, and `build_nets`, which makes fresh ones for a system.

Each network has its structure *by construction*, for every value of the weights (the structural
conditions (i)–(iii) of the paper's Proposition 3, label ``prop:vanishing_mu``):

* `interconnection.InterconnectionNet` — J_d(x) = skew(NN_J(u)) ∈ 𝔰𝔬(n): J_d + J_dᵀ = 0.
* `damping.DampingNet` — R_d(x) = L(x)L(x)ᵀ + ρS with L lower triangular with a positive diagonal:
  R_d ≻ 0 (DESIGN §2; the paper's sym(NN) + ρI is not PD for all weights).
* `energy.EnergyNet` — H_d from an input-convex network (`icnn.ICNN`, Amos et al. 2017) shaped so
  that H_d(x*) = 0, ∇H_d(x*) = 0, H_d > 0 elsewhere and ∇²H_d ≻ 0, exactly.

Two forms of each (chosen by ``TrainConfig.form``, i.e. by passing anchors or not):

* free form (the paper's, with the exact Bregman shift for H_d);
* anchored form (DESIGN §2 "Local exactness: an LQR anchor"): given (P, J0, R0) from
  `anchor.system_anchor`, ∇²H_d(x*) = P, J_d(x*) = J0, R_d(x*) = R0 (ρ = 0), so the closed-loop
  Jacobian at x* is (J0 − R0)P = A − BK, the LQR loop, for any weights.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from ..config import TrainConfig
from ..model import System
from ..model.angles import wrap_angles
from .anchor import anchor_settings, half_widths, local_rate, system_anchor
from .damping import DampingNet
from .energy import EnergyNet
from .interconnection import InterconnectionNet
from .layers import _Cached

__all__ = ["IdaPbcNets", "build_nets"]


class IdaPbcNets(_Cached):
    """H_d, J_d, R_d and the system's constant input structure, in one torch module.

    Buffers: g (n, m), g_perp (n − m, n), G_inv (n, n), x_star (n,), the decay rate λ, and
    ``angle_mask`` (n,) bool, True on the angles the control law wraps (`wrap`), or None.
    """

    _CACHES = ("_cache", "_cache_key", "_params")  # the networks' values at x* (`desired_fast`)

    def __init__(self, H: EnergyNet, J: InterconnectionNet, R: DampingNet, g, g_perp, decay_rate: float, angle_mask=None):
        super().__init__()
        self.H, self.J, self.R = H, J, R
        like = H.x_star
        as_t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=like.dtype, device=like.device)  # noqa: E731
        G = np.concatenate([np.asarray(g).T, np.asarray(g_perp)])
        self.register_buffer("g", as_t(g))
        self.register_buffer("g_perp", as_t(g_perp))
        self.register_buffer("G_inv", as_t(np.linalg.inv(G)))
        g = np.asarray(g, dtype=np.float64)
        self.register_buffer("g_pinv", as_t(np.linalg.solve(g.T @ g, g.T)), persistent=False)  # (gᵀg)⁻¹gᵀ
        self.register_buffer("decay_rate", torch.tensor(float(decay_rate), dtype=like.dtype, device=like.device))
        mask = None if angle_mask is None or not np.any(angle_mask) else torch.as_tensor(np.asarray(angle_mask, bool), device=like.device)
        self.register_buffer("angle_mask", mask)

    @property
    def x_star(self) -> Tensor:
        return self.H.x_star

    def wrap(self, x: np.ndarray) -> np.ndarray:
        """x* + wrap(x − x*): (N, n) -> (N, n) float64, the angles brought to within π of the target.

        The control law's input (`Controller`): f is 2π-periodic in every angle, the networks are
        not, and were trained on the box around x*. Identity when ``angle_mask`` is None.
        """
        x = np.asarray(x, dtype=np.float64)
        if self.angle_mask is None:
            return x
        if "_wrap_np" not in self.__dict__:  # once: this runs every control period. Copies, not views of
            # the buffers: sending the nets to a worker process moves their storage (torch.multiprocessing)
            self._wrap_np = (self.x_star.detach().to("cpu", torch.float64).numpy().copy(), self.angle_mask.cpu().numpy().copy())
        x_star, mask = self._wrap_np
        return x_star + wrap_angles(x - x_star, mask)

    @property
    def m(self) -> int:
        return self.g.shape[1]

    def desired(self, x: Tensor, create_graph: bool = False) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """H_d (N,), ∇H_d (N, n), J_d (N, n, n), R_d (N, n, n), f̃_d = (J_d − R_d)∇H_d (N, n)."""
        H, dH = self.H.value_and_grad(x, create_graph=create_graph)
        J, R = self.J(x), self.R(x)
        f_d = ((J - R) @ dH.unsqueeze(-1)).squeeze(-1)
        return H, dH, J, R, f_d

    @torch.no_grad()
    def desired_fast(self, x: Tensor) -> Tensor:
        """f̃_d(x) (N, n) with no autograd (explicit ∇H_d): the run-time path.

        The networks' values at x* are cached while the weights are unchanged (keyed on the
        parameters' version counters), so a control step runs each network once.
        """
        params = self.__dict__.get("_params") or self.__dict__.setdefault("_params", list(self.parameters()))
        key = tuple(p._version for p in params)
        if getattr(self, "_cache_key", None) != key:
            zero = torch.zeros_like(self.x_star)
            self._cache = (
                self.H.icnn.value_and_grad(zero),
                self.J.net(zero) if self.J.J0 is not None else None,
                self.R.net(zero) if self.R.L0 is not None else None,
            )
            self._cache_key = key
        at_h, v0, out0 = self._cache
        _, dH = self.H.value_and_grad_explicit(x, at_h)
        L = self.R.cholesky_factor(x, out0)
        R = L @ L.transpose(-1, -2) + self.R.rho * self.R.S
        return ((self.J(x, v0) - R) @ dH.unsqueeze(-1)).squeeze(-1)

    def control(self, f: Tensor, f_d: Tensor) -> Tensor:
        """u = (gᵀg)⁻¹gᵀ(f̃_d − f) with constant g: (N, n), (N, n) -> (N, m)."""
        return (f_d - f) @ self.g_pinv.T

    def mismatch(self, f: Tensor, f_d: Tensor) -> Tensor:
        """μ = −g⊥(f − f̃_d): (N, n − m)."""
        return (f_d - f) @ self.g_perp.T

    def xi(self, mu: Tensor) -> Tensor:
        """ξ = −G⁻¹(0; μ): (N, n − m) -> (N, n), so that the true closed loop is ẋ = f̃_d + ξ.

        Sign: with μ = −g⊥(f − f̃_d) (eq. mismatch), g⊥ẋ = g⊥f = g⊥f̃_d − μ, hence ξ = −G⁻¹(0; μ).
        The paper's proof of Proposition 1 writes +G⁻¹(0; μ); only ‖ξ‖ enters f_sd1, but Ḣ_d and the
        dissipation inequality need the sign that matches the plant (checked in tests).
        """
        return -mu @ self.G_inv[:, self.m :].T


def build_nets(system: System, config: TrainConfig) -> IdaPbcNets:
    """Fresh networks for `system` on ``config.device`` (weights from torch's current CPU RNG state;
    seed it first). They are drawn on the CPU and then moved, so a seed gives the same initial
    networks on a GPU as on the CPU (a GPU's own generator would draw other weights)."""
    dtype = getattr(torch, config.dtype)
    device = torch.device("cpu")
    x_star = torch.as_tensor(system.x_star, dtype=dtype, device=device)
    half = half_widths(system)
    x_scale = torch.as_tensor(half, dtype=dtype, device=device)
    actuated = torch.as_tensor(system.actuated_mask, device=device)
    kw = dict(width=config.width, depth=config.depth, x_scale=x_scale)
    scaling, anchor_q = anchor_settings(system, config)
    metric = dict(metric=x_scale if scaling == "box" else None, input_bound=1.0 if config.bounded_structure else None)
    if config.form == "anchored":
        anchor = system_anchor(system, config, (scaling, anchor_q))
        W = half[:, None] * anchor.P if config.energy_input == "anchor" else None  # u = S P δ
        H = EnergyNet(x_star, P=anchor.P, eps=0.0, input_map=W, **kw)
        J = InterconnectionNet(x_star, J0=anchor.J, out_scale=0.1, **metric, **kw)
        R = DampingNet(x_star, R0=anchor.R, rho=config.rho, pattern=config.damping, actuated=actuated, out_scale=0.1, **metric, **kw)
        decay = config.decay_rate if config.decay_rate >= 0 else 0.5 * local_rate(anchor)
    else:
        H = EnergyNet(x_star, eps=1e-3, **kw)
        J = InterconnectionNet(x_star, **metric, **kw)
        R = DampingNet(x_star, rho=config.rho, pattern=config.damping, actuated=actuated, **metric, **kw)
        decay = config.decay_rate if config.decay_rate >= 0 else 0.5
    wrap = system.angle_mask if config.wrap_angles else None
    return IdaPbcNets(H, J, R, system.g(system.x_star), system.g_perp(system.x_star), decay, wrap).to(torch.device(config.device))
