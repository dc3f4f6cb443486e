"""Initial states for evaluation: boxes around x* and uniform draws from them (fixed seeds)."""

from __future__ import annotations

import numpy as np

from ..errors import IdapbcError

__all__ = ["ANYWHERE_SPEED", "moving_states", "RESTING_SPREAD", "anywhere_states", "box_gate_states", "circle_states", "evaluation_box", "half_box", "initial_states", "resting_states", "scaled_box", "uniform_states"]


def half_box(system) -> tuple[np.ndarray, np.ndarray]:
    """The training domain shrunk by half around x*: x* + (lo − x*)/2, x* + (hi − x*)/2."""
    lo, hi = (np.asarray(b, float) for b in system.domain)
    x_star = np.asarray(system.x_star, float)
    return x_star + 0.5 * (lo - x_star), x_star + 0.5 * (hi - x_star)


def evaluation_box(system, box="domain") -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), each (n,): ``"domain"`` (the training box), ``"half"`` (`half_box`) or a pair."""
    if isinstance(box, str):
        if box == "domain":
            lo, hi = system.domain
            return np.asarray(lo, float).copy(), np.asarray(hi, float).copy()
        if box == "half":
            return half_box(system)
        raise ValueError(f"box must be 'domain', 'half' or a (lo, hi) pair, got {box!r}")
    lo, hi = (np.broadcast_to(np.asarray(b, float), (system.n,)).copy() for b in box)
    if np.any(~(hi >= lo)):
        raise ValueError("box: need lo ≤ hi componentwise")
    return lo, hi


def uniform_states(system, n: int, box="domain", seed: int = 0) -> np.ndarray:
    """(n, system.n) states (q, p) drawn uniformly from `evaluation_box(system, box)`."""
    lo, hi = evaluation_box(system, box)
    return lo + (hi - lo) * np.random.default_rng(seed).random((int(n), system.n))


def box_gate_states(system, n: int, seed: int) -> np.ndarray:
    """(n, system.n) states of a gate's box check: n // 2 uniform in the half box (`seed`), the rest
    uniform in the training box (seed + 1)."""
    half = int(n) // 2
    return np.concatenate([uniform_states(system, half, "half", seed), uniform_states(system, int(n) - half, "domain", seed + 1)])


def initial_states(system, x0, n: int, seed: int) -> np.ndarray:
    """(N, n) start states: the given `x0` ((N, n) states, or (N, nq) positions at rest), or, when
    `x0` is None, `n` uniform states of the half box drawn with `seed`."""
    if x0 is None:
        if int(n) < 1:
            raise IdapbcError(f"n must be at least 1, got {n}. Fix: pass --n 1 or more.")
        return uniform_states(system, int(n), box="half", seed=seed)
    x0 = np.atleast_2d(np.asarray(x0, float))
    if x0.ndim == 2 and x0.shape[1] == system.nq:  # positions at rest
        x0 = np.concatenate([x0, np.zeros_like(x0)], axis=1)
    if x0.ndim != 2 or x0.shape[1] != system.n:
        raise IdapbcError(f"x0 needs {system.n} values (q, p: {', '.join(system.state_names)}) or {system.nq} positions at rest, got shape {x0.shape}.")
    if not np.all(np.isfinite(x0)):
        raise IdapbcError("x0 contains NaN or inf. Fix: give finite values.")
    return x0


def scaled_box(system, s: float) -> tuple[np.ndarray, np.ndarray]:
    """X_s = x* + s·(X − x*): (lo, hi), each (n,). s = 1 is the training domain itself and s = 0.5
    equals `half_box` bit for bit."""
    lo, hi = evaluation_box(system, "domain")
    if s == 1.0:
        return lo, hi
    x_star = np.asarray(system.x_star, float)
    return x_star + s * (lo - x_star), x_star + s * (hi - x_star)


#: Spread of the near-resting starts of a swing-up about the resting posture: ± rad (m) and ± rad/s (m/s).
RESTING_SPREAD = 0.1


def resting_states(system, n: int, seed: int = 0, spread: float = RESTING_SPREAD) -> np.ndarray:
    """n start states x = (q, p) (n, 2·nq) of a swing-up (DESIGN §4): the first exactly at rest in the
    resting posture q_rest (`idapbc_pin.model.resting.resting_configuration`), the others q_rest +
    U(−spread, spread) and speeds U(−spread, spread), drawn from numpy's default_rng(seed)."""
    from ..model.resting import resting_configuration

    if n < 1:
        raise IdapbcError(f"a swing-up needs at least one start state, got n = {n}. Fix: pass n ≥ 1.")
    rng = np.random.default_rng(seed)
    q = np.tile(resting_configuration(system), (n, 1))
    v = np.zeros_like(q)
    q[1:] += rng.uniform(-spread, spread, q[1:].shape)
    v[1:] += rng.uniform(-spread, spread, v[1:].shape)
    return system.state_from(q, v)


def circle_states(system, n: int, seed: int = 0) -> np.ndarray:
    """n start states x = (q, p) (n, 2·nq) at rest from anywhere on the full circle: the first exactly
    in the resting posture q_rest (`idapbc_pin.model.resting.resting_configuration`), the others with
    every angle x*'s + U(−π, π) (rad) and every linear coordinate at q_rest's (m), v = 0, drawn from
    numpy's default_rng(seed)."""
    q, _ = system.split(resting_states(system, n, seed, spread=0.0))  # every row at rest in q_rest
    angle = np.asarray(system.angle_mask, bool)[: system.nq]
    drawn = np.asarray(system.x_star, float)[: system.nq] + np.random.default_rng(seed).uniform(-np.pi, np.pi, q[1:].shape)
    q[1:] = np.where(angle, drawn, q[1:])
    return system.state_from(q, np.zeros_like(q))


#: Speeds of the "anywhere" starts: U(−ANYWHERE_SPEED, ANYWHERE_SPEED) rad/s (m/s) on every coordinate.
ANYWHERE_SPEED = 1.0


def anywhere_states(system, n: int, seed: int = 0, speed: float = ANYWHERE_SPEED) -> np.ndarray:
    """n start states x = (q, p) (n, 2·nq) from anywhere on the torus, moving: the first exactly at
    rest in the resting posture, the others with the postures of `circle_states` (every angle x*'s +
    U(−π, π), every linear coordinate at the resting posture's) and every speed U(−speed, speed)
    (rad/s or m/s), p = M(q) v; drawn from numpy's default_rng(seed) (the speeds after the postures)."""
    q, _ = system.split(circle_states(system, n, seed))
    rng = np.random.default_rng(seed)
    rng.uniform(-np.pi, np.pi, q[1:].shape)  # the postures' draw (circle_states), so the speeds come after it
    v = np.zeros_like(q)
    v[1:] = rng.uniform(-speed, speed, v[1:].shape)
    return system.state_from(q, v)


def moving_states(system, n: int, seed: int = 0) -> np.ndarray:
    """n start states x = (q, p) (n, 2·nq) anywhere and moving: every angle x*'s + U(−π, π) (rad),
    every linear coordinate at the resting posture's (m), and every joint's speed U(−v̄, v̄) with v̄
    its URDF rated speed (`<limit velocity>`, rad/s or m/s; `ANYWHERE_SPEED` for a joint without
    one), p = M(q) v; drawn from numpy's default_rng(seed), the postures first. No row is at rest."""
    from ..model.resting import resting_configuration
    from .metrics import joint_ratings

    if n < 1:
        raise IdapbcError(f"moving starts need n ≥ 1, got {n}. Fix: pass n ≥ 1.")
    rng = np.random.default_rng(seed)
    nq = system.nq
    q = np.tile(resting_configuration(system), (int(n), 1))
    angle = np.asarray(system.angle_mask, bool)[:nq]
    q = np.where(angle, np.asarray(system.x_star, float)[:nq] + rng.uniform(-np.pi, np.pi, q.shape), q)
    rated = joint_ratings(system)
    rated = np.where(np.isfinite(rated) & (rated > 0), rated, ANYWHERE_SPEED)
    v = rng.uniform(-1.0, 1.0, q.shape) * rated
    return system.state_from(q, v)
