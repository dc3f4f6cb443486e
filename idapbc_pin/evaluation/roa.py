"""Region of attraction: several controllers from the very same uniform initial states, scored by
the DESIGN §4 metrics ("How we measure"). `score` is the one place a rollout becomes a score."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .._parallel import process_map
from ..sim.integrate import Controller, simulate
from ..sim.limits import InputLimits, input_limits
from ..sim.metrics import equilibrium_offset, peak_input, settled, settling_time, success
from ..sim.states import evaluation_box, uniform_states
from ..sim.step import judge_step
from ..sim.trajectory import Trajectory
from .paired import PairedComparison, paired_comparison

__all__ = ["ControllerScore", "RoaResult", "roa", "roa_result", "roa_states", "run_score_job", "score", "score_job"]


def _median(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else math.nan


@dataclass(frozen=True, eq=False)
class ControllerScore:
    """One controller's results on the ROA states (per-state arrays (N,), summaries as properties).

    Attributes
    ----------
    name : controller name.
    success : (N,) bool, DESIGN §4 criterion.
    settling_time : (N,) s, nan where never settled.
    offset : (N,) ‖x̄ − x*‖ over the last window; nan where diverged.
    settled : (N,) bool, at rest over the last window (anywhere).
    peak_input : (N,) max |u|.
    diverged : (N,) bool.
    wall_time : simulation wall time, s.
    """

    name: str
    success: np.ndarray
    settling_time: np.ndarray
    offset: np.ndarray
    settled: np.ndarray
    peak_input: np.ndarray
    diverged: np.ndarray
    wall_time: float

    @property
    def success_rate(self) -> float:
        """Fraction of states that succeed."""
        return float(self.success.mean()) if self.success.size else math.nan

    @property
    def median_settling_time(self) -> float:
        """Median settling time of the successes, s (nan if none)."""
        return _median(self.settling_time[self.success])

    @property
    def median_offset(self) -> float:
        """Median equilibrium offset of the trajectories that settle (at rest over the last window)."""
        return _median(self.offset[self.settled])

    @property
    def median_peak_input(self) -> float:
        """Median peak |u| over all states."""
        return _median(self.peak_input)

    @property
    def n_diverged(self) -> int:
        """Number of diverged states."""
        return int(self.diverged.sum())


@dataclass(frozen=True, eq=False)
class RoaResult:
    """ROA estimate of several controllers from the same uniform initial states.

    Attributes
    ----------
    system : system name.
    box : (lo, hi) evaluation box, each (n,).
    box_name : ``"domain"``, ``"half"`` or ``"custom"``.
    x0 : (N, n) initial states.
    T, dt : horizon and step, s.
    seed : seed of the states.
    hold : the law was sampled once per step of dt and held (True), or evaluated at every RK4 stage.
    scores : {controller name: ControllerScore}, in the order given.
    limits : the input bound every controller was clipped to (`InputLimits`; None: not recorded).
    """

    system: str
    box: tuple[np.ndarray, np.ndarray]
    box_name: str
    x0: np.ndarray
    T: float
    dt: float
    seed: int
    scores: Mapping[str, ControllerScore]
    limits: InputLimits | None = None
    hold: bool = True

    def __getitem__(self, name: str) -> ControllerScore:
        return self.scores[name]

    def compare(self, a: str, b: str, level: float = 0.95) -> PairedComparison:
        """Controller `a` against `b` on these states: the lead, its interval and McNemar's p-value
        (`paired.paired_comparison`)."""
        return paired_comparison(self.scores[a].success, self.scores[b].success, a, b, level)

    def common_settling(self, a: str, b: str) -> dict:
        """Median settling times of `a` and `b` on the states both bring to x* (s; nan where none):
        ``{"states": k, a: t_a, b: t_b}``. The per-controller medians of `table` are over each one's
        own successes, so a controller that also reaches the far states LQR fails from is timed on
        harder starts; on the common states both are timed from the same ones."""
        sa, sb = self.scores[a], self.scores[b]
        both = sa.success & sb.success
        return {"states": int(both.sum()), a: _median(sa.settling_time[both]), b: _median(sb.settling_time[both])}

    def table(self) -> str:
        """The scores side by side, one row per controller."""
        head = (
            f"ROA of {self.system}: {self.x0.shape[0]} states uniform in the {self.box_name} box "
            f"(seed {self.seed}), T = {self.T:g} s, dt = {self.dt:g} s"
            + (f" (law sampled and held at {1.0 / self.dt:.4g} Hz)" if self.hold else " (law at every RK4 stage)")
        )
        if self.limits is not None:
            head += f"; {self.limits.describe()}"
        peak = "peak |u|" if self.limits is None or self.limits.bound is None else "peak |u| / lim"
        cols = f"{'controller':<16}{'success':>9}{'settle s':>10}{'offset':>10}{peak:>16}{'diverged':>10}{'wall s':>9}"
        rows = [head, cols, "-" * len(cols)]
        for s in self.scores.values():
            peak_cell = self.limits.peak_text(s.median_peak_input) if self.limits is not None else f"{s.median_peak_input:.3g}"
            rows.append(
                f"{s.name:<16}{100 * s.success_rate:>8.1f}%{s.median_settling_time:>10.2f}{s.median_offset:>10.2e}"
                f"{peak_cell:>16}{s.n_diverged:>10d}{s.wall_time:>9.1f}"
            )
        rows.append("settle, offset, peak |u|: medians over successes, settled states, all states")
        names = list(self.scores)
        for other in names[1:]:
            rows.append(self.compare(names[0], other).text())
            common = self.common_settling(names[0], other)
            if common["states"]:
                rows.append(f"median settle on the {common['states']} states both reach: {names[0]} {common[names[0]]:.2f} s, "
                            f"{other} {common[other]:.2f} s")
        return "\n".join(rows)


def score(
    system,
    name: str,
    ctrl: Controller,
    x0: np.ndarray,
    T: float,
    dt: float,
    *,
    method: str = "rk4",
    saturation=None,
    limits: bool = True,
    hold: bool = True,
    threads: int | None = None,
    stop_settled: bool = False,
    stop_converged: bool = False,
    enough_settled: int | None = None,
) -> tuple[ControllerScore, Trajectory]:
    """Simulate one controller from x0 (N, n) on `system` (the judge) and score the rollouts.

    T, dt, method, saturation, limits, hold, threads, stop_settled, stop_converged, enough_settled :
    passed to `simulate` (limits: the system's effort limits apply unless False; stop_settled: for
    callers that read `success` only, since a row's settling time and peak input then stop where
    the row stopped; stop_converged: the scores are the full horizon's, the rollouts of converged
    rows end where they stopped; enough_settled: for callers that read the count of successes
    only). Returns the score and the rollouts.
    """
    t0 = time.perf_counter()
    traj = simulate(system, ctrl, x0, T=T, dt=dt, method=method, saturation=saturation, limits=limits, hold=hold, threads=threads,
                    stop_settled=stop_settled, stop_converged=stop_converged, enough_settled=enough_settled)
    wall = time.perf_counter() - t0
    result = ControllerScore(
        name=name,
        success=success(traj, system),
        settling_time=settling_time(traj, system),
        offset=equilibrium_offset(traj, system),
        settled=settled(traj),
        peak_input=peak_input(traj),
        diverged=traj.diverged.copy(),
        wall_time=wall,
    )
    return result, traj


def roa(
    system,
    controllers: Mapping[str, Controller],
    n: int = 200,
    box="domain",
    seed: int = 0,
    T: float = 20.0,
    dt: float | None = None,
    *,
    method: str = "rk4",
    saturation=None,
    limits: bool = True,
    hold: bool = True,
    threads: int | None = None,
    workers: int = 1,
    stop_converged: bool = True,
) -> RoaResult:
    """Region-of-attraction estimate: every controller from the very same `n` uniform states.

    Parameters
    ----------
    system : the `System`.
    controllers : {name: ctrl}, ctrl (N, n) -> (N, m).
    n : number of initial states.
    box : ``"domain"``, ``"half"`` or (lo, hi) (see `evaluation_box`).
    seed : seed of the uniform states.
    T, dt, method, saturation, limits, hold, threads : passed to `simulate` (the system's effort
        limits apply to every controller alike unless ``limits=False``); dt None: one step for all of them,
        `judge_step` of the stiffest loop.
    workers : processes simulating the controllers side by side (1: in this process, 0: one per
        core; `idapbc_pin._parallel.process_map`); the count changes the time, never a score (a score's
        ``wall_time`` is its own simulation's).
    stop_converged : a rollout that enters its loop's terminal set stops there, its verdict known
        (`simulate`); False integrates every state for the whole horizon. The laws must not depend
        on time.

    Returns
    -------
    RoaResult (``.table()`` prints it).
    """
    x0 = roa_states(system, n, box, seed)
    dt = judge_step(system, controllers, T, dt)
    kw = dict(method=method, saturation=saturation, limits=limits, hold=hold, threads=threads, stop_converged=stop_converged)
    jobs = [score_job(system, name, ctrl, x0, T, dt, **kw) for name, ctrl in controllers.items()]
    scores = {s.name: s for s in process_map(run_score_job, jobs, workers)}
    return roa_result(system, box, x0, T, dt, seed, scores, limits=limits, saturation=saturation, hold=hold)


def roa_states(system, n: int, box, seed: int) -> np.ndarray:
    """The `n` uniform states (n, n_x) of `seed` in the evaluation box `box` (see `evaluation_box`)."""
    return uniform_states(system, n, evaluation_box(system, box), seed)


def score_job(system, name: str, ctrl: Controller, x0: np.ndarray, T: float, dt: float, **kw) -> tuple:
    """The job of `run_score_job` (for `process_map` or `JobPool`): `score` of one controller from x0."""
    return (system, name, ctrl, x0, T, dt, kw)


def run_score_job(job) -> ControllerScore:
    """Worker: the `score` of one controller, for a `score_job`."""
    system, name, ctrl, x0, T, dt, kw = job
    return score(system, name, ctrl, x0, T, dt, **kw)[0]


def roa_result(system, box, x0: np.ndarray, T: float, dt: float, seed: int, scores: Mapping[str, ControllerScore], *,
               limits: bool = True, saturation=None, hold: bool = True) -> RoaResult:
    """The `RoaResult` of `scores` on the states x0 of `box` (as `roa` returns it)."""
    return RoaResult(
        system=getattr(system, "name", type(system).__name__),
        box=evaluation_box(system, box),
        box_name=box if isinstance(box, str) else "custom",
        x0=x0,
        T=float(T),
        dt=float(dt),
        seed=int(seed),
        scores=scores,
        limits=input_limits(system, limits, saturation),
        hold=bool(hold),
    )
