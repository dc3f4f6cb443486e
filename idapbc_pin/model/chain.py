"""The kinematic tree of a URDF plant as plain arrays: what a closed form or an interval evaluation
of its dynamics needs, without Pinocchio (`PinocchioPlant.chain`).

Joint k (in the order of the minimal coordinates) hangs from joint ``parent[k]`` (−1: the fixed
base) through the fixed placement (``rotation[k]``, ``translation[k]``) of its frame in its
parent's; it turns about (revolute, continuous) or slides along (prismatic) ``axis[k]`` of its own
frame. The body it moves (fixed children lumped in) has mass ``mass[k]``, its centre of mass at
``lever[k]`` and its rotational inertia about that centre ``inertia[k]``, both in the joint's
frame. M(q) = Σ_k m_k J_{c,k}ᵀJ_{c,k} + J_{ω,k}ᵀ R_k I_k R_kᵀ J_{ω,k} + diag(armature), and
U(q) = −Σ_k m_k gᵀc_k (Featherstone, *Rigid Body Dynamics Algorithms*, 2008, ch. 2 and 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Chain"]


@dataclass(frozen=True, eq=False)
class Chain:
    """A tree of 1-DoF joints (module docstring). Arrays over the K joints; metres, kilograms, radians."""

    parent: tuple[int, ...]
    prismatic: tuple[bool, ...]
    rotation: np.ndarray  # (K, 3, 3)
    translation: np.ndarray  # (K, 3)
    axis: np.ndarray  # (K, 3), unit
    mass: np.ndarray  # (K,)
    lever: np.ndarray  # (K, 3)
    inertia: np.ndarray  # (K, 3, 3), about the centre of mass
    armature: np.ndarray  # (K,)
    gravity: np.ndarray  # (3,), m/s²

    @property
    def size(self) -> int:
        return len(self.parent)

    def ancestors(self, k: int) -> list[int]:
        """The joints that move body k: k and its ancestors, base first."""
        out = []
        while k >= 0:
            out.append(k)
            k = self.parent[k]
        return out[::-1]
