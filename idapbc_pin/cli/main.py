"""`idapbc-pin`: the command line. Thin: each sub-command calls one library function.

Bad input prints one line ``error: <problem>. Fix: <fix>`` and exits with status 2. One file per
family of sub-commands; argparse is used nowhere outside this package.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from ..errors import IdapbcError
from .train import add_model_commands, add_train_command

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The `idapbc-pin` parser with every sub-command."""
    parser = argparse.ArgumentParser(prog="idapbc-pin", description="Neural IDA-PBC for underactuated robots, from URDF with Pinocchio.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_model_commands(sub)
    add_train_command(sub)

    from .view import add_view_command

    add_view_command(sub)

    from .evaluate import add_eval_commands

    add_eval_commands(sub)

    from .batch import add_batch_command

    add_batch_command(sub)

    from .export import add_export_command

    add_export_command(sub)

    from .recover import add_recover_command

    add_recover_command(sub)
    return parser


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    return f"warning: {message}\n"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `idapbc-pin` console script; returns the exit status."""
    warnings.formatwarning = _one_line_warning  # "warning: …" lines, no source paths
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except IdapbcError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
