"""Goal: time the torque-plan search of `recover` one start at a time and batched over starts.

`recover` searches a plan for every start saturated LQR loses (`training.plans`). The search of
one start simulates `population` candidates per cross-entropy iteration; `search_plans` advances
several starts together, so each simulation carries S·population rows and pays the fixed per-tick
cost of `simulate` once. This prints seconds per plan both ways on the same starts and streams,
and whether the plans agree exactly.
Run: python benchmarks/bench_plans.py pendubot --effort shoulder=8 [--starts 16]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.cli._args import add_system_arguments, system_kwargs
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.metrics import success
from idapbc_pin.sim.states import uniform_states
from idapbc_pin.trajectory.plans import PLAN_STEP, PlanSettings, search_plan, search_plans


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_system_arguments(parser)
    parser.add_argument("--starts", type=int, default=16, help="lost half-box starts to plan for (default 16, recover's batch)")
    parser.add_argument("--seed", type=int, default=101, help="seed of the start states and the plans' streams (default 101)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    try:
        system = ip.load_system(args.source, **system_kwargs(args))
    except ip.IdapbcError as exc:
        parser.error(str(exc))
    if not np.all(np.isfinite(system.effort)):
        parser.error("plans need an effort limit on every actuated joint: pass --effort JOINT=LIMIT")
    lqr, bound, settings = LQRController(system), np.asarray(system.effort), PlanSettings()
    x0 = uniform_states(system, 20 * args.starts, "half", args.seed)
    lost = np.flatnonzero(~success(simulate(system, lqr, x0, T=20.0, dt=PLAN_STEP), system))[: args.starts]
    if lost.size == 0:
        parser.error("saturated LQR loses none of these starts: nothing to plan")
    streams = lambda: [np.random.default_rng((args.seed, int(i))) for i in lost]  # noqa: E731
    print(f"{system.name}: plans for {lost.size} starts saturated LQR loses (population {settings.population}, "
          f"{settings.iterations} iterations, {settings.score_T:g} s scored)", flush=True)
    start = time.perf_counter()
    one = np.concatenate([search_plan(system, lqr, x0[i], bound, settings, rng) for i, rng in zip(lost, streams())])
    t_one = time.perf_counter() - start
    print(f"  one start at a time: {t_one:.1f} s ({t_one / lost.size:.2f} s per plan)", flush=True)
    start = time.perf_counter()
    batch = search_plans(system, lqr, x0[lost], bound, settings, streams())
    t_batch = time.perf_counter() - start
    print(f"  {lost.size} starts together: {t_batch:.1f} s ({t_batch / lost.size:.2f} s per plan), {t_one / t_batch:.1f}× faster")
    print(f"  the plans agree exactly: {np.array_equal(one, batch)} (largest difference {np.abs(one - batch).max():.1e} N·m or N)")


if __name__ == "__main__":
    main()
