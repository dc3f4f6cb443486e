"""The verification box V_box ⊇ X in which a certified set is looked for (`certify`) and trained for
(`TrainConfig.verification_terms`), by default

    V_box = x* + 4·(X − x*),   each angle capped at x* ± π (or X's own range, if wider):

wide enough to hold most trajectories that reach x* (most of the basin swings out of X and back,
docs/method.md §7), and within one turn of x* in every angle, where the plant is periodic and a
wrapped law continuous.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import IdapbcError
from .angles import wrap_angles

__all__ = ["DEFAULT_SCALE", "in_box", "verification_box"]

#: Default width of the verification box, in multiples of the training box about x*.
DEFAULT_SCALE = 4.0


def verification_box(system, scale: float = DEFAULT_SCALE, box=None) -> tuple[np.ndarray, np.ndarray]:
    """The verification box V_box ⊇ X: (lo, hi), each (n,).

    scale : V_box = x* + scale·(X − x*) (scale ≥ 1), each angle capped at x* ± π unless X is wider.
    box : an explicit (lo, hi) instead, or {coordinate name: (lo, hi)} overriding coordinates of the
        scaled box (names as ``system.state_names``); it must contain the training box X.
    """
    x_star = np.asarray(system.x_star, float)
    lo, hi = (np.asarray(b, float) for b in system.domain)
    if not (math.isfinite(scale) and scale >= 1.0):
        raise IdapbcError(f"the verification box scale must be ≥ 1 (it holds the training box), got {scale}. Fix: pass a scale ≥ 1.")
    vlo, vhi = x_star + scale * (lo - x_star), x_star + scale * (hi - x_star)
    mask = np.asarray(system.angle_mask, bool)
    vlo[mask] = np.minimum(lo[mask], np.maximum(vlo[mask], x_star[mask] - math.pi))
    vhi[mask] = np.maximum(hi[mask], np.minimum(vhi[mask], x_star[mask] + math.pi))
    if box is None:
        return vlo, vhi
    if isinstance(box, dict):
        names = list(getattr(system, "state_names", ()))
        for name, (a, b) in box.items():
            if name not in names:
                raise IdapbcError(f"unknown coordinate '{name}' of the verification box. Fix: use one of {', '.join(names)}.")
            vlo[names.index(name)], vhi[names.index(name)] = a, b
        box = (vlo, vhi)
    vlo, vhi = (np.atleast_1d(np.asarray(b, float)).copy() for b in box)
    if vlo.shape != lo.shape or vhi.shape != hi.shape or not (np.all(np.isfinite(vlo)) and np.all(np.isfinite(vhi))):
        raise IdapbcError(f"the verification box needs {lo.size} finite bounds on each side, got {vlo.tolist()} and {vhi.tolist()}. "
                          "Fix: give one LO:HI per state coordinate.")
    if np.any(vlo > lo + 1e-12) or np.any(vhi < hi - 1e-12):
        def text(a, b):
            return "[" + ", ".join(f"{x:.3g}:{y:.3g}" for x, y in zip(a, b)) + "]"

        raise IdapbcError(f"the verification box {text(vlo, vhi)} does not contain the training box {text(lo, hi)}. "
                          "Fix: widen it to hold the training box.")
    return vlo, vhi


def in_box(system, x: np.ndarray, box) -> np.ndarray:
    """(...) bool: the states x (..., n) lie in `box` = (lo, hi) (n,) each, angles of x − x* wrapped
    (and within 1e-12 of a face); a non-finite component is outside."""
    x_star = np.asarray(system.x_star, float)
    d = wrap_angles(np.asarray(x, float) - x_star, np.asarray(system.angle_mask))
    lo, hi = (np.asarray(b, float) - x_star for b in box)
    return np.all((d >= lo - 1e-12) & (d <= hi + 1e-12), axis=-1)
