"""A system is data: dimensions, actuation, target, training domain, effort limits and a plant.

`load_system` (in `loading.py`) builds one from a URDF, a zoo name, a built-in analytic name or an
example-robot-data robot. Every quantity is batched over a leading dimension N (a single state may
drop it) and computed in float64. Notation (paper eq. OLPH, DESIGN §2): x = (q, p) ∈ ℝⁿ, n = 2 nv,
ẋ = f(x) + g(x)u, g = [0; B], g⊥ = [[I, 0], [0, B⊥]], G = [gᵀ; g⊥].
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..errors import IdapbcError
from .joint import JointInfo
from .plant import Plant

__all__ = ["EQUILIBRIUM_TOL", "System"]

#: A target is an assignable equilibrium when every component of g⊥ f(x*) is below this (N·m or N).
EQUILIBRIUM_TOL = 1e-8


def _batch(a, width: int, what: str) -> tuple[np.ndarray, bool]:
    a = np.asarray(a, dtype=float)
    single = a.ndim == 1
    a = a[None] if single else a
    if a.ndim != 2 or a.shape[1] != width:
        raise ValueError(f"{what} must have shape (N, {width}) or ({width},), got {np.shape(a)}")
    return a, single


def _unbatch(a: np.ndarray, single: bool) -> np.ndarray:
    return a[0] if single else a


@dataclass(frozen=True, eq=False)
class System:
    """An input-affine system with x = (q, p), ready for Neural IDA-PBC.

    Attributes
    ----------
    name : short name (zoo name, built-in name or URDF stem).
    source : where it came from (path or name).
    joints : one `JointInfo` per minimal coordinate, in model order.
    actuated : names of the actuated coordinates, in the order of the input u.
    B : (nv, m) input matrix, columns of the identity picking the actuated joints.
    B_perp : (nv − m, nv) left annihilator of B (rows of the identity, unactuated joints).
    x_star : (n,) target state (q*, 0).
    domain : (lo, hi), each (n,): the training box X.
    plant : back-end (Pinocchio or closed form); not part of the public API.
    effort : (m,) actuator limits |u_i| ≤ effort_i of the actuated joints (N·m or N), in the order
        of u; +inf where a joint has none (URDF ``<limit effort>`` of 0 or absent, built-in systems).
    """

    name: str
    source: str
    joints: tuple[JointInfo, ...]
    actuated: tuple[str, ...]
    B: np.ndarray
    B_perp: np.ndarray
    x_star: np.ndarray
    domain: tuple[np.ndarray, np.ndarray]
    plant: Plant = field(repr=False)
    effort: np.ndarray | None = None

    def __post_init__(self):
        effort = np.full(self.B.shape[1], np.inf) if self.effort is None else np.asarray(self.effort, dtype=np.float64).reshape(-1)
        if effort.shape != (self.B.shape[1],) or np.any(~(effort > 0)):
            raise IdapbcError(f"effort limits need {self.B.shape[1]} positive values (inf for none), got {self.effort!r}.")
        effort.flags.writeable = False
        object.__setattr__(self, "effort", effort)

    @property
    def limited(self) -> bool:
        """True when at least one actuated joint has a finite effort limit."""
        return bool(np.isfinite(self.effort).any())

    def saturate(self, u) -> np.ndarray:
        """u clipped to ±effort per input: (N, m) -> (N, m) (unchanged where unlimited)."""
        return np.clip(np.asarray(u, dtype=np.float64), -self.effort, self.effort)

    # ------------------------------------------------------------------ dimensions and names
    @property
    def nq(self) -> int:
        """Number of minimal coordinates (one per 1-DoF joint)."""
        return len(self.joints)

    @property
    def nv(self) -> int:
        """Velocity dimension (= nq in minimal coordinates)."""
        return len(self.joints)

    @property
    def n(self) -> int:
        """State dimension 2 nq."""
        return 2 * len(self.joints)

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def coordinate_names(self) -> tuple[str, ...]:
        """Joint names, one per q coordinate."""
        return tuple(j.name for j in self.joints)

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the n state coordinates: joint names, then ``p_<joint>``."""
        return self.coordinate_names + tuple(f"p_{j.name}" for j in self.joints)

    @property
    def unactuated(self) -> tuple[str, ...]:
        """Names of the unactuated joints."""
        return tuple(name for name in self.coordinate_names if name not in self.actuated)

    @property
    def angle_mask(self) -> np.ndarray:
        """(n,) bool: True for angle coordinates (wrapped to (−π, π] when judging success)."""
        return np.array([j.is_angle for j in self.joints] + [False] * self.nq)

    @property
    def actuated_mask(self) -> np.ndarray:
        """(n,) bool: True on the momenta of actuated joints (rows the input reaches)."""
        return np.concatenate([np.zeros(self.nq, bool), self.B.sum(axis=1) > 0])

    # ------------------------------------------------------------------ state maps
    def split(self, x) -> tuple[np.ndarray, np.ndarray]:
        """x = (q, p) -> (q, v) with v = M(q)⁻¹p. Shapes (N, n) -> (N, nq), (N, nq)."""
        xb, single = _batch(x, self.n, "x")
        q, p = xb[:, : self.nq], xb[:, self.nq :]
        v = self.plant.velocity(q, p)
        return _unbatch(q.copy(), single), _unbatch(v, single)

    def state_from(self, q, v) -> np.ndarray:
        """(q, v) -> x = (q, M(q) v). Shapes (N, nq), (N, nq) -> (N, n)."""
        qb, single = _batch(q, self.nq, "q")
        vb, _ = _batch(v, self.nq, "v")
        return _unbatch(np.concatenate([qb, self.plant.momenta(qb, vb)], axis=1), single)

    # ------------------------------------------------------------------ energies
    def mass_matrix(self, q) -> np.ndarray:
        """M(q): (N, nq) -> (N, nq, nq), symmetric positive definite (kg, kg·m²)."""
        qb, single = _batch(q, self.nq, "q")
        return _unbatch(self.plant.mass_matrix(qb), single)

    def potential(self, q) -> np.ndarray:
        """U(q): (N, nq) -> (N,), joules (gravity 9.81 m/s² along −z for URDFs)."""
        qb, single = _batch(q, self.nq, "q")
        return _unbatch(self.plant.potential(qb), single)

    def hamiltonian(self, x) -> np.ndarray:
        """H(x) = ½ pᵀM(q)⁻¹p + U(q): (N, n) -> (N,), joules."""
        xb, single = _batch(x, self.n, "x")
        return _unbatch(self.plant.hamiltonian(xb[:, : self.nq], xb[:, self.nq :]), single)

    # ------------------------------------------------------------------ open loop (eq. OLPH)
    def f(self, x) -> np.ndarray:
        """Drift f(x) = (∂H/∂p, −∂H/∂q − D v): (N, n) -> (N, n)."""
        xb, single = _batch(x, self.n, "x")
        return _unbatch(self.plant.f(xb[:, : self.nq], xb[:, self.nq :]), single)

    def f_rows(self, x, rows) -> np.ndarray:
        """Rows `rows` (k,) of the drift, indices into x = (q, p): (N, n) -> (N, k); f(x)[:, rows] to
        rounding, cheaper where the plant skips terms that vanish on those rows (`Plant.f_rows`)."""
        xb, single = _batch(x, self.n, "x")
        return _unbatch(self.plant.f_rows(xb[:, : self.nq], xb[:, self.nq :], np.asarray(rows, dtype=int)), single)

    def f_and_df_dx(self, x) -> tuple[np.ndarray, np.ndarray]:
        """f(x) (N, n) and its Jacobian ∂f/∂x (N, n, n) in one pass (cheaper than both apart)."""
        xb, single = _batch(x, self.n, "x")
        f, J = self.plant.f_and_jacobian(xb[:, : self.nq], xb[:, self.nq :])
        return _unbatch(f, single), _unbatch(J, single)

    def df_dx(self, x) -> np.ndarray:
        """∂f/∂x: (N, n) -> (N, n, n)."""
        return self.f_and_df_dx(x)[1]

    def g(self, x) -> np.ndarray:
        """Input matrix g(x) = [0; B]: (N, n) -> (N, n, m) (constant for these systems)."""
        xb, single = _batch(x, self.n, "x")
        g = np.concatenate([np.zeros((self.nq, self.m)), self.B])
        return _unbatch(np.broadcast_to(g, (xb.shape[0],) + g.shape).copy(), single)

    def g_perp(self, x) -> np.ndarray:
        """Left annihilator g⊥ = [[I, 0], [0, B⊥]]: (N, n) -> (N, n − m, n), g⊥ g = 0."""
        xb, single = _batch(x, self.n, "x")
        nq = self.nq
        gp = np.zeros((self.n - self.m, self.n))
        gp[:nq, :nq] = np.eye(nq)
        gp[nq:, nq:] = self.B_perp
        return _unbatch(np.broadcast_to(gp, (xb.shape[0],) + gp.shape).copy(), single)

    def G(self, x) -> np.ndarray:
        """G(x) = [gᵀ; g⊥], square and invertible: (N, n) -> (N, n, n)."""
        return np.concatenate([np.swapaxes(self.g(x), -1, -2), self.g_perp(x)], axis=-2)

    def forward_dynamics(self, q, v, tau, threads: int = 1) -> np.ndarray:
        """Accelerations of the true plant (Pinocchio's ABA with joint damping, or the closed form).

        Shapes (N, nq) ×3 -> (N, nq); tau in N·m / N on every joint (use B u for inputs u);
        threads: Pinocchio threads for URDF plants (pooled ABA).
        """
        qb, single = _batch(q, self.nq, "q")
        vb, _ = _batch(v, self.nq, "v")
        tb, _ = _batch(tau, self.nq, "tau")
        return _unbatch(self.plant.forward_dynamics(qb, vb, tb, threads=threads), single)

    def momenta(self, q, v, threads: int = 1) -> np.ndarray:
        """p = M(q) v from the plant (pooled RNEA for URDF plants): (N, nq) ×2 -> (N, nq)."""
        qb, single = _batch(q, self.nq, "q")
        vb, _ = _batch(v, self.nq, "v")
        return _unbatch(self.plant.momenta(qb, vb, threads=threads), single)

    def with_plant(self, plant: Plant) -> "System":
        """The same system (actuation, target, domain, limits) with another plant as the truth."""
        return dataclasses.replace(self, plant=plant)

    def linearization(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, B_x) = (∂f/∂x(x*), g(x*)), shapes (n, n), (n, m): the linear model at the target."""
        return self.df_dx(self.x_star), self.g(self.x_star)

    def equilibrium_residual(self, x=None) -> np.ndarray:
        """g⊥ f(x) at x (default x*), shape (n − m,): zero iff x is an assignable equilibrium."""
        x = self.x_star if x is None else np.asarray(x, float)
        return self.g_perp(x) @ self.f(x)
