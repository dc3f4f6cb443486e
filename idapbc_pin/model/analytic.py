"""The paper's benchmark systems (§V), exactly as written there, as plants with closed-form derivatives.

* ``paper_double_pendulum``: fully actuated, m₁ = m₂ = l₁ = l₂ = 1, x* = 0 (upright),
  M(q) = [[(m₁+m₂)l₁², ½m₂l₁l₂cos(q₁−q₂)], [·, m₂l₂²]],
  U(q) = m₂g(l₁(1+cos q₁) + l₂(1+cos q₂)) + m₁gl₁(1+cos q₁).
* ``paper_cartpole``: force on the cart, m₁ = m₂ = l₂ = 1, x* = 0,
  M(q) = [[m₁+m₂, ½m₂l₂cos q₂], [·, m₂l₂²]], U(q) = m₂gl₂(1+cos q₂).
* ``paper_mass_spring_damper``: general input-affine (not port-Hamiltonian) form
  ẋ = A(x)x + (0, 1)ᵀu with A = [[0, 1], [−(k+0.5q²)/m, −bp(1+|p|)/m]], m = k = 1, b = 0.5,
  x* = (0.5, 0).

These M are not physically consistent rigid bodies (the ½ factors); the URDF zoo holds physical
robots. g = 9.81 m/s². Both mechanical benchmarks belong to one family, M(q) = diag(d) +
k cos(aᵀq)(E₁₂ + E₂₁) and U(q) = Σᵢ cᵢ(1 + cos qᵢ), whose derivatives are written in closed form
below; tests hold them against autograd of the formulas.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from ._mechanics import mechanical_f, mechanical_jacobian
from ..errors import IdapbcError
from .joint import JointInfo

__all__ = ["ANALYTIC", "AnalyticSpec", "CosCoupledPlant", "MassSpringDamperPlant", "analytic_names"]

GRAVITY = 9.81


def _joint(name: str, kind: str = "analytic-angle") -> JointInfo:
    return JointInfo(name=name, kind=kind, axis=(0.0, 0.0, 0.0), lower=-math.inf, upper=math.inf, damping=0.0, mass=math.nan)


class CosCoupledPlant:
    """Two-coordinate mechanical plant M(q) = diag(d) + k cos(aᵀq)(E₁₂+E₂₁), U = Σ cᵢ(1 + cos qᵢ).

    Same back-end interface as `PinocchioPlant`; q (N, 2), p (N, 2). No damping (paper: R = 0).
    """

    nv = nq_config = 2

    def __init__(self, joints, diag, k, a, c):
        self.joints = tuple(joints)
        self.diag = np.asarray(diag, float)
        self.k = float(k)
        self.a = np.asarray(a, float)
        self.c = np.asarray(c, float)
        self.damping = np.zeros(2)

    def _off(self, q):
        s = q @ self.a
        return self.k * np.cos(s), -self.k * np.sin(s), -self.k * np.cos(s)  # value, d/ds, d²/ds²

    def mass_matrix(self, q):
        off, _, _ = self._off(q)
        M = np.zeros((q.shape[0], 2, 2))
        M[:, 0, 0], M[:, 1, 1] = self.diag
        M[:, 0, 1] = M[:, 1, 0] = off
        return M

    def potential(self, q):
        return (self.c * (1.0 + np.cos(q))).sum(axis=1)

    def gravity(self, q):
        return -self.c * np.sin(q)

    def hamiltonian(self, q, p):
        v = self.velocity(q, p)
        return 0.5 * np.einsum("ni,ni->n", p, v) + self.potential(q)

    def velocity(self, q, p):
        return np.linalg.solve(self.mass_matrix(q), p[..., None])[..., 0]

    def _W(self, q, v):
        # W[:, :, j] = (∂M/∂q_j) v ; ∂M/∂q_j = d_off·a_j (E12+E21)
        _, d1, _ = self._off(q)
        Ev = v[:, ::-1]  # (E12+E21) v
        return (d1[:, None, None] * Ev[:, :, None]) * self.a[None, None, :]

    def f(self, q, p):
        v = self.velocity(q, p)
        return mechanical_f(v, self._W(q, v), self.gravity(q), self.damping)

    def f_rows(self, q, p, rows):
        return self.f(q, p)[:, rows]

    def f_and_jacobian(self, q, p):
        M = self.mass_matrix(q)
        M_inv = np.linalg.inv(M)
        v = np.einsum("nij,nj->ni", M_inv, p)
        W = self._W(q, v)
        _, _, d2 = self._off(q)
        vEv = 2.0 * v[:, 0] * v[:, 1]
        Phi = (d2 * vEv)[:, None, None] * np.outer(self.a, self.a)[None]
        hess_U = np.zeros_like(M)
        hess_U[:, 0, 0], hess_U[:, 1, 1] = (-self.c * np.cos(q)).T
        return mechanical_f(v, W, self.gravity(q), self.damping), mechanical_jacobian(M_inv, v, W, Phi, hess_U, self.damping)

    def momenta(self, q, v, threads: int = 1):
        """p = M(q) v (threads: unused, the protocol's signature)."""
        return np.einsum("nij,nj->ni", self.mass_matrix(q), v)

    def scaled(self, mass: float = 1.0, length: float = 1.0, damping: float = 1.0) -> "CosCoupledPlant":
        """Masses × mass, lengths × length (inertia terms × length², couplings × length per angle),
        damping × damping (an error: the paper's benchmarks have none)."""
        if damping != 1.0 and not np.any(self.damping != 0):
            raise IdapbcError("the plant has no damping to scale (the paper's mechanical benchmarks have R = 0). Fix: drop damping=....")
        new = copy.copy(self)
        a = np.array([1.0 if j.is_angle else 0.0 for j in self.joints])  # length exponent / 2 of each coordinate
        new.diag = self.diag * mass * length ** (2 * a)
        new.k = self.k * mass * length ** (a[0] + a[1])
        new.c = self.c * mass * length
        new.damping = self.damping * damping
        return new

    def forward_dynamics(self, q, v, tau, threads: int = 1):
        """Lagrange: M a = τ − D v − W v + ½ Wᵀ v − ∇U."""
        W = self._W(q, v)
        rhs = tau - self.damping * v - np.einsum("nij,nj->ni", W, v) + 0.5 * np.einsum("nkj,nk->nj", W, v) - self.gravity(q)
        return np.linalg.solve(self.mass_matrix(q), rhs[..., None])[..., 0]


class MassSpringDamperPlant:
    """The paper's nonlinear mass-spring-damper, ẋ = A(x)x + (0, 1)ᵀu, x = (q, p).

    In the paper's form q̇ = p, so p is the velocity and `mass_matrix` is 1 for this state; the
    `hamiltonian` ½p² + ½kq² + q⁴/8 is informational (the system is not written port-Hamiltonian).
    """

    nv = nq_config = 1

    def __init__(self, m=1.0, k=1.0, b=0.5):
        self.m, self.k, self.b = float(m), float(k), float(b)
        self.joints = (_joint("q", kind="analytic-linear"),)
        self.damping = np.zeros(1)

    def mass_matrix(self, q):
        return np.ones((q.shape[0], 1, 1))

    def potential(self, q):
        return (0.5 * self.k * q**2 + q**4 / 8.0)[:, 0]

    def hamiltonian(self, q, p):
        return 0.5 * p[:, 0] ** 2 + self.potential(q)

    def velocity(self, q, p):
        return p.copy()

    def _accel(self, q, p):
        return (-(self.k + 0.5 * q**2) * q - self.b * p * (1.0 + np.abs(p)) * p) / self.m

    def f(self, q, p):
        return np.concatenate([p, self._accel(q, p)], axis=1)

    def f_rows(self, q, p, rows):
        return self.f(q, p)[:, rows]

    def f_and_jacobian(self, q, p):
        J = np.zeros((q.shape[0], 2, 2))
        J[:, 0, 1] = 1.0
        J[:, 1, 0] = (-(self.k + 1.5 * q[:, 0] ** 2)) / self.m
        J[:, 1, 1] = -self.b * (2.0 * p[:, 0] + 3.0 * p[:, 0] * np.abs(p[:, 0])) / self.m
        return self.f(q, p), J

    def momenta(self, q, v, threads: int = 1):
        """p = v (the paper writes this system with q̇ = p)."""
        return np.array(v, dtype=float)

    def scaled(self, mass: float = 1.0, length: float = 1.0, damping: float = 1.0) -> "MassSpringDamperPlant":
        """Mass × mass, damping b × damping; there is no length to scale."""
        if length != 1.0:
            raise IdapbcError("the mass-spring-damper has no length to scale. Fix: use mass=... or damping=....")
        return MassSpringDamperPlant(m=self.m * mass, k=self.k, b=self.b * damping)

    def forward_dynamics(self, q, v, tau, threads: int = 1):
        return self._accel(q, v) + tau


@dataclass(frozen=True)
class AnalyticSpec:
    """A built-in analytic system: how to build its plant, its actuated coordinates and target."""

    name: str
    description: str
    build: object  # () -> plant
    actuated: tuple[str, ...]
    target: tuple[tuple[str, float], ...] = ()
    domain: tuple[tuple[str, float, float], ...] = ()


def _paper_double_pendulum(m1=1.0, m2=1.0, l1=1.0, l2=1.0):
    return CosCoupledPlant(
        (_joint("q1"), _joint("q2")),
        diag=((m1 + m2) * l1**2, m2 * l2**2),
        k=0.5 * m2 * l1 * l2,
        a=(1.0, -1.0),
        c=((m1 + m2) * GRAVITY * l1, m2 * GRAVITY * l2),
    )


def _paper_cartpole(m1=1.0, m2=1.0, l2=1.0):
    return CosCoupledPlant(
        (_joint("q1", kind="analytic-linear"), _joint("q2")),
        diag=(m1 + m2, m2 * l2**2),
        k=0.5 * m2 * l2,
        a=(0.0, 1.0),
        c=(0.0, m2 * GRAVITY * l2),
    )


ANALYTIC: dict[str, AnalyticSpec] = {
    spec.name: spec
    for spec in sorted(
        [
            AnalyticSpec("paper_cartpole", "paper §V cartpole (force on the cart)", _paper_cartpole, ("q1",)),
            AnalyticSpec("paper_double_pendulum", "paper §V fully actuated double pendulum", _paper_double_pendulum, ("q1", "q2")),
            AnalyticSpec(
                "paper_mass_spring_damper",
                "paper §V nonlinear mass-spring-damper, general input-affine form",
                MassSpringDamperPlant,
                ("q",),
                target=(("q", 0.5),),
            ),
        ],
        key=lambda s: s.name,
    )
}


def analytic_names() -> list[str]:
    """Names of the built-in analytic systems."""
    return list(ANALYTIC)
