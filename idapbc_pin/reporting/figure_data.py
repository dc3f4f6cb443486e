"""`FigureData`: the arrays one row of the paper's figure is drawn from, simulated and evaluated.

The true plant integrates; H_d and the dissipation margin along the rollouts are those of the
controller's model (`idapbc_pin.certificate.terms.closed_loop_terms`), so that tests can hold the
panels against the simulated trajectories.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..certificate.certify import resolve_controller
from ..certificate.terms import closed_loop_terms
from ..errors import IdapbcError
from ..evaluation.robustness import MeasuredController
from ..sim.integrate import simulate
from ..sim.states import initial_states
from ..sim.step import horizon, judge_step

__all__ = ["FigureData", "figure_data"]


@dataclass(frozen=True, eq=False)
class FigureData:
    """What one row of the figure shows.

    Attributes
    ----------
    label : row label (system, ρ, conditions).
    traj : the simulated `Trajectory` (t (K,), q, v (N, K, nq), x (N, K, n), u (N, K, m)).
    H : (N, K) H_d along the trajectories.
    margin : (N, K) ∇H_dᵀR_d∇H_d − ∇H_dᵀξ along them (> 0: the dissipation inequality holds).
    epsilon : ε of E = H_ε.
    t_E : (N,) first time with H_d < ε (nan if never).
    rho : the controller's ρ (nan if it has none).
    in_domain : (N, K) bool, the state lies in the training box X (where the certificate samples).
    valid : (N, K) bool, False after a trajectory diverged (`simulate` freezes diverged rows at
        their last finite state; the figure leaves those samples out).
    coordinate_names, input_names : names of q and u components.
    q_units, p_units, u_units : per component ("rad", "m"; "N·m·s", "N·s"; "N·m", "N").
    """

    label: str
    traj: object
    H: np.ndarray
    margin: np.ndarray
    epsilon: float
    t_E: np.ndarray
    rho: float
    in_domain: np.ndarray
    valid: np.ndarray
    coordinate_names: tuple
    input_names: tuple
    q_units: tuple
    p_units: tuple
    u_units: tuple

    @property
    def p(self) -> np.ndarray:
        """(N, K, nq) momenta, the second half of x."""
        nq = len(self.coordinate_names)
        return self.traj.x[..., nq:]


def _units(system):
    joints = system.joints
    q = tuple("rad" if j.is_angle else "m" for j in joints)
    p = tuple("N·m·s" if j.is_angle else "N·s" for j in joints)
    by_name = {j.name: j for j in joints}
    u = tuple("N·m" if by_name[a].is_angle else "N" for a in system.actuated)
    return q, p, u


def _valid(traj) -> np.ndarray:
    """(N, K): True up to the last finite state of a diverged row (the frozen repeats after it: False)."""
    valid = np.ones(traj.x.shape[:2], bool)
    for k in np.flatnonzero(traj.diverged):
        same = np.all(traj.x[k] == traj.x[k, -1], axis=-1)
        frozen_from = len(same) - int(np.argmin(same[::-1])) if not same.all() else 0
        valid[k, frozen_from + 1 :] = False
    return valid


def _entry_times(t: np.ndarray, H: np.ndarray, epsilon: float) -> np.ndarray:
    inside = H < epsilon
    first = np.argmax(inside, axis=1)
    out = t[first].astype(float)
    out[~inside.any(axis=1)] = np.nan
    return out


def figure_data(
    run,
    x0=None,
    n: int = 4,
    T: float = 20.0,
    dt: float | None = None,
    seed: int = 0,
    *,
    rho: float | None = None,
    epsilon: float | None = None,
    plant=None,
    saturation=None,
    noise: float = 0.0,
    traj=None,
    label: str | None = None,
    limits: bool = True,
) -> FigureData:
    """Simulate and evaluate one row of the figure.

    Parameters
    ----------
    run : a `Run`, a run directory or a controller (see `idapbc_pin.certificate.terms`).
    x0 : (N, n) initial states or (N, nq) positions at rest; default `n` uniform states of the
        half-size box (seed `seed`).
    T, dt : horizon and RK4 step, s (dt None: 2 ms, or shorter for a stiff loop, `judge_step`).
    rho : replace the controller's ρ ("extra damping", `Controller.with_damping`).
    epsilon : ε of E (default the run's estimate).
    plant : the judge `System` (default the controller's model), e.g. `perturbed_system(...)`.
    saturation, noise : as in `simulate` and `MeasuredController`.
    limits : clip the input to the judge's effort limits (the default); False lifts them.
    traj : an already simulated `Trajectory` of this controller (then nothing is simulated).
    """
    ctrl, system, eps, _ = resolve_controller(run, epsilon)
    if rho is not None:
        if not hasattr(ctrl, "with_damping"):
            raise IdapbcError(f"{type(ctrl).__name__} has no with_damping(ρ). Fix: drop rho.")
        if not (math.isfinite(rho) and rho >= 0):
            raise IdapbcError(f"ρ must be finite and ≥ 0, got {rho}. Fix: e.g. --rho 1.")
        ctrl = ctrl.with_damping(float(rho))
    if traj is None:
        x0 = initial_states(system, x0, n, seed)
        judge = system if plant is None else plant
        law = ctrl if (plant is None and not noise) else MeasuredController(ctrl, plant=judge, model=system, noise=noise, seed=seed)
        if saturation is not None and not np.all(np.asarray(saturation, float) > 0):
            raise IdapbcError(f"saturation must be > 0 (max |u| per input), got {saturation!r}.")
        dt = judge_step(judge, {"law": ctrl}, T, dt)  # the noise-free law
        traj = simulate(judge, law, x0, T=horizon(T, dt), dt=dt, saturation=saturation, limits=limits)
    N, K, nx = traj.x.shape
    terms = closed_loop_terms(ctrl, traj.x.reshape(N * K, nx), system)
    H, margin = terms.H.reshape(N, K), terms.margin.reshape(N, K)
    q_u, p_u, u_u = _units(system)
    r = float(ctrl.rho) if hasattr(ctrl, "rho") else math.nan
    if label is None:
        label = f"{getattr(system, 'name', 'system')}, ρ = {r:g}" if math.isfinite(r) else str(getattr(system, "name", "system"))
    return FigureData(
        label=label, traj=traj, H=H, margin=margin, epsilon=eps, t_E=_entry_times(traj.t, H, eps), rho=r, valid=_valid(traj),
        in_domain=np.all((traj.x >= system.domain[0]) & (traj.x <= system.domain[1]), axis=-1),
        coordinate_names=tuple(system.coordinate_names), input_names=tuple(system.actuated),
        q_units=q_u, p_units=p_u, u_units=u_u,
    )
