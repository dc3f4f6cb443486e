"""Goal: the cost of one `rollout` epoch (training on simulations of the saturated loop), per robot.

Builds fast-preset networks, then times `rollout_cost` and its backward pass with the default
rollout settings (64 rollouts, 3 s, Euler steps of 0.01 s), and the share of that time spent in the
plant (f in the forward pass, ∂f/∂x in the backward pass).
Run: python benchmarks/bench_rollout.py [--repeat 3] [names ...]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.control.nets import build_nets
from idapbc_pin.training.rollout import rollout_cost, rollout_starts


class _Timed:
    """A System proxy that adds up the seconds spent in f and df_dx."""

    def __init__(self, system):
        self._system, self.seconds = system, 0.0

    def __getattr__(self, name):
        attr = getattr(self._system, name)
        if name not in ("f", "df_dx"):
            return attr

        def timed(*args):
            t0 = time.perf_counter()
            try:
                return attr(*args)
            finally:
                self.seconds += time.perf_counter() - t0

        return timed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=["pendubot", "acrobot", "cartpole", "cart_double_pendulum"])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = TrainConfig.fast()
    print(f"{'system':<24}{'n':>3}{'s/epoch':>10}{'plant share':>13}")
    for name in args.names:
        system = ip.load_system(name)
        torch.manual_seed(0)
        nets = build_nets(system, config)
        timed = _Timed(system)
        effort = torch.as_tensor(np.array(system.effort), dtype=torch.float32)
        gen = torch.Generator().manual_seed(0)
        t0 = time.perf_counter()
        for _ in range(args.repeat):
            x0 = torch.as_tensor(rollout_starts(system, config.rollout_samples, config.rollout_box, gen), dtype=torch.float32)
            cost = rollout_cost(nets, timed, x0, config.rollout_horizon, config.rollout_step, config.rollout_tail, effort)
            cost.backward()
        per_epoch = (time.perf_counter() - t0) / args.repeat
        print(f"{name:<24}{system.n:>3}{per_epoch:>10.2f}{100 * timed.seconds / args.repeat / per_epoch:>12.0f}%", flush=True)


if __name__ == "__main__":
    main()
