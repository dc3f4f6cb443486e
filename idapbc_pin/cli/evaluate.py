"""`simulate`, `certify`, `report` and `robustness`: the evaluation sub-commands, each a thin call
of one library function on a run directory."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..certificate.certify import certify
from ..errors import IdapbcError
from ..evaluation.closed_loop import JUDGES, simulate_run
from ..evaluation.robustness import default_conditions, robustness_table
from ..reporting.report import report
from ..training.run import CHECKPOINTS, DEFAULT_CHECKPOINT, load_run
from ._args import add_workers_argument, positive_int, workers_of

__all__ = ["add_eval_commands"]


def _run(args: argparse.Namespace):
    """The run the command works on: RUN's `--checkpoint` (default: last, refusing damaged checkpoints)."""
    return load_run(args.run, checkpoint=args.checkpoint)


def _cmd_simulate(args: argparse.Namespace) -> int:
    x0 = args.x0
    if x0 is not None and len({len(v) for v in x0}) != 1:
        raise IdapbcError("every --x0 needs the same number of values. Fix: give n (q, p) or nq (q) values each time.")
    result = simulate_run(
        _run(args), n=args.n, T=args.T, dt=args.dt, x0=x0, rho=args.rho, mismatch=args.mismatch,
        saturation=args.saturation, noise=args.noise, seed=args.seed, box=args.box, limits=not args.no_limits, radius=not args.no_radius,
        judge=args.judge, workers=workers_of(args),
    )
    print(result.table())
    return 0


def _cmd_certify(args: argparse.Namespace) -> int:
    cert = certify(_run(args), n=args.n, seed=args.seed, epsilon=args.epsilon, settle=args.settle, limits=not args.no_limits)
    print(cert.table())
    print(f"wrote {Path(args.run) / 'certificate.json'}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    print(report(_run(args), n_roa=args.n, T=args.T, rho_extra=args.rho, n_figure=args.n_figure, html=not args.no_html, seed=args.seed,
                 limits=not args.no_limits, radius=not args.no_radius, workers=workers_of(args)))
    return 0


def _cmd_robustness(args: argparse.Namespace) -> int:
    sat = "auto" if args.saturation is None else args.saturation
    conds = default_conditions(mass=args.mass, saturation=sat, noise=args.noise)
    result = robustness_table(_run(args), n=args.n, T=args.T, seed=args.seed, box=args.box, conditions=conds, rho=args.rho, limits=not args.no_limits,
                              workers=workers_of(args))
    print(result.table())
    print(f"wrote {Path(args.run) / 'robustness.json'}")
    return 0


def _add_run_options(p) -> None:
    """--no-limits and --checkpoint: how every evaluation sub-command treats RUN."""
    p.add_argument("--no-limits", action="store_true",
                   help="lift the actuators' effort limits (URDF <limit effort>; applied to every controller by default)")
    p.add_argument("--checkpoint", choices=list(CHECKPOINTS),
                   help=f"checkpoint of RUN to use (default: {DEFAULT_CHECKPOINT}, the final weights that train --evaluate measured; a run with a damaged checkpoint is refused)")


def add_eval_commands(subparsers) -> None:
    """Register ``simulate``, ``certify``, ``report`` and ``robustness`` on argparse sub-parsers."""
    p = subparsers.add_parser("simulate", help="closed loop from random states, Neural IDA-PBC next to LQR; metrics + figure into RUN")
    p.add_argument("run", metavar="RUN", help="run directory (made by `idapbc-pin train`)")
    p.add_argument("--n", type=positive_int, default=100, help="initial states uniform in the box (default 100)")
    p.add_argument("--T", type=float, default=20.0, metavar="SECONDS", help="horizon (default 20)")
    p.add_argument("--dt", type=float, default=None, metavar="SECONDS", help="RK4 step and control period: the law is sampled once per step and held (default: 0.002, a 500 Hz controller, or shorter where a loop at x* has a pole faster than 250 1/s)")
    p.add_argument("--x0", type=float, nargs="+", action="append", metavar="V",
                   help="initial state: n values (q then p) or nq positions at rest; repeat for several (overrides --n)")
    p.add_argument("--box", choices=["domain", "half"], default="domain", help="box of the random states (default: the training domain)")
    p.add_argument("--rho", type=float, metavar="R", help="extra damping ρ (R_d = L Lᵀ + ρS) for Neural IDA-PBC")
    p.add_argument("--mismatch", action="append", metavar="KIND=SCALE",
                   help="scale the judge plant: mass=1.2, length=0.9, damping=2 (repeatable or comma-separated)")
    p.add_argument("--saturation", type=float, metavar="U", help="extra actuator limit |u| ≤ U (N·m or N; the smaller of it and the effort limit applies)")
    p.add_argument("--noise", type=float, default=0.0, metavar="SIGMA", help="Gaussian measurement noise σ on (q, v) (rad, m, rad/s, m/s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the states and the noise (default 0)")
    p.add_argument("--no-radius", action="store_true", help="skip the ROA radii (a few more ROA evaluations of --n states)")
    p.add_argument("--judge", choices=JUDGES, default="pinocchio",
                   help="engine of the true plant for both controllers (default pinocchio; mujoco needs `pip install mujoco`, URDF robots only)")
    add_workers_argument(p)
    _add_run_options(p)
    p.set_defaults(func=_cmd_simulate)

    p = subparsers.add_parser("certify", help="the paper's conditions checked on dense samples (a sampled certificate); certificate.json")
    p.add_argument("run", metavar="RUN", help="run directory")
    p.add_argument("--n", type=positive_int, default=20000, help="uniform samples of the domain (default 20000)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--epsilon", type=float, help="level ε of E = H_ε (default: the run's estimate)")
    p.add_argument("--settle", type=int, default=4, help="simulated states near x* (and as many in the half box) for the settled equilibrium (0: skip)")
    _add_run_options(p)
    p.set_defaults(func=_cmd_certify)

    p = subparsers.add_parser("report", help="ROA vs LQR, certificate, the paper's figure and a meshcat replay, into RUN")
    p.add_argument("run", metavar="RUN", help="run directory")
    p.add_argument("--n", type=positive_int, default=200, help="ROA states per box (default 200)")
    p.add_argument("--T", type=float, default=20.0, metavar="SECONDS", help="horizon (default 20)")
    p.add_argument("--rho", type=float, metavar="R", help="ρ of the extra-damping row (default: the median damping along ∇H_d, at least 1)")
    p.add_argument("--n-figure", type=positive_int, default=4, help="trajectories in the figure (default 4)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--no-html", action="store_true", help="skip the meshcat replay")
    p.add_argument("--no-radius", action="store_true", help="skip the ROA radii (a few more ROA evaluations of --n states)")
    add_workers_argument(p)
    _add_run_options(p)
    p.set_defaults(func=_cmd_report)

    p = subparsers.add_parser("robustness", help="success rates under mass mismatch, saturation and noise, Neural IDA-PBC vs LQR")
    p.add_argument("run", metavar="RUN", help="run directory")
    p.add_argument("--n", type=positive_int, default=100, help="states (default 100)")
    p.add_argument("--T", type=float, default=20.0, metavar="SECONDS", help="horizon (default 20)")
    p.add_argument("--box", choices=["domain", "half"], default="half", help="box of the states (default half)")
    p.add_argument("--mass", type=float, nargs="+", default=[0.8, 1.2], metavar="S", help="link-mass scales (default 0.8 1.2)")
    p.add_argument("--saturation", type=float, metavar="U", help="actuator limit (default 2 × LQR's median nominal peak |u|)")
    p.add_argument("--noise", type=float, default=0.01, metavar="SIGMA", help="measurement noise σ (default 0.01)")
    p.add_argument("--rho", type=float, metavar="R", help="extra damping ρ for Neural IDA-PBC")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    add_workers_argument(p)
    _add_run_options(p)
    p.set_defaults(func=_cmd_robustness)
