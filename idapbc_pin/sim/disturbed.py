"""Closed loop with what a real robot adds: late and noisy measurements, a slow and noisy actuator,
pushes, friction and a plant that is not the model. Each row of the batch has its own.

One control tick of dt (the law held over it, RK4 on the true plant), in the order of the RealAIGym
simulator (github.com/dfki-ric-underactuated-lab/double_pendulum, ``simulation.py``; written
independently from its description):

1. measure: the state `delay` ticks ago (the start state before the first), speeds plus
   N(0, σ_v²) noise; the law sees x = (q, M_model(q) v) of what it measured;
2. command u_d = law(x);
3. actuate: u = u_prev + k (u_d − u_prev) (the responsiveness k; 1 is an ideal actuator), plus
   N(0, σ_τ²) noise, clipped to the effort limits; u_prev ← u;
4. push: τ = B u + w(t), w the row's pulses, added after the clip, on every joint;
5. integrate the row's own plant (`idapbc_pin.model.variations.RowPlants`: its model, damping and
   Coulomb friction) over dt with τ held.

A row that blows up (non-finite, or beyond `DIVERGENCE_BOUND`) is frozen and flagged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .integrate import DIVERGENCE_BOUND
from .limits import input_limits
from .metrics import rail_limits

__all__ = ["Disturbances", "Ending", "actuate", "pulse_torques", "simulate_disturbed"]


@dataclass(frozen=True, eq=False)
class Disturbances:
    """What each of N rows adds to the nominal loop (module docstring).

    speed_noise : (N,) σ_v of the measured speeds (rad/s or m/s).
    torque_noise : (N,) σ_τ of the actuated inputs (N·m or N).
    lag : (N,) responsiveness k of the actuator (1: ideal).
    delay : (N,) int, measurement delay in control ticks.
    pulses : (N, nv, P, 3) Gaussian torque pulses per joint: centre (s), width σ (s), amplitude (N·m
        or N); amplitude 0 where a row has fewer.
    """

    speed_noise: np.ndarray
    torque_noise: np.ndarray
    lag: np.ndarray
    delay: np.ndarray
    pulses: np.ndarray

    @classmethod
    def none(cls, N: int, nv: int) -> "Disturbances":
        """N rows with nothing added."""
        return cls(np.zeros(N), np.zeros(N), np.ones(N), np.zeros(N, int), np.zeros((N, nv, 0, 3)))

    @staticmethod
    def stack(parts: list["Disturbances"]) -> "Disturbances":
        """The rows of several batches, one after another (pulses padded to the most per joint)."""
        P = max(p.pulses.shape[2] for p in parts)
        pad = [np.pad(p.pulses, ((0, 0), (0, 0), (0, P - p.pulses.shape[2]), (0, 0))) for p in parts]
        return Disturbances(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("speed_noise", "torque_noise", "lag", "delay")),
                            np.concatenate(pad))


def pulse_torques(pulses: np.ndarray, t: float) -> np.ndarray:
    """Σ_p A exp(−(t − μ)²/(2σ²)) at time t (s): (N, nv, P, 3) -> (N, nv)."""
    if pulses.shape[2] == 0:
        return np.zeros(pulses.shape[:2])
    mu, sigma, amp = pulses[..., 0], pulses[..., 1], pulses[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = amp * np.exp(-0.5 * ((t - mu) / np.where(sigma > 0, sigma, 1.0)) ** 2)
    return np.where(amp != 0, w, 0.0).sum(axis=2)


def actuate(u_prev: np.ndarray, u_cmd: np.ndarray, lag, noise, bound) -> np.ndarray:
    """The torque an actuator applies for a command: u_prev + k (u_cmd − u_prev) + noise, clipped to
    ±bound ((m,) or None); a non-finite command counts as 0. (N, m) arrays; k (N, 1) or scalar."""
    u_cmd = np.where(np.isfinite(u_cmd), u_cmd, 0.0)
    u = u_prev + lag * (u_cmd - u_prev) + noise
    return u if bound is None else np.clip(u, -bound, bound)


@dataclass(frozen=True, eq=False)
class Ending:
    """Where each row ends: q, v (N, nq) at T, diverged (N,) and on_rail (N,) (every prismatic
    coordinate within its URDF limits throughout)."""

    q: np.ndarray
    v: np.ndarray
    diverged: np.ndarray
    on_rail: np.ndarray


def simulate_disturbed(system, plants, law, x0: np.ndarray, dist: Disturbances, T: float, dt: float, seed: int = 0,
                       limits: bool = True) -> Ending:
    """Run `law` ((N, n) -> (N, m), one call per tick) on the rows of `plants` (`RowPlants`) from
    x0 (N, n) for round(T/dt) ticks, each row with its `dist` (module docstring). `system` is the
    law's model (its B, effort limits, momenta). The noise comes from one generator seeded `seed`:
    the same draws for every law judged on the same rows (a law with a speed filter:
    `idapbc_pin.control.speed_filter.FilteredLaw`)."""
    x0 = np.asarray(x0, float)
    N, nq = x0.shape[0], system.nq
    B = np.asarray(system.B, float)
    bound = input_limits(system, limits)
    hi = None if bound.bound is None else np.asarray(bound.bound, float)
    rng = np.random.default_rng(seed)
    q, v = system.split(x0)
    q, v = np.array(q, float), np.array(v, float)
    lower, upper = rail_limits(system)
    on_rail = ((q >= lower) & (q <= upper)).all(axis=1)
    K = int(round(T / dt))
    depth = int(dist.delay.max(initial=0)) + 1
    past_q, past_v = np.repeat(q[None], depth, axis=0), np.repeat(v[None], depth, axis=0)  # ring buffer of the measured states
    rows = np.arange(N)
    u_prev = np.zeros((N, system.m))
    bad = np.zeros(N, bool)
    sig_v, sig_u, lag = dist.speed_noise[:, None], dist.torque_noise[:, None], dist.lag[:, None]
    noisy_v, noisy_u = bool(np.any(dist.speed_noise > 0)), bool(np.any(dist.torque_noise > 0))

    for k in range(K):
        slot = k % depth
        past_q[slot], past_v[slot] = q, v
        back = (k - np.minimum(dist.delay, k)) % depth
        qm, vm = past_q[back, rows], past_v[back, rows]
        if noisy_v:
            vm = vm + sig_v * rng.standard_normal(vm.shape)
        u = np.asarray(law(system.state_from(qm, vm)), float).reshape(N, system.m)
        noise = sig_u * rng.standard_normal(u.shape) if noisy_u else 0.0
        u = u_prev = actuate(u_prev, u, lag, noise, hi)
        tau = u @ B.T + pulse_torques(dist.pulses, k * dt)
        k1q, k1v = v, plants.accel(q, v, tau)
        k2q, k2v = v + 0.5 * dt * k1v, plants.accel(q + 0.5 * dt * k1q, v + 0.5 * dt * k1v, tau)
        k3q, k3v = v + 0.5 * dt * k2v, plants.accel(q + 0.5 * dt * k2q, v + 0.5 * dt * k2v, tau)
        k4q, k4v = v + dt * k3v, plants.accel(q + dt * k3q, v + dt * k3v, tau)
        qn = q + (dt / 6.0) * (k1q + 2 * k2q + 2 * k3q + k4q)
        vn = v + (dt / 6.0) * (k1v + 2 * k2v + 2 * k3v + k4v)
        blown = ~(np.isfinite(qn).all(axis=1) & np.isfinite(vn).all(axis=1)
                  & (np.abs(qn) <= DIVERGENCE_BOUND).all(axis=1) & (np.abs(vn) <= DIVERGENCE_BOUND).all(axis=1))
        bad |= blown
        q, v = np.where(bad[:, None], q, qn), np.where(bad[:, None], v, vn)
        on_rail &= ((q >= lower) & (q <= upper)).all(axis=1)
    return Ending(q=q, v=v, diverged=bad, on_rail=on_rail)
