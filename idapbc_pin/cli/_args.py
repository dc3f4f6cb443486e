"""Argument types and groups shared by several sub-commands (argparse lives only in `cli/`)."""

from __future__ import annotations

import argparse

from ..errors import IdapbcError

__all__ = ["add_effort_argument", "add_system_arguments", "add_workers_argument", "key_range", "key_value", "positive_int", "system_kwargs",
           "workers_of"]


def key_value(text: str) -> tuple[str, float]:
    """'JOINT=VALUE' -> (JOINT, float(VALUE))."""
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected JOINT=VALUE, got '{text}'")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{value}' in '{text}' is not a number") from None


def key_range(text: str) -> tuple[str, tuple[float, float]]:
    """'NAME=LO:HI' -> (NAME, (LO, HI))."""
    name, sep, rng = text.partition("=")
    lo, sep2, hi = rng.partition(":")
    try:
        if not (sep and sep2 and name):
            raise ValueError
        return name, (float(lo), float(hi))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=LO:HI (NAME a joint or p_<joint>), got '{text}'") from None


def positive_int(text: str) -> int:
    """An integer ≥ 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be ≥ 1, got {value}")
    return value


def add_workers_argument(parser: argparse.ArgumentParser) -> None:
    """--workers W: processes for a sub-command's closed-loop simulations (0, the default: one per core)."""
    parser.add_argument("--workers", type=int, default=0, metavar="W",
                        help="processes for the simulations (the two controllers side by side, and train's gate); default 0: "
                             "one per core, at most 16; 1: this process. The count changes the time, never a result")


def workers_of(args: argparse.Namespace) -> int:
    """``args.workers`` (0: one per core, resolved where the processes start); a negative count is
    refused in one line."""
    if args.workers < 0:
        raise IdapbcError(f"--workers must be ≥ 0, got {args.workers}. Fix: 0 (one process per core) or a count such as 2.")
    return args.workers


def add_system_arguments(parser: argparse.ArgumentParser) -> None:
    """SOURCE, --actuated, --target, --domain: shared by every sub-command that loads a system."""
    parser.add_argument("source", metavar="SOURCE", help="URDF path, zoo name, built-in name (paper_*) or erd:<example-robot-data URDF stem>")
    parser.add_argument("--actuated", nargs="+", action="extend", metavar="JOINT", help="actuated joint(s); default: the zoo entry's")
    parser.add_argument("--target", type=key_value, action="append", metavar="JOINT=VALUE", help="target joint value (rad or m), repeatable; default 0 (upright)")
    parser.add_argument("--domain", type=key_range, action="append", metavar="NAME=LO:HI", help="training-box bounds of a coordinate (joint or p_<joint>), repeatable")
    add_effort_argument(parser)


def add_effort_argument(parser: argparse.ArgumentParser) -> None:
    """--effort JOINT=VALUE: override the URDF's actuator limit of an actuated joint."""
    parser.add_argument(
        "--effort", type=key_value, action="append", metavar="JOINT=VALUE",
        help="actuator limit |u| ≤ VALUE (N·m or N) of an actuated joint, overriding the URDF's <limit effort> (inf: none), repeatable",
    )


def system_kwargs(args: argparse.Namespace) -> dict:
    """load_system keyword arguments from parsed CLI arguments."""
    return {
        "actuated": args.actuated,
        "target": dict(args.target) if args.target else None,
        "domain": dict(args.domain) if args.domain else None,
        "effort": dict(args.effort) if getattr(args, "effort", None) else None,
    }
