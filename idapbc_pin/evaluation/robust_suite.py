"""The robustness suite (DESIGN §4, "Robust swing-up"): six tests of what a real robot adds.

The RealAIGym robustness leaderboard v2 (github.com/dfki-ric-underactuated-lab/double_pendulum,
``analysis/benchmark.py``; written independently from its description), for any chain of 1-DoF
joints. Every rollout runs `SuiteConfig.T` = 10 s at 500 Hz from one start (exactly hanging for a
swing-up run; else states of the half box, one per row, the same for every law) and succeeds when,
at the end, every wrapped angle (and every linear coordinate) is within `SuiteConfig.position` of
x*'s, every speed within `SuiteConfig.speed`, and a cart stayed on its rail:

1. **model**: one plant parameter varied at a time, `levels` values each, the law unchanged
   (`idapbc_pin.model.variations.plant_families`: each link's m·r, I about its axis and m, each
   joint's damping and Coulomb friction, the rotors); score: the share of these rollouts that succeed;
2. **speed noise**: σ_v from 0 to 0.5 rad/s in `levels` steps, `repetitions` rollouts each; a level
   passes when more than half succeed; score: the share of passing levels;
3. **torque noise**: σ_τ from 0 to 1.1 N·m on the actuated inputs, the same rule;
4. **lag**: the actuator's responsiveness k from 0.1 to 2.0 (`idapbc_pin.sim.disturbed`);
5. **delay**: the measured state 0 to 40 ms late (rounded to the tick);
6. **pushes**: `pushes` random profiles, each `pulses` Gaussian torque pulses per joint (0.5 to 5 N·m,
   0.05 to 0.1 s wide, centres at least 1 s apart), added after the clip. `SuiteConfig.push_joints`
   says which joints they reach: every joint (a hand on any link), or only the actuated ones. The
   leaderboard's own simulator draws pulses for every joint but passes the applied torques through
   its plant's actuation matrix, so there the pulses on unactuated joints never reach the robot:
   ``"actuated"`` reproduces that, and its published push scores.

The suite's score is the mean of the six. All rows of all tests are simulated as one batch per law
(`simulate_disturbed`); the noise draws and push profiles are the same for every law. The rows'
true plants are Pinocchio's (`RowPlants`), or MuJoCo's with the same varied parameters
(``judge="mujoco"``, `idapbc_pin.sim.mujoco_rows`): an independent engine for the same tests.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .._parallel import process_map
from ..control.speed_filter import FilteredLaw, SpeedFilter
from ..model.angles import wrap_angles
from ..model.resting import resting_configuration
from ..errors import IdapbcError
from ..model.variations import Family, RowPlants, plant_families, varied_model
from ..sim.disturbed import Disturbances, simulate_disturbed
from ..sim.mujoco_plant import MujocoPlant
from ..sim.mujoco_rows import MujocoRowPlants
from ..sim.states import uniform_states

__all__ = ["FILTERED", "PUSH_JOINTS", "SUITE_FILE", "SUITE_JUDGES", "SUITE_TESTS", "SuiteConfig", "SuiteResult", "SuiteRows", "evaluate_run_suite", "judge_suite", "push_profiles", "suite_rows", "suite_start"]

#: The six tests, in the leaderboard's order.
SUITE_TESTS = ("model", "speed noise", "torque noise", "lag", "delay", "pushes")
#: Seed offset of the suite's noise and pushes (apart from the other evaluations').
SUITE_SEED = 70_000
#: Engines of the suite's true plants (`judge_suite`).
SUITE_JUDGES = ("pinocchio", "mujoco")
#: Which joints the pushes reach (`SuiteConfig.push_joints`).
PUSH_JOINTS = ("all", "actuated")


@dataclass(frozen=True)
class SuiteConfig:
    """The suite's settings; the defaults are the RealAIGym robustness leaderboard v2's.

    Attributes
    ----------
    T : rollout length, s.  dt : control period and RK4 step, s.
    position, speed : success tolerances at the end (rad or m; rad/s or m/s).
    levels : levels of every graded test.  repetitions : rollouts per noise level.
    scale : range of the inertial scales.  damping : range of the damping increments (N·m·s/rad).
    coulomb : range of the Coulomb coefficients (N·m).  rotor : range of the rotor inertias (kg·m²).
    speed_noise : largest σ_v (rad/s).  torque_noise : largest σ_τ (N·m).  lag : range of k.
    delay : largest delay, s.  pushes : push profiles.  pulses : pulses per joint in a profile.
    pulse_width : range of a pulse's σ, s.  pulse_amplitude : range of |A|, N·m.
    spacing : least time between two pulse centres, s.
    push_joints : joints the pulses reach: ``"all"``, or ``"actuated"`` (the pulses drawn for the
        others are dropped, as the leaderboard's simulator drops them; module docstring).
    """

    T: float = 10.0
    dt: float = 0.002
    position: float = 0.35
    speed: float = 1.0
    levels: int = 21
    repetitions: int = 10
    scale: tuple = (0.75, 1.25)
    damping: tuple = (-0.1, 0.1)
    coulomb: tuple = (-0.2, 0.2)
    rotor: tuple = (0.0, 1e-4)
    speed_noise: float = 0.5
    torque_noise: float = 1.1
    lag: tuple = (0.1, 2.0)
    delay: float = 0.04
    pushes: int = 50
    pulses: int = 3
    pulse_width: tuple = (0.05, 0.1)
    pulse_amplitude: tuple = (0.5, 5.0)
    spacing: float = 1.0
    push_joints: str = "all"

    def __post_init__(self):
        if self.push_joints not in PUSH_JOINTS:
            raise ValueError(f"unknown push_joints {self.push_joints!r}: one of {', '.join(PUSH_JOINTS)}")


def push_profiles(rng: np.random.Generator, n: int, nv: int, config: SuiteConfig) -> np.ndarray:
    """(n, nv, P, 3) push profiles (centre s, width s, amplitude N·m): P = `pulses` per joint, the
    nv·P centres drawn in increasing order with at least `spacing` between them (less where T leaves
    no room) and then shuffled over the joints; widths and |amplitudes| uniform in their ranges,
    signs at random."""
    P = int(config.pulses)
    k = nv * P
    out = np.zeros((n, nv, P, 3))
    if k == 0:
        return out
    gap = min(float(config.spacing), config.T / (k + 1))
    room = max(0.0, (config.T - (k + 1) * gap) / k)
    for i in range(n):
        mu = np.cumsum(gap + rng.uniform(0.0, room, k))
        rng.shuffle(mu)
        width = rng.uniform(*config.pulse_width, size=k)
        lo, hi = config.pulse_amplitude
        amp = rng.choice([-1.0, 1.0], size=k) * rng.uniform(lo, hi, size=k)
        out[i] = np.stack([mu, width, amp], axis=-1).reshape(nv, P, 3)
    return out


@dataclass(frozen=True, eq=False)
class SuiteRows:
    """Every rollout of the suite: N rows, what each varies and where each starts.

    families : the model test's `Family` list.  test : (N,) index into `SUITE_TESTS`.
    level : (N,) the row's level within its test (its family's level for the model test; the push
    profile for the pushes).  family : (N,) the family of a model row (-1 elsewhere).
    x0 : (N, n) start states.  models : length-N list (a varied `pin.Model`, or None: the nominal).
    damping, coulomb : (N, nv) joint friction.  dist : `Disturbances`.  values : (N,) the varied value.
    """

    families: list
    test: np.ndarray
    level: np.ndarray
    family: np.ndarray
    x0: np.ndarray
    models: list
    damping: np.ndarray
    coulomb: np.ndarray
    dist: Disturbances
    values: np.ndarray

    @property
    def N(self) -> int:
        return int(self.test.shape[0])


def suite_rows(system, config: SuiteConfig = SuiteConfig(), start: str = "hanging", seed: int = 0) -> SuiteRows:
    """The suite's rows for `system` (a URDF robot): the model test's families × levels, then the
    noise levels × repetitions, the lags, the delays and the push profiles. ``start="hanging"``:
    every row at rest in the resting posture; ``"box"``: row i at the i-th state uniform in the half
    box (seeded)."""
    nv, L, R = system.nq, int(config.levels), int(config.repetitions)
    families = plant_families(system.plant, L, config.scale, config.damping, config.coulomb, config.rotor)
    D0 = np.asarray(system.plant.damping, float)
    test, level, family, values, models, damping, coulomb, dists = [], [], [], [], [], [], [], []

    def add(t, lv, fam, val, model, d, c, dist):
        test.append(t), level.append(lv), family.append(fam), values.append(val), models.append(model)
        damping.append(d), coulomb.append(c), dists.append(dist)

    one = Disturbances.none(1, nv)
    for f, fam in enumerate(families):
        for j, value in enumerate(fam.levels):
            d, c = D0.copy(), np.zeros(nv)
            model = None
            if fam.inertial:
                model = varied_model(system.plant, fam.kind, fam.joint, value)
            elif fam.kind == "b":
                d[fam.joint] += value
            else:
                c[fam.joint] = value
            add(0, j, f, value, model, d, c, one)
    for t, top in ((1, config.speed_noise), (2, config.torque_noise)):
        for j, sigma in enumerate(np.linspace(0.0, top, L)):
            for _ in range(R):
                dist = Disturbances(np.array([sigma if t == 1 else 0.0]), np.array([sigma if t == 2 else 0.0]), np.ones(1), np.zeros(1, int),
                                    np.zeros((1, nv, 0, 3)))
                add(t, j, -1, sigma, None, D0, np.zeros(nv), dist)
    for j, k in enumerate(np.linspace(*config.lag, L)):
        add(3, j, -1, k, None, D0, np.zeros(nv), Disturbances(np.zeros(1), np.zeros(1), np.array([k]), np.zeros(1, int), np.zeros((1, nv, 0, 3))))
    for j, late in enumerate(np.linspace(0.0, config.delay, L)):
        ticks = int(np.rint(late / config.dt))
        add(4, j, -1, late, None, D0, np.zeros(nv), Disturbances(np.zeros(1), np.zeros(1), np.ones(1), np.array([ticks]), np.zeros((1, nv, 0, 3))))
    rng = np.random.default_rng(SUITE_SEED + int(seed))
    profiles = push_profiles(rng, int(config.pushes), nv, config)
    if config.push_joints == "actuated":  # the same draws, the unactuated joints' pulses dropped
        profiles[:, ~(np.abs(np.asarray(system.B, float)) > 0).any(axis=1), :, 2] = 0.0
    for j in range(int(config.pushes)):
        add(5, j, -1, float(j), None, D0, np.zeros(nv), Disturbances(np.zeros(1), np.zeros(1), np.ones(1), np.zeros(1, int), profiles[j: j + 1]))
    N = len(test)
    if start == "hanging":
        q = resting_configuration(system)[None].repeat(N, axis=0)
        x0 = system.state_from(q, np.zeros_like(q))
    elif start == "box":
        x0 = uniform_states(system, N, "half", seed)
    else:
        raise ValueError(f"unknown start {start!r}: hanging or box")
    return SuiteRows(families=families, test=np.array(test), level=np.array(level), family=np.array(family), x0=x0, models=models,
                     damping=np.array(damping), coulomb=np.array(coulomb), dist=Disturbances.stack(dists), values=np.array(values, float))


def _successes(system, rows: SuiteRows, ending, config: SuiteConfig) -> np.ndarray:
    """(N,) bool: the suite's success at the end of each row (module docstring)."""
    nq = system.nq
    dq = wrap_angles(ending.q - np.asarray(system.x_star, float)[:nq], np.asarray(system.angle_mask, bool)[:nq])
    near = (np.abs(dq) < config.position).all(axis=1) & (np.abs(ending.v) < config.speed).all(axis=1)
    return near & ~ending.diverged & ending.on_rail


def _row_plants(system, rows: SuiteRows, judge: str):
    """The rows' true plants: Pinocchio's (`RowPlants`) or MuJoCo's (`MujocoRowPlants`)."""
    if judge == "mujoco":
        return MujocoRowPlants(MujocoPlant(system.plant), rows.models, rows.damping, rows.coulomb)
    return RowPlants(system.plant, rows.models, rows.damping, rows.coulomb)


def _judge_job(job) -> np.ndarray:
    """Worker: (system, law, rows, config, seed, limits, judge) -> (N,) successes of the law on every row."""
    system, law, rows, config, seed, limits, judge = job
    plants = _row_plants(system, rows, judge)
    ending = simulate_disturbed(system, plants, law, rows.x0, rows.dist, config.T, config.dt, seed=SUITE_SEED + 1 + int(seed), limits=limits)
    return _successes(system, rows, ending, config)


@dataclass(frozen=True, eq=False)
class SuiteResult:
    """Several laws judged on the same suite rows.

    system : name.  start : "hanging" | "box".  config : `SuiteConfig`.  rows : `SuiteRows`.
    success : law name -> (N,) bool per row.  judge : the engine of the true plants.
    """

    system: str
    start: str
    config: SuiteConfig
    rows: SuiteRows
    success: dict = field(default_factory=dict)
    judge: str = "pinocchio"

    def scores(self, name: str) -> dict:
        """{test: score in [0, 1]} of one law, and "overall": their mean (module docstring)."""
        ok, rows = self.success[name], self.rows
        out = {}
        for t, test in enumerate(SUITE_TESTS):
            sel = rows.test == t
            if test in ("speed noise", "torque noise"):
                levels = np.unique(rows.level[sel])
                passed = [ok[sel & (rows.level == j)].mean() > 0.5 for j in levels]
                out[test] = float(np.mean(passed)) if passed else math.nan
            else:
                out[test] = float(ok[sel].mean()) if sel.any() else math.nan
        scored = [out[t] for t in SUITE_TESTS if math.isfinite(out[t])]
        out["overall"] = float(np.mean(scored)) if scored else math.nan
        return out

    def family_counts(self, name: str) -> dict:
        """{family name: successes} of one law in the model test (out of `levels` each)."""
        ok, rows = self.success[name], self.rows
        return {fam.name: int(ok[(rows.test == 0) & (rows.family == f)].sum()) for f, fam in enumerate(rows.families)}

    def table(self) -> str:
        """Two markdown tables: the six scores and their mean per law; the model test per family."""
        head = "| law | overall | " + " | ".join(SUITE_TESTS) + " |"
        lines = [head, "|" + "---|" * (len(SUITE_TESTS) + 2)]
        for name in self.success:
            s = self.scores(name)
            lines.append(f"| {name} | {s['overall']:.3f} | " + " | ".join(f"{s[t]:.3f}" for t in SUITE_TESTS) + " |")
        fams = [f.name for f in self.rows.families]
        lines += ["", f"model test, successes of {self.config.levels} levels per parameter:", "",
                  "| law | " + " | ".join(fams) + " |", "|" + "---|" * (len(fams) + 1)]
        for name in self.success:
            c = self.family_counts(name)
            lines.append(f"| {name} | " + " | ".join(str(c[f]) for f in fams) + " |")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-ready: the settings, each law's scores, its model test per family and every row's verdict."""
        return {"system": self.system, "start": self.start, "judge": self.judge, "config": asdict(self.config),
                "families": [{"name": f.name, "kind": f.kind, "levels": list(f.levels)} for f in self.rows.families],
                "rows": {"test": self.rows.test.tolist(), "level": self.rows.level.tolist(), "family": self.rows.family.tolist(),
                         "value": self.rows.values.tolist()},
                "scores": {k: self.scores(k) for k in self.success}, "model": {k: self.family_counts(k) for k in self.success},
                "success": {k: v.tolist() for k, v in self.success.items()}}


def judge_suite(system, laws: dict, config: SuiteConfig = SuiteConfig(), start: str = "hanging", seed: int = 0, workers: int = 1,
                limits: bool = True, judge: str = "pinocchio") -> SuiteResult:
    """Judge `laws` (name -> law (N, n) -> (N, m), called once per tick; a fresh instance each) on
    the suite's rows of `system` (`suite_rows`): one batched rollout per law, `workers` processes
    (0: one per core; the laws must pickle), the effort limits applied unless `limits` is False.
    `judge`: the engine of the rows' true plants, "pinocchio" or "mujoco" (the same varied
    parameters, `idapbc_pin.sim.mujoco_rows`); the laws keep `system` as their model."""
    if judge not in SUITE_JUDGES:
        raise IdapbcError(f"judge must be one of {', '.join(SUITE_JUDGES)}, got {judge!r}. Fix: --judge pinocchio or --judge mujoco.")
    if judge == "mujoco":
        MujocoPlant(system.plant)  # refuse a robot MuJoCo cannot judge here, before any worker starts
    rows = suite_rows(system, config, start, seed)
    oks = process_map(_judge_job, [(system, law, rows, config, seed, bool(limits), judge) for law in laws.values()], workers)
    return SuiteResult(system=str(system.name), start=start, config=config, rows=rows, success=dict(zip(laws, oks)), judge=judge)


#: The run directory's file of the suite.
SUITE_FILE = "robustness-suite.json"


def suite_start(run) -> str:
    """Where a run's suite starts: "hanging" for a run with a swing-up law or manoeuvre, else "box"."""
    swings = bool(getattr(run, "uses_swing_up", False)) or getattr(run, "manoeuvre", None) is not None
    return "hanging" if swings else "box"


#: The row of a law run on the shipped speed filter's estimates.
FILTERED = "{} + speed filter"


def evaluate_run_suite(run, config: SuiteConfig = SuiteConfig(), start: str = "auto", seed: int = 0, workers: int = 1,
                       limits: bool = True, judge: str = "pinocchio") -> SuiteResult:
    """A run judged by the suite (`judge_suite`) beside saturated LQR and the energy-pumping law
    (`EnergyPumpLaw`, handing over to LQR near x*); from hanging also the run's swing-up manoeuvre
    where it keeps one (then the run's law). The run's laws are judged as measured and on the speeds
    of the shipped `SpeedFilter` (rows `FILTERED`). `start` "auto": `suite_start`; `judge`: the
    engine of the true plants (`judge_suite`). Written to the run directory (`SUITE_FILE`)."""
    from .._io import write_json
    from ..control.baseline import LQRController
    from ..control.energy_pump import EnergyPumpLaw
    from .swingup import DT, MANOEUVRE_ROW

    start = suite_start(run) if start == "auto" else start
    system, ctrl = run.system, run.controller
    laws = {"NIDA-PBC": ctrl, FILTERED.format("NIDA-PBC"): FilteredLaw(ctrl, system, SpeedFilter(dt=DT))}
    manoeuvre = getattr(run, "manoeuvre", None) if start == "hanging" else None
    if manoeuvre is not None:
        laws[MANOEUVRE_ROW] = manoeuvre.law(ctrl, dt=DT)
        laws[FILTERED.format(MANOEUVRE_ROW)] = FilteredLaw(manoeuvre.law(ctrl, dt=DT), system, SpeedFilter(dt=DT))
    laws |= {"LQR": LQRController(system), "energy pump + LQR": EnergyPumpLaw(system)}
    result = judge_suite(run.system, laws, config, start, seed, workers, limits, judge)
    write_json(run.path / SUITE_FILE, result.to_dict(), sort_keys=False)
    return result
