"""Outside the training box, the anchor's linear law: `BoxFallback` and `box_fallback`.

The networks are trained on the box X = [lo, hi] only; beyond it H_d, J_d and R_d extrapolate, and a
saturated swing leaves X for much of its course, its momenta reaching many box half-widths. With
the fallback on, the law is

    u(x) = u_IDA-PBC(x)          where |wrap(x − x*)_i| ≤ s_i for every i   (s: the box's half-widths)
    u(x) = u* − k K wrap(x − x*)  elsewhere

with K the gain of the LQR loop the anchored networks are pinned to at x* (`anchor.system_anchor`,
Q = anchor_q·I in physical units, R = I), k the run's `fallback_gain` and u* the input that holds x*.
For a robot with effort limits the automatic k is `LIMITED_GAIN` = 3: outside the box the law then
saturates on most of a swing and acts like a bang-bang law switching on the sign of Kδ, which brings
more states to x* than k = 1 (docs/method.md §6). Its loop A − kBK at x* (never used there) stays
within the judge's `POLE_STEP` at 2 ms on the zoo. Inside X nothing changes:
H_d, J_d, R_d, the certificate (whose sublevel sets lie inside X) and the linearisation at x* are
those of the networks. The switch is discontinuous on the box's faces; the actuator limits clip
both sides alike (docs/method.md §6 measures what the switching costs: no torque step the saturated
law does not already take).

With an ``inside_gain`` k_in > 1 the learned law is also scaled about u* inside the box,

    u(x) = u* + k_in (u_IDA-PBC(x) − u*)   where |wrap(x − x*)_i| ≤ s_i for every i,

so under the limits the whole law switches on its sign as the linear law does outside. Its
linearisation at x* is u* − k_in K δ, still exponentially stable for any k_in ≥ ½ (LQR's gain margin:
(A − kBK)ᵀS + S(A − kBK) = −Q − (2k − 1)KᵀRK with S, K the anchor's Riccati solution and gain).
It helps some robots and costs others (docs/results-history.md), which is why the gate decides it
per run.

The constant k_in leaves the loop at x* as A − k_in BK, whose slowest pole can be far slower than
the anchor's, so that the loop settles slower than LQR. So the gain ramps up with the distance from
x* in the box's ∞-norm, r = max_i |δ_i| / s_i:

    k(x) = 1 + (k_in − 1) · clip((r − r₀) / (r₁ − r₀), 0, 1),     (r₀, r₁) = ``inside_ramp``

which is 1 within r₀ of x* (the learned law as trained: its linearisation is the anchor's LQR loop
again) and k_in beyond r₁; (0, 0) is the constant k_in. The gate uses `INSIDE_RAMP` = (0.2, 0.5),
which keeps the constant gain's success and settles faster (docs/results-history.md).

Whether a run uses the fallback, and which inside gain, is decided after training on states of its
own (`recovery.box_gate`): each helps some robots and costs others (docs/results-history.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..control.anchor import half_widths, system_anchor
from ..control.baseline import equilibrium_input
from ..model.angles import wrap_angles

__all__ = ["INSIDE_RAMP", "LIMITED_GAIN", "BoxFallback", "box_fallback", "fallback_gain"]

#: The automatic gain factor k of the fallback for a robot with effort limits (see the module docstring).
LIMITED_GAIN = 3.0
#: Where the inside gain ramps from 1 to k_in, in the box's ∞-norm around x* (fractions of its
#: half-widths; see the module docstring).
INSIDE_RAMP = (0.2, 0.5)


@dataclass(frozen=True, eq=False)
class BoxFallback:
    """The linear law u = u* − Kδ that replaces the learned law outside the training box.

    Attributes
    ----------
    K : (m, n) gain applied, k times the anchor's, in the state's physical units (u in N·m or N, x = (q, p)).
    u_star : (m,) input that holds x*.
    x_star : (n,) target state.
    half : (n,) half-widths s of the training box around x* (its larger side), > 0.
    angle_mask : (n,) bool, components wrapped to within π of x* before δ is formed.
    gain : k, the factor `K` carries over the anchor's gain.
    inside_gain : k_in ≥ ½, the factor on the learned law's deviation from u* inside the box
        (1: the learned law unchanged there).
    inside_ramp : (r₀, r₁), 0 ≤ r₀ ≤ r₁: the factor is 1 where max_i |δ_i| / s_i ≤ r₀, k_in beyond
        r₁, linear in between; (0, 0): k_in everywhere inside (runs gated before the ramp).
    """

    K: np.ndarray
    u_star: np.ndarray
    x_star: np.ndarray
    half: np.ndarray
    angle_mask: np.ndarray
    gain: float = 1.0
    inside_gain: float = 1.0
    inside_ramp: tuple[float, float] = (0.0, 0.0)

    @property
    def anchor_K(self) -> np.ndarray:
        """(m, n) the anchor's own LQR gain K (= `K` / `gain`), the loop the networks reproduce at x*."""
        return self.K / self.gain

    def delta(self, x) -> np.ndarray:
        """δ = wrap(x − x*): (..., n) -> (..., n)."""
        return wrap_angles(np.asarray(x, dtype=np.float64) - self.x_star, self.angle_mask)

    def outside(self, x) -> np.ndarray:
        """(..., n) -> (...) bool: True where some |δ_i| > s_i (the state is outside the training box)."""
        return (np.abs(self.delta(x)) > self.half).any(axis=-1)

    def reads_networks(self, x) -> np.ndarray:
        """(N, n) -> (N,) bool: the rows whose networks' input `apply` reads (`OuterLaw`): inside the box."""
        return ~self.outside(np.atleast_2d(x))

    def apply(self, x, u, energy=None) -> np.ndarray:
        """u* + k(x) (u − u*) where x is inside the box (k = `gain_at`), u* − Kδ outside:
        (N, n), (N, m) -> (N, m) (a new array; u itself inside when k_in = 1). `energy` (H_d, which
        `RecoveryLaw.apply` may read) is not used."""
        d = self.delta(np.atleast_2d(x))
        u = np.array(u, dtype=np.float64, copy=True).reshape(len(d), -1)
        if self.inside_gain != 1.0:
            u = self.u_star + self.gain_at(d)[:, None] * (u - self.u_star)
        out = (np.abs(d) > self.half).any(axis=-1)
        if out.any():
            u[out] = self.u_star - d[out] @ self.K.T
        return u

    def gain_at(self, delta) -> np.ndarray:
        """The factor k(x) on u − u* inside the box, for δ = `delta` (N, n) -> (N,): 1 within r₀ of x*
        in the box's ∞-norm, `inside_gain` beyond r₁, linear in between (`inside_ramp`)."""
        r0, r1 = self.inside_ramp
        r = (np.abs(delta) / self.half).max(axis=-1)
        w = np.clip((r - r0) / (r1 - r0), 0.0, 1.0) if r1 > r0 else (r >= r0).astype(np.float64)
        return 1.0 + (self.inside_gain - 1.0) * w

    @property
    def gain_at_target(self) -> float:
        """The factor that sets the loop's linearisation at x*: `inside_gain` for a constant gain
        (r₀ = r₁ = 0), else 1 (k − 1 and u − u* both vanish at x*, so the ramp adds no term there)."""
        return self.inside_gain if self.inside_ramp[1] == 0.0 else 1.0

    def with_inside_gain(self, inside_gain: float, inside_ramp=(0.0, 0.0)) -> "BoxFallback":
        """The same fallback with the learned law scaled by `inside_gain` about u* inside the box,
        ramped in over `inside_ramp` (r₀, r₁) = fractions of the box (default: constant)."""
        if not (math.isfinite(inside_gain) and inside_gain >= 0.5):
            raise ValueError(f"inside_gain must be ≥ 0.5 (LQR's gain margin), got {inside_gain}")
        r0, r1 = (float(r) for r in inside_ramp)
        if not (math.isfinite(r1) and 0.0 <= r0 <= r1):
            raise ValueError(f"inside_ramp must be two fractions of the box 0 ≤ r0 ≤ r1, got {tuple(inside_ramp)}")
        return replace(self, inside_gain=float(inside_gain), inside_ramp=(r0, r1))

    def to_json(self) -> dict:
        """The arrays as lists (controller.json of an export)."""
        return {k: np.asarray(getattr(self, k)).tolist() for k in ("K", "u_star", "x_star", "half", "angle_mask", "gain", "inside_gain", "inside_ramp")}


def fallback_gain(system, config) -> float:
    """The gain factor k of `system`'s fallback: ``config.fallback_gain``, or when that is 0 (automatic)
    `LIMITED_GAIN` for a robot with effort limits and 1 for one without."""
    if config.fallback_gain > 0:
        return float(config.fallback_gain)
    return LIMITED_GAIN if system.limited else 1.0


def box_fallback(system, config, inside_gain: float = 1.0, inside_ramp=(0.0, 0.0)) -> BoxFallback:
    """The fallback of `system` trained with `config` (its resolved scaling, anchor_q and fallback_gain):
    k times the anchor's LQR gain K (physical units), u* = −(gᵀg)⁻¹gᵀf(x*), the training box's
    half-widths, and `inside_gain` on the learned law inside the box (1: unchanged), ramped in over
    `inside_ramp` (`BoxFallback.gain_at`)."""
    anchor = system_anchor(system, config)
    gain = fallback_gain(system, config)
    return BoxFallback(
        K=gain * np.array(anchor.K, dtype=np.float64),
        gain=gain,
        u_star=equilibrium_input(system),
        x_star=np.array(system.x_star, dtype=np.float64),
        half=np.array(half_widths(system), dtype=np.float64),
        angle_mask=np.array(system.angle_mask, dtype=bool),
    ).with_inside_gain(inside_gain, inside_ramp)
