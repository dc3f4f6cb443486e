"""`idapbc-pin`: the command line. Thin: each sub-command calls one library function.

Bad input prints one line ``error: <problem>. Fix: <fix>`` and exits with status 2.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import IdapbcError

__all__ = ["main"]


def TrainConfig_fast_help() -> str:
    from ..config import TrainConfig

    return TrainConfig.fast.__doc__.splitlines()[0].split(": ", 1)[-1]


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
    from ..model.inspection import format_report, inspect_system

    print(format_report(inspect_system(args.source, **system_kwargs(args))))
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from ..model.analytic import ANALYTIC
    from ..model.zoo import ZOO

    print("zoo (urdf/):")
    for entry in ZOO.values():
        print(f"  {entry.name:<24}{entry.urdf:<28}actuated: {', '.join(entry.actuated):<18}{entry.description}")
    print("built-in analytic systems (paper §V):")
    for spec in ANALYTIC.values():
        print(f"  {spec.name:<24}actuated: {', '.join(spec.actuated):<18}{spec.description}")
    print("example-robot-data: erd:<URDF stem>, e.g. erd:double_pendulum_continuous --actuated joint1")
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    from ..config import TrainConfig
    from ..model.system import load_system
    from ..training.train import train

    overrides = {k: getattr(args, k) for k in ("epochs", "seed", "device", "form", "damping", "rho", "kappa", "lr", "width", "depth") if getattr(args, k) is not None}
    if args.resume:
        run = train(_resume_system(args.resume), TrainConfig(epochs=args.epochs) if args.epochs else None, resume=args.resume)
    else:
        if args.source is None:
            raise_usage("train needs SOURCE (or --resume RUN)")
        base = TrainConfig.from_file(args.config) if args.config else TrainConfig()
        if args.fast:
            base = TrainConfig.fast(**{k: v for k, v in base.to_dict().items() if v != getattr(TrainConfig(), k)})
        config = base.replace(**overrides)
        system = load_system(args.source, **system_kwargs(args))
        run = train(system, config, out=args.out)
    print(format_train_summary(run))
    if run.summary.get("status") == "interrupted":
        print(f"interrupted: resume with  idapbc-pin train --resume {run.path}")
        return 130
    if args.evaluate > 0:
        from ..evaluation.evaluate import evaluate_run, format_evaluation

        print(format_evaluation(evaluate_run(run, n=args.evaluate)))
    return 0


def raise_usage(message: str):
    from ..errors import IdapbcError

    raise IdapbcError(f"{message}. Fix: see `idapbc-pin train --help`.")


def _resume_system(run_dir):
    from ..training.run import load_run_system

    return load_run_system(run_dir)


def format_train_summary(run) -> str:
    s = run.summary
    eig = ", ".join(f"{re:.3g}" + (f"{im:+.3g}j" if abs(im) > 1e-12 else "") for re, im in s["eigenvalues_at_target"])
    lines = [
        f"run: {run.path}",
        f"status: {s['status']} after {s['epochs_done']} epochs, {s['train_seconds']:.1f} s",
        "final loss terms: " + ", ".join(f"{k} {v:.3g}" for k, v in s["final_terms"].items()),
        f"closed-loop eigenvalues at x*: {eig}",
    ]
    config = getattr(run, "config", None)
    if config is not None and getattr(config, "form", "anchored") == "anchored":
        units = "box units, Q = anchor_q·diag(1/s²)" if config.scaling == "box" else "physical units, Q = anchor_q·I"
        lines.insert(3, f"anchor: LQR with anchor_q = {config.anchor_q:g} ({units})")
    if s["locally_exponentially_stable"]:
        lines.append("x* is locally exponentially stable (all eigenvalues have negative real part)")
    else:
        lines.append("WARNING: x* is NOT locally exponentially stable under the learned controller (an eigenvalue has Re >= 0)")
    fastest = max((abs(complex(re, im)) for re, im in s["eigenvalues_at_target"]), default=0.0)
    if fastest * STIFF_DT > STIFF_WARN:
        plant = s.get("open_loop_fastest_pole", 0.0)
        smaller_step = f"simulate with --dt {0.5 / fastest:.1g}"
        fix = (
            f"the plant has it too (open loop at x*: |λ| = {plant:.3g} 1/s, e.g. joint damping on light links), so no anchor "
            f"weight removes it: {smaller_step}"
            if plant >= PLANT_POLE_SHARE * fastest
            else f"{smaller_step} or train with a gentler anchor (smaller anchor_q)"
        )
        lines.append(
            f"NOTE: the fastest closed-loop pole at x* has |λ| = {fastest:.3g} 1/s: |λ|·dt = {fastest * STIFF_DT:.2g} at the default "
            f"{STIFF_DT * 1e3:g} ms RK4 step of `simulate`, near or past RK4's stability limit 2.78 (and the loop is faster "
            f"still away from x*); {fix}"
        )
    return "\n".join(lines)


#: `simulate`'s default RK4 step (s), and the |λ|·dt above which `train` warns that the learned loop
#: is too stiff for it (RK4 is stable on the negative real axis up to 2.78; measured: the Furuta
#: pendulum's anchor with |λ| = 253 1/s, |λ|·dt = 2.5, diverged from every state at 10 ms and reached
#: x* from 24 % of the half box at 2 ms).
STIFF_DT, STIFF_WARN = 0.01, 1.0
#: The NOTE blames the plant rather than the anchor when the open loop at x* has a pole at least this
#: share of the fastest closed-loop one (`erd:double_pendulum`: open loop 136 1/s from joint damping on
#: light links, closed loop 136 1/s with the weakest automatic anchor).
PLANT_POLE_SHARE = 0.9


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="idapbc-pin", description="Neural IDA-PBC for underactuated robots, from URDF with Pinocchio.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("inspect", help="joints, dimensions, actuation, target equilibrium, controllability")
    add_system_arguments(p)
    p.set_defaults(func=_cmd_inspect)

    from ..config import FIELD_HELP

    p = sub.add_parser("train", help="train Neural IDA-PBC; writes a run directory")
    p.add_argument("source", metavar="SOURCE", nargs="?", help="URDF path, zoo name, built-in name or erd:<stem>")
    p.add_argument("--actuated", nargs="+", action="extend", metavar="JOINT", help="actuated joint(s); default: the zoo entry's")
    p.add_argument("--target", type=_key_value, action="append", metavar="JOINT=VALUE", help="target joint value, repeatable")
    p.add_argument("--domain", type=_key_range, action="append", metavar="NAME=LO:HI", help="training-box bounds, repeatable")
    p.add_argument("--config", metavar="FILE", help="TOML ([train] table) or JSON training config")
    p.add_argument("--fast", action="store_true", help="fast preset: " + TrainConfig_fast_help())
    p.add_argument("--out", metavar="DIR", help="parent of the run directory (default runs/<system>)")
    p.add_argument("--resume", metavar="RUN", help="continue RUN from its last checkpoint (same result as uninterrupted)")
    p.add_argument("--evaluate", type=int, default=100, metavar="N", help="closed-loop check vs LQR from N random states after training (0: skip)")
    for name, kind in (("epochs", int), ("seed", int), ("lr", float), ("width", int), ("depth", int), ("rho", float), ("kappa", float)):
        p.add_argument(f"--{name}", type=kind, help=FIELD_HELP[name])
    p.add_argument("--device", help=FIELD_HELP["device"])
    p.add_argument("--form", choices=["anchored", "free"], help=FIELD_HELP["form"])
    p.add_argument("--damping", choices=["full", "actuated"], help=FIELD_HELP["damping"])
    p.set_defaults(func=_cmd_train)

    p = sub.add_parser("list", help="zoo robots and built-in systems")
    p.set_defaults(func=_cmd_list)

    from ..viewer.view import add_view_command

    add_view_command(sub)

    from ..reporting.report import add_eval_commands

    add_eval_commands(sub)

    from ..batch.batch import add_batch_command

    add_batch_command(sub)
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
