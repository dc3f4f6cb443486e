"""Goal: time a 1000-state, 20 s ROA evaluation of the LQR baseline (DESIGN §4, "Speed").

Target (DESIGN): ≤ 60 s for a 2-DoF robot on 2 cores. Prints the ROA table of each system and the
wall time of the simulation, with the integrator settings used.
Run: python benchmarks/bench_roa.py [--states 1000] [--T 20] [--dt 0.01] [--threads N] [names ...]
"""

from __future__ import annotations

import argparse
import os
import time

import idapbc_pin as ip
from idapbc_pin.simulate import DEFAULT_THREADS, LQRController, roa


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=["acrobot", "paper_cartpole"])
    parser.add_argument("--states", type=int, default=1000)
    parser.add_argument("--T", type=float, default=20.0)
    parser.add_argument("--dt", type=float, default=0.01)
    parser.add_argument("--box", default="domain", choices=["domain", "half"])
    parser.add_argument("--threads", type=int, default=None, help=f"Pinocchio threads (default {DEFAULT_THREADS})")
    args = parser.parse_args()
    print(f"cpus={os.cpu_count()} load={os.getloadavg()[0]:.2f} threads={args.threads or DEFAULT_THREADS} "
          f"states={args.states} T={args.T:g}s dt={args.dt:g}s rk4")
    for name in args.names:
        system = ip.load_system(name)
        t0 = time.perf_counter()
        result = roa(system, {"lqr": LQRController(system)}, n=args.states, box=args.box, T=args.T, dt=args.dt, threads=args.threads)
        total = time.perf_counter() - t0
        print(result.table())
        print(f"{name}: {args.states} states x {args.T:g} s in {result['lqr'].wall_time:.1f} s of simulation ({total:.1f} s with LQR set-up and metrics)\n")


if __name__ == "__main__":
    main()
