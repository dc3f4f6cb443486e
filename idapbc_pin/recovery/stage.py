"""`recover`: fit a recovery law for a run on a weak actuator, and keep it only where it helps.

The steps (`RecoveryConfig` holds every number):

1. **Labels.** From `starts` uniform start states of the half box, or of the training box
   (`start_box`; seed `plan_seed`, never an evaluation seed), the `teacher` runs first: the run's
   own law (`Run.own_controller`, the default) or saturated LQR. Where it fails within `judge_T`,
   torque plans within the limits are searched (`plans.plan_candidates`: iLQR from several warm
   starts, every lost start of a chunk at once, each candidate tracked by a time-varying LQR and
   then caught by the teacher; or `plans.search_plans`, the cross-entropy search, with
   ``plan.method = "cem"``). An input without an effort limit plans within `plans.plan_bound`,
   LQR's largest demand on the training box (and the fitted law stays within it). Every start that
   reaches x* with a cart on its rail throughout (`sim.metrics.on_rail`) gives labels (x(t), u(t))
   every 10 ms over its first 6 s. With the run's law as the teacher the fitted law imitates the
   IDA-PBC law on the states that law already brings to x*, so a trajectory that leaves the inner
   box meets a law that continues what the IDA-PBC law was doing; with LQR it meets LQR's habits,
   and can lose states near x* that the run's law holds (docs/stages.md). Each finished chunk of starts is kept in ``recovery-chunks/``
   (`chunks.ChunkStore`) until the stage ends, so a stage started again after a kill reads it back.
   From `PILOT_MIN_STARTS` starts on, the first `LABEL_PILOT` chunks (a quarter of the starts) are
   a pilot: where none of their starts reaches x*, the others are not planned and the stage
   refuses; so it does where the plans reach fewer than `margin` of the starts the run's law loses
   (with the run's law as the teacher): the gate asks that many more than the run's law brings.
   The labels stay for `refit`.
2. **Fit.** A `recovery.law.RecoveryLaw` MLP (two tanh layers of `width`) by least squares on
   u/ū (Adam, minibatches of 4096; `fit`). With `form` "residual" the MLP is a correction
   added to the IDA-PBC law's own input (`RecoveryLaw.residual`). After the DAgger rounds, `fits`
   laws are fitted to the final labels (seeds `fit_seed`, `fit_seed` + 1, …) and the gate judges each,
   and beside them (`library`) the labelled paths themselves, each with the gains of a time-varying
   LQR along it, read at the nearest point (`label_library`, `library_law.LibraryLaw`): where the
   fits average the paths, the library keeps them. The library of the first labels is judged
   first: where the gate keeps it, steps 2–3 are skipped (unless `always_fit`), and so they are where
   it brings `margin` or more fewer gate states to x* than the run's law (`gate.lost`): the fits
   only imitate those paths, and cost minutes (docs/stages.md).
3. **DAgger** (Ross, Gordon, Bagnell 2011), `dagger` rounds: the fitted law runs from
   `dagger_starts` new starts of the same box; the states its failures visit at 0.5, 1.5 and 3 s are
   labelled as in step 1, and a fresh law is fitted on all labels. When the first fit brings none
   of the first round's starts to x*, and fewer than half of them even end in the gate's near box,
   the rounds end there (`stop_when_lost`): such a law is far from a working one, and a round of
   labels costs plans. A first fit whose starts all fail yet mostly end near x* (`ends_near`) goes
   on: DAgger's labels of the states it visits are what it lacks.
4. **Gate.** The run's law as it is, and the law with the recovery law outside an inner box of
   each scale in `inner_scales`, run from `gate_states` states of their own (half from the half
   box, half from the training box). Of the inner boxes that bring at most `half_loss` fewer of the
   half-box states (none fewer where the run's law brings them all), and at most `half_loss` fewer
   of `near_states` further states of the near box (scale NEAR_SCALE = 0.25), to x* than the run's
   law, the best is kept if it brings at least `margin` more of the `gate_states`; otherwise the run
   is left as it was (`gate_choice`). Where the run's law brings all those half-box states to x*,
   a kept law is checked again on `confirm_states` half-box states of their own.

What it buys is recorded in docs/results-history.md. `train` runs `recover` by default where
saturated LQR leaves room (`recovery.trigger`); `workers` processes (or Ray tasks) share the plans,
fits and gate, and change the time only.

The result is written into the run directory: ``recovery.npz`` (the law, when the gate keeps it;
`Run.controller` then applies it) or ``recovery-refused.npz`` (when it does not; never applied),
``recovery-labels.npz`` (the labels of the last fit) and the ``"recovery"`` entry of summary.json,
each atomically (`gate.save_recovery`). `again.regate` judges the saved law again with another
gate, or keeps it, and `again.refit` fits a law again to the saved labels (another `fit_seed`, `width` or
`steps`) and gates it, without searching plans again.
"""

from __future__ import annotations

import sys
import time
from contextlib import closing
from dataclasses import asdict

import numpy as np
import torch
from tqdm.auto import tqdm

from .._io import write_json
from .._parallel import process_map, resolve_workers
from ..control.baseline import LQRController
from ..control.speed_governor import ENERGY_MARGIN
from ..model.angles import wrap_angles
from ..run import RECOVERY_LABELS_FILE, resolve_run
from ..sim.integrate import simulate
from ..sim.metrics import on_rail, success
from ..sim.states import scaled_box, uniform_states
from ..trajectory.chunks import ChunkStore, chunk_key
from ._failures import record_refusal, stage_errors
from .config import FORMS, START_BOXES, TEACHERS, RecoveryConfig
from .fit import base_inputs, fit_job, fit_recovery_law
from .gate import NEAR_SCALE, choose_fit, choose_inner, format_gate, gate_choice, library_first, save_labels, save_recovery
from .governor_margin import catch_margin
from .law import RecoveryLaw
from .library_law import LibraryLaw
from ..trajectory.tracks import KNOT
from ..trajectory.plans import PLAN_STEP, PlanThenLaw, TrackThenLaw, plan_candidates, planning_system, search_plans

__all__ = ["FORMS", "LABEL_EVERY", "LABEL_PATH", "LABEL_PILOT", "PILOT_MIN_STARTS", "LABEL_SPAN", "RecoveryConfig", "START_BOXES", "TEACHERS", "choose_inner", "collect_labels", "dagger_round", "ends_near", "fit_recovery_law", "gate_choice", "label_library", "pilot_starts", "recover"]

#: A label every LABEL_EVERY ticks (10 ms) over the first LABEL_SPAN ticks (6 s) of a successful start.
LABEL_EVERY, LABEL_SPAN = 5, 3000
#: Labels of one start's path.
LABEL_PATH = LABEL_SPAN // LABEL_EVERY
#: The labelled span, s: a rollout's record is complete up to it, and rows that enter their loop's
#: terminal set after it stop there (`simulate`'s stop_converged: their success is known).
LABEL_TIME = LABEL_SPAN * PLAN_STEP
#: Lost starts whose plans are searched together (`plans.search_plans`): 16 × 48 candidates per batch.
PLAN_BATCH = 16
#: Chunks the starts of one labelling step are split into, whatever the number of workers: a batch's
#: rounding depends on its rows, so a fixed count gives the same labels (and law) for any --workers;
#: 8 keeps the labels of runs recovered with two workers before the count was fixed.
LABEL_CHUNKS = 8
#: The labels step's first LABEL_PILOT chunks (a quarter of its starts) are a pilot: where none of
#: their starts reaches x*, with the teacher or with a plan, the other chunks are not planned.
LABEL_PILOT = 2
#: The pilot, and the refusal of plans fewer than the gate's margin, act from this many starts on
#: (a pilot of 32): fewer say too little about what the plans can reach.
PILOT_MIN_STARTS = 128


# ------------------------------------------------------------------------------------ labels
def _labels_ok(traj, system) -> np.ndarray:
    """(N,) bool: the rows whose states may label a law: they reach x* (`success`) and a cart stays
    on its rail throughout (`on_rail`)."""
    return success(traj, system) & on_rail(traj, system)


def _label_chunk(job) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Worker: (X (K, n), U (K, m), the teacher's successes, plans that reached x*) for one chunk of
    starts (teacher None: saturated LQR)."""
    system, x0, first, plan_seed, settings, teacher, T = job
    torch.set_num_threads(1)
    law = LQRController(system) if teacher is None else teacher
    traj = simulate(system, law, x0, T=T, dt=PLAN_STEP, stop_converged=True, stop_from=LABEL_TIME)
    ok = _labels_ok(traj, system)
    X = [traj.x[i, :LABEL_SPAN:LABEL_EVERY] for i in np.flatnonzero(ok)]
    U = [system.saturate(traj.u[i, :LABEL_SPAN:LABEL_EVERY]) for i in np.flatnonzero(ok)]
    lost, bound = np.flatnonzero(~ok), np.asarray(system.effort)
    plan = _ilqr_labels if settings.method == "ilqr" else _cem_labels
    Xp, Up = plan(system, law, x0[lost], traj.u[lost], lost + first, plan_seed, bound, settings, T) if lost.size else ([], [])
    X, U = X + Xp, U + Up
    empty = (np.empty((0, system.n)), np.empty((0, system.m)))
    return (np.concatenate(X), np.concatenate(U), int(ok.sum()), len(Xp)) if X else (*empty, int(ok.sum()), len(Xp))


def _labelled(system, t, i) -> tuple[np.ndarray, np.ndarray]:
    """The labels (x, u) of row i of trajectory t: every LABEL_EVERY ticks over LABEL_SPAN."""
    return t.x[i, :LABEL_SPAN:LABEL_EVERY], system.saturate(t.u[i, :LABEL_SPAN:LABEL_EVERY])


def _ilqr_labels(system, law, x0, failed_u, ids, plan_seed, bound, settings, T):
    """Labels of the lost starts x0 (S, n) from iLQR candidates (`plans.plan_candidates`), every
    candidate tracked and then caught by `law` in one simulation; per start, the reaching candidate
    of the lowest warm-start index labels it. Deterministic: no random stream is drawn."""
    starts, Uc, Zc, gains = plan_candidates(system, x0, failed_u, bound, settings)
    tracker = TrackThenLaw(Uc, Zc, gains, settings.knot_step, law, system, hold=settings.hold)
    t = simulate(system, tracker, starts, T=T, dt=PLAN_STEP, stop_converged=law if tracker.horizon <= LABEL_TIME else False,
                 stop_from=LABEL_TIME)
    ok = _labels_ok(t, system).reshape(-1, len(x0))  # (C, S)
    X, U = [], []
    for s in np.flatnonzero(ok.any(0)):
        x, u = _labelled(system, t, int(np.argmax(ok[:, s])) * len(x0) + s)
        X.append(x), U.append(u)
    return X, U


def _cem_labels(system, law, x0, failed_u, ids, plan_seed, bound, settings, T):
    """Labels of the lost starts x0 (S, n) from cross-entropy plans (`plans.search_plans`), PLAN_BATCH
    starts searched together, start i drawing from the stream (plan_seed, ids[i]); each plan is judged alone."""
    X, U = [], []
    for k in range(0, len(x0), PLAN_BATCH):
        group = np.arange(k, min(k + PLAN_BATCH, len(x0)))
        rngs = [np.random.default_rng((plan_seed, int(ids[i]))) for i in group]
        plans = search_plans(system, law, x0[group], bound, settings, rngs)
        # Each plan is judged alone: numpy's matrix product (LQR's -Kδ) rounds a batch of one
        # differently, and judging it in a batch would move existing runs' labels by rounding.
        for plan, i in zip(plans, group):
            t = simulate(system, PlanThenLaw(plan[None], settings.horizon, law), x0[i : i + 1], T=T, dt=PLAN_STEP,
                         stop_converged=law if settings.horizon <= LABEL_TIME else False, stop_from=LABEL_TIME)
            if _labels_ok(t, system)[0]:
                x, u = _labelled(system, t, 0)
                X.append(x), U.append(u)
    return X, U


def collect_labels(system, x0: np.ndarray, plan_seed: int, config: RecoveryConfig, progress: bool = True, teacher=None,
                   store: ChunkStore | None = None, step: str = "labels", pilot: int = 0):
    """Labels (X (K, n), U (K, m)) of `system` from the start states x0 (N, n), with the counts of
    starts the teacher and the plans brought to x*: (X, U, teacher_ok, recovered). The teacher is
    `teacher` (a law (N, n) -> (N, m), picklable), or saturated LQR when None; it also catches every
    plan after its horizon. A cross-entropy plan of start i draws from the stream (plan_seed, i); an
    iLQR plan draws none. The starts are split into `LABEL_CHUNKS` chunks for `config.workers`
    processes (the system and the teacher are pickled to them; Ray tasks with `config.ray`), so the
    labels depend on neither the count nor the back-end. With a `store`, each finished chunk is
    saved under `step` as it arrives, and chunks already saved there are read instead of planned
    (`chunks.ChunkStore`). `progress` shows a bar over the chunks with its ETA. With `pilot` > 0 the
    first `pilot` chunks are a pilot: where none of their starts reaches x*, the other chunks are not
    planned (those in flight finish first) and no labels come back (the counts 0); the verdict reads
    the pilot's chunks only, whatever the workers."""
    workers = config.workers if config.ray else resolve_workers(config.workers)  # Ray: 0 leaves the count to the cluster
    store = store or ChunkStore(None)
    chunks = [c for c in np.array_split(np.arange(len(x0)), LABEL_CHUNKS) if c.size]
    keys = [chunk_key(x0[c], int(c[0]), plan_seed, config.plan, config.judge_T, config.teacher) for c in chunks]
    parts = [store.read(step, k, key) for k, key in enumerate(keys)]
    todo = [] if _pilot_lost(parts, pilot) else [k for k, p in enumerate(parts) if p is None]
    jobs = [(system, x0[chunks[k]], int(chunks[k][0]), plan_seed, config.plan, teacher, config.judge_T) for k in todo]
    with tqdm(total=len(chunks), initial=len(chunks) - len(todo), desc=f"recovery: {step}", unit="chunk", disable=not progress,
              dynamic_ncols=True, file=sys.stderr) as bar, closing(process_map(_label_chunk, jobs, workers, config.ray)) as results:
        for k, part in zip(todo, results):
            store.write(step, k, keys[k], part)
            parts[k] = part
            bar.update(1)
            if _pilot_lost(parts, pilot):
                break
    if _pilot_lost(parts, pilot):
        return np.empty((0, system.n)), np.empty((0, system.m)), 0, 0
    X, U = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    return X, U, sum(p[2] for p in parts), sum(p[3] for p in parts)


def _pilot_lost(parts: list, pilot: int) -> bool:
    """The first `pilot` chunks (of more) are in, and none of their starts reached x*."""
    head = parts[:pilot]
    return 0 < pilot < len(parts) and all(p is not None for p in head) and sum(p[2] + p[3] for p in head) == 0


def pilot_starts(n: int, pilot: int = LABEL_PILOT) -> int:
    """How many of n starts `collect_labels` plans before its pilot's verdict (all n where the
    chunks are no more than the pilot's)."""
    chunks = [c for c in np.array_split(np.arange(n), LABEL_CHUNKS) if c.size]
    return n if len(chunks) <= pilot else sum(c.size for c in chunks[:pilot])


# ------------------------------------------------------------------------------------ recover
def dagger_round(system, law: RecoveryLaw, X: np.ndarray, U: np.ndarray, r: int, config: RecoveryConfig, progress: bool = True, start: float | None = None,
                 teacher=None, networks=None, store: ChunkStore | None = None, refit: bool = True):
    """DAgger round r: run `law` alone from `config.dagger_starts` starts in `config.start_box` (seed
    plan_seed + 300 + r), label the states its failures visit at 0.5, 1.5 and 3 s (`collect_labels`
    with `teacher`, plan streams plan_seed + 1000 (r + 1)), and fit a fresh law on all labels (unless
    `refit` is False: the last round leaves its fits to `_gate_fits`, which runs them side by side).
    Returns (law, X, U, counts of the round); without `refit` the law is None where labels were added. In round 0, when `law` fails from every start, fewer
    than half of them end in the near box (`ends_near`) and `config.stop_when_lost`, nothing is
    labelled: `law`, X and U come back as they were, the counts with "stopped": True. A residual law
    runs on `networks` (the run's controller without a fallback, `_fit`), everywhere but at x*."""
    start = time.perf_counter() if start is None else start
    x0 = uniform_states(system, config.dagger_starts, config.start_box, config.plan_seed + 300 + r)
    traj = simulate(system, networks.with_fallback(law) if law.residual else law.law, x0, T=config.judge_T, dt=PLAN_STEP, stop_converged=True)
    failed = np.flatnonzero(~success(traj, system))  # failures never stop early: their records are whole
    if r == 0 and failed.size == len(x0) and config.stop_when_lost and ends_near(traj.x[:, -1], system).mean() < 0.5:
        if progress:
            print(f"DAgger round 1/{config.dagger}: the law fails from all {failed.size} starts, most ending outside the near box: no DAgger rounds "
                  f"(stop_when_lost), the gate judges the first fit  [{time.perf_counter() - start:.0f} s]", flush=True)
        return law, X, U, {"failed": int(failed.size), "visited": 0, "teacher": 0, "plans": 0, "mse": None, "stopped": True}
    visited = np.concatenate([traj.x[failed, round(t / PLAN_STEP)] for t in (0.5, 1.5, 3.0)]) if failed.size else x0[:0]
    if progress:
        print(f"DAgger round {r + 1}/{config.dagger}: the law fails from {failed.size} of {config.dagger_starts} starts; "
              f"labelling the {len(visited)} states they visit  [{time.perf_counter() - start:.0f} s]", flush=True)
    if visited.size:
        Xr, Ur, taught, recovered = collect_labels(system, visited, config.plan_seed + 1000 * (r + 1), config, progress, teacher, store, f"dagger{r + 1}")
        X, U = np.concatenate([X, Xr]), np.concatenate([U, Ur])
    else:
        taught = recovered = 0
    mse = None
    if refit:
        law, mse = _fit(system, X, U, config, networks, f"recovery: fit, DAgger {r + 1}" if progress else None)
    elif visited.size:
        law = None  # fitted to the labels of this round by `_gate_fits`
    if progress:
        fitted = f"refitted on {len(X)} labels, mean squared error {mse:.4f}" if mse is not None else f"{len(X)} labels"
        print(f"DAgger round {r + 1}/{config.dagger}: of those states {_teacher_name(config)} brings {taught} to x*, plans {recovered}; {fitted}  "
              f"[{time.perf_counter() - start:.0f} s]", flush=True)
    return law, X, U, {"failed": int(failed.size), "visited": int(len(visited)), "teacher": int(taught), "plans": int(recovered), "mse": mse}


def _teacher_name(config: RecoveryConfig) -> str:
    return "saturated LQR" if config.teacher == "lqr" else "the run's law"


def ends_near(x: np.ndarray, system) -> np.ndarray:
    """(N, n) states -> (N,) bool: inside the near box x* + NEAR_SCALE·(X − x*) (angles wrapped to
    within π of x*). A first fit whose trajectories all fail yet end there (at rest just off x*, its
    output at x* not quite u*) is near a working law, and DAgger's labels of the states it visits
    are what it lacks."""
    lo, hi = scaled_box(system, NEAR_SCALE)
    x_star = np.asarray(system.x_star, dtype=np.float64)
    d = wrap_angles(np.atleast_2d(x) - x_star, np.asarray(system.angle_mask, dtype=bool))
    return np.all((d >= lo - x_star) & (d <= hi - x_star), axis=-1)


def recover(run_or_path, config: RecoveryConfig = RecoveryConfig(), progress: bool = True, *, keep: bool = False) -> dict:
    """Fit, gate and save a recovery law for a run (see the module docstring); returns the summary
    entry written to summary.json → "recovery". The run directory gets ``recovery.npz`` when the
    gate keeps the law (or `keep` forces it), else ``recovery-refused.npz`` for `regate`; an earlier
    recovery law is replaced either way. Where no start reaches x* the stage refuses (the entry says
    why, ``"refused": True``) and the run keeps its law; any other failure inside the stage is one
    `IdapbcError` line, the run as it was (`_failures.stage_errors`)."""
    run = resolve_run(run_or_path)
    with stage_errors("the recovery stage", run.path, f"`idapbc-pin train --resume {run.path}` (or `idapbc-pin recover {run.path}`) runs it "
                      "again, reading back its finished chunks of plans; --recover never skips it."):
        return _recover(run, config, progress, keep)


def _recover(run, config: RecoveryConfig, progress: bool, keep: bool) -> dict:
    """`recover`'s steps on a resolved run."""
    system = planning_system(run.system)  # an input without a limit plans within LQR's largest demand
    torch.set_num_threads(1)
    start = time.perf_counter()
    x0 = uniform_states(system, config.starts, config.start_box, config.plan_seed)
    teacher = run.own_controller if config.teacher == "run" else None
    networks = run.own_controller.with_fallback(None)  # the input a recovery law's apply gets
    store = ChunkStore(run.path)  # chunks a killed stage finished are read back, not planned again
    counts = config.starts >= PILOT_MIN_STARTS
    X, U, taught, recovered = collect_labels(system, x0, config.plan_seed, config, progress, teacher, store, "labels", pilot=LABEL_PILOT if counts else 0)
    counted = {"teacher": config.teacher, "teacher_starts": int(taught), "plan_starts": int(recovered)}
    if not len(X):  # nothing reached x*: with a pilot, of its starts only (the others were not planned)
        tried = pilot_starts(config.starts) if counts else config.starts
        which = "" if tried == config.starts else f" (the first {tried} of {config.starts} were tried)"
        reason = f"no start state reached x*{which}, with {_teacher_name(config)} or with a plan: no plan to fit a recovery law to"
        return _refuse(run, reason, start, store, progress, **counted, planned_starts=tried)
    save_labels(run.path, X, U)  # after every labelling step: an interrupted recover keeps its plans for --refit
    if progress:
        print(f"labels: {_teacher_name(config)} brings {taught} of {config.starts} starts to x*, plans {recovered} of the other "
              f"{config.starts - taught}; {len(X)} labels  [{time.perf_counter() - start:.0f} s]", flush=True)
    if counts and config.teacher == "run" and recovered < config.margin:  # the gate asks `margin` more than the run's law brings
        reason = (f"plans reached only {recovered} of the {config.starts - taught} starts the run's law loses, fewer than the {config.margin} more "
                  f"states the gate asks of a recovery law (its margin): no law was fitted (`idapbc-pin recover {run.path} --refit` fits and gates one on "
                  "the saved labels)")
        return _refuse(run, reason, start, store, progress, **counted, labels=int(len(X)), labels_file=RECOVERY_LABELS_FILE)
    library = label_library(system, X, U, config.library_speed, config.library_every, min(config.inner_scales)) if config.library and not config.always_fit else None
    known = {}  # the run's law's gate verdicts, simulated once for both gates (`choose_fit`)
    verdict, first = library_first(run, library, len(X) // LABEL_PATH, config, progress, known) if library is not None else ("fit", None)
    if verdict != "fit":  # kept alone, or lost by so much that no fit of its paths is tried
        (law, gate), mse, rounds, skipped = (library, first), None, [], {"fits_skipped": True} | ({"library_lost": True} if verdict == "lost" else {})
    else:
        (law, gate), mse, rounds, X, U = _fits_and_dagger(run, system, X, U, config, progress, start, teacher, networks, store, known)
        skipped = {}
    entry = _verdict(gate, config, keep) | skipped | {
        "labels": int(len(X)), "labels_file": RECOVERY_LABELS_FILE, "teacher": config.teacher, "teacher_starts": int(taught), "plan_starts": int(recovered), "first_fit_mse": mse, "dagger": rounds,
        "seconds": round(time.perf_counter() - start, 1),
    }
    entry = _save_and_tell(run, law, entry, config, progress, start)
    store.clear()
    return entry


def _refuse(run, reason: str, start: float, store: ChunkStore, progress: bool, **extra) -> dict:
    """The stage refuses: says why, drops its chunks of plans and records the refusal (`record_refusal`)."""
    if progress:
        print(f"recovery stage: {reason}; the run keeps its law as it is  [{time.perf_counter() - start:.0f} s]", flush=True)
    store.clear()
    return record_refusal(run, "recovery", reason, start, **extra)


def _fits_and_dagger(run, system, X, U, config: RecoveryConfig, progress: bool, start: float, teacher, networks, store, known: dict | None = None):
    """Steps 2–3 and the gate of the fits (with the library beside them; `known` as in `choose_fit`):
    ((law, gate), the first fit's mse, the DAgger rounds, X, U with the rounds' labels)."""
    try:
        law, mse = _fit(system, X, U, config, networks, "recovery: fit" if progress else None)
        if progress:
            print(f"fitted: mean squared error {mse:.4f} (u/ū)  [{time.perf_counter() - start:.0f} s]", flush=True)
        rounds = []
        for r in range(config.dagger):
            last = r == config.dagger - 1 and config.fits > 1  # its fits run side by side in `_gate_fits`
            law, X, U, info = dagger_round(system, law, X, U, r, config, progress, start, teacher, networks, store, refit=not last)
            rounds.append(info)
            if info.get("stopped"):
                break
            save_labels(run.path, X, U)
    except KeyboardInterrupt:
        if progress:
            print(f"recover interrupted: the labels so far are in {run.path / RECOVERY_LABELS_FILE}; "
                  f"`idapbc-pin recover {run.path} --refit` fits and gates a law on them without the plans", flush=True)
        raise
    return _gate_fits(run, system, law, X, U, config, progress, start, networks, known), mse, rounds, X, U


def _gate_fits(run, system, law: RecoveryLaw | None, X: np.ndarray, U: np.ndarray, config: RecoveryConfig, progress: bool, start: float, networks,
               known: dict | None = None):
    """Fit the laws of `config.fits` seeds (from `config.fit_seed`) to the labels that `law` does
    not stand for already (the fit of the first seed; None: every seed, in parallel), on `system`
    (the run's, with `plans.plan_bound` as its limits, as `law` was fitted), and let the gate choose
    among all (`choose_fit`); returns (the chosen law, its gate). `networks`: as in `_fit`."""
    laws = [] if law is None else [law]
    base = base_inputs(networks, X, system.effort) if config.form == "residual" else None
    jobs = [(system, X, U, config.width, config.steps, config.fit_seed + k, base, None, config.batch) for k in range(len(laws), config.fits)]
    if progress and law is None:
        print(f"fitting {config.fits} laws to the {len(X)} labels side by side ...", flush=True)
    for k, (more, mse) in enumerate(process_map(fit_job, jobs, config.workers, config.ray), start=len(laws)):
        laws.append(more)
        if progress:
            print(f"fit {k + 1}/{config.fits} (seed {config.fit_seed + k}): mean squared error {mse:.4f}  [{time.perf_counter() - start:.0f} s]", flush=True)
    library = label_library(system, X, U, config.library_speed, config.library_every, min(config.inner_scales)) if config.library else None
    if progress and library is not None:
        print(f"library: the {len(X) // LABEL_PATH} labelled paths read at the nearest point ({library.points} points), judged beside the fits", flush=True)
    k, gate = choose_fit(run, laws + ([library] if library is not None else []), config, progress, known)
    if library is not None:
        gate |= {"library": k == len(laws), "library_points": library.points}
    return (laws + [library])[k], gate


def label_library(system, X: np.ndarray, U: np.ndarray, speed_weight: float, every: int = 1, inner: float = 0.0) -> LibraryLaw | None:
    """The labels X (K, n), U (K, m) as the paths they were sampled from (`LABEL_PATH` labels each,
    every LABEL_EVERY ticks), each knot of each read at the nearest point (`LibraryLaw`,
    `trajectory.library.paths_law`; momenta weighted `speed_weight` / M_ii(q*)), then thinned for the
    exported controller's brute-force search: the points inside the inner box `inner`·s are dropped
    (the IDA-PBC law's there) and of the others every `every`-th is kept. None where the labels are
    not whole paths."""
    if not len(X) or len(X) % LABEL_PATH:
        return None
    step = int(round(KNOT / (LABEL_EVERY * PLAN_STEP)))
    P = len(X) // LABEL_PATH
    return LibraryLaw.from_paths(system, X.reshape(P, LABEL_PATH, system.n)[:, ::step], U.reshape(P, LABEL_PATH, system.m)[:, ::step],
                                 speed_weight, every, inner)


def _fit(system, X: np.ndarray, U: np.ndarray, config: RecoveryConfig, networks, progress: str | None = None) -> tuple[RecoveryLaw, float]:
    """`fit_recovery_law` with `config`'s width, steps, fit seed and form (residual: on the inputs of
    `networks`, the run's controller without a fallback, at X); `progress`: the label of its bar."""
    base = base_inputs(networks, X, system.effort) if config.form == "residual" else None
    return fit_recovery_law(system, X, U, config.width, config.steps, config.fit_seed, base, progress, config.batch)


def _verdict(gate: dict, config: RecoveryConfig, keep: bool) -> dict:
    """The summary entry's verdict: the gate's (or forced by `keep`), its inner box, the seed of the
    law it judged (the best of `config.fits`) and the settings."""
    return {"used": bool(gate["used"] or keep), "forced": bool(keep and not gate["used"]), "inner_scale": gate["inner_scale"], "level": gate.get("level"),
            "fit_seed": None if gate.get("library") else config.fit_seed + gate.get("fit", 0), "library": bool(gate.get("library", False)), "gate": gate, "config": asdict(config) | {"inner_scales": list(config.inner_scales), "levels": list(config.levels)}}


def _save_and_tell(run, law: RecoveryLaw, entry: dict, config: RecoveryConfig, progress: bool, start: float) -> dict:
    """Save `law` and `entry` (`save_recovery`), with the governor's margin for a kept law
    (`catch_margin`), and print the gate's line; returns `entry`."""
    entry = {key: value for key, value in entry.items() if key != "governor_margin"}  # judged afresh (a regate's earlier entry had one)
    save_recovery(run, law, entry)
    if entry["used"]:
        entry = entry | {"governor_margin": catch_margin(run.system, run.controller, config.gate_states, run.config.seed, config.judge_T, config.workers)}
        run.summary = dict(run.summary) | {"recovery": dict(run.summary["recovery"]) | {"governor_margin": entry["governor_margin"]}}
        write_json(run.path / "summary.json", run.summary)
    if progress:
        forced = f"; kept anyway (--keep), inner box r = {entry['inner_scale']:g}" if entry["forced"] else ""
        print(f"{format_gate(entry['gate'], config.margin, config.half_loss)}{forced}  [{time.perf_counter() - start:.0f} s]", flush=True)
        if entry.get("governor_margin", ENERGY_MARGIN) > ENERGY_MARGIN:
            print(f"governor: its energy clause starts {entry['governor_margin']:g} ΔE above the upright, where this law's own catches from the box reach", flush=True)
    return entry
