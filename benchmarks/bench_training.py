"""Goal: training time per paper benchmark, paper setting vs the `--fast` preset.

Trains each system with both configurations and prints the time per epoch, the time of a full
training (2000 epochs paper, 1200 fast) and the speed-up. The fast preset is timed as a complete
training, start-up and first epochs included ("fast full s" is measured, not extrapolated); the
paper setting is timed over `--epochs` epochs (default 40) and extrapolated to its 2000, unless
--full times it completely too. Trainings are timed without the `fallback` gate
(`fallback="none"`); the gate, which simulates 100 states for 20 s under two or three laws after
every training, is timed apart on the fast preset's networks ("gate s", in `--workers` processes as
`idapbc-pin train` runs it: one per core by default) and added to both full-training figures.
Issue #3 target: the fast preset trains ≥ 5× faster; issue #13: a 2-DoF robot in ≤ 90 s, gate
included. --device cuda trains on a GPU (the gate always simulates on the CPU's plant).
Run: python benchmarks/bench_training.py [--epochs 40] [--full] [--device cpu|cuda] [--workers W] [names ...]
"""

from __future__ import annotations

import argparse
import tempfile
import time

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.recovery.box_law import box_fallback
from idapbc_pin.recovery.box_gate import fallback_gate
from idapbc_pin.training.train import train


def seconds_per_epoch(system, config: TrainConfig, out: str) -> tuple[float, ip.Run]:
    """Wall time of `train` (start-up included) over its epochs, and the run."""
    t0 = time.perf_counter()
    run = train(system, config.replace(fallback="none"), out=out, progress=False)
    return (time.perf_counter() - t0) / config.epochs, run


def gate_seconds(run: ip.Run, workers: int) -> float:
    """Wall time of the `fallback` gate on a run's networks, in `workers` processes (0: one per core)."""
    t0 = time.perf_counter()
    fallback_gate(run.system, run.controller, box_fallback(run.system, run.config), run.config.seed, workers)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=["paper_double_pendulum", "paper_cartpole", "paper_mass_spring_damper"])
    parser.add_argument("--epochs", type=int, default=40, help="epochs the paper setting is timed over (extrapolated to 2000)")
    parser.add_argument("--full", action="store_true", help="time the paper setting's complete training too (slow)")
    parser.add_argument("--device", default="cpu", help="where the networks train: cpu, cuda or cuda:N")
    parser.add_argument("--workers", type=int, default=0, help="processes for the gate's simulations (0: one per core, as `train`)")
    args = parser.parse_args()
    paper, fast = TrainConfig(device=args.device), TrainConfig.fast(device=args.device)
    print(f"device: {args.device}")
    print(f"{'system':<26}{'paper s/ep':>11}{'fast s/ep':>11}{'gate s':>8}{'paper full s':>14}{'fast full s':>13}{'speed-up':>10}")
    with tempfile.TemporaryDirectory() as out:
        for name in args.names:
            system = ip.load_system(name)
            p, _ = seconds_per_epoch(system, paper if args.full else paper.replace(epochs=args.epochs), out)
            f, run = seconds_per_epoch(system, fast, out)
            gate = gate_seconds(run, args.workers)
            tp, tf = p * paper.epochs + gate, f * fast.epochs + gate
            print(f"{name:<26}{p:>11.3f}{f:>11.3f}{gate:>8.1f}{tp:>14.0f}{tf:>13.0f}{tp / tf:>9.1f}x")


if __name__ == "__main__":
    main()
