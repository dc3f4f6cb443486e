"""The RealAIGym reset drive: a PID with gravity compensation that pushes the robot towards a posture.

The leaderboard's global policy test resets the robot by a drive: for `DRIVE_T` = 0.2 s the law
under test is not called, and upstream's `PointPIDController` (as the test builds it: kp = 10,
ki = 0.1, kd = 1, its step taken as `PID_DT` = 1 ms while the loop runs at 2 ms) plus gravity
compensation on every joint drives the robot from wherever it is towards a drawn posture, then
releases it, moving. The error q_d − q is not wrapped (q is the plant's own, unwrapped), the PID's
memory is kept across an episode's drives (the integral, and the derivative's first step of a
drive, read the previous drive's errors) and it takes no derivative on its first two calls:

    e_k = q_d − q_k,  u = clip(clip(kp e_k + ki PID_DT Σ_{i≤k} e_i + kd (e_k − e_{k−1}) / PID_DT, ±ū) + ∇U(q_k), ±ū),

ū each joint's limit (`drive_bound`). `evaluation.uptime` resets its episodes with `pid_drive`;
`drive_release_states` gives the states such a drive leaves, for the swing-up stage's anywhere step
to plan from and gate on.

Reference: github.com/dfki-ric-underactuated-lab/double_pendulum, the global policy testing
controller (v2) and its point PID controller; written independently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import IdapbcError
from ..model.resting import resting_configuration

__all__ = ["DRIVE_KD", "DRIVE_KI", "DRIVE_KP", "DRIVE_T", "PID_DT", "DrivePID", "drive_bound", "drive_release_states", "drive_targets", "pid_drive"]

#: The drive: its length (s) and the PID's gains kp (N·m/rad), ki (N·m/(rad·s)), kd (N·m·s/rad) with
#: the step PID_DT (s) it was built with (the leaderboard's).
DRIVE_T, DRIVE_KP, DRIVE_KI, DRIVE_KD, PID_DT = 0.2, 10.0, 0.1, 1.0, 0.001


def drive_bound(system) -> np.ndarray:
    """(nq,) the drive's torque limit on each joint, N·m or N: its URDF effort limit where finite,
    else the largest finite limit of the robot's inputs."""
    effort = np.asarray(system.effort, float)
    fallback = float(effort[np.isfinite(effort)].max()) if np.isfinite(effort).any() else np.inf
    own = np.array([float(j.effort) for j in system.joints])
    return np.where(np.isfinite(own) & (own > 0), own, fallback)


@dataclass
class DrivePID:
    """The drive's PID memory over a batch (E,): the sum of its errors (E, nq), the last error (E, nq)
    and how many times it was called (the same for every row)."""

    total: np.ndarray
    last: np.ndarray
    calls: int = 0

    @classmethod
    def fresh(cls, rows: int, nq: int) -> "DrivePID":
        """A memory that has never been called: (rows, nq) zeros."""
        return cls(np.zeros((rows, nq)), np.zeros((rows, nq)))

    def __call__(self, target: np.ndarray, q: np.ndarray) -> np.ndarray:
        """kp e + ki PID_DT Σe + kd Δe / PID_DT (E, nq) at positions q (E, nq), e = target − q unwrapped."""
        e = target - q
        self.total = self.total + e
        self.calls += 1
        d = (e - self.last) / PID_DT if self.calls > 2 else np.zeros_like(e)
        self.last = e
        return DRIVE_KP * e + DRIVE_KI * PID_DT * self.total + DRIVE_KD * d


def pid_drive(system, x: np.ndarray, target: np.ndarray, ticks: int, dt: float, pid: DrivePID | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The drive (module docstring) from the states x (E, n) towards the postures target (E, nq) over
    `ticks` steps of dt s (RK4, the torque held per step), with the PID memory `pid` (updated; None: a
    fresh one): (the states at the start of each step (E, ticks, n), the state at the end (E, n))."""
    bound = drive_bound(system)
    q, v = (np.array(a, float) for a in system.split(x))
    pid = DrivePID.fresh(*q.shape) if pid is None else pid

    def accel(q, v):
        rest = np.zeros_like(q)
        gravity = -np.einsum("nij,nj->ni", system.mass_matrix(q), system.forward_dynamics(q, rest, rest))  # ∇U(q)
        tau = np.clip(np.clip(pid(target, q), -bound, bound) + gravity, -bound, bound)
        return lambda q2, v2: system.forward_dynamics(q2, v2, tau)

    xs = []
    for _ in range(ticks):
        xs.append(np.concatenate([q, v], axis=1))
        f = accel(q, v)
        k1q, k1v = v, f(q, v)
        k2q, k2v = v + 0.5 * dt * k1v, f(q + 0.5 * dt * k1q, v + 0.5 * dt * k1v)
        k3q, k3v = v + 0.5 * dt * k2v, f(q + 0.5 * dt * k2q, v + 0.5 * dt * k2v)
        k4q, k4v = v + dt * k3v, f(q + dt * k3q, v + dt * k3v)
        q, v = q + dt / 6.0 * (k1q + 2 * k2q + 2 * k3q + k4q), v + dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return np.stack(xs, axis=1), system.state_from(q, v)


def drive_targets(system, states: np.ndarray) -> np.ndarray:
    """(..., nq) the drive's postures for the drawn states (..., n): their angles within π of the
    resting posture's (rad), their linear coordinates as drawn (m)."""
    q = system.split(states.reshape(-1, system.n))[0]
    rest = resting_configuration(system)[None]
    angle = np.asarray(system.angle_mask, bool)[: system.nq]
    q = np.where(angle, rest + (q - rest + np.pi) % (2 * np.pi) - np.pi, q)
    return q.reshape(states.shape[:-1] + (system.nq,))


def drive_release_states(system, n: int, seed: int = 0, dt: float = 0.002) -> np.ndarray:
    """(n, n_x) states x = (q, p) as a reset of the uptime test releases them: the drive run for
    `DRIVE_T` s (steps of dt s) towards postures with every angle x*'s + U(−π, π) (rad; linear
    coordinates at the resting posture's), from x* at rest (the first ⌈n/2⌉ rows, where a reset
    mostly finds a law that holds) and from `moving_states` (the others: a reset that finds the robot
    still swinging up). Each drive's PID memory is that of an earlier drive from x* at rest towards a
    posture of its own, so its derivative's first step kicks as in an episode's second and later
    resets. Drawn from numpy's default_rng(seed): the postures of the earlier drives, then the targets;
    the moving starts from `moving_states` with seed + 1."""
    from .states import moving_states

    if n < 1:
        raise IdapbcError(f"drive release states need n ≥ 1, got {n}. Fix: pass n ≥ 1.")
    n, nq = int(n), system.nq
    rng = np.random.default_rng(seed)
    rest = resting_configuration(system)
    angle = np.asarray(system.angle_mask, bool)[:nq]
    x_star = np.asarray(system.x_star, float)

    def postures() -> np.ndarray:
        q = np.where(angle, x_star[:nq] + rng.uniform(-np.pi, np.pi, (n, nq)), np.tile(rest, (n, 1)))
        return drive_targets(system, system.state_from(q, np.zeros_like(q)))

    earlier, targets = postures(), postures()
    q_up = np.tile(x_star[:nq], (n, 1))
    up = system.state_from(q_up, np.zeros_like(q_up))
    ticks = int(round(DRIVE_T / dt))
    pid = DrivePID.fresh(n, nq)
    pid_drive(system, up, earlier, ticks, dt, pid)  # the memory an earlier drive leaves
    k = (n + 1) // 2
    start = up if k == n else np.concatenate([up[:k], moving_states(system, n - k, seed + 1)])
    return pid_drive(system, start, targets, ticks, dt, pid)[1]
