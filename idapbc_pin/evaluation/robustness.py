"""Robustness of a controller: model mismatch of the judge plant, measurement noise, saturation.

The controller keeps its nominal model (the one it was trained on); only the *judge* changes:

    plant = perturbed_system(run.system, mass=1.2)          # links 20 % heavier
    ctrl = MeasuredController(run.controller, plant=plant)   # sees (q, v) of the true plant
    traj = simulate(plant, ctrl, x0)                         # the true (perturbed) plant integrates

* `perturbed_system` scales the judge plant: link masses (mass and rotational inertia together),
  lengths (joint placements and centre-of-mass levers; rotational inertia ∝ length² at fixed
  mass) or joint damping. URDF robots get a modified copy of the Pinocchio model; the paper's
  analytic systems get their closed-form parameters scaled the same way (M_ij ∝ mass·length^(aᵢ+aⱼ)
  with aᵢ = 1 for angles and 0 for prismatic coordinates, U ∝ mass·length).
* `MeasuredController` models the sensor: it takes the true state x = (q, M_true(q) v), measures
  (q, v) (plus Gaussian noise, seeded), and gives the controller x = (q, M_nominal(q) v), the
  momentum the controller's own model computes from the measurement.
* Saturation is `simulate`'s ``saturation`` argument; the actuators' effort limits apply in every
  row unless lifted (``limits=False``), the smaller bound winning where both are given.

`robustness_table` runs Neural IDA-PBC and the LQR baseline side by side from the same uniform
states under: nominal, link mass ×(1 ± 20 %), torque saturation and measurement noise.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from .._io import finite_or_none, write_json
from ..control.baseline import LQRController
from ..errors import IdapbcError
from ..run import resolve_run
from ..sim.limits import InputLimits, input_limits
from ..sim.step import judge_step
from .roa import roa

__all__ = [
    "MISMATCH_KINDS",
    "Condition",
    "MeasuredController",
    "RobustnessResult",
    "default_conditions",
    "parse_mismatch",
    "perturbed_system",
    "robustness_table",
]

#: What `perturbed_system` can scale.
MISMATCH_KINDS = ("mass", "length", "damping")


# ====================================================================== perturbed plants
def parse_mismatch(spec) -> dict[str, float]:
    """``"mass=1.2"``, ``"mass=1.2,length=0.9"``, a list of those, or a mapping -> {kind: scale}.

    Raises `IdapbcError` for an unknown kind or a scale that is not a finite number > 0 (≥ 0 for
    damping).
    """
    if spec is None:
        return {}
    items: list[tuple[str, object]] = []
    if isinstance(spec, Mapping):
        items = list(spec.items())
    else:
        texts = [spec] if isinstance(spec, str) else list(spec)
        for text in texts:
            for part in str(text).split(","):
                part = part.strip()
                if not part:
                    continue
                name, sep, value = part.partition("=")
                if not sep:
                    raise IdapbcError(f"mismatch '{part}' is not KIND=SCALE. Fix: write e.g. mass=1.2 (kinds: {', '.join(MISMATCH_KINDS)}).")
                items.append((name.strip(), value.strip()))
    out: dict[str, float] = {}
    for name, value in items:
        if name not in MISMATCH_KINDS:
            raise IdapbcError(f"unknown mismatch kind '{name}'. Fix: use one of {', '.join(MISMATCH_KINDS)} (e.g. mass=1.2).")
        try:
            scale = float(value)
        except (TypeError, ValueError):
            raise IdapbcError(f"mismatch scale '{value}' for {name} is not a number. Fix: write e.g. {name}=1.2.") from None
        low_ok = scale >= 0 if name == "damping" else scale > 0
        if not (math.isfinite(scale) and low_ok):
            raise IdapbcError(f"mismatch scale {name}={value} must be a finite number {'≥' if name == 'damping' else '>'} 0. Fix: e.g. {name}=1.2.")
        out[name] = scale
    return out


def perturbed_system(system, mass: float = 1.0, length: float = 1.0, damping: float = 1.0):
    """A copy of `system` whose plant (the judge) has scaled masses, lengths or damping.

    Parameters
    ----------
    system : `System`.
    mass : every link's mass and rotational inertia × mass (M(q) and U(q) scale by exactly this).
    length : joint placements and centre-of-mass levers × length, rotational inertia × length²
        (geometric similarity at fixed mass).
    damping : joint damping × damping (an error if the plant has none).

    Returns
    -------
    `System` with the same name, actuation, target and domain and the perturbed plant; pass it
    to `simulate` with the nominal controller (wrapped in `MeasuredController`).
    """
    for name, value in (("mass", mass), ("length", length), ("damping", damping)):
        ok = value >= 0 if name == "damping" else value > 0
        if not (math.isfinite(value) and ok):
            raise IdapbcError(f"{name} scale must be finite and {'≥' if name == 'damping' else '>'} 0, got {value}. Fix: e.g. {name}=1.2.")
    return system.with_plant(system.plant.scaled(float(mass), float(length), float(damping)))


# ====================================================================== the sensor
class MeasuredController:
    """What the controller sees of the true plant: measured (q, v), nominal momentum, noise.

    ``u = ctrl(model.state_from(q + n_q, v + n_v))`` with (q, v) = ``plant.split(x)`` of the true
    state x and (n_q, n_v) ~ N(0, σ²) drawn afresh at every call (every control tick of the judge) from a seeded
    generator. With no plant and σ = 0 it is a pass-through.

    Parameters
    ----------
    ctrl : callable (N, n) -> (N, m) (`Controller`, `LQRController`, ...).
    plant : the judge `System` (default: the model, i.e. no mismatch).
    model : the controller's `System` (default ``ctrl.system``; required for controllers
        without one, e.g. `LQRController`).
    noise : σ, scalar or (n,) per (q, v) component (rad, m, rad/s, m/s).
    seed : seed of the noise.
    """

    def __init__(self, ctrl, plant=None, model=None, noise=0.0, seed: int = 0):
        self.ctrl = ctrl
        self.model = model if model is not None else getattr(ctrl, "system", None)
        if self.model is None:
            raise IdapbcError(f"MeasuredController needs the controller's model for {type(ctrl).__name__}. Fix: pass model=<its System>.")
        self.plant = plant if plant is not None else self.model
        sigma = np.broadcast_to(np.asarray(noise, float), (self.model.n,)).copy()
        if not np.all(np.isfinite(sigma) & (sigma >= 0)):
            raise IdapbcError(f"noise must be finite and ≥ 0, got {noise!r}. Fix: e.g. --noise 0.01.")
        self.sigma = sigma
        self.seed = int(seed)
        self.rng = np.random.default_rng(seed)
        self._identity = self.plant is self.model and not np.any(sigma > 0)

    @property
    def system(self):
        """The controller's model."""
        return self.model

    @property
    def noise_free(self) -> "MeasuredController":
        """The same measurement without noise (what `idapbc_pin.sim.step.loop_pole` linearises: the
        noisy law would draw from this one's generator)."""
        return MeasuredController(self.ctrl, plant=self.plant, model=self.model, noise=0.0, seed=self.seed)

    def __call__(self, x) -> np.ndarray:
        """u for true states x: (N, n) -> (N, m) (or (n,) -> (m,))."""
        x = np.asarray(x, float)
        if self._identity:
            return self.ctrl(x)
        single = x.ndim == 1
        xb = x[None] if single else x
        nq = self.model.nq
        if self.plant is self.model:
            q, v = xb[:, :nq], None
        else:
            q, v = self.plant.split(xb)
        if np.any(self.sigma > 0):
            if v is None:
                q, v = self.model.split(xb)
            noise = self.rng.standard_normal(xb.shape) * self.sigma
            q, v = q + noise[:, :nq], v + noise[:, nq:]
        x_meas = self.model.state_from(q, v)
        u = self.ctrl(x_meas)
        return u[0] if single else u

    def __repr__(self) -> str:
        return f"MeasuredController({type(self.ctrl).__name__}, mismatch={self.plant is not self.model}, noise={self.sigma.max():g})"


# ====================================================================== the table
@dataclass(frozen=True)
class Condition:
    """One row of the robustness table.

    Attributes
    ----------
    label : row label.
    mismatch : {kind: scale} for `perturbed_system`.
    saturation : max |u| per input (None: none; "auto": `saturation_factor` × the median peak
        |u| of LQR in the nominal row).
    noise : σ of the measurement noise on (q, v).
    """

    label: str
    mismatch: Mapping[str, float] = dataclasses.field(default_factory=dict)
    saturation: float | str | None = None
    noise: float = 0.0


def default_conditions(mass: Sequence[float] = (0.8, 1.2), saturation="auto", noise: float = 0.01) -> list[Condition]:
    """nominal; mass ×s for each s in `mass`; saturation; noise σ (issue 4 robustness table)."""
    rows = [Condition("nominal")]
    rows += [Condition(f"mass ×{s:g}", {"mass": float(s)}) for s in mass]
    if saturation is not None:
        rows.append(Condition("saturation" if saturation == "auto" else f"saturation {float(saturation):g}", saturation=saturation))
    if noise:
        rows.append(Condition(f"noise σ={noise:g}", noise=float(noise)))
    return rows


@dataclass(frozen=True, eq=False)
class RobustnessResult:
    """`roa` results per condition, Neural IDA-PBC and LQR from the same states.

    Attributes
    ----------
    system : name.  box : "domain" | "half".  n, seed, T, dt : the ROA settings.
    conditions : the rows, with "auto" saturation resolved to its value.
    results : one `RoaResult` per condition (controllers "NIDA-PBC" and "LQR").
    wall_time : seconds.
    limits : the effort limits applied in every row (`InputLimits` of the nominal system).
    """

    system: str
    box: str
    n: int
    seed: int
    T: float
    dt: float
    conditions: tuple
    results: tuple
    wall_time: float
    limits: InputLimits | None = None

    def to_dict(self) -> dict:
        rows = []
        for cond, res in zip(self.conditions, self.results):
            row = {"condition": cond.label, "mismatch": dict(cond.mismatch), "saturation": cond.saturation, "noise": cond.noise}
            for name, s in res.scores.items():
                row[name] = {
                    "success_rate": s.success_rate,
                    "median_settling_time": finite_or_none(s.median_settling_time),
                    "median_peak_input": finite_or_none(s.median_peak_input),
                    "diverged": s.n_diverged,
                }
            rows.append(row)
        limits = None if self.limits is None else self.limits.to_json()
        return {"system": self.system, "box": self.box, "n": self.n, "seed": self.seed, "T": self.T, "dt": self.dt, "limits": limits, "rows": rows}

    def table(self) -> str:
        names = list(self.results[0].scores) if self.results else []
        head = (
            f"robustness of {self.system}: {self.n} states uniform in the {self.box} box (seed {self.seed}), T = {self.T:g} s; "
            f"success % (median settle s, median peak |u| / limit)"
        )
        if self.limits is not None:
            head += f"\nin every row: {self.limits.describe()}"
        cols = f"{'condition':<22}" + "".join(f"{nm:>32}" for nm in names)
        lines = [head, cols, "-" * len(cols)]
        for cond, res in zip(self.conditions, self.results):
            label = cond.label + (f" (|u|≤{cond.saturation:.3g})" if isinstance(cond.saturation, float) and cond.label == "saturation" else "")
            cells = []
            for nm in names:
                s = res.scores[nm]
                st = s.median_settling_time
                peak = res.limits.peak_text(s.median_peak_input) if res.limits is not None else f"{s.median_peak_input:.3g}"
                cells.append(f"{100 * s.success_rate:5.1f} %" + (f" ({st:5.2f}, " if math.isfinite(st) else " (  -  , ") + f"{peak})")
            lines.append(f"{label:<22}" + "".join(f"{c:>32}" for c in cells))
        lines.append(f"{self.wall_time:.0f} s; noise on (q, v), resampled at every control tick; mismatch of the judge plant only")
        return "\n".join(lines)


def robustness_table(
    run,
    n: int = 100,
    T: float = 20.0,
    dt: float | None = None,
    seed: int = 0,
    box: str = "half",
    conditions: Sequence[Condition] | None = None,
    *,
    saturation_factor: float = 2.0,
    rho: float | None = None,
    write: bool = True,
    limits: bool = True,
    workers: int = 1,
) -> RobustnessResult:
    """Success rates of Neural IDA-PBC and LQR under model mismatch, saturation and noise.

    Parameters
    ----------
    run : a `Run` or a run directory (its controller, optionally with extra damping `rho`).
    n, T, dt, seed, box : the ROA settings (`idapbc_pin.evaluation.roa.roa`); the same states and the same
        step in every row (dt None: `judge_step` of both laws on the nominal plant).
    conditions : rows (default `default_conditions()`: nominal, mass ×0.8 and ×1.2, saturation at
        `saturation_factor` × LQR's median nominal peak |u|, noise σ = 0.01).
    write : write ``robustness.json`` into the run directory.
    limits : apply the system's effort limits in every row (False lifts them; a saturation row
        then clips to its own bound only).
    workers : processes simulating the two controllers of each row side by side (1: in this
        process, 0: one per core; `roa`); the count changes the time, never a figure.
    """
    t0 = time.perf_counter()
    run = resolve_run(run)
    nominal = run.system
    nida = run.controller if rho is None else run.controller.with_damping(rho)
    lqr = LQRController(nominal)
    dt = judge_step(nominal, {"NIDA-PBC": nida, "LQR": lqr}, T, dt)
    conditions = list(default_conditions() if conditions is None else conditions)
    if conditions and conditions[0].saturation == "auto":
        raise IdapbcError("the first condition cannot use saturation='auto' (it needs a nominal row first). Fix: start with the nominal row.")
    resolved, results = [], []
    lqr_peak = None
    for k, cond in enumerate(conditions):
        plant = perturbed_system(nominal, **parse_mismatch(cond.mismatch)) if cond.mismatch else nominal
        sat = cond.saturation
        if sat == "auto":
            if lqr_peak is None or not math.isfinite(lqr_peak):
                raise IdapbcError("saturation='auto' needs a nominal row where LQR has a finite median peak |u|. Fix: give a value.")
            sat = saturation_factor * lqr_peak
        controllers = {
            "NIDA-PBC": MeasuredController(nida, plant=plant, model=nominal, noise=cond.noise, seed=seed + 1000 * k),
            "LQR": MeasuredController(lqr, plant=plant, model=nominal, noise=cond.noise, seed=seed + 1000 * k),
        }
        res = roa(plant, controllers, n=n, box=box, seed=seed, T=T, dt=dt, saturation=sat, limits=limits, workers=workers)
        if lqr_peak is None and not cond.mismatch and cond.saturation is None and not cond.noise:
            lqr_peak = res["LQR"].median_peak_input
        resolved.append(dataclasses.replace(cond, saturation=None if sat is None else float(np.max(sat))))
        results.append(res)
    result = RobustnessResult(
        system=nominal.name, box=box, n=int(n), seed=int(seed), T=float(T), dt=float(dt),
        conditions=tuple(resolved), results=tuple(results), wall_time=time.perf_counter() - t0,
        limits=input_limits(nominal, limits),
    )
    if write and getattr(run, "path", None) is not None:
        write_json(run.path / "robustness.json", result.to_dict(), sort_keys=False)
    return result
