"""Goal: the robustness suite (DESIGN §4, "Robust swing-up") for the zoo and the RealAIGym robots.

For each robot, `judge_suite` judges saturated LQR (Q = I, R = I) and the energy-pumping law with an
LQR catch from exactly hanging under the six tests of the RealAIGym robustness leaderboard v2 (plant
parameters varied one at a time, speed noise, torque noise, actuator lag, delay, pushes; 10 s at
500 Hz, effort limits on) and prints each law's six scores and their mean. With ``--train``, each
robot is first trained as a user would (``idapbc-pin train ROBOT --fast --swing-up``) and its state
feedback and manoeuvre are judged beside them; ``--run RUN`` adds run directories (from hanging for
a swing-up run, else from half-box states). The RealAIGym rows quote the leaderboard's published
figures, measured by the leaderboard's simulator, where pushes reach the actuated joints only
(``--push-joints actuated`` judges the same way). ``--judge mujoco`` integrates the same varied
plants in MuJoCo. ``--roa`` prints the older table instead (success
from the half box under mass ×0.8/×1.2, saturation and measurement noise) for the runs given.
Run: python benchmarks/bench_robustness.py [--only [NAME ...]] [--run RUN ...] [--train] [--levels 21] [--repetitions 10]
         [--pushes 50] [--push-joints all|actuated] [--judge pinocchio|mujoco] [--workers 0] [--roa]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import torch

import idapbc_pin as ip
from bench_swingup import ROBOTS, load, trained_run
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.control.energy_pump import EnergyPumpLaw
from idapbc_pin.evaluation.robust_suite import PUSH_JOINTS, SUITE_JUDGES, SuiteConfig, evaluate_run_suite, judge_suite
from idapbc_pin.evaluation.robustness import default_conditions, robustness_table

#: The robustness leaderboard v2's published scores (overall; model / speed noise / torque noise / lag / delay / pushes for TVLQR).
PUBLISHED = {
    "realaigym_pendubot": "AR-EAPO 0.913, evolsac 0.786, History SAC 0.770, TVLQR 0.767 (0.629 / 0.905 / 1.0 / 1.0 / 0.429 / 0.64)",
    "realaigym_acrobot": "History SAC 0.751, AR-EAPO 0.727, evolsac 0.687, TVLQR 0.607 (0.481 / 0.190 / 1.0 / 0.952 / 0.238 / 0.78)",
}
SOURCE = "github dfki-ric-underactuated-lab/double_pendulum, leaderboard robustness_v2"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", default=None, help=f"robots (default all: {', '.join(ROBOTS)}; `--only` alone: none, for --run)")
    parser.add_argument("--run", nargs="+", default=[], help="run directories judged on their own systems")
    parser.add_argument("--train", action="store_true", help="train each robot with `idapbc-pin train --fast --swing-up` and judge its run too")
    parser.add_argument("--train-seed", type=int, default=0)
    parser.add_argument("--levels", type=int, default=SuiteConfig.levels)
    parser.add_argument("--repetitions", type=int, default=SuiteConfig.repetitions)
    parser.add_argument("--pushes", type=int, default=SuiteConfig.pushes)
    parser.add_argument("--push-joints", choices=PUSH_JOINTS, default=SuiteConfig.push_joints,
                        help="joints the pushes reach (actuated: as the leaderboard's own simulator, whose published push scores drop the others')")
    parser.add_argument("--judge", choices=SUITE_JUDGES, default="pinocchio", help="the engine of the true plants (mujoco: an independent check)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=0, help="worker processes, one law each (0: one per core)")
    parser.add_argument("--roa", action="store_true", help="the older table (success from the half box under mismatch) for the runs given")
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = SuiteConfig(levels=args.levels, repetitions=args.repetitions, pushes=args.pushes, push_joints=args.push_joints)
    print(f"cpus={os.cpu_count()} load={os.getloadavg()[0]:.2f} {config}")
    if args.roa:
        for path in args.run:
            print("\n" + robustness_table(path, conditions=default_conditions(), workers=args.workers).table())
        return
    for name in args.only if args.only is not None else ROBOTS:
        t0 = time.perf_counter()
        if args.train:
            with tempfile.TemporaryDirectory() as out:
                run, wall, gate = trained_run(name, out, args.train_seed)
                print(f"\n{name}: `idapbc-pin train --fast --swing-up` took {wall:.0f} s; {gate}")
                result = evaluate_run_suite(run, config, seed=args.seed, workers=args.workers, judge=args.judge)
        else:
            system = load(name)
            laws = {"LQR": LQRController(system), "energy pump + LQR": EnergyPumpLaw(system)}
            result = judge_suite(system, laws, config, "hanging", args.seed, args.workers, judge=args.judge)
        print(f"\n### {name}, from {result.start}, judged by {result.judge} ({result.rows.N} rollouts per law, {time.perf_counter() - t0:.0f} s)\n")
        print(result.table())
        if name in PUBLISHED:
            print(f'\n> published: {PUBLISHED[name]} — "{SOURCE}"')
    for path in args.run:
        t0 = time.perf_counter()
        result = evaluate_run_suite(ip.load_run(path), config, seed=args.seed, workers=args.workers, judge=args.judge)
        print(f"\n### run {path} ({result.system}), from {result.start}, judged by {result.judge} ({result.rows.N} rollouts per law, {time.perf_counter() - t0:.0f} s)\n")
        print(result.table())


if __name__ == "__main__":
    main()
