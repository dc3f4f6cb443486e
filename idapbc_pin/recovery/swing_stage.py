"""`swing_up`: fit a swing-up law for a run, from its resting posture to x*, and keep it where it helps.

The reach stage's machinery (`recovery.stage`) with another start set (DESIGN §3). `SwingUpConfig`
holds every number.

1. **Labels** (where no tracking law of step 4 holds all of its near-resting starts, or
   `always_fit`; else steps 1–3 are skipped and the gate judges the tracking laws alone). From
   `starts` states near the resting posture (`sim.states.resting_states`: the
   first exactly at rest there, a pendulum hanging) and round(`circle` × `starts`) states at rest
   with every angle from the full circle (`swing_starts`), the teacher runs first: the classical
   energy-pumping law outside the training box's angles and the run's law inside them
   (`PumpThenRun`; the run's law is `Run.box_controller`: its networks with its recovery or linear
   law). Where it does not bring a start to x* within `judge_T`, iLQR plans of `horizon` seconds
   within the effort limits are searched from ten warm starts (its own failed inputs first;
   `plans.plan_candidates`), each tracked by its time-varying LQR and then caught by the teacher
   (`collect_labels`, the same chunks, workers and resumable store as the reach stage's). The
   labels are the states of the trajectories that reach x* with a cart on its rail throughout,
   every 10 ms over their first 6 s, with the inputs applied there; where the run has a recovery
   law, the recovery stage's own labels (``recovery-labels.npz``, at most as many as the
   swing-up's) join them, so that the law also knows the box.
2. **Fit.** A `SwingUpLaw` MLP (features: sin and cos of every angle, the other components scaled
   by the labels' spread) by least squares on u/ū (`trajectory.fit.fit_mlp`).
3. **DAgger**, `dagger` rounds: the run's law with the fitted swing-up law (outside its kept box,
   `posture_box`: the training box's angles and a multiple of its momenta) runs from `dagger_starts`
   new near-resting starts (and `circle` times as many from the circle); the states its failures
   visit at 1, 2.5 and 4 s are labelled as in step 1, with that law as the teacher (its own rollouts
   label the states it brings to x*, and its failed inputs warm-start the plans of the others), and
   a fresh law is fitted on all labels. Where the first fit holds none of the first round's starts,
   the rounds end there (`stop_when_lost`).
4. **Gate.** The run's law as it is and with each fitted swing-up law (the first fit's and each
   DAgger round's, then the `tracks` best tracking laws of `swing_tracks`: nominal plans from the
   exact resting posture read at the nearest point) outside each candidate kept box (`posture_box`,
   and r·s for r in `inner_scales`, none by default), judged from `gate_states` near-resting states
   of their own and `circle` times as many from the circle ("holds" over `judge_T`,
   `sim.metrics.holds`), and from `box_states` states of the half box and the training box (success
   over 20 s). Among the candidates that lose at most `box_loss` of the box states the run's law
   brings to x* (all of them, where none does), those that hold the most swing-up states, and of
   them the fastest (median time to x* over the swing-up states, within `time_margin`), the chosen
   one is a fit before a tracking law, then the one that brings more box states to x*, the later,
   the larger kept box. It is kept when it keeps the box and holds at least `margin` more than the
   run's law, or as many and is at x* `time_margin` sooner (median). Where none is kept, the same gate runs once more with the box's angles and no
   momentum read (`any_speed_boxes`): a robot whose training box allows far less momentum than a
   swing-up arrives with (a reaction wheel, a rotary arm) never leaves a bounded box to its law.
   Where still none is kept, the gate runs once more with each tracking law acting only within each
   of `funnels` of its nominal (`TrackingLaw.funnel`): the run's law then keeps the paths of its box
   that swing far outside the kept box, which a tracking law would take over far from its plan.
   The library of step 6 reads the kept box the gate chose (`chosen_box`).

5. **Manoeuvre.** Each nominal plan (those of `horizon`, and as many of each `manoeuvre_horizons`)
   as a manoeuvre from a command at rest (`manoeuvre`: tracked in time, then the run's law as the
   gate leaves it); among those that hold nearly the most of near-resting starts of their own, the
   one whose swing-up from exact rest scores best (RealAIGym v2) is kept when it holds `margin` more
   of the gate's near-resting states than the run's law, or as many and scores higher from the exact
   resting state (``swingup-manoeuvre.npz``, summary.json → "swing_manoeuvre").
6. **Anywhere** (`library` > 0; `anywhere_stage`): a library of short plans from postures all
   round the circle and moving states, joined by the kept manoeuvre's nominal (else the kept
   tracking law's), read at the nearest point, replaces the law the gate left where it brings the
   robot up sooner from moving states anywhere, holds nearly as many of them, and loses nothing
   near hanging or in the box (summary.json → "swing_up" → "anywhere").

The law goes to ``swingup.npz`` when kept (every command on the run then applies it), else to
``swingup-refused.npz``, and the entry to summary.json → "swing_up"; each write atomic.
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict

import numpy as np
import torch

from .._io import write_json
from .._parallel import process_map
from ..control.energy_pump import EnergyPumpLaw
from ..model.angles import wrap_angles
from ..run import MANOEUVRE_FILE, MANOEUVRE_REFUSED_FILE, SWINGUP_FILE, SWINGUP_REFUSED_FILE, resolve_run
from ..sim.compare import compare_laws
from ..sim.integrate import simulate
from ..sim.metrics import holds
from ..sim.states import box_gate_states, circle_states, resting_states
from ..trajectory.holds import judge_starts
from ..trajectory.chunks import ChunkStore
from .anywhere_stage import run_anywhere_step
from ._failures import stage_errors
from .config import RecoveryConfig, SwingUpConfig
from ..trajectory.fit import fit_mlp
from .gate import GATE_HORIZON, RECOVERY_GATE_SEED, read_labels, write_law
from ..trajectory.plans import PLAN_STEP, PlanSettings, planning_system
from .stage import collect_labels
from .swing_boxes import ANY_SPEED, box_half_widths, any_speed_boxes, chosen_box, kept_boxes, posture_box
from .swing_law import SwingUpLaw, swing_features
from ..trajectory.manoeuvre import MANOEUVRE_NOMINALS, SwingManoeuvre, choose_manoeuvre
from ..trajectory.tracks import KNOT, NOMINALS, nominals, tracking_law, tracking_laws

__all__ = ["ANY_SPEED", "SWING_GATE_SEED", "any_speed_boxes", "chosen_box", "fit_swing_law", "kept_boxes", "swing_gate", "swing_starts", "swing_up"]

#: Seed offset of the swing-up gate's states (neither the plans', DAgger's nor an evaluation's).
SWING_GATE_SEED = RECOVERY_GATE_SEED + 5_000
#: Times (s) of a failed DAgger rollout whose states are labelled.
DAGGER_TIMES = (1.0, 2.5, 4.0)
#: The swing-up labels' plans (`PlanSettings` fields): LQR's end cost alone, the former step sizes and
#: the input computed at every tick, as before the reach plans gained their running cost and held
#: inputs (not yet measured on the swing-up stage).
SWING_LABEL_PLANS = {"q": 0.0, "end_box": 0.0, "alphas": (1.0, 0.3, 0.1), "hold": False}


def _labels_config(config: SwingUpConfig) -> RecoveryConfig:
    """The reach stage's settings `collect_labels` reads, for swing-up plans."""
    plan = PlanSettings(horizon=config.horizon, ilqr_iterations=config.ilqr_iterations, speed_limits=config.speed_limits, **SWING_LABEL_PLANS)
    return RecoveryConfig(plan=plan, judge_T=max(config.judge_T, 8.0), workers=config.workers, ray=config.ray, teacher="run")


def fit_swing_law(system, X: np.ndarray, U: np.ndarray, config: SwingUpConfig, seed: int | None = None,
                  progress: str | None = None) -> tuple[SwingUpLaw, float]:
    """Least-squares fit of a `SwingUpLaw` to labels X (K, n), U (K, m) (within ±ū) around no inner
    law, with `posture_box` as its kept box; returns (law, the last minibatch's mean
    squared error in units of ū)."""
    effort = np.asarray(system.effort, dtype=np.float64)
    x_star, mask = np.asarray(system.x_star, dtype=np.float64), np.asarray(system.angle_mask, dtype=bool)
    box = box_half_widths(system)
    delta = wrap_angles(np.asarray(X, dtype=np.float64) - x_star, mask)
    scale = np.maximum(delta.std(axis=0), box)  # the labels' spread, at least the box's
    F = swing_features(delta, mask, scale)
    (weights, biases), mse = fit_mlp(F, U / effort, config.width, config.steps, config.fit_seed if seed is None else seed,
                                     None, progress, config.batch)
    return SwingUpLaw(weights, biases, x_star, scale, effort, mask, posture_box(system, config)), mse


def _box_labels(run, system, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """At most `limit` of the recovery stage's labels (evenly spaced), where the run has a recovery
    law; else none."""
    if not run.uses_recovery:
        return np.empty((0, system.n)), np.empty((0, system.m))
    X, U = read_labels(run.path, system.n, system.m)
    keep = np.unique(np.linspace(0, len(X) - 1, min(limit, len(X))).astype(int)) if limit > 0 else np.arange(0)
    return X[keep], U[keep]


class PumpThenRun:
    """The first teacher of the swing-up labels: the classical energy-pumping law (`EnergyPumpLaw`)
    where the posture lies outside the training box's angles, the run's law (`run_law`) inside
    them. Its rollouts from near hanging label the starts it brings to x*; for the others its inputs
    are the first warm start of the plans, and it catches each plan after its horizon, so a plan
    only has to bring the robot to where pumping and the run's law finish the job.
    (N, n) -> (N, m); picklable."""

    def __init__(self, system, run_law):
        self.run_law, self.pump, self.m = run_law, EnergyPumpLaw(system), int(system.m)
        self.x_star, self.mask = np.asarray(system.x_star, dtype=np.float64), np.asarray(system.angle_mask, dtype=bool)
        self.box = np.where(self.mask, box_half_widths(system), np.inf)

    def __call__(self, x):
        x = np.atleast_2d(x)
        out = (np.abs(wrap_angles(x - self.x_star, self.mask)) > self.box).any(axis=1)
        u = np.empty((len(x), self.m))
        if out.any():
            u[out] = np.asarray(self.pump(x[out]), dtype=np.float64).reshape(-1, self.m)
        if not out.all():  # the run's law only where it applies: it costs most of a rollout's time
            u[~out] = np.asarray(self.run_law(x[~out]), dtype=np.float64).reshape(-1, self.m)
        return u


def swing_starts(system, n: int, circle: float, seed: int) -> np.ndarray:
    """(n + round(circle·n), 2 nq) swing-up starts: `n` near the resting posture (`resting_states`,
    `seed`; the first exactly at rest), then round(circle·n) at rest with every angle from the full
    circle (`circle_states`, seed + 1, its exactly-resting first state left out)."""
    x = resting_states(system, n, seed)
    k = int(round(circle * n))
    return np.concatenate([x, circle_states(system, k + 1, seed + 1)[1:]]) if k else x


def _label(system, x0, seed: int, config: SwingUpConfig, teacher, store, step: str, progress: bool):
    """Labels from the starts x0 (`collect_labels` with swing-up plans); with the count of starts the
    teacher and the plans brought to x*."""
    return collect_labels(system, x0, seed, _labels_config(config), progress, teacher, store, step)


def swing_up(run_or_path, config: SwingUpConfig = SwingUpConfig(), progress: bool = True) -> dict:
    """Fit, gate and save a swing-up law for a run (see the module docstring); returns the summary entry
    written to summary.json → "swing_up". A failure inside is one `IdapbcError` line, the run as it was."""
    run = resolve_run(run_or_path)
    with stage_errors("the swing-up stage", run.path, f"`idapbc-pin train --resume {run.path}` runs it again, reading back its finished chunks of plans; without --swing-up the run keeps its law."):
        return _swing_up(run, config, progress)


def _swing_up(run, config: SwingUpConfig, progress: bool) -> dict:
    system = planning_system(run.system)
    torch.set_num_threads(1)
    start = time.perf_counter()
    teacher = run.box_controller
    store = ChunkStore(run.path)
    x0 = swing_starts(system, config.starts, config.circle, config.plan_seed)
    catch = PumpThenRun(system, teacher)  # the labels' first teacher, and the catch of every nominal plan
    by_horizon = _all_nominals(system, catch, config) if config.tracks or config.manoeuvre else []
    plans = by_horizon[0][1] if by_horizon else []
    tracks, track_info = tracking_laws(system, teacher, plans, kept_boxes(system, config)["posture"], config, progress) if config.tracks and plans else ([], {})
    tracked = bool(track_info) and max(track_info["held"], default=0) >= track_info["states"]
    if tracked and not config.always_fit:  # step 1's condition: a tracking law already holds every start
        X, U, taught, planned = np.empty((0, system.n)), np.empty((0, system.m)), 0, 0
        if progress:
            print("swing-up: a tracking law holds every near-resting start: no labels and no fits (always_fit)", flush=True)
    else:
        X, U, taught, planned = _label(system, x0, config.plan_seed, config, catch, store, "swing-labels", progress)
    Xb, Ub = _box_labels(run, system, len(X))
    if progress and len(X):
        circle = f" ({config.starts} near-resting, {len(x0) - config.starts} at rest from the full circle)" if len(x0) > config.starts else " near-resting"
        print(f"swing-up labels: energy pumping with the run's law in the box brings {taught} of {len(x0)}{circle} starts to x*, "
              f"plans {planned} more; "
              f"{len(X)} labels, and {len(Xb)} of the recovery stage's  [{time.perf_counter() - start:.0f} s]", flush=True)
    if not len(X) and not tracks:
        reason = (f"no plan from the resting posture reached x* within {config.horizon:g} s: nothing to fit a swing-up law to "
                  "(a longer horizon in the swing-up config may find some)")
        if progress:
            print(f"swing-up: {reason}; the run keeps its law as it is", flush=True)
        entry = {"used": False, "reason": reason, "teacher_starts": int(taught), "plan_starts": 0, "tracks": track_info,
                 "seconds": round(time.perf_counter() - start, 1), "config": asdict(config)}
        write_json(run.path / "summary.json", dict(run.summary) | {"swing_up": entry})
        run.summary = dict(run.summary) | {"swing_up": entry}
    else:
        entry = _fit_and_gate(run, system, teacher, (X, U), (Xb, Ub), tracks, config, store, progress, start)
        entry |= {"teacher_starts": int(taught), "plan_starts": int(planned), "tracks": track_info, "fits_skipped": bool(tracked and not config.always_fit)}
        save_swing_up(run, entry.pop("_law"), entry)
        if progress:
            print(f"{format_swing_gate(entry['gate'], config)}  [{time.perf_counter() - start:.0f} s]", flush=True)
    store.clear()
    if config.manoeuvre:
        candidates = [(plan, config.horizon) for plan in plans[:MANOEUVRE_NOMINALS]]
        candidates += [(plan, h) for h, more in by_horizon[1:] for plan in more]
        if candidates:
            _manoeuvre(run, system, candidates, config, progress, start)
    if config.library:
        entry = _anywhere(run, system, catch, entry, config, progress)
    return entry


def _nominals_job(job) -> list:
    """Worker: (system, catch, config, count) -> `tracks.nominals`."""
    system, catch, config, count = job
    return nominals(system, catch, config, count)


def _all_nominals(system, catch, config: SwingUpConfig) -> list[tuple[float, list]]:
    """[(horizon s, its nominal plans)]: `config.horizon`'s (as many as the tracking laws and the
    manoeuvre read), then, with `config.manoeuvre`, `MANOEUVRE_NOMINALS` of each other horizon of
    `manoeuvre_horizons`; each horizon planned in a worker process of its own (`config.workers`)."""
    horizons = [config.horizon] + ([h for h in config.manoeuvre_horizons if h != config.horizon] if config.manoeuvre else [])
    counts = [max(NOMINALS, MANOEUVRE_NOMINALS if config.manoeuvre else 0)] + [MANOEUVRE_NOMINALS] * (len(horizons) - 1)
    jobs = [(system, catch, config.replace(horizon=h), k) for h, k in zip(horizons, counts)]
    return list(zip(horizons, process_map(_nominals_job, jobs, config.workers, config.ray)))


def _anywhere(run, system, catch, entry: dict, config: SwingUpConfig, progress: bool) -> dict:
    """Step 6 of the module docstring (`anywhere_stage`): the library kept as the swing-up law, or its
    gate recorded beside the law the swing-up gate left; returns the stage's summary entry."""
    run = resolve_run(run.path)  # with the manoeuvre the stage kept, if any
    kept, anywhere = run_anywhere_step(run, system, catch, chosen_box(run, system, config), config, progress)
    recorded = dict(run.summary.get("swing_up") or {}) | {"anywhere": anywhere}
    if kept is not None:
        recorded |= {"used": True, "law": "library", "funnel": None}  # the library acts wherever it is read
        save_swing_up(run, kept, {k: v for k, v in recorded.items() if k != "law_file"})
    else:
        write_json(run.path / "summary.json", dict(run.summary) | {"swing_up": recorded})
        run.summary = dict(run.summary) | {"swing_up": recorded}
    return dict(entry) | {k: recorded[k] for k in ("anywhere", "used", "law", "funnel") if k in recorded}


def _fit_and_gate(run, system, teacher, labels: tuple, box_labels: tuple, tracks: list, config: SwingUpConfig, store, progress: bool, start: float) -> dict:
    """Steps 2–4 of the module docstring: the fits on `labels` (X, U) and the recovery stage's
    `box_labels`, the DAgger rounds, and the gate of the fits and the tracking laws `tracks`; returns
    the summary entry, with the judged law under "_law"."""
    (X, U), (Xb, Ub) = labels, box_labels
    laws, rounds, first_mse = [], [], None
    if len(X):
        X, U = np.concatenate([X, Xb]), np.concatenate([U, Ub])
        law, first_mse = fit_swing_law(system, X, U, config, progress="swing-up: fit" if progress else None)
        laws.append(law)
        for r in range(config.dagger):
            law, X, U, info = _dagger_round(system, teacher, law, X, U, r, config, store, progress, start)
            rounds.append(info)
            if info.get("stopped"):
                break
            laws.append(law)
    shared: dict = {}  # the run's law's verdicts, simulated by the first gate only
    (k, box), gate = swing_gate(run, laws + tracks, config, progress, fitted=len(laws), shared=shared)
    second = any_speed_boxes(system, config)
    if not gate["used"] and second:  # a robot whose box momenta are far below a swing's (a wheel, a rotor arm)
        (k2, box2), gate2 = swing_gate(run, laws + tracks, config, progress, fitted=len(laws), boxes=second, shared=shared)
        if gate2["used"]:
            (k, box), gate = (k2, box2), gate2 | {"bounded": gate}
    candidates = laws + tracks
    if not gate["used"] and tracks and config.funnels:  # each tracking law only near its nominal: the box's own paths stay the run's law's
        funnelled = [t.with_funnel(r) for r in config.funnels for t in tracks]
        (k3, box3), gate3 = swing_gate(run, funnelled, config, progress, fitted=0, shared=shared)
        gate3 |= {"fit": len(laws) + k3 % len(tracks), "fitted": len(laws), "funnel": funnelled[k3].funnel}  # "fit": the tracking law it narrows
        if gate3["used"]:
            candidates = laws + funnelled
            (k, box), gate = (len(laws) + k3, box3), gate3 | {"unfunnelled": gate}
        else:
            gate = gate | {"funnelled": gate3}
    funnel = getattr(candidates[k], "funnel", np.inf)
    gate["funnel"] = float(funnel) if np.isfinite(funnel) and gate["used"] else None
    return {"used": gate["used"], "gate": gate, "fit": k, "law": "fitted" if k < len(laws) else "tracking", "labels": int(len(X)),
            "funnel": gate["funnel"], "first_fit_mse": first_mse, "dagger": rounds, "seconds": round(time.perf_counter() - start, 1),
            "config": asdict(config), "_law": candidates[k].with_box((kept_boxes(system, config) | second)[box])}


def _manoeuvre(run, system, candidates: list, config: SwingUpConfig, progress: bool, start: float) -> dict:
    """Step 5 of the module docstring: the manoeuvre of each nominal plan of `candidates` [(plan, its
    horizon s)] judged against the run's law as the stage leaves it; written to summary.json →
    "swing_manoeuvre" and its file."""
    run = resolve_run(run.path)  # with the swing-up law the stage kept, if any
    box = kept_boxes(system, config)["posture"]
    manoeuvres = [SwingManoeuvre(tracking_law(system, U, Z, G, 1.0, box), system.state_from(Z[-1:, : system.nq], Z[-1:, system.nq :])[0], KNOT)
                  for (U, Z, G), _ in candidates]
    x_pick = resting_states(system, config.gate_states, config.plan_seed + 600)
    x_gate = swing_starts(system, config.gate_states, 0.0, SWING_GATE_SEED + run.config.seed)
    best, entry = choose_manoeuvre(system, run.controller, manoeuvres, x_pick, x_gate, config)
    entry["horizons"] = [float(h) for _, h in candidates]
    write_law(run, manoeuvres[entry["choice"]].arrays(), "swing_manoeuvre", entry, (MANOEUVRE_FILE, MANOEUVRE_REFUSED_FILE))
    if progress:
        verdict = "kept" if entry["used"] else f"not kept (needs {config.margin} more held than the run's law, or as many and better from rest)"
        at = {k: "never" if t is None else f"{t:.2f} s" for k, t in entry["rest_time"].items()}
        v2 = {k: "–" if v is None else f"{v:.3f}" for k, v in entry["rest_score"].items()}
        scores = ", ".join("–" if v is None else f"{v:.3f}" for v in entry["picked_score"])
        lengths = "/".join(f"{h:g}" for h in dict.fromkeys(entry["horizons"]))
        print(f"swing-up manoeuvre (a nominal plan tracked in time from the command, then the run's law): the {len(manoeuvres)} nominals of "
              f"{lengths} s hold {', '.join('–' if h is None else str(h) for h in entry['picked'])} of {len(x_pick)} near-resting starts (v2 from rest {scores}); of the gate's "
              f"{entry['states']}, the run's law holds {entry['run']}, manoeuvre {entry['choice'] + 1} ({entry['horizons'][entry['choice']]:g} s) "
              f"{entry['held']}; from rest at x* from {at['run']} and "
              f"{at['manoeuvre']}, v2 {v2['run']} and {v2['manoeuvre']}: {verdict}  [{time.perf_counter() - start:.0f} s]", flush=True)
    return entry


def _dagger_round(system, teacher, law: SwingUpLaw, X: np.ndarray, U: np.ndarray, r: int, config: SwingUpConfig, store, progress: bool, start: float):
    """DAgger round r: the run's law with `law` from `dagger_starts` near-resting starts (seed
    plan_seed + 300 + r); the states its failures visit at `DAGGER_TIMES` are labelled with that law
    as the teacher, and a fresh law is fitted on all labels. Returns (law, X, U, the round's counts);
    where the first round's law holds none of its starts and `stop_when_lost`, nothing is labelled
    and the counts say "stopped"."""
    xd = swing_starts(system, config.dagger_starts, config.circle, config.plan_seed + 300 + r)
    ctrl = teacher.with_fallback(law.with_inner(teacher.fallback))  # its kept box: `posture_box`
    traj = simulate(system, ctrl, xd, T=config.judge_T, dt=PLAN_STEP)
    failed = np.flatnonzero(~holds(traj, system))
    if r == 0 and config.stop_when_lost and failed.size == len(xd):
        if progress:
            print(f"swing-up DAgger round 1/{config.dagger}: the first fit holds none of {len(xd)} starts: the rounds end here "
                  f"(stop_when_lost), the gate judges the first fit  [{time.perf_counter() - start:.0f} s]", flush=True)
        return law, X, U, {"failed": int(failed.size), "stopped": True}
    ticks = sorted({min(round(t / PLAN_STEP), traj.x.shape[1] - 1) for t in DAGGER_TIMES})  # a short judge_T: its last sample
    visited = np.concatenate([traj.x[failed, k] for k in ticks]) if failed.size else xd[:0]
    # the law itself labels the visited states it brings to x*, and its own failed inputs are the
    # first warm start of their plans: the labels continue what the law does, rather than average
    # swings in opposite directions that plans from nearby states may choose
    Xr, Ur, _, planned = (_label(system, visited, config.plan_seed + 1000 * (r + 1), config, ctrl, store, f"swing-dagger{r + 1}", progress)
                          if failed.size else (X[:0], U[:0], 0, 0))
    X, U = np.concatenate([X, Xr]), np.concatenate([U, Ur])
    law, mse = fit_swing_law(system, X, U, config, progress=f"swing-up: fit, DAgger {r + 1}" if progress else None)
    if progress:
        print(f"swing-up DAgger round {r + 1}/{config.dagger}: the law fails from {failed.size} of {len(xd)} starts; "
              f"plans from {planned} of the {len(visited)} states they visit; refitted on {len(X)} labels  "
              f"[{time.perf_counter() - start:.0f} s]", flush=True)
    return law, X, U, {"failed": int(failed.size), "visited": int(len(visited)), "plans": int(planned), "labels": int(len(X)), "mse": mse}


def swing_gate(run, laws: list, config: SwingUpConfig, progress: bool = False, fitted: int | None = None,
               boxes: dict | None = None, shared: dict | None = None) -> tuple[tuple[int, str], dict]:
    """The run's law with and without each of `laws` (around the run's own outer law) outside each
    candidate kept box (`boxes`, {name: (n,)}; default `kept_boxes`), from the gate's states: ((k, box name) of the candidate judged,
    {"states", "run", "law": near-resting starts each holds, "candidates": {box name: holds of each
    law}; "run_time", "law_time": their median times to x*, s (None: most not there);
    "box_states", "run_box", "law_box": box states the run's law and the candidate bring to x*;
    "fit", "box", "used": the verdict; "fitted": how many of `laws` are fitted laws, the others
    tracking laws}) (see the module docstring). `shared`: a dict kept across the gates of one run
    and config; the run's law's verdicts, which do not depend on the candidates, are simulated by
    the first of them and read from it by the others."""
    system, seed = run.system, SWING_GATE_SEED + run.config.seed
    ctrl = run.box_controller
    boxes = kept_boxes(system, config) if boxes is None else boxes
    cands = [(k, name) for name in boxes for k in range(len(laws))]
    with_laws = [ctrl.with_fallback(laws[k].with_box(boxes[name]).with_inner(ctrl.fallback)) for k, name in cands]
    x_swing = swing_starts(system, config.gate_states, config.circle, seed)
    known = None if shared is None else shared.get("run")  # the run's law's (Judged, box states) from an earlier gate
    simulated = with_laws if known else [ctrl, *with_laws]
    judged = judge_starts(system, simulated, x_swing, config)
    run_judged, judged = (known[0], judged) if known else (judged[0], judged[1:])
    run_holds, held, times = run_judged.held, [j.held for j in judged], [j.median_time for j in judged]
    order = list(boxes)
    run_box, boxed = 0, [0] * len(cands)
    if config.box_states:
        x_box = box_gate_states(system, config.box_states, seed + 1)
        boxed = [int(ok.sum()) for ok, _ in compare_laws(system, [(c, x_box) for c in simulated], T=GATE_HORIZON, dt=PLAN_STEP,
                                                          workers=config.workers, ray=config.ray)]
        run_box, boxed = (known[1], boxed) if known else (boxed[0], boxed[1:])
    if shared is not None:
        shared["run"] = (run_judged, run_box)
    keeps_box = [b >= run_box - config.box_loss for b in boxed]
    # the candidate that holds the most among those that keep the box (all of them where none does),
    # then the fastest: within `time_margin` of the fastest median time to x*, the ties go to a fit
    # before a tracking law, more box states, the later, the larger box
    pool = [i for i in range(len(cands)) if keeps_box[i]] or list(range(len(cands)))
    pool = [i for i in pool if held[i] == max(held[j] for j in pool)]
    pool = [i for i in pool if times[i] <= min(times[j] for j in pool) + config.time_margin]
    fitted = len(laws) if fitted is None else int(fitted)
    best = max(pool, key=lambda i: (cands[i][0] < fitted, boxed[i], cands[i][0], -order.index(cands[i][1])))
    box = run_box, boxed[best]
    faster = held[best] >= run_holds and times[best] <= run_judged.median_time - config.time_margin
    used = (held[best] >= run_holds + config.margin or faster) and keeps_box[best]
    if progress:
        print(f"swing-up gate: simulated {len(x_swing)} swing-up states and {config.box_states} box states for the run's law and "
              f"{len(cands)} candidates ({len(laws)} laws × {len(boxes)} kept boxes)", file=sys.stderr, flush=True)
    candidates = {name: [held[i] for i, (_, b) in enumerate(cands) if b == name] for name in boxes}
    candidates_box = {name: [boxed[i] for i, (_, b) in enumerate(cands) if b == name] for name in boxes}
    finite = lambda t: round(t, 3) if np.isfinite(t) else None  # noqa: E731
    return cands[best], {"states": len(x_swing), "near_resting": config.gate_states, "run": run_holds, "law": held[best], "candidates": candidates, "candidates_box": candidates_box,
                         "run_time": finite(run_judged.median_time), "law_time": finite(times[best]), "fit": cands[best][0],
                         "box": cands[best][1], "box_states": config.box_states, "run_box": box[0], "law_box": box[1], "used": bool(used),
                         "fitted": fitted}


def format_swing_gate(gate: dict, config: SwingUpConfig) -> str:
    """The swing-up gate's figures and verdict in one line (the bounded box's gate first, where a
    second gate with no momentum read kept the law)."""
    funnels = "each tracking law only within each funnel"
    if "funnelled" in gate:  # the last gate, which refused too
        return f"{format_swing_gate({k: v for k, v in gate.items() if k != 'funnelled'}, config)}; again {funnels}: {format_swing_gate(gate['funnelled'], config)}"
    for key, again in (("unfunnelled", funnels), ("bounded", "with no momentum read")):
        if key in gate:
            return f"{format_swing_gate(gate[key], config)}; again {again}: {format_swing_gate({k: v for k, v in gate.items() if k != key}, config)}"
    verdict = "kept" if gate["used"] else (f"not kept (needs {config.margin} more held than the run's law, or as many and "
                                            f"{config.time_margin:g} s sooner at x*, and at most {config.box_loss} fewer box states)")
    boxed = gate.get("candidates_box", {})
    cands = "; ".join(f"kept box {name}: {', '.join(map(str, held))}" + (f" (box states {', '.join(map(str, boxed[name]))})" if name in boxed else "")
                      for name, held in gate["candidates"].items())
    near = gate.get("near_resting", gate["states"])
    where = "near-resting states" if near == gate["states"] else f"states ({near} near-resting, {gate['states'] - near} at rest from the full circle)"
    fitted = gate.get("fitted", len(next(iter(gate["candidates"].values()))))
    which = f"fit {gate['fit'] + 1}" if gate["fit"] < fitted else f"tracking law {gate['fit'] - fitted + 1}"
    which += f" within the funnel {gate['funnel']:g}" if gate.get("funnel") else ""
    at = lambda t: "never" if t is None else f"{t:.2f} s"  # noqa: E731
    times = f", median time to x* {at(gate['run_time'])} and {at(gate['law_time'])}" if "run_time" in gate else ""
    return (f"swing-up gate: of {gate['states']} {where} the run's law holds {gate['run']} at x*, with the swing-up law "
            f"{gate['law']} ({which}, kept box {gate['box']}; each fit, then each tracking law: {cands}){times}; of {gate['box_states']} box states it brings {gate['run_box']} to x*, with the swing-up law {gate['law_box']}: {verdict}")


def save_swing_up(run, law: SwingUpLaw, entry: dict) -> None:
    """Write `law` and summary.json → "swing_up" = `entry`: ``swingup.npz`` when ``entry["used"]``,
    else ``swingup-refused.npz`` (`gate.write_law`)."""
    write_law(run, law.arrays(), "swing_up", entry, (SWINGUP_FILE, SWINGUP_REFUSED_FILE))
