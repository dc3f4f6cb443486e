"""The global-policy uptime test (DESIGN §4, "From anywhere"): one long episode with resets.

The RealAIGym global policy test (simulation leaderboard v3) asks of a state feedback what a robot on
a bench asks of it: to get up, and stay up, whatever state it is put in. One episode of `T` = 60 s
starts at rest in the resting posture (a chain hanging). At `resets` = 15 times, spaced T/(resets+1)
apart with a jitter U(−`jitter`, `jitter`) s each (±1 s), the robot is reset towards a posture drawn
uniformly from the full circle (every angle x*'s + U(−π, π); a linear coordinate at the resting
posture's), below. The law runs on, with no clock and no notice. The score is the **uptime**: the
share of the episode's samples at which the tip is up (`sim.leaderboard.tip_up`: the tip test's
normalised height ≥ 0.95, the leaderboard's 0.9 of the upright height above the pivot for a chain
hanging from it, with a cart on its rail at that sample). A row of a segment that diverged counts as down for the
whole segment.

`uptime_test` judges several controllers on the same `episodes` schedules (fixed seed); each segment
between two resets is simulated once for every episode together (`simulate`, RK4 at 2 ms, the law
held at 500 Hz, effort limits on), up to the longest, and each episode reads its own length of it.

How a reset moves the robot (`RESETS`). ``"drive"`` (the default) resets as the leaderboard's own
test does (`sim.drive`): for `DRIVE_T` = 0.2 s the law is not called, and upstream's PID with gravity
compensation on every joint drives the robot from wherever it is towards the drawn posture (its
angles within π of the resting posture's, `drive_targets`), its memory kept across the episode's
resets (`DrivePID`); then the law resumes from the state the drive left, **moving**; the drive's
0.2 s count in the episode like any other. ``"put"`` puts the state at the drawn posture, at rest, so
each reset asks for a whole swing-up from rest.

Besides the uptime, the test reads how fast the law drives the robot (`UptimeResult.speed`): the
largest |v_j| / v̄_j over the rated joints (`sim.metrics.speed_over_rating`, v̄ the URDF
`<limit velocity>`) and the share of samples with it above 1, both outside the drive windows and
the `RELEASE_GRACE` s after each (the robot is released moving: its speed then is the drive's).

Reference: github.com/dfki-ric-underactuated-lab/double_pendulum, the global policy testing
controller (v2), its leaderboard script (simulation v3: 15 resets,
0.2 s each) and ``get_uptime`` of the leaderboard analysis; written independently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._parallel import process_map
from ..model.resting import resting_configuration
from ..sim.drive import DRIVE_KD, DRIVE_KI, DRIVE_KP, DRIVE_T, PID_DT, DrivePID, drive_bound, drive_targets, pid_drive
from ..sim.integrate import simulate
from ..sim.leaderboard import tip_up
from ..sim.metrics import speed_over_rating
from ..sim.step import DEFAULT_STEP

__all__ = ["DRIVE_KD", "DRIVE_KI", "DRIVE_KP", "DRIVE_T", "PID_DT", "RELEASE_GRACE", "RESETS", "UPTIME_EPISODES", "UPTIME_JITTER", "UPTIME_RESETS", "UPTIME_T", "UptimeResult",
           "drive_bound", "reset_schedule", "reset_postures", "uptime_test"]

#: The leaderboard's episode: T s, `UPTIME_RESETS` resets with ±`UPTIME_JITTER` s of jitter; the mean over `UPTIME_EPISODES` episodes.
UPTIME_T, UPTIME_RESETS, UPTIME_JITTER, UPTIME_EPISODES = 60.0, 15, 1.0, 5
#: Seed offset of the schedules and postures (apart from the other evaluations' start states).
UPTIME_SEED = 60_000
#: How a reset moves the robot (module docstring); the first is the default.
RESETS = ("drive", "put")
#: Seconds after each drive window left out of the speed figures: the robot is released moving.
RELEASE_GRACE = 0.5


def reset_schedule(rng: np.random.Generator, T: float = UPTIME_T, resets: int = UPTIME_RESETS, jitter: float = UPTIME_JITTER,
                   dt: float = DEFAULT_STEP) -> np.ndarray:
    """(resets,) int: the control steps (of dt) at which the state is reset, increasing, within (0, T/dt):
    k·T/(resets+1) + U(−jitter, jitter) s for k = 1 … resets, rounded to the step."""
    spacing = T / (resets + 1)
    times = spacing * np.arange(1, resets + 1) + rng.uniform(-jitter, jitter, resets)
    steps = np.rint(times / dt).astype(np.int64)
    K = int(round(T / dt))
    return np.clip(np.maximum.accumulate(steps), 1, K - 1)


def reset_postures(system, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, n_x) states x = (q, 0) at rest: every angle x*'s + U(−π, π) (rad), every linear
    coordinate at the resting posture's (m)."""
    nq = system.nq
    q = np.tile(resting_configuration(system), (n, 1))
    angle = np.asarray(system.angle_mask, bool)[:nq]
    drawn = np.asarray(system.x_star, float)[:nq] + rng.uniform(-np.pi, np.pi, (n, nq))
    q = np.where(angle, drawn, q)
    return system.state_from(q, np.zeros_like(q))


@dataclass(frozen=True)
class _Schedule:
    """The episodes' resets: steps (E, R) and the states put there (E, R, n), and the start (n,)."""

    steps: np.ndarray
    states: np.ndarray
    start: np.ndarray
    K: int


def _schedules(system, episodes: int, seed: int, T: float, resets: int, jitter: float, dt: float) -> _Schedule:
    rng = np.random.default_rng(UPTIME_SEED + int(seed))
    steps = np.stack([reset_schedule(rng, T, resets, jitter, dt) for _ in range(episodes)]) if resets else np.zeros((episodes, 0), np.int64)
    states = reset_postures(system, rng, episodes * resets).reshape(episodes, resets, system.n)
    q_rest = resting_configuration(system)[None]
    start = system.state_from(q_rest, np.zeros_like(q_rest))[0]
    return _Schedule(steps=steps, states=states, start=start, K=int(round(T / dt)))


def _episode_uptime(job) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Worker: (system, law, schedule, dt, reset) -> (up, ratio, counted), each (E, K): the tip up at
    each control step of each episode, the largest speed / rating there (`speed_over_rating`; inf in a
    diverged segment), and whether the step counts for the speed figures (outside the drive windows
    and the `RELEASE_GRACE` s after each)."""
    system, law, sched, dt, reset = job
    E, R = sched.steps.shape
    bounds = np.concatenate([np.zeros((E, 1), np.int64), sched.steps, np.full((E, 1), sched.K, np.int64)], axis=1)
    up, ratio, counted = np.zeros((E, sched.K), bool), np.zeros((E, sched.K)), np.ones((E, sched.K), bool)
    grace = int(round(RELEASE_GRACE / dt))
    rows, x_end = np.arange(E), np.tile(sched.start, (E, 1))
    targets = drive_targets(system, sched.states) if reset == "drive" else None
    pid = DrivePID.fresh(E, system.nq)
    for j in range(R + 1):
        x0, first = (np.tile(sched.start, (E, 1)) if j == 0 else sched.states[:, j - 1]), bounds[:, j].copy()
        if j and reset == "drive":
            D = int(min(round(DRIVE_T / dt), (bounds[:, j + 1] - bounds[:, j]).min()))
            x_end = np.where(np.isfinite(x_end).all(axis=1, keepdims=True), x_end, sched.states[:, j - 1])
            xd, x0 = pid_drive(system, x_end, targets[:, j - 1], D, dt, pid)
            driven = tip_up(system, xd[..., : system.nq])  # (E, D)
            for e in range(E):
                up[e, first[e]: first[e] + D] = driven[e]
                counted[e, first[e]: first[e] + D + grace] = False
            first += D
        lengths = bounds[:, j + 1] - first
        L = int(lengths.max())
        if L <= 0:
            continue
        traj = simulate(system, law, x0, T=L * dt, dt=dt)
        seg = tip_up(system, traj.q[:, :L])  # (E, L): the state at the start of each held step
        seg[traj.diverged] = False
        fast = speed_over_rating(system, traj.v[:, :L])
        fast[traj.diverged] = np.inf
        for e in range(E):
            up[e, first[e]: bounds[e, j + 1]] = seg[e, : lengths[e]]
            ratio[e, first[e]: bounds[e, j + 1]] = fast[e, : lengths[e]]
        x_end = np.where(traj.diverged[:, None], np.nan, traj.x[rows, np.maximum(lengths, 0)])
    return up, ratio, counted


@dataclass(frozen=True, eq=False)
class UptimeResult:
    """Several controllers judged on the same uptime episodes.

    Attributes
    ----------
    system : name. T : episode length (s). resets : resets per episode. jitter : s. dt : control period (s).
    steps : (E, resets) the reset steps of each episode. states : (E, resets, n) the states put there.
    uptime : controller name -> (E,) the share of each episode's control steps with the tip up.
    reset : how each reset moved the robot (`RESETS`).
    speed : controller name -> (E,) the largest speed / rating of each episode (`speed_over_rating`),
        outside the drive windows and the `RELEASE_GRACE` s after each (0 without rated joints).
    over_rating : controller name -> (E,) the share of those samples with a speed above its rating.
    """

    system: str
    T: float
    resets: int
    jitter: float
    dt: float
    steps: np.ndarray
    states: np.ndarray
    uptime: dict = field(default_factory=dict)
    reset: str = "drive"
    speed: dict = field(default_factory=dict)
    over_rating: dict = field(default_factory=dict)

    def table(self) -> str:
        """A markdown table: each controller's mean uptime and its range over the episodes, its peak
        speed / rating and the share of time above the rating (outside the drives and their grace)."""
        E = self.steps.shape[0]
        rows = [f"| controller | uptime, mean of {E} episodes | min | max | peak speed / rating | time above rating |", "|---|---|---|---|---|---|"]
        for name, u in self.uptime.items():
            peak, over = self.speed.get(name, np.full(E, np.nan)), self.over_rating.get(name, np.full(E, np.nan))
            rows.append(f"| {name} | {float(np.mean(u)):.3f} | {float(np.min(u)):.3f} | {float(np.max(u)):.3f} | "
                        f"{float(np.max(peak)):.2f} | {100 * float(np.mean(over)):.2f} % |")
        return "\n".join(rows)

    def to_dict(self) -> dict:
        """JSON-ready: the settings, the schedules and every controller's uptime per episode."""
        return {"system": self.system, "T": self.T, "resets": self.resets, "reset": self.reset, "jitter": self.jitter, "dt": self.dt,
                "reset_times": (self.steps * self.dt).tolist(), "reset_states": self.states.tolist(),
                "uptime": {k: [float(x) for x in u] for k, u in self.uptime.items()},
                "mean": {k: float(np.mean(u)) for k, u in self.uptime.items()},
                "speed_over_rating": {k: [float(x) if np.isfinite(x) else None for x in u] for k, u in self.speed.items()},
                "time_over_rating": {k: [float(x) for x in u] for k, u in self.over_rating.items()}}


def uptime_test(system, controllers: dict, episodes: int = UPTIME_EPISODES, seed: int = 0, T: float = UPTIME_T,
                resets: int = UPTIME_RESETS, jitter: float = UPTIME_JITTER, dt: float = DEFAULT_STEP, workers: int = 1,
                reset: str = "drive") -> UptimeResult:
    """The global-policy uptime test (module docstring) of `controllers` (name -> state feedback
    (N, n) -> (N, m), no clock) on `system` (the true plant: a `System` or its MuJoCo twin), on the
    same `episodes` schedules drawn with `seed`, each reset as `reset` says (`RESETS`); one worker
    process per controller (`workers`, 0: one per core; the laws must pickle)."""
    if episodes < 1 or resets < 0 or not (T > 0 and math.isfinite(T)) or jitter < 0 or jitter * 2 >= T / (resets + 1):
        raise ValueError(f"need episodes ≥ 1, resets ≥ 0, T > 0 and 0 ≤ jitter < half the spacing, got {episodes}, {resets}, {T}, {jitter}")
    if reset not in RESETS:
        raise ValueError(f"unknown reset {reset!r}: one of {', '.join(RESETS)}")
    sched = _schedules(system, int(episodes), seed, float(T), int(resets), float(jitter), float(dt))
    outs = list(process_map(_episode_uptime, [(system, law, sched, float(dt), reset) for law in controllers.values()], workers))
    uptime = {name: up.mean(axis=1) for name, (up, _, _) in zip(controllers, outs)}
    speed = {name: np.where(counted, ratio, 0.0).max(axis=1) for name, (_, ratio, counted) in zip(controllers, outs)}
    over = {name: ((ratio > 1.0) & counted).sum(axis=1) / np.maximum(counted.sum(axis=1), 1) for name, (_, ratio, counted) in zip(controllers, outs)}
    return UptimeResult(system=str(system.name), T=float(T), resets=int(resets), jitter=float(jitter), dt=float(dt),
                        steps=sched.steps, states=sched.states, uptime=uptime, reset=reset, speed=speed, over_rating=over)
