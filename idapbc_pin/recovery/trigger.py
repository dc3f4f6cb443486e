"""When `train` fits a recovery law on its own: saturated LQR leaves room on the half box, or else on
the training box.

A recovery law (`recovery.stage`) is worth its cost (a few minutes for a 2-DoF robot) where a
linear law under the robot's torque limits loses states that torque plans within the same limits
bring to x* (docs/stages.md). Saturated LQR leaves **room** when it fails from at least
`ROOM_POINTS` per cent of the half box's states: `train` reads that from its own evaluation
(`room_from`), after printing it; without one, `limits_bind` runs saturated LQR from `BIND_STATES`
uniform half-box states (a seed no evaluation uses), and LQR without the limits from the same
states, to say whether the limits **bind** (saturated LQR loses ≥ `BIND_POINTS` per cent more than
unsaturated LQR): printed as context, not used in the decision. Where the half box leaves no room,
the same test runs on the training box, and where that leaves room the recovery law's plans and
DAgger rounds start from the training box (`RecoveryConfig.start_box`). A robot given no effort
limits (the paper's built-in systems, a URDF without `<limit effort>`) takes the same test with LQR
itself, and its plans and recovery law stay within `plans.plan_bound`, the largest |u| LQR asks on
the training box: a basin larger than LQR's is what the user comes for with or without limits.

Room, not binding, decides: a robot whose limits do not bind can still leave room that a recovery
law fills. Where plans cannot help a feedback law the gate keeps none and only time is lost. What
the test says for each zoo robot is in docs/stages.md.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..control.baseline import LQRController
from ..errors import IdapbcError
from ..sim.integrate import simulate
from ..sim.metrics import success
from ..sim.states import uniform_states
from ..trajectory.plans import PLAN_STEP, plan_bound
from .stage import RecoveryConfig, recover

__all__ = ["BIND_POINTS", "BIND_STATES", "RECOVER_MODES", "RECOVER_TIME", "ROOM_POINTS", "SMOKE_EPOCHS", "auto_recover", "limits_bind", "recovery_hint", "room_from"]

#: Half-box states of the test, and the loss (percentage points) of saturated LQR against unsaturated
#: LQR that makes the limits bind.
BIND_STATES, BIND_POINTS = 100, 10.0
#: Failures of saturated LQR (percentage of the test's states) that leave a recovery law room.
ROOM_POINTS = 10.0
#: Seed of the test's states (neither the plans', the gates', nor an evaluation's).
BIND_SEED = 5_190_421
#: `train --recover`: fit a recovery law where saturated LQR leaves room (the default), always, or never.
RECOVER_MODES = ("auto", "always", "never")
#: What the recovery stage costs, as `train` and `recovery_hint` announce it.
RECOVER_TIME = "about 5 min on 2 cores for a 2-DoF robot, up to about 15 min for a 3-DoF one, less with more cores (--workers)"
#: Fewer training epochs than this make a smoke run: `train`'s default `--recover auto` then skips the
#: stage with one line (an explicit --recover runs it).
SMOKE_EPOCHS = 200


def limits_bind(system, states: int = BIND_STATES, seed: int = BIND_SEED, box: str = "half") -> dict:
    """Saturated against unsaturated LQR from `states` uniform states of `box` ("half" or "domain", seed `seed`), T = 20 s,
    the law held every 2 ms. Returns {"states", "saturated": successes, "unsaturated": successes,
    "binds": whether saturated LQR loses ≥ BIND_POINTS per cent of the states more than unsaturated
    LQR, "room": whether saturated LQR fails on ≥ ROOM_POINTS per cent of them}; "binds" and "room"
    are False (and nothing is simulated) for a system without inputs. Without any effort limit the two
    are one simulation (a robot given no limits has room where LQR itself fails; `recover` then plans
    within `plans.plan_bound`). A state that has rested in the success box for the success window is
    integrated no further."""
    if system.m == 0:
        return {"states": 0, "saturated": 0, "unsaturated": 0, "binds": False, "room": False}
    x0 = uniform_states(system, states, box, seed)
    lqr = LQRController(system)

    def count(limits: bool) -> int:
        return int(success(simulate(system, lqr, x0, T=20.0, dt=PLAN_STEP, limits=limits, stop_settled=True, stop_converged=True), system).sum())

    sat = count(True)
    free = count(False) if system.limited else sat
    return {"states": int(states), "saturated": sat, "unsaturated": free, "binds": 100.0 * (free - sat) / states >= BIND_POINTS,
            "room": 100.0 * (states - sat) / states >= ROOM_POINTS}


def room_from(lqr_success: dict[str, float]) -> dict | None:
    """`limits_bind`'s verdict from an evaluation that already ran saturated LQR: lqr_success
    {"half": share, "domain": share} (shares in [0, 1]) -> {"box": the first of "half", "domain"
    where LQR fails from ≥ ROOM_POINTS per cent, "failed": that percentage}, or None (no room)."""
    for box in ("half", "domain"):
        if box in lqr_success and 100.0 * (1.0 - lqr_success[box]) >= ROOM_POINTS - 1e-9:
            return {"box": box, "failed": 100.0 * (1.0 - lqr_success[box])}
    return None


def auto_recover(run, mode: str = "auto", config: RecoveryConfig = RecoveryConfig(), progress: bool = True, lqr_success: dict | None = None) -> dict | None:
    """What `train --recover MODE` does after training: ``"always"`` runs `recover`, ``"never"``
    nothing, ``"auto"`` runs it only where saturated LQR leaves room (fails on ≥ ROOM_POINTS per cent
    of the half box; where it does not, of the training box, and then the plans start from the
    training box). That verdict comes from the evaluation's LQR results when given (`lqr_success`,
    see `room_from`), else from `limits_bind`; it is printed either way when `progress`. Returns
    recover's summary entry, or None when it did not run."""
    if mode not in RECOVER_MODES:
        raise IdapbcError(f"unknown recover mode {mode!r}. Fix: use one of {', '.join(RECOVER_MODES)}.")
    if mode == "never":
        return None
    if mode == "auto":
        if lqr_success is not None and run.system.m:
            room = room_from(lqr_success)
            if progress:
                _tell_evaluation(lqr_success, room)
            if room is None:
                return None
            box = room["box"]
        else:
            for box in ("half", "domain"):  # the training box only where the half box leaves no room
                test = limits_bind(run.system, box=box)
                if progress and test["states"]:
                    _tell(test, box, run.system)
                if test["room"]:
                    break
            else:
                return None
        if box == "domain":
            config = replace(config, start_box="domain")
    return recover(run, config, progress)


def _tell_evaluation(lqr_success: dict, room: dict | None) -> None:
    """Print the room verdict read from the evaluation and what `auto_recover` does next."""
    shares = ", ".join(f"{100.0 * (1.0 - v):.0f} % of the {'half box' if k == 'half' else 'training box'}" for k, v in lqr_success.items())
    if room is None:
        print(f"saturated LQR fails from {shares}: no room for a recovery law (--recover always fits one anyway)", flush=True)
    else:
        start = "" if room["box"] == "half" else " from training-box starts"
        print(f"saturated LQR fails from {shares}: fitting a recovery law{start} where the law loses states ({RECOVER_TIME}; "
              "Ctrl-C keeps the run as it is and `idapbc-pin train --resume RUN` continues; --recover never skips it)", flush=True)


def recovery_hint(run, half_box_lqr_success: float | None = None) -> str | None:
    """The line `train` prints after its evaluation when it did not run the recovery stage: the
    ``idapbc-pin recover`` command and its cost, where saturated LQR failed from at least
    ROOM_POINTS per cent of the evaluation's half-box states (`half_box_lqr_success`, a share in
    [0, 1]; None: not evaluated, then the hint names the test instead). None where there is no room
    or the system has no inputs."""
    if run.system.m == 0 or (half_box_lqr_success is not None and 100.0 * (1.0 - half_box_lqr_success) < ROOM_POINTS - 1e-9):
        return None
    command = f"idapbc-pin recover {run.path} --workers 0"
    if half_box_lqr_success is None:
        return (f"weak actuators? `{command}` fits a recovery law where saturated LQR leaves room, and keeps it only if it "
                f"helps ({RECOVER_TIME})")
    return (f"saturated LQR fails from {100.0 * (1.0 - half_box_lqr_success):.0f} % of the half box: a recovery law may bring more "
            f"states to x*: `{command}` ({RECOVER_TIME}; kept only if it helps)")


def _tell(test: dict, box: str, system) -> None:
    """Print `limits_bind`'s verdict on `box` and what `auto_recover` does next."""
    n, sat = test["states"], test["saturated"]
    where = "half-box" if box == "half" else "training-box"
    free = ~np.isfinite(np.asarray(system.effort, dtype=np.float64))  # inputs without a limit
    bound = " ".join(f"±{b:.3g}" for b in plan_bound(system)[free]) if free.any() else ""
    if system.limited:
        law = f"saturated LQR brings {sat} of {n} {where} states to x*"
        if box == "half":
            law += f", unsaturated LQR {test['unsaturated']} (the limits {'bind' if test['binds'] else 'do not bind'})"
        head = "torque limits: " if not free.any() else (
            f"torque limits on {int((~free).sum())} of {free.size} inputs (a recovery law plans the others within {bound}, "
            "LQR's largest demand on the training box): ")
    else:
        law = f"LQR brings {sat} of {n} {where} states to x*"
        head = f"no effort limits (a recovery law plans within {bound}, LQR's largest demand on the training box): "
    if test["room"]:
        start = "" if box == "half" else " from training-box starts"
        verdict = f"fitting a recovery law{start} where it fails ({RECOVER_TIME}; --recover never skips it)"
    else:
        verdict = "no room there; testing the training box" if box == "half" else "no recovery law (--recover always fits one anyway)"
    print(f"{head}{law}; it fails on {n - sat}: {verdict}", flush=True)
