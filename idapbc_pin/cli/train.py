"""`inspect`, `list` and `train`: the model and training sub-commands."""

from __future__ import annotations

import argparse

from ..config import FIELD_HELP, TrainConfig
from ..errors import IdapbcError
from ._args import add_effort_argument, add_system_arguments, add_workers_argument, key_range, key_value, system_kwargs, workers_of

__all__ = ["add_model_commands", "add_train_command"]


def _cmd_inspect(args: argparse.Namespace) -> int:
    from ..model.inspection import format_report, inspect_system

    print(format_report(inspect_system(args.source, **system_kwargs(args))))
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from ..model.analytic import ANALYTIC
    from ..model.zoo import ZOO

    zoo, analytic = list(ZOO.values()), list(ANALYTIC.values())
    w_name = 2 + max(len(e.name) for e in zoo + analytic)  # columns never run together
    w_urdf = 2 + max(len(e.urdf) for e in zoo)
    w_act = 2 + max(len(", ".join(e.actuated)) for e in zoo + analytic)
    print("zoo (urdf/):")
    for entry in zoo:
        print(f"  {entry.name:<{w_name}}{entry.urdf:<{w_urdf}}actuated: {', '.join(entry.actuated):<{w_act}}{entry.description}")
    print("built-in analytic systems (paper §V):")
    for spec in analytic:
        print(f"  {spec.name:<{w_name}}{'':<{w_urdf}}actuated: {', '.join(spec.actuated):<{w_act}}{spec.description}")
    print("example-robot-data: erd:<URDF stem>, e.g. erd:double_pendulum_continuous --actuated joint1")
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    from ..model import load_system
    from ..training.run import load_run_system, read_config
    from ..training.summary import format_train_summary
    from ..training.train import train

    workers = workers_of(args)
    overrides = {k: getattr(args, k) for k in ("epochs", "seed", "device", "form", "damping", "rho", "kappa", "lr", "width", "depth", "rollout_epochs", "fallback", "fallback_gain") if getattr(args, k) is not None}
    if args.resume:
        saved = read_config(args.resume)
        config = saved.replace(**{k: v for k, v in (("epochs", args.epochs), ("lr", args.lr), ("device", args.device)) if v is not None})
        system = load_run_system(args.resume)
        run = train(system, config, resume=args.resume, workers=workers)  # checks the device and both checkpoints before anything is written
    else:
        if args.source is None:
            raise IdapbcError("train needs SOURCE (or --resume RUN). Fix: see `idapbc-pin train --help`.")
        given = TrainConfig.file_values(args.config) if args.config else {}  # only the keys the file sets
        config = (TrainConfig.fast(**given) if args.fast else TrainConfig(**given)).replace(**overrides)
        system = load_system(args.source, **system_kwargs(args))
        run = train(system, config, out=args.out, workers=workers)
    print(format_train_summary(run))
    if run.summary.get("status") == "interrupted":
        print(f"interrupted: resume with  idapbc-pin train --resume {run.path}")
        return 130
    if args.recover != "never":
        from ..training.weak_actuators import auto_recover

        auto_recover(run, args.recover)
    if args.evaluate > 0:
        from ..evaluation.evaluate import evaluate_run, format_evaluation

        print(format_evaluation(evaluate_run(run, n=args.evaluate, limits=not args.no_limits, workers=workers)))
    print(
        f"next: idapbc-pin report {run.path}   (ROA vs LQR, certificate.json, figure.png, replay.html)\n"
        f"      idapbc-pin view {run.path}     (3-D replay in the browser)"
    )
    return 0


def add_model_commands(sub) -> None:
    """`inspect` and `list`."""
    p = sub.add_parser("inspect", help="joints, dimensions, actuation, target equilibrium, controllability")
    add_system_arguments(p)
    p.set_defaults(func=_cmd_inspect)
    p = sub.add_parser("list", help="zoo robots and built-in systems")
    p.set_defaults(func=_cmd_list)


def add_train_command(sub) -> None:
    """`train`, its options named after `TrainConfig`'s fields (help from `FIELD_HELP`)."""
    p = sub.add_parser(
        "train", help="train Neural IDA-PBC; writes a run directory",
        epilog="The networks, the anchored form and the loss terms are described in docs/method.md (in the source repository).",
    )
    p.add_argument("source", metavar="SOURCE", nargs="?", help="URDF path, zoo name, built-in name or erd:<stem>")
    p.add_argument("--actuated", nargs="+", action="extend", metavar="JOINT", help="actuated joint(s); default: the zoo entry's")
    p.add_argument("--target", type=key_value, action="append", metavar="JOINT=VALUE", help="target joint value, repeatable")
    p.add_argument("--domain", type=key_range, action="append", metavar="NAME=LO:HI", help="training-box bounds, repeatable")
    add_effort_argument(p)
    p.add_argument("--config", metavar="FILE", help="TOML ([train] table) or JSON training config")
    fast = TrainConfig.fast()
    p.add_argument("--fast", action="store_true", help=f"fast preset: width {fast.width} × {fast.depth} layers, {fast.dtype}, {fast.epochs} epochs")
    p.add_argument("--out", metavar="DIR", help="parent of the run directory (default runs/<system>)")
    p.add_argument("--resume", metavar="RUN", help="continue RUN from its last checkpoint (same result as uninterrupted)")
    p.add_argument("--evaluate", type=int, default=100, metavar="N", help="closed-loop check vs LQR from N random states after training (0: skip)")
    p.add_argument("--no-limits", action="store_true", help="evaluate without the actuators' effort limits (they apply to both controllers by default)")
    add_workers_argument(p)
    for name, kind in (("epochs", int), ("seed", int), ("lr", float), ("width", int), ("depth", int), ("rho", float), ("kappa", float)):
        p.add_argument(f"--{name}", type=kind, help=FIELD_HELP[name])
    p.add_argument("--rollout-epochs", dest="rollout_epochs", type=int, metavar="K", help=FIELD_HELP["rollout_epochs"])
    p.add_argument("--device", help=FIELD_HELP["device"])
    p.add_argument("--form", choices=["anchored", "free"], help=FIELD_HELP["form"])
    p.add_argument("--damping", choices=["full", "actuated"], help=FIELD_HELP["damping"])
    p.add_argument("--fallback", choices=["auto", "linear", "none"], help=FIELD_HELP["fallback"])
    p.add_argument("--fallback-gain", dest="fallback_gain", type=float, metavar="K", help=FIELD_HELP["fallback_gain"])
    p.add_argument("--recover", nargs="?", const="always", default="auto", choices=["auto", "always", "never"],
                   help="weak actuators: after training, fit a recovery law to torque plans within the limits and keep it "
                        "if simulation shows it helps (`idapbc-pin recover`; 15-50 min on 2 cores for a 2-DoF robot, an hour for a 3-DoF one). "
                        "auto (default): only where saturated LQR leaves room, i.e. fails from at least 10 of 100 half-box "
                        "states, or else of 100 training-box states (then the plans start from the training box: the cartpole; "
                        "reaction wheel and double pendulum leave no room at their URDF limits); --recover alone: always; never: skip")
    p.set_defaults(func=_cmd_train)
