"""Goal: where the default path's time goes, stage by stage, for one robot.

Runs what ``idapbc-pin train ROBOT --fast`` runs (training, the gate of the outer law, the recovery
stage where `--recover` asks for it, the evaluation on two boxes and the ROA radius) through the
Python API, and prints the wall time and share of each stage:

    training       the epochs (`training.train._run_epochs`)
    gate           the gate of the linear law outside the box (`recovery.box_gate.fallback_gate`)
    recovery: test whether saturated LQR leaves room (`recovery.trigger.limits_bind`; read from
                   the evaluation when it ran)
    recovery: plans + labels, DAgger rounds, fits + gate (`recovery.stage`)
    evaluation + radius   both boxes and both ROA radius searches, NIDA-PBC and LQR, which share
                   one pool of workers (`evaluation.evaluate._simulate`), again after a kept
                   recovery law

A stage's time is its wall time in this process, minus the stages nested in it; work a stage hands
to worker processes counts in the stage that waits for it. "other" is the rest (loading, set-up).
Run: python benchmarks/bench_default_path.py ROBOT [--effort JOINT=LIMIT] [--epochs N] [--recover auto|always|never]
     [--evaluate N] [--workers W] [--seed S]
"""

from __future__ import annotations

import argparse
import functools
import importlib
import tempfile
import time

import idapbc_pin as ip
from idapbc_pin.evaluation.evaluate import evaluate_run, format_evaluation
from idapbc_pin.recovery.config import RecoveryConfig
from idapbc_pin.recovery.trigger import auto_recover

#: (stage, module, attribute): the functions timed, as the default path calls them.
STAGES = (
    ("training", "idapbc_pin.training.train", "_run_epochs"),
    ("gate", "idapbc_pin.recovery.box_gate", "fallback_gate"),
    ("recovery: room test", "idapbc_pin.recovery.trigger", "limits_bind"),
    ("recovery: plans + labels", "idapbc_pin.recovery.stage", "collect_labels"),
    ("recovery: DAgger rounds", "idapbc_pin.recovery.stage", "dagger_round"),
    ("recovery: fits + gate", "idapbc_pin.recovery.stage", "_gate_fits"),
    ("evaluation + radius", "idapbc_pin.evaluation.evaluate", "_simulate"),
)


class Stopwatch:
    """Exclusive wall time per stage of functions patched in their modules (nested stages apart)."""

    def __init__(self):
        self.seconds: dict[str, float] = {name: 0.0 for name, _, _ in STAGES}
        self._stack: list[list] = []  # [stage, start, time spent in nested stages]

    def wrap(self, name: str, fn):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            self._stack.append([name, time.perf_counter(), 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                stage, start, nested = self._stack.pop()
                spent = time.perf_counter() - start
                self.seconds[stage] += spent - nested
                if self._stack:
                    self._stack[-1][2] += spent

        return timed

    def install(self) -> None:
        for name, module, attr in STAGES:
            mod = importlib.import_module(module)
            setattr(mod, attr, self.wrap(name, getattr(mod, attr)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("robot", help="zoo name, built-in name, erd:<stem> or URDF path (zoo actuation)")
    parser.add_argument("--epochs", type=int, default=None, help="training epochs (default: the fast preset's)")
    parser.add_argument("--recover", choices=("auto", "always", "never"), default="auto", help="as `train --recover` (default auto, as train's)")
    parser.add_argument("--evaluate", type=int, default=100, help="evaluation states per box, as `train --evaluate`")
    parser.add_argument("--workers", type=int, default=0, help="processes (0: one per core), as `train --workers`")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--effort", action="append", default=[], metavar="JOINT=LIMIT", help="an actuated joint's effort limit (N·m or N), as `train --effort`")
    args = parser.parse_args()
    effort = {k: float(v) for k, v in (e.split("=", 1) for e in args.effort)}

    watch = Stopwatch()
    watch.install()
    start = time.perf_counter()
    system = ip.load_system(args.robot, effort=effort or None)
    config = ip.TrainConfig.fast(seed=args.seed, **({} if args.epochs is None else {"epochs": args.epochs}))
    first = None
    with tempfile.TemporaryDirectory() as out:
        run = ip.train(system, config, out=out, workers=args.workers)
        lqr, evaluation = None, None
        if args.evaluate > 0:  # train's order: the law against LQR first (its radii later where the stage may run), then the stage
            evaluation = evaluate_run(run, n=args.evaluate, workers=args.workers, radius=args.recover == "never")
            print(format_evaluation(evaluation), flush=True)
            lqr = {box: evaluation.results[box]["LQR"].success_rate for box in ("half", "domain")}
        first = time.perf_counter() - start
        if args.recover != "never":
            auto_recover(run, args.recover, RecoveryConfig(workers=args.workers), lqr_success=lqr)
            run = ip.load_run(run.path)
            if evaluation is not None and run.uses_recovery:
                print("with the recovery law:\n" + format_evaluation(evaluate_run(run, n=args.evaluate, workers=args.workers)), flush=True)
            elif evaluation is not None:
                print(evaluate_run(run, n=args.evaluate, workers=args.workers, reuse=evaluation).radius.line(), flush=True)
    total = time.perf_counter() - start
    other = total - sum(watch.seconds.values())
    print(f"\ndefault path of {args.robot} (fast preset, {config.epochs} epochs, --recover {args.recover}): {total:.1f} s wall, "
          f"the first result (the law against LQR) after {first:.1f} s")
    print(f"{'stage':<28}{'s':>9}{'share':>9}")
    for name, seconds in [*watch.seconds.items(), ("other", other)]:
        print(f"{name:<28}{seconds:>9.1f}{100 * seconds / total:>8.1f}%")


if __name__ == "__main__":
    main()
