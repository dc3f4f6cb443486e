"""Goal: time the plant data one training epoch needs (f, ∂f/∂x, g⊥) for 512 states.

Target (issue #2): ≤ 20 ms for a 2-DoF robot on 2 cores. Prints the median of repeated runs.
Run: python benchmarks/bench_plant.py [--states 512] [--repeat 20] [names ...]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import idapbc_pin as ip


def time_plant_data(system, n_states: int, repeat: int) -> tuple[float, float]:
    """Median seconds of (f + ∂f/∂x + g⊥) and of f alone, over `repeat` runs."""
    lo, hi = system.domain
    x = lo + (hi - lo) * np.random.default_rng(0).random((n_states, system.n))
    full, f_only = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        system.f_and_df_dx(x)
        system.g_perp(x)
        full.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        system.f(x)
        f_only.append(time.perf_counter() - t0)
    return statistics.median(full), statistics.median(f_only)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=["acrobot", "cartpole", "furuta", "reaction_wheel", "cart_double_pendulum", "paper_cartpole"])
    parser.add_argument("--states", type=int, default=512)
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    print(f"{'system':<24}{'DoF':>4}{'f+df/dx+g_perp ms':>20}{'f only ms':>12}")
    for name in args.names:
        system = ip.load_system(name)
        full, f_only = time_plant_data(system, args.states, args.repeat)
        print(f"{name:<24}{system.nq:>4}{full * 1e3:>20.2f}{f_only * 1e3:>12.2f}")


if __name__ == "__main__":
    main()
