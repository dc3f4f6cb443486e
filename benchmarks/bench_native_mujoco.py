"""Goal: judge trained runs with MuJoCo's own integrator and a sampled controller, as a robot runs it.

The project's judges (Pinocchio, `ip.mujoco_judge`) sample the law every 2 ms, hold it, and integrate
the plant with RK4. An outside judge using MuJoCo as it ships steps the physics with MuJoCo's own
integrator (semi-implicit Euler by default) and holds the torque for one control period. This script
does that: MuJoCo loads the run's URDF (contacts and joint limits off, as `ip.mujoco_judge` does), the
torque u(x) is computed once per step of `--h` seconds (zero-order hold), clipped at the effort
limits and applied as a generalised force on the actuated joints; `mj_step` advances the state.
Success is DESIGN §4's: over the last 2 s of T = 20 s, every joint within 0.05 of x* (angles
wrapped) and every speed below 0.05. A state whose accelerations MuJoCo flags as unstable (it then
resets that state to its default pose, which is x* for the zoo) counts as a failure.
Run: python benchmarks/bench_native_mujoco.py RUN [RUN ...] [--h 0.002] [--integrator EULER]
     [--n 200] [--box half] [--seed 7]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.sim._mujoco import import_mujoco, joint_addresses, mujoco_model
from idapbc_pin.sim.metrics import SUCCESS_WINDOW, in_target_box
from idapbc_pin.sim.states import uniform_states
from idapbc_pin.sim.trajectory import Trajectory

#: Horizon of DESIGN §4 (s); success is judged over its last `SUCCESS_WINDOW` seconds.
HORIZON = 20.0


def native_success(system, ctrl, x0: np.ndarray, h: float, integrator: str) -> np.ndarray:
    """(N,) bool: success of `ctrl` from the (N, n) states `x0`, stepped by MuJoCo at `h` s with the
    torque held over each step."""
    mj = import_mujoco()
    model = mujoco_model(system.plant.path)
    model.opt.timestep = h
    model.opt.integrator = getattr(mj.mjtIntegrator, f"mjINT_{integrator}")
    qadr, dadr = joint_addresses(model, [j.name for j in system.plant.joints])
    B, effort = np.asarray(system.B, float), np.asarray(system.effort, float)
    datas = [mj.MjData(model) for _ in range(len(x0))]
    q0, v0 = system.split(x0)
    for k, d in enumerate(datas):
        d.qpos[qadr], d.qvel[dadr] = q0[k], v0[k]
        mj.mj_forward(model, d)
    steps, tail = int(round(HORIZON / h)), int(round(SUCCESS_WINDOW / h))
    alive, q_tail, v_tail = np.ones(len(x0), bool), [], []
    for i in range(steps):
        q = np.array([d.qpos[qadr] for d in datas])
        v = np.array([d.qvel[dadr] for d in datas])
        u = np.clip(np.nan_to_num(ctrl(system.state_from(q, v))), -effort, effort)
        tau = u @ B.T  # (N, m) -> (N, nv) generalised forces on the actuated joints
        for k, d in enumerate(datas):
            d.qfrc_applied[dadr] = tau[k]
            mj.mj_step(model, d)
            if d.warning[mj.mjtWarning.mjWARN_BADQACC].number > 0:
                alive[k] = False
        if i >= steps - tail:  # the states at the start of the last `tail` steps
            q_tail.append(q)
            v_tail.append(v)
    q_tail, v_tail = np.stack(q_tail, axis=1), np.stack(v_tail, axis=1)  # (N, tail, nq)
    x_tail = system.state_from(q_tail.reshape(-1, system.nq), v_tail.reshape(-1, system.nq)).reshape(len(x0), tail, system.n)
    tail_traj = Trajectory(t=h * np.arange(steps - tail, steps), x=x_tail, q=q_tail, v=v_tail,
                           u=np.zeros((len(x0), tail, system.m)), diverged=~alive)  # fmt: skip
    return in_target_box(tail_traj, system).all(axis=1) & alive


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run directories (URDF robots)")
    parser.add_argument("--h", type=float, default=0.002, help="MuJoCo step and control period, s (default 0.002, MuJoCo's own default step)")
    parser.add_argument("--integrator", default="EULER", choices=["EULER", "RK4", "IMPLICIT", "IMPLICITFAST"])
    parser.add_argument("--n", type=int, default=200, help="states (default 200)")
    parser.add_argument("--box", default="half", choices=["half", "domain"])
    parser.add_argument("--seed", type=int, default=7, help="seed of the states (default 7, not the evaluation's 0)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"| run | NIDA-PBC | LQR | ({args.n} states of seed {args.seed}, {args.box} box, mj_step {args.integrator} at {args.h * 1e3:g} ms, torque held per step) |")
    print("|---|---|---|---|")
    for path in args.runs:
        run = ip.load_run(path)
        system = run.system
        x0 = uniform_states(system, args.n, args.box, args.seed)
        t0 = time.perf_counter()
        rates = [100 * native_success(system, c, x0, args.h, args.integrator).mean() for c in (run.controller, LQRController(system))]
        print(f"| {system.name} | {rates[0]:.1f} % | {rates[1]:.1f} % | {time.perf_counter() - t0:.0f} s |", flush=True)


if __name__ == "__main__":
    main()
