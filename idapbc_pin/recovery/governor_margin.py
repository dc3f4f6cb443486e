"""The governor's energy margin that leaves a kept law's own catches alone: `catch_margin`.

A recovery law fitted to torque plans may catch a state at the training box's edge by swinging the
links through more energy than the upright holds (a cart double pendulum's poles: their energy
E_g peaks at several ΔE above E* on the way). The speed and energy governor
(`control.speed_governor`) brakes above E* + `ENERGY_MARGIN`·ΔE, so it may fight those catches.
Where it costs the kept law more than `LOSS` of the training-box states that law brings to x*
without it, the recovery stage raises the run's margin to the peak excess of E_g along those
catches: the energy clause then acts only beyond what the law does from its own box (a whirl after a
release or a push), and the speed clause still holds every joint to its rating. Where the governor
costs nothing there, the margin stays `ENERGY_MARGIN`.
"""

from __future__ import annotations

import math

import numpy as np

from .._parallel import process_map
from ..control.speed_governor import ENERGY_MARGIN, SpeedGovernor
from ..sim.integrate import simulate
from ..sim.metrics import success
from ..sim.states import uniform_states

__all__ = ["CATCH_STATES", "CATCH_T", "LOSS", "catch_margin"]

#: Training-box states (uniform, the run's seed) simulated for the margin ...
CATCH_STATES = 100
#: ... for this long (s): the success window's 2 s after the catch.
CATCH_T = 10.0
#: States the governor may cost the law before the margin is raised (the recovery gate's margin).
LOSS = 3


def _catches(job) -> tuple[np.ndarray, np.ndarray]:
    """(caught (N,) bool, peak (N,) of (E_g − E*)/ΔE along each rollout) of one law from x0."""
    governor, law, x0, T = job
    system = governor.system
    traj = simulate(system, law, x0, T=T)
    e_g = governor.energy(traj.x.reshape(-1, system.n))[0].reshape(len(x0), -1)
    return success(traj, system), ((e_g - governor.e_star) / governor.delta_e).max(axis=1)


def catch_margin(system, law, n: int = CATCH_STATES, seed: int = 0, T: float = CATCH_T, workers: int = 1) -> float:
    """The energy clause's margin (ΔE above E*) for `law`, a `Controller` with its governor: from `n`
    uniform training-box states, `ENERGY_MARGIN` where the law governed brings at most `LOSS` fewer
    of them to x* than without its governor; else the largest (E_g − E*)/ΔE along the rollouts that
    reach x* without it, rounded up to 0.01. `ENERGY_MARGIN` too where the robot has no energy
    clause (no governor, or ΔE ≤ 0). `workers`: processes for the two simulations (the time only)."""
    governor = SpeedGovernor.of(system)
    if governor is None or governor.delta_e <= 0:
        return ENERGY_MARGIN
    x0 = uniform_states(system, n, "domain", seed)
    (caught, peak), (governed, _) = process_map(_catches, [(governor, law.with_governor(False), x0, T), (governor, law, x0, T)], workers)
    if int(governed.sum()) >= int(caught.sum()) - LOSS:
        return ENERGY_MARGIN
    return max(ENERGY_MARGIN, math.ceil(float(peak[caught].max()) * 100.0) / 100.0)
