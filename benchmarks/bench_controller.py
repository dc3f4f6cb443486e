"""Goal: latency of `ctrl.torque(q, v)` for one state (what a robot's control loop calls).

Target (issue #3): ≤ 1 ms, i.e. a 1 kHz loop. Uses freshly initialised networks of the fast and the
paper sizes (latency does not depend on the weights' values). Prints median and 99th percentile.
Run: python benchmarks/bench_controller.py [names ...]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.control.controller import Controller, build_nets


def latency(ctrl: Controller, q: np.ndarray, v: np.ndarray, repeat: int) -> np.ndarray:
    for _ in range(20):
        ctrl.torque(q, v)
    times = np.empty(repeat)
    for k in range(repeat):
        t0 = time.perf_counter()
        ctrl.torque(q, v)
        times[k] = time.perf_counter() - t0
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=["acrobot", "cartpole", "cart_double_pendulum", "paper_cartpole"])
    parser.add_argument("--repeat", type=int, default=2000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"{'system':<24}{'preset':<8}{'median ms':>10}{'p99 ms':>10}")
    for name in args.names:
        system = ip.load_system(name)
        q, v = system.x_star[: system.nq] + 0.1, np.full(system.nq, 0.2)
        for preset, config in (("fast", TrainConfig.fast()), ("paper", TrainConfig())):
            torch.manual_seed(0)
            ctrl = Controller(system, build_nets(system, config))
            t = latency(ctrl, q, v, args.repeat)
            print(f"{name:<24}{preset:<8}{np.median(t) * 1e3:>10.3f}{np.quantile(t, 0.99) * 1e3:>10.3f}")


if __name__ == "__main__":
    main()
