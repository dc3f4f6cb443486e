"""`recover`: fit a recovery law beside a run's IDA-PBC law (weak actuators), kept only where it helps."""

from __future__ import annotations

import argparse

from ..training.recovery import FORMS, START_BOXES, TEACHERS, RecoveryConfig, recover, refit, regate

__all__ = ["add_recover_command"]


def _cmd_recover(args: argparse.Namespace) -> int:
    keys = ("starts", "start_box", "teacher", "dagger", "workers", "margin", "half_loss", "confirm_states", "fit_seed", "fits", "width", "steps", "form")
    config = RecoveryConfig(**{k: getattr(args, k) for k in keys if getattr(args, k) is not None})
    if args.regate:
        entry = regate(args.run, config, keep=args.keep)
        seconds = entry["regated"]["seconds"]
    elif args.refit:
        entry = refit(args.run, config, keep=args.keep)
        seconds = entry["refit"]["seconds"]
    else:
        entry = recover(args.run, config, keep=args.keep)
        seconds = entry["seconds"]
    kept = ("kept: `simulate`, `view` and `export` of RUN now use it" if entry["used"]
            else "not kept: RUN runs its own law; the fitted one waits in recovery-refused.npz (--regate judges it again, --keep keeps it)")
    print(f"recovery law {kept} ({seconds:.0f} s; summary.json → recovery)")
    return 0


def add_recover_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin recover RUN`` on an argparse sub-parsers object."""
    d = RecoveryConfig()
    p = subparsers.add_parser(
        "recover",
        help="weak actuators: fit a recovery law to torque plans within the limits, beside the IDA-PBC law",
        description=(
            "Search torque plans within RUN's effort limits (where a joint has none, within LQR's largest demand on the training box) from states RUN's own law loses (half box, or --start-box domain; --teacher lqr: "
            "states saturated LQR loses), fit a small feedback law to "
            "them (then DAgger rounds), and use it outside an inner box around x* (or, where no box helps, only where "
            "H_d is above a level) if simulation on states of its own shows it brings more states to x*. Writes RUN/recovery.npz (kept) or RUN/recovery-refused.npz (not kept; "
            "--regate judges it again) and summary.json → recovery. Took 15-50 minutes on 2 cores for a 2-DoF robot."
        ),
    )
    p.add_argument("run", metavar="RUN", help="run directory written by `idapbc-pin train` (an actuated joint without an effort limit plans within LQR's largest demand on the training box)")
    p.add_argument("--starts", type=int, metavar="N", help=f"start states labelled by the teacher or plans (default {d.starts})")
    p.add_argument("--start-box", choices=START_BOXES, dest="start_box",
                   help=f"box of the start states and DAgger starts: the half box, or the training box (default {d.start_box})")
    p.add_argument("--teacher", choices=TEACHERS,
                   help=f"law that labels the starts it brings to x* and catches every plan: saturated LQR, or the run's own law (default {d.teacher})")
    p.add_argument("--dagger", type=int, metavar="K", help=f"DAgger rounds after the first fit (default {d.dagger})")
    p.add_argument("--workers", type=int, metavar="W", help="processes searching plans, fitting and running the gate's simulations (default: one per core, at most 16; "
                        "the count changes the time, not the result)")
    p.add_argument("--margin", type=int, metavar="M", help=f"gate states the law must add to the run's law to be kept (default {d.margin})")
    p.add_argument("--half-loss", type=int, metavar="L", dest="half_loss",
                   help=f"half-box and near-box gate states the law may lose against the run's law (default {d.half_loss}; "
                        "none in the half box where the run's law brings all of it)")
    p.add_argument("--confirm-states", type=int, metavar="N", dest="confirm_states",
                   help=f"where the run's law brings the whole half box of the gate to x*, other half-box states on which a kept law is checked "
                        f"again, losing at most L of them (default {d.confirm_states}; 0: no check)")
    p.add_argument("--fit-seed", type=int, metavar="S", dest="fit_seed", help=f"seed of each fit (default {d.fit_seed})")
    p.add_argument("--fits", type=int, metavar="K", help=f"laws fitted to the final labels (seeds S, S+1, …); the gate keeps the best (default {d.fits})")
    p.add_argument("--form", choices=FORMS,
                   help=f"the fitted law's output: the input itself (direct) or a correction added to the IDA-PBC law's input (residual) (default {d.form})")
    p.add_argument("--width", type=int, metavar="W", help=f"width of the law's two tanh layers (default {d.width})")
    p.add_argument("--steps", type=int, metavar="N", help=f"Adam steps of each fit (default {d.steps})")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--regate", action="store_true",
                       help="judge the law the last recover fitted again (kept or refused), with the gate's settings above; no plans, no fit: minutes")
    again.add_argument("--refit", action="store_true",
                       help="fit a law again to the labels the last recover saved (recovery-labels.npz; --fit-seed, --width, --steps) and gate it; no plans: minutes")
    p.add_argument("--keep", action="store_true", help="keep the law at the gate's best inner box whatever its verdict (summary.json says forced)")
    p.set_defaults(func=_cmd_recover)
    return p
