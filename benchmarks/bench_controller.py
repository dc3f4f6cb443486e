"""Goal: latency of the control law for one state (what a robot's control loop calls), per artifact,
and the cost of the law in simulation (what `idapbc-pin simulate --n N` spends on its rollouts).

* `ctrl.torque(q, v)` in the library, fast and paper network sizes (target, issue #3: ≤ 1 ms);
* the exported standalone `controller.torque(q, v)` (numpy + Pinocchio, `idapbc-pin export`) and
  the exported `desired_flow.onnx` (f̃_d only) under onnxruntime on one thread, fast preset
  (target, issue #14: ≤ 0.2 ms for the standalone torque);
* the same standalone torque for a run that keeps a recovery law with a level set of H_d (the
  switch evaluates H_d on top of the law: the state is outside the inner box and inside {H_d ≤ c},
  its slowest branch), where every actuated joint has a finite effort limit.
* with ``--states N``, instead: a run's NIDA-PBC rollouts against LQR's from the same N uniform
  states of the training box, on the judge's step, one thread each (as `simulate`'s workers run):
  CPU seconds of `simulate` for each law (what a busy machine does not inflate) and their ratio
  (target: NIDA-PBC ≤ 2 × LQR). The plant is the same for both, so the difference is the control
  law's own cost per step.

Latency does not depend on the weights' values: the library rows use freshly initialised networks,
the exported rows a run trained for one epoch (its recovery law fitted for one step to random labels).
Rollouts do (a state that diverges is frozen and costs nothing after): they use a trained run,
by default the committed pendubot fixture ``tests/data/reference_run``. Prints median and 99th
percentile latencies; rollout seconds are the least of `--rounds` alternating rounds.
Run: python benchmarks/bench_controller.py [names ...] [--repeat N]
     python benchmarks/bench_controller.py --states 1000 [--T 2] [--run RUN] [--rounds 2]
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from threadpoolctl import threadpool_limits

import idapbc_pin as ip
from idapbc_pin.config import TrainConfig
from idapbc_pin.control.controller import Controller
from idapbc_pin.control.nets import build_nets
from idapbc_pin.recovery.stage import RecoveryConfig, fit_recovery_law
from idapbc_pin.recovery.gate import save_recovery
from idapbc_pin.sim.states import uniform_states
from idapbc_pin.sim.step import horizon, judge_step

#: The committed pendubot run the rollout rows use unless --run names another.
REFERENCE_RUN = Path(__file__).resolve().parents[1] / "tests" / "data" / "reference_run"


def latency(fn, repeat: int) -> np.ndarray:
    """Seconds per call of fn(), `repeat` calls after 20 warm-up calls."""
    for _ in range(20):
        fn()
    times = np.empty(repeat)
    for k in range(repeat):
        t0 = time.perf_counter()
        fn()
        times[k] = time.perf_counter() - t0
    return times


def _row(name: str, what: str, t: np.ndarray) -> str:
    return f"{name:<24}{what:<22}{np.median(t) * 1e3:>10.3f}{np.quantile(t, 0.99) * 1e3:>10.3f}"


def _load_exported(folder: Path):
    """The exported controller.py as a module (by path, as a robot's code would load it)."""
    spec = importlib.util.spec_from_file_location(f"exported_{folder.name}", folder / "controller.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def exported_rows(system, q: np.ndarray, v: np.ndarray, repeat: int, tmp: Path) -> list[str]:
    """Standalone torque and ONNX f̃_d latency of a fast-preset run trained for one epoch."""
    if not (system.source.endswith(".urdf") and Path(system.source).is_file()):
        return [f"{system.name:<24}(built-in system: no URDF, nothing to export)"]
    run = ip.train(system, TrainConfig.fast(epochs=1), out=tmp / "runs", progress=False)
    folder = ip.export(run, tmp / system.name)
    standalone = _load_exported(folder)
    rows = [_row(system.name, "export: controller.py", latency(lambda: standalone.torque(q, v), repeat))]
    try:
        import onnxruntime as ort
    except ImportError:
        return rows + [f"{system.name:<24}export: ONNX          (onnxruntime not installed: pip install 'idapbc-pin[export]')"]
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    session = ort.InferenceSession(str(folder / "desired_flow.onnx"), options)
    x = system.state_from(q, v)[None].astype(run.config.dtype)
    rows.append(_row(system.name, "export: ONNX f_d", latency(lambda: session.run(None, {"x": x}), repeat)))
    return rows + level_rows(run, q, v, repeat, tmp)


def level_rows(run, q: np.ndarray, v: np.ndarray, repeat: int, tmp: Path) -> list[str]:
    """Standalone torque latency of `run` given a recovery law that acts where H_d(x) > c, with c
    twice H_d at the timed state: the switch evaluates H_d, then the IDA-PBC law acts."""
    system = run.system
    if not np.all(np.isfinite(system.effort)):
        return []
    rng = np.random.default_rng(0)
    X, U = rng.uniform(*system.domain, size=(64, system.n)), rng.uniform(-1, 1, (64, system.m)) * system.effort
    law, _ = fit_recovery_law(system, X, U, RecoveryConfig().width, steps=1)
    x = system.state_from(q, v)[None]
    c = 2.0 * float(run.own_controller.flow().energy(run.own_controller.nets.wrap(x))[0])
    save_recovery(run, law, {"used": True, "inner_scale": 0.0, "level": c})
    standalone = _load_exported(ip.export(run, tmp / f"{system.name}-level", onnx=False))
    return [_row(system.name, "export: + level law", latency(lambda: standalone.torque(q, v), repeat))]


def rollout_rows(run_dir: Path, n: int, T: float, rounds: int) -> list[str]:
    """CPU seconds of `simulate` for the run's controller and for LQR from the same `n` uniform states of
    the training box over `T` s, the faster of `rounds` alternating rounds, and their ratio."""
    with tempfile.TemporaryDirectory() as tmp:  # a copy: loading may write into the run directory
        run = ip.load_run(Path(shutil.copytree(run_dir, Path(tmp) / "run")))
        system, nida = run.system, run.controller
    laws = {"NIDA-PBC": nida, "LQR": ip.LQRController(system)}
    dt = judge_step(system, laws, T)
    T = horizon(T, dt)
    x0 = uniform_states(system, n, seed=0)
    seconds, diverged = {name: np.inf for name in laws}, {}
    for _ in range(rounds):
        for name, law in laws.items():
            t0 = time.process_time()
            traj = ip.simulate(system, law, x0, T=T, dt=dt)
            seconds[name] = min(seconds[name], time.process_time() - t0)
            diverged[name] = int(traj.diverged.sum())
    steps = int(round(T / dt))
    rows = [f"{system.name}: {n} states, T = {T:g} s, {steps} steps of {dt * 1e3:g} ms",
            f"{'law':<12}{'CPU s':>10}{'µs/state/step':>15}{'diverged':>10}"]
    rows += [f"{name:<12}{s:>10.2f}{s / (n * steps) * 1e6:>15.2f}{diverged[name]:>10}" for name, s in seconds.items()]
    return rows + [f"NIDA-PBC / LQR: {seconds['NIDA-PBC'] / seconds['LQR']:.2f}"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=["acrobot", "cartpole", "cart_double_pendulum", "paper_cartpole"])
    parser.add_argument("--repeat", type=int, default=2000)
    parser.add_argument("--states", type=int, default=0, help="time NIDA-PBC's rollouts against LQR's from this many states instead")
    parser.add_argument("--T", type=float, default=2.0, help="rollout horizon, s (simulate's default is 20)")
    parser.add_argument("--run", type=Path, default=REFERENCE_RUN, help="the trained run whose controller the rollouts use")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.states > 0:
        with threadpool_limits(1):  # one BLAS thread, as in simulate's worker processes
            print("\n".join(rollout_rows(args.run, args.states, args.T, args.rounds)))
        return
    print(f"{'system':<24}{'artifact':<22}{'median ms':>10}{'p99 ms':>10}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.names:
            system = ip.load_system(name)
            q, v = system.x_star[: system.nq] + 0.1, np.full(system.nq, 0.2)
            for preset, config in (("fast", TrainConfig.fast()), ("paper", TrainConfig())):
                torch.manual_seed(0)
                ctrl = Controller(system, build_nets(system, config))
                print(_row(name, f"ctrl.torque ({preset})", latency(lambda: ctrl.torque(q, v), args.repeat)))
            for row in exported_rows(system, q, v, args.repeat, Path(tmp)):
                print(row)


if __name__ == "__main__":
    main()
