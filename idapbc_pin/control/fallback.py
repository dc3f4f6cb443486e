"""Outside the training box, the anchor's linear law: `BoxFallback` and `box_fallback`.

The networks are trained on the box X = [lo, hi] only; beyond it H_d, J_d and R_d extrapolate, and a
saturated swing leaves X for much of its course (acrobot, 100 half-box states: every trajectory
left X, elbow momenta reached 34–43 box half-widths, and the successes spent a third of their time
outside). With the fallback on, the law is

    u(x) = u_IDA-PBC(x)          where |wrap(x − x*)_i| ≤ s_i for every i   (s: the box's half-widths)
    u(x) = u* − K wrap(x − x*)    elsewhere

with K the gain of the LQR loop the anchored networks are pinned to at x* (`anchor.system_anchor`,
Q = anchor_q·I in physical units, R = I) and u* the input that holds x*. Inside X nothing changes:
H_d, J_d, R_d, the certificate (whose sublevel sets lie inside X) and the linearisation at x* are
those of the networks. The switch is discontinuous on the box's faces; the actuator limits clip
both sides alike (docs/method.md §6 measures what the switching costs: no torque step the saturated
law does not already take).

Whether a run uses it is decided after training on states of its own (`training.fallback_gate`):
it helped some robots and cost others (docs/results-history.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.angles import wrap_angles
from .anchor import half_widths, system_anchor
from .baseline import equilibrium_input

__all__ = ["BoxFallback", "box_fallback"]


@dataclass(frozen=True, eq=False)
class BoxFallback:
    """The linear law u = u* − Kδ that replaces the learned law outside the training box.

    Attributes
    ----------
    K : (m, n) gain, in the state's physical units (u in N·m or N, x = (q, p)).
    u_star : (m,) input that holds x*.
    x_star : (n,) target state.
    half : (n,) half-widths s of the training box around x* (its larger side), > 0.
    angle_mask : (n,) bool, components wrapped to within π of x* before δ is formed.
    """

    K: np.ndarray
    u_star: np.ndarray
    x_star: np.ndarray
    half: np.ndarray
    angle_mask: np.ndarray

    def delta(self, x) -> np.ndarray:
        """δ = wrap(x − x*): (..., n) -> (..., n)."""
        return wrap_angles(np.asarray(x, dtype=np.float64) - self.x_star, self.angle_mask)

    def outside(self, x) -> np.ndarray:
        """(..., n) -> (...) bool: True where some |δ_i| > s_i (the state is outside the training box)."""
        return (np.abs(self.delta(x)) > self.half).any(axis=-1)

    def apply(self, x, u) -> np.ndarray:
        """u where x is inside the box, u* − Kδ outside: (N, n), (N, m) -> (N, m) (a new array)."""
        d = self.delta(np.atleast_2d(x))
        u = np.array(u, dtype=np.float64, copy=True).reshape(len(d), -1)
        out = (np.abs(d) > self.half).any(axis=-1)
        if out.any():
            u[out] = self.u_star - d[out] @ self.K.T
        return u

    def to_json(self) -> dict:
        """The arrays as lists (controller.json of an export)."""
        return {k: np.asarray(getattr(self, k)).tolist() for k in ("K", "u_star", "x_star", "half", "angle_mask")}


def box_fallback(system, config) -> BoxFallback:
    """The fallback of `system` trained with `config` (its resolved scaling and anchor_q): the anchor's
    LQR gain K (physical units), u* = −(gᵀg)⁻¹gᵀf(x*), and the training box's half-widths."""
    anchor = system_anchor(system, config)
    return BoxFallback(
        K=np.array(anchor.K, dtype=np.float64),
        u_star=equilibrium_input(system),
        x_star=np.array(system.x_star, dtype=np.float64),
        half=np.array(half_widths(system), dtype=np.float64),
        angle_mask=np.array(system.angle_mask, dtype=bool),
    )
