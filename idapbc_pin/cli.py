"""`idapbc-pin`: the command line. Thin: each sub-command calls one library function.

Bad input prints one line ``error: <problem>. Fix: <fix>`` and exits with status 2.
"""

from __future__ import annotations

import argparse
import sys

from .errors import IdapbcError

__all__ = ["main"]


def _key_value(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected JOINT=VALUE, got '{text}'")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{value}' in '{text}' is not a number") from None


def _key_range(text: str) -> tuple[str, tuple[float, float]]:
    name, sep, rng = text.partition("=")
    lo, sep2, hi = rng.partition(":")
    try:
        if not (sep and sep2 and name):
            raise ValueError
        return name, (float(lo), float(hi))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=LO:HI (NAME a joint or p_<joint>), got '{text}'") from None


def add_system_arguments(parser: argparse.ArgumentParser) -> None:
    """SOURCE, --actuated, --target, --domain: shared by every sub-command that loads a system."""
    parser.add_argument("source", metavar="SOURCE", help="URDF path, zoo name, built-in name (paper_*) or erd:<example-robot-data URDF stem>")
    parser.add_argument("--actuated", nargs="+", action="extend", metavar="JOINT", help="actuated joint(s); default: the zoo entry's")
    parser.add_argument("--target", type=_key_value, action="append", metavar="JOINT=VALUE", help="target joint value (rad or m), repeatable; default 0 (upright)")
    parser.add_argument("--domain", type=_key_range, action="append", metavar="NAME=LO:HI", help="training-box bounds of a coordinate (joint or p_<joint>), repeatable")


def system_kwargs(args: argparse.Namespace) -> dict:
    """load_system keyword arguments from parsed CLI arguments."""
    return {
        "actuated": args.actuated,
        "target": dict(args.target) if args.target else None,
        "domain": dict(args.domain) if args.domain else None,
    }


def _cmd_inspect(args: argparse.Namespace) -> int:
    from .inspection import format_report, inspect_system

    print(format_report(inspect_system(args.source, **system_kwargs(args))))
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from .analytic import ANALYTIC
    from .zoo import ZOO

    print("zoo (urdf/):")
    for entry in ZOO.values():
        print(f"  {entry.name:<24}{entry.urdf:<28}actuated: {', '.join(entry.actuated):<18}{entry.description}")
    print("built-in analytic systems (paper §V):")
    for spec in ANALYTIC.values():
        print(f"  {spec.name:<24}actuated: {', '.join(spec.actuated):<18}{spec.description}")
    print("example-robot-data: erd:<URDF stem>, e.g. erd:double_pendulum_continuous --actuated joint1")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="idapbc-pin", description="Neural IDA-PBC for underactuated robots, from URDF with Pinocchio.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("inspect", help="joints, dimensions, actuation, target equilibrium, controllability")
    add_system_arguments(p)
    p.set_defaults(func=_cmd_inspect)

    p = sub.add_parser("list", help="zoo robots and built-in systems")
    p.set_defaults(func=_cmd_list)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `idapbc-pin` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except IdapbcError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
