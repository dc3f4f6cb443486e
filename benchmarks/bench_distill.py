"""Goal: can a state feedback learn what torque plans do under weak actuators, and can the IDA-PBC networks hold it?

`bench_recoverable.py` shows that plans within the effort limits bring almost every half-box state of
a weak pendubot to x*, where saturated LQR and NIDA-PBC bring a quarter. Plans are open loop, one
per state. This benchmark asks whether their torques can be turned into one feedback law u(x):

1. **Labels.** From `--starts` uniform start states (seed `--plan-seed`, never the evaluation's),
   saturated LQR runs first; where it fails, a cross-entropy plan within the limits is searched
   (`idapbc_pin.trajectory.plans`), then LQR. Every start that reaches x* gives labels (x(t), u(t))
   every 10 ms over its first 6 s (`idapbc_pin.recovery.stage.collect_labels`).
2. **A plain feedback** (`control.recovery.RecoveryLaw`: an MLP of wrap(x − x*)/s, two tanh layers
   of `--width`, output ū·tanh(·)) fitted to the labels by least squares (Adam).
   With `--dagger K`, K rounds of DAgger (Ross et al., 2011) follow: the fitted law runs from new
   starts, the states its failures visit are labelled the same way, and the law is refitted on
   all labels. `idapbc-pin recover RUN` runs the same steps and attaches the law to a run.
   (The README's figures were measured when this code lived here: the DAgger starts had seeds
   300 + r, now plan_seed + 300 + r.)
3. **The IDA-PBC networks** of `--run RUN` (optional), trained on the same robot and limits, then
   trained further for `--epochs` epochs on their residual terms plus `--weight` × an imitation
   term: the saturated law's distance to the labels, in units of ū (where a label sits at the
   limit, only the wrong side of the limit counts). The run directory is never written.

Each law is judged like every controller here (T = 20 s, law held every 2 ms, limits applied)
from `--n` states of the evaluation seed, beside saturated LQR on the same states, optionally also on
MuJoCo's dynamics (`--mujoco`).
Run: python benchmarks/bench_distill.py pendubot --effort shoulder=8 [--run RUN] [--starts 240]
     [--workers 2] [--mujoco] [--dagger K] [--labels FILE.npz]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

import idapbc_pin as ip
from idapbc_pin.cli._args import key_value
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.metrics import success
from idapbc_pin.sim.states import uniform_states
from idapbc_pin.training.loss import loss_terms
from idapbc_pin.trajectory.plans import PLAN_STEP as DT
from idapbc_pin.recovery.stage import RecoveryConfig, collect_labels, dagger_round, fit_recovery_law


def imitation(nets, x: torch.Tensor, f: torch.Tensor, u_label: torch.Tensor, effort: torch.Tensor) -> torch.Tensor:
    """Mean squared distance of the networks' law to the labels in units of ū; at a label on the limit
    only the wrong side of the limit counts (the saturated law cannot tell beyond it)."""
    x = x.detach().requires_grad_(True)
    u = nets.control(f, nets.desired(x, create_graph=True)[4]) / effort
    y = u_label / effort
    at_limit = y.abs() > 0.99
    r = torch.where(at_limit, torch.relu(1 - torch.sign(y) * u), u.clamp(-1.5, 1.5) - y)
    return r.pow(2).mean()


def finetune(run, X: np.ndarray, U: np.ndarray, epochs: int, weight: float, seed: int) -> dict:
    """Train `run.nets` further (in memory) on residuals + weight × imitation; returns the last epoch's terms."""
    system, nets, config = run.system, run.nets, run.config
    dtype = getattr(torch, config.dtype)
    Xw = nets.wrap(X)
    Xt, Ut, fX = (torch.as_tensor(a, dtype=dtype) for a in (Xw, U, system.f(Xw)))
    effort = torch.as_tensor(np.array(system.effort), dtype=dtype)
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(nets.parameters(), config.lr)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in system.domain)
    for _ in range(epochs):
        x = lo + (hi - lo) * torch.rand(config.samples, system.n, generator=gen, dtype=torch.float64).numpy()
        xt = torch.as_tensor(x, dtype=dtype)
        with torch.no_grad():
            eps = torch.quantile(nets.H(xt).double(), config.inside_fraction).to(dtype)
            inside = nets.H(xt) < eps
        df_in = torch.as_tensor(system.df_dx(x[inside.numpy()]), dtype=dtype)
        terms, _ = loss_terms(nets, xt, torch.as_tensor(system.f(x), dtype=dtype), eps, config.kappa, df_in, inside)
        idx = torch.randint(0, len(Xt), (1024,), generator=gen)
        terms["imitation"] = imitation(nets, Xt[idx], fX[idx], Ut[idx], effort)
        total = sum(v for k, v in terms.items() if k != "imitation") + weight * terms["imitation"]
        opt.zero_grad()
        total.backward()
        torch.nn.utils.clip_grad_norm_(nets.parameters(), 10.0)
        opt.step()
    return {k: float(v.detach()) for k, v in terms.items() if float(v.detach()) != 0.0}


def _judge(system, laws: dict, x0: np.ndarray) -> dict:
    return {name: float(success(simulate(system, law, x0, T=20.0, dt=DT), system).mean()) for name, law in laws.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", help="zoo name or URDF path")
    parser.add_argument("--effort", type=key_value, action="append", default=[], metavar="JOINT=LIMIT", help="effort limit override, repeatable")
    parser.add_argument("--run", help="a run trained on the same robot and limits: also fine-tune its IDA-PBC networks")
    parser.add_argument("--starts", type=int, default=240, help="start states of the plans (default 240)")
    parser.add_argument("--plan-seed", type=int, default=101, help="seed of the plans' start states (default 101)")
    parser.add_argument("--box", default="half", choices=["half", "domain"], help="box of the plans' and the evaluation's states (default half)")
    parser.add_argument("--n", type=int, default=200, help="evaluation states per seed (default 200)")
    parser.add_argument("--eval-seeds", default="0,7", help="seeds of the evaluation states (default 0,7)")
    parser.add_argument("--width", type=int, default=128, help="MLP width (default 128)")
    parser.add_argument("--steps", type=int, default=4500, help="MLP fitting steps (default 4500)")
    parser.add_argument("--epochs", type=int, default=1500, help="fine-tuning epochs of the run's networks (default 1500)")
    parser.add_argument("--weight", type=float, default=100.0, help="imitation weight in the fine-tuning (default 100)")
    parser.add_argument("--workers", type=int, default=2, help="processes searching plans (default 2)")
    parser.add_argument("--mujoco", action="store_true", help="also judge on MuJoCo's dynamics")
    parser.add_argument("--dagger", type=int, default=0, help="rounds of DAgger after the first fit (default 0)")
    parser.add_argument("--dagger-starts", type=int, default=30, help="half-box starts of the MLP per DAgger round (default 30)")
    parser.add_argument("--labels", help="an .npz of labels: read it if it exists (no plans searched), else write the new labels there")
    args = parser.parse_args()
    torch.set_num_threads(1)
    effort = dict(args.effort) or None
    try:
        system = ip.load_system(args.source, effort=effort)
        run = ip.load_run(args.run) if args.run else None
    except ip.IdapbcError as exc:
        parser.error(str(exc))
    if not np.isfinite(system.effort).all():
        parser.error(f"{system.name} has an actuated joint without an effort limit; plans need one. Fix: pass --effort JOINT=LIMIT.")
    if run is not None and not np.allclose(run.system.effort, system.effort):
        parser.error(f"the run was trained with effort {list(run.system.effort)}, not {list(system.effort)}. Fix: give the run's limits with --effort.")

    start = time.perf_counter()
    config = RecoveryConfig(starts=args.starts, plan_seed=args.plan_seed, dagger=args.dagger, dagger_starts=args.dagger_starts,
                            width=args.width, steps=args.steps, workers=args.workers)  # fmt: skip
    if args.labels and Path(args.labels).is_file():
        with np.load(args.labels) as saved:
            X, U, lqr_ok, recovered, args.starts = saved["X"], saved["U"], int(saved["lqr_ok"]), int(saved["recovered"]), int(saved["starts"])
        print(f"labels read from {args.labels} (its --starts and --plan-seed apply)")
    else:
        X, U, lqr_ok, recovered = collect_labels(system, uniform_states(system, args.starts, args.box, args.plan_seed), args.plan_seed, config, True)
        if args.labels:
            np.savez(args.labels, X=X, U=U, lqr_ok=lqr_ok, recovered=recovered, starts=args.starts)
    print(f"labels: saturated LQR reaches x* from {lqr_ok} of {args.starts} starts, plans from {recovered} of the other {args.starts - lqr_ok}; {len(X)} labels [{time.perf_counter() - start:.0f} s]")

    law, mse = fit_recovery_law(system, X, U, args.width, args.steps)
    print(f"MLP fitted: mean squared error {mse:.4f} (u/ū) [{time.perf_counter() - start:.0f} s]")
    for r in range(args.dagger):
        law, X, U, _ = dagger_round(system, law, X, U, r, config, True, start)
    laws = {"saturated LQR": LQRController(system), "distilled MLP": law.law}
    if run is not None:
        laws["NIDA-PBC (run)"] = ip.load_run(args.run).controller
        terms = finetune(run, X, U, args.epochs, args.weight, seed=0)
        print("IDA-PBC networks fine-tuned, last epoch: " + ", ".join(f"{k} {v:.3g}" for k, v in terms.items()) + f" [{time.perf_counter() - start:.0f} s]")
        laws["NIDA-PBC + imitation"] = run.controller
    judges = {"our judge": system} | ({"MuJoCo's dynamics": ip.mujoco_judge(system)} if args.mujoco else {})
    for seed in (int(s) for s in args.eval_seeds.split(",")):
        x_eval = uniform_states(system, args.n, args.box, seed)
        for judge_name, judge in judges.items():
            rates = _judge(judge, laws, x_eval)
            print(f"{args.box} box, {args.n} states of seed {seed}, {judge_name}: " + ", ".join(f"{k} {100 * v:.1f} %" for k, v in rates.items()), flush=True)
    print(f"total {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
