"""The judge's step: `loop_pole`, `step_for_pole` and `judge_step`.

The judge runs a control law as a robot does: sampled every dt and held over the step (a 500 Hz
digital controller at the default `DEFAULT_STEP` = 2 ms, MuJoCo's own default step), the plant
integrated by classical RK4 over that step; MuJoCo's RK4 integrator stepping the same URDF with the
torque held follows the judge's trajectory to 1e-6 (tests/test_mujoco_judge.py). Saturated swings
are sensitive to how the law is sampled, so the law is held as a robot holds it rather than
evaluated at every RK4 stage (docs/results-history.md); which states a chaotic swing catches still
depends on the integrator at any control rate (docs/method.md §5).

Classical RK4 with step dt is stable on a linear mode λ only while |λ|·dt stays inside its stability
region (up to 2.78 on the negative real axis), and a sampled law needs a step short against the loop
too. Every evaluation takes ``dt=None`` to mean: `DEFAULT_STEP`, or a shorter step where a judged
loop, linearised at x*, has a pole faster than ``POLE_STEP / DEFAULT_STEP`` (250 1/s). The zoo robots and
the paper's benchmarks stay at 2 ms; a plant with joint damping on light links can itself have poles
above 100 1/s, which a longer step would not follow.
"""

from __future__ import annotations

import math
import warnings
from typing import Mapping

import numpy as np

from ..errors import IdapbcError
from .judge import Judge

__all__ = ["DEFAULT_STEP", "MIN_AUTO_STEP", "POLE_STEP", "horizon", "judge_step", "loop_pole", "step_for_pole"]

#: The judge's RK4 step and control period (s) unless a loop is stiffer: a 500 Hz controller.
DEFAULT_STEP = 0.002
#: The largest |λ|·dt an automatic step allows at x* (the loop is faster still away from x*).
POLE_STEP = 0.5
#: The shortest automatic step (s): a loop faster than POLE_STEP / MIN_AUTO_STEP (500 1/s) gets this
#: step and a warning, since a shorter one makes every rollout of 20 s too long to simulate.
MIN_AUTO_STEP = 1e-3
#: Relative size of the central-difference steps of `loop_pole`.
_FD_STEP = 1e-6


def loop_pole(system, ctrl, threads: int | None = None) -> float:
    """The fastest |λ| (1/s) of the closed loop ``q̇ = v, v̇ = a(q, v, B u(x(q, v)))`` linearised at
    (q*, 0) by central differences on the judge `system` (its forward dynamics, not the model).

    ctrl : callable (N, n) -> (N, m); the input is not clipped (the limits do not act at x*). A
    controller with measurement noise is linearised through its ``noise_free`` version when it has one.
    Returns nan when the controller or the plant gives non-finite values there.
    """
    ctrl = getattr(ctrl, "noise_free", ctrl)
    judge = Judge(system, threads)
    nq = judge.nq
    z0 = np.concatenate([np.asarray(system.x_star, float)[:nq], np.zeros(nq)])
    h = _FD_STEP * np.maximum(1.0, np.abs(z0))
    Z = np.concatenate([z0 + np.diag(h), z0 - np.diag(h)])  # (2·2nq, 2nq): +h rows, then −h rows
    q, v = Z[:, :nq], Z[:, nq:]
    u = np.asarray(ctrl(judge.state(q, v)), float)
    m = judge.B.shape[1]
    if u.size != Z.shape[0] * m:
        raise ValueError(f"the controller returned shape {u.shape} for {Z.shape[0]} states; expected ({Z.shape[0]}, {m})")
    u = u.reshape(Z.shape[0], m)
    F = np.concatenate([v, judge.accel(q, v, u @ judge.B.T)], axis=1)
    n = 2 * nq
    J = ((F[:n] - F[n:]) / (2.0 * h[:, None])).T  # column i: ∂ż/∂z_i
    if not np.all(np.isfinite(J)):
        return math.nan
    return float(np.abs(np.linalg.eigvals(J)).max())


def step_for_pole(fastest: float, T: float, default: float = DEFAULT_STEP, pole_step: float = POLE_STEP) -> float:
    """`default`, or where ``fastest · default > pole_step`` the largest step ≤ ``pole_step / fastest``
    that divides the horizon `T` (s) into whole steps. A non-finite `fastest` keeps `default`."""
    if not math.isfinite(fastest) or fastest * default <= pole_step or T <= 0:
        return float(default)
    return float(T) / math.ceil(float(T) * fastest / pole_step)


def judge_step(system, controllers: Mapping[str, object], T: float, dt: float | None = None) -> float:
    """The RK4 step (s) to judge `controllers` on `system` over horizon `T`: `dt` when given, else
    `step_for_pole` of the fastest `loop_pole` among them, never below `MIN_AUTO_STEP` (with a warning
    that names ``--dt``)."""
    if dt is not None:
        return float(dt)
    poles = [p for p in (loop_pole(system, c) for c in controllers.values()) if not math.isnan(p)]
    fastest = max(poles, default=math.nan)
    step = step_for_pole(fastest, T)
    if step < MIN_AUTO_STEP:
        short = step_for_pole(POLE_STEP / MIN_AUTO_STEP, T)
        warnings.warn(
            f"a judged loop has a pole of {fastest:.3g} 1/s at x*, too stiff for the {short * 1e3:.3g} ms RK4 step the judge "
            f"allows itself; rollouts may diverge numerically. Fix: pass an explicit step (--dt / dt=) of at most {POLE_STEP / fastest:.2g} s.",
            RuntimeWarning,
            stacklevel=2,
        )
        return short
    return step


def horizon(T: float, dt: float) -> float:
    """T rounded to a whole number (≥ 1) of steps dt, s; a non-positive T or dt is an `IdapbcError`."""
    if not (dt > 0 and math.isfinite(dt)):
        raise IdapbcError(f"dt must be a positive number of seconds, got {dt!r}.")
    if not (T > 0 and math.isfinite(T)):
        raise IdapbcError(f"T must be a positive number of seconds, got {T!r}. Fix: e.g. --T 20.")
    return max(1, int(round(T / dt))) * dt
