"""Goal: how slow can a moving start be kept after its release grace, whatever the law?

The moving-start test asks that no joint run above 1.5 times its rated speed once `RELEASE_GRACE`
(0.5 s) has passed. From some starts the passive joints speed up after that whatever the motors do.
For a run: the deployed law's peak of max_i |v_i| / rating_i after the grace, from `--starts`
moving states (`swingup_states(..., "moving")`, Pinocchio's plant, the URDF limits); then, for the
`--worst` starts with the highest peaks, the lowest peak that an open-loop search finds: torque
held piecewise constant over `--knots` knots of `--horizon` s within the limits (u = u_max·tanh z),
a soft maximum of the speed ratios after the grace minimised by L-BFGS with finite-difference
gradients, from `--restarts` initial histories (zero, full torque either way, random). A local search:
its figure, like the law's own, is an upper bound on the lowest peak, so a start whose lowest known
peak is above 1.5 is evidence, not proof, that no law meets the clause there. RK4 at `--dt` (the best history rechecked at dt/2).
Run: python benchmarks/bench_speed_floor.py RUN [RUN ...] [--starts 100] [--worst 10] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.optimize import minimize

import idapbc_pin as ip
from idapbc_pin.control.speed_governor import SpeedGovernor
from idapbc_pin.evaluation.swingup import RELEASE_GRACE, swingup_states
from idapbc_pin.sim.integrate import simulate

SOFTNESS = 30.0  # of the soft maximum, per unit of speed ratio


def ratios(system, x0: np.ndarray, U: np.ndarray, horizon: float, dt: float) -> np.ndarray:
    """(B, steps, nq) |v| / rating from one start x0 (n,) under B open-loop histories U (B, K) of
    inputs in units of the limits, each knot held for horizon / K s (one input: m = 1)."""
    bound = np.asarray(system.effort, np.float64)
    rating = SpeedGovernor.of(system).rating
    steps, K = int(round(horizon / dt)), U.shape[1]
    x = np.repeat(np.asarray(x0, np.float64)[None], len(U), 0)
    out = []
    for k in range(steps):
        u = bound * U[:, [min(k * K // steps, K - 1)]]

        def field(z):
            return system.f(z) + (system.g(z) @ u[..., None])[..., 0]

        k1 = field(x)
        k2 = field(x + 0.5 * dt * k1)
        k3 = field(x + 0.5 * dt * k2)
        k4 = field(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(np.abs(system.split(x)[1]) / rating)
    return np.stack(out, 1)


def _late(R: np.ndarray, dt: float) -> np.ndarray:
    return R[:, int(round(RELEASE_GRACE / dt)):, :].reshape(len(R), -1)


def lowest_peak(system, x0, knots: int, horizon: float, dt: float, restarts: int, seed: int) -> float:
    """The lowest peak speed ratio after the grace found from x0 (module docstring), at dt / 2."""
    def soft(z_batch):
        late = _late(ratios(system, x0, np.tanh(z_batch), horizon, dt), dt)
        top = late.max(1)
        return np.log(np.exp(SOFTNESS * (late - top[:, None])).sum(1)) / SOFTNESS + top

    def value_and_grad(z, h=1e-4):
        values = soft(np.vstack([z[None], z[None] + h * np.eye(knots)]))
        return values[0], (values[1:] - values[0]) / h

    rng = np.random.default_rng(seed)
    sign = np.sign(system.split(np.asarray(x0)[None])[1][0, np.flatnonzero(system.actuated_mask[system.nq:])[0]]) or 1.0
    inits = [np.zeros(knots), -2 * sign * np.ones(knots), 2 * sign * np.ones(knots)]
    inits += [rng.normal(0.0, 1.5, knots) for _ in range(max(0, restarts - 3))]
    best = None
    for z0 in inits[:restarts]:
        z = minimize(value_and_grad, z0, jac=True, method="L-BFGS-B", options={"maxiter": 60}).x
        peak = float(_late(ratios(system, x0, np.tanh(z)[None], horizon, dt / 2), dt / 2).max())
        best = peak if best is None else min(best, peak)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--starts", type=int, default=100)
    parser.add_argument("--worst", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--knots", type=int, default=25)
    parser.add_argument("--horizon", type=float, default=1.5)
    parser.add_argument("--dt", type=float, default=0.004)
    parser.add_argument("--restarts", type=int, default=8)
    args = parser.parse_args()
    for path in args.runs:
        run = ip.load_run(path)
        system = run.system
        if system.m != 1:
            print(f"{path}: {system.m} inputs; this search takes one")
            continue
        x0 = swingup_states(system, n=args.starts, seed=args.seed, starts="moving")
        traj = simulate(system, run.controller, x0, T=args.horizon, dt=0.002)
        rating = SpeedGovernor.of(system).rating
        v = system.split(traj.x.reshape(-1, system.n))[1].reshape(len(x0), -1, system.nq)
        law = (np.abs(v) / rating)[:, int(round(RELEASE_GRACE / 0.002)):, :].max(axis=(1, 2))
        print(f"{system.name} ({path}): the deployed law's peak after {RELEASE_GRACE} s above 1.5 ratings from "
              f"{int((law > 1.5).sum())} of {len(x0)} moving starts (seed {args.seed})")
        print("| start | law's peak | lowest found by the search | lowest known | seconds |")
        print("|---|---|---|---|---|")
        over = 0
        for i in np.argsort(-law)[: args.worst]:
            t0 = time.perf_counter()
            best = lowest_peak(system, x0[i], args.knots, args.horizon, args.dt, args.restarts, int(i))
            known = min(best, law[i])
            over += known > 1.5
            print(f"| {i} | {law[i]:.2f} | {best:.2f} | {known:.2f} | {time.perf_counter() - t0:.0f} |", flush=True)
        print(f"of the {min(args.worst, len(x0))} worst starts, {over} have no known history under 1.5 ratings after the grace")


if __name__ == "__main__":
    main()
