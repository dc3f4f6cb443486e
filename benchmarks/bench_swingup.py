"""Goal: swing-up from hanging under the URDF's torque limits (DESIGN §4): saturated LQR, the energy pump, runs.

For each robot, `evaluate_swingup` judges saturated LQR (Q = I, R = I) and the classical
energy-pumping law with an LQR catch (`EnergyPumpLaw`) from the same start states (the first exactly
hanging, the others ±0.1 rad and ±0.1 rad/s), T s at 500 Hz with the effort limits, and prints both
verdicts (holds, tip test) and the RealAIGym v2 score of the hanging start. Each ``--run RUN``
directory adds a table for its own system with its controller beside the two references. With
``--train``, each robot is first trained as a user would, ``idapbc-pin train ROBOT --fast --swing-up``
(the default path: training, the box evaluation, the recovery stage where the limits bind, the
swing-up stage), timed, and its run is judged beside the references. The RealAIGym rows carry the
leaderboard's published figures as a quoted line. ``--starts hanging circle anywhere moving`` adds
tables from states at rest with every angle drawn from the full circle, from anywhere on the torus
with speeds (the first again exactly hanging), and from moving states with every joint's speed up to
its URDF rating; ``--uptime`` adds the global policy test (the RealAIGym simulation v3 uptime: 60-s
episodes with 15 resets) of the state feedbacks, twice: with the leaderboard's own reset, a 0.2-s
PID drive towards a random posture that releases the robot moving (`evaluation.uptime`), and with
each reset putting the robot at the posture at rest; each with the laws' peak speed over the ratings.
Run: python benchmarks/bench_swingup.py [--n 20] [--T 10] [--only [NAME ...]] [--run RUN ...] [--train] [--workers 1]
         [--starts hanging circle anywhere moving] [--uptime [E]]
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.control.energy_pump import EnergyPumpLaw
from idapbc_pin.evaluation.swingup import STARTS, evaluate_swingup
from idapbc_pin.evaluation.uptime import DRIVE_T, UPTIME_EPISODES, uptime_test

URDF_DIR = Path(__file__).resolve().parents[1] / "urdf"

#: name -> (zoo name, or the RealAIGym URDF with its actuated joint)
ROBOTS = {
    "pendubot": ("pendubot", None),
    "acrobot": ("acrobot", None),
    "cartpole": ("cartpole", None),
    "furuta": ("furuta", None),
    "reaction_wheel": ("reaction_wheel", None),
    "realaigym_pendubot": ("realaigym_double_pendulum.urdf", "shoulder"),
    "realaigym_acrobot": ("realaigym_double_pendulum.urdf", "elbow"),
}

#: The leaderboard's published figures (simulation leaderboard v2, design C.1, |τ| ≤ 6 N·m, 10 s).
PUBLISHED = {
    "realaigym_pendubot": "best 0.682 (swing-up 1.15 s), TVLQR 0.526 (4.13 s)",
    "realaigym_acrobot": "best 0.655 (swing-up 1.0 s), TVLQR 0.504 (4.05 s)",
}
SOURCE = "github dfki-ric-underactuated-lab/real_ai_gym_leaderboard, simulation leaderboard v2"
#: The global policy leaderboard's best uptimes (simulation v3, the ICRA 2025 competition).
PUBLISHED_UPTIME = {"realaigym_pendubot": "best uptime 0.799 (VIMPPI)", "realaigym_acrobot": "best uptime 0.658 (AR-EAPO)"}
SOURCE_V3 = "github dfki-ric-underactuated-lab/double_pendulum, leaderboard simulation_v3"


def name_of(title: str) -> str:
    """The robot name a table's title starts with."""
    return title.split(" ")[0].split(",")[0]


def load(name: str):
    """The `System` of a robot of `ROBOTS`."""
    source, actuated = ROBOTS[name]
    if actuated is None:
        return ip.load_system(source)
    return ip.load_system(str(URDF_DIR / source), actuated=[actuated], target={"shoulder": math.pi})


def train_command(name: str, out: str, seed: int) -> list[str]:
    """`idapbc-pin train … --fast --swing-up` for a robot of `ROBOTS` (the RealAIGym q = 0 hangs: target shoulder = π)."""
    source, actuated = ROBOTS[name]
    cmd = [sys.executable, "-m", "idapbc_pin.cli", "train"]
    cmd += [source] if actuated is None else [str(URDF_DIR / source), "--actuated", actuated, "--target", f"shoulder={math.pi!r}"]
    return cmd + ["--fast", "--swing-up", "--seed", str(seed), "--out", out]


def trained_run(name: str, out: str, seed: int):
    """Train `name` through the default path with --swing-up; -> (its `Run`, wall time s, the stage's gate, manoeuvre and library lines)."""
    t0 = time.perf_counter()
    done = subprocess.run(train_command(name, out, seed), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"training {name} failed:\n{done.stderr[-2000:]}")
    lines = done.stdout.splitlines()
    gate = "; ".join(next((line for line in lines if line.startswith(head)), f"{head}: none") for head in ("swing-up gate", "swing-up manoeuvre", "swing-up library"))
    (path,) = [p for p in Path(out).iterdir() if p.is_dir()]
    return ip.load_run(path), wall, gate


def report(title: str, system, controllers: dict, args, published: str | None = None, run=None) -> None:
    """Evaluate and print one table per start set of `--starts`; from near hanging also the
    swing-up manoeuvre `run` keeps, if any (a fresh one per table: it counts its own time)."""
    limit = ", ".join(f"{j}={e:g}" for j, e in zip(system.actuated, system.effort))
    for starts in args.starts:
        t0 = time.perf_counter()
        laws = dict(controllers)
        if run is not None and run.manoeuvre is not None and starts == "hanging":
            laws["NIDA-PBC manoeuvre (then the run's law)"] = run.manoeuvre.law(run.controller)
        result = evaluate_swingup(system, laws, n=args.n, T=args.T, seed=args.seed, workers=args.workers, starts=starts)
        where = {"hanging": "near hanging", "circle": "at rest, angles from the full circle",
                 "anywhere": "anywhere on the torus, angles from the full circle and speeds U(-1, 1) rad/s",
                 "moving": "moving, angles from the full circle and every speed up to its joint's URDF rating"}[starts]
        print(f"\n### {title}, from {where} (actuated {limit}; {time.perf_counter() - t0:.1f} s)\n")
        print(result.table())
    if args.uptime:  # state feedbacks only: a manoeuvre's clock means nothing after a reset
        for reset, how in (("drive", f"each a {DRIVE_T:g}-s PID drive towards a posture, released moving, as the leaderboard's own test"),
                           ("put", "to postures at rest from the full circle")):
            t0 = time.perf_counter()
            result = uptime_test(system, controllers, episodes=args.uptime, seed=args.seed, workers=args.workers, reset=reset)
            print(f"\n### {title}, the global policy test: {args.uptime} episodes of 60 s, 15 resets {how} "
                  f"({time.perf_counter() - t0:.1f} s)\n")
            print(result.table())
    if published:
        print(f'\n> RealAIGym leaderboard, published: {published} — "{SOURCE}"')
    if args.uptime and name_of(title) in PUBLISHED_UPTIME:
        print(f'\n> RealAIGym global policy leaderboard (simulation v3), published: {PUBLISHED_UPTIME[name_of(title)]} — "{SOURCE_V3}"')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20, help="start states per robot (default 20)")
    parser.add_argument("--T", type=float, default=10.0, help="horizon, s (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the start states")
    parser.add_argument("--starts", nargs="+", choices=STARTS, default=["hanging"],
                        help="start sets: hanging (near-resting, default) and/or circle (at rest, every angle from the full circle)")
    parser.add_argument("--uptime", type=int, nargs="?", const=UPTIME_EPISODES, default=0, metavar="E",
                        help=f"also the global policy test: E episodes of 60 s with 15 resets (default E {UPTIME_EPISODES}); state feedbacks only")
    parser.add_argument("--only", nargs="*", default=None, help=f"robots to run (default all: {', '.join(ROBOTS)}; `--only` alone: none, for --run)")
    parser.add_argument("--run", nargs="+", default=[], help="run directories judged on their own systems")
    parser.add_argument("--workers", type=int, default=1, help="worker processes (0: one per core)")
    parser.add_argument("--train", action="store_true", help="train each robot with `idapbc-pin train --fast --swing-up` and judge its run too")
    parser.add_argument("--train-seed", type=int, default=0, help="training seed with --train")
    args = parser.parse_args()
    torch.set_num_threads(1)
    unknown = [name for name in args.only or () if name not in ROBOTS]
    if unknown:
        parser.error(f"unknown robot(s) {', '.join(unknown)}; valid: {', '.join(ROBOTS)}")
    print(f"cpus={os.cpu_count()} load={os.getloadavg()[0]:.2f} n={args.n} T={args.T} seed={args.seed} (RK4 at 2 ms, law held: 500 Hz; effort limits on)")
    for name in args.only if args.only is not None else ROBOTS:
        system = load(name)
        ctrls = {"LQR (saturated)": LQRController(system), "energy pump + LQR": EnergyPumpLaw(system)}
        if args.train:
            with tempfile.TemporaryDirectory() as out:
                run, wall, gate = trained_run(name, out, args.train_seed)
                ctrls["NIDA-PBC (train --fast --swing-up)"] = run.controller
                print(f"\n{name}: `idapbc-pin train --fast --swing-up` took {wall:.0f} s; {gate}")
                report(name, run.system, ctrls, args, PUBLISHED.get(name), run)
            continue
        report(name, system, ctrls, args, PUBLISHED.get(name))
    for path in args.run:
        run = ip.load_run(path)
        system = run.system
        ctrls = {"LQR (saturated)": LQRController(system), "energy pump + LQR": EnergyPumpLaw(system), f"run {Path(path).name}": run.controller}
        report(f"run {path} ({system.name})", system, ctrls, args, run=run)


if __name__ == "__main__":
    main()
