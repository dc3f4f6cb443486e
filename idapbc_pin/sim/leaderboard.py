"""The RealAIGym simulation leaderboard's tip test and v2 score of a swing-up: success · (1 − ⅕ Σ tanh(π c_i / n_i)).

* `tip_swingup_times`: the tip test of a `Trajectory`. With h_rest and h* the tip's height
  (`idapbc_pin.model.resting.tip_height`) at rest and at x*, the swing-up time is the first sample
  time from which the normalised height (h − h_rest)/(h* − h_rest) stays ≥ `TIP_SHARE` to the end
  (a cart on its rail throughout). For a chain hanging straight down from its pivot (h_rest = −L,
  h* = L) that is exactly the leaderboard's h ≥ 0.9 L measured from the pivot.
* `leaderboard_score`: the v2 score of one trajectory given its swing-up time; `row_score`: the
  same for one row of a `Trajectory` (the swing-up stage and the swing-up evaluation both use it).

The criteria c_i of a trajectory sampled at t_0 … t_K (the input τ_k held over [t_k, t_{k+1}]),
summed over every joint (an unactuated joint's torque is 0):

* swing-up time: when the tip enters the region above the threshold and stays there to the end
  (`tip_swingup_times` measures it); success: it does so before the end;
* energy Σ_k Σ_j |(q_{k+1,j} − q_{k,j}) τ_{k,j}| (J);
* torque cost Σ_k τ_kᵀ τ_k (t_{k+1} − t_k) (N²·m²·s);
* torque smoothness Σ_j std_k(τ_{k+1,j} − τ_{k,j}) over all samples, population std (N·m);
* velocity cost Σ_k v_kᵀ v_k (t_{k+1} − t_k), every joint (rad²/s);

normalised by n = 20 s, 60 J, 20, 0.1 N·m and 400 (`NORMALISATION`), each with weight 1, and the
sum divided by the number of criteria with a non-zero weight (5).

Definitions read from github.com/dfki-ric-underactuated-lab/double_pendulum:
src/python/double_pendulum/analysis/leaderboard.py (``leaderboard_scores`` with
``score_version="v2"``, ``get_energy``, ``get_torque_cost``, ``get_tau_smoothness``,
``get_velocity_cost``, ``get_swingup_time``) and
leaderboard/pendubot/simulation_v2/calculate_leaderboard_score.py (weights and normalisations; the
acrobot's are the same). This module is written independently from those definitions.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..model.resting import resting_configuration, tip_height
from .metrics import on_rail, rail_limits
from .trajectory import Trajectory

__all__ = ["NORMALISATION", "TIP_SHARE", "LeaderboardScore", "leaderboard_score", "row_score", "stays_from", "tip_share", "tip_swingup_times", "tip_up"]

#: The tip test: normalised tip height ≥ TIP_SHARE (0.95 ⇔ the leaderboard's 0.9 L above the pivot).
TIP_SHARE = 0.95

#: The v2 normalisation n_i of each criterion (weights 1).
NORMALISATION = {"swingup_time": 20.0, "energy": 60.0, "torque_cost": 20.0, "torque_smoothness": 0.1, "velocity_cost": 400.0}


@dataclass(frozen=True)
class LeaderboardScore:
    """The v2 criteria of one trajectory and its score (module docstring for the definitions).

    Attributes
    ----------
    success : the tip swung up before the end and stayed up.
    swingup_time : s, nan without success.
    energy : J. torque_cost : N²·m²·s. torque_smoothness : N·m. velocity_cost : rad²/s (m²/s on
        prismatic joints).
    score : success · (1 − ⅕ Σ tanh(π c_i / n_i)), in [0, 1]; 0 without success.
    """

    success: bool
    swingup_time: float
    energy: float
    torque_cost: float
    torque_smoothness: float
    velocity_cost: float
    score: float

    def to_dict(self) -> dict:
        """JSON-ready (nan as None)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}


def leaderboard_score(t, q, v, tau, swingup_time: float) -> LeaderboardScore:
    """The RealAIGym v2 score of one trajectory.

    Parameters
    ----------
    t : (K,) sample times, s. q, v : (K, nq) positions (rad or m, not wrapped) and velocities.
    tau : (K, nq) joint torques (N·m or N), B u; tau[k] held over [t_k, t_{k+1}].
    swingup_time : s, from the tip test; nan (or ≥ t[-1]) means no success.
    """
    t, q, v, tau = (np.asarray(a, float) for a in (t, q, v, tau))
    if not (t.ndim == 1 and q.shape == v.shape == tau.shape and q.shape[0] == t.shape[0] and t.shape[0] >= 2):
        raise ValueError(f"need t (K,) and q, v, tau (K, nq) with K ≥ 2, got {t.shape}, {q.shape}, {v.shape}, {tau.shape}")
    h = np.diff(t)
    criteria = {
        "swingup_time": float(swingup_time),
        "energy": float(np.abs(np.diff(q, axis=0) * tau[:-1]).sum()),
        "torque_cost": float((np.einsum("kj,kj->k", tau[:-1], tau[:-1]) * h).sum()),
        "torque_smoothness": float(np.std(np.diff(tau, axis=0), axis=0).sum()),
        "velocity_cost": float((np.einsum("kj,kj->k", v[:-1], v[:-1]) * h).sum()),
    }
    success = bool(math.isfinite(criteria["swingup_time"]) and criteria["swingup_time"] < t[-1])
    penalty = sum(math.tanh(math.pi * criteria[k] / n) for k, n in NORMALISATION.items()) / len(NORMALISATION) if success else 1.0
    return LeaderboardScore(
        success=success,
        swingup_time=criteria["swingup_time"] if success else math.nan,
        energy=criteria["energy"],
        torque_cost=criteria["torque_cost"],
        torque_smoothness=criteria["torque_smoothness"],
        velocity_cost=criteria["velocity_cost"],
        score=float(1.0 - penalty) if success else 0.0,
    )


def stays_from(flags: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N,) s: the first sample time from which `flags` (N, K) holds to the end; nan where the last
    sample fails."""
    stays = np.flip(np.logical_and.accumulate(np.flip(flags, axis=1), axis=1), axis=1)
    out = t[np.argmax(stays, axis=1)].astype(float)
    out[~stays[:, -1]] = np.nan
    return out


def tip_share(system, q) -> np.ndarray:
    """(...) the tip's normalised height (h − h_rest)/(h* − h_rest) at configurations q (..., nq):
    0 at rest, 1 at x* (`idapbc_pin.model.resting.tip_height`)."""
    nq = system.nq
    q = np.asarray(q, float)
    h_rest = float(tip_height(system, resting_configuration(system)))
    h_star = float(tip_height(system, np.asarray(system.x_star, float)[:nq]))
    return ((tip_height(system, q.reshape(-1, nq)) - h_rest) / (h_star - h_rest)).reshape(q.shape[:-1])


def tip_up(system, q: np.ndarray) -> np.ndarray:
    """(...) bool: the tip is up at configurations q (..., nq): its normalised height
    (h − h_rest)/(h* − h_rest) ≥ `TIP_SHARE`, and every linear coordinate within its rail."""
    q = np.asarray(q, float)
    lower, upper = rail_limits(system)
    return (tip_share(system, q) >= TIP_SHARE) & ((q >= lower) & (q <= upper)).all(axis=-1)


def tip_swingup_times(system, traj: Trajectory) -> np.ndarray:
    """(N,) s: the tip test's swing-up time of each row of `traj` (module docstring); nan where the
    tip is not up at the end, the row diverged or a cart left its rail. Needs a URDF system
    (`tip_height` raises IdapbcError for a built-in analytic one)."""
    out = stays_from(tip_share(system, traj.q) >= TIP_SHARE, traj.t)
    out[traj.diverged | ~on_rail(traj, system) | ~(out < traj.t[-1])] = np.nan
    return out


def row_score(system, traj: Trajectory, row: int = 0, swingup_time: float | None = None) -> LeaderboardScore:
    """The v2 score of row `row` of `traj` (recorded at every step, inputs u (N, K, m) held over
    each step), with that row's tip-test swing-up time (`tip_swingup_times`, unless given)."""
    B = np.asarray(system.B, float)
    if swingup_time is None:
        rows = slice(row, row + 1)
        one = Trajectory(traj.t, traj.x[rows], traj.q[rows], traj.v[rows], traj.u[rows], traj.diverged[rows])
        swingup_time = float(tip_swingup_times(system, one)[0])
    return leaderboard_score(traj.t, traj.q[row], traj.v[row], traj.u[row] @ B.T, swingup_time)
