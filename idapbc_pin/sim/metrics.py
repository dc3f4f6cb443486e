"""The closed-loop metrics of DESIGN §4, pure functions of a `Trajectory` (batched over its rows).

Success: inside the box ‖wrap(q − q*)‖∞ ≤ `SUCCESS_TOL`, ‖v‖∞ ≤ `SUCCESS_TOL` at every sample of
the last `SUCCESS_WINDOW` seconds, and not diverged.
"""

from __future__ import annotations

import numpy as np

from ..model.angles import wrap_angles
from ..model.joint import rail_limits as joint_rail_limits
from .trajectory import Trajectory

__all__ = [
    "SUCCESS_TOL",
    "SUCCESS_WINDOW",
    "HOLD_ANGLE",
    "HOLD_SPEED",
    "at_target",
    "equilibrium_offset",
    "holds",
    "in_target_box",
    "on_rail",
    "rail_limits",
    "peak_input",
    "settled",
    "settling_time",
    "speed_limits",
    "speed_over_rating",
    "joint_ratings",
    "success",
    "window_samples",
]

#: DESIGN §4: success is judged over the last SUCCESS_WINDOW seconds ...
SUCCESS_WINDOW = 2.0
#: ... against the box ‖q − q*‖∞ ≤ SUCCESS_TOL (angles wrapped), ‖v‖∞ ≤ SUCCESS_TOL.
SUCCESS_TOL = 0.05


def _window(t: np.ndarray, window: float) -> np.ndarray:
    return t >= t[-1] - window - 1e-9 * max(1.0, abs(t[-1]))


def at_target(q: np.ndarray, v: np.ndarray, system, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(...) bool: ‖wrap(q − q*)‖∞ ≤ tol and ‖v‖∞ ≤ tol for q, v of shape (..., nq) (rad or m, per s)."""
    nq = system.nq
    dq = wrap_angles(q - np.asarray(system.x_star)[:nq], np.asarray(system.angle_mask)[:nq])
    return (np.abs(dq).max(axis=-1) <= tol) & (np.abs(v).max(axis=-1) <= tol)


def in_target_box(traj: Trajectory, system, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(N, T_k) bool: the state is in the target box (`at_target`) at each sample."""
    return at_target(traj.q, traj.v, system, tol)


def window_samples(t: np.ndarray, window: float = SUCCESS_WINDOW) -> int:
    """How many samples of the times t (T_k,) the success test reads: those of the last `window` s."""
    return int(_window(np.asarray(t, float), window).sum())


def success(traj: Trajectory, system, window: float = SUCCESS_WINDOW, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(N,) bool: inside the target box (see `in_target_box`) at every sample of the last `window`
    seconds, and not diverged (DESIGN §4)."""
    box = in_target_box(traj, system, tol)[:, _window(traj.t, window)]
    return box.all(axis=1) & ~traj.diverged


#: DESIGN §4, swing-up: a swing-up *holds* when over the last SUCCESS_WINDOW seconds every wrapped
#: angle (and prismatic coordinate) is within HOLD_ANGLE rad (m) of x* and every speed within HOLD_SPEED.
HOLD_ANGLE, HOLD_SPEED = 0.1, 0.5


def rail_limits(system) -> tuple[np.ndarray, np.ndarray]:
    """(lower (nq,), upper (nq,)): the URDF position limits of every linear coordinate (a prismatic
    joint: a cart on its rail), m; ∓∞ for angles and for a joint without limits (`model.joint.rail_limits`)."""
    return joint_rail_limits(system.joints)


def speed_limits(system) -> np.ndarray:
    """(nq,) the URDF speed limits (`<limit velocity>`, rad/s or m/s) of the actuated joints, the
    motors' rated speeds; +∞ for a joint without one and for every joint the input does not drive."""
    driven = np.abs(np.asarray(system.B, dtype=np.float64)).sum(axis=1) > 0
    return np.array([j.speed if d else np.inf for j, d in zip(system.joints, driven)], dtype=np.float64)


def joint_ratings(system) -> np.ndarray:
    """(nq,) every joint's rated speed, the URDF `<limit velocity>` (rad/s or m/s), passive joints
    included; +∞ for a joint without one (a closed-form system has none)."""
    return np.array([j.speed for j in system.joints], dtype=np.float64)


def speed_over_rating(system, v) -> np.ndarray:
    """(...,) max over the rated joints of |v_j| / v̄_j for speeds v (..., nq) (`joint_ratings`); 0
    where no joint has a rating."""
    rated = joint_ratings(system)
    limited = np.isfinite(rated) & (rated > 0)
    v = np.asarray(v, dtype=np.float64)
    if not limited.any():
        return np.zeros(v.shape[:-1])
    return (np.abs(v[..., limited]) / rated[limited]).max(axis=-1)


def on_rail(traj: Trajectory, system) -> np.ndarray:
    """(N,) bool: every linear coordinate within its URDF position limits (`rail_limits`) at every
    sample; a robot without such limits always passes."""
    lower, upper = rail_limits(system)
    if not (np.isfinite(lower).any() or np.isfinite(upper).any()):
        return np.ones(traj.q.shape[0], bool)
    return ((traj.q >= lower) & (traj.q <= upper)).all(axis=(1, 2))


def holds(traj: Trajectory, system, window: float = SUCCESS_WINDOW) -> np.ndarray:
    """(N,) bool: the swing-up verdict "holds" (DESIGN §4): ‖wrap(q − q*)‖∞ ≤ HOLD_ANGLE and
    ‖v‖∞ ≤ HOLD_SPEED at every sample of the last `window` seconds, not diverged, and on the rail
    throughout (`on_rail`: a prismatic joint within its URDF limits at every sample)."""
    nq = system.nq
    dq = wrap_angles(traj.q - np.asarray(system.x_star)[:nq], np.asarray(system.angle_mask)[:nq])
    near = (np.abs(dq).max(axis=-1) <= HOLD_ANGLE) & (np.abs(traj.v).max(axis=-1) <= HOLD_SPEED)
    return near[:, _window(traj.t, window)].all(axis=1) & ~traj.diverged & on_rail(traj, system)


def settled(traj: Trajectory, window: float = SUCCESS_WINDOW, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(N,) bool: at rest (‖v‖∞ ≤ tol) over the last `window` seconds and not diverged, wherever
    that is (a controller may settle at a wrong equilibrium)."""
    still = np.abs(traj.v[:, _window(traj.t, window)]).max(axis=-1) <= tol
    return still.all(axis=1) & ~traj.diverged


def settling_time(traj: Trajectory, system, tol: float = SUCCESS_TOL) -> np.ndarray:
    """(N,) seconds: the first sample time after which the state stays in the target box until the
    end; nan if it is not in the box at the end or the row diverged."""
    box = in_target_box(traj, system, tol)
    stays = np.flip(np.logical_and.accumulate(np.flip(box, axis=1), axis=1), axis=1)
    first = np.argmax(stays, axis=1)
    out = traj.t[first].astype(float)
    out[~stays[:, -1] | traj.diverged] = np.nan
    return out


def equilibrium_offset(traj: Trajectory, system, window: float = SUCCESS_WINDOW) -> np.ndarray:
    """(N,) ‖x̄ − x*‖₂ with x̄ the mean of x = (q, p) over the last `window` seconds (angle
    components of x − x* wrapped sample by sample before averaging); nan for diverged rows, 0 for
    rows stopped inside the terminal set (``traj.converged``: their limit is x*)."""
    dx = wrap_angles(traj.x[:, _window(traj.t, window)] - np.asarray(system.x_star), system.angle_mask)
    out = np.linalg.norm(dx.mean(axis=1), axis=-1)
    if traj.converged is not None:
        out[traj.converged] = 0.0
    out[traj.diverged] = np.nan
    return out


def peak_input(traj: Trajectory) -> np.ndarray:
    """(N,) max over time and inputs of |u| (N·m or N) along each trajectory."""
    if traj.u.shape[1] == 0 or traj.u.shape[2] == 0:
        return np.zeros(traj.u.shape[0])
    return np.abs(traj.u).max(axis=(1, 2))
