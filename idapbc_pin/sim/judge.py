"""The judge: the true plant a controller is simulated on, in (q, v), batched.

URDF robots are judged by Pinocchio's own forward dynamics (pooled ABA, plus joint damping), the
paper's analytic systems by their closed form: the model a controller was trained on never judges
it (STYLE §6). The judge asks the system, which asks its `Plant`; it never checks which kind.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DEFAULT_THREADS", "Judge"]

#: Threads for Pinocchio's ``abaInParallel`` / ``rneaInParallel``. One: on a loaded machine OpenMP
#: threads slow the pooled calls down several-fold, and on an idle one they gain at most their count.
DEFAULT_THREADS = 1


class Judge:
    """The true plant in (q, v), batched: accelerations and states.

    system : a `System` (or any object with ``nq``, ``B``, ``forward_dynamics(q, v, tau)`` and
        ``state_from(q, v)``); threads : Pinocchio threads (more than one is passed on as
        ``threads=`` to ``forward_dynamics``).
    """

    def __init__(self, system, threads: int | None = None):
        self.system = system
        self.nq = int(system.nq)
        self.B = np.asarray(system.B, float)
        self.threads = int(threads or DEFAULT_THREADS)
        self._kw = {} if self.threads == 1 else {"threads": self.threads}
        # A `System`'s own plant, called with the (N, nq) float arrays the integrator holds, spares the
        # System's shape checks at every RK4 stage; any other object is asked through its methods.
        self._plant = getattr(system, "plant", None)
        self._dynamics = system if self._plant is None else self._plant

    def accel(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """v̇ of the true plant: (N, nq) ×3 -> (N, nq), tau on every joint."""
        if q.shape[0] == 0:
            return np.zeros_like(q)
        return np.asarray(self._dynamics.forward_dynamics(q, v, tau, **self._kw), float).reshape(q.shape)

    def state(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """x = (q, M(q) v): (N, nq) ×2 -> (N, n)."""
        if q.shape[0] == 0:
            return np.zeros((0, 2 * self.nq))
        if self._plant is not None:
            return np.concatenate([q, self._plant.momenta(q, v, **self._kw)], axis=1)
        return np.asarray(self.system.state_from(q, v), float).reshape(q.shape[0], 2 * self.nq)
