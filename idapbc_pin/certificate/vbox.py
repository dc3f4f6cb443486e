"""Where a certified set is looked for, and how it is sampled.

A certified set {V < c} (V = H_d, or LQR's δᵀSδ) must keep its trajectories, so it cannot be judged
inside the training box X alone: most trajectories of the basin swing out of X and back
(docs/method.md §7). It is looked for in a **verification box** V_box ⊇ X
(`idapbc_pin.model.boxes.verification_box`, re-exported here; ``certify --scale`` and
``--verification-box`` override it).

The sampled statement needs i.i.d. uniform samples of the set: they are drawn by rejection from a
parallelepiped that holds the (convex) set, checked face by face (`set_frame`), so that a set far
smaller than V_box still gets its `zero_failure_samples` at a reasonable cost.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np
from tqdm.auto import tqdm

from ..errors import IdapbcError
from ..model.boxes import DEFAULT_SCALE, verification_box
from .checks import boundary_min, face_samples
from .terms import _f64, hessians

__all__ = ["DEFAULT_SCALE", "SetFrame", "radial_boundary", "sample_set", "set_frame", "verification_box", "zero_failure_samples"]


def zero_failure_samples(epsilon: float, beta: float) -> int:
    """N = ⌈ln(1/β)/ε⌉: if N i.i.d. samples of a set, drawn after the set is fixed, all pass a test,
    the share of the set where it fails is ≤ ε with confidence ≥ 1 − β, since (1 − ε)^N ≤ e^{−εN} ≤ β
    (the zero-failure sampling bound; Tempo, Bai & Dabbene, Systems & Control Letters 1997)."""
    if not (0 < epsilon < 1 and 0 < beta < 1):
        raise IdapbcError(f"epsilon and beta must lie in (0, 1), got {epsilon} and {beta}. Fix: e.g. epsilon 1e-3, beta 1e-6.")
    return int(math.ceil(math.log(1.0 / beta) / epsilon))


class _Whitened:
    """V in coordinates z with x = x* + T z (T = L⁻ᵀ, P = LLᵀ = ∇²V(x*)): ½zᵀz is V's quadratic part."""

    def __init__(self, fn, x_star, T):
        self.fn, self.x_star, self.T = fn, x_star, T

    def x(self, z) -> np.ndarray:
        return self.x_star + np.atleast_2d(z) @ self.T.T

    def H_d(self, z) -> np.ndarray:
        return _f64(self.fn.H_d(self.x(z))).ravel()

    def grad_H_d(self, z) -> np.ndarray:
        return _f64(self.fn.grad_H_d(self.x(z))).reshape(np.atleast_2d(z).shape) @ self.T


@dataclass(frozen=True, eq=False)
class SetFrame:
    """A parallelepiped x* + T·[zlo, zhi] that holds the set {V < c}: uniform samples of it are
    uniform in x (T is linear), and it fits an elongated set far better than an axis-aligned box.

    x_star : (n,).  T : (n, n).  zlo, zhi : (n,).
    """

    x_star: np.ndarray
    T: np.ndarray
    zlo: np.ndarray
    zhi: np.ndarray

    @property
    def volume(self) -> float:
        """Its volume in x (units of the state)."""
        return float(np.prod(self.zhi - self.zlo) * abs(np.linalg.det(self.T)))

    def sample(self, rng, k: int) -> np.ndarray:
        """(k, n) uniform samples."""
        z = self.zlo + (self.zhi - self.zlo) * rng.random((int(k), self.zlo.size))
        return self.x_star + z @ self.T.T


def _whitening(fn, x_star, lo, hi) -> np.ndarray:
    """T = L⁻ᵀ with P = LLᵀ = ∇²V(x*); the box's own scaling where P is not positive definite."""
    try:
        P = hessians(fn, x_star[None])[0][0]
        return np.linalg.inv(np.linalg.cholesky(0.5 * (P + P.T))).T
    except np.linalg.LinAlgError:
        return np.diag(hi - lo)


def radial_boundary(fn, c: float, directions, t_max, iters: int = 40) -> np.ndarray:
    """(K, n) the point where the ray t·d (t ∈ [0, t_max]) leaves {V < c}, for each direction d of
    `directions` (K, n), by bisection on t (one batched evaluation of V per step)."""
    d = _f64(directions)
    t_lo, t_hi = np.zeros(d.shape[0]), np.full(d.shape[0], float(t_max))
    for _ in range(iters):
        t = 0.5 * (t_lo + t_hi)
        inside = _f64(fn.H_d(t[:, None] * d)).ravel() < c
        t_lo, t_hi = np.where(inside, t, t_lo), np.where(inside, t_hi, t)
    return t_hi[:, None] * d


def set_frame(fn, c: float, x_star, lo, hi, rng, per_face: int = 64, n_rays: int = 512) -> SetFrame:
    """A `SetFrame` that holds {V < c}, for a convex V with its minimum at x* whose set lies in [lo, hi].

    In whitened coordinates z (½zᵀz the quadratic part of V), the set's extent is estimated from
    where 2n + `n_rays` rays from x* leave it (`radial_boundary`), widened by 20 %. Each face is then
    checked: the minimum of V on it (`boundary_min`, sampled and refined) must be ≥ c, else the face
    moves out 2× (at most 6 times; then the frame is the one holding [lo, hi]). V convex, the set
    cannot reach past faces that pass.
    """
    x_star, lo, hi = _f64(x_star), _f64(lo), _f64(hi)
    n = x_star.size
    T = _whitening(fn, x_star, lo, hi)
    wfn = _Whitened(fn, x_star, T)
    corners = (lo - x_star) + (hi - lo) * ((np.arange(2 ** n)[:, None] >> np.arange(n)) & 1)
    z_corners = np.linalg.solve(T, corners.T).T
    z_max = float(np.abs(z_corners).max())
    d = np.concatenate([np.eye(n), -np.eye(n), rng.standard_normal((n_rays, n))])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = radial_boundary(wfn, c, d, z_max)
    zlo, zhi = np.minimum(pts.min(axis=0), 0.0), np.maximum(pts.max(axis=0), 0.0)
    pad = 0.2 * (zhi - zlo) + 1e-12
    zlo, zhi = zlo - pad, zhi + pad
    for _ in range(6):
        low = [(i, side) for i, side, pts in face_samples(zlo, zhi, per_face, rng)
               if boundary_min(wfn, zlo, zhi, [(i, side, pts)])[0] < c]
        if not low:
            return SetFrame(x_star, T, zlo, zhi)
        for i, side in low:
            if side == zlo[i]:
                zlo[i] *= 2.0
            else:
                zhi[i] *= 2.0
    return SetFrame(x_star, T, z_corners.min(axis=0), z_corners.max(axis=0))


#: Seconds before `sample_set` shows its bar: quick searches print nothing.
BAR_DELAY = 2.0


def sample_set(fn, c: float, frame: SetFrame, n: int, rng, chunk: int = 20000, max_draws: int = 20_000_000) -> tuple[np.ndarray, int]:
    """At least `n` i.i.d. uniform samples of {V < c} by rejection from the `frame` that holds it.

    Frame samples are drawn `chunk` at a time and every hit is kept. Returns (x (k, dim), draws):
    k ≥ n unless `max_draws` frame samples ran out first (a set that small leaves k < n); draws
    counts every frame sample, so vol(set) ≈ frame.volume·k/draws. A search that lasts more than
    `BAR_DELAY` s shows a bar of the samples kept, with its ETA (a thin set in a wide frame, as on
    long chains, takes minutes).
    """
    kept, k, draws = [], 0, 0
    with tqdm(total=n, desc="certify: samples of {V < c}", unit="sample", delay=BAR_DELAY, dynamic_ncols=True, file=sys.stderr) as bar:
        while k < n and draws < max_draws:
            x = frame.sample(rng, chunk)
            draws += chunk
            x = x[_f64(fn.H_d(x)).ravel() < c]
            kept.append(x)
            bar.update(min(x.shape[0], n - k))
            bar.set_postfix(draws=f"{draws:.3g}", refresh=False)
            k += x.shape[0]
    return (np.concatenate(kept) if kept else np.empty((0, frame.zlo.size))), draws
