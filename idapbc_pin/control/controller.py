"""The Neural IDA-PBC control law u = (gᵀg)⁻¹gᵀ(f̃_d − f) (paper eq. tilde_u) as an object.

`Controller` wraps trained `nets.IdaPbcNets` (H_d, J_d, R_d and the constant input structure g, g⊥,
G⁻¹, in torch) with the `System` for numpy, float64 use at run time:

    ctrl(x) -> u (N, m);  ctrl.torque(q, v) -> τ (N, nv);  ctrl.with_damping(ρ) -> Controller
    ctrl.H_d(x), ctrl.J_d(x), ctrl.R_d(x), ctrl.f_d(x), ctrl.mismatch(x)
    ctrl.fallback: the outer law used where the networks' does not act (`OuterLaw`), or None

Desired closed loop (eq. CLPH): f̃_d = (J_d − R_d)∇H_d. Mismatch (eq. mismatch): μ = −g⊥(f − f̃_d);
the closed loop is ẋ = f̃_d + ξ with ξ = G⁻¹(0; μ) (Proposition 1). g is constant for every system
here (g = [0; B]), so gᵀg = BᵀB = I and u = gᵀ(f̃_d − f). Angles are wrapped to within π of the
target before the law is evaluated (`IdaPbcNets.wrap`), as the LQR baseline does.
"""

from __future__ import annotations

import copy
from typing import Callable, Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor, nn

from ..model import System
from ._runtime import snapshot
from .desired_flow import DesiredFlow
from .nets import IdaPbcNets
from .rail_guard import RailGuard
from .speed_governor import ENERGY_MARGIN, SpeedGovernor

__all__ = ["Controller", "OuterLaw"]


@runtime_checkable
class OuterLaw(Protocol):
    """What the controller knows of a law that replaces the networks' input where they do not act.

    ``apply(x, u, energy)`` takes states x (N, n), the networks' inputs u (N, m) in N or N·m and a
    callable ``energy(x) -> H_d(x)`` (N,), and returns the inputs to apply (N, m). The run's outer
    laws (the linear law outside the training box, a recovery law) live in `idapbc_pin.recovery`.
    An optional ``gain_at_target`` (float) scales the networks' part of the loop's linearisation at x*.
    An optional ``reads_networks(x) -> (N,) bool`` names the rows of x whose networks' input ``apply``
    reads: the controller computes the networks on those rows alone (NaN in the others).
    """

    def apply(self, x: np.ndarray, u: np.ndarray, energy: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray: ...


#: `Controller.__call__` evaluates f̃_d in numpy (`flow`) for every batch when the networks sit on the CPU
#: (with one thread numpy is the faster of the two at every batch size, `benchmarks/bench_controller.py`),
#: and for at most this many states when they sit on a GPU, where a batch pays the device round trip but
#: large products are cheap: larger batches run in torch there (`IdaPbcNets.desired_fast`).
RUNTIME_GPU_MAX_BATCH = 16


class Controller:
    """Neural IDA-PBC controller for a `System`, numpy float64 in and out, batched.

    Parameters
    ----------
    system : the plant (its f(x) enters the control law).
    nets : trained `IdaPbcNets`.
    fallback : the `OuterLaw` that replaces the learned one where it does not act, through its
        ``apply(x, u, energy)``; a run's own comes from
        `Run.controller`. None: the learned law everywhere.
    guard : brake a cart wherever it could no longer stop before its rail's end (`RailGuard`, after
        every other law; only where the system has such a rail). False: the laws alone.
    governor : take energy out wherever the robot holds clearly more than the upright needs or a motor
        runs near its rating (`SpeedGovernor`, after the outer laws, before the rail guard; only where
        every input has a finite effort limit). False: the laws alone.
    governor_margin : where the governor's energy clause starts, in ΔE above E* (a run's own:
        `Run.governor_margin`).
    """

    def __init__(self, system: System, nets: IdaPbcNets, fallback: OuterLaw | None = None, guard: bool = True, governor: bool = True,
                 governor_margin: float = ENERGY_MARGIN):
        self.system = system
        self.nets = nets.eval()
        self.fallback = fallback
        self.guard = RailGuard.of(system) if guard else None
        self.governor = SpeedGovernor.of(system, governor_margin) if governor else None
        self.governor_margin = float(governor_margin)
        self._dtype = nets.x_star.dtype
        self._device = nets.x_star.device
        self._g_pinv = self._np(nets.g_pinv)  # (gᵀg)⁻¹gᵀ, (m, n)
        self._rows = np.flatnonzero(np.any(self._g_pinv != 0, axis=0))  # the rows of f̃_d − f that u reads
        self._flow = None
        self._params = list(nets.parameters())

    def _t(self, x) -> Tensor:
        return torch.as_tensor(np.asarray(x, dtype=np.float64), dtype=self._dtype, device=self._device)

    @staticmethod
    def _np(t: Tensor) -> np.ndarray:
        """A float64 numpy copy of `t`, never a view of its storage: a tensor sent to a worker process
        moves to shared memory (torch.multiprocessing), and a view kept here (`_g_pinv`) would dangle."""
        return t.detach().to("cpu", torch.float64).numpy().copy()

    def _batch(self, x):
        x = np.asarray(x, dtype=np.float64)
        return (x[None], True) if x.ndim == 1 else (x, False)

    def __call__(self, x) -> np.ndarray:
        """u(x) = (gᵀg)⁻¹gᵀ(f̃_d(x) − f(x)): (N, n) -> (N, m) (N·m or N).

        The law is evaluated at x* + wrap(x − x*) when the networks wrap angles (`IdaPbcNets.wrap`,
        `TrainConfig.wrap_angles`): a state one turn away from x* gets the torque of x*'s neighbour.
        With a `fallback`, the states it covers (outside the training box, or outside a recovery
        law's inner box) get its law instead; then the `governor` takes energy out where the robot
        holds too much or runs near a motor's rating, and the `guard` brakes a cart near its rail's end.
        """
        xb, single = self._batch(x)
        xb = self.nets.wrap(xb)
        reads = getattr(self.fallback, "reads_networks", None)
        mask = None if reads is None else np.asarray(reads(xb), dtype=bool)
        if mask is None or mask.all():
            u = self._networks(xb)
        else:  # the outer law takes the other rows whatever the networks say there
            u = np.full((len(xb), self.system.m), np.nan)
            if mask.any():
                u[mask] = self._networks(xb[mask])
        if self.fallback is not None:  # a recovery law with a level reads H_d on the rows it may take
            u = self.fallback.apply(xb, u, energy=lambda x: self.flow().energy(x))
        if self.governor is not None:
            u = self.governor.apply(xb, u)
        if self.guard is not None:  # wrapping leaves a cart's position as it is
            u = self.guard.apply(xb, u)
        return u[0] if single else u

    def _networks(self, xb: np.ndarray) -> np.ndarray:
        """The networks' law (gᵀg)⁻¹gᵀ(f̃_d − f) at wrapped states xb (N, n) -> (N, m), before any outer law."""
        numpy = self._device.type == "cpu" or len(xb) <= RUNTIME_GPU_MAX_BATCH
        f_d = self.flow()(xb) if numpy else self._np(self.nets.desired_fast(self._t(xb)))
        rows = self._rows  # only the input rows of f (`System.f_rows`); float64 whatever the networks' dtype
        return (f_d[:, rows] - self.system.f_rows(xb, rows)) @ self._g_pinv[:, rows].T

    def flow(self) -> DesiredFlow:
        """f̃_d as a numpy `DesiredFlow` of the current weights (retaken when a parameter changes).

        The run-time path of `__call__` and `torque` (every batch on the CPU, up to
        `RUNTIME_GPU_MAX_BATCH` states from a GPU): several times faster than torch for one state
        (`_runtime`), equal to `f_d` to rounding.
        """
        key = tuple((p._version, p.data_ptr()) for p in self._params)
        if self._flow is None or self._flow[0] != key:
            self._flow = (key, snapshot(self.nets))
        return self._flow[1]

    def torque(self, q, v, limits: bool = True) -> np.ndarray:
        """Joint torques τ = B sat(u(x(q, v))) for measured (q, v): (N, nv) ×2 -> (N, nv), N·m or N.

        limits : clip u to the actuators' effort limits (``system.effort``), as the robot would;
            False gives the raw law B u.
        """
        q = np.asarray(q, dtype=np.float64)
        single = q.ndim == 1
        x = self.system.state_from(np.atleast_2d(q), np.atleast_2d(v))
        u = self(x)
        tau = (self.system.saturate(u) if limits else u) @ self.system.B.T
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
        for name, buf in self.nets._buffers.items():  # None buffers too (angle_mask)
            nets.register_buffer(name, buf, persistent=name not in self.nets._non_persistent_buffers_set)
        return self._variant(nets=nets)

    def _variant(self, **changes) -> "Controller":
        """This controller with `changes` (nets, fallback, guard, governor) in place of its own."""
        own = dict(nets=self.nets, fallback=self.fallback, guard=self.guard is not None, governor=self.governor is not None, governor_margin=self.governor_margin)
        return Controller(self.system, **(own | changes))

    def with_fallback(self, fallback: OuterLaw | None) -> "Controller":
        """Same networks, another law where they do not act (None: the learned law everywhere)."""
        return self._variant(fallback=fallback)

    def with_guard(self, guard: bool) -> "Controller":
        """Same laws, with or without the rail guard (`RailGuard`)."""
        return self._variant(guard=guard)

    def with_governor(self, governor: bool) -> "Controller":
        """Same laws, with or without the speed and energy governor (`SpeedGovernor`)."""
        return self._variant(governor=governor)

    def in_float64(self) -> "Controller":
        """Same laws on the same weights, evaluated in float64 (every float32 weight is exactly a
        float64 one): the arithmetic in which conditions (i)–(iii) are checked, since float32 rounds
        a damping R_d of wide condition number into an indefinite one. Itself where already float64."""
        if self._dtype == torch.float64:
            return self
        nets = copy.deepcopy(self.nets).to(torch.float64)
        return self._variant(nets=nets)

    @property
    def rho(self) -> float:
        return float(self.nets.R.rho)

    def closed_loop_jacobian(self, x=None) -> np.ndarray:
        """∂/∂x of the true closed loop f + g u at x (default x*): (n, n).

        With u = gᵀ(f̃_d − f) and gᵀg = I: ẋ = (I − ggᵀ)f + ggᵀf̃_d. An outer law that scales
        the networks' u − u* by k_in at x* (its ``gain_at_target``, 1 when it has none) gives
        ∂ẋ/∂x = A + k_in ggᵀ(∂f̃_d/∂x − A).
        """
        x = self.system.x_star if x is None else np.asarray(x, dtype=np.float64)
        A = self.system.df_dx(x)
        xt = self._t(x)
        Jfd = torch.autograd.functional.jacobian(lambda z: self.nets.desired(z[None], create_graph=True)[4][0], xt)
        g = self.system.g(x)
        Pg = g @ np.linalg.solve(g.T @ g, g.T)
        k_in = getattr(self.fallback, "gain_at_target", 1.0)
        return A + k_in * Pg @ (self._np(Jfd) - A)

    def eigenvalues_at_target(self) -> np.ndarray:
        """Eigenvalues of the closed-loop Jacobian at x*; all Re < 0 ⇔ x* locally exponentially stable."""
        return np.linalg.eigvals(self.closed_loop_jacobian())
