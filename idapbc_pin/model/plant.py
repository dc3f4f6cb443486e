"""The Plant protocol: what every back-end (Pinocchio from a URDF, or a closed form) provides.

A `System` holds one plant and never asks which kind it is; neither does the simulator, the
robustness study or the trainer. Only the viewer's Pinocchio drawing looks inside a URDF plant.
All arrays are float64 and batched over a leading dimension N; q and v are minimal coordinates
(one number per 1-DoF joint), p = M(q) v.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["Plant"]


@runtime_checkable
class Plant(Protocol):
    """A mechanical (or input-affine) plant, batched over states.

    Attributes
    ----------
    joints : one `JointInfo` per minimal coordinate.
    nv : number of minimal coordinates.
    nq_config : size of the back-end's configuration vector (Pinocchio: continuous joints count 2).
    damping : (nv,) viscous joint damping D (N·m·s/rad or N·s/m).
    """

    joints: tuple
    nv: int
    nq_config: int
    damping: np.ndarray

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q): (N, nv) -> (N, nv, nv)."""

    def potential(self, q: np.ndarray) -> np.ndarray:
        """U(q): (N, nv) -> (N,), joules."""

    def hamiltonian(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """H(q, p): (N, nv) ×2 -> (N,), joules."""

    def velocity(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """v = M(q)⁻¹p: (N, nv) ×2 -> (N, nv)."""

    def momenta(self, q: np.ndarray, v: np.ndarray, threads: int = 1) -> np.ndarray:
        """p = M(q) v: (N, nv) ×2 -> (N, nv)."""

    def f(self, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Open-loop drift f(x) for x = (q, p): (N, nv) ×2 -> (N, 2 nv)."""

    def f_rows(self, q: np.ndarray, p: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Rows `rows` (k,) of f(x), indices into (q̇, ṗ): (N, nv) ×2 -> (N, k), f(x)[:, rows] to
        rounding (a back-end may skip terms that vanish on those rows)."""

    def f_and_jacobian(self, q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """f(x) (N, 2 nv) and ∂f/∂x (N, 2 nv, 2 nv)."""

    def forward_dynamics(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, threads: int = 1) -> np.ndarray:
        """Accelerations with joint damping: (N, nv) ×3 -> (N, nv); tau on every joint (N·m or N)."""

    def scaled(self, mass: float = 1.0, length: float = 1.0, damping: float = 1.0) -> "Plant":
        """A copy with masses, lengths or damping scaled (a robustness study's true plant)."""
