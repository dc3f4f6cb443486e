"""A swing-up law that tracks a planned trajectory from the state alone: `TrackingLaw`.

A torque plan from the resting posture to x* (`trajectory.tracks`) is a nominal trajectory of
states X_k and inputs U_k, k = 0 … P − 1, with the gains K_k of a time-varying LQR along it. Tracked
in time, it needs a clock started at the swing-up's beginning. This law needs none: it reads the
nominal point nearest to the state,

    k(x) = argmin_k ‖W wrap(x − X_k)‖²,      u(x) = clip(U_k + K_k wrap(x − X_k), ±ū)   (k = k(x)),

with W = diag(weight), and the run's law inside the kept box, as `SwingUpLaw` (`kept_box`). A
finite `funnel` ϱ bounds where the law acts to the states within ϱ of the nominal, ‖W wrap(x −
X_k(x))‖ ≤ ϱ: a time-varying LQR is valid near its path only, and beyond ϱ the run's law keeps
control (a state of the box whose own path swings far out is not taken over by a plan it is nowhere
near). Every
array is in the run's coordinates x = (q, p), so the law needs no model of the robot. It is a state
feedback like the others: `Controller`, `simulate` and `export` treat it as any outer law. Where the
nominal passes close to itself at different times the nearest point may be the wrong one: the stage
keeps such a law only where its gate says it holds swing-ups.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from .._memo import last_call
from ..model.angles import wrap_angles
from .kept_box import KeptBoxLaw

__all__ = ["TrackingLaw"]

#: Nominal points from which `TrackingLaw.nearest` searches a k-d tree instead of every point.
_TREE_FROM = 256


def _brute_nearest(x: np.ndarray, X: np.ndarray, weight: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N,) argmin_k ‖W wrap(x − X_k)‖² over every point (what the export computes)."""
    d = wrap_angles(x[:, None, :] - X[None], mask)
    return np.argmin(((d * weight) ** 2).sum(axis=-1), axis=1)


class _TorusTree:
    """The same nearest point from a k-d tree on the torus (`scipy.spatial.cKDTree` with periodic
    boxes): each angle a circle of length 2π·w, each other coordinate (scaled by w) on a circle so
    long that no two points that matter are half of it apart. States beyond a quarter of that length
    (beyond ±`_FAR` times the nominal's spread) are clipped to it."""

    _FAR = 1e4

    def __init__(self, X: np.ndarray, weight: np.ndarray, mask: np.ndarray):
        from scipy.spatial import cKDTree

        self.weight, self.mask = np.asarray(weight, float), np.asarray(mask, bool)
        span = np.abs(X * self.weight).max(axis=0) + 1.0
        self.half = np.where(self.mask, np.pi * self.weight, 2.0 * self._FAR * span)  # half of each circle
        self.half = np.where(self.half > 0, self.half, 1.0)
        self.tree = cKDTree(self._embed(X), boxsize=2.0 * self.half)

    def _embed(self, x: np.ndarray) -> np.ndarray:
        y = np.where(self.mask, x * self.weight, np.clip(x * self.weight, -0.5 * self.half, 0.5 * self.half))
        y = np.mod(y + self.half, 2.0 * self.half)
        return np.where(y >= 2.0 * self.half, 0.0, y)

    def nearest(self, x: np.ndarray) -> np.ndarray:
        return self.tree.query(self._embed(x), k=1)[1]

_FIELDS = ("X", "U", "K", "weight", "x_star", "effort", "angle_mask", "box", "funnel")


@dataclass(frozen=True, eq=False)
class TrackingLaw(KeptBoxLaw):
    """A nominal trajectory with its feedback gains, read at the nearest point.

    Attributes
    ----------
    X : (P, n) nominal states (q, p).
    U : (P, m) nominal inputs, N·m or N.
    K : (P, m, n) feedback gains on wrap(x − X_k).
    weight : (n,) weights of the distance that picks the nearest point (1/rad, 1/m, 1/(kg·m²/s), …).
    x_star : (n,) target state. effort : (m,) ū, the effort limits (finite).
    angle_mask : (n,) bool, components wrapped to within π (angles of q).
    box : (n,) half-widths of the kept box, where the run's law keeps control (∞: not read).
    inner : the run's own outer law applied first, or None.
    funnel : ϱ, the largest distance ‖W wrap(x − X_k)‖ to the nearest point at which the law acts
        (beyond it the run's law, as in the kept box); ∞: everywhere outside the kept box.
    """

    X: np.ndarray
    U: np.ndarray
    K: np.ndarray
    weight: np.ndarray
    x_star: np.ndarray
    effort: np.ndarray
    angle_mask: np.ndarray
    box: np.ndarray
    inner: object = None
    funnel: float = float("inf")

    @cached_property
    def _tree(self) -> "_TorusTree":
        return _TorusTree(self.X, self.weight, self.angle_mask)

    def nearest(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(k (N,) the index of the nearest nominal point, wrap(x − X_k) (N, n)) for states x (N, n)."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        k = self._tree.nearest(x) if len(self.X) >= _TREE_FROM else _brute_nearest(x, self.X, self.weight, self.angle_mask)
        return k, wrap_angles(x - self.X[k], self.angle_mask)

    @last_call
    def outside(self, x) -> np.ndarray:
        """(..., n) -> (...) bool: True where the law acts: outside the kept box, and within the funnel."""
        out = super().outside(x)
        if np.isfinite(self.funnel) and out.any():
            flat = out.reshape(-1)
            _, d = self.nearest(np.asarray(x, dtype=np.float64).reshape(-1, self.X.shape[1])[flat])
            flat[flat] = ((d * self.weight) ** 2).sum(axis=-1) <= self.funnel ** 2
            out = flat.reshape(out.shape)
        return out

    def with_funnel(self, funnel: float) -> "TrackingLaw":
        """The same law acting only within `funnel` of its nominal (∞: wherever outside the kept box)."""
        return replace(self, funnel=float(funnel))

    def law(self, x) -> np.ndarray:
        """The tracking law alone: (N, n) -> (N, m), within ±ū."""
        k, d = self.nearest(x)
        return np.clip(self.U[k] + np.einsum("nij,nj->ni", self.K[k], d), -self.effort, self.effort)

    @classmethod
    def join(cls, laws: list["TrackingLaw"]) -> "TrackingLaw":
        """One law over every knot of `laws` (same system), read with the first's distance weights and
        kept box, around no inner law."""
        first = laws[0]
        return cls(np.concatenate([t.X for t in laws]), np.concatenate([t.U for t in laws]), np.concatenate([t.K for t in laws]),
                   first.weight, first.x_star, first.effort, first.angle_mask, first.box)

    def arrays(self) -> dict:
        """The law as named arrays (swingup.npz of a run, without `inner`): X, U, K, weight, x_star,
        effort, angle_mask, box, funnel."""
        return {k: np.asarray(getattr(self, k)) for k in _FIELDS}

    @classmethod
    def from_arrays(cls, arrays, inner=None) -> "TrackingLaw":
        """Inverse of `arrays` (a dict or an open .npz) around `inner`; raises ValueError when a piece is
        missing, misshapen or not finite."""
        try:
            X, U, K, weight, x_star, effort, box = (np.asarray(arrays[k], dtype=np.float64) for k in ("X", "U", "K", "weight", "x_star", "effort", "box"))
            mask = np.asarray(arrays["angle_mask"], dtype=bool)
            funnel = float(np.asarray(arrays["funnel"])) if "funnel" in arrays else float("inf")  # laws saved before it: none
        except KeyError as err:
            raise ValueError(f"the tracking law has no {err.args[0]!r}") from None
        P, n = X.shape if X.ndim == 2 else (0, 0)
        m = len(effort)
        if P < 1 or U.shape != (P, m) or K.shape != (P, m, n) or any(a.shape != (n,) for a in (weight, x_star, mask, box)):
            raise ValueError("the tracking law's arrays do not fit together")
        if not all(np.isfinite(a).all() for a in (X, U, K, weight, x_star, effort)) or not (box >= 0).all() or not (weight >= 0).all():
            raise ValueError("the tracking law has non-finite arrays, or negative weights or box half-widths")
        if not funnel > 0:
            raise ValueError("the tracking law's funnel must be positive")
        return cls(X, U, K, weight, x_star, effort, mask, box, inner, funnel)

    def to_json(self) -> dict:
        """controller.json's "fallback" of an export (kind "swing_up", with the nominal "X"): every
        array as lists (an unread component of the kept box as null), and the run's own outer law it
        wraps as "wraps" (None: the networks alone)."""
        out = {k: np.asarray(v).tolist() for k, v in self.arrays().items()}
        out["box"] = [float(b) if np.isfinite(b) else None for b in self.box]
        out["funnel"] = float(self.funnel) if np.isfinite(self.funnel) else None
        return {"kind": "swing_up"} | out | {"wraps": None if self.inner is None else self.inner.to_json()}
