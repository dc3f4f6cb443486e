"""`inspect`, `list` and `train`: the model and training sub-commands."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path

from ..config import FIELD_HELP, TrainConfig
from ..errors import IdapbcError
from ..recovery.config import RecoveryConfig, SwingUpConfig
from ..recovery.trigger import RECOVER_TIME, SMOKE_EPOCHS
from ._args import (add_limits_argument, add_ray_argument, add_seed_argument, add_system_arguments, add_workers_argument, config_keys, ray_of,
                    system_kwargs, workers_of)

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


#: TrainConfig fields that are also flags (help from `FIELD_HELP`); every other field is set in the --config file.
FLAGS = ("epochs", "lr", "device")


def _recovery_config(args: argparse.Namespace) -> RecoveryConfig:
    """The recovery stage's settings: the --recover-config file's (or the defaults), with --workers and
    --ray when given (--ray only with --recover auto|always)."""
    config = RecoveryConfig.from_file(args.recover_config) if args.recover_config else RecoveryConfig()
    config = config if args.workers is None else config.replace(workers=workers_of(args))
    if args.ray is not None and args.recover in (None, "never"):
        raise IdapbcError("--ray runs the recovery stage as Ray tasks, which train runs only with an explicit --recover. Fix: add --recover auto (or always), or drop --ray.")
    return config if args.ray is None else config.replace(ray=ray_of(args))


def _cmd_train(args: argparse.Namespace) -> int:
    from ..model import load_system
    from ..run import load_run, load_run_system, read_config
    from ..training.train import train

    workers = workers_of(args)
    recovery = _recovery_config(args)  # a bad file is refused before training
    swing = SwingUpConfig.from_file(args.swing_config) if args.swing_config else SwingUpConfig()
    swing = swing if args.workers is None else swing.replace(workers=workers)
    if args.resume:
        saved = read_config(args.resume)
        config = saved.replace(**{k: getattr(args, k) for k in FLAGS if getattr(args, k) is not None}, **({"swing_up": True} if args.swing_up else {}))
        system = load_run_system(args.resume)
        if _trained(args.resume, config):  # only the stages after training are left
            run = load_run(args.resume)
            print(f"run directory: {run.path} (trained: {config.epochs} epochs; continuing after training)", flush=True)
            with contextlib.ExitStack() as stack:
                _after_training(args, run, recovery, workers, _baseline_beside_training(stack, args, system, workers), swing, config.swing_up)
            return 0
    else:
        if args.source is None:
            raise IdapbcError("train needs SOURCE (or --resume RUN). Fix: see `idapbc-pin train --help`.")
        given = TrainConfig.file_values(args.config) if args.config else {}  # only the keys the file sets
        overrides = {k: getattr(args, k) for k in (*FLAGS, "seed") if getattr(args, k) is not None} | ({"swing_up": True} if args.swing_up else {})
        config = (TrainConfig.fast(**given) if args.fast else TrainConfig(**given)).replace(**overrides)
        system = load_system(args.source, **system_kwargs(args))
    with contextlib.ExitStack() as stack:
        baseline = _baseline_beside_training(stack, args, system, workers)
        if args.resume:  # train checks the device and both checkpoints before anything is written
            run = train(system, config, resume=args.resume, workers=workers)
        else:
            run = train(system, config, out=args.out, workers=workers)
        _after_training(args, run, recovery, workers, baseline, swing, config.swing_up)
    return 130 if run.summary.get("status") == "interrupted" else 0


def _trained(run_dir, config: TrainConfig) -> bool:
    """Whether the run at `run_dir` finished its training (with its check of the law outside the
    box) at `config.epochs` or more, as its summary.json says: `train --resume` then goes on with
    the recovery stage and the evaluation without training again."""
    from .._io import read_json

    summary_path = Path(run_dir) / "summary.json"
    try:
        summary = read_json(summary_path, fix="delete summary.json and run `idapbc-pin train --resume` again")
    except IdapbcError:  # missing or damaged: the resume trains (no epochs left) and rewrites it
        return False
    done = summary.get("status") == "finished" and not (summary.get("fallback") or {}).get("interrupted")
    return bool(done and int(summary.get("epochs_done", -1)) >= config.epochs)


def _baseline_beside_training(stack: contextlib.ExitStack, args: argparse.Namespace, system, workers: int):
    """A future of LQR's part of the evaluation (`evaluation.evaluate.run_baseline_job`), simulated in a
    worker process while the training takes one core, or None (no evaluation, or one process asked for)."""
    from .._parallel import JobPool, resolve_workers
    from ..evaluation.evaluate import baseline_job, run_baseline_job

    if args.evaluate <= 0 or resolve_workers(workers) < 2:
        return None
    pool = stack.enter_context(JobPool(1, processes=True))
    return pool.submit(run_baseline_job, baseline_job(system, n=args.evaluate, limits=not args.no_limits))


def _after_training(args: argparse.Namespace, run, recovery: RecoveryConfig, workers: int, baseline, swing: SwingUpConfig, swing_up: bool = False) -> None:
    """The summary, then (unless interrupted) the evaluation's two boxes, the recovery stage where it
    has room (then the evaluation again, with the law it kept), the ROA radii, and the next commands.
    Where the stage may run, the first evaluation leaves the radii out, so its tables come first; the
    radii come with the last evaluation (or alone, from the same rollouts, where the law stays); a smoke
    run (fewer than `SMOKE_EPOCHS` epochs) skips them with one line. With
    `swing_up`, the swing-up stage and the evaluation from near-resting states come last."""
    from ..training.summary import format_train_summary

    print(format_train_summary(run))
    if run.summary.get("status") == "interrupted":
        print(f"interrupted: resume with  idapbc-pin train --resume {run.path}")
        return
    mode = _recover_mode(args, run)
    stage = mode != "never" and not run.uses_recovery
    smoke = run.config.epochs < SMOKE_EPOCHS
    if smoke and args.evaluate > 0:
        print(f"ROA radii skipped: a smoke run ({run.config.epochs} < {SMOKE_EPOCHS} epochs); `idapbc-pin simulate {run.path}` "
              "finds them", flush=True)
    evaluation = _evaluate(args, run, workers, baseline, radius=not (stage or smoke)) if args.evaluate > 0 else None
    lqr = None if evaluation is None or args.no_limits else {box: evaluation.results[box]["LQR"].success_rate for box in ("half", "domain")}
    if stage:
        from ..recovery.trigger import auto_recover

        try:
            entry = auto_recover(run, mode, recovery, lqr_success=lqr)
        except KeyboardInterrupt:
            print(f"recovery stage interrupted: the run keeps its law as it is; `idapbc-pin train --resume {run.path}` continues "
                  "the stage from its last finished chunk of plans", flush=True)
            return
        if entry is not None and entry.get("used") and args.evaluate > 0:
            from ..run import load_run

            run = load_run(run.path)  # with the recovery law it keeps
            print("with the recovery law:", flush=True)
            _evaluate(args, run, workers, baseline, radius=not smoke)
        elif evaluation is not None and not smoke:  # the law stays: its radius from the same rollouts
            print(_evaluate(args, run, workers, baseline, reuse=evaluation, tables=False).radius.line(), flush=True)
    elif mode == "never" and not run.uses_recovery and not args.no_limits:
        from ..recovery.trigger import recovery_hint

        hint = recovery_hint(run, None if lqr is None else lqr["half"])
        if hint:
            print(hint)
    if swing_up and not _swing_up(run, swing, args.evaluate > 0):
        return
    print(
        f"next: idapbc-pin report {run.path}   (ROA vs LQR, certificate.json, figure.png, replay.html)\n"
        f"      idapbc-pin view {run.path}     (3-D replay in the browser)"
    )


def _swing_up(run, config: SwingUpConfig, evaluate: bool) -> bool:
    """The swing-up stage (unless the run has been through it: a resumed run), then, with `evaluate`,
    the run judged from near-resting states beside saturated LQR and the energy-pumping law (printed,
    and written to swingup.json). False when Ctrl-C stopped the stage (the run keeps its law as it is)."""
    from ..run import load_run

    if "swing_up" not in run.summary:
        from ..recovery.swing_stage import swing_up

        print("swing-up: fitting a law from the resting posture to x* within the effort limits (a few minutes on 2 cores for a "
              "2-DoF robot; Ctrl-C keeps the run as it is)", flush=True)
        try:
            swing_up(run, config)
        except KeyboardInterrupt:
            print(f"swing-up stage interrupted: the run keeps its law as it is; `idapbc-pin train --resume {run.path}` runs the stage "
                  "again, reading back its finished chunks of plans", flush=True)
            return False
    if evaluate:
        from ..evaluation.swingup import evaluate_run_swingup

        print(evaluate_run_swingup(load_run(run.path), workers=config.workers).table(), flush=True)
    return True


def _recover_mode(args: argparse.Namespace, run) -> str:
    """--recover as given; by default "auto", except after a smoke run (fewer than SMOKE_EPOCHS epochs),
    where the stage is skipped with one line."""
    if args.recover is not None:
        return args.recover
    if run.config.epochs < SMOKE_EPOCHS:
        print(f"recovery stage skipped: a smoke run ({run.config.epochs} < {SMOKE_EPOCHS} epochs); "
              f"`idapbc-pin recover {run.path}` runs it", flush=True)
        return "never"
    return "auto"


def _evaluate(args: argparse.Namespace, run, workers: int, baseline, *, radius: bool = True, reuse=None, tables: bool = True):
    """`evaluate_run` as `train --evaluate N` runs it (with the ROA radii unless `radius` is False;
    `reuse`: an earlier evaluation of the same law whose rollouts serve again), printed unless
    `tables` is False; returns the `Evaluation`."""
    from ..evaluation.evaluate import evaluate_run, format_evaluation

    evaluation = evaluate_run(run, n=args.evaluate, limits=not args.no_limits, workers=workers, progress=True, baseline=baseline,
                              radius=radius, reuse=reuse)
    if tables:
        print(format_evaluation(evaluation), flush=True)
    return evaluation


def add_model_commands(sub) -> None:
    """`inspect` and `list`."""
    p = sub.add_parser("inspect", help="joints, dimensions, actuation, target equilibrium, controllability")
    add_system_arguments(p)
    p.set_defaults(func=_cmd_inspect)
    p = sub.add_parser("list", help="zoo robots and built-in systems")
    p.set_defaults(func=_cmd_list)


def add_train_command(sub) -> None:
    """`train`: the system, the run's place, and the few `TrainConfig` fields a user sets on the command
    line (`FLAGS`, seed); every field can be set in the --config file (help from `FIELD_HELP`)."""
    fast = TrainConfig.fast()
    p = sub.add_parser(
        "train", help="train Neural IDA-PBC; writes a run directory",
        epilog=f"--config FILE keys (TrainConfig fields, described in FIELD_HELP of idapbc_pin/config.py; the defaults, "
               f"which --fast changes to width {fast.width}, depth {fast.depth}, dtype {fast.dtype!r}, epochs {fast.epochs}): "
               f"{config_keys(TrainConfig(), 'train')}. --recover-config FILE: see `idapbc-pin recover --help`. "
               "The networks, the anchored form and the loss terms are described in docs/method.md (in the source repository).",
    )
    add_system_arguments(p, optional=True)
    p.add_argument("--config", metavar="FILE", help="TOML ([train] table, or top-level keys) or JSON training config: any TrainConfig field "
                                                   "(width, depth, form, fallback, rollout_epochs, …; listed below); flags override it")
    p.add_argument("--fast", action="store_true", help=f"fast preset: width {fast.width} × {fast.depth} layers, {fast.dtype}, {fast.epochs} epochs")
    for name in FLAGS:
        kind = type(getattr(fast, name))
        p.add_argument(f"--{name}", type=kind, metavar=name.upper() if kind is not str else None, help=FIELD_HELP[name])
    add_seed_argument(p, what=FIELD_HELP["seed"])
    p.add_argument("--out", metavar="DIR", help="parent of the run directory (default runs/<system>)")
    p.add_argument("--resume", metavar="RUN", help="continue RUN from its last checkpoint (same result as uninterrupted; --epochs, --lr, --device apply); "
                                                  "a run whose training finished goes on with the recovery stage and the evaluation")
    p.add_argument("--evaluate", type=int, default=100, metavar="N", help="closed-loop check vs LQR from N random states after training (0: skip)")
    add_limits_argument(p, "evaluate without the actuators' effort limits")
    add_workers_argument(p, "the simulations (the two controllers side by side, train's gate and the recovery stage)")
    p.add_argument("--recover", nargs="?", const="always", default=None, choices=["auto", "always", "never"],
                   help="weak actuators: after the evaluation, fit a recovery law to torque plans within the limits and keep it "
                        f"if simulation shows it helps (`idapbc-pin recover`; {RECOVER_TIME}). auto (default): only where "
                        "saturated LQR fails from at least 10 %% of the evaluation's half-box states, or else of its training-box "
                        "states (then the plans start from the training box); skipped with one line after fewer than "
                        f"{SMOKE_EPOCHS} epochs unless given. never: skip it. --recover alone: always")
    p.add_argument("--swing-up", action="store_true", dest="swing_up",
                   help="then fit a swing-up law from the resting posture (a pendulum hanging) to x* within the effort limits, keep it "
                        "if simulation shows it helps, and judge the run from 20 near-resting states beside saturated LQR and the "
                        "energy-pumping law (swingup.json; TrainConfig.swing_up)")
    p.add_argument("--swing-config", metavar="FILE", dest="swing_config",
                   help="the swing-up stage's settings: a TOML file with a [swing_up] table (SwingUpConfig's fields)")
    p.add_argument("--recover-config", metavar="FILE", dest="recover_config",
                   help="the recovery stage's settings: a TOML file with a [recovery] table, as `idapbc-pin recover --config` reads")
    add_ray_argument(p, "the recovery stage (with --recover)")
    p.set_defaults(func=_cmd_train)
