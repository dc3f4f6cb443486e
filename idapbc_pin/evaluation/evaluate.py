"""Closed-loop evaluation of a run: region of attraction of Neural IDA-PBC next to LQR.

`evaluate_run` simulates the true plant (DESIGN §4) from the same uniform states of the training
domain and of its half-size box under the learned controller and the LQR baseline (Q = I, R = I),
with the actuators' effort limits applied to both unless lifted, finds both ROA radii
(`idapbc_pin.evaluation.radius`, reusing those two boxes' rollouts) and writes ``evaluation.json`` into the
run directory.
"""

from __future__ import annotations

import sys
import time
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass

from tqdm.auto import tqdm

from .._io import finite_or_none, write_json
from .._parallel import JobPool
from ..control.baseline import LQRController
from ..recovery.law import RecoveryLaw
from ..run import Run
from ..sim.limits import input_limits
from ..sim.step import judge_step
from .radius import RadiusResult, radius_job, radius_result, run_radius_job
from .roa import RoaResult, roa_result, roa_states, run_score_job, score_job

__all__ = ["BASELINE", "Evaluation", "baseline_job", "evaluate_run", "format_evaluation", "run_baseline_job"]

#: The baseline controller's name in every evaluation.
BASELINE = "LQR"


@dataclass(frozen=True)
class Evaluation:
    """ROA results per box ("domain", "half") and the ROA radii, for "NIDA-PBC" and "LQR".

    radius : the `RadiusResult` (None when skipped).  limits : whether the effort limits applied.
    """

    run: Run
    results: dict[str, RoaResult]
    radius: RadiusResult | None = None
    limits: bool = True

    def record(self) -> dict:
        """JSON-ready summary: per box and controller, success rate and medians, and NIDA-PBC's lead over
        LQR on the box's states (``"paired"``: counts, interval, McNemar's p; `evaluation.paired`) and both
        median settling times on the states both reach (``"common_settling"``); the radii
        ``"radius": {controller: s}`` (with ``"radius_search"``: settings, brackets, probes) and the
        input bound applied (``"limits"``)."""
        out = {}
        for box, res in self.results.items():
            out[box] = {
                name: {
                    "success_rate": s.success_rate,
                    "median_settling_time": finite_or_none(s.median_settling_time),
                    "median_offset": finite_or_none(s.median_offset),
                    "median_peak_input": finite_or_none(s.median_peak_input),
                    "diverged": s.n_diverged,
                    "wall_time": s.wall_time,
                }
                for name, s in res.scores.items()
            }
            out[box]["n"] = int(res.x0.shape[0])
            out[box]["seed"] = res.seed
            out[box]["T"] = res.T
            out[box]["dt"] = res.dt
            out[box]["hold"] = res.hold  # the law sampled once per step of dt and held (a 1/dt Hz controller)
            if {"NIDA-PBC", "LQR"} <= set(res.scores):  # the lead on these states, its interval and p-value
                out[box]["paired"] = res.compare("NIDA-PBC", "LQR").to_dict()
                common = res.common_settling("NIDA-PBC", "LQR")  # median settling on the states both reach
                out[box]["common_settling"] = {k: v if k == "states" else finite_or_none(v) for k, v in common.items()}
        out["limits"] = input_limits(self.run.system, self.limits).to_json()
        if self.radius is not None:
            out["radius"] = dict(self.radius.radius)
            out["radius_search"] = self.radius.to_dict()
        return out


def evaluate_run(
    run: Run,
    n: int = 200,
    T: float = 20.0,
    dt: float | None = None,
    seed: int = 0,
    rho: float | None = None,
    boxes=("domain", "half"),
    *,
    limits: bool = True,
    radius: bool = True,
    workers: int = 1,
    progress: bool = False,
    baseline=None,
) -> Evaluation:
    """ROA of the run's controller (optionally with extra damping ρ) and LQR on `n` states per box,
    and their ROA radii on `n` states per scale (the boxes' rollouts reused at s = 1 and 0.5).

    dt : RK4 step and control period (s); None: 2 ms, or shorter where either loop is stiffer at x* (`judge_step`).
    limits : apply the system's effort limits to both controllers (False lifts them).
    radius : find the ROA radii (False skips them; they cost a few more ROA evaluations).
    workers : processes sharing the simulations (1: in this process, 0: one per core; `_simulate`); the count
        changes the time, never a result.
    progress : show a progress bar over the simulation jobs (with an ETA).
    baseline : LQR's part of this evaluation computed beforehand (`run_baseline_job`'s result, or a
        future of it, e.g. run beside the training by `idapbc-pin train`); used where its settings are
        this evaluation's (else simulated again), so the results are the same either way.
    """
    ctrl = run.controller if rho is None else run.controller.with_damping(rho)
    controllers = {"NIDA-PBC": ctrl, BASELINE: LQRController(run.system)}
    dt = judge_step(run.system, controllers, T, dt)
    if baseline is not None and not isinstance(baseline, dict):
        baseline = baseline.result()  # a future: wait for it
    settings = (int(n), float(T), float(dt), int(seed), tuple(boxes), bool(limits), bool(radius))
    done = {BASELINE: baseline} if baseline is not None and baseline["settings"] == settings else {}
    results, found = _simulate(run.system, controllers, tuple(boxes), n, seed, T, dt, bool(limits), radius, workers, progress, done)
    evaluation = Evaluation(run, results, found, bool(limits))
    record = evaluation.record()
    record["rho"] = ctrl.rho
    law = getattr(ctrl, "fallback", None)
    record["recovery"] = isinstance(law, RecoveryLaw)  # NIDA-PBC used a recovery law outside an inner box (`idapbc-pin recover`)
    record["fallback"] = law is not None and not record["recovery"]  # NIDA-PBC used the anchor's linear law outside the training box
    record["inside_gain"] = float(getattr(law, "inside_gain", 1.0)) if record["fallback"] else 1.0  # and scaled its law inside it
    record["inside_ramp"] = list(getattr(law, "inside_ramp", (0.0, 0.0))) if record["fallback"] else [0.0, 0.0]  # from 1 near x*
    write_json(run.path / "evaluation.json", record)
    return evaluation


def _simulate(system, controllers: dict, boxes: tuple, n: int, seed: int, T: float, dt: float, limits: bool, radius: bool,
              workers: int, progress: bool = False, done: dict | None = None) -> tuple[dict[str, RoaResult], RadiusResult | None]:
    """Every controller on every box, and each controller's radius search once its own boxes are in
    (they are its probes at s = 1 and 0.5), on one pool of `workers` processes. A free worker takes
    the first ready job in the controllers' order (boxes, then the search): the first controller's
    search, the longest job (NIDA-PBC's bisection), starts as soon as it can, while the other
    controllers' rollouts fill the other workers. Each job is the computation `roa` and
    `roa_radius` run, so the results are theirs, whatever the workers. `progress`: a bar over the
    jobs, with the elapsed time and an ETA. `done`: {controller: `run_baseline_job` result} already
    computed, whose jobs are not run again."""
    t0 = time.perf_counter()
    names, nb = list(controllers), len(boxes)
    states = {box: roa_states(system, n, box, seed) for box in boxes}
    known_box = {box: scale for scale, box in ((1.0, "domain"), (0.5, "half")) if box in boxes}
    ready = {(i, j): (run_score_job, score_job(system, name, controllers[name], states[box], T, dt, limits=limits, stop_converged=True))
             for i, name in enumerate(names) for j, box in enumerate(boxes)}
    futures, in_flight = {}, {}
    for i, name in enumerate(names):
        if name in (done or {}):
            for j, box in enumerate(boxes):
                del ready[i, j]
                futures[i, j] = _completed(done[name]["scores"][box])
            if radius:
                futures[i, nb] = _completed(done[name]["search"])
    bar = tqdm(total=len(ready) + int(radius) * sum(name not in (done or {}) for name in names), disable=not progress, desc=f"evaluate {getattr(system, 'name', '')}", unit="job",
               dynamic_ncols=True, mininterval=0.5 if sys.stderr.isatty() else 15.0)
    with JobPool(workers) as pool, bar:
        while ready or in_flight:
            while ready and len(in_flight) < pool.workers:  # the first ready job in the controllers' order
                key = min(ready)
                futures[key] = future = pool.submit(*ready.pop(key))
                in_flight[future] = key
            done = [f for f in in_flight if f.done()] or list(wait(in_flight, return_when=FIRST_COMPLETED).done)
            for future in done:
                future.result()  # a worker's error surfaces here
                i, j = in_flight.pop(future)
                bar.update()
                if radius and j < nb and (i, nb) not in ready and (i, nb) not in futures and all(
                        (i, b) in futures and futures[i, b].done() for b in range(nb)):
                    name = names[i]
                    known = {scale: roa_result(system, box, states[box], T, dt, seed, {name: futures[i, boxes.index(box)].result()},
                                               limits=limits) for box, scale in known_box.items()}
                    ready[i, nb] = (run_radius_job, radius_job(system, name, controllers[name], n=n, seed=seed, T=T, dt=dt, known=known,
                                                               limits=limits))
    results = {box: roa_result(system, box, states[box], T, dt, seed, {name: futures[i, j].result() for i, name in enumerate(names)},
                               limits=limits) for j, box in enumerate(boxes)}
    found = None
    if radius:
        found = radius_result(system, {name: futures[i, nb].result() for i, name in enumerate(names)}, n=n, seed=seed, T=T, dt=dt,
                              limits=limits, wall_time=time.perf_counter() - t0)
    return results, found


def _completed(value) -> Future:
    """A future that holds `value` already."""
    future = Future()
    future.set_result(value)
    return future


def baseline_job(system, n: int = 200, T: float = 20.0, dt: float | None = None, seed: int = 0, boxes=("domain", "half"), *,
                 limits: bool = True, radius: bool = True) -> tuple:
    """The job of `run_baseline_job`: the LQR part of `evaluate_run` with these settings, which does
    not depend on the trained law, so `idapbc-pin train` runs it in a worker process beside the
    training (which takes one core). dt None: the judge's step for LQR's loop (`judge_step`); an
    evaluation whose law asks for a shorter step simulates LQR again."""
    lqr = LQRController(system)
    return (system, lqr, int(n), float(T), judge_step(system, {BASELINE: lqr}, T, dt), int(seed), tuple(boxes), bool(limits), bool(radius))


def run_baseline_job(job) -> dict:
    """Worker: LQR on the boxes and its radius search, for a `baseline_job`: {"settings", "scores":
    {box: ControllerScore}, "search": its radius search (None without)}, what `evaluate_run` takes as
    `baseline`."""
    system, lqr, n, T, dt, seed, boxes, limits, radius = job
    results, found = _simulate(system, {BASELINE: lqr}, boxes, n, seed, T, dt, limits, radius, workers=1)
    search = None if found is None else tuple(getattr(found, a)[BASELINE] for a in ("radius", "bracket", "below", "above", "probes"))
    return {"settings": (n, T, dt, seed, boxes, limits, radius), "scores": {box: results[box][BASELINE] for box in boxes}, "search": search}


def format_evaluation(evaluation: Evaluation) -> str:
    """The ROA tables, one per box, and the ROA radii."""
    parts = [res.table() for res in evaluation.results.values()]
    if evaluation.radius is not None:
        parts.append(evaluation.radius.line())
    return "\n\n".join(parts)
