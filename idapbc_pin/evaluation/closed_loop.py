"""`simulate_run`: a run's controller next to LQR from the same states, under optional conditions
(mismatch of the judge plant, saturation, measurement noise), with the actuators' effort limits
applied to both unless lifted, judged by Pinocchio or (``judge="mujoco"``) by MuJoCo; the
``idapbc-pin simulate`` command.

Writes ``simulation.json`` (settings, scores and both ROA radii under the same conditions) into the
run directory; `idapbc_pin.reporting.simulation_figure` draws ``simulation.png`` from the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from .._io import write_json
from .._parallel import process_map
from ..control.baseline import LQRController
from ..errors import IdapbcError
from ..run import resolve_run
from ..sim.limits import input_limits
from ..sim.mujoco_plant import mujoco_judge
from ..sim.states import evaluation_box, initial_states, uniform_states
from ..sim.step import horizon, judge_step
from ..sim.trajectory import Trajectory
from .radius import RadiusResult, roa_radius
from .roa import RoaResult, score
from .robustness import MeasuredController, parse_mismatch, perturbed_system

__all__ = ["JUDGES", "SimulationResult", "simulate_run"]

#: Engines that can integrate the true plant: Pinocchio (the system's own plant) or MuJoCo.
JUDGES = ("pinocchio", "mujoco")


@dataclass(frozen=True, eq=False)
class SimulationResult:
    """`simulate_run`'s outcome: the scores side by side and where things were written."""

    roa: object  #: `RoaResult` (NIDA-PBC, LQR)
    settings: dict
    json_path: Path | None
    radius: RadiusResult | None = None  #: both ROA radii under the same conditions (None: skipped)
    controller: object = None  #: the Neural IDA-PBC law simulated (with its extra damping)
    trajectory: Trajectory | None = None  #: its rollouts, (N, ...) per field
    label: str = ""  #: the system and the conditions, for a figure's title

    def table(self) -> str:
        s = self.settings
        conds = [f"{k}={v:g}" for k, v in (s.get("mismatch") or {}).items()]
        if s.get("saturation") is not None:
            conds.append(f"|u| ≤ {s['saturation']:g}")
        if s.get("noise"):
            conds.append(f"noise σ = {s['noise']:g}")
        lines = [self.roa.table(), f"judge: {s.get('judge', 'pinocchio')}"]
        if self.radius is not None:
            lines.append(self.radius.line())
        if conds:
            lines.append("conditions: " + ", ".join(conds))
        if self.json_path is not None:
            lines.append(f"wrote {self.json_path}")
        return "\n".join(lines)


def _score_job(job):
    """Worker: `idapbc_pin.evaluation.roa.score` of one controller and its rollouts, for
    job = (system, name, ctrl, x0, T, dt, saturation, limits)."""
    system, name, ctrl, x0, T, dt, saturation, limits = job
    return score(system, name, ctrl, x0, T, dt, saturation=saturation, limits=limits)


def _scores(system, controllers, x0, T, dt, saturation, limits, box_name, box, seed, workers: int = 1):
    """Every controller from x0 on the judge `system`, scored by `idapbc_pin.evaluation.roa.score`, side by
    side in `workers` processes (`idapbc_pin._parallel.process_map`; each controller's batch whole, so
    the count changes the time, never a score); -> (RoaResult, {name: Trajectory})."""
    jobs = [(system, name, ctrl, x0, T, dt, saturation, limits) for name, ctrl in controllers.items()]
    scores, trajs = {}, {}
    for name, (scored, traj) in zip(controllers, process_map(_score_job, jobs, workers)):
        scores[name], trajs[name] = scored, traj
    res = RoaResult(system=system.name, box=box, box_name=box_name, x0=x0, T=float(T), dt=float(dt), seed=int(seed), scores=scores,
                    limits=input_limits(system, limits, saturation))
    return res, trajs


def _start_states(system, n, x0, box: str, seed: int):
    """(x0 (N, n), box name, (lo, hi)): `n` uniform states of `box`, or the given `x0` ("custom")."""
    if box not in ("domain", "half"):
        raise IdapbcError(f"box must be 'domain' or 'half', got {box!r}.")
    if x0 is None:
        if int(n) < 1:
            raise IdapbcError(f"n must be at least 1, got {n}. Fix: --n 100.")
        return uniform_states(system, int(n), box, seed), box, evaluation_box(system, box)
    x0 = initial_states(system, x0, 0, seed)
    return x0, "custom", (x0.min(axis=0), x0.max(axis=0))


def _judged(nominal, judge: str, scales: dict):
    """The true plant: `nominal`, or its MuJoCo twin (`mujoco_judge`), then scaled by `scales`."""
    if judge not in JUDGES:
        raise IdapbcError(f"judge must be one of {', '.join(JUDGES)}, got {judge!r}. Fix: --judge pinocchio or --judge mujoco.")
    truth = mujoco_judge(nominal) if judge == "mujoco" else nominal
    return perturbed_system(truth, **scales) if scales else truth


def _check_conditions(saturation, noise, rho) -> None:
    if saturation is not None and not (math.isfinite(saturation) and saturation > 0):
        raise IdapbcError(f"saturation must be a positive max |u|, got {saturation}. Fix: e.g. --saturation 20.")
    if not (math.isfinite(noise) and noise >= 0):
        raise IdapbcError(f"noise must be ≥ 0, got {noise}. Fix: e.g. --noise 0.01.")
    if rho is not None and not (math.isfinite(rho) and rho >= 0):
        raise IdapbcError(f"ρ must be finite and ≥ 0, got {rho}. Fix: e.g. --rho 1.")


def _write(run, res: RoaResult, settings: dict, x0, radius: RadiusResult | None) -> Path:
    """simulation.json (settings, scores, radii, x0) in the run directory; -> its path."""
    record = dict(settings)
    if radius is not None:
        record["radius"], record["radius_search"] = dict(radius.radius), radius.to_dict()
    for name, s in res.scores.items():
        record[name] = {
            "success_rate": s.success_rate, "median_settling_time": s.median_settling_time, "median_offset": s.median_offset,
            "median_peak_input": s.median_peak_input, "diverged": s.n_diverged, "wall_time": s.wall_time,
            "success": s.success.tolist(), "settling_time": s.settling_time.tolist(),
        }
    record["x0"] = x0.tolist()
    return write_json(run.path / "simulation.json", record, sort_keys=False)


def _label(run, res: RoaResult, settings: dict, nida) -> str:
    """The system, ρ and the conditions, as a figure's title."""
    scales, noise = settings["mismatch"], settings["noise"]
    bound = res.limits.bound_text() if res.limits is not None else ""
    conds = ", ".join([f"{a}×{b:g}" for a, b in scales.items()] + ([f"|u|≤{bound}"] if bound else []) + ([f"σ={noise:g}"] if noise else []))
    return f"{run.system.name}, ρ = {nida.rho:g}" + (f", {conds}" if conds else "")


def simulate_run(
    run,
    n: int = 100,
    T: float = 20.0,
    dt: float | None = None,
    x0=None,
    *,
    rho: float | None = None,
    mismatch=None,
    saturation: float | None = None,
    noise: float = 0.0,
    seed: int = 0,
    box: str = "domain",
    write: bool = True,
    limits: bool = True,
    radius: bool = True,
    judge: str = "pinocchio",
    workers: int = 1,
) -> SimulationResult:
    """Closed loop of a run's controller next to LQR from the same states, under optional conditions.

    Writes ``simulation.json`` (settings, scores and radii) into the run directory (`write`); the
    result carries Neural IDA-PBC's rollouts for `idapbc_pin.reporting.simulation_figure`.

    Parameters
    ----------
    run : a `Run` or a run directory.
    n : uniform states of `box` ("domain" or "half"), seed `seed`; or `x0` (N, n) / (N, nq).
    T, dt : horizon and RK4 step (the control period), s (dt None: 2 ms, or shorter where either loop is stiffer at x*,
        `judge_step` on the judge plant).
    rho : extra damping ρ for Neural IDA-PBC.
    mismatch : {kind: scale} or "mass=1.2,..." for the judge plant (`perturbed_system`).
    saturation : max |u| per input (with the effort limits: the smaller bound applies).
    noise : σ of the (q, v) measurement noise.
    limits : apply the system's effort limits to both controllers (False lifts them).
    radius : also find both ROA radii under the same conditions, `n` states per scale (the
        rollouts from the domain or half box reused); False skips them, and so does a given `x0`.
    judge : ``"pinocchio"`` (the system's plant) or ``"mujoco"`` (`mujoco_judge`: MuJoCo loads the
        same URDF; no mismatch, and no built-in analytic systems).
    workers : processes simulating the two controllers side by side, for the scores and the radii
        (1: in this process, 0: one per core); the count changes the time, never a figure.
    """
    run = resolve_run(run)
    nominal = run.system
    _check_conditions(saturation, noise, rho)
    scales = parse_mismatch(mismatch)
    plant = _judged(nominal, judge, scales)
    nida = run.controller if rho is None else run.controller.with_damping(rho)
    laws = {"NIDA-PBC": nida, "LQR": LQRController(nominal)}
    dt = judge_step(plant, laws, T, dt)  # the noise-free laws
    T = horizon(T, dt)
    x0, box_name, bounds = _start_states(nominal, n, x0, box, seed)
    wrap = plant is not nominal or noise > 0
    controllers = {
        name: MeasuredController(law, plant=plant, model=nominal, noise=noise, seed=seed) if wrap else law for name, law in laws.items()
    }
    res, trajs = _scores(plant, controllers, x0, T, dt, saturation, limits, box_name, bounds, seed, workers)
    found = None
    if radius and box_name != "custom":  # random states of a box, not given ones
        known = {1.0: res} if box_name == "domain" else {0.5: res}
        found = roa_radius(plant, controllers, n=int(n), seed=seed, T=T, dt=dt, known=known, saturation=saturation, limits=limits,
                           workers=workers)
    settings = {"n": int(x0.shape[0]), "T": T, "dt": dt, "hold": res.hold, "seed": seed, "box": box_name, "rho": float(nida.rho),
                "mismatch": scales, "saturation": saturation, "noise": noise, "limits": res.limits.to_json(), "judge": judge}
    json_path = _write(run, res, settings, x0, found) if write else None
    return SimulationResult(res, settings, json_path, found, nida, trajs["NIDA-PBC"], _label(run, res, settings, nida))
