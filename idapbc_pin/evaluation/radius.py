"""ROA radius: a figure of a controller's basin that does not hinge on one arbitrary box (DESIGN §4).

The radius of a controller is the largest scale s of the training box around x*,

    X_s = x* + s·(X − x*),        s ∈ [0.05, 2],

at which at least 90 % of n uniform states of X_s reach x* (DESIGN §4 success). The states of X_s
are the same unit draws for every scale and every controller, ``uniform_states(system, n, X_s,
seed)``; at s = 1 and s = 0.5 they are, bit for bit, the states `roa` draws from the domain and
the half box, so an ROA already computed there is reused instead of simulated again.

The search is a bisection per controller on those fixed states: s = 1 first, then (if it fails)
s = 0.5, then halving the bracket [passing s, failing s] down to the resolution; the ends of the
range (0.05, 2) are probed only when the bracket ends next to them. A probe simulates first the
draws that failed at the nearest larger probed scale (at least a quarter of its states) and stops
there when more than 10 % of all its states already failed; it integrates a state no further once
that state has rested in the success box for the success window (its verdict is then known:
``simulate(stop_settled=True)``), and it stops the rest once 90 % of all its states rest (the probe
passes whatever the others do: ``enough_settled``). The success share need not be monotone in s;
the result is a scale that passes with the next probed scale above it failing, on the same seeds.
A search runs probe by probe (`RadiusSearch`): alone in one process, or in a pool where a spare
worker probes ahead, with the same result.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from .._parallel import process_map
from ..sim.integrate import Controller
from ..sim.limits import InputLimits, input_limits
from ..sim.states import scaled_box, uniform_states
from ..sim.step import judge_step
from .roa import RoaResult, score

__all__ = [
    "RADIUS_RANGE", "RADIUS_RESOLUTION", "RADIUS_THRESHOLD", "RadiusResult", "RadiusSearch", "probe_job", "radius_job", "radius_result",
    "roa_radius", "run_probe_job", "run_radius_job",
]  # fmt: skip

#: Scales searched: below the first the radius is reported as "< 0.05", at the last as "≥ 2".
RADIUS_RANGE = (0.05, 2.0)
#: Share of the states that must succeed (DESIGN §4).
RADIUS_THRESHOLD = 0.9
#: The bisection stops once the bracket [passing s, failing s] is at most this wide.
RADIUS_RESOLUTION = 0.04
#: A probe simulates this share of its states first and stops there when more than the allowed
#: failures are already in (a batch of 50 states costs about a third of one of 200: the
#: controllers' per-call overhead is a large part of a rollout).
_FIRST_SHARE = 0.25


def _fmt(s: float, s_range: tuple[float, float], below: bool, above: bool) -> str:
    if below:
        return f"< {s_range[0]:g}"
    if above:
        return f"≥ {s_range[1]:g}"
    return f"{s:.2f}"


@dataclass(frozen=True, eq=False)
class RadiusResult:
    """The ROA radius of several controllers on the same states.

    Attributes
    ----------
    system : system name.
    radius : {controller: s}, the largest passing scale found; the lower end of the range when
        even that fails (`below`), the upper end when it passes (`above`).
    bracket : {controller: (s passing, s failing)}: the returned s and the next probed scale above
        it (None where there is none: below the range, or at its top).
    below, above : {controller: bool}, see `radius`.
    probes : {controller: {s: (successes, states simulated)}}; a probe that failed early has
        simulated fewer than n states, and one that passed early counts the successes it needed.
    n, seed, T, dt : the states per scale, their seed, the horizon and step (s).
    threshold, resolution, s_range : the criterion and the search settings.
    limits : the input bound the rollouts applied.
    wall_time : seconds, simulations included.
    """

    system: str
    radius: Mapping[str, float]
    bracket: Mapping[str, tuple]
    below: Mapping[str, bool]
    above: Mapping[str, bool]
    probes: Mapping[str, dict] = field(repr=False)
    n: int
    seed: int
    T: float
    dt: float
    threshold: float
    resolution: float
    s_range: tuple
    limits: InputLimits | None
    wall_time: float

    def text(self, name: str) -> str:
        """The radius of one controller as printed: ``'0.73'``, ``'< 0.05'`` or ``'≥ 2'``."""
        return _fmt(self.radius[name], self.s_range, self.below[name], self.above[name])

    def line(self) -> str:
        """One line for the tables: every controller's radius side by side."""
        values = ", ".join(f"{name} {self.text(name)}" for name in self.radius)
        return (
            f"ROA radius (largest s with ≥ {100 * self.threshold:g} % of {self.n} states succeeding in x* + s·(box − x*), "
            f"±{self.resolution:g}): {values}"
        )

    def to_dict(self) -> dict:
        """The settings and the per-controller details (the radii themselves: `radius`)."""
        return {
            "n": self.n, "seed": self.seed, "T": self.T, "dt": self.dt, "threshold": self.threshold,
            "resolution": self.resolution, "range": list(self.s_range),
            "text": {name: self.text(name) for name in self.radius},
            "bracket": {name: list(b) for name, b in self.bracket.items()},
            "probes": {name: [[s, k, m] for s, (k, m) in sorted(p.items())] for name, p in self.probes.items()},
            "limits": None if self.limits is None else self.limits.to_json(),
            "wall_time": self.wall_time,
        }


def _known_successes(known, name: str, x0: np.ndarray) -> np.ndarray | None:
    """(N,) bool successes of `name` in an already computed `RoaResult` drawn from exactly these states."""
    if known is None or name not in known.scores or known.x0.shape != x0.shape or not np.array_equal(known.x0, x0):
        return None
    return np.asarray(known[name].success, bool)


def _order(n: int, suspects: np.ndarray | None) -> tuple[np.ndarray, int]:
    """The draws in the order simulated, and the size of the first batch: the `suspects` ((n,) bool,
    the draws that failed at the nearest larger probed scale) first, at least a quarter of the states
    (`_FIRST_SHARE`)."""
    suspects = np.zeros(n, bool) if suspects is None else suspects
    order = np.concatenate([np.flatnonzero(suspects), np.flatnonzero(~suspects)])
    return order, max(int(suspects.sum()), math.ceil(_FIRST_SHARE * n))


def probe_job(system, name: str, ctrl: Controller, n: int, seed: int, need: int, s: float, suspects, sim_kw: dict) -> tuple:
    """The job of `run_probe_job`: whether `ctrl` passes at scale `s` (`need` successes of the `n`
    draws), the draws in `suspects` first."""
    return (system, name, ctrl, n, seed, need, float(s), suspects, sim_kw)


def run_probe_job(job) -> tuple[int, int, np.ndarray]:
    """Worker: one probe, for a `probe_job`. Returns (successes, states simulated, (n,) bool the draws
    that did not succeed: failed, or left undecided by an early stop)."""
    system, name, ctrl, n, seed, need, s, suspects, sim_kw = job
    x0 = uniform_states(system, n, scaled_box(system, s), seed)
    order, first = _order(n, suspects)
    failed = np.zeros(n, bool)
    ok, done = 0, 0
    for end in sorted({min(first, n), n}):
        rows = order[done:end]
        # a batch stops once enough of its states rest for the probe to pass: its count is then a lower bound
        res = score(system, name, ctrl, x0[rows], **sim_kw, stop_settled=True, stop_converged=True, enough_settled=need - ok)[0]
        failed[rows] = ~res.success
        ok, done = ok + int(np.count_nonzero(res.success)), end
        if done - ok > n - need:  # too many failures already: decided
            break
    return ok, done, failed


def _bisect(s_lo: float, s_hi: float, resolution: float):
    """The search as a generator: it yields the scales to probe, in order, is sent back whether each
    passes, and returns (s, (s passing, s failing), below, above).

    The ends of the range are assumed to pass (s_lo) and fail (s_hi) and only probed when the
    bisection ends next to them: most searches never simulate them.
    """
    start = min(max(1.0, s_lo), s_hi)
    if (yield start):
        a, b = start, s_hi
    else:
        half = max(s_lo, 0.5 * start)
        a, b = (half, start) if half < start and (yield half) else (s_lo, half)
    while b - a > resolution * (1 + 1e-9):
        mid = 0.5 * (a + b)
        a, b = (mid, b) if (yield mid) else (a, mid)
    if not (yield a):  # only s_lo can still be unprobed here
        return s_lo, (None, s_lo), True, False
    if b == s_hi and (yield s_hi):
        return s_hi, (s_hi, None), False, True
    return a, (a, b), False, False


def _replay(passed: Mapping[float, bool], s_range: tuple[float, float], resolution: float) -> tuple[list, float | None, tuple | None]:
    """The bisection over the verdicts known so far ({s: passes}): (the scales probed on its path, in
    order; the next scale it needs, or None; its result once it needs none)."""
    search, path = _bisect(*s_range, resolution), []
    try:
        s = next(search)
        while s in passed:
            if s not in path:
                path.append(s)
            s = search.send(passed[s])
        return path, s, None
    except StopIteration as stop:
        return path, None, stop.value


class RadiusSearch:
    """One controller's bisection, driven probe by probe: `wanted` names the probe jobs it can use now,
    `record` takes their results. Every probe is the job the search would run alone, one probe at a time
    (the same scale, the same draws in the same order), so the result does not depend on how many run
    at once.

    With a spare worker, the search also asks for the probe it would need next if the one in flight
    passes (the upper half's midpoint): a probe whose draws and order are already fixed, since the
    failures it reads first are those of the nearest larger scale, never the midpoint below it. A
    guess that turns out wrong is dropped and kept out of the record.
    """

    def __init__(self, system, name: str, ctrl: Controller, *, n: int, seed: int, need: int, sim_kw: dict, known,
                 s_range: tuple[float, float], resolution: float):
        self.system, self.name, self.ctrl, self.n, self.seed, self.need, self.sim_kw = system, name, ctrl, n, seed, need, sim_kw
        self.s_range, self.resolution = s_range, resolution
        self.counts: dict[float, tuple[int, int]] = {}  # {s: (successes, states simulated)}
        self.failed: dict[float, np.ndarray] = {}  # {s: (n,) bool, the draws that did not succeed there}
        for s, res in known.items():  # already simulated (the evaluation's boxes), where its states are this scale's
            x0 = uniform_states(system, n, scaled_box(system, s), seed)
            ok = _known_successes(res, name, x0)
            if ok is not None:
                self.counts[s], self.failed[s] = (int(ok.sum()), n), ~ok

    def _state(self, extra: Mapping[float, bool] | None = None):
        passed = {s: k >= self.need for s, (k, _) in self.counts.items()}
        return _replay({**passed, **(extra or {})}, self.s_range, self.resolution)

    def _job(self, s: float, path: list) -> tuple:
        larger = [t for t in path if t > s]
        return probe_job(self.system, self.name, self.ctrl, self.n, self.seed, self.need, s,
                         self.failed[min(larger)] if larger else None, self.sim_kw)

    def wanted(self, spare: bool = False) -> list[tuple[float, tuple]]:
        """[(s, probe job)]: the probe the search needs next, then, with `spare`, the one it needs
        after that if this one passes (when that is a new scale); [] once it has its result."""
        path, needed, _ = self._state()
        if needed is None:
            return []
        out = [(needed, self._job(needed, path))]
        if spare:
            _, after, _ = self._state({needed: True})
            if after is not None and after > needed:
                out.append((after, self._job(after, path)))
        return out

    def record(self, s: float, result: tuple[int, int, np.ndarray]) -> None:
        """Take a probe's result (`run_probe_job`)."""
        ok, done, failed = result
        self.counts[s], self.failed[s] = (ok, done), failed

    def result(self) -> tuple | None:
        """`run_radius_job`'s result once the search is over (else None): the radius, the bracket,
        below, above, and {s: (successes, states simulated)} of the probes on its path."""
        path, needed, found = self._state()
        return None if needed is not None else (*found, {s: self.counts[s] for s in path})


def roa_radius(
    system,
    controllers: Mapping[str, Controller],
    n: int = 200,
    seed: int = 0,
    T: float = 20.0,
    dt: float | None = None,
    *,
    known: Mapping[float, RoaResult] | None = None,
    s_range: tuple[float, float] = RADIUS_RANGE,
    resolution: float = RADIUS_RESOLUTION,
    threshold: float = RADIUS_THRESHOLD,
    method: str = "rk4",
    saturation=None,
    limits: bool = True,
    threads: int | None = None,
    workers: int = 1,
) -> RadiusResult:
    """The ROA radius of every controller (see the module docstring).

    Parameters
    ----------
    system : the judge `System`.
    controllers : {name: ctrl}, ctrl (N, n) -> (N, m).
    n, seed : states per scale and their seed (the same unit draws at every scale).
    T, dt, method, saturation, limits, threads : passed to `simulate` (effort limits apply unless
        ``limits=False``); dt None: one step for all of them, `judge_step` of the stiffest loop.
    known : {s: RoaResult} already simulated (e.g. ``{1.0: domain ROA, 0.5: half-box ROA}``),
        reused where its states are exactly the states of that scale.
    s_range, resolution, threshold : the search range, the bracket width at which it stops, the
        share of states that must succeed.
    workers : processes searching the controllers side by side (1: in this process, 0: one per core); the count
        changes the time, never a radius.

    Returns
    -------
    RadiusResult (``.line()`` prints it, ``.radius`` is {name: s}).
    """
    t0 = time.perf_counter()
    _settings(n, s_range, resolution, threshold)  # bad settings are refused before anything runs
    dt = judge_step(system, controllers, T, dt)
    settings = dict(n=n, seed=seed, T=T, dt=dt, s_range=s_range, resolution=resolution, threshold=threshold, limits=limits, saturation=saturation)
    jobs = [radius_job(system, name, ctrl, known=known, method=method, threads=threads, **settings) for name, ctrl in controllers.items()]
    found = dict(zip(controllers, process_map(run_radius_job, jobs, workers)))
    return radius_result(system, found, wall_time=time.perf_counter() - t0, **settings)


def _settings(n, s_range, resolution, threshold) -> tuple[int, float, float, int]:
    """(n, s_lo, s_hi, successes needed), checked."""
    n, (s_lo, s_hi) = int(n), (float(s_range[0]), float(s_range[1]))
    if n < 1 or not (0 < s_lo < s_hi) or not (resolution > 0) or not (0 < threshold <= 1):
        raise ValueError(f"need n ≥ 1, 0 < s_lo < s_hi, resolution > 0, 0 < threshold ≤ 1; got {n}, {s_range}, {resolution}, {threshold}")
    return n, s_lo, s_hi, math.ceil(threshold * n - 1e-9)


def radius_job(system, name: str, ctrl: Controller, *, n: int, seed: int, T: float, dt: float, known=None, s_range=RADIUS_RANGE,
               resolution: float = RADIUS_RESOLUTION, threshold: float = RADIUS_THRESHOLD, method: str = "rk4", saturation=None,
               limits: bool = True, threads: int | None = None) -> RadiusSearch:
    """One controller's search with the arguments of `roa_radius` (dt resolved; `known` may hold
    results of this controller only): a `RadiusSearch`, and the job of `run_radius_job`."""
    n, s_lo, s_hi, need = _settings(n, s_range, resolution, threshold)
    sim_kw = dict(T=T, dt=dt, method=method, saturation=saturation, limits=limits, threads=threads)
    known = {float(s): r for s, r in (known or {}).items()}
    return RadiusSearch(system, name, ctrl, n=n, seed=seed, need=need, sim_kw=sim_kw, known=known, s_range=(s_lo, s_hi),
                        resolution=float(resolution))


def run_radius_job(search: RadiusSearch) -> tuple[float, tuple, bool, bool, dict]:
    """Worker: one controller's whole search, one probe at a time, in this process."""
    while (found := search.result()) is None:
        (s, job), *_ = search.wanted()
        search.record(s, run_probe_job(job))
    return found


def radius_result(system, found: Mapping[str, tuple], *, n: int, seed: int, T: float, dt: float, s_range=RADIUS_RANGE,
                  resolution: float = RADIUS_RESOLUTION, threshold: float = RADIUS_THRESHOLD, limits: bool = True,
                  saturation=None, wall_time: float = 0.0) -> RadiusResult:
    """The `RadiusResult` of the searches `found` ({controller: `run_radius_job`'s result})."""
    n, s_lo, s_hi, _ = _settings(n, s_range, resolution, threshold)
    radius, bracket, below, above, probes = {}, {}, {}, {}, {}
    for name, result in found.items():
        radius[name], bracket[name], below[name], above[name], probes[name] = result
    return RadiusResult(
        system=str(getattr(system, "name", type(system).__name__)), radius=radius, bracket=bracket, below=below, above=above,
        probes=probes, n=n, seed=int(seed), T=float(T), dt=float(dt), threshold=float(threshold), resolution=float(resolution),
        s_range=(s_lo, s_hi), limits=input_limits(system, limits, saturation), wall_time=float(wall_time),
    )
