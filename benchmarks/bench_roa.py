"""Goal: time a 1000-state, 20 s ROA evaluation (DESIGN §4, "Speed"), LQR and trained NIDA-PBC.

Target (DESIGN): ≤ 60 s for a 2-DoF robot on 2 cores. Prints the ROA table of each system (LQR only)
or of each trained run (NIDA-PBC and LQR on the same states) and the wall time per controller and
in total, with the integrator settings used. The actuators' effort limits apply unless --no-limits.
With --radius it also times the ROA radius search (`roa_radius`, --radius-states per scale, the
ROA above reused at s = 1 when --box domain and the state counts agree) and prints every probe.
Run: python benchmarks/bench_roa.py [--states 1000] [--T 20] [--dt S] [--box domain|half]
                                    [--threads N] [--no-limits] [--radius] [--radius-states 200]
                                    [names ...] [--run RUN_DIR ...]
"""

from __future__ import annotations

import argparse
import os
import time

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.sim.judge import DEFAULT_THREADS
from idapbc_pin.evaluation.radius import roa_radius
from idapbc_pin.evaluation.roa import roa


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="systems for an LQR-only timing (default acrobot paper_cartpole without --run)")
    parser.add_argument("--states", type=int, default=1000)
    parser.add_argument("--T", type=float, default=20.0)
    parser.add_argument("--dt", type=float, default=None, help="RK4 step and control period, s (default: the judge's, 2 ms unless the loop is stiffer)")
    parser.add_argument("--box", default="domain", choices=["domain", "half"])
    parser.add_argument("--run", action="append", default=[], help="a trained run directory: time NIDA-PBC and LQR")
    parser.add_argument("--threads", type=int, default=None, help=f"Pinocchio threads (default {DEFAULT_THREADS})")
    parser.add_argument("--no-limits", action="store_true", help="lift the effort limits")
    parser.add_argument("--radius", action="store_true", help="also time the ROA radius search")
    parser.add_argument("--radius-states", type=int, default=200, help="states per scale of the radius search (default 200)")
    args = parser.parse_args()
    limits = not args.no_limits
    print(f"cpus={os.cpu_count()} load={os.getloadavg()[0]:.2f} threads={args.threads or DEFAULT_THREADS} "
          f"states={args.states} T={args.T:g}s dt={args.dt or 'judge'}{'s' if args.dt else ''} rk4")
    names = args.names or ([] if args.run else ["acrobot", "paper_cartpole"])
    jobs = [(ip.load_system(name), {"lqr": None}) for name in names]
    for path in args.run:
        run = ip.load_run(path)
        jobs.append((run.system, {"NIDA-PBC": run.controller, "lqr": None}))
    for system, controllers in jobs:
        controllers = {k: c if c is not None else LQRController(system) for k, c in controllers.items()}
        t0 = time.perf_counter()
        result = roa(system, controllers, n=args.states, box=args.box, T=args.T, dt=args.dt, threads=args.threads, limits=limits)
        total = time.perf_counter() - t0
        print(result.table())
        each = ", ".join(f"{k} {result[k].wall_time:.1f} s" for k in controllers)
        print(f"{system.name}: {args.states} states x {args.T:g} s: {each}; {total:.1f} s in total with set-up and metrics\n")
        if args.radius:
            known = {1.0: result} if args.box == "domain" else {0.5: result}
            found = roa_radius(system, controllers, n=args.radius_states, T=args.T, dt=args.dt, known=known, limits=limits, threads=args.threads)
            print(found.line())
            for name, probes in found.probes.items():
                steps = ", ".join(f"s={s:.3f}: {k}/{m}" for s, (k, m) in sorted(probes.items()))
                print(f"  {name}: {steps}")
            print(f"{system.name}: radius search {found.wall_time:.1f} s\n")


if __name__ == "__main__":
    main()
