"""A swing-up manoeuvre from rest: a nominal plan tracked in time, then the run's law
(`SwingManoeuvre`, `ManoeuvreLaw`, `choose_manoeuvre`).

The run's swing-up law is a state feedback (`SwingUpLaw`, `TrackingLaw`): it needs no clock, but
where a nominal swing-up passes close to itself it cannot tell the swings apart. A manoeuvre is the
other answer, the one a robot runs on command from rest: during knot k of a nominal plan from the
resting posture (t ∈ [k·knot, (k + 1)·knot), t counted from the command),

    u(x, t) = clip(U(t) + K_k wrap(x − X(t)), ±ū),    X(t) = X_k + (t/knot − k)(X_{k+1} − X_k),

the time-varying LQR along the plan (`tracks.tvlqr_gains`, in x = (q, p)) against the nominal
state interpolated between its knots, with U(t) the plan's inputs interpolated linearly between the
knots' midpoints (U_0 before the first, U_{P−1} after the last; each knot's mean input stays close
to the U_k the plan held). The law is sampled every 2 ms and the plan's knots are 20 ms: against
X_k alone, the nominal itself would read as an error within each knot, and U_k held would step at
every knot (the leaderboard's torque smoothness counts each step). After the plan's end the run's
own law (its networks, and its swing-up or recovery law where it keeps one) catches.
The swing-up stage picks, among the nominals (`tracks.nominals`, at most `MANOEUVRE_NOMINALS`
of each horizon), from near-resting states of its own (the first exactly at rest), among the
manoeuvres that hold at least `PICK_SHARE` of the most any of them holds, the one whose swing-up
from exact rest scores best by the RealAIGym v2 score (`sim.leaderboard`: time, energy, torque,
smoothness and speed, what a command at rest is judged by; the sooner settled where the system has
no URDF tip to score; then the most held, then the cheapest nominal). Each is judged from exact
rest first, then from the other starts best first, until one holds them all: those ranked lower
could not be picked. It keeps it (``swingup-manoeuvre.npz``) when it holds
`SwingUpConfig.margin` more of its gate's near-resting states than the run's law does, or as many
and, from the exact resting state, scores higher (settles at x* sooner, `sim.metrics.settling_time`,
without a tip).
`simulate --from hanging` judges it beside the run's law.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._parallel import resolve_workers
from ..model.angles import wrap_angles
from .holds import Judged, judge_starts
from .plans import PLAN_STEP
from .tracking_law import TrackingLaw

__all__ = ["MANOEUVRE_NOMINALS", "PICK_SHARE", "ManoeuvreLaw", "SwingManoeuvre", "choose_manoeuvre"]

#: Nominal plans of each horizon (those that hold from rest, cheapest first) whose manoeuvres are
#: tried: which nominal tracks well from near rest does not follow from its cost.
MANOEUVRE_NOMINALS = 4
#: Manoeuvres that hold at least this share of the most any holds are ranked by their v2 score from rest.
PICK_SHARE = 0.9


@dataclass(frozen=True, eq=False)
class SwingManoeuvre:
    """A nominal plan from rest and its tracking gains, read by time.

    Attributes
    ----------
    track : the plan as a `TrackingLaw` (X (P, n) in (q, p), U (P, m), K (P, m, n), limits); its
        kept box and distance weights are not read here.
    end : (n,) the plan's end state X_P in (q, p).
    knot : length of a knot, s; the manoeuvre lasts P·knot.
    """

    track: TrackingLaw
    end: np.ndarray
    knot: float

    @property
    def duration(self) -> float:
        """Length of the plan, s."""
        return len(self.track.X) * self.knot

    def inputs(self, x, t: float) -> np.ndarray:
        """u(x, t) during the plan (0 ≤ t < `duration`): (N, n) -> (N, m), within ±ū."""
        tr = self.track
        k = min(int(np.floor(t / self.knot + 1e-9)), len(tr.X) - 1)
        after = tr.X[k + 1] if k + 1 < len(tr.X) else self.end
        nominal = tr.X[k] + min(max(t / self.knot - k, 0.0), 1.0) * (after - tr.X[k])  # between the knots
        mids = np.arange(len(tr.U)) + 0.5  # the inputs between the knots' midpoints, held beyond the first and last
        feed = np.array([np.interp(t / self.knot, mids, u) for u in tr.U.T])
        d = wrap_angles(np.atleast_2d(np.asarray(x, dtype=np.float64)) - nominal, tr.angle_mask)
        return np.clip(feed + d @ tr.K[k].T, -tr.effort, tr.effort)

    def law(self, after, dt: float = PLAN_STEP) -> "ManoeuvreLaw":
        """A fresh `ManoeuvreLaw`: this manoeuvre from the first call on, then `after`."""
        return ManoeuvreLaw(self, after, dt)

    def arrays(self) -> dict:
        """The manoeuvre as named arrays (swingup-manoeuvre.npz): the tracking law's, "end" and "knot"."""
        return self.track.arrays() | {"end": np.asarray(self.end), "knot": np.asarray(self.knot)}

    @classmethod
    def from_arrays(cls, arrays) -> "SwingManoeuvre":
        """Inverse of `arrays`; raises ValueError when a piece is missing, misshapen or not finite."""
        if "knot" not in arrays or not (np.isfinite(float(arrays["knot"])) and float(arrays["knot"]) > 0):
            raise ValueError("the manoeuvre has no positive knot length")
        track = TrackingLaw.from_arrays(arrays)
        end = np.asarray(arrays["end"], dtype=np.float64) if "end" in arrays else np.full(0, np.nan)
        if end.shape != track.x_star.shape or not np.isfinite(end).all():
            raise ValueError("the manoeuvre has no finite end state of the right size")
        return cls(track, end, float(arrays["knot"]))

    def to_json(self) -> dict:
        """controller.json's "manoeuvre" of an export: X, U, K, x_star, effort, angle_mask, end and knot as lists."""
        keep = ("X", "U", "K", "x_star", "effort", "angle_mask")
        return {k: np.asarray(v).tolist() for k, v in self.track.arrays().items() if k in keep} | {"end": self.end.tolist(), "knot": float(self.knot)}


class ManoeuvreLaw:
    """The manoeuvre in closed loop: (N, n) -> (N, m). Each call is one tick of `dt` seconds (as
    `simulate` calls a law held over its steps, its default), the first at t = 0; after the plan,
    `after` (the run's controller). Use a fresh instance per simulation; picklable."""

    def __init__(self, manoeuvre: SwingManoeuvre, after, dt: float = PLAN_STEP):
        self.manoeuvre, self.after, self.dt, self.tick = manoeuvre, after, float(dt), 0

    def __call__(self, x):
        t = self.tick * self.dt
        self.tick += 1
        if t < self.manoeuvre.duration - 1e-12:
            return self.manoeuvre.inputs(x, t)
        return self.after(x)


def _plain(value: float) -> float | None:
    """`value` for JSON: None where it is not finite."""
    return float(value) if math.isfinite(value) else None


def _from_rest(judged: Judged) -> float:
    """How well a law does from exact rest, higher is better: its v2 score, or (a system without a
    URDF tip) minus its settling time (−∞: not settled)."""
    if math.isfinite(judged.rest_score):
        return judged.rest_score
    return -judged.rest_time if math.isfinite(judged.rest_time) else -math.inf


def choose_manoeuvre(system, after, manoeuvres: list, x_pick: np.ndarray, x_gate: np.ndarray, config) -> tuple[int | None, dict]:
    """The manoeuvre of `manoeuvres` (each then `after`, the run's controller) picked from the
    near-resting states x_pick (the first exactly at rest): among those that hold at least
    `PICK_SHARE` of the most any holds, the best from rest (v2 score; without a tip, the sooner
    settled), then the most held, then the first; judged with `after` alone from the gate's states
    x_gate (the first exactly at rest) over `config.judge_T`: (its index where it holds
    `config.margin` more of x_gate than `after`, or as many and does better from rest, else None;
    {"picked": holds of each from x_pick (None: not judged, `_picked_holds`), "picked_score": each
    one's v2 from rest (None: no tip), "choice", "states", "run", "held": from x_gate, "rest_time":
    {"run", "manoeuvre"} in s (None: not settled), "rest_score": {"run", "manoeuvre"} (None: no
    tip), "used"})."""
    rest = judge_starts(system, [m.law(after) for m in manoeuvres], x_pick[:1], config, score=True)  # each from exact rest alone
    held = _picked_holds(system, after, manoeuvres, rest, x_pick[1:], config)
    top = max(h for h in held if h is not None)
    pool = [i for i, h in enumerate(held) if h is not None and h >= PICK_SHARE * top]
    best = max(pool, key=lambda i: (_from_rest(rest[i]), held[i], -i))
    run, own = judge_starts(system, [after, manoeuvres[best].law(after)], x_gate, config, score=True)
    used = own.held >= run.held + config.margin or (own.held >= run.held and _from_rest(own) > _from_rest(run))
    return (best if used else None), {"picked": held, "picked_score": [_plain(j.rest_score) for j in rest],
                                      "choice": int(best), "states": int(len(x_gate)), "run": int(run.held), "held": int(own.held),
                                      "rest_time": {"run": _plain(run.rest_time), "manoeuvre": _plain(own.rest_time)},
                                      "rest_score": {"run": _plain(run.rest_score), "manoeuvre": _plain(own.rest_score)}, "used": bool(used)}


def _picked_holds(system, after, manoeuvres: list, rest: list, x_more: np.ndarray, config) -> list[int | None]:
    """How many near-resting starts each manoeuvre holds: its verdict from exact rest (`rest`, its
    `Judged`) plus those from the other starts x_more, judged best from rest first, a few at a time
    (as many as the workers), and only until one holds every start and all ranked as high are
    judged: then the most any holds is known, and none ranked lower can be picked (None: not judged)."""
    rank = [_from_rest(j) for j in rest]
    order = sorted(range(len(manoeuvres)), key=lambda i: (-rank[i], i))
    held: list[int | None] = [None] * len(manoeuvres)
    width, every, k = max(2, resolve_workers(config.workers)), len(x_more) + 1, 0
    while k < len(order):
        chunk = order[k : k + width]
        k += len(chunk)
        more = judge_starts(system, [manoeuvres[i].law(after) for i in chunk], x_more, config) if len(x_more) else [Judged(0, math.nan, math.nan)] * len(chunk)
        for i, judged in zip(chunk, more):
            held[i] = int(rest[i].held + judged.held)
        full = [rank[i] for i in order[:k] if held[i] == every]
        if full and (k == len(order) or rank[order[k]] < max(full)):
            break
    return held
