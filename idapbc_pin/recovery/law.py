"""A recovery law beside the IDA-PBC one, for weak actuators: `RecoveryLaw`.

Under tight effort limits most of the box cannot be brought to x* by a saturated smooth law: the
actuator has to pump, and the matched IDA-PBC law cannot hold such a swing (its H_d would have to
decrease along every pumping trajectory; docs/stages.md). A
recovery law is a plain state feedback fitted to torque plans within the limits
(`recovery.stage`); the IDA-PBC law keeps the neighbourhood of x*:

    u(x) = u_IDA-PBC(x)                 where |δ_i| ≤ r·s_i for every i   (the inner box)
                                        or H_d(x) ≤ c                     (the level set, if c < ∞)
    u(x) = ū ⊙ tanh(MLP(δ / s))         elsewhere, inside and outside the training box  (direct form)
    u(x) = ū ⊙ clip(clip(u_IDA-PBC(x)/ū, ±1) + MLP(δ / s), ±1)  elsewhere            (residual form)

with δ = wrap(x − x*), s the training box's half-widths, r the inner scale chosen on validation
states (`recovery.gate.choose_inner`) and ū the effort limits: the recovery law stays within
the limits by construction. The MLP has tanh hidden layers and a linear output. The residual form
adds the MLP to the IDA-PBC law's own input instead of replacing it: where the labels are that
law's inputs (every start the run's law brings to x*, and every plan after its horizon) the fit
only has to learn zero, so a trajectory that swings out of the level set near x* keeps the IDA-PBC
law's inputs up to the fitted correction (docs/stages.md, "The residual form"). Like
`fallback.BoxFallback` it acts through `apply(x, u)`, so `Controller`, `simulate`, `export` and the
exported controller.py treat both alike; the switch is discontinuous on the inner box's faces.

The level c (∞ by default: the box alone) lets the IDA-PBC law keep the sublevel set {H_d ≤ c} of
its own energy as well. Along the matched closed loop H_d does not grow, so a trajectory that starts
there tends to stay there and never meets the recovery law, where with a box alone a swing from
near x* leaves the box and is handed over (docs/stages.md, "A level set of H_d").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .._memo import last_call
from ..model.angles import wrap_angles

__all__ = ["InnerSwitch", "RecoveryLaw"]


class InnerSwitch:
    """Mixin of a recovery law: the IDA-PBC law inside the inner box (and where H_d ≤ `level`), the
    law's own `law(x, u)` elsewhere.

    The dataclass that mixes it in holds x_star (n,), angle_mask (n,) bool, scale (n,) s, inner (n,)
    half-widths r·s and level c, and defines `law`.
    """

    def delta(self, x) -> np.ndarray:
        """δ = wrap(x − x*): (..., n) -> (..., n)."""
        return wrap_angles(np.asarray(x, dtype=np.float64) - self.x_star, self.angle_mask)

    @last_call
    def outside(self, x) -> np.ndarray:
        """(..., n) -> (...) bool: True where the state is outside the inner box (the recovery law acts)."""
        return (np.abs(self.delta(x)) > self.inner).any(axis=-1)

    @property
    def uses_level(self) -> bool:
        """True when the IDA-PBC law also keeps the sublevel set {H_d ≤ level}: `apply` needs H_d."""
        return math.isfinite(self.level)

    def reads_networks(self, x) -> np.ndarray:
        """(N, n) -> (N,) bool: the rows whose IDA-PBC input `apply` reads (`OuterLaw`): inside the
        inner box, every row for a level or a residual law."""
        if self.uses_level or self.residual:
            return np.ones(len(np.atleast_2d(x)), dtype=bool)
        return ~self.outside(np.atleast_2d(x))

    def apply(self, x, u, energy=None) -> np.ndarray:
        """u inside the inner box (and where H_d ≤ `level`), the recovery law elsewhere:
        (N, n), (N, m) -> (N, m) (a new array). energy : H_d as a function (K, n) -> (K,), called on
        the rows outside the inner box only; needed when `uses_level`."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        u = np.array(u, dtype=np.float64, copy=True).reshape(len(x), -1)
        out = self.outside(x)
        if self.uses_level and out.any():
            if energy is None:
                raise ValueError("this recovery law switches on H_d's level: pass energy, the function x -> H_d(x)")
            out[out] = np.asarray(energy(x[out]), dtype=np.float64).reshape(-1) > self.level
        if out.any():
            u[out] = self.law(x[out], u[out])
        return u

    def with_inner(self, inner_scale: float):
        """The same law with the inner box r·s for another r (s = `scale`)."""
        return replace(self, inner=inner_scale * self.scale)

    def with_level(self, level: float):
        """The same law with the IDA-PBC law also keeping {H_d ≤ level} (∞: the inner box alone)."""
        return replace(self, level=float(level))

    def to_json(self) -> dict:
        """controller.json's "fallback" of an export (kind "recovery"): every array as lists."""
        return {"kind": "recovery"} | {k: np.asarray(v).tolist() for k, v in self.arrays().items()}


@dataclass(frozen=True, eq=False)
class RecoveryLaw(InnerSwitch):
    """The fitted recovery law and the inner box where the IDA-PBC law keeps control.

    Attributes
    ----------
    weights : per layer (out, in) matrices, the last one (m, width).
    biases : per layer (out,) vectors.
    x_star : (n,) target state.
    scale : (n,) s, the training box's half-widths (the MLP sees δ / s).
    effort : (m,) ū, the effort limits (finite), N·m or N.
    angle_mask : (n,) bool, components wrapped to within π of x*.
    inner : (n,) half-widths r·s of the inner box (0: the recovery law everywhere but exactly x*).
    level : c, the IDA-PBC law also keeps the states with H_d(x) ≤ c (∞: the inner box alone).
    residual : True: the MLP corrects the IDA-PBC law's input (the residual form); False: it
        replaces it (the direct form, every law saved before the residual form existed).
    """

    weights: tuple
    biases: tuple
    x_star: np.ndarray
    scale: np.ndarray
    effort: np.ndarray
    angle_mask: np.ndarray
    inner: np.ndarray
    level: float = math.inf
    residual: bool = False

    def law(self, x, u=None) -> np.ndarray:
        """The recovery law alone: (N, n) -> (N, m), within ±ū. Direct form: ū ⊙ tanh(MLP(δ/s)).
        Residual form: ū ⊙ clip(clip(u/ū, ±1) + MLP(δ/s), ±1), with u (N, m) the IDA-PBC law's
        input at x (required)."""
        z = self.delta(np.atleast_2d(x)) / self.scale
        for W, b in zip(self.weights[:-1], self.biases[:-1]):
            z = np.tanh(z @ W.T + b)
        z = z @ self.weights[-1].T + self.biases[-1]
        if not self.residual:
            return self.effort * np.tanh(z)
        if u is None:
            raise ValueError("a residual recovery law corrects the IDA-PBC law's input: pass u, that input at x")
        return self.effort * np.clip(np.clip(np.asarray(u, dtype=np.float64).reshape(z.shape) / self.effort, -1.0, 1.0) + z, -1.0, 1.0)

    def arrays(self) -> dict:
        """The law as named arrays (recovery.npz of a run): W0, b0, W1, b1, …, x_star, scale, effort,
        angle_mask, inner, level when it is finite, and residual when it is set."""
        out = {f"W{k}": W for k, W in enumerate(self.weights)} | {f"b{k}": b for k, b in enumerate(self.biases)}
        out |= {k: np.asarray(getattr(self, k)) for k in ("x_star", "scale", "effort", "angle_mask", "inner")}
        out |= {"level": np.asarray(self.level)} if self.uses_level else {}
        return out | ({"residual": np.asarray(True)} if self.residual else {})

    @classmethod
    def from_arrays(cls, arrays) -> "RecoveryLaw":
        """Inverse of `arrays` (a dict or an open .npz); raises ValueError when a piece is missing or misshapen."""
        depth = sum(1 for k in arrays if k.startswith("W"))
        weights = tuple(np.asarray(arrays[f"W{k}"], dtype=np.float64) for k in range(depth))
        biases = tuple(np.asarray(arrays[f"b{k}"], dtype=np.float64) for k in range(depth))
        x_star, scale, effort, inner = (np.asarray(arrays[k], dtype=np.float64) for k in ("x_star", "scale", "effort", "inner"))
        level = float(np.asarray(arrays["level"], dtype=np.float64)) if "level" in arrays else math.inf  # laws saved before it had none
        residual = bool(np.asarray(arrays["residual"])) if "residual" in arrays else False  # laws saved before it: the direct form
        law = cls(weights, biases, x_star, scale, effort, np.asarray(arrays["angle_mask"], dtype=bool), inner, level, residual)
        n, m = len(x_star), len(effort)
        widths = [n] + [len(b) for b in biases]
        shapes_ok = depth >= 1 and all(W.shape == (widths[k + 1], widths[k]) for k, W in enumerate(weights)) and widths[-1] == m
        if not shapes_ok or any(a.shape != (n,) for a in (scale, law.angle_mask, inner)):
            raise ValueError("the recovery law's arrays do not fit together")
        if not all(np.isfinite(a).all() for a in (*weights, *biases, x_star, scale, effort, inner)) or not (scale > 0).all() or math.isnan(level):
            raise ValueError("the recovery law has non-finite weights, limits or scales")
        return law
