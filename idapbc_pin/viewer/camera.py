"""The camera: meshcat's default perspective camera, framed on the whole motion."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["CAMERA_FOV_DEG", "Camera", "frame_camera"]

#: meshcat's default perspective camera: vertical field of view, degrees.
CAMERA_FOV_DEG = 75.0


@dataclass(frozen=True)
class Camera:
    """meshcat's default perspective camera, aimed at `target` from `position` (world, z up).

    meshcat's orbit controls look at the world origin, so the viewer shifts the whole scene by
    −target; in the robot's coordinates the camera is at `position` and looks at `target`.

    Attributes
    ----------
    target : (3,) point looked at, m.
    position : (3,) camera position, m.
    fov_deg : vertical field of view, degrees (meshcat's default camera: 75).
    """

    target: np.ndarray
    position: np.ndarray
    fov_deg: float = CAMERA_FOV_DEG

    def project(self, points, width: int, height: int) -> np.ndarray:
        """Pixel coordinates (K, 2) (x right, y down) of world points (K, 3) in a width×height view.

        Points behind the camera get nan.
        """
        p = np.atleast_2d(np.asarray(points, float))
        forward = self.target - self.position
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right = right / np.linalg.norm(right)
        up = np.cross(right, forward)
        rel = p - self.position
        depth = rel @ forward
        f = 0.5 * height / math.tan(math.radians(self.fov_deg) / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = 0.5 * width + f * (rel @ right) / depth
            y = 0.5 * height - f * (rel @ up) / depth
        out = np.stack([x, y], axis=1)
        out[depth <= 0] = np.nan
        return out


def frame_camera(points: np.ndarray, aspect: float = 4 / 3, fill: float = 0.7) -> Camera:
    """A camera that sees every point (K, 3) (in a view at least `aspect` wide): across the plane of motion.

    Planar motion in x-z is seen from −y (slightly from the side and above), in y-z from +x, any other
    motion from an oblique direction. The distance is the smallest at which every point projects
    inside `fill` of the view, and at least 0.5 m.
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    target = 0.5 * (lo + hi)
    spread = hi - lo
    if spread[1] <= 0.1 * max(spread.max(), 1e-9):  # motion in the x-z plane: look from -y
        direction = np.array([0.25, -1.0, 0.3])
    elif spread[0] <= 0.1 * max(spread.max(), 1e-9):  # y-z plane: look from +x
        direction = np.array([1.0, 0.25, 0.3])
    else:
        direction = np.array([1.0, -1.0, 0.7])
    direction /= np.linalg.norm(direction)
    right = np.cross(-direction, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, -direction)
    tan_v = fill * math.tan(math.radians(CAMERA_FOV_DEG) / 2)
    rel = points - target
    along = rel @ direction
    need = np.maximum(np.abs(rel @ right) / (tan_v * aspect), np.abs(rel @ up) / tan_v) + along
    distance = max(0.5, float(need.max()) * 1.05)
    return Camera(target=target, position=target + distance * direction)
