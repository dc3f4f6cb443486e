"""The Neural IDA-PBC control law u = (gᵀg)⁻¹gᵀ(f̃_d − f) (paper eq. tilde_u) as an object.

`IdaPbcNets` holds the three networks (H_d, J_d, R_d) and the constant input structure (g, g⊥,
G⁻¹) in torch; `Controller` wraps them with the `System` for numpy, float64 use at run time:

    ctrl(x) -> u (N, m);  ctrl.torque(q, v) -> τ (N, nv);  ctrl.with_damping(ρ) -> Controller
    ctrl.H_d(x), ctrl.J_d(x), ctrl.R_d(x), ctrl.f_d(x), ctrl.mismatch(x)

Desired closed loop (eq. CLPH): f̃_d = (J_d − R_d)∇H_d. Mismatch (eq. mismatch): μ = −g⊥(f − f̃_d);
the closed loop is ẋ = f̃_d + ξ with ξ = G⁻¹(0; μ) (Proposition 1). g is constant for every system
here (g = [0; B]), so gᵀg = BᵀB = I and u = gᵀ(f̃_d − f).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from ._runtime import DesiredFlow, snapshot
from ..config import TrainConfig
from .linear import fastest_pole, lqr_anchor
from .networks import DampingNet, EnergyNet, InterconnectionNet
from ..model.system import System

__all__ = ["Controller", "IdaPbcNets", "build_nets"]


class IdaPbcNets(nn.Module):
    """H_d, J_d, R_d and the system's constant input structure, in one torch module.

    Buffers: g (n, m), g_perp (n − m, n), G_inv (n, n), x_star (n,), and the decay rate λ.
    """

    def __init__(self, H: EnergyNet, J: InterconnectionNet, R: DampingNet, g, g_perp, decay_rate: float):
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

    @property
    def x_star(self) -> Tensor:
        return self.H.x_star

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


def _half_widths(system: System) -> np.ndarray:
    """s (n,): half-widths of the training box around x* (the larger side)."""
    lo, hi = system.domain
    return np.maximum(hi - system.x_star, system.x_star - lo)


#: ``scaling="auto"`` picks box units when the training box's half-widths span more than this ratio.
AUTO_BOX_RATIO = 20.0
#: ``anchor_q=0`` (automatic) tries these weights in turn and keeps the first whose anchor has no pole
#: faster than ``AUTO_MAX_POLE`` 1/s (|λ|·dt ≤ 0.5 for `simulate`'s 10 ms RK4 step).
AUTO_ANCHOR_Q = (10.0, 1.0, 0.1, 0.01)
AUTO_MAX_POLE = 50.0


def anchor_settings(system: System, config: TrainConfig) -> tuple[str, float]:
    """The resolved ``(scaling, anchor_q)`` of `config` for `system` (see `TrainConfig`'s "auto" values).

    Measured (the earlier 64 × 2, 600-epoch fast preset, 200 domain states): box units took the zoo
    cartpole (half-widths spanning 65×) from 9 % to 86.5 % success and cost the paper cartpole (2×)
    70 % → 54.5 %; the Furuta pendulum in box units reached 0 / 44.5 / 51 % with anchor_q = 10 / 1 /
    0.1 (fastest anchor pole 253 / 80 / 25 1/s).
    """
    scaling = config.scaling
    if scaling == "auto":
        half = _half_widths(system)
        scaling = "box" if half.max() > AUTO_BOX_RATIO * half.min() else "none"
    if config.anchor_q > 0:
        return scaling, float(config.anchor_q)
    for q in AUTO_ANCHOR_Q:
        if fastest_pole(_lqr_anchor(system, config, scaling, q).A_cl) <= AUTO_MAX_POLE:
            return scaling, q
    return scaling, AUTO_ANCHOR_Q[-1]


def _anchor(system: System, config: TrainConfig):
    return _lqr_anchor(system, config, *anchor_settings(system, config))


def _lqr_anchor(system: System, config: TrainConfig, scaling: str, anchor_q: float):
    A, Bx = system.linearization()
    half = _half_widths(system)
    box = scaling == "box"
    Q = anchor_q * (np.diag(1.0 / half**2) if box else np.eye(system.n))
    if config.anchor_p == "riccati":
        kw = dict(P_mode="riccati")
    else:
        kw = dict(P_mode="lyapunov", Q_lyap=np.diag(1.0 / half**2) if config.anchor_p == "box" else None)
    if not box:
        return lqr_anchor(A, Bx, Q=Q, scale="unit", **kw)
    P = lqr_anchor(A, Bx, Q=Q, scale=None, **kw).P  # λ_max(SPS) = 1: H_d ≈ ½zᵀ(SPS)z ≤ ½‖z‖² in box units
    return lqr_anchor(A, Bx, Q=Q, scale=1.0 / np.linalg.eigvalsh(half[:, None] * P * half[None, :]).max(), **kw)


def build_nets(system: System, config: TrainConfig) -> IdaPbcNets:
    """Fresh networks for `system` (weights from torch's current RNG state; seed it first)."""
    dtype = getattr(torch, config.dtype)
    device = torch.device(config.device)
    x_star = torch.as_tensor(system.x_star, dtype=dtype, device=device)
    half = _half_widths(system)
    x_scale = torch.as_tensor(half, dtype=dtype, device=device)
    actuated = torch.as_tensor(system.actuated_mask, device=device)
    kw = dict(width=config.width, depth=config.depth, x_scale=x_scale)
    scaling, anchor_q = anchor_settings(system, config)
    metric = dict(metric=x_scale if scaling == "box" else None)
    if config.form == "anchored":
        anchor = _lqr_anchor(system, config, scaling, anchor_q)
        W = half[:, None] * anchor.P if config.energy_input == "anchor" else None  # u = S P δ
        H = EnergyNet(x_star, P=anchor.P, eps=0.0, input_map=W, **kw)
        J = InterconnectionNet(x_star, J0=anchor.J, out_scale=0.1, **metric, **kw)
        R = DampingNet(x_star, R0=anchor.R, rho=config.rho, pattern=config.damping, actuated=actuated, out_scale=0.1, **metric, **kw)
        decay = config.decay_rate if config.decay_rate >= 0 else 0.5 * _local_rate(anchor)
    else:
        H = EnergyNet(x_star, eps=1e-3, **kw)
        J = InterconnectionNet(x_star, **metric, **kw)
        R = DampingNet(x_star, rho=config.rho, pattern=config.damping, actuated=actuated, **metric, **kw)
        decay = config.decay_rate if config.decay_rate >= 0 else 0.5
    return IdaPbcNets(H, J, R, system.g(system.x_star), system.g_perp(system.x_star), decay)


def _local_rate(anchor) -> float:
    """Decay rate of ½δᵀPδ along the LQR loop: min over δ of −(d/dt δᵀPδ)/(δᵀPδ)."""
    P, A_cl = anchor.P, anchor.A_cl
    Qp = -(A_cl.T @ P + P @ A_cl)
    L = np.linalg.cholesky(P)
    Li = np.linalg.inv(L)
    return float(np.linalg.eigvalsh(Li @ Qp @ Li.T).min())


#: `Controller.__call__` evaluates f̃_d in numpy (`flow`) for at most this many states and in torch
#: (`IdaPbcNets.desired_fast`) above: one state took 0.13 / 0.44 ms in numpy against 0.56 / 1.09 ms in
#: torch (width 64 × 2 / 300 × 3), while torch's matrix products win from about 32 states on (paper size).
RUNTIME_MAX_BATCH = 16


class Controller:
    """Neural IDA-PBC controller for a `System`, numpy float64 in and out, batched.

    Parameters
    ----------
    system : the plant (its f(x) enters the control law).
    nets : trained `IdaPbcNets`.
    """

    def __init__(self, system: System, nets: IdaPbcNets):
        self.system = system
        self.nets = nets.eval()
        self._dtype = nets.x_star.dtype
        self._device = nets.x_star.device
        self._g_pinv = self._np(nets.g_pinv)  # (gᵀg)⁻¹gᵀ, (m, n)
        self._flow = None
        self._params = list(nets.parameters())

    def _t(self, x) -> Tensor:
        return torch.as_tensor(np.asarray(x, dtype=np.float64), dtype=self._dtype, device=self._device)

    @staticmethod
    def _np(t: Tensor) -> np.ndarray:
        return t.detach().to("cpu", torch.float64).numpy()

    def _batch(self, x):
        x = np.asarray(x, dtype=np.float64)
        return (x[None], True) if x.ndim == 1 else (x, False)

    def __call__(self, x) -> np.ndarray:
        """u(x) = (gᵀg)⁻¹gᵀ(f̃_d(x) − f(x)): (N, n) -> (N, m) (N·m or N)."""
        xb, single = self._batch(x)
        f_d = self.flow()(xb) if len(xb) <= RUNTIME_MAX_BATCH else self._np(self.nets.desired_fast(self._t(xb)))
        u = (f_d - self.system.f(xb)) @ self._g_pinv.T  # float64 whatever the networks' dtype
        return u[0] if single else u

    def flow(self) -> DesiredFlow:
        """f̃_d as a numpy `DesiredFlow` of the current weights (retaken when a parameter changes).

        The run-time path of `__call__` and `torque` for up to `RUNTIME_MAX_BATCH` states: numpy on
        the CPU, 2.5–4.5× faster than torch for one state (`_runtime`), equal to `f_d` to rounding.
        """
        key = tuple((p._version, p.data_ptr()) for p in self._params)
        if self._flow is None or self._flow[0] != key:
            self._flow = (key, snapshot(self.nets))
        return self._flow[1]

    def torque(self, q, v) -> np.ndarray:
        """Joint torques τ = B u(x(q, v)) for measured (q, v): (N, nv) ×2 -> (N, nv)."""
        q = np.asarray(q, dtype=np.float64)
        single = q.ndim == 1
        x = self.system.state_from(np.atleast_2d(q), np.atleast_2d(v))
        tau = self(x) @ self.system.B.T
        return tau[0] if single else tau

    def _apply(self, fn, x) -> np.ndarray:
        """Evaluate a torch function of x on numpy states, batched, dropping N for a single state."""
        xb, single = self._batch(x)
        out = self._np(fn(self._t(xb)))
        return out[0] if single else out

    def H_d(self, x) -> np.ndarray:
        """Desired energy H_d(x): (N, n) -> (N,)."""
        return self._apply(torch.no_grad()(self.nets.H), x)

    def grad_H_d(self, x) -> np.ndarray:
        """∇H_d(x): (N, n) -> (N, n)."""
        return self._apply(self.nets.H.grad, x)

    def J_d(self, x) -> np.ndarray:
        """Desired interconnection J_d(x) (skew): (N, n) -> (N, n, n)."""
        return self._apply(torch.no_grad()(self.nets.J), x)

    def R_d(self, x) -> np.ndarray:
        """Desired damping R_d(x) (positive definite): (N, n) -> (N, n, n)."""
        return self._apply(torch.no_grad()(self.nets.R), x)

    def f_d(self, x) -> np.ndarray:
        """f̃_d(x) = (J_d − R_d)∇H_d: (N, n) -> (N, n)."""
        return self._apply(lambda t: self.nets.desired(t)[4], x)

    def mismatch(self, x) -> np.ndarray:
        """μ(x) = −g⊥(f − f̃_d): (N, n) -> (N, n − m)."""
        xb, single = self._batch(x)
        out = self.system.g_perp(xb) @ (self.f_d(xb) - self.system.f(xb))[..., None]
        return out[0, :, 0] if single else out[..., 0]

    def with_damping(self, rho: float) -> "Controller":
        """Same networks, R_d = L Lᵀ + ρS with a new ρ ("extra damping", paper Fig. ii)."""
        nets = IdaPbcNets.__new__(IdaPbcNets)
        nn.Module.__init__(nets)
        nets.H, nets.J, nets.R = self.nets.H, self.nets.J, self.nets.R.with_rho(rho)
        for name, buf in self.nets.named_buffers(recurse=False):
            nets.register_buffer(name, buf)
        return Controller(self.system, nets)

    @property
    def rho(self) -> float:
        return float(self.nets.R.rho)

    def closed_loop_jacobian(self, x=None) -> np.ndarray:
        """∂/∂x of the true closed loop f + g u at x (default x*): (n, n).

        With u = gᵀ(f̃_d − f) and gᵀg = I: ẋ = (I − ggᵀ)f + ggᵀf̃_d.
        """
        x = self.system.x_star if x is None else np.asarray(x, dtype=np.float64)
        A = self.system.df_dx(x)
        xt = self._t(x)
        Jfd = torch.autograd.functional.jacobian(lambda z: self.nets.desired(z[None], create_graph=True)[4][0], xt)
        g = self.system.g(x)
        Pg = g @ np.linalg.solve(g.T @ g, g.T)
        return (np.eye(len(x)) - Pg) @ A + Pg @ self._np(Jfd)

    def eigenvalues_at_target(self) -> np.ndarray:
        """Eigenvalues of the closed-loop Jacobian at x*; all Re < 0 ⇔ x* locally exponentially stable."""
        return np.linalg.eigvals(self.closed_loop_jacobian())
