"""`view`: meshcat animation of closed-loop rollouts, live in the browser or as a standalone HTML file."""

from __future__ import annotations

import argparse
import signal
from pathlib import Path

from ..errors import IdapbcError
from ..model import load_system
from ..run import resolve_run
from ..viewer import PICK_CANDIDATES, PICKS, view
from ._args import (add_command, add_checkpoint_argument, add_horizon_argument, add_limits_argument, add_seed_argument, add_states_argument, add_system_arguments,
                    add_x0_argument, library_default, seed_of, system_kwargs, x0_of)

__all__ = ["add_view_command"]


def add_view_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin view RUN_OR_SOURCE ...`` on an argparse sub-parsers object (defaults: `view`'s)."""
    p = add_command(subparsers, "view", _cmd_view, help="meshcat animation of closed-loop rollouts: live in the browser, or a standalone HTML file")
    add_system_arguments(p, metavar="RUN_OR_SOURCE", source_help="run directory, or URDF path, zoo name, built-in name (paper_*) or erd:<stem>")
    add_x0_argument(p, "overrides --n")
    add_states_argument(p, view, "rollouts from random states of the half-size training box")
    add_horizon_argument(p, view, "duration of each rollout")
    pick = library_default(view, "pick")
    p.add_argument("--pick", choices=list(PICKS), default=pick,
                   help=f"random: the first K random half-box states; success: up to K rollouts that reach x* "
                        f"(the success criterion of docs/method.md), chosen among {PICK_CANDIDATES}·K random states; hanging: K swing-ups "
                        f"from near the resting posture; auto: hanging for a run with a swing-up law, else random (default {pick})")
    add_seed_argument(p, view, "seed of the random initial states")
    p.add_argument("--html", metavar="FILE", help="write the standalone HTML replay (offline, one file)")
    p.add_argument("--port", type=int, metavar="P", help="HTTP port of the live page (default: first free from 7000)")
    p.add_argument("--serve", action="store_true", help="serve live even when --html is given")
    add_limits_argument(p)
    add_checkpoint_argument(p, "animate")
    return p


def _serve_until_stopped(viewer, port: int | None) -> None:
    """Serve `viewer` live until Ctrl-C or SIGTERM (both leave through KeyboardInterrupt), then close it."""

    def _terminate(signum, frame):  # SIGTERM: leave through the same path as Ctrl-C
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        url = viewer.serve(port)
        try:  # a signal that lands just after the URL is printed, before wait() starts, stops it too
            print(f"meshcat viewer: {url}  ({viewer.note}; Ctrl-C to stop)", flush=True)
            viewer.wait()
        except KeyboardInterrupt:
            pass
    finally:
        viewer.close()
        signal.signal(signal.SIGTERM, previous)


def _cmd_view(args: argparse.Namespace) -> int:
    """Animate closed-loop rollouts in meshcat. RUN_OR_SOURCE is a run directory (its controller)
    or a system source (the LQR baseline; --actuated, --target, --domain and --effort apply to a
    SOURCE). Serves http://127.0.0.1:PORT/static/ until Ctrl-C; with --html FILE it writes the
    standalone replay and exits (add --serve or --port to serve as well). The layout and the
    traced link are `idapbc_pin.view` arguments."""
    seed, source = seed_of(args), Path(args.source)
    if source.is_dir() and (source / "config.json").is_file():
        target = resolve_run(source, checkpoint=args.checkpoint)
    elif args.checkpoint is not None:
        raise IdapbcError(f"--checkpoint applies to a run directory, and '{args.source}' is not one. Fix: drop --checkpoint, or pass a run directory.")
    else:
        try:
            target = load_system(args.source, **system_kwargs(args))
        except IdapbcError:
            if source.is_dir():  # meant as a run: say what it lacks
                resolve_run(source)
            raise
    serve = args.html is None or args.serve or args.port is not None
    viewer = view(target, x0=x0_of(args), n=args.n, pick=args.pick, T=args.T, seed=seed, html=args.html, open_server=False,
                  limits=not args.no_limits)
    if args.html:
        print(f"wrote {args.html} ({len(viewer.segments)} rollouts, {viewer.duration:.1f} s; {viewer.note})")
    if not serve:
        return 0
    _serve_until_stopped(viewer, args.port)
    print("viewer closed")
    return 0
