"""`Trajectory`: a batch of closed-loop rollouts sampled at common times (what `simulate` returns)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory"]


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A batch of closed-loop trajectories sampled at common times.

    Attributes
    ----------
    t : (T_k,) sample times, s (t[0] = 0, t[-1] = T).
    x : (N, T_k, n) states (q, p), p = M(q) v.
    q : (N, T_k, nq) positions, rad or m (a view of ``x[..., :nq]``).
    v : (N, T_k, nq) velocities, rad/s or m/s.
    u : (N, T_k, m) applied inputs (after saturation), N·m or N.
    diverged : (N,) bool; a diverged row is frozen at its last finite state within the bound
        (state and input then repeat that last value).
    converged : (N,) bool or None; a converged row stopped inside the loop's terminal set
        (`idapbc_pin.sim.terminal`), where it stays in the success box and tends to x*; its state
        and input then repeat the sample where it stopped.
    """

    t: np.ndarray
    x: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    diverged: np.ndarray
    converged: np.ndarray | None = None

    @property
    def n_states(self) -> int:
        """Number of trajectories N."""
        return int(self.x.shape[0])
