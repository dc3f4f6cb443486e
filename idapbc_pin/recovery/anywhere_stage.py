"""The anywhere step of the swing-up stage: a library of short plans from postures all round the
circle (`trajectory.library`), kept as the run's swing-up law where it brings the robot up faster
from anywhere and loses nothing near hanging or in the box.

1. **Library.** `SwingUpConfig.library` postures at rest from the full circle (seed `plan_seed` +
   700) and the resting posture, each planned in `library_horizon` s (`library_iterations` iLQR
   iterations) within `library_share` of the limits and caught by the stage's teacher (`PumpThenRun`)
   into a hold over `judge_T`; the nominals' knots read at the nearest point (speed weight
   `LIBRARY_SPEED_WEIGHT`), around the run's own outer law, outside its kept box. A 1-s plan from
   hanging must lean on its catch, so the library alone reads poor knots near hanging: the knots of
   a nominal from the resting posture join it, the run's manoeuvre's where it keeps one (its
   fastest swing-up from rest), else those of the tracking law the swing-up gate kept.
2. **Gate.** The run's law as the swing-up gate left it (with its swing-up law, if kept) and with the
   library instead, from states of their own (`ANYWHERE_GATE_SEED`): `gate_states` near-resting
   states ("holds" over `judge_T`), `gate_states` states anywhere on the torus, moving
   (`sim.states.anywhere_states`: "holds", the share of their first `UP_WINDOW` s with the tip up
   (`sim.leaderboard.tip_up`: what the uptime test counts between two resets), and the median time
   to the success box, recorded only), and `box_states` box states (success over 20 s). The library
   is kept when it holds at least as many states from anywhere, keeps the tip up for a share at
   least `ANYWHERE_MARGIN` larger, holds at most `LIBRARY_LOSS` fewer near-resting states, and
   brings at most `box_loss` fewer box states to x*.

A kept library is written as the run's swing-up law (``swingup.npz``, a `TrackingLaw`); summary.json
→ "swing_up" → "anywhere" records the gate either way.
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from .._parallel import process_map
from ..run import resolve_run
from ..sim.compare import compare_laws
from ..sim.integrate import simulate
from ..sim.leaderboard import tip_up
from ..sim.metrics import holds, settling_time
from ..sim.states import anywhere_states, box_gate_states, resting_states
from ..trajectory.library import library_starts, plan_library
from ..trajectory.plans import PLAN_STEP
from ..trajectory.tracking_law import TrackingLaw
from .config import SwingUpConfig
from .gate import GATE_HORIZON, RECOVERY_GATE_SEED

__all__ = ["ANYWHERE_GATE_SEED", "ANYWHERE_MARGIN", "LIBRARY_LOSS", "LIBRARY_SPEED_WEIGHT", "UP_WINDOW", "anywhere_gate", "format_anywhere", "library_law",
           "run_anywhere_step"]

#: Seed offset of the anywhere gate's states (apart from the swing-up gate's and the evaluations').
ANYWHERE_GATE_SEED = RECOVERY_GATE_SEED + 7_000
#: The library must keep the tip up for this much larger a share of the first `UP_WINDOW` s than the law it replaces
#: (mean over the gate's states from anywhere).
ANYWHERE_MARGIN = 0.05
#: Seconds after each start over which the gate counts the tip up: the uptime test's spacing of resets (60 s / 16).
UP_WINDOW = 3.75
#: Near-resting states the library may hold fewer than the law it replaces.
LIBRARY_LOSS = 1
#: Weight of the momenta in the library's nearest-point distance (positions: 1; `tracks.tracking_law`).
LIBRARY_SPEED_WEIGHT = 0.1


def library_law(system, catch, box: np.ndarray, config: SwingUpConfig, progress: bool = False):
    """Step 1 of the module docstring: (the library's `TrackingLaw` with the kept `box`, or None; how
    many of its starts have a nominal; how many starts); with `progress`, a bar over its chunks."""
    starts = library_starts(system, config.library, config.plan_seed + 700)
    law, found = plan_library(system, catch, starts, box, horizon=config.library_horizon, share=config.library_share,
                              iterations=config.library_iterations, judge_T=config.judge_T, seed=config.plan_seed + 800,
                              speed_weight=LIBRARY_SPEED_WEIGHT, workers=config.workers, progress="swing-up: library" if progress else None)
    return law, found, len(starts)


def _verdicts(job) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Worker: (system, law, x0, T) -> (holds (N,), time to the success box (N,), s, nan where never,
    share of the samples of the first `UP_WINDOW` s with the tip up (N,); a diverged row counts as down)."""
    system, law, x0, T = job
    torch.set_num_threads(1)
    traj = simulate(system, law, x0, T=T, dt=PLAN_STEP)
    early = np.asarray(traj.t) <= UP_WINDOW + 1e-9
    up = tip_up(system, traj.q[:, early]) & ~np.asarray(traj.diverged, bool)[:, None]
    return holds(traj, system), settling_time(traj, system), up.mean(axis=1)


def anywhere_gate(run, current, library, config: SwingUpConfig) -> dict:
    """Step 2 of the module docstring for the run's law `current` (as the swing-up gate left it) and
    the same with the `library` law instead: {"near": [held by current, by library], "anywhere":
    [held, held], "up": [share with the tip up, share], "time": [median time to x*, median time],
    "box": [box states, box states], "states": per set, "used": the verdict}."""
    system, seed = run.system, ANYWHERE_GATE_SEED + run.config.seed
    teacher = run.box_controller
    candidate = teacher.with_fallback(library.with_inner(teacher.fallback))
    laws = [current, candidate]
    x_near = resting_states(system, config.gate_states, seed)
    x_any = anywhere_states(system, config.gate_states, seed + 1)
    x = np.concatenate([x_near, x_any])
    near, anywhere, times, ups = [], [], [], []
    for held, arrive, up in process_map(_verdicts, [(system, law, x, config.judge_T) for law in laws], config.workers, config.ray):
        near.append(int(held[: len(x_near)].sum()))
        anywhere.append(int(held[len(x_near):].sum()))
        ups.append(round(float(up[len(x_near):].mean()), 4))
        arrive = arrive[len(x_near):]
        times.append(float(np.median(np.where(np.isfinite(arrive), arrive, np.inf))))
    box = [0, 0]
    if config.box_states:
        x_box = box_gate_states(system, config.box_states, seed + 2)
        box = [int(ok.sum()) for ok, _ in compare_laws(system, [(law, x_box) for law in laws], T=GATE_HORIZON, dt=PLAN_STEP,
                                                        workers=config.workers, ray=config.ray)]
    used = anywhere[1] >= anywhere[0] and ups[1] >= ups[0] + ANYWHERE_MARGIN and near[1] >= near[0] - LIBRARY_LOSS and box[1] >= box[0] - config.box_loss
    plain = [t if math.isfinite(t) else None for t in times]
    return {"near": near, "anywhere": anywhere, "up": ups, "time": plain, "box": box, "states": {"near": len(x_near), "anywhere": len(x_any),
            "box": config.box_states}, "used": bool(used)}


def format_anywhere(entry: dict, seconds: float) -> str:
    """The anywhere step's figures and verdict in one line."""
    if entry.get("nominals", 0) == 0:
        return f"swing-up library: no plan from {entry['starts']} postures held at x*: nothing to keep  [{seconds:.0f} s]"
    t = ["never" if v is None else f"{v:.2f} s" for v in entry["time"]]
    s = entry["states"]
    verdict = "kept" if entry["used"] else (f"not kept (needs as many held from anywhere, the tip up for a share {ANYWHERE_MARGIN:g} larger, "
                                            f"at most {LIBRARY_LOSS} fewer near hanging and the box kept)")
    up = entry.get("up", [math.nan, math.nan])
    source = "the manoeuvre's" if entry.get("joined_from") == "manoeuvre" else "the swing-up law's"
    joined = f" and {source} {entry['joined']} knots" if entry.get("joined") else ""
    return (f"swing-up library: nominals from {entry['nominals']} of {entry['starts']} postures round the circle{joined}; of {s['anywhere']} states "
            f"from anywhere the run's law holds {entry['anywhere'][0]} (tip up {up[0]:.0%} of their first {UP_WINDOW:g} s, median time to x* "
            f"{t[0]}), with the library {entry['anywhere'][1]} ({up[1]:.0%}, {t[1]}); near hanging {entry['near'][0]} and {entry['near'][1]} of {s['near']}; box {entry['box'][0]} and {entry['box'][1]} of "
            f"{s['box']}: {verdict}  [{seconds:.0f} s]")


def _from_hanging(run) -> tuple[TrackingLaw | None, str | None]:
    """The knots from hanging the library joins (step 1): (the run's manoeuvre's nominal, or else
    its swing-up law where that is a tracking law, or None; which one)."""
    manoeuvre = run.manoeuvre
    if manoeuvre is not None:
        return manoeuvre.track, "manoeuvre"
    fallback = run.controller.fallback
    return (fallback, "tracking law") if isinstance(fallback, TrackingLaw) else (None, None)


def run_anywhere_step(run, system, catch, box: np.ndarray, config: SwingUpConfig, progress: bool) -> tuple[object | None, dict]:
    """Steps 1 and 2: (the library law to keep, or None; the summary entry)."""
    start = time.perf_counter()
    law, found, starts = library_law(system, catch, box, config, progress)
    entry = {"nominals": found, "starts": starts, "horizon": config.library_horizon}
    if law is not None:
        now = resolve_run(run.path)  # with the swing-up law and manoeuvre the stage kept, if any
        current = now.controller
        hanging, source = _from_hanging(now)
        if hanging is not None:
            law = TrackingLaw.join([law, hanging])
            entry |= {"joined": len(hanging.X), "joined_from": source}
        entry |= anywhere_gate(run, current, law, config)
    else:
        entry["used"] = False
    entry["seconds"] = round(time.perf_counter() - start, 1)
    if progress:
        print(format_anywhere(entry, entry["seconds"]), flush=True)
    return (law if entry["used"] else None), entry
