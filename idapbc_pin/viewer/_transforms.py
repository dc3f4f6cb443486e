"""Homogeneous transforms, quaternions and materials shared by the drawings and the animation (numpy only)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PALETTE", "material", "quaternions", "rot_y", "translation"]

#: Colours of successive links and rollouts (0xRRGGBB).
PALETTE = (0x3366CC, 0xF28C1A, 0x2CA02C, 0xD62728, 0x9467BD, 0x8C564B, 0xE377C2, 0x17BECF)


def rot_y(theta: np.ndarray) -> np.ndarray:
    """(K,) angles, rad -> (K, 4, 4) rotations about +y (z tilts towards +x for theta > 0)."""
    c, s = np.cos(theta), np.sin(theta)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0], T[..., 0, 2], T[..., 1, 1], T[..., 2, 0], T[..., 2, 2], T[..., 3, 3] = c, s, 1.0, -s, c, 1.0
    return T


def translation(p: np.ndarray) -> np.ndarray:
    """(K, 3) positions, m -> (K, 4, 4) translations."""
    p = np.atleast_2d(p)
    T = np.broadcast_to(np.eye(4), p.shape[:-1] + (4, 4)).copy()
    T[..., :3, 3] = p
    return T


def _quaternion(m: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a 3×3 rotation: Shoemake's method, step for step as Eigen's
    ``Quaternion(Matrix3)`` (so the values are Pinocchio's to the last bit)."""
    t = (float(m[1, 1]) + float(m[2, 2])) + float(m[0, 0])  # the order Eigen's vectorised trace adds in
    if t > 0.0:
        t = math.sqrt(t + 1.0)
        w = 0.5 * t
        t = 0.5 / t
        return (float(m[2, 1] - m[1, 2]) * t, float(m[0, 2] - m[2, 0]) * t, float(m[1, 0] - m[0, 1]) * t, w)
    i = 0
    if m[1, 1] > m[0, 0]:
        i = 1
    if m[2, 2] > m[i, i]:
        i = 2
    j = (i + 1) % 3
    k = (j + 1) % 3
    t = math.sqrt(float(m[i, i] - m[j, j] - m[k, k]) + 1.0)
    v = [0.0, 0.0, 0.0]
    v[i] = 0.5 * t
    t = 0.5 / t
    v[j] = float(m[j, i] + m[i, j]) * t
    v[k] = float(m[k, i] + m[i, k]) * t
    return (v[0], v[1], v[2], float(m[k, j] - m[j, k]) * t)


def quaternions(T: np.ndarray) -> np.ndarray:
    """(K, 4, 4) placements -> (K, 4) unit quaternions (x, y, z, w) of their rotations,
    sign-continuous along K (q and −q are the same rotation; three.js interpolates the short way)."""
    q = np.array([_quaternion(R) for R in np.asarray(T, float)[:, :3, :3]])
    for k in range(1, q.shape[0]):
        if q[k] @ q[k - 1] < 0:
            q[k] = -q[k]
    return q


def material(color: int, opacity: float = 1.0):
    """meshcat Lambert material of colour 0xRRGGBB, transparent when `opacity` < 1."""
    import meshcat.geometry as mg

    if opacity < 1.0:
        return mg.MeshLambertMaterial(color=color, transparent=True, opacity=opacity)
    return mg.MeshLambertMaterial(color=color)
