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
from ..recovery.law import InnerSwitch
from ..recovery.swing_law import KeptBoxLaw
from ..run import Run
from ..sim.limits import input_limits
from ..sim.step import judge_step
from .radius import RadiusResult, RadiusSearch, radius_job, radius_result, run_probe_job
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
    reuse: Evaluation | None = None,
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
        this evaluation's (else simulated again), so the results are the same either way; one
        computed without the radius serves an evaluation without it.
    reuse : an earlier `Evaluation` of the same law with these settings (e.g. one without the radius,
        printed first): its box rollouts are taken as they are, so only what it lacks (the radius
        searches) is simulated; the results are those of an evaluation from scratch.
    """
    ctrl = run.controller if rho is None else run.controller.with_damping(rho)
    controllers = {"NIDA-PBC": ctrl, BASELINE: LQRController(run.system)}
    dt = judge_step(run.system, controllers, T, dt)
    if baseline is not None and not isinstance(baseline, dict):
        baseline = baseline.result()  # a future: wait for it
    settings = (int(n), float(T), float(dt), int(seed), tuple(boxes), bool(limits))
    done = {BASELINE: baseline} if baseline is not None and _serves(baseline, settings, radius) else {}
    if reuse is not None:
        done = _reused(reuse, settings) | done
    results, found = _simulate(run.system, controllers, tuple(boxes), n, seed, T, dt, bool(limits), radius, workers, progress, done)
    evaluation = Evaluation(run, results, found, bool(limits))
    record = evaluation.record()
    record["rho"] = ctrl.rho
    law = getattr(ctrl, "fallback", None)
    record["swing_up"] = isinstance(law, KeptBoxLaw)  # NIDA-PBC used a swing-up law where the posture left the training box
    law = law.inner if record["swing_up"] else law
    record["recovery"] = isinstance(law, InnerSwitch)  # NIDA-PBC used a recovery law outside an inner box (`idapbc-pin recover`)
    record["fallback"] = law is not None and not record["recovery"]  # NIDA-PBC used the anchor's linear law outside the training box
    record["inside_gain"] = float(getattr(law, "inside_gain", 1.0)) if record["fallback"] else 1.0  # and scaled its law inside it
    record["inside_ramp"] = list(getattr(law, "inside_ramp", (0.0, 0.0))) if record["fallback"] else [0.0, 0.0]  # from 1 near x*
    write_json(run.path / "evaluation.json", record)
    return evaluation


def _serves(part: dict, settings: tuple, radius: bool) -> bool:
    """Whether a `run_baseline_job` result (or a `_reused` part) has these settings, and its radius
    search where `radius` asks for one."""
    return tuple(part["settings"][:6]) == settings and (not radius or part.get("search") is not None)


def _reused(evaluation: Evaluation, settings: tuple) -> dict:
    """{controller: its part of `evaluation`, as `_simulate` takes it in `done`} when `evaluation` ran
    with `settings` (n, T, dt, seed, boxes, limits), else {}: box scores, and the radius search where
    it has one."""
    first = next(iter(evaluation.results.values()))
    mine = (int(first.x0.shape[0]), float(first.T), float(first.dt), int(first.seed), tuple(evaluation.results), bool(evaluation.limits))
    if mine != settings:
        return {}
    found = evaluation.radius
    out = {}
    for name in first.scores:
        search = None if found is None else tuple(getattr(found, a)[name] for a in ("radius", "bracket", "below", "above", "probes"))
        out[name] = {"settings": settings, "scores": {box: res.scores[name] for box, res in evaluation.results.items()}, "search": search}
    return out


def _simulate(system, controllers: dict, boxes: tuple, n: int, seed: int, T: float, dt: float, limits: bool, radius: bool,
              workers: int, progress: bool = False, done: dict | None = None) -> tuple[dict[str, RoaResult], RadiusResult | None]:
    """Every controller on every box, and each controller's radius search once its own boxes are in
    (they are its probes at s = 1 and 0.5), on one pool of `workers` processes. A free worker takes
    the first ready job in the controllers' order (boxes, then the search's next probe): the first
    controller's search, the longest chain of jobs (NIDA-PBC's bisection), goes on as soon as it can,
    while the other controllers' rollouts fill the other workers; a worker with nothing else to do
    probes ahead for a search (`RadiusSearch.wanted`). Each job is the computation `roa` and
    `roa_radius` run, so the results are theirs, whatever the workers. `progress`: a bar over the
    boxes and the searches, with the elapsed time and an ETA. `done`: {controller: `run_baseline_job`
    result} already computed, whose jobs are not run again."""
    t0 = time.perf_counter()
    names, nb, done = list(controllers), len(boxes), done or {}
    states = {box: roa_states(system, n, box, seed) for box in boxes}
    known_box = {box: scale for scale, box in ((1.0, "domain"), (0.5, "half")) if box in boxes}
    ready = {(i, j): (run_score_job, score_job(system, name, controllers[name], states[box], T, dt, limits=limits, stop_converged=True))
             for i, name in enumerate(names) for j, box in enumerate(boxes) if name not in done}
    scores = {(i, j): done[name]["scores"][box] for i, name in enumerate(names) if name in done for j, box in enumerate(boxes)}
    found = {i: done[name]["search"] for i, name in enumerate(names) if name in done and radius and done[name].get("search") is not None}
    searches: dict[int, RadiusSearch] = {}
    in_flight: dict[Future, tuple] = {}
    bar = tqdm(total=len(ready) + int(radius) * (len(names) - len(found)), disable=not progress,
               desc=f"evaluate {getattr(system, 'name', '')}", unit="job", dynamic_ncols=True, mininterval=0.5 if sys.stderr.isatty() else 15.0)

    def unfinished() -> bool:
        return len(scores) < len(names) * nb or (radius and len(found) < len(names))

    def close_if_over(i: int) -> None:  # a search with its result leaves the pool's work
        if (result := searches[i].result()) is not None:
            found[i] = result
            del searches[i]
            bar.update()

    def start_search(i: int) -> None:  # once a controller's boxes are in: its search, the boxes as its first probes
        name = names[i]
        known = {scale: roa_result(system, box, states[box], T, dt, seed, {name: scores[i, boxes.index(box)]}, limits=limits)
                 for box, scale in known_box.items()}
        searches[i] = radius_job(system, name, controllers[name], n=n, seed=seed, T=T, dt=dt, known=known, limits=limits)
        close_if_over(i)  # decided by the boxes alone

    with JobPool(workers) as pool, bar:
        for i, name in enumerate(names):  # controllers whose boxes were done before: their searches start now
            if radius and name in done and i not in found:
                start_search(i)
        while unfinished():
            ready = {key: job for key, job in ready.items() if len(key) == 2}  # boxes; then each search's next probe, unless in flight
            ready |= {(i, nb, s): (run_probe_job, job) for i, search in searches.items() for s, job in search.wanted()[:1]
                      if (i, nb, s) not in in_flight.values()}
            while ready and len(in_flight) < pool.workers:  # the first ready job in the controllers' order
                key = min(ready)
                in_flight[pool.submit(*ready.pop(key))] = key
            if len(in_flight) < pool.workers:  # a spare worker: the probe a search needs next if its current one passes
                ahead = [((i, nb, s), job) for i, search in searches.items() for s, job in search.wanted(spare=True)[1:]
                         if (i, nb, s) not in in_flight.values()]
                for key, job in ahead[:1]:
                    in_flight[pool.submit(run_probe_job, job)] = key
            finished = [f for f in in_flight if f.done()] or list(wait(in_flight, return_when=FIRST_COMPLETED).done)
            for future in finished:
                key = in_flight.pop(future)
                value = future.result()  # a worker's error surfaces here
                if len(key) == 3:  # a probe of a search (or a probe ahead for a search already over: dropped)
                    i, _, s = key
                    if i not in searches:
                        continue
                    searches[i].record(s, value)
                    close_if_over(i)
                    continue
                scores[key] = value
                bar.update()
                i = key[0]
                if radius and i not in found and i not in searches and all((i, b) in scores for b in range(nb)):
                    start_search(i)
    # probes ahead still running when every search is over were guesses that turned out wrong: the pool stops them
    results = {box: roa_result(system, box, states[box], T, dt, seed, {name: scores[i, j] for i, name in enumerate(names)},
                               limits=limits) for j, box in enumerate(boxes)}
    radii = None
    if radius:
        radii = radius_result(system, {name: found[i] for i, name in enumerate(names)}, n=n, seed=seed, T=T, dt=dt,
                              limits=limits, wall_time=time.perf_counter() - t0)
    return results, radii


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
    return {"settings": (n, T, dt, seed, boxes, limits), "scores": {box: results[box][BASELINE] for box in boxes}, "search": search}


def format_evaluation(evaluation: Evaluation) -> str:
    """The ROA tables, one per box, and the ROA radii."""
    parts = [res.table() for res in evaluation.results.values()]
    if evaluation.radius is not None:
        parts.append(evaluation.radius.line())
    return "\n\n".join(parts)
