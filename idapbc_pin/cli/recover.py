"""`recover`: fit a recovery law beside a run's IDA-PBC law (weak actuators), kept only where it helps."""

from __future__ import annotations

import argparse

from ..training.recovery import RecoveryConfig, recover

__all__ = ["add_recover_command"]


def _cmd_recover(args: argparse.Namespace) -> int:
    config = RecoveryConfig(**{k: getattr(args, k) for k in ("starts", "dagger", "workers") if getattr(args, k) is not None})
    entry = recover(args.run, config)
    kept = "kept: `simulate`, `view` and `export` of RUN now use it" if entry["used"] else "not kept: RUN is unchanged"
    print(f"recovery law {kept} ({entry['seconds']:.0f} s; summary.json → recovery)")
    return 0


def add_recover_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin recover RUN`` on an argparse sub-parsers object."""
    d = RecoveryConfig()
    p = subparsers.add_parser(
        "recover",
        help="weak actuators: fit a recovery law to torque plans within the limits, beside the IDA-PBC law",
        description=(
            "Search torque plans within RUN's effort limits from half-box states LQR loses, fit a small feedback law to "
            "them (then DAgger rounds), and use it outside an inner box around x* if simulation on states of its own "
            "shows it brings more states to x*. Writes RUN/recovery.npz and summary.json → recovery. Took 20-50 "
            "minutes on 2 cores for a 2-DoF robot."
        ),
    )
    p.add_argument("run", metavar="RUN", help="run directory written by `idapbc-pin train` (effort limits on every actuated joint)")
    p.add_argument("--starts", type=int, metavar="N", help=f"half-box start states labelled by LQR or plans (default {d.starts})")
    p.add_argument("--dagger", type=int, metavar="K", help=f"DAgger rounds after the first fit (default {d.dagger})")
    p.add_argument("--workers", type=int, metavar="W", help=f"processes searching plans (default {d.workers})")
    p.set_defaults(func=_cmd_recover)
    return p
