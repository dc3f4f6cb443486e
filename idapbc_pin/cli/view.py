"""`view`: meshcat animation of closed-loop rollouts, live in the browser or as a standalone HTML file."""

from __future__ import annotations

import argparse
import signal
from pathlib import Path

from ..errors import IdapbcError
from ..model import load_system
from ..training.run import CHECKPOINTS, DEFAULT_CHECKPOINT, resolve_run
from ..viewer import PICK_CANDIDATES, view
from ._args import key_range, key_value, system_kwargs

__all__ = ["add_view_command"]


def add_view_command(subparsers) -> argparse.ArgumentParser:
    """Register ``idapbc-pin view RUN_OR_SOURCE ...`` on an argparse sub-parsers object."""
    p = subparsers.add_parser(
        "view",
        help="meshcat animation of closed-loop rollouts: live in the browser, or a standalone HTML file",
        description=(
            "Animate closed-loop rollouts in meshcat. RUN_OR_SOURCE is a run directory (its controller) or a system "
            "source (the LQR baseline). Serves http://127.0.0.1:PORT/static/ until Ctrl-C; with --html FILE it writes "
            "the standalone replay and exits (add --serve or --port to serve as well)."
        ),
    )
    p.add_argument("source", metavar="RUN_OR_SOURCE", help="run directory, or URDF path, zoo name, built-in name (paper_*) or erd:<stem>")
    p.add_argument("--actuated", nargs="+", action="extend", metavar="JOINT", help="actuated joint(s) of a SOURCE; default: the zoo entry's")
    p.add_argument("--target", type=key_value, action="append", metavar="JOINT=VALUE", help="target joint value of a SOURCE (rad or m), repeatable")
    p.add_argument("--domain", type=key_range, action="append", metavar="NAME=LO:HI", help="training-box bounds of a SOURCE, repeatable")
    p.add_argument("--x0", type=float, nargs="+", action="append", metavar="V",
                   help="initial state: n values (q then momenta p) or nq positions at rest; repeat for several rollouts")
    p.add_argument("--n", type=int, default=3, metavar="K", help="rollouts from random states of the half-size training box (default 3)")
    p.add_argument("--T", type=float, default=10.0, metavar="SECONDS", help="duration of each rollout (default 10)")
    p.add_argument("--pick", choices=["random", "success"], default="random",
                   help=f"random: the first K random half-box states (default); success: up to K rollouts that reach x* "
                        f"(the success criterion of docs/method.md), chosen among {PICK_CANDIDATES}·K random states")
    p.add_argument("--seed", type=int, default=0, help="seed of the random initial states (default 0)")
    p.add_argument("--html", metavar="FILE", help="write the standalone HTML replay (offline, one file)")
    p.add_argument("--port", type=int, metavar="P", help="HTTP port of the live page (default: first free from 7000)")
    p.add_argument("--serve", action="store_true", help="serve live even when --html is given")
    p.add_argument("--layout", choices=["sequence", "side_by_side"], default="sequence", help="rollouts one after another (default) or side by side")
    p.add_argument("--trace-link", metavar="NAME", help="joint or link whose far end is traced (default: the last link)")
    p.add_argument("--no-trace", action="store_true", help="do not draw the end-link trace")
    p.add_argument("--no-limits", action="store_true", help="simulate without the actuators' effort limits (applied by default)")
    p.add_argument("--checkpoint", choices=list(CHECKPOINTS),
                   help=f"which checkpoint of a RUN to animate (default: {DEFAULT_CHECKPOINT}, the final weights; best: the lowest loss)")
    p.set_defaults(func=_cmd_view)
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
    source = Path(args.source)
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
    x0 = args.x0
    if x0 is not None and len({len(v) for v in x0}) != 1:
        raise IdapbcError("every --x0 needs the same number of values. Fix: give n (q, p) or nq (q) values each time.")
    viewer = view(
        target, x0=x0, n=args.n, pick=args.pick, T=args.T, seed=args.seed, html=args.html, open_server=False,
        layout=args.layout, trace=not args.no_trace, trace_link=args.trace_link, limits=not args.no_limits,
    )
    if args.html:
        print(f"wrote {args.html} ({len(viewer.segments)} rollouts, {viewer.duration:.1f} s; {viewer.note})")
    if not serve:
        return 0
    _serve_until_stopped(viewer, args.port)
    print("viewer closed")
    return 0
