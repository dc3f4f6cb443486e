"""A braking-distance guard that keeps a cart on its rail: `RailGuard`.

A prismatic joint that the input drives and whose URDF gives it position limits (a cart on a rail)
can be carried past them by a law read far from where it was fitted, a swing-up from a tilted
start that swings the cart to full speed. The guard replaces the law's input on that joint with
full braking whenever the cart could no longer stop short of the rail's end:

    brake where  k v² / (2 a_b) ≥ d,    then u_j = −sign(v) ū_j,

with v the cart's speed, d its distance to the end it moves toward less `GUARD_MARGIN` of the
rail's half-width, ū_j the effort limit and a_b the deceleration the plant gives under full
braking at the current state (its forward dynamics: the pendulum's pull on the cart counts; where
braking does not decelerate the cart at that instant, it brakes), k = `GUARD_SAFETY` (the pull
changes as the pendulum swings during the braking). A cart already past that margin
line is pushed back at full force, whichever way it moves. Everywhere else the input is the law's. It is a state feedback, applied by `Controller` after every other law, and the exported
controller applies the same rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import System
from ..model.joint import rail_limits

__all__ = ["GUARD_MARGIN", "GUARD_SAFETY", "RailGuard"]

#: The share of a rail's half-width the guard keeps free at each end (the plans keep 0.1 of it).
GUARD_MARGIN = 0.05
#: The guard's stopping distance is this many times the one at the deceleration of the moment: the
#: pendulum's pull on the cart changes as it swings while the cart brakes.
GUARD_SAFETY = 2.0
#: Decelerations (m/s²) below this count as none: the cart may not stop, so it brakes.
_NO_DECELERATION = 1e-9


@dataclass(frozen=True, eq=False)
class RailGuard:
    """Full braking of each rail the input drives wherever the cart could not stop before its end.

    Attributes
    ----------
    system : the plant whose forward dynamics give the braking deceleration.
    coordinate : (r,) indices in q of the guarded prismatic joints.
    inputs : (r,) the input (column of B) that drives each, alone.
    sign : (r,) the sign of B[coordinate, input]: the joint's force per unit of input.
    lower, upper : (r,) the rail's ends less the margin, m.
    effort : (r,) ū of each guarded input (finite), N.
    """

    system: System
    coordinate: np.ndarray
    inputs: np.ndarray
    sign: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    effort: np.ndarray

    @classmethod
    def of(cls, system: System, margin: float = GUARD_MARGIN) -> "RailGuard | None":
        """The guard of `system`'s rails: every prismatic joint with finite URDF limits that one input
        with a finite effort limit drives alone; None where there is none."""
        lower, upper = rail_limits(system.joints)
        B = np.asarray(system.B, dtype=np.float64)
        rows = []
        for j in np.flatnonzero(np.isfinite(lower) & np.isfinite(upper)):
            cols = np.flatnonzero(B[j] != 0)
            if len(cols) == 1 and np.count_nonzero(B[:, cols[0]]) == 1 and np.isfinite(system.effort[cols[0]]):
                rows.append((j, cols[0]))
        if not rows:
            return None
        j, a = (np.array(c, dtype=int) for c in zip(*rows))
        keep = margin * 0.5 * (upper[j] - lower[j])
        return cls(system, j, a, np.sign(B[j, a]), lower[j] + keep, upper[j] - keep, np.asarray(system.effort, dtype=np.float64)[a])

    def braking(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(brake (N, r) bool, u_b (N, r) the braking input, N) for the rows of x (N, n) = (q, p): brake
        where the cart on a rail is past a guarded end, or heads for one it could no longer stop short of."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        q, v = self.system.split(x)
        s, w = q[:, self.coordinate], v[:, self.coordinate]
        past = np.where(s > self.upper, 1.0, np.where(s < self.lower, -1.0, 0.0))
        toward = np.where(past != 0, past, np.sign(w))  # the end the cart is past, else the one it heads for
        u_b = -toward * self.sign * self.effort
        u = np.zeros((len(x), self.system.m))
        u[:, self.inputs] = u_b
        a = self.system.forward_dynamics(q, v, u @ np.asarray(self.system.B, dtype=np.float64).T)[:, self.coordinate]
        deceleration = -toward * a
        room = np.where(toward > 0, self.upper - s, s - self.lower)
        stop = np.where(deceleration > _NO_DECELERATION, GUARD_SAFETY * w**2 / (2.0 * np.maximum(deceleration, _NO_DECELERATION)), np.inf)
        return (past != 0) | ((w != 0) & (stop >= room)), u_b

    def apply(self, x, u) -> np.ndarray:
        """The law's inputs u (N, m) at x (N, n), full braking where `braking` says so (a new array)."""
        u = np.array(u, dtype=np.float64, copy=True).reshape(len(np.atleast_2d(x)), -1)
        brake, u_b = self.braking(x)
        for i, a in enumerate(self.inputs):
            u[brake[:, i], a] = u_b[brake[:, i], i]
        return u

    def to_json(self) -> dict:
        """The guard's arrays for controller.json (the exported controller's "rail_guard")."""
        return {"coordinate": self.coordinate.tolist(), "input": self.inputs.tolist(), "sign": self.sign.tolist(),
                "lower": self.lower.tolist(), "upper": self.upper.tolist(), "effort": self.effort.tolist(), "safety": GUARD_SAFETY}
