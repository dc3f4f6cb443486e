"""The swing-up evaluation (DESIGN §4): from hanging to upright under the URDF's torque limits.

From N states near the resting equilibrium (`swingup_states`: the first exactly at rest there, the
others ±0.1 rad or m and ±0.1 rad/s or m/s; or, with ``starts="circle"``, at rest with every angle
from the full circle), each controller runs T = 10 s on the true plant (RK4 at 2 ms, the law held
over each step: 500 Hz; effort limits on every controller), and two verdicts are read side by side:

* *holds*: over the last `HOLD_WINDOW` s every wrapped angle within `HOLD_POSITION` rad of x*'s
  (a prismatic coordinate within `HOLD_POSITION` m), every speed within `HOLD_SPEED`, and a
  prismatic joint within its URDF limits throughout (a cart on its rail);
* the *tip test* of the RealAIGym leaderboard: the tip stays above `TIP_SHARE` of its way from
  rest to x* from the swing-up time to the end, with a cart on its rail
  (`idapbc_pin.sim.leaderboard.tip_swingup_times`).

For the exact hanging start also the leaderboard's v2 score (`idapbc_pin.sim.leaderboard`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._parallel import process_map
from ..errors import IdapbcError
from ..model.angles import wrap_angles
from ..sim.integrate import simulate
from ..sim.metrics import HOLD_ANGLE, HOLD_SPEED, SUCCESS_WINDOW, holds as holds_verdict, on_rail, speed_over_rating
from ..sim.states import RESTING_SPREAD, anywhere_states, circle_states, moving_states, resting_states
from ..sim.step import DEFAULT_STEP
from ..sim.leaderboard import TIP_SHARE, LeaderboardScore, row_score, stays_from, tip_swingup_times

__all__ = [
    "HOLD_POSITION",
    "HOLD_SPEED",
    "HOLD_WINDOW",
    "STARTS",
    "START_SPREAD",
    "TIP_SHARE",
    "SwingupResult",
    "SwingupScore",
    "evaluate_run_swingup",
    "evaluate_swingup",
    "judge_swingup",
    "swingup_file",
    "swingup_states",
]

#: The holds verdict (`sim.metrics.holds`) reads the last HOLD_WINDOW seconds for
#: |wrap(q − q*)| ≤ HOLD_POSITION (rad or m) and |v| ≤ HOLD_SPEED (rad/s or m/s) on every coordinate.
HOLD_WINDOW, HOLD_POSITION, HOLD_SPEED = SUCCESS_WINDOW, HOLD_ANGLE, HOLD_SPEED
#: Start states: q_rest ± U(−START_SPREAD, START_SPREAD) and v ± U(−START_SPREAD, START_SPREAD).
START_SPREAD = RESTING_SPREAD


#: The start sets: "hanging" (near the resting posture), "circle" (at rest, angles from the full
#: circle), "anywhere" (angles from the full circle, speeds U(−1, 1): `sim.states.anywhere_states`)
#: and "moving" (angles from the full circle, speeds up to each joint's rating: `sim.states.moving_states`).
STARTS = ("hanging", "circle", "anywhere", "moving")
#: From moving starts: a row counts as caught when it holds and is in the hold box from CATCH_BY s on,
#: and the late speed figure leaves out the first RELEASE_GRACE s (the start's own speed).
CATCH_BY, RELEASE_GRACE = 5.0, 0.5
#: The judge's step (s): the law held at 500 Hz. The row of a run's swing-up manoeuvre from rest.
DT = DEFAULT_STEP
MANOEUVRE_ROW = "NIDA-PBC manoeuvre"


def swingup_states(system, n: int = 20, seed: int = 0, starts: str = "hanging") -> np.ndarray:
    """(n, 2 nq) start states x = (q, p), the first exactly at rest at `resting_configuration`.
    ``"hanging"``: the others q_rest + U(−0.1, 0.1) (rad or m) with v = U(−0.1, 0.1) (rad/s or m/s),
    p = M(q) v (`idapbc_pin.sim.states.resting_states`, which the swing-up stage draws its starts
    from too). ``"circle"``: the others at rest with every angle drawn from the full circle
    (`idapbc_pin.sim.states.circle_states`). ``"anywhere"``: the same postures, moving
(`idapbc_pin.sim.states.anywhere_states`). ``"moving"``: every row anywhere and moving, each speed
up to its joint's rating (`idapbc_pin.sim.states.moving_states`)."""
    if starts not in STARTS:
        raise IdapbcError(f"unknown swing-up starts {starts!r}. Fix: one of {', '.join(STARTS)}.")
    if starts == "circle":
        return circle_states(system, int(n), seed)
    if starts == "anywhere":
        return anywhere_states(system, int(n), seed)
    if starts == "moving":
        return moving_states(system, int(n), seed)
    return resting_states(system, int(n), seed, START_SPREAD)


@dataclass(frozen=True, eq=False)
class SwingupScore:
    """One controller's swing-up verdicts, one entry per start state (N,).

    Attributes
    ----------
    holds : bool, in the hold box over the last `HOLD_WINDOW` s, not diverged.
    tip : bool, the tip test passed (a swing-up time before the end).
    swingup_time : s, first time from which the tip test holds to the end; nan without `tip`.
    time_to_goal : s, first time from which the hold box holds to the end; nan if it does not hold
        at the end (or the row diverged).
    peak_input : max |u| (N·m or N). peak_ratio : max over inputs of max |u_i| / effort_i (nan
        without a finite limit).
    speed_ratio : max over the rated joints (passive ones too) of max |v_i| / v̄_i, v̄ the URDF
        `<limit velocity>` (`sim.metrics.speed_over_rating`); 0 where no joint has one.
    late_speed_ratio : the same after the first `RELEASE_GRACE` s.
    energy : Σ|Δq_a · u| over the actuated joints (J).
    diverged : bool, the rollout blew up.
    off_rail : bool, a prismatic joint left its URDF position limits (`sim.metrics.on_rail`): such a
        row neither holds nor passes the tip test.
    hanging : the leaderboard's v2 score of the first state's trajectory (the exact hanging start).
    """

    holds: np.ndarray
    tip: np.ndarray
    swingup_time: np.ndarray
    time_to_goal: np.ndarray
    peak_input: np.ndarray
    peak_ratio: np.ndarray
    energy: np.ndarray
    speed_ratio: np.ndarray
    late_speed_ratio: np.ndarray
    diverged: np.ndarray
    off_rail: np.ndarray
    hanging: LeaderboardScore

    def to_dict(self) -> dict:
        """JSON-ready (nan as None)."""

        def plain(a):
            return [None if isinstance(x, float) and not math.isfinite(x) else x for x in np.asarray(a).tolist()]

        out = {k: plain(getattr(self, k)) for k in ("holds", "tip", "swingup_time", "time_to_goal", "peak_input", "peak_ratio", "speed_ratio", "late_speed_ratio",
                                                "energy", "diverged", "off_rail")}
        out["hanging"] = self.hanging.to_dict()
        return out


def judge_swingup(system, traj) -> SwingupScore:
    """The swing-up verdicts (`SwingupScore`) of a `Trajectory` of `system` recorded at every step
    (row 0 taken as the exact hanging start for the v2 score)."""
    nq = system.nq
    t, q, v, u = traj.t, traj.q, traj.v, traj.u
    N, K = q.shape[:2]
    q_star = np.asarray(system.x_star, float)[:nq]
    rail = on_rail(traj, system)
    swingup = tip_swingup_times(system, traj)
    dq = wrap_angles(q - q_star, np.asarray(system.angle_mask, bool)[:nq])
    box = (np.abs(dq) <= HOLD_POSITION).all(axis=-1) & (np.abs(v) <= HOLD_SPEED).all(axis=-1)
    holds = holds_verdict(traj, system, HOLD_WINDOW)
    to_goal = stays_from(box, t)
    to_goal[traj.diverged | ~rail] = np.nan
    B = np.asarray(system.B, float)
    effort = np.asarray(system.effort, float)
    peak_each = np.abs(u).max(axis=1) if K else np.zeros((N, system.m))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(np.isfinite(effort), peak_each / effort, np.nan)
    peak_ratio = np.full(N, np.nan) if np.all(np.isnan(ratio)) else np.nanmax(ratio, axis=1)
    energy = np.abs(np.diff(q @ B, axis=1) * u[:, :-1]).sum(axis=(1, 2))
    fast = speed_over_rating(system, v) if K else np.zeros((N, 1))  # (N, K)
    late = t >= RELEASE_GRACE - 1e-9
    fast[np.asarray(traj.diverged, bool)] = np.inf
    speed_ratio = fast.max(axis=1)
    late_speed_ratio = fast[:, late].max(axis=1) if late.any() else np.zeros(N)
    hanging = row_score(system, traj, 0, swingup[0])
    return SwingupScore(holds=holds, tip=np.isfinite(swingup), swingup_time=swingup, time_to_goal=to_goal,
                        peak_input=peak_each.max(axis=1), peak_ratio=peak_ratio, energy=energy, speed_ratio=speed_ratio, late_speed_ratio=late_speed_ratio,
                        diverged=np.asarray(traj.diverged, bool).copy(), off_rail=~rail, hanging=hanging)


def _judge_job(job) -> SwingupScore:
    """Worker: (system, controller, x0, T, dt, limits) -> its `SwingupScore`."""
    system, ctrl, x0, T, dt, limits = job
    return judge_swingup(system, simulate(system, ctrl, x0, T=T, dt=dt, limits=limits))


def _median(a) -> float:
    a = np.asarray(a, float)
    return float(np.nanmedian(a)) if np.isfinite(a).any() else math.nan


@dataclass(frozen=True, eq=False)
class SwingupResult:
    """Several controllers judged from the same swing-up starts.

    Attributes
    ----------
    system : name of the system. states : (N, n) start states (q, p). T, dt : horizon and step (s).
    limits : effort limits applied. scores : controller name -> `SwingupScore`, in the order given.
    starts : the start set (`STARTS`).
    """

    system: str
    states: np.ndarray
    T: float
    dt: float
    limits: bool
    scores: dict = field(default_factory=dict)
    starts: str = "hanging"

    def table(self) -> str:
        """A markdown table, one row per controller: holds k/N, tip k/N, median swing-up time, median
        time to goal (over the states that have one), median peak |u| / limit, median peak speed / the
        URDF's rating (where a joint has one), hanging-start v2 score; rows that left the rail are
        counted beside the holds. From moving starts, also the rows caught by `CATCH_BY` s and the
        largest speed / rating after `RELEASE_GRACE` s, instead of the hanging-start score."""
        N = self.states.shape[0]
        rated = any((s.speed_ratio > 0).any() for s in self.scores.values())
        moving = self.starts == "moving"
        speed = (" median peak speed / rating |", "---|") if rated else ("", "")
        last = (f" at x* by {CATCH_BY:g} s | max speed / rating after {RELEASE_GRACE:g} s |", "---|---|") if moving else (" hanging-start score |", "---|")
        rows = [f"| controller | holds | tip | median swing-up time | median time to goal | median peak input / limit |{speed[0]}{last[0]}",
                f"|---|---|---|---|---|---|{speed[1]}{last[1]}"]
        for name, s in self.scores.items():
            if moving:
                caught = int((s.holds & (np.nan_to_num(s.time_to_goal, nan=np.inf) <= CATCH_BY)).sum())
                tail = f" {caught}/{N} | {float(np.max(s.late_speed_ratio)):.2f} |"
            else:
                tail = f" {s.hanging.score:.3f}" + (f" (swing-up {s.hanging.swingup_time:.2f} s)" if s.hanging.success else "") + " |"
            rail = f" ({int(s.off_rail.sum())} off the rail)" if s.off_rail.any() else ""
            rows.append(f"| {name} | {int(s.holds.sum())}/{N}{rail} | {int(s.tip.sum())}/{N} | {_median(s.swingup_time):.2f} s | "
                        f"{_median(s.time_to_goal):.2f} s | {_median(s.peak_ratio):.2f} |" + (f" {_median(s.speed_ratio):.2f} |" if rated else "") + tail)
        return "\n".join(rows)

    def to_dict(self) -> dict:
        """JSON-ready: the settings, the start states and every controller's verdicts."""
        return {"system": self.system, "starts": self.starts, "T": self.T, "dt": self.dt, "limits": self.limits, "states": self.states.tolist(),
                "scores": {k: s.to_dict() for k, s in self.scores.items()}}


def evaluate_swingup(system, controllers: dict, n: int = 20, T: float = 10.0, dt: float = 0.002, seed: int = 0,
                     limits: bool = True, workers: int = 1, starts: str = "hanging") -> SwingupResult:
    """Judge `controllers` (name -> law (N, n) -> (N, m)) swinging `system` up from the same
    `swingup_states` (n, seed, starts): one batched `simulate` per controller over T s at the RK4
    step dt (the law held over each step), with the effort limits unless `limits` is False;
    `workers` processes (0: one per core; `idapbc_pin._parallel.process_map`, the laws must pickle)."""
    x0 = swingup_states(system, n, seed, starts)
    jobs = [(system, ctrl, x0, float(T), float(dt), bool(limits)) for ctrl in controllers.values()]
    scores = dict(zip(controllers, process_map(_judge_job, jobs, workers)))
    return SwingupResult(system=str(system.name), states=x0, T=float(T), dt=float(dt), limits=bool(limits), scores=scores, starts=starts)


def swingup_file(starts: str = "hanging") -> str:
    """The run directory's file of a swing-up evaluation: ``swingup.json``, or ``swingup-circle.json``."""
    return "swingup.json" if starts == "hanging" else f"swingup-{starts}.json"


def evaluate_run_swingup(run, n: int = 20, T: float = 10.0, seed: int = 0, workers: int = 1, starts: str = "hanging",
                         judge: str = "pinocchio") -> SwingupResult:
    """A run judged from `n` swing-up starts (`evaluate_swingup`; near-resting by default, or at rest
    from the full circle) beside saturated LQR and the energy-pumping law (`EnergyPumpLaw`, handing
    over to LQR near x*), with the effort limits, on the judge plant (``"pinocchio"``, or
    ``"mujoco"``: `sim.mujoco_plant.mujoco_judge`); from near rest also the run's swing-up manoeuvre
    where it keeps one (row `MANOEUVRE_ROW`: the manoeuvre from t = 0, then the run's law). The
    result is also written to the run directory (`swingup_file`, with the judge's name)."""
    from .._io import write_json
    from ..control.baseline import LQRController
    from ..control.energy_pump import EnergyPumpLaw
    from .closed_loop import _judged

    controllers = {"NIDA-PBC": run.controller}
    manoeuvre = getattr(run, "manoeuvre", None) if starts == "hanging" else None
    if manoeuvre is not None:  # from rest on command: the manoeuvre, then the run's law
        controllers[MANOEUVRE_ROW] = manoeuvre.law(run.controller, dt=DT)
    controllers |= {"LQR": LQRController(run.system), "energy pump + LQR": EnergyPumpLaw(run.system)}
    result = evaluate_swingup(_judged(run.system, judge, {}), controllers, n=n, T=T, dt=DT, seed=seed, workers=workers, starts=starts)
    write_json(run.path / swingup_file(starts), result.to_dict() | {"judge": judge, "swing_up_law": bool(getattr(run, "uses_swing_up", False)),
                                                                    "manoeuvre": manoeuvre is not None})
    return result
