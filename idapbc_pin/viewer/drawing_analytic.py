"""The paper's analytic systems (§V) drawn from their coordinates, with no URDF.

* cart-pole: a cart at q1 on a rail along x, a pole of length 1 at angle q2 about y (upright at 0);
* double pendulum: two links of length 1, absolute angles from upright;
* mass-spring-damper: a block at position q along x, a wall, and a mark at the target x*.
"""

from __future__ import annotations

import numpy as np

from ..errors import IdapbcError
from ..model.analytic import CosCoupledPlant
from ._transforms import material, rot_y, translation
from .drawing_base import Drawing

__all__ = ["AnalyticDrawing"]

#: three.js cylinders run along local y; R_x(+90°) turns y into z (a rod upright at angle 0).
_Y_TO_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])

# nodes per kind: (path, shape, size (m), colour, moving)
_NODES = {
    "cartpole": [
        ("rail", "box", (6.0, 0.03, 0.03), 0x888888, False),
        ("cart", "box", (0.4, 0.25, 0.15), 0x3366CC, True),
        ("pole", "rod", 1.0, 0xF28C1A, True),
        ("bob", "ball", 0.07, 0xF28C1A, True),
    ],
    "double_pendulum": [
        ("base", "box", (0.12, 0.12, 0.12), 0x555555, False),
        ("link1", "rod", 1.0, 0x3366CC, True),
        ("elbow", "ball", 0.06, 0x222222, True),
        ("link2", "rod", 1.0, 0xF28C1A, True),
        ("tip", "ball", 0.07, 0xF28C1A, True),
    ],
    "block": [
        ("wall", "box", (0.05, 0.5, 0.5), 0x888888, False),
        ("target", "box", (0.005, 0.42, 0.42), 0x2CA02C, False),
        ("block", "box", (0.3, 0.3, 0.3), 0x3366CC, True),
    ],
}


def _kind(system) -> str:
    """Which analytic drawing fits `system`: "cartpole", "double_pendulum" or "block"."""
    kinds = tuple(j.kind for j in system.joints)
    if isinstance(system.plant, CosCoupledPlant) and kinds == ("analytic-linear", "analytic-angle"):
        return "cartpole"
    if isinstance(system.plant, CosCoupledPlant) and kinds == ("analytic-angle", "analytic-angle"):
        return "double_pendulum"
    if len(system.joints) == 1:
        return "block"
    raise IdapbcError(f"no drawing for the analytic system '{system.name}'. Fix: give it a URDF to view it.")


class AnalyticDrawing(Drawing):
    """The paper's analytic systems, drawn from their coordinates (no URDF)."""

    def __init__(self, system):
        self.kind = _kind(system)
        self._nodes = _NODES[self.kind]
        if self.kind == "block":
            self.q_star = float(system.x_star[0])
        self.paths = [n[0] for n in self._nodes]
        self.scales = np.ones((len(self._nodes), 3))
        self.moving = np.array([n[4] for n in self._nodes])

    def load(self, vis) -> None:
        import meshcat.geometry as mg

        for path, kind, size, color, _ in self._nodes:
            if kind == "box":
                geom = mg.Box(size)
            elif kind == "ball":
                geom = mg.Sphere(size)
            else:
                geom = mg.Cylinder(size, 0.025)
            vis[path].set_object(geom, material(color, 0.5 if path == "target" else 1.0))

    def _points(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Named points (K, 3), m, at q (K, nq): the cart or elbow and the tip, or the block."""
        q = np.atleast_2d(np.asarray(q, float))
        zeros = np.zeros(q.shape[0])
        if self.kind == "cartpole":
            cart = np.stack([q[:, 0], zeros, zeros], axis=1)
            tip = cart + np.stack([np.sin(q[:, 1]), zeros, np.cos(q[:, 1])], axis=1)
            return {"cart": cart, "tip": tip}
        if self.kind == "double_pendulum":
            elbow = np.stack([np.sin(q[:, 0]), zeros, np.cos(q[:, 0])], axis=1)
            tip = elbow + np.stack([np.sin(q[:, 1]), zeros, np.cos(q[:, 1])], axis=1)
            return {"elbow": elbow, "tip": tip}
        return {"block": np.stack([q[:, 0], zeros, zeros + 0.15], axis=1)}

    def placements(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, float))
        K = q.shape[0]
        pts = self._points(q)
        half_up = translation(np.array([[0.0, 0.0, 0.5]]))[0]
        T: dict[str, np.ndarray] = {}
        if self.kind == "cartpole":
            T["rail"] = np.broadcast_to(np.eye(4), (K, 4, 4))
            T["cart"] = translation(pts["cart"])
            T["pole"] = translation(pts["cart"]) @ rot_y(q[:, 1]) @ half_up @ _Y_TO_Z
            T["bob"] = translation(pts["tip"])
        elif self.kind == "double_pendulum":
            T["base"] = np.broadcast_to(np.eye(4), (K, 4, 4))
            T["link1"] = rot_y(q[:, 0]) @ half_up @ _Y_TO_Z
            T["elbow"] = translation(pts["elbow"])
            T["link2"] = translation(pts["elbow"]) @ rot_y(q[:, 1]) @ half_up @ _Y_TO_Z
            T["tip"] = translation(pts["tip"])
        else:
            T["wall"] = np.broadcast_to(translation(np.array([[-1.0, 0.0, 0.25]]))[0], (K, 4, 4))
            T["target"] = np.broadcast_to(translation(np.array([[self.q_star, 0.0, 0.21]]))[0], (K, 4, 4))
            T["block"] = translation(pts["block"])
        return np.stack([T[p] for p in self.paths], axis=1)

    def trace(self, q: np.ndarray) -> np.ndarray:
        pts = self._points(q)
        return pts["tip"] if "tip" in pts else pts["block"]
