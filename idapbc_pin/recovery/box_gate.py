"""Whether a run uses the linear law outside its training box (`recovery.box_law`), and whether it
scales the learned law inside it: decided by simulation.

After training, the learned law is simulated on the true plant, with the actuators' limits, from
`GATE_STATES` states of its own: as trained, with the anchor's linear law outside the training box,
and (robots with effort limits, whose fallback gain k is 3) with that linear law outside and the
learned law scaled by k about u* inside, the factor ramped in from 1 near x*
(`BoxFallback.inside_gain`, `recovery.box_law.INSIDE_RAMP`). The law that brings the most of those
states to x* is used (DESIGN §4 success: T = 20 s, within 0.05 over the last 2 s); a tie keeps the
simpler one. Half the states are drawn from the half box and half from the training box, with
seeds ``GATE_SEED + seed`` and ``GATE_SEED + seed + 1``: neither the training samples nor the
evaluation's seed-0 states.

Why a decision per run and not one rule: the fallback brings more states to x* on some robots and
fewer on others (docs/results-history.md).
"""

from __future__ import annotations

import sys

import numpy as np
from tqdm.auto import tqdm

from ..control.controller import Controller
from ..control.linear import fastest_pole
from ..model import System
from ..sim.compare import compare_laws
from ..sim.states import uniform_states
from ..sim.step import step_for_pole
from .box_law import INSIDE_RAMP, BoxFallback

__all__ = ["GATE_SEED", "GATE_STATES", "fallback_gate", "gate_step"]

#: States of the gate (half from the half box, half from the training box), its seed offset, and the
#: horizon and step of its simulations (s): the judge's (DESIGN §4, `idapbc_pin.sim.step.DEFAULT_STEP`:
#: the law sampled and held at 500 Hz), so the gate decides on the same judge as every evaluation.
GATE_STATES = 100
GATE_SEED = 15_485_863
GATE_HORIZON = 20.0
GATE_STEP = 0.002
#: The gate's RK4 step is at most this over the fastest pole of the linear loop at x* (|λ|·dt ≤ 0.5,
#: the judge's `POLE_STEP`): beyond it RK4 itself blows up on a stiff loop (joint damping on light
#: links), and a decision taken on such blow-ups would be noise.
GATE_POLE_STEP = 0.5
#: The trajectories the fallback changes are simulated again in this many batches, whatever the
#: number of workers (a batch's rounding depends on its rows: BLAS's matrix-vector kernels), so the
#: batches run side by side on two cores and the verdicts do not depend on the worker count.
GATE_FALLBACK_CHUNKS = 2


def gate_step(system: System, fallback: BoxFallback) -> float:
    """The gate's RK4 step (s): `GATE_STEP`, or less where the loop A − BK at x* (K the anchor's gain, whose
    loop the anchored networks reproduce there; the fallback never acts at x*) has a pole faster than
    ``GATE_POLE_STEP / GATE_STEP``; then the largest step ≤ ``GATE_POLE_STEP / |λ|`` that divides
    `GATE_HORIZON` into whole steps."""
    A, B = system.linearization()
    return step_for_pole(fastest_pole(A - B @ fallback.anchor_K), GATE_HORIZON, GATE_STEP, GATE_POLE_STEP)


def _counted(results, bar):
    """`results` as a list, the bar moved on as each comes in."""
    out = []
    for result in results:
        out.append(result)
        bar.update()
    return out


def fallback_gate(system: System, ctrl: Controller, fallback: BoxFallback, seed: int, workers: int = 1, progress: bool = False) -> dict:
    """Success of `ctrl` (the learned law everywhere), of ``ctrl.with_fallback(fallback)`` and, for a
    fallback whose gain k exceeds 1 (a robot with effort limits), of the same with the learned law
    scaled by k about u* inside the box, ramped in over `INSIDE_RAMP` (`BoxFallback.with_inside_gain`),
    from the same `GATE_STATES` states, simulated on `system` with its effort limits.

    Only the trajectories that leave the box at one of their samples (every `gate_step`: 2 ms unless
    the loop is stiffer) are simulated again with the fallback; the others are the same under both
    laws (up to an RK4 stage grazing a face); they run in `GATE_FALLBACK_CHUNKS` batches.
    The scaled law changes the law everywhere, so it is simulated from every state, beside the
    learned law when `workers` > 1 (processes, `idapbc_pin._parallel.process_map`: the count
    changes the time, never a verdict). A trajectory is no longer integrated once it has rested in
    the success box for the success window (``simulate(stop_settled=True)``): its verdict is known
    then, unless it would leave the box again (docs/method.md §6).

    Returns {"states", "networks", "with_fallback", "scaled" (success rates in [0, 1]; "scaled" None
    where k = 1), "left_box" (how many trajectories of the learned law left the box),
    "only_networks" and "only_fallback" (how many states only that law brought to x*: the discordant
    pairs between the first two), "used" (bool: the run uses the fallback), "inside_gain" (k where
    the scaled law is used, else 1), "inside_ramp" ([r₀, r₁] where it is used, else [0, 0]), "step"
    (s)}. The law with the most successes is used; a tie goes to the simpler one (the learned law
    everywhere, then the fallback outside only). `progress`: a bar over the simulation runs, with an ETA.
    """
    k = GATE_STATES // 2
    x0 = np.concatenate([
        uniform_states(system, k, "half", GATE_SEED + seed),
        uniform_states(system, GATE_STATES - k, "domain", GATE_SEED + seed + 1),
    ])
    dt = gate_step(system, fallback)
    runs = [(ctrl.with_fallback(None), x0)]
    if fallback.gain > 1.0:
        runs.append((ctrl.with_fallback(fallback.with_inside_gain(fallback.gain, INSIDE_RAMP)), x0))
    bar = tqdm(total=len(runs) + GATE_FALLBACK_CHUNKS, disable=not progress, desc="gate", unit="run", dynamic_ncols=True,
               mininterval=0.5 if sys.stderr.isatty() else 15.0)
    with bar:
        (ok, left), *rest = _counted(compare_laws(system, runs, T=GATE_HORIZON, dt=dt, workers=workers, box=fallback), bar)
        ok_fb = ok.copy()
        chunks = np.array_split(np.flatnonzero(left), min(GATE_FALLBACK_CHUNKS, int(left.sum()))) if left.any() else []
        bar.total = len(runs) + len(chunks)
        if chunks:  # a trajectory that never leaves the box is the same under both laws
            law = ctrl.with_fallback(fallback)
            judged = compare_laws(system, [(law, x0[rows]) for rows in chunks], T=GATE_HORIZON, dt=dt, workers=workers)
            for rows, (ok_rows, _) in zip(chunks, _counted(judged, bar)):
                ok_fb[rows] = ok_rows
    counts = [int(ok.sum()), int(ok_fb.sum())] + [int(r[0].sum()) for r in rest]
    scaled = float(rest[0][0].mean()) if rest else None
    best = int(np.argmax(counts))  # the first of the largest: ties go to the simpler law
    rates = {"networks": float(ok.mean()), "with_fallback": float(ok_fb.mean()), "scaled": scaled}
    only_nn, only_fb = int((ok & ~ok_fb).sum()), int((ok_fb & ~ok).sum())  # the pairs between the first two
    return {"states": int(len(x0)), **rates, "left_box": int(left.sum()), "only_networks": only_nn, "only_fallback": only_fb,
            "used": best > 0, "inside_gain": float(fallback.gain) if best == 2 else 1.0,
            "inside_ramp": list(INSIDE_RAMP) if best == 2 else [0.0, 0.0], "step": dt}
