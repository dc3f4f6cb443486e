"""Goal: robots the defaults were never chosen on, judged by MuJoCo against LQR (issue 13's last check).

Writes variants of the zoo URDFs (heavier or lighter links, continuous joints, more joint damping)
into a temporary folder, loads each from its path as a user would (`load_system(path, actuated=…)`,
so the default training box follows the variant's own masses), trains it with every default of the fast preset
(`TrainConfig.fast(seed=…)`) and of `train`'s recovery stage (`--recover auto`: a recovery law where
saturated LQR fails from ≥ 10 of 100 half-box states, a few minutes per robot; `--recover never`:
the law alone) and judges NIDA-PBC and LQR (Q = I, R = I) with MuJoCo from the same
uniform states (their own seed, not the evaluation's seed 0), with the URDF's effort limits on both,
and prints NIDA-PBC's lead with its 95 % interval (`idapbc_pin.evaluation.paired`). With several
training seeds (``--seed 0 1 2``), each variant gets a row per seed and a line with the spread of its
leads (per seed, the least and the median), the same judged states for every seed.
Run: python benchmarks/bench_outside_zoo.py [--n 200] [--seed 0 [1 2]] [--judge-seed 1] [--recover auto|always|never] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import torch

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.evaluation.roa import roa
from idapbc_pin.recovery.trigger import RECOVER_MODES

URDF_DIR = Path(__file__).resolve().parents[1] / "urdf"


@dataclass(frozen=True)
class Variant:
    """A zoo URDF with its links' mass and inertia scaled, and optionally its joints changed."""

    name: str
    urdf: str  #: file in urdf/
    actuated: tuple[str, ...]
    mass_scale: dict[str, float] = field(default_factory=dict)  #: link -> factor on mass and inertia
    continuous: tuple[str, ...] = ()  #: joints turned into continuous joints
    damping: dict[str, float] = field(default_factory=dict)  #: joint -> viscous damping (N·m·s/rad)
    effort: dict[str, float] = field(default_factory=dict)  #: joint -> effort limit written into the URDF (N·m or N)
    target: dict[str, float] = field(default_factory=dict)  #: joint -> target angle, as `train --target`


VARIANTS = (
    Variant("pendubot_heavy", "double_pendulum.urdf", ("shoulder",), {"link1": 1.5, "link2": 1.5}),
    Variant("acrobot_light_elbow", "double_pendulum.urdf", ("elbow",), {"link2": 0.7}),
    Variant("acrobot_continuous_damped", "double_pendulum.urdf", ("elbow",), continuous=("shoulder", "elbow"), damping={"elbow": 0.1}),
    Variant("furuta_other_masses", "furuta.urdf", ("arm",), {"arm": 0.7, "pendulum": 1.5}),
    Variant("cartpole_heavy_pole", "cartpole.urdf", ("slider",), {"pole": 2.0}),
    Variant("pendubot_8nm", "double_pendulum.urdf", ("shoulder",), effort={"shoulder": 8.0}),
    Variant("pendubot_heavy_30nm", "double_pendulum.urdf", ("shoulder",), {"link1": 1.5, "link2": 1.5}, effort={"shoulder": 30.0}),
    Variant("realaigym_pendubot", "realaigym_double_pendulum.urdf", ("shoulder",), target={"shoulder": math.pi}),
    Variant("realaigym_acrobot", "realaigym_double_pendulum.urdf", ("elbow",), target={"shoulder": math.pi}),
    Variant("cart_double_pendulum_heavy_poles", "cart_double_pendulum.urdf", ("slider",), {"pole1": 1.3, "pole2": 1.3}),
    Variant("triple_pendulum_light_tip", "triple_pendulum.urdf", ("shoulder",), {"link3": 0.7}),
)


def write_variant(v: Variant, folder: Path) -> Path:
    """The variant's URDF in `folder`; raises ValueError if a named link or joint is absent."""
    tree = ET.parse(URDF_DIR / v.urdf)
    links = {e.get("name"): e for e in tree.getroot().iter("link")}
    joints = {e.get("name"): e for e in tree.getroot().iter("joint")}
    for name in (*v.mass_scale, *v.continuous, *v.damping, *v.effort):
        if name not in links and name not in joints:
            raise ValueError(f"{v.name}: no link or joint '{name}' in {v.urdf}")
    for name, k in v.mass_scale.items():
        inertial = links[name].find("inertial")
        inertial.find("mass").set("value", repr(k * float(inertial.find("mass").get("value"))))
        inertia = inertial.find("inertia")
        for key, val in inertia.attrib.items():
            inertia.set(key, repr(k * float(val)))
    for name in v.continuous:
        joints[name].set("type", "continuous")
    for name, d in v.damping.items():
        dyn = joints[name].find("dynamics")
        if dyn is None:
            dyn = ET.SubElement(joints[name], "dynamics")
        dyn.set("damping", repr(d))
    for name, e in v.effort.items():
        joints[name].find("limit").set("effort", repr(e))
    path = folder / f"{v.name}.urdf"
    tree.write(path)
    return path


def _lead(res) -> str:
    """NIDA-PBC's lead over LQR on one box in points, with its 95 % interval (`sim.paired`)."""
    c = res.compare("NIDA-PBC", "LQR")
    lo, hi = c.interval
    return f"{100 * c.difference:+.1f}, CI {100 * lo:+.1f} to {100 * hi:+.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200, help="states per box (default 200)")
    parser.add_argument("--seed", type=int, nargs="+", default=[0], help="training seeds (default 0; several: a row per seed and their spread)")
    parser.add_argument("--judge-seed", type=int, default=1, help="seed of the judged states")
    parser.add_argument("--only", nargs="+", default=None, help=f"variants to run (default all: {', '.join(v.name for v in VARIANTS)})")
    parser.add_argument("--recover", choices=RECOVER_MODES, default="auto", help="a recovery law after training, as `train --recover` (default auto, as train's)")
    parser.add_argument("--out", default=None, help="where to write URDFs and runs (default: a temporary folder)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    out = Path(args.out or tempfile.mkdtemp(prefix="bench_outside_zoo_"))
    out.mkdir(parents=True, exist_ok=True)
    chosen = [v for v in VARIANTS if args.only is None or v.name in args.only]
    print(f"cpus={os.cpu_count()} load={os.getloadavg()[0]:.2f} n={args.n} seed={args.seed} judge_seed={args.judge_seed} out={out}")
    print("| variant (seed) | actuated (limit) | half box: NIDA-PBC / LQR (lead, 95 % CI) | domain: NIDA-PBC / LQR (lead, 95 % CI) | median settling, half: NIDA-PBC / LQR | recovery law | training + recover |")
    print("|---|---|---|---|---|---|---|")
    for v in chosen:
        system = ip.load_system(write_variant(v, out), actuated=list(v.actuated), target=v.target or None)
        leads = {"half": [], "domain": []}
        for seed in args.seed:
            t0 = time.perf_counter()
            run = ip.train(system, ip.TrainConfig.fast(seed=seed), out=out / v.name / f"seed{seed}", progress=False)
            ip.recovery.auto_recover(run, args.recover, progress=False)
            seconds = time.perf_counter() - t0
            judge = ip.mujoco_judge(system)
            ctrls = {"NIDA-PBC": run.controller, "LQR": LQRController(system)}
            res = {box: roa(judge, ctrls, n=args.n, box=box, seed=args.judge_seed, limits=True) for box in ("half", "domain")}
            for box, r in res.items():
                leads[box].append(100 * r.compare("NIDA-PBC", "LQR").difference)
            rate = {box: " / ".join(f"{100 * r[k].success_rate:.1f} %" for k in ctrls) + f" ({_lead(r)})" for box, r in res.items()}
            settle = " / ".join(f"{res['half'][k].median_settling_time:.2f} s" for k in ctrls)
            limit = ", ".join(f"{j}={e:g}" for j, e in zip(v.actuated, system.effort))
            print(f"| {v.name} ({seed}) | {limit} | {rate['half']} | {rate['domain']} | {settle} | {'kept' if run.uses_recovery else 'none'} | "
                  f"{seconds:.0f} s |", flush=True)
        if len(args.seed) > 1:
            spread = "; ".join(f"{box}: {', '.join(f'{x:+.1f}' for x in xs)} (least {min(xs):+.1f}, median {sorted(xs)[len(xs) // 2]:+.1f})"
                               for box, xs in leads.items())
            print(f"| {v.name}: lead per seed {', '.join(str(s) for s in args.seed)} | {spread} |||||", flush=True)


if __name__ == "__main__":
    main()
