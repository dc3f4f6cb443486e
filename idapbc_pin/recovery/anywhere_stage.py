"""The anywhere step of the swing-up stage: a library of short plans from postures all round the
circle (`trajectory.library`), kept as the run's swing-up law where it brings the robot up faster
from anywhere and loses nothing near hanging or in the box.

1. **Library.** `SwingUpConfig.library` postures at rest from the full circle (seed `plan_seed` +
   700), the resting posture, `library_moving` states anywhere, moving at up to the joints'
   ratings (seed `plan_seed` + 701), and `library_released` states as the uptime test's reset
   drive releases them (`sim.drive.drive_release_states`, seed `plan_seed` + 702), each planned in `library_horizon` s, or where no such plan brings
   it up in the first of `library_longer` that does (`library_iterations` iLQR iterations; for the
   `library_horizon` plans `library_refine` more for the cheapest of a start none of whose plans
   ends with its tip at `library_tip`, and each plan ending so), within `library_share` of the
   limits and caught by the stage's teacher (`PumpThenRun`) into a hold over `judge_T`; the
   nominals' knots read at the nearest point (speed weight `LIBRARY_SPEED_WEIGHT`), around the
   run's own outer law, outside its kept box. A short plan from hanging must lean on its
   catch, so the library alone reads poor knots near hanging: the knots of a nominal from the
   resting posture the stage kept join it, the run's manoeuvre's (its fastest swing-up from rest),
   else the tracking law's the swing-up gate kept. Where the longer horizons gave more nominals, a
   second library holds them all, joined by both (the tracking law's longer nominal has knots at
   every step of its path out of hanging).
2. **Gate.** The run's law as the swing-up gate left it (with its swing-up law, if kept) and with
   each library instead, from states of their own (`ANYWHERE_GATE_SEED`): `gate_states` near-resting
   states ("holds" over `judge_T`), `gate_moving` states anywhere on the torus, moving at up to
   the joints' ratings as a reset of the uptime test leaves them (`sim.states.moving_states`), and
   `gate_released` states as its reset drive releases them (`sim.drive.drive_release_states`),
   together the states "from anywhere" ("holds", the share of their first `UP_WINDOW` s with the
   tip up (`sim.leaderboard.tip_up`: what the uptime test counts between two resets), and the
   median time to the success box, recorded only), and `box_states` box states (success over 20 s). The library is kept when it keeps the
   tip up for a share at least `ANYWHERE_MARGIN` larger, holds at most `LIBRARY_LOSS` fewer states
   from anywhere (some moving starts no law catches in `judge_T`; one of them is noise, not a
   loss) and at most `LIBRARY_LOSS` fewer near-resting states, and brings at most `box_loss` fewer box states to x*. Of two libraries the rule keeps, the second
   is chosen only where its tip is up for a share `ANYWHERE_MARGIN` larger than the first's
   (`_preferred`): the short plans swing up sooner, so the longer library has to earn its place.

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
from ..sim.drive import drive_release_states
from ..sim.integrate import simulate
from ..sim.leaderboard import tip_up
from ..sim.metrics import holds, settling_time
from ..sim.states import box_gate_states, moving_states, resting_states
from ..trajectory.ilqr import SPEED_WEIGHT
from ..trajectory.library import horizon_nominals, library_starts, nominals_law
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
#: States from anywhere, and near-resting states, the library may hold fewer than the law it replaces (each set).
LIBRARY_LOSS = 1
#: Weight of the momenta in the library's nearest-point distance (positions: 1; `tracks.tracking_law`).
LIBRARY_SPEED_WEIGHT = 0.1


def library_law(system, catch, box: np.ndarray, config: SwingUpConfig, progress: bool = False):
    """Step 1 of the module docstring: ([(library, the horizons of its plans, s)]: a `TrackingLaw` with
    the kept `box` of the nominals of `library_horizon`, then one of all of them where a longer
    horizon gave more (either may be missing); how many of its starts each horizon gave a nominal;
    how many starts); with `progress`, a bar over its chunks."""
    starts = library_starts(system, config.library, config.plan_seed + 700, config.library_moving, config.library_released)
    horizons = (config.library_horizon, *config.library_longer)
    found, passes = horizon_nominals(system, catch, starts, horizons, share=config.library_share, iterations=config.library_iterations,
                                     judge_T=config.judge_T, seed=config.plan_seed + 800, workers=config.workers,
                                     progress="swing-up: library" if progress else None, speed=SPEED_WEIGHT if config.speed_limits else 0.0,
                                     refine=config.library_refine, tip=config.library_tip)
    short = [nominal for nominal, j in zip(found, passes) if j == 0]
    laws = [(nominals_law(system, short, box, LIBRARY_SPEED_WEIGHT), [horizons[0]])] if short else []
    if any(j > 0 for j in passes):
        every = [nominal for nominal in found if nominal is not None]
        laws.append((nominals_law(system, every, box, LIBRARY_SPEED_WEIGHT), [h for j, h in enumerate(horizons) if j in passes]))
    return laws, [passes.count(j) for j in range(len(horizons))], len(starts)


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
    the same with each library law of `library` (one law, or a list in the order of preference)
    instead: {"near": [held by current, by each library], "anywhere": [held, …], "up": [share with
    the tip up, …], "time": [median time to x*, …], "box": [box states, …], "states": per set,
    "library": the index of the library chosen (`_preferred`), "used": the verdict}."""
    libraries = library if isinstance(library, (list, tuple)) else [library]
    system, seed = run.system, ANYWHERE_GATE_SEED + run.config.seed
    teacher = run.box_controller
    laws = [current] + [teacher.with_fallback(law.with_inner(teacher.fallback)) for law in libraries]
    x_near = resting_states(system, config.gate_states, seed)
    x_any = moving_states(system, config.gate_moving, seed + 1)
    if config.gate_released:
        x_any = np.concatenate([x_any, drive_release_states(system, config.gate_released, seed + 3)])
    x = np.concatenate([x_near, x_any])
    near, anywhere, times, ups = [], [], [], []
    for held, arrive, up in process_map(_verdicts, [(system, law, x, config.judge_T) for law in laws], config.workers, config.ray):
        near.append(int(held[: len(x_near)].sum()))
        anywhere.append(int(held[len(x_near):].sum()))
        ups.append(round(float(up[len(x_near):].mean()), 4))
        arrive = arrive[len(x_near):]
        times.append(float(np.median(np.where(np.isfinite(arrive), arrive, np.inf))))
    box = [0] * len(laws)
    if config.box_states:
        x_box = box_gate_states(system, config.box_states, seed + 2)
        box = [int(ok.sum()) for ok, _ in compare_laws(system, [(law, x_box) for law in laws], T=GATE_HORIZON, dt=PLAN_STEP,
                                                        workers=config.workers, ray=config.ray)]
    passes = [anywhere[i] >= anywhere[0] - LIBRARY_LOSS and ups[i] >= ups[0] + ANYWHERE_MARGIN and near[i] >= near[0] - LIBRARY_LOSS and box[i] >= box[0] - config.box_loss
              for i in range(1, len(laws))]
    best = _preferred(passes, ups[1:])
    plain = [t if math.isfinite(t) else None for t in times]
    return {"near": near, "anywhere": anywhere, "up": ups, "time": plain, "box": box, "states": {"near": len(x_near), "anywhere": len(x_any),
            "box": config.box_states}, "library": best, "used": bool(passes[best])}


def _preferred(passes: list[bool], ups: list[float]) -> int:
    """The library chosen among several, in the order of preference, by their verdicts `passes` and
    shares with the tip up `ups`: the first the rule keeps, unless a later one it keeps has its tip
    up for a share `ANYWHERE_MARGIN` larger (a later library is chosen by a margin, never by a tie);
    where the rule keeps none, the first with the largest share."""
    kept = [i for i, ok in enumerate(passes) if ok]
    if not kept:
        return max(range(len(ups)), key=lambda i: (ups[i], -i))
    best = kept[0]
    for i in kept[1:]:
        if ups[i] >= ups[best] + ANYWHERE_MARGIN:
            best = i
    return best


def format_anywhere(entry: dict, seconds: float) -> str:
    """The anywhere step's figures and verdict in one line."""
    if entry.get("nominals", 0) == 0:
        return f"swing-up library: no plan from {entry['starts']} postures held at x*: nothing to keep  [{seconds:.0f} s]"
    t = ["never" if v is None else f"{v:.2f} s" for v in entry["time"]]
    s, up = entry["states"], entry["up"]
    libraries = entry.get("libraries", [entry["horizon"][:1]])
    chosen = f", the library of {_plans(libraries[entry['library']])}" if len(libraries) > 1 else ""
    verdict = f"kept{chosen}" if entry["used"] else (f"not kept (needs the tip up for a share {ANYWHERE_MARGIN:g} larger, at most {LIBRARY_LOSS} fewer held "
                                                     f"from anywhere and near hanging, and the box kept)")
    joined = f" and the {' and '.join(entry['joined_from'])}'s {entry['joined']} knots" if entry.get("joined") else ""
    longer = f" ({', '.join(str(k) for k in entry['by_horizon'])} with plans of {', '.join(f'{h:g}' for h in entry['horizon'])} s)" if len(entry["horizon"]) > 1 else ""
    each = "; ".join(f"with the library of {_plans(plans)} {entry['anywhere'][i]} ({up[i]:.0%}, {t[i]})" for i, plans in enumerate(libraries, start=1))
    nears = " and ".join(str(k) for k in entry["near"])
    boxes = " and ".join(str(k) for k in entry["box"])
    return (f"swing-up library: nominals from {entry['nominals']} of {entry['starts']} starts round the circle{longer}{joined}; of {s['anywhere']} moving states "
            f"from anywhere the run's law holds {entry['anywhere'][0]} (tip up {up[0]:.0%} of their first {UP_WINDOW:g} s, median time to x* "
            f"{t[0]}), {each}; near hanging {nears} of {s['near']}; box {boxes} of {s['box']}: {verdict}  [{seconds:.0f} s]")


def _plans(horizons) -> str:
    """The horizons of a library's plans, for its line: "1 s plans", "1 and 2 s plans"."""
    return f"{' and '.join(f'{h:g}' for h in horizons)} s plans"


def _from_hanging(run) -> tuple[list[TrackingLaw], list[str]]:
    """The knots from hanging the library joins (step 1): ([the run's manoeuvre's nominal, its swing-up
    law where that is a tracking law], each where the run has one; their names)."""
    laws, names = [], []
    if run.manoeuvre is not None:
        laws.append(run.manoeuvre.track), names.append("manoeuvre")
    fallback = run.controller.fallback
    if isinstance(fallback, TrackingLaw):
        laws.append(fallback), names.append("tracking law")
    return laws, names


def run_anywhere_step(run, system, catch, box: np.ndarray, config: SwingUpConfig, progress: bool) -> tuple[object | None, dict]:
    """Steps 1 and 2: (the library law to keep, or None; the summary entry)."""
    start = time.perf_counter()
    libraries, found, starts = library_law(system, catch, box, config, progress)
    horizons = [config.library_horizon, *config.library_longer]
    entry = {"nominals": sum(found), "by_horizon": found, "starts": starts, "horizon": horizons}
    law = None
    if libraries:
        now = resolve_run(run.path)  # with the swing-up law and manoeuvre the stage kept, if any
        hanging, sources = _from_hanging(now)
        joins = [len(hanging) if len(plans) > 1 else min(1, len(hanging)) for _, plans in libraries]  # knot sets each library joins
        laws = [TrackingLaw.join([library, *hanging[:j]]) for (library, _), j in zip(libraries, joins)]
        entry |= anywhere_gate(run, now.controller, laws, config) | {"libraries": [plans for _, plans in libraries]}
        j = joins[entry["library"]]
        if j:
            entry |= {"joined": sum(len(h.X) for h in hanging[:j]), "joined_from": sources[:j]}
        law = laws[entry["library"]]
    else:
        entry["used"] = False
    entry["seconds"] = round(time.perf_counter() - start, 1)
    if progress:
        print(format_anywhere(entry, entry["seconds"]), flush=True)
    return (law if entry["used"] else None), entry
