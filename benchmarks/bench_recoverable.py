"""Goal: tell a weak actuator from a weak law: which states can the limited robot bring to x* at all?

Saturated LQR (Q = I, R = I) runs from uniform states of a box. For every state it loses, a
cross-entropy search looks for a torque plan within the effort limits: piecewise-constant over
`--knots` intervals of the first `--horizon` seconds, then saturated LQR takes over. A plan is scored
by the distance to x* after `--score-T` seconds (angles wrapped, plus 0.3 × speeds; a diverged
rollout scores 1e3); the best plan is then judged by the usual test (T = 20 s, within 0.05 of x*
over the last 2 s), with the law held every 2 ms. A recovered state proves the actuator can do it;
a state not recovered proves nothing (the search may have missed a plan). Plans are open loop and
per state: a bound on what a torque-aware law could reach, not a controller.
Run: python benchmarks/bench_recoverable.py pendubot --effort shoulder=8 [--n 100] [--box half]
     [--seed 7] [--mujoco 4]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.cli._args import key_value
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.metrics import success
from idapbc_pin.sim.states import uniform_states
from idapbc_pin.trajectory.plans import PLAN_STEP as DT
from idapbc_pin.trajectory.plans import PlanSettings, PlanThenLaw, search_plan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", help="zoo name or URDF path")
    parser.add_argument("--effort", type=key_value, action="append", default=[], metavar="JOINT=LIMIT", help="effort limit override, repeatable")
    parser.add_argument("--n", type=int, default=100, help="start states (default 100)")
    parser.add_argument("--box", default="half", choices=["half", "domain"], help="box of the start states (default half)")
    parser.add_argument("--seed", type=int, default=7, help="seed of the start states (default 7)")
    parser.add_argument("--horizon", type=float, default=2.0, help="length of the plan, s (default 2)")
    parser.add_argument("--knots", type=int, default=20, help="pieces of the plan (default 20)")
    parser.add_argument("--population", type=int, default=48, help="plans per iteration (default 48)")
    parser.add_argument("--iterations", type=int, default=8, help="cross-entropy iterations (default 8)")
    parser.add_argument("--score-T", type=float, default=6.0, help="horizon of a plan's score, s (default 6)")
    parser.add_argument("--mujoco", type=int, default=0, help="also judge the first K recovered plans with MuJoCo's dynamics")
    args = parser.parse_args()
    torch.set_num_threads(1)
    try:
        system = ip.load_system(args.source, effort=dict(args.effort) or None)
    except ip.IdapbcError as exc:
        parser.error(str(exc))
    bound = np.where(np.isfinite(system.effort), system.effort, 1e3)  # the plans' search range, N·m or N
    lqr = LQRController(system)
    x0 = uniform_states(system, args.n, args.box, args.seed)
    lost = np.flatnonzero(~success(simulate(system, lqr, x0, T=20.0, dt=DT), system))
    limits = ", ".join(f"{j}={e:g}" for j, e in zip(system.actuated, system.effort))
    print(f"{system.name}, effort {limits}: saturated LQR brings {args.n - lost.size} of {args.n} {args.box}-box states (seed {args.seed}) to x*", flush=True)
    settings = PlanSettings(horizon=args.horizon, knots=args.knots, population=args.population, iterations=args.iterations, score_T=args.score_T)
    rng, recovered, checked, start = np.random.default_rng(0), 0, 0, time.perf_counter()
    judge = ip.mujoco_judge(system) if args.mujoco else None
    for j, i in enumerate(lost):
        plan = search_plan(system, lqr, x0[i], bound, settings, rng)
        ok = bool(success(simulate(system, PlanThenLaw(plan, args.horizon, lqr), x0[i : i + 1], T=20.0, dt=DT), system)[0])
        recovered += ok
        note = ""
        if ok and checked < args.mujoco:
            traj = simulate(judge, PlanThenLaw(plan, args.horizon, lqr), x0[i : i + 1], T=20.0, dt=DT)
            checked += 1
            note = f"; MuJoCo's dynamics: {'reaches x*' if success(traj, judge)[0] else 'FAILS'}, peak |u| {np.abs(traj.u).max():.2f}"
        elapsed = time.perf_counter() - start
        print(f"  state {j + 1}/{lost.size}: {'recovered' if ok else 'not recovered'}{note}  [{elapsed:.0f} s, ETA {elapsed / (j + 1) * (lost.size - j - 1):.0f} s]", flush=True)
    print(f"recovered {recovered} of the {lost.size} states LQR loses: at least {args.n - lost.size + recovered} of {args.n} states are reachable with these limits")


if __name__ == "__main__":
    main()
