"""`recover`: fit a recovery law beside a run's IDA-PBC law (weak actuators), kept only where it helps."""

from __future__ import annotations

import argparse

from ..recovery.again import refit, regate
from ..recovery.stage import RecoveryConfig, recover
from ._args import add_command, add_ray_argument, add_run_argument, add_workers_argument, config_keys, ray_of, workers_of

__all__ = ["add_recover_command"]


def _config(args: argparse.Namespace) -> RecoveryConfig:
    """The --config file's settings (or the defaults), with --workers and --ray when given."""
    config = RecoveryConfig.from_file(args.config) if args.config else RecoveryConfig()
    config = config if args.workers is None else config.replace(workers=workers_of(args))
    return config if args.ray is None else config.replace(ray=ray_of(args))


def _cmd_recover(args: argparse.Namespace) -> int:
    """Search torque plans within RUN's effort limits (where a joint has none, within LQR's largest
    demand on the training box) from states RUN's own law loses (the half box, or the training
    box with start_box = "domain"; with teacher = "lqr": states saturated LQR loses), fit a
    small feedback law to them (then DAgger rounds), and use it outside an inner box around x*
    (or, where no box helps, only where H_d is above a level) if simulation on states of its own
    shows it brings more states to x*. Writes RUN/recovery.npz (kept) or
    RUN/recovery-refused.npz (not kept; --regate judges it again) and summary.json → recovery.
    `train` runs it by default where saturated LQR leaves room; a killed stage continues from its
    finished chunks of plans (`train --resume RUN`, or this command again)."""
    config = _config(args)
    if args.regate:
        entry = regate(args.run, config, keep=args.keep)
        seconds = entry["regated"]["seconds"]
    elif args.refit:
        entry = refit(args.run, config, keep=args.keep)
        seconds = entry["refit"]["seconds"]
    else:
        entry = recover(args.run, config, keep=args.keep)
        seconds = entry["seconds"]
    if entry.get("refused"):
        print(f"recovery stage refused: {entry['reason']}; RUN runs its own law ({seconds:.0f} s; summary.json → recovery)")
        return 0
    kept = ("kept: `simulate`, `view` and `export` of RUN now use it" if entry["used"]
            else "not kept: RUN runs its own law; the fitted one waits in recovery-refused.npz (--regate judges it again, --keep keeps it)")
    print(f"recovery law {kept} ({seconds:.0f} s; summary.json → recovery)")
    return 0


def add_recover_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin recover RUN`` on an argparse sub-parsers object."""
    p = add_command(subparsers, "recover", _cmd_recover, help="weak actuators: fit a recovery law to torque plans within the limits, beside the IDA-PBC law", epilog=f"--config FILE keys (RecoveryConfig fields, described in its docstring, idapbc_pin/recovery/config.py; the defaults): "
               f"{config_keys(RecoveryConfig(), 'recovery')}.")
    add_run_argument(p, "run directory written by `idapbc-pin train` (an actuated joint without an effort limit plans within LQR's largest demand on the training box)")
    p.add_argument("--config", metavar="FILE",
                   help="TOML file with a [recovery] table (or top-level keys; a [recovery.plan] table for the plans' search) or JSON: "
                        "any RecoveryConfig field (starts, teacher, margin, fits, width, steps, form, …; listed below)")
    add_workers_argument(p, "searching plans, fitting and running the gate's simulations (overrides the file's workers)")
    add_ray_argument(p, "the plans, fits and gate simulations")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--regate", action="store_true",
                       help="judge the law the last recover fitted again (kept or refused), with the gate's settings of the config; no plans, no fit: minutes")
    again.add_argument("--refit", action="store_true",
                       help="fit a law again to the labels the last recover saved (recovery-labels.npz; the config's fit_seed, fits, width, steps, form) "
                            "and gate it; no plans: minutes")
    p.add_argument("--keep", action="store_true", help="keep the law at the gate's best inner box whatever its verdict (summary.json says forced)")
    return p
