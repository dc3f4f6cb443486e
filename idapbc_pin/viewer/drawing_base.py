"""How one copy of a robot is drawn: the interface every drawing back-end implements."""

from __future__ import annotations

import numpy as np

__all__ = ["Drawing"]


class Drawing:
    """How one copy of a robot is drawn: nodes, their world placements at q, and a traced point.

    Subclasses set `paths` (node paths relative to the robot's root), `scales` ((n_nodes, 3),
    applied once with the first placement; meshcat animates position and orientation only) and
    `moving` ((n_nodes,) bool), and implement `load`, `placements` and `trace`.
    """

    paths: list[str]
    scales: np.ndarray
    moving: np.ndarray

    def load(self, vis) -> None:
        """Create every node under the meshcat visualizer `vis` (the robot's root)."""
        raise NotImplementedError

    def placements(self, q: np.ndarray) -> np.ndarray:
        """World placements (K, n_nodes, 4, 4) of the nodes at minimal coordinates q (K, nq)."""
        raise NotImplementedError

    def trace(self, q: np.ndarray) -> np.ndarray:
        """World position (K, 3) of the traced point (far end of the end link) at q (K, nq)."""
        raise NotImplementedError
