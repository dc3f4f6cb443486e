"""A recovery law read from the labelled paths themselves: `LibraryLaw`.

The reach stage's labels are whole closed-loop paths: from each start, a plan tracked and caught
by the run's law until x*, sampled every 10 ms (`recovery.stage`). A fitted MLP
(`recovery.law.RecoveryLaw`) averages them; this law keeps them. Each path, sampled every knot,
gets the gains of a time-varying LQR along it, and the law reads the nearest point of all paths
(`trajectory.library.paths_law`, a funnel library):

    k(x) = argmin_k ‖W wrap(x − X_k)‖²,    u(x) = clip(U_k + K_k wrap(x − X_k), ±ū)   (k = k(x)),

outside the inner box (and where H_d > `level`), the IDA-PBC law inside, as for the fitted law
(`InnerSwitch`). It is a state feedback: `export` ships its arrays, and the exported controller
searches the nearest point by brute force.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from ..trajectory.library import paths_law
from ..trajectory.tracking_law import TrackingLaw
from .law import InnerSwitch, RecoveryLaw

__all__ = ["LibraryLaw", "recovery_law_from_arrays"]

_PATH_FIELDS = ("X", "U", "K", "weight")


@dataclass(frozen=True, eq=False)
class LibraryLaw(InnerSwitch):
    """Labelled paths with their gains, read at the nearest point, and where the IDA-PBC law keeps control.

    Attributes
    ----------
    X : (P, n) the paths' states (q, p). U : (P, m) their inputs, N·m or N.
    K : (P, m, n) feedback gains on wrap(x − X_k).
    weight : (n,) weights of the distance that picks the nearest point.
    x_star : (n,) target state. scale : (n,) s, the training box's half-widths.
    effort : (m,) ū, the effort limits (finite). angle_mask : (n,) bool, components wrapped to within π.
    inner : (n,) half-widths r·s of the inner box. level : c, as `RecoveryLaw.level` (∞: the box alone).
    """

    X: np.ndarray
    U: np.ndarray
    K: np.ndarray
    weight: np.ndarray
    x_star: np.ndarray
    scale: np.ndarray
    effort: np.ndarray
    angle_mask: np.ndarray
    inner: np.ndarray
    level: float = math.inf
    residual = False  # the RecoveryLaw protocol: the law replaces the IDA-PBC law's input

    @classmethod
    def from_tracks(cls, tracks: TrackingLaw, scale: np.ndarray) -> "LibraryLaw":
        """The law of a `TrackingLaw` over the paths (`paths_law`), the inner box empty."""
        return cls(tracks.X, tracks.U, tracks.K, tracks.weight, tracks.x_star, np.asarray(scale, dtype=np.float64), tracks.effort,
                   tracks.angle_mask, np.zeros(len(tracks.x_star)))

    @classmethod
    def from_paths(cls, system, X: np.ndarray, U: np.ndarray, speed_weight: float, every: int = 1, inner: float = 0.0) -> "LibraryLaw | None":
        """The law of whole paths X (P, L, n), U (P, L, m) sampled every knot (`paths_law`, momenta
        weighted `speed_weight` / M_ii(q*)), thinned for the exported controller's brute-force search:
        the points inside the inner box `inner`·s dropped (the IDA-PBC law's there) and of the others
        every `every`-th kept; the inner box left empty for the gate to choose. None where no point is left."""
        lo, hi = (np.asarray(b, dtype=np.float64) for b in system.domain)
        law = cls.from_tracks(paths_law(system, X, U, speed_weight, np.full(system.n, np.inf)), 0.5 * (hi - lo)).with_inner(inner)
        keep = np.flatnonzero(law.outside(law.X))[::every]
        return None if not keep.size else replace(law, X=law.X[keep], U=law.U[keep], K=law.K[keep], inner=np.zeros(system.n))

    @cached_property
    def _tracks(self) -> TrackingLaw:
        return TrackingLaw(self.X, self.U, self.K, self.weight, self.x_star, self.effort, self.angle_mask, np.zeros(len(self.x_star)))

    @property
    def points(self) -> int:
        """How many path points the law reads."""
        return len(self.X)

    def law(self, x, u=None) -> np.ndarray:
        """The library alone: (N, n) -> (N, m), within ±ū (u is not read)."""
        return self._tracks.law(x)

    def arrays(self) -> dict:
        """The law as named arrays (recovery.npz of a run): X, U, K, weight, x_star, scale, effort,
        angle_mask, inner, and level when it is finite."""
        out = {k: np.asarray(getattr(self, k)) for k in (*_PATH_FIELDS, "x_star", "scale", "effort", "angle_mask", "inner")}
        return out | ({"level": np.asarray(self.level)} if self.uses_level else {})

    @classmethod
    def from_arrays(cls, arrays) -> "LibraryLaw":
        """Inverse of `arrays` (a dict or an open .npz); raises ValueError when a piece is missing,
        misshapen or not finite."""
        try:
            X, U, K, weight, x_star, scale, effort, inner = (np.asarray(arrays[k], dtype=np.float64)
                                                             for k in (*_PATH_FIELDS, "x_star", "scale", "effort", "inner"))
            mask = np.asarray(arrays["angle_mask"], dtype=bool)
        except KeyError as err:
            raise ValueError(f"the recovery library has no {err.args[0]!r}") from None
        level = float(np.asarray(arrays["level"], dtype=np.float64)) if "level" in arrays else math.inf
        P, n = X.shape if X.ndim == 2 else (0, 0)
        m = len(effort)
        if P < 1 or U.shape != (P, m) or K.shape != (P, m, n) or any(a.shape != (n,) for a in (weight, x_star, scale, mask, inner)):
            raise ValueError("the recovery library's arrays do not fit together")
        if not all(np.isfinite(a).all() for a in (X, U, K, weight, x_star, scale, effort, inner)) or not (scale > 0).all() or math.isnan(level):
            raise ValueError("the recovery library has non-finite arrays or scales")
        return cls(X, U, K, weight, x_star, scale, effort, mask, inner, level)


def recovery_law_from_arrays(arrays):
    """A run's recovery law from its arrays (a dict or an open .npz): a `LibraryLaw` where they hold
    paths ("X"), else a fitted `RecoveryLaw`; raises ValueError as theirs do."""
    return (LibraryLaw if "X" in arrays else RecoveryLaw).from_arrays(arrays)
