"""Argument types and the arguments several sub-commands share, each declared once here (argparse
lives only in `cli/`). A default that a library function has is read from its signature
(`library_default`), so the help and the behaviour follow the function."""

from __future__ import annotations

import argparse
import inspect
import json
from dataclasses import fields, is_dataclass

from .._parallel import import_ray
from ..errors import IdapbcError
from ..run import CHECKPOINTS, DEFAULT_CHECKPOINT

__all__ = ["add_box_argument", "add_command", "add_checkpoint_argument", "add_effort_argument", "add_horizon_argument", "add_limits_argument",
           "add_radius_argument", "add_ray_argument", "add_rho_argument", "add_run_argument", "add_seed_argument", "add_states_argument",
           "add_system_arguments", "add_workers_argument", "add_x0_argument", "config_keys", "key_range", "key_value",
           "library_default", "positive_int", "ray_of", "seed_of", "system_kwargs", "workers_of", "x0_of"]

SOURCE_HELP = "URDF path, zoo name, built-in name (paper_*) or erd:<example-robot-data URDF stem>"


def library_default(function, name: str):
    """The default of `function`'s parameter `name`: the one place an evaluation default is written."""
    return inspect.signature(function).parameters[name].default


def config_keys(config, table: str) -> str:
    """'key = default, …' of a config dataclass instance, as TOML values (a nested dataclass as its
    own ``[table.name]`` table; an unset optional one as ``key (unset)``): the keys a config file
    may set, for help text."""
    flat, nested = [], []
    for f in fields(config):
        value = getattr(config, f.name)
        if is_dataclass(value):
            nested.append(f"[{table}.{f.name}]: {config_keys(value, f'{table}.{f.name}')}")
        elif value is None:
            flat.append(f"{f.name} (unset)")
        else:
            flat.append(f"{f.name} = {json.dumps(list(value) if isinstance(value, tuple) else value)}")
    return "; ".join([", ".join(flat), *nested])


# ------------------------------------------------------------------------------------ value types
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


# ------------------------------------------------------------------------------------ the system
def add_system_arguments(parser: argparse.ArgumentParser, *, metavar: str = "SOURCE", source_help: str = SOURCE_HELP,
                         optional: bool = False) -> None:
    """SOURCE, --actuated, --target, --domain, --effort: every sub-command that loads a system."""
    parser.add_argument("source", metavar=metavar, nargs="?" if optional else None, help=source_help)
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


# ------------------------------------------------------------------------------------ a run
def add_run_argument(parser: argparse.ArgumentParser, help: str = "run directory (made by `idapbc-pin train`)") -> None:
    """RUN: the run directory a sub-command works on."""
    parser.add_argument("run", metavar="RUN", help=help)


def add_checkpoint_argument(parser: argparse.ArgumentParser, use: str = "use") -> None:
    """--checkpoint {last,best}: which weights of RUN (default: `DEFAULT_CHECKPOINT`)."""
    parser.add_argument("--checkpoint", choices=list(CHECKPOINTS),
                        help=f"checkpoint of RUN to {use} (default: {DEFAULT_CHECKPOINT}, the final weights that train --evaluate measured; "
                             "best: the lowest loss; a run with a damaged checkpoint is refused)")


def add_limits_argument(parser: argparse.ArgumentParser, what: str = "lift the actuators' effort limits") -> None:
    """--no-limits: lift the actuators' effort limits (``limits=False``)."""
    parser.add_argument("--no-limits", action="store_true", help=f"{what} (URDF <limit effort>; applied to every controller by default)")


def add_workers_argument(parser: argparse.ArgumentParser, what: str = "the simulations (the two controllers side by side)") -> None:
    """--workers W: processes of a sub-command (None when not given: one per core, `workers_of`)."""
    parser.add_argument("--workers", type=int, metavar="W",
                        help=f"processes for {what}; default: one per core, at most 16; 1: this process. The count changes the time, never a result")


def workers_of(args: argparse.Namespace) -> int:
    """``args.workers`` (0 when not given: one per core, resolved where the processes start); a
    negative count is refused in one line."""
    if args.workers is None:
        return 0
    if args.workers < 0:
        raise IdapbcError(f"--workers must be ≥ 0, got {args.workers}. Fix: 0 (one process per core) or a count such as 2.")
    return args.workers


def add_ray_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """--ray auto|ADDRESS: run `what` as Ray tasks (None when not given; `ray_of`)."""
    parser.add_argument("--ray", metavar="auto|ADDRESS", help=f"run {what} as Ray tasks: 'auto' starts a local Ray instance ($RAY_ADDRESS's cluster when set), "
                        "ADDRESS joins a cluster (HOST:6379 on a node, ray://HOST:10001 from outside); pip install 'idapbc-pin[ray]'")


def ray_of(args: argparse.Namespace) -> str | None:
    """``args.ray`` (None when not given); where Ray is not installed, a one-line `IdapbcError` with
    the install hint before anything runs."""
    if args.ray is not None:
        import_ray()
    return args.ray


# ------------------------------------------------------------------------------------ the states
def add_states_argument(parser: argparse.ArgumentParser, function, what: str, name: str = "n") -> None:
    """--n N: how many states (or samples); the default is `function`'s parameter `name`."""
    default = library_default(function, name)
    parser.add_argument("--n", type=positive_int, default=default, metavar="N", help=f"{what} (default {default})")


def add_horizon_argument(parser: argparse.ArgumentParser, function, what: str = "horizon", name: str = "T") -> None:
    """--T SECONDS: the horizon; the default is `function`'s parameter `name`."""
    default = library_default(function, name)
    parser.add_argument("--T", type=float, default=default, metavar="SECONDS", help=f"{what} (default {default:g})")


def add_seed_argument(parser: argparse.ArgumentParser, function=None, what: str = "seed of the random states") -> None:
    """--seed S: `function`'s default, or None (the config's) without a function."""
    default = None if function is None else library_default(function, "seed")
    parser.add_argument("--seed", type=int, default=default, metavar="S", help=what if function is None else f"{what} (default {default})")


def seed_of(args: argparse.Namespace) -> int | None:
    """``args.seed``; a negative seed (which numpy's generators refuse with a traceback) is refused
    in one line before anything runs."""
    if args.seed is not None and args.seed < 0:
        raise IdapbcError(f"--seed must be ≥ 0, got {args.seed}. Fix: a seed such as 0 or 1.")
    return args.seed


def add_box_argument(parser: argparse.ArgumentParser, function) -> None:
    """--box {domain,half}: the box the random states are drawn from (`function`'s default)."""
    default = library_default(function, "box")
    parser.add_argument("--box", choices=["domain", "half"], default=default,
                        help=f"box of the random states: the training domain or its half-size copy around x* (default {default})")


def add_x0_argument(parser: argparse.ArgumentParser, what: str = "overrides --n") -> None:
    """--x0 V …: initial states given by hand (repeatable); read them with `x0_of`."""
    parser.add_argument("--x0", type=float, nargs="+", action="append", metavar="V",
                        help=f"initial state: n values (q then momenta p) or nq positions at rest; repeat for several ({what})")


def x0_of(args: argparse.Namespace) -> list[list[float]] | None:
    """The ``--x0`` states, all of one length (else one line naming the fix)."""
    if args.x0 is not None and len({len(v) for v in args.x0}) != 1:
        raise IdapbcError("every --x0 needs the same number of values. Fix: give n (q, p) or nq (q) values each time.")
    return args.x0


def add_rho_argument(parser: argparse.ArgumentParser, what: str = "extra damping ρ (R_d = L Lᵀ + ρS) for Neural IDA-PBC") -> None:
    """--rho R: extra damping of the learned law (None: the library's choice)."""
    parser.add_argument("--rho", type=float, metavar="R", help=what)


def add_radius_argument(parser: argparse.ArgumentParser) -> None:
    """--no-radius: skip the ROA radii (``radius=False``)."""
    parser.add_argument("--no-radius", action="store_true", help="skip the ROA radii (a few more ROA evaluations of --n states)")


def add_command(subparsers, name: str, func, help: str, **kwargs) -> argparse.ArgumentParser:
    """The sub-command `name`, which runs ``func(args)``: its `--help` shows `help` and, as the
    description, `func`'s docstring. `kwargs` go to ``add_parser`` (an ``epilog``, say)."""
    p = subparsers.add_parser(name, help=help, description=inspect.getdoc(func) or help, **kwargs)
    p.set_defaults(func=func)
    return p
