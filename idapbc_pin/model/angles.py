"""Angle coordinates: differences wrapped to (−π, π] (the judge and the baseline compare states this way)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["wrap_angles"]


def wrap_angles(dq, angle_mask) -> np.ndarray:
    """Wrap the angle components of a difference to (−π, π].

    Parameters
    ----------
    dq : (..., k) differences (rad on angles, anything elsewhere).
    angle_mask : (k,) bool, True on angle components (e.g. ``system.angle_mask`` for x − x*,
        ``system.angle_mask[:nq]`` for q − q*).

    Returns
    -------
    (..., k) copy with the masked components in (−π, π].
    """
    dq = np.array(dq, dtype=float, copy=True)
    mask = np.asarray(angle_mask, bool)
    if mask.shape != dq.shape[-1:]:
        raise ValueError(f"angle_mask has shape {mask.shape}, expected ({dq.shape[-1]},)")
    if mask.all():  # every component an angle: the same formula without the masked copy
        return np.subtract(math.pi, np.mod(math.pi - dq, 2.0 * math.pi), out=dq)
    dq[..., mask] = math.pi - np.mod(math.pi - dq[..., mask], 2.0 * math.pi)
    return dq
