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

__all__ = ["RADIUS_RANGE", "RADIUS_RESOLUTION", "RADIUS_THRESHOLD", "RadiusResult", "radius_job", "radius_result", "roa_radius", "run_radius_job"]

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


class _Prober:
    """Whether one controller passes at scale s (cached per scale), simulating in batches.

    The states of every scale are the same unit draws, scaled; the draws that failed at the nearest
    larger probed scale are simulated first (a basin is roughly star-shaped about x*, so they are
    the likeliest to fail again), so a failing probe is decided on a small batch.
    """

    def __init__(self, system, name, ctrl, n, seed, need, known, sim_kw):
        self.system, self.name, self.ctrl, self.n, self.seed, self.need = system, name, ctrl, n, seed, need
        self.known, self.sim_kw, self.probes = known, sim_kw, {}
        self.failed: dict[float, np.ndarray] = {}  # {s: (n,) bool, the draws that did not succeed there (failed or left undecided)}

    def passes(self, s: float) -> bool:
        if s not in self.probes:
            self.probes[s] = self._run(s)
        return self.probes[s][0] >= self.need

    def _order(self, s: float) -> tuple[np.ndarray, int]:
        """The draws in the order simulated, and the size of the first batch: the draws that failed
        at the nearest larger probed scale first (at least a quarter of the states: `_FIRST_SHARE`)."""
        larger = [t for t in self.failed if t > s]
        suspects = self.failed[min(larger)] if larger else np.zeros(self.n, bool)
        order = np.concatenate([np.flatnonzero(suspects), np.flatnonzero(~suspects)])
        return order, max(int(suspects.sum()), math.ceil(_FIRST_SHARE * self.n))

    def _run(self, s: float) -> tuple[int, int]:
        x0 = uniform_states(self.system, self.n, scaled_box(self.system, s), self.seed)
        known = _known_successes(self.known.get(s), self.name, x0)
        if known is not None:
            self.failed[s] = ~known
            return int(known.sum()), self.n
        order, first = self._order(s)
        failed = np.zeros(self.n, bool)
        ok, done = 0, 0
        for end in sorted({min(first, self.n), self.n}):
            rows = order[done:end]
            # a batch stops once enough of its states rest for the probe to pass: its count is then a lower bound
            res = score(self.system, self.name, self.ctrl, x0[rows], **self.sim_kw, stop_settled=True, stop_converged=True, enough_settled=self.need - ok)[0]
            failed[rows] = ~res.success
            ok, done = ok + int(np.count_nonzero(res.success)), end
            if done - ok > self.n - self.need:  # too many failures already: decided
                break
        self.failed[s] = failed
        return ok, done


def _search(probe: _Prober, s_lo: float, s_hi: float, resolution: float) -> tuple[float, tuple, bool, bool]:
    """Bisection on `probe.passes`; -> (s, (s passing, s failing), below, above).

    The ends of the range are assumed to pass (s_lo) and fail (s_hi) and only probed when the
    bisection ends next to them: most searches never simulate them.
    """
    start = min(max(1.0, s_lo), s_hi)
    if probe.passes(start):
        a, b = start, s_hi
    else:
        half = max(s_lo, 0.5 * start)
        a, b = (half, start) if half < start and probe.passes(half) else (s_lo, half)
    while b - a > resolution * (1 + 1e-9):
        mid = 0.5 * (a + b)
        a, b = (mid, b) if probe.passes(mid) else (a, mid)
    if not probe.passes(a):  # only s_lo can still be unprobed here
        return s_lo, (None, s_lo), True, False
    if b == s_hi and probe.passes(s_hi):
        return s_hi, (s_hi, None), False, True
    return a, (a, b), False, False


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
               limits: bool = True, threads: int | None = None) -> tuple:
    """The job of `run_radius_job` (for `process_map` or `JobPool`): one controller's search, with the
    arguments of `roa_radius` (dt resolved; `known` may hold results of this controller only)."""
    n, s_lo, s_hi, need = _settings(n, s_range, resolution, threshold)
    sim_kw = dict(T=T, dt=dt, method=method, saturation=saturation, limits=limits, threads=threads)
    known = {float(s): r for s, r in (known or {}).items()}
    return (system, name, ctrl, n, seed, need, known, sim_kw, (s_lo, s_hi), float(resolution))


def run_radius_job(job) -> tuple[float, tuple, bool, bool, dict]:
    """Worker: one controller's search, for a `radius_job`; returns `_search`'s result and the probes."""
    system, name, ctrl, n, seed, need, known, sim_kw, (s_lo, s_hi), resolution = job
    probe = _Prober(system, name, ctrl, n, seed, need, known, sim_kw)
    return (*_search(probe, s_lo, s_hi, resolution), probe.probes)


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
