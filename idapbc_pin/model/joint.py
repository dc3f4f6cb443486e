"""One minimal coordinate of a system: a 1-DoF joint and what the URDF says about it."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["JointInfo", "rail_limits"]


@dataclass(frozen=True)
class JointInfo:
    """One minimal coordinate: a 1-DoF joint of the model.

    Attributes
    ----------
    name : joint name in the URDF.
    kind : "revolute" | "continuous" | "prismatic"; built-in models use "analytic-angle" | "analytic-linear".
    axis : (3,) joint axis in the joint frame.
    lower, upper : position limits (rad or m); ±inf when the joint has none.
    damping : viscous joint damping (N·m·s/rad or N·s/m) from the URDF `<dynamics damping>`.
    mass : mass of the body this joint moves, fixed children lumped in (kg).
    effort : actuator limit |τ| ≤ effort (N·m or N) from the URDF `<limit effort>`; +inf when the
        joint has none (absent or 0).
    speed : speed limit |v| ≤ speed (rad/s or m/s) from the URDF `<limit velocity>`; +inf when the
        joint has none (absent or 0).
    """

    name: str
    kind: str
    axis: tuple[float, float, float]
    lower: float
    upper: float
    damping: float
    mass: float
    effort: float = math.inf
    speed: float = math.inf

    @property
    def is_angle(self) -> bool:
        """True for rotational coordinates (wrapped to (−π, π] when judging success)."""
        return self.kind in ("revolute", "continuous", "analytic-angle")


def rail_limits(joints) -> tuple[np.ndarray, np.ndarray]:
    """(lower (nq,), upper (nq,)) of the coordinates of `joints` (`JointInfo`s): the position limits of
    every linear coordinate (a prismatic joint: a cart on its rail), m; ∓∞ for angles (a swing-up may
    turn a joint past its URDF range) and for a joint without limits."""
    lower = np.array([-np.inf if j.is_angle else j.lower for j in joints], dtype=np.float64)
    upper = np.array([np.inf if j.is_angle else j.upper for j in joints], dtype=np.float64)
    return lower, upper
