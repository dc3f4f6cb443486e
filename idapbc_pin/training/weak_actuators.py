"""When `train` fits a recovery law on its own: the robot's torque limits bind.

A recovery law (`training.recovery`) is worth its cost (20–50 minutes of plans on 2 cores) where the
actuators are too weak for a linear law: there saturated LQR loses states that the same LQR without
the limits brings to x*, and plans within the limits recover them (README, "A recovery law for weak
actuators"). The test is that comparison, on `BIND_STATES` uniform states of the half box (a seed
no evaluation uses): the limits **bind** when saturated LQR brings at least `BIND_POINTS` per cent
of them fewer to x* than unsaturated LQR.

Measured with these defaults (successes of the 100 states, saturated / unsaturated LQR; the full
table is in docs/method.md §6): no zoo robot at its URDF limits binds (pendubot 61 / 61, acrobot
69 / 6, cart_double_pendulum 22 / 18, furuta 81 / 69, cartpole, reaction_wheel and double_pendulum
100 / 100), so `train --recover auto` leaves them alone; a pendubot with an 8 N·m shoulder gives
24 / 61, a cartpole with a 10 N slider 80 / 100 and a reaction wheel with a 2 N·m wheel 76 / 100, so
they get one. An acrobot with a 5 N·m elbow gives 13 / 6: its linear law fails with or without the
limits, and the recovery law added only 1–7.5 points there, so auto leaves it alone too
(`--recover always` does not).
"""

from __future__ import annotations

import numpy as np

from ..control.baseline import LQRController
from ..errors import IdapbcError
from ..sim.integrate import simulate
from ..sim.metrics import success
from ..sim.states import uniform_states
from .plans import PLAN_STEP
from .recovery import RecoveryConfig, recover

__all__ = ["BIND_POINTS", "BIND_STATES", "RECOVER_MODES", "auto_recover", "limits_bind"]

#: Half-box states of the test, and the loss (percentage points) of saturated LQR that makes the limits bind.
BIND_STATES, BIND_POINTS = 100, 10.0
#: Seed of the test's states (neither the plans', the gates', nor an evaluation's).
BIND_SEED = 5_190_421
#: `train --recover`: fit a recovery law when the limits bind, always, or never.
RECOVER_MODES = ("auto", "always", "never")


def limits_bind(system, states: int = BIND_STATES, seed: int = BIND_SEED) -> dict:
    """Saturated against unsaturated LQR from `states` uniform half-box states (seed `seed`), T = 20 s,
    the law held every 2 ms. Returns {"states", "saturated": successes, "unsaturated": successes,
    "binds": whether saturated LQR loses ≥ BIND_POINTS per cent of the states}; "binds" is False (and
    nothing is simulated) unless every actuated joint has a finite effort limit."""
    if system.m == 0 or not np.all(np.isfinite(system.effort)):  # recover plans within every limit
        return {"states": 0, "saturated": 0, "unsaturated": 0, "binds": False}
    x0 = uniform_states(system, states, "half", seed)
    lqr = LQRController(system)
    sat, free = (int(success(simulate(system, lqr, x0, T=20.0, dt=PLAN_STEP, limits=lim), system).sum()) for lim in (True, False))
    return {"states": int(states), "saturated": sat, "unsaturated": free, "binds": 100.0 * (free - sat) / states >= BIND_POINTS}


def auto_recover(run, mode: str = "auto", config: RecoveryConfig = RecoveryConfig(), progress: bool = True) -> dict | None:
    """What `train --recover MODE` does after training: ``"always"`` runs `recover`, ``"never"``
    nothing, ``"auto"`` runs it only when `limits_bind` says the limits bind (printing the test
    either way when `progress`). Returns recover's summary entry, or None when it did not run."""
    if mode not in RECOVER_MODES:
        raise IdapbcError(f"unknown recover mode {mode!r}. Fix: use one of {', '.join(RECOVER_MODES)}.")
    if mode == "never":
        return None
    if mode == "auto":
        test = limits_bind(run.system)
        if progress and test["states"]:
            verdict = "they bind: fitting a recovery law (20-50 min on 2 cores; --recover never skips it)" if test["binds"] else \
                "they do not bind: no recovery law (--recover always fits one anyway)"
            print(f"torque limits: saturated LQR brings {test['saturated']} of {test['states']} half-box states to x*, "
                  f"unsaturated LQR {test['unsaturated']}; {verdict}", flush=True)
        if not test["binds"]:
            return None
    return recover(run, config, progress)
