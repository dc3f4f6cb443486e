"""`SpeedFilter`: joint speeds estimated from noisy measurements, batched, in plain numpy.

A robot's speeds are differentiated from its encoders and come noisy, while the positions are
precise. Each joint's (q, v) is taken as a double integrator driven by white acceleration noise and
measured with noise on both:

    x_{k+1} = F x_k + G a_k,   F = [[1, dt], [0, 1]],   G = (dt²/2, dt),   a_k ~ N(0, σ_a²)
    z_k = x_k + n_k,           n_k ~ N(0, diag(σ_q², σ_v²))

and filtered by the steady-state Kalman filter of that model: x̂⁻ = F x̂, x̂ = x̂⁻ + K (z − x̂⁻), with
the 2×2 gain K of the discrete Riccati equation (solved once, by iteration). The law then runs on
(q, v̂): ``u = law(q, filter.update(q, v))`` at every control tick. The filter keeps its state
between calls (one instance per robot, or per batch of N robots); `torque(q, v)` stays stateless.
`FilteredLaw` wraps a law in state coordinates x = (q, p) the same way, for the simulators.

The defaults assume encoder positions precise to about 1e-4 rad (a 14-bit encoder) and speeds as
noisy as the robustness suite's worst level (σ_v = 0.5 rad/s); with coarser encoders, raise
`position_noise`. This file is copied verbatim into an export (numpy only).
"""

from __future__ import annotations

import numpy as np

__all__ = ["FilteredLaw", "SpeedFilter", "kalman_gain"]


def kalman_gain(dt: float, position_noise: float, speed_noise: float, acceleration: float, iterations: int = 100_000) -> np.ndarray:
    """(2, 2) steady-state Kalman gain of one joint (module docstring): dt (s), σ_q (rad or m),
    σ_v (rad/s or m/s), σ_a (rad/s² or m/s²)."""
    if not (dt > 0 and position_noise > 0 and speed_noise > 0 and acceleration > 0):
        raise ValueError(f"the filter needs dt, σ_q, σ_v and σ_a > 0, got {dt}, {position_noise}, {speed_noise}, {acceleration}")
    F = np.array([[1.0, dt], [0.0, 1.0]])
    G = np.array([[0.5 * dt * dt], [dt]])
    Q = (acceleration**2) * (G @ G.T)
    R = np.diag([position_noise**2, speed_noise**2])
    P = Q + R  # the predicted covariance, iterated to its fixed point
    for _ in range(int(iterations)):
        K = P @ np.linalg.inv(P + R)
        P_next = F @ ((np.eye(2) - K) @ P) @ F.T + Q
        if np.allclose(P_next, P, rtol=1e-13, atol=0.0):
            P = P_next
            break
        P = P_next
    return P @ np.linalg.inv(P + R)


class SpeedFilter:
    """Steady-state Kalman filter of every joint's speed (module docstring), batched over N robots.

    Parameters
    ----------
    dt : control period, s (one `update` per tick).
    position_noise : σ_q the filter assumes for the measured positions (rad or m).
    speed_noise : σ_v it assumes for the measured speeds (rad/s or m/s).
    acceleration : σ_a, the accelerations it expects (rad/s² or m/s²): larger follows faster, smaller smooths more.
    """

    def __init__(self, dt: float = 0.002, position_noise: float = 1e-4, speed_noise: float = 0.5, acceleration: float = 300.0):
        self.dt = float(dt)
        self.settings = {"position_noise": float(position_noise), "speed_noise": float(speed_noise), "acceleration": float(acceleration)}
        self.K = kalman_gain(self.dt, **self.settings)
        self.q_hat = self.v_hat = None

    def reset(self) -> None:
        """Forget the state: the next `update` starts from its measurement."""
        self.q_hat = self.v_hat = None

    def update(self, q, v) -> np.ndarray:
        """One tick: measured q, v (N, nq) or (nq,) -> the filtered speeds v̂ of the same shape."""
        q, v = np.asarray(q, np.float64), np.asarray(v, np.float64)
        single = q.ndim == 1
        q, v = np.atleast_2d(q), np.atleast_2d(v)
        if self.q_hat is None or self.q_hat.shape != q.shape:
            self.q_hat, self.v_hat = q.copy(), v.copy()
            return v[0].copy() if single else v.copy()
        q_pred = self.q_hat + self.dt * self.v_hat
        v_pred = self.v_hat
        dq, dv = q - q_pred, v - v_pred
        K = self.K
        self.q_hat = q_pred + K[0, 0] * dq + K[0, 1] * dv
        self.v_hat = v_pred + K[1, 0] * dq + K[1, 1] * dv
        return self.v_hat[0].copy() if single else self.v_hat.copy()

    def to_json(self) -> dict:
        """The settings and dt (controller.json's "speed_filter" of an export)."""
        return {"dt": self.dt} | self.settings


class FilteredLaw:
    """A law in x = (q, p) run on filtered speeds: x -> (q, v) -> (q, `SpeedFilter.update`(q, v)) ->
    law(q, M(q) v̂). Stateful like its filter: call it once per control tick (as the simulators
    call a law held over each step), a fresh instance per rollout batch; picklable.

    law : (N, n) -> (N, m).  system : anything with ``split(x) -> (q, v)`` and ``state_from(q, v)``.
    speed_filter : a fresh `SpeedFilter`.
    """

    def __init__(self, law, system, speed_filter: SpeedFilter):
        self.law, self.system, self.speed_filter = law, system, speed_filter

    def __call__(self, x):
        q, v = self.system.split(x)
        return self.law(self.system.state_from(q, self.speed_filter.update(q, v)))
