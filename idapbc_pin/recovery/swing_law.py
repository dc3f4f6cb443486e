"""A swing-up law around the run's law: `SwingUpLaw`.

From the resting posture (a pendulum hanging) to x* the actuator has to pump energy over several
swings, far outside the training box where the IDA-PBC law (and a recovery law) were fitted. A
swing-up law is a plain state feedback fitted to torque plans from near the resting posture, and to
the recovery stage's labels where the run has them (`recovery.swing_stage`); the run's own law
keeps a box around x*:

    u(x) = u_run(x)                         where |δ_i| ≤ b_i for every component i (the kept box)
    u(x) = ū ⊙ tanh(MLP(φ(δ)))              elsewhere

with δ = wrap(x − x*), b the kept box's half-widths (∞ for a component the switch does not read),
u_run the run's law as it is (the networks, and its linear or recovery law outside its own box) and
ū the effort limits. Two kept boxes are in use (`swing_stage`): the run's recovery law's inner box
r·s (the swing-up law then replaces the recovery law and acts along the whole swing, through the
box's postures at speed too), or the training box's angles alone (b = s on the angles, ∞ on the rest:
the run's law keeps every posture of its box, whatever the speeds). The features φ(δ) are
(sin δ_i, cos δ_i) for each angle (the law is continuous around the whole circle, where δ = ±π meet
at the hanging posture) and δ_j / c_j for every other component (c_j the spread of the labels).
Like `RecoveryLaw` it acts through `apply(x, u)`, so `Controller`, `simulate` and `export` treat it
as any outer law; the switch is discontinuous on the kept box's faces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..trajectory.kept_box import KeptBoxLaw

__all__ = ["KeptBoxLaw", "SwingUpLaw", "swing_features", "swing_law_from_arrays"]


def swing_features(delta: np.ndarray, angle_mask: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """φ(δ): (N, n) -> (N, 2·a + (n − a)), a the number of angles: (sin, cos) of every angle of δ,
    then δ_j / s_j for every other component, in that order."""
    mask = np.asarray(angle_mask, dtype=bool)
    a = delta[:, mask]
    return np.concatenate([np.sin(a), np.cos(a), delta[:, ~mask] / np.asarray(scale)[~mask]], axis=1)


@dataclass(frozen=True, eq=False)
class SwingUpLaw(KeptBoxLaw):
    """The fitted swing-up law and the postures where the run's law keeps control.

    Attributes
    ----------
    weights : per layer (out, in) matrices, the first (width, 2·a + n − a), the last (m, width).
    biases : per layer (out,) vectors.
    x_star : (n,) target state.
    scale : (n,) c, the spread of the labels of each component (read for the components that are
        not angles only).
    effort : (m,) ū, the effort limits (finite), N·m or N.
    angle_mask : (n,) bool, components wrapped to within π of x* (angles of q).
    box : (n,) half-widths b of the kept box, where the run's law keeps control (∞: the component
        is not read).
    inner : the run's own outer law (`BoxFallback`, `RecoveryLaw`) applied first, or None.
    """

    weights: tuple
    biases: tuple
    x_star: np.ndarray
    scale: np.ndarray
    effort: np.ndarray
    angle_mask: np.ndarray
    box: np.ndarray
    inner: object = None

    def law(self, x) -> np.ndarray:
        """The swing-up law alone: (N, n) -> (N, m), within ±ū."""
        z = swing_features(self.delta(np.atleast_2d(x)), self.angle_mask, self.scale)
        for W, b in zip(self.weights[:-1], self.biases[:-1]):
            z = np.tanh(z @ W.T + b)
        return self.effort * np.tanh(z @ self.weights[-1].T + self.biases[-1])

    def arrays(self) -> dict:
        """The law as named arrays (swingup.npz of a run, without `inner`, which the run supplies):
        W0, b0, W1, b1, …, x_star, scale, effort, angle_mask, box."""
        out = {f"W{k}": W for k, W in enumerate(self.weights)} | {f"b{k}": b for k, b in enumerate(self.biases)}
        return out | {k: np.asarray(getattr(self, k)) for k in ("x_star", "scale", "effort", "angle_mask", "box")}

    @classmethod
    def from_arrays(cls, arrays, inner=None) -> "SwingUpLaw":
        """Inverse of `arrays` (a dict or an open .npz) around `inner`; raises ValueError when a piece is
        missing, misshapen or not finite."""
        depth = sum(1 for k in arrays if k.startswith("W"))
        weights = tuple(np.asarray(arrays[f"W{k}"], dtype=np.float64) for k in range(depth))
        biases = tuple(np.asarray(arrays[f"b{k}"], dtype=np.float64) for k in range(depth))
        x_star, scale, effort, box = (np.asarray(arrays[k], dtype=np.float64) for k in ("x_star", "scale", "effort", "box"))
        mask = np.asarray(arrays["angle_mask"], dtype=bool)
        n, m = len(x_star), len(effort)
        widths = [2 * int(mask.sum()) + n - int(mask.sum())] + [len(b) for b in biases]
        if depth < 1 or any(W.shape != (widths[k + 1], widths[k]) for k, W in enumerate(weights)) or widths[-1] != m \
                or any(a.shape != (n,) for a in (scale, mask, box)):
            raise ValueError("the swing-up law's arrays do not fit together")
        if not all(np.isfinite(a).all() for a in (*weights, *biases, x_star, scale, effort)) or not (scale > 0).all() or not (box >= 0).all():
            raise ValueError("the swing-up law has non-finite weights, limits or scales")
        return cls(weights, biases, x_star, scale, effort, mask, box, inner)

    def to_json(self) -> dict:
        """controller.json's "fallback" of an export (kind "swing_up"): every array as lists (an
        unread component of the kept box as null), and the run's own outer law it wraps as "wraps"
        (None: the networks alone)."""
        inner = None if self.inner is None else self.inner.to_json()
        out = {k: np.asarray(v).tolist() for k, v in self.arrays().items()}
        out["box"] = [float(b) if np.isfinite(b) else None for b in self.box]
        return {"kind": "swing_up"} | out | {"wraps": inner}



def swing_law_from_arrays(arrays, inner=None):
    """A run's swing-up law from its arrays (a dict or an open .npz): a `TrackingLaw` where they hold
    a nominal trajectory ("X"), else a `SwingUpLaw`, around `inner`; raises ValueError as theirs do."""
    from ..trajectory.tracking_law import TrackingLaw

    return (TrackingLaw if "X" in arrays else SwingUpLaw).from_arrays(arrays, inner)
