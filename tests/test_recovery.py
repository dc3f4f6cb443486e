"""A recovery law beside the IDA-PBC law, for weak actuators (`control.recovery`, `training.plans`,
`training.recovery`).

Claims:
* the recovery law stays within the effort limits everywhere, leaves the IDA-PBC law in charge
  inside its inner box, and sees angles wrapped to within π of x*;
* a fit recovers a saturated linear law from its own labels, the same for the same seed;
* the residual form adds its MLP to the IDA-PBC law's saturated input, within the limits, and where
  the labels are that law's own inputs its fit reproduces them, closer than the direct form;
* labels are torques within the limits of trajectories that reach x*, with a cart on its rail;
* a torque plan within the limits brings a pendubot with an 8 N·m shoulder to x* from a half-box
  state saturated LQR loses; plans searched together equal plans searched one start at a time;
* the plans' starts and the DAgger starts come from the box `start_box` names (half box or
  training box); the labels come from the `teacher` it names (saturated LQR, or the run's own law,
  whose labels near x* are its own torques);
* DAgger searches no plan after a first fit that loses every start of its first round, unless those
  most of those starts come to rest in the near box around x*;
* the default gate forgives a recovery law 2 lost states of the half or near box, not 6;
* `recover` writes recovery.npz exactly when its gate keeps the law, and the run's controller then
  applies it; a later `recover` that does not keep one removes it;
* `recover --regate` judges the saved law again without fitting; `recover --refit` fits a law again
  to the saved labels (the same seed gives the same law as a fit on those labels) without plans;
  missing or damaged labels are refused with one line;
* a damaged or missing recovery.npz is refused when the run loads, with one line;
* `train --recover auto` (opt-in: `train`'s default, never, prints the `recover` command instead) fits one exactly when saturated LQR leaves room: it fails on
  ≥ 10 % of the half box (the zoo pendubot, whose 20 N·m limit does not bind, and an 8 N·m shoulder,
  where it binds; not the cartpole), or else of the training box, and then from training-box starts
  (the cartpole; not the reaction wheel); a robot without limits is tested with LQR itself, and
  its plans and recovery law stay within the largest force LQR asks on the training box.
(The exported controller.py applies it as the library does: tests/test_export.py.)
"""

from __future__ import annotations

import json
import shutil
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.speed_governor import ENERGY_MARGIN
from idapbc_pin._io import DamagedFileError
from idapbc_pin.cli.main import main
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.recovery.law import RecoveryLaw
from idapbc_pin.errors import IdapbcError
from idapbc_pin.model.angles import wrap_angles
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.metrics import success
from idapbc_pin.sim.states import scaled_box
from idapbc_pin.sim.states import evaluation_box, uniform_states
from idapbc_pin.recovery import stage as recovery_module
from idapbc_pin.recovery import gate as recovery_gate
from idapbc_pin.trajectory.plans import PLAN_STEP, PlanSettings, PlanThenLaw, plan_bound, planning_system, search_plan, search_plans
from idapbc_pin.recovery.again import refit, regate
from idapbc_pin.recovery.stage import LABEL_EVERY, LABEL_SPAN, RecoveryConfig, collect_labels, ends_near, fit_recovery_law, gate_choice, recover
from idapbc_pin.recovery.fit import base_inputs
from idapbc_pin.recovery.gate import NEAR_SCALE, read_labels, save_labels
from idapbc_pin.run import RECOVERY_FILE, RECOVERY_LABELS_FILE, RECOVERY_REFUSED_FILE
from idapbc_pin.recovery import trigger as weak_actuators
from idapbc_pin.recovery.trigger import BIND_POINTS, BIND_STATES, ROOM_POINTS, auto_recover, limits_bind

from .conftest import cart_out_and_back, sample_domain

#: The labelling steps here take their few starts in one chunk (`one_label_chunk`); the two tests of
#: the chunks across worker counts put the eight back.
pytestmark = pytest.mark.usefixtures("one_label_chunk")


def random_law(system, inner_scale: float, seed: int = 0, width: int = 16, residual: bool = False) -> RecoveryLaw:
    """A recovery law with random weights (large enough that the output saturates somewhere), in the
    direct form or the residual one."""
    rng = np.random.default_rng(seed)
    sizes = [system.n, width, width, system.m]
    weights = tuple(2.0 * rng.standard_normal((b, a)) for a, b in zip(sizes[:-1], sizes[1:]))
    biases = tuple(rng.standard_normal(b) for b in sizes[1:])
    lo, hi = system.domain
    scale = (hi - lo) / 2
    effort = np.where(np.isfinite(system.effort), system.effort, 5.0)
    return RecoveryLaw(weights, biases, system.x_star, scale, effort, np.asarray(system.angle_mask), inner_scale * scale, residual=residual)


@pytest.fixture(scope="module")
def weak_pendubot():
    return ip.load_system("pendubot", effort={"shoulder": 8.0})


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    system = ip.load_system("pendubot", effort={"shoulder": 8.0})
    config = ip.TrainConfig.fast(epochs=5, width=8, depth=1, samples=64, dtype="float64")
    return ip.train(system, config, out=tmp_path_factory.mktemp("runs"), progress=False)


def test_the_recovery_law_stays_within_the_limits_and_keeps_the_inner_box(weak_pendubot):
    system = weak_pendubot
    law = random_law(system, inner_scale=0.5)
    x = np.concatenate([sample_domain(system, 1000), system.x_star + 4 * (sample_domain(system, 1000, seed=1) - system.x_star)])
    u_law = law.law(x)
    assert np.abs(u_law).max() <= law.effort.max() * (1 + 1e-12)
    assert (np.abs(u_law) > 0.9 * law.effort).any()  # the weights are large enough to reach the limit
    u_ida = np.full((len(x), system.m), 123.0)  # stands for the IDA-PBC law's output
    u = law.apply(x, u_ida)
    inside = (np.abs(wrap_angles(x - system.x_star, system.angle_mask)) <= law.inner).all(axis=1)
    assert 0 < inside.sum() < len(x)
    np.testing.assert_array_equal(u[inside], 123.0)
    np.testing.assert_array_equal(u[~inside], u_law[~inside])
    turned = x.copy()
    turned[:, 0] += 2 * np.pi  # one turn of the shoulder: the same state for the law
    np.testing.assert_allclose(law.law(turned), u_law, atol=1e-12)
    np.testing.assert_array_equal(law.with_inner(0.25).inner, 0.25 * law.scale)


def test_with_a_level_the_ida_pbc_law_also_keeps_the_sublevel_set_of_its_energy(weak_pendubot):
    """u is the IDA-PBC law's inside the inner box or where H_d ≤ c, the recovery law's elsewhere;
    the level needs H_d, survives a round trip, and a law saved without one has none (c = ∞)."""
    system = weak_pendubot
    law = random_law(system, inner_scale=0.3)
    x = sample_domain(system, 1000)
    def energy_of(xs):  # stands for H_d, values in [0, 2]
        return 2.0 * np.abs(np.sin(7.0 * xs.sum(axis=1)))

    energy = energy_of(x)
    u_ida = np.full((len(x), system.m), 123.0)
    u = law.with_level(1.0).apply(x, u_ida, energy_of)
    recovering = law.outside(x) & (energy > 1.0)
    assert 0 < recovering.sum() < law.outside(x).sum()
    np.testing.assert_array_equal(u[~recovering], 123.0)
    np.testing.assert_array_equal(u[recovering], law.law(x[recovering]))
    np.testing.assert_array_equal(law.apply(x, u_ida), law.with_level(np.inf).apply(x, u_ida, energy_of))  # no level: the box alone
    with pytest.raises(ValueError, match="H_d"):
        law.with_level(1.0).apply(x, u_ida)
    again = RecoveryLaw.from_arrays(law.with_level(1.0).arrays())
    assert again.level == 1.0 and RecoveryLaw.from_arrays(law.arrays()).level == np.inf and "level" not in law.arrays()


def test_arrays_round_trip_and_bad_arrays_are_refused(weak_pendubot):
    law = random_law(weak_pendubot, inner_scale=0.1)
    again = RecoveryLaw.from_arrays(law.arrays())
    x = sample_domain(weak_pendubot, 50)
    np.testing.assert_array_equal(again.apply(x, np.zeros((50, 1))), law.apply(x, np.zeros((50, 1))))
    bad = law.arrays() | {"W1": np.zeros((3, 3))}
    with pytest.raises(ValueError, match="do not fit"):
        RecoveryLaw.from_arrays(bad)
    with pytest.raises(ValueError, match="non-finite"):
        RecoveryLaw.from_arrays(law.arrays() | {"b0": np.full(16, np.nan)})


def _mlp(law: RecoveryLaw, x: np.ndarray) -> np.ndarray:
    """The MLP's output of `law` at x (N, n), layer by layer: a reference for both forms."""
    z = wrap_angles(x - law.x_star, law.angle_mask) / law.scale
    for W, b in zip(law.weights[:-1], law.biases[:-1]):
        z = np.tanh(z @ W.T + b)
    return z @ law.weights[-1].T + law.biases[-1]


def test_the_residual_form_corrects_the_ida_pbc_input_and_stays_within_the_limits(weak_pendubot):
    """Outside the inner box: ū clip(clip(u/ū, ±1) + MLP(δ/s), ±1) (residual) and ū tanh(MLP(δ/s))
    (direct); a zero output layer leaves the IDA-PBC law's saturated input; the residual law needs
    that input; the flag survives a round trip, and a law saved without it is direct."""
    system = weak_pendubot
    law = random_law(system, inner_scale=0.3, residual=True)
    x = sample_domain(system, 1000)
    u_ida = 3.0 * law.effort * np.sin(np.arange(len(x)))[:, None]  # stands for the IDA-PBC law, often beyond the limit
    u, out = law.apply(x, u_ida), law.outside(x)
    assert 0 < out.sum() < len(x)
    expected = law.effort * np.clip(np.clip(u_ida / law.effort, -1.0, 1.0) + _mlp(law, x), -1.0, 1.0)
    np.testing.assert_allclose(u[out], expected[out], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(u[~out], u_ida[~out])
    assert np.abs(u[out]).max() <= law.effort.max() and (np.abs(u[out]) < 0.99 * law.effort).any()
    zero = replace(law, weights=law.weights[:-1] + (0.0 * law.weights[-1],), biases=law.biases[:-1] + (0.0 * law.biases[-1],))
    np.testing.assert_array_equal(zero.law(x, u_ida), np.clip(u_ida, -law.effort, law.effort))
    with pytest.raises(ValueError, match="pass u"):
        law.law(x)
    np.testing.assert_allclose(replace(law, residual=False).law(x), law.effort * np.tanh(_mlp(law, x)), rtol=0, atol=1e-12)
    assert RecoveryLaw.from_arrays(law.arrays()).residual and not RecoveryLaw.from_arrays(replace(law, residual=False).arrays()).residual
    assert "residual" not in replace(law, residual=False).arrays()  # what laws saved before the residual form hold


def test_a_residual_fit_reproduces_labels_that_are_the_ida_pbc_law_s_own_inputs(weak_pendubot):
    """Labels of a law that saturates on much of the box (the IDA-PBC law's inputs, as the run's law
    teaches them): the residual fit only has to learn zero and is within 1 % of ū on new states,
    where the direct fit of the same size and steps is not."""
    system = weak_pendubot
    K = 4.0 * LQRController(system).K

    def ida(x):  # stands for the IDA-PBC law, unsaturated
        return -wrap_angles(x - system.x_star, system.angle_mask) @ K.T

    X = sample_domain(system, 4000, seed=1)
    U = system.saturate(ida(X))
    assert (np.abs(U) >= system.effort).mean() > 0.2
    residual, _ = fit_recovery_law(system, X, U, width=32, steps=300, seed=3, base=U)
    direct, _ = fit_recovery_law(system, X, U, width=32, steps=300, seed=3)
    x_new = sample_domain(system, 1000, seed=2)
    target = system.saturate(ida(x_new))

    def rms(u):
        return float(np.sqrt(np.mean(((u - target) / system.effort) ** 2)))

    assert residual.residual and not direct.residual
    assert rms(residual.law(x_new, ida(x_new))) < 0.01 < rms(direct.law(x_new)), (rms(residual.law(x_new, ida(x_new))), rms(direct.law(x_new)))


def test_a_fit_recovers_a_saturated_linear_law_from_its_labels(weak_pendubot):
    """Labels of u = sat(−Kδ) on box states: the fitted law is within 5 % of ū of it on new states,
    and the same seed gives the same weights."""
    system = weak_pendubot
    K = LQRController(system).K

    def target(x):
        return system.saturate(-wrap_angles(x - system.x_star, system.angle_mask) @ K.T)

    X = sample_domain(system, 4000, seed=1)
    law, mse = fit_recovery_law(system, X, target(X), width=32, steps=1500, seed=3)
    x_new = sample_domain(system, 1000, seed=2)
    err = np.abs(law.law(x_new) - target(x_new)) / system.effort
    assert np.sqrt(np.mean(err**2)) < 0.05, np.sqrt(np.mean(err**2))
    assert mse < 0.01
    again, _ = fit_recovery_law(system, X, target(X), width=32, steps=1500, seed=3)
    np.testing.assert_array_equal(again.weights[0], law.weights[0])


def test_a_plan_within_the_limits_recovers_a_state_saturated_lqr_loses(weak_pendubot):
    system = weak_pendubot
    lqr = LQRController(system)
    x0 = uniform_states(system, 12, "half", seed=101)
    lost = np.flatnonzero(~success(simulate(system, lqr, x0, T=20.0, dt=PLAN_STEP), system))
    assert lost.size > 0  # with 8 N·m saturated LQR loses most of the half box
    bound = np.asarray(system.effort)
    plan = search_plan(system, lqr, x0[lost[0]], bound, PlanSettings(), np.random.default_rng(0))
    assert plan.shape == (1, system.m, PlanSettings().knots) and np.abs(plan).max() <= bound.max()
    traj = simulate(system, PlanThenLaw(plan, PlanSettings().horizon, lqr), x0[lost[:1]], T=20.0, dt=PLAN_STEP)
    assert success(traj, system)[0]
    assert np.abs(traj.u).max() <= bound.max() * (1 + 1e-12)


def test_plans_searched_together_equal_plans_searched_one_start_at_a_time(weak_pendubot):
    system = weak_pendubot
    lqr, bound = LQRController(system), np.asarray(system.effort)
    settings = PlanSettings(knots=4, population=16, iterations=3, score_T=0.5)
    x0 = uniform_states(system, 3, "half", seed=5)
    streams = lambda: [np.random.default_rng((1, i)) for i in range(3)]  # noqa: E731
    together = search_plans(system, lqr, x0, bound, settings, streams())
    alone = np.concatenate([search_plan(system, lqr, x0[i], bound, settings, rng) for i, rng in enumerate(streams())])
    assert together.shape == (3, system.m, 4) and np.abs(together).max() <= bound.max()
    np.testing.assert_array_equal(together, alone)
    assert not np.array_equal(together[0], together[1])  # each start keeps its own search


def test_labels_are_torques_within_the_limits_of_trajectories_that_reach_the_target(weak_pendubot):
    system = weak_pendubot
    x0 = uniform_states(system, 2, "half", 101)
    X, U, lqr_ok, recovered = collect_labels(system, x0, 101, RecoveryConfig(workers=1, plan=PlanSettings(horizon=1.0, ilqr_iterations=4)), progress=False)
    assert lqr_ok + recovered >= 1
    assert len(X) == len(U) == (lqr_ok + recovered) * (LABEL_SPAN // LABEL_EVERY)
    assert np.all(np.abs(U) <= 8.0 + 1e-12) and np.isfinite(X).all()


def test_a_trajectory_that_reaches_the_target_off_the_rail_labels_nothing():
    """The zoo cartpole's rail is ±5 m. Two hand-made trajectories end at rest at x*: the cart goes
    out to 4.9 m and back, or to 5.2 m and back; only the first may label a law."""
    system = ip.load_system("cartpole")
    traj = cart_out_and_back([4.9, 5.2], T=10.0)
    np.testing.assert_array_equal(success(traj, system), [True, True])
    np.testing.assert_array_equal(recovery_module._labels_ok(traj, system), [True, False])


def test_worker_processes_change_the_time_of_recover_never_its_plans_fits_or_gate(tiny_run, monkeypatch):
    monkeypatch.setattr(recovery_module, "LABEL_CHUNKS", 8)
    _short_gate(monkeypatch)
    system = tiny_run.system
    small = dict(TINY, steps=60, fits=2, inner_scales=(0.1, 0.5))
    x0 = uniform_states(system, 3, "half", 101)
    results = []
    for workers in (1, 2):
        config = RecoveryConfig(**(small | {"workers": workers}))
        X, U, lqr_ok, recovered = collect_labels(system, x0, 101, config, progress=False)
        first, _ = fit_recovery_law(system, X, U, config.width, config.steps, config.fit_seed)
        law, gate = recovery_module._gate_fits(tiny_run, tiny_run.system, first, X, U, config, False, 0.0, tiny_run.controller.with_fallback(None))
        results.append((X, U, lqr_ok, recovered, law, gate))
    (X1, U1, *counts1, law1, gate1), (X2, U2, *counts2, law2, gate2) = results
    assert recovered + lqr_ok >= 1 and counts1 == counts2
    np.testing.assert_array_equal(X1, X2)
    np.testing.assert_array_equal(U1, U2)
    for w1, w2 in zip(law1.weights + law1.biases, law2.weights + law2.biases):
        np.testing.assert_array_equal(w1, w2)
    assert gate1 == gate2 and len(gate1["fits"]) == 2
    assert RecoveryConfig().workers == 0 and recovery_module.resolve_workers(0) >= 1  # 0: one per core


def test_the_labels_do_not_depend_on_the_number_of_worker_processes(weak_pendubot, monkeypatch):
    """The starts are split into the same chunks for one worker or two (chunks that followed the
    workers gave other plans), on the 8 N·m pendubot, whose saturated LQR settles within seconds where
    it settles at all (starts judged over 8 s)."""
    monkeypatch.setattr(recovery_module, "LABEL_CHUNKS", 8)
    system = planning_system(weak_pendubot)
    x0 = uniform_states(system, 9, "domain", 5)  # more starts than chunks (8): one chunk holds two
    plan = PlanSettings(horizon=1.0, ilqr_iterations=4)
    labels = [collect_labels(system, x0, 3, RecoveryConfig(workers=w, plan=plan, judge_T=8.0), progress=False) for w in (1, 2)]
    (X1, U1, *counts1), (X2, U2, *counts2) = labels
    assert counts1 == counts2 and counts1[1] >= 1  # some start needed a plan
    np.testing.assert_array_equal(X1, X2)
    np.testing.assert_array_equal(U1, U2)


def _torques(job):
    ctrl, x = job
    return ctrl(x)


def test_a_controller_sent_to_a_worker_process_gives_the_same_torques_there_and_here(tiny_run):
    # concurrent.futures pickles torch tensors with torch.multiprocessing's reductions, which move the
    # sender's tensors to shared memory: numpy views of them (the law's (gᵀg)⁻¹gᵀ, the wrap's x*) dangled
    ctrl = ip.load_run(tiny_run.path).controller
    x = uniform_states(tiny_run.system, 8, "half", 3)
    u = ctrl(x)
    with ProcessPoolExecutor(1) as pool:
        there = pool.submit(_torques, (ctrl, x)).result()
    np.testing.assert_array_equal(ctrl(x), u)
    np.testing.assert_array_equal(there, u)
    fresh = ip.load_run(tiny_run.path).controller
    assert list(recovery_module.process_map(_torques, [(fresh, x), (fresh, x)], 2)) == [pytest.approx(u, abs=0)] * 2
    assert not any(p.is_shared() for p in fresh.nets.parameters())  # process_map sends plain pickles


def test_the_gate_s_verdicts_are_the_full_rollouts_though_rows_at_rest_stop_early(weak_pendubot):
    """The gate reads success only, so it integrates a state no further once that state has rested
    in the success box for the success window: the same verdicts as 20 s rollouts, fewer law calls."""
    system, lqr = weak_pendubot, LQRController(weak_pendubot)
    x0 = uniform_states(system, 24, "half", seed=3)
    rows = []

    def counting(x):
        rows.append(x.shape[0])
        return lqr(x)

    [(verdicts, _)] = list(recovery_gate.compare_laws(system, [(counting, x0)], T=recovery_gate.GATE_HORIZON, dt=PLAN_STEP))
    gate_rows, rows[:] = sum(rows), []
    full = success(simulate(system, counting, x0, T=20.0, dt=PLAN_STEP), system)
    np.testing.assert_array_equal(verdicts, full)
    assert 0 < full.sum() < len(x0)  # both verdicts occur
    assert gate_rows < 0.8 * sum(rows)


def test_the_gate_never_keeps_a_recovery_law_that_shrinks_the_basin_near_x_star():
    # (half-box, training-box, near-box) successes of the run's law and of each inner box r
    run = (40, 20, 50)
    assert gate_choice(run, {0.1: (38, 35, 50), 0.5: (40, 24, 50)}, margin=3) == (0.5, True)  # r = 0.1 wins more but loses 2 on the half box
    assert gate_choice(run, {0.1: (38, 35, 50), 0.5: (40, 22, 50)}, margin=3) == (0.5, False)  # the eligible one adds 2 < 3
    assert gate_choice(run, {0.1: (38, 35, 50)}, margin=3) == (None, False)
    assert gate_choice(run, {0.1: (38, 35, 50)}, margin=3, half_loss=2) == (0.1, True)
    assert gate_choice(run, {0.1: (45, 35, 46)}, margin=3) == (None, False)  # far better, but loses 4 near x*
    assert gate_choice(run, {0.1: (45, 35, 46), 0.5: (41, 23, 50)}, margin=3) == (0.5, True)
    assert gate_choice(run, {0.1: (41, 30, 50), 0.25: (45, 25, 50)}, margin=3) == (0.1, True)  # most in all, not most on the half box
    assert gate_choice(run, {0.1: (42, 30, 50), 0.25: (40, 32, 50)}, margin=3) == (0.25, True)  # ties: the larger inner box


def test_the_default_gate_forgives_two_lost_states_near_x_star_not_six():
    # gate counts measured with the default path (half box, training box, near box)
    half_loss = RecoveryConfig().half_loss
    wheel_run, wheel = (33, 47, 98), {0.1: (49, 49, 95), 0.25: (49, 49, 96), 0.5: (47, 49, 96)}  # reaction wheel, 2 N·m
    assert gate_choice(wheel_run, wheel, margin=3, half_loss=half_loss) == (0.25, True)
    assert gate_choice(wheel_run, wheel, margin=3, half_loss=0) == (None, False)
    pendubot_run, pendubot = (32, 19, 99), {0.5: (35, 32, 93)}  # zoo pendubot, 20 N·m: 6 near states lost
    assert gate_choice(pendubot_run, pendubot, margin=3, half_loss=half_loss) == (None, False)


def test_where_the_run_s_law_brings_the_whole_half_box_the_gate_forgives_no_loss_there():
    # the paper cartpole's seed 1 (default path): its run's law brings all 50 half-box gate states
    # to x*; the law the forgiving rule kept lost 9 of the evaluation's 200 half-box states
    half_loss = RecoveryConfig().half_loss
    cartpole_run, cartpole = (50, 40, 100), {0.1: (48, 49, 100), 0.25: (48, 49, 100), 0.5: (46, 48, 100)}
    assert gate_choice(cartpole_run, cartpole, margin=3, half_loss=half_loss) == (0.25, True)  # half_states unknown: 2 forgiven
    assert gate_choice(cartpole_run, cartpole, margin=3, half_loss=half_loss, half_states=50) == (None, False)
    assert gate_choice(cartpole_run, {0.5: (50, 45, 99)}, margin=3, half_loss=half_loss, half_states=50) == (0.5, True)  # near x*: still 2 forgiven
    wheel_run, wheel = (33, 47, 98), {0.25: (49, 49, 96)}  # a run's law short of the whole half box: unchanged
    assert gate_choice(wheel_run, wheel, margin=3, half_loss=half_loss, half_states=50) == (0.25, True)


@pytest.mark.parametrize("effort, head", [
    ({"shoulder": 20.0, "elbow": 20.0}, "torque limits: saturated LQR"),
    ({"shoulder": 20.0, "elbow": np.inf}, "torque limits on 1 of 2 inputs (a recovery law plans the others within ±"),
    ({"shoulder": np.inf, "elbow": np.inf}, "no effort limits (a recovery law plans within ±"),
])
def test_train_says_which_inputs_plan_within_their_limit_and_which_within_lqr_s_demand(capsys, effort, head):
    system = ip.load_system("double_pendulum", effort=effort)
    bound = plan_bound(system)
    weak_actuators._tell({"states": 100, "saturated": 80, "unsaturated": 90, "binds": True, "room": True}, "half", system)
    line = capsys.readouterr().out
    assert line.startswith(head) and "it fails on 20: fitting a recovery law" in line
    free = [f"±{b:.3g}" for b, e in zip(bound, effort.values()) if not np.isfinite(e)]
    assert all(b in line for b in free) and line.count("±") == len(free)  # a limited input is not listed as planned within LQR's demand


TINY = dict(starts=4, dagger=1, dagger_starts=2, width=8, steps=30, gate_states=4, near_states=2, confirm_states=2, inner_scales=(0.25,), workers=1, fits=1, library=False,
            plan=PlanSettings(horizon=0.5, ilqr_iterations=4), judge_T=8.0)  # fmt: skip (one fit and no library: the tests of --fits and of the library set their own)


@pytest.mark.parametrize("near_of_the_best", [90, 80])
def test_of_several_fits_the_gate_keeps_the_eligible_one_that_brings_most_states_to_x_star(tiny_run, monkeypatch, near_of_the_best):
    laws = [random_law(tiny_run.system, 0.0, seed=k) for k in range(3)]
    # (half box, training box, near box) successes of 50, 50 and 100 gate states; the run's law: (25, 25, 90)
    counts = {id(law.weights): c for law, c in zip(laws, [(30, 30, 90), (40, 40, near_of_the_best), (35, 35, 90)])}

    def fake(job):
        system, ctrl, x0 = job
        fb = ctrl.fallback
        h, d, near = counts[id(fb.weights)] if isinstance(fb, RecoveryLaw) else (25, 25, 90)
        ok = np.zeros(len(x0), bool)
        ok[:h], ok[50 : 50 + d], ok[100 : 100 + near] = True, True, True
        return ok

    monkeypatch.setattr(recovery_gate, "compare_laws", _as_compare(fake))
    k, gate = recovery_gate.choose_fit(tiny_run, laws, RecoveryConfig(gate_states=100, near_states=100, workers=1))
    assert gate["fits"] == [60, 80, 70] and gate["used"]
    assert k == gate["fit"] == (1 if near_of_the_best == 90 else 2)  # 10 fewer near x* than the run's law: not eligible
    assert [g["with_recovery"] for g in gate["fit_gates"]] == gate["fits"]  # every fit's own gate is kept, not only the chosen one
    assert gate["fit_gates"][1]["candidates_near"][0.25] == near_of_the_best  # the second fit's own near-box count
    none_kept = recovery_gate.choose_fit(tiny_run, laws, RecoveryConfig(gate_states=100, near_states=100, margin=50, workers=1))
    assert none_kept[0] == 1 and not none_kept[1]["used"]  # none kept: the refused law saved is the one that brought most
    runs = []

    def counting(job):  # the run's own law is the one without a recovery law
        runs.append(not isinstance(job[1].fallback, RecoveryLaw))
        return fake(job)

    monkeypatch.setattr(recovery_gate, "compare_laws", _as_compare(counting))
    known, config = {}, RecoveryConfig(gate_states=100, near_states=100, workers=1)
    recovery_gate.choose_fit(tiny_run, laws[:1], config, known=known)  # the reach stage's first gate, then its second
    assert recovery_gate.choose_fit(tiny_run, laws, config, known=known) == (k, gate) and sum(runs) == 1  # the run's law simulated once


def test_a_level_that_loses_the_near_box_is_never_run_from_the_box_states(tiny_run, monkeypatch):
    """A level of H_d whose law brings more than `half_loss` fewer near-box states to x* than the
    run's law is never eligible, whatever the rest: the gate runs it from the near box only, and its
    line says so. The inner boxes run from every state in one batch, as before."""
    laws = [random_law(tiny_run.system, 0.0, seed=k) for k in range(2)]
    near = {id(laws[0].weights): 88, id(laws[1].weights): 87}  # each law's level; the run's law: 90 of 100, half_loss 2
    config = RecoveryConfig(gate_states=100, near_states=100, inner_scales=(0.5,), levels=(0.25,), workers=1)
    simulated = []

    def fake(job):
        system, ctrl, x0 = job
        fb = ctrl.fallback
        key = id(fb.weights) if isinstance(fb, RecoveryLaw) else None
        ok = np.zeros(len(x0), bool)
        ok[:30], ok[50:80], ok[100 : 100 + (near[key] if key and fb.uses_level else 90)] = True, True, True  # every box as the run's law
        return ok

    compare = _as_compare(fake)

    def counting(system, runs, **kw):
        runs = list(runs)
        simulated.extend((id(law.fallback.weights), law.fallback.uses_level, len(x0)) if isinstance(law.fallback, RecoveryLaw) else (None, len(x0))
                         for law, x0 in runs)
        yield from compare(system, runs, **kw)

    monkeypatch.setattr(recovery_gate, "compare_laws", counting)
    k, gate = recovery_gate.choose_fit(tiny_run, laws, config)
    first, second = (id(law.weights) for law in laws)
    expected = [(None, 200), (first, False, 200), (second, False, 200), (first, True, 100), (second, True, 100), (first, True, 100)]
    assert sorted(simulated, key=str) == sorted(expected, key=str)  # the second law's level: from the near box only
    assert gate["fits"] == [60, 60] and k == 0 and not gate["used"]  # as many as the run's law: no margin
    level_gates = [(g["level_candidates"], g["level_candidates_near"]) for g in gate["fit_gates"]]
    assert [list(c.values()) for c, _ in level_gates] == [[60], [None]] and [list(c.values()) for _, c in level_gates] == [[88], [87]]
    assert "–: too few near x* to be eligible" in recovery_gate.format_gate(gate["fit_gates"][1], config.margin, config.half_loss)


@pytest.mark.parametrize("lost", [2, 3])
@pytest.mark.parametrize("run_half", [50, 49])
def test_where_the_run_s_law_holds_the_whole_half_box_a_kept_law_is_checked_again_on_half_box_states_of_their_own(tiny_run, monkeypatch, lost, run_half):
    """Paper cartpole seed 4: the kept law brought all 50 half-box gate states to x* and 189 of the
    evaluation's 200. Where the run's law brings every half-box gate state to x*, each law the rule
    keeps runs again from `confirm_states` half-box states the choice never saw, and is refused if it
    brings more than `half_loss` fewer of them to x* than the run's law; elsewhere nothing more runs."""
    laws = [random_law(tiny_run.system, 0.0, seed=k) for k in range(2)]
    gate_counts = {id(laws[0].weights): (50, 40, 100), id(laws[1].weights): (50, 35, 100)}  # the rule keeps both; the first brings more
    confirm_lost = {None: 0, id(laws[0].weights): lost, id(laws[1].weights): 0}
    config = RecoveryConfig(gate_states=100, near_states=100, confirm_states=60, workers=1)
    confirm_x0 = []

    def fake(job):
        system, ctrl, x0 = job
        key = id(ctrl.fallback.weights) if isinstance(ctrl.fallback, RecoveryLaw) else None
        ok = np.zeros(len(x0), bool)
        if len(x0) == config.confirm_states:
            confirm_x0.append(x0)
            ok[: len(x0) - confirm_lost[key]] = True
            return ok
        h, d, near = gate_counts[key] if key else (run_half, 25, 100)
        ok[:h], ok[50 : 50 + d], ok[100 : 100 + near] = True, True, True
        return ok

    monkeypatch.setattr(recovery_gate, "compare_laws", _as_compare(fake))
    k, gate = recovery_gate.choose_fit(tiny_run, laws, config)
    assert gate["used"]
    if run_half < 50:  # the run's law misses a half-box gate state: the rule alone decides
        assert k == 0 and not confirm_x0 and "confirm" not in gate
        return
    assert len(confirm_x0) == 3  # the run's law once, then each kept law
    assert k == (0 if lost <= config.half_loss else 1)
    assert gate["confirm"] == [{"states": 60, "run": 60, "law": 60 - confirm_lost[id(laws[k].weights)], "inner_scale": 0.5}]
    lo, hi = evaluation_box(tiny_run.system, "half")
    assert np.all((confirm_x0[0] >= lo) & (confirm_x0[0] <= hi))
    assert f"on 60 other half-box states the run's law brings 60, with the recovery law {gate['confirm'][0]['law']} (r = 0.5)" in recovery_gate.format_gate(gate, config.margin, config.half_loss)


def test_a_law_the_check_refuses_at_every_inner_box_is_judged_at_the_levels_of_h_d_and_checked_again(tiny_run, monkeypatch):
    """Paper cartpole seed 4 again: its law lost states of the check at r = 0.5, and the IDA-PBC law
    keeping {H_d ≤ c} lost none; the gate keeps the level, and its line names both checks."""
    law = random_law(tiny_run.system, 0.0)
    config = RecoveryConfig(gate_states=100, near_states=100, confirm_states=60, workers=1)

    def fake(job):
        system, ctrl, x0 = job
        fb = ctrl.fallback
        ok = np.zeros(len(x0), bool)
        if len(x0) == config.confirm_states:
            ok[: len(x0) - (5 if isinstance(fb, RecoveryLaw) and not fb.uses_level else 0)] = True
            return ok
        h, d, near = (50, 25, 100) if not isinstance(fb, RecoveryLaw) else (50, 45, 100) if fb.uses_level else (50, 40, 100)
        ok[:h], ok[50 : 50 + d], ok[100 : 100 + near] = True, True, True
        return ok

    monkeypatch.setattr(recovery_gate, "compare_laws", _as_compare(fake))
    _, gate = recovery_gate.choose_fit(tiny_run, [law], config)
    levels = recovery_gate.energy_levels(tiny_run, config.levels)
    assert gate["used"] and gate["level"] == max(levels)  # ties: the largest c, the most IDA-PBC
    assert [c["law"] for c in gate["confirm"]] == [55, 60] and gate["confirm"][0]["inner_scale"] == 0.5 and gate["confirm"][1]["level"] == gate["level"]
    line = recovery_gate.format_gate(gate, config.margin, config.half_loss)
    assert f"with the recovery law 55 (r = 0.5), 60 (H_d > {gate['level']:.3g}): kept, the IDA-PBC law keeping H_d ≤ {gate['level']:.3g}" in line


@pytest.mark.parametrize("box_kept", [True, False])
def test_levels_of_h_d_are_tried_only_when_no_inner_box_is_kept(tiny_run, tmp_path, monkeypatch, box_kept):
    """The gate judges the law with the IDA-PBC law keeping {H_d ≤ c} only when every inner box is
    refused, by the same rule; a law kept that way is saved with its level and applied with it."""
    law = random_law(tiny_run.system, 0.0)
    config = RecoveryConfig(gate_states=100, near_states=100, workers=1)
    levels = recovery_gate.energy_levels(tiny_run, config.levels)
    assert levels == sorted(levels) and len(set(levels)) == 3
    by_level = dict(zip(levels, [(40, 40, 80), (35, 35, 89), (30, 30, 90)]))  # the lowest c loses 10 near x*
    simulated = []

    def fake(job):
        system, ctrl, x0 = job
        fb = ctrl.fallback
        simulated.append(fb.level if isinstance(fb, RecoveryLaw) else None)
        box = (30, 30, 90) if box_kept else (45, 45, 70)
        h, d, near = (25, 25, 90) if not isinstance(fb, RecoveryLaw) else by_level[fb.level] if fb.uses_level else box
        ok = np.zeros(len(x0), bool)
        ok[:h], ok[50 : 50 + d], ok[100 : 100 + near] = True, True, True
        return ok

    monkeypatch.setattr(recovery_gate, "compare_laws", _as_compare(fake))
    k, gate = recovery_gate.choose_fit(tiny_run, [law], config)
    assert gate["used"]
    if box_kept:
        assert all(c is None or c == np.inf for c in simulated) and "level" not in gate
        return
    assert gate["level"] == levels[1] and gate["inner_scale"] == 0.0 and gate["with_recovery"] == 70
    assert gate["level_candidates"] == dict(zip(levels, [None, 70, 60]))  # the lowest c: screened out near x*
    path = tmp_path / "run"
    shutil.copytree(tiny_run.path, path)
    run = ip.load_run(path)
    recovery_gate.save_recovery(run, law, {"used": True, "inner_scale": 0.0, "level": gate["level"], "gate": gate})
    assert ip.load_run(path).controller.fallback.level == levels[1]


def _idle_law(system) -> RecoveryLaw:
    """A recovery law that applies no torque anywhere: it brings no start of the half box to x*."""
    law = random_law(system, 0.0)
    return replace(law, weights=tuple(0.0 * w for w in law.weights), biases=tuple(0.0 * b for b in law.biases))


@pytest.mark.parametrize("stop_when_lost", [True, False])
def test_dagger_labels_nothing_after_a_first_fit_that_loses_every_start(weak_pendubot, monkeypatch, stop_when_lost):
    """A first fit that loses every DAgger start ends the rounds before any plan is searched
    (stop_when_lost); without it the round labels the states those failures visit."""
    labelled = []

    def labels(system, x0, *args, **kwargs):
        labelled.append(len(x0))
        return np.zeros((1, system.n)), np.zeros((1, system.m)), 0, 0

    monkeypatch.setattr(recovery_module, "collect_labels", labels)
    config = RecoveryConfig(**(TINY | {"dagger_starts": 3, "stop_when_lost": stop_when_lost}))
    X, U = np.zeros((4, weak_pendubot.n)), np.zeros((4, weak_pendubot.m))
    law = _idle_law(weak_pendubot)
    out, X2, U2, info = recovery_module.dagger_round(weak_pendubot, law, X, U, 0, config, progress=False)
    assert info["failed"] == 3
    if stop_when_lost:
        assert info["stopped"] and labelled == [] and out is law and X2 is X and U2 is U
    else:
        assert "stopped" not in info and labelled == [9] and len(X2) == 5  # 3 failures × 3 visited times, 1 label each


def test_a_first_fit_that_loses_every_start_but_rests_near_x_star_gets_its_dagger_rounds(monkeypatch):
    """A law that brings every start to rest 0.2 m from x* (the cartpole's LQR plus 0.2 N) fails the
    success test from all of them, but ends in the near box: DAgger labels the states it visits
    instead of stopping (0.5 N rests 0.5 m away, outside the near box, and stops)."""
    system = ip.load_system("cartpole")
    lqr = LQRController(system)
    near = uniform_states(system, 3, scaled_box(system, 0.05), 0)
    monkeypatch.setattr(recovery_module, "uniform_states", lambda *args: near)
    labelled = []

    def labels(system, x0, *args, **kwargs):
        labelled.append(len(x0))
        return np.zeros((1, system.n)), np.zeros((1, system.m)), 0, 0

    monkeypatch.setattr(recovery_module, "collect_labels", labels)
    monkeypatch.setattr(recovery_module, "fit_recovery_law", lambda system, X, U, *a: (None, 0.0))
    config = RecoveryConfig(**(TINY | {"dagger_starts": 3}))
    X, U = np.zeros((4, system.n)), np.zeros((4, system.m))
    for bias, stops in ((0.2, False), (0.5, True)):
        law = SimpleNamespace(law=lambda x, b=bias: lqr(x) + b, residual=False)
        _, _, _, info = recovery_module.dagger_round(system, law, X, U, 0, config, progress=False)
        assert info["failed"] == 3 and info.get("stopped", False) == stops
    assert labelled == [9]  # only the 0.2 N law's round: 3 failures × 3 visited times


def test_the_near_box_is_the_gates_around_x_star_with_angles_wrapped():
    system = ip.load_system("cartpole")
    lo, hi = scaled_box(system, NEAR_SCALE)
    x_star = np.asarray(system.x_star)
    inside = np.stack([x_star, 0.99 * hi, 0.99 * lo, x_star + np.where(system.angle_mask, 2 * np.pi, 0.0)])
    outside = np.stack([x_star + 1.01 * (hi - x_star) * np.eye(system.n)[k] for k in range(system.n)])
    assert ends_near(inside, system).all() and not ends_near(outside, system).any()


@pytest.mark.parametrize("box", ["half", "domain"])
def test_the_labels_and_dagger_start_from_the_box_the_config_names(tiny_run, monkeypatch, box):
    """`start_box` decides where the plans' starts and the DAgger starts are drawn: the half box by
    default, the training box where saturated LQR leaves room only there."""
    drawn, starts = [], []
    real = recovery_module.uniform_states

    def spy(system, n, which, seed):
        drawn.append(which)
        return real(system, n, which, seed)

    class Stop(Exception):
        pass

    def labels(system, x0, *args, **kwargs):
        starts.append(x0)
        raise Stop

    monkeypatch.setattr(recovery_module, "uniform_states", spy)
    monkeypatch.setattr(recovery_module, "collect_labels", labels)
    config = RecoveryConfig(**(TINY | {"starts": 200, "start_box": box}))
    with pytest.raises(IdapbcError, match=r"the recovery stage failed \(Stop\)"):  # a failure inside the stage: one line
        recover(tiny_run.path, config, progress=False)
    system = tiny_run.system
    (x0,) = starts
    lo, hi = evaluation_box(system, box)
    half_lo, half_hi = evaluation_box(system, "half")
    assert drawn == [box] and np.all((x0 >= lo) & (x0 <= hi))
    assert np.any((x0 < half_lo) | (x0 > half_hi)) == (box == "domain")  # 200 training-box states: some outside the half box
    X, U = np.zeros((4, system.n)), np.zeros((4, system.m))
    recovery_module.dagger_round(system, _idle_law(system), X, U, 0, config, progress=False)
    assert drawn == [box, box]


def test_a_start_box_that_is_neither_half_nor_domain_is_refused_in_one_line():
    with pytest.raises(IdapbcError, match="start_box must be one of half, domain"):
        RecoveryConfig(start_box="quarter")


def test_with_the_run_as_teacher_the_labels_near_x_star_are_the_run_s_own_saturated_law(tiny_run):
    """`teacher` = a law: the starts it brings to x* are labelled with its own torques (saturated),
    states sampled every LABEL_EVERY ticks of its trajectory: the fitted law imitates it there."""
    system, teacher = tiny_run.system, tiny_run.own_controller
    x0 = uniform_states(system, 3, scaled_box(system, 0.02), 101)  # right by x*: the run's law holds them
    X, U, taught, recovered = collect_labels(system, x0, 101, RecoveryConfig(workers=1), progress=False, teacher=teacher)
    assert (taught, recovered) == (3, 0) and len(X) == 3 * (LABEL_SPAN // LABEL_EVERY)
    np.testing.assert_allclose(U, system.saturate(teacher(X)), rtol=0, atol=1e-9)
    lqr = system.saturate(LQRController(system)(X))
    assert np.abs(U - lqr).max() > 1e-6  # not LQR's torques


@pytest.mark.parametrize("teacher", ["lqr", "run"])
def test_recover_hands_the_teacher_the_config_names_to_the_labels(tiny_run, monkeypatch, teacher):
    """`teacher` = "lqr" labels with saturated LQR (None: `collect_labels`' own), "run" with the
    run's law without a recovery law (`Run.own_controller`)."""
    given = []

    class Stop(Exception):
        pass

    def labels(system, x0, plan_seed, config, progress, law, *store, **pilot):
        given.append(law)
        raise Stop

    monkeypatch.setattr(recovery_module, "collect_labels", labels)
    with pytest.raises(IdapbcError, match=r"the recovery stage failed \(Stop\)"):  # a failure inside the stage: one line
        recover(tiny_run.path, RecoveryConfig(**(TINY | {"teacher": teacher})), progress=False)
    (law,) = given
    if teacher == "lqr":
        assert law is None
    else:
        x = uniform_states(tiny_run.system, 50, "domain", seed=4)
        np.testing.assert_array_equal(law(x), tiny_run.own_controller(x))


def test_a_teacher_that_is_neither_lqr_nor_run_is_refused_in_one_line():
    with pytest.raises(IdapbcError, match="teacher must be one of lqr, run"):
        RecoveryConfig(teacher="mpc")


def test_the_run_s_own_law_is_its_law_without_the_recovery_law_and_keeps_the_inside_gain(tiny_run, tmp_path):
    """`Run.own_controller`: the networks, and the linear law outside the box with the gate's
    inside gain where the run uses it, never an earlier recovery law (what the gate compares with)."""
    path, law = _with_recovery(tiny_run, tmp_path)
    summary = json.loads((path / "summary.json").read_text())
    summary["fallback"] = {"used": True, "inside_gain": 3.0, "inside_ramp": [0.2, 0.5]}
    (path / "summary.json").write_text(json.dumps(summary))
    run = ip.load_run(path)
    own = run.own_controller
    assert isinstance(run.fallback, RecoveryLaw) and own.fallback.inside_gain == 3.0 and own.fallback.inside_ramp == (0.2, 0.5)
    x = uniform_states(run.system, 200, "domain", seed=3)
    alone = own.with_governor(False)  # the laws alone; the governor comes after them, last
    np.testing.assert_allclose(alone(x), own.fallback.apply(x, run.controller.with_fallback(None).with_governor(False)(x)), atol=1e-12)
    assert not np.allclose(own(x), run.controller(x))


@pytest.mark.slow
def test_recover_keeps_the_law_exactly_when_its_gate_does(tiny_run, tmp_path, monkeypatch):
    _short_gate(monkeypatch)
    plan_once(monkeypatch)
    path = tmp_path / "run"
    shutil.copytree(tiny_run.path, path)
    kept = recover(path, RecoveryConfig(**TINY, margin=-4, half_loss=2), progress=False)  # kept whatever the gate sees
    assert kept["used"] and (path / RECOVERY_FILE).is_file()
    assert kept["gate"]["states"] == 4 and all(0 <= s <= 4 for s in kept["gate"]["candidates"].values())
    assert all(0 <= kept["gate"]["candidates_half"][r] <= min(2, s) for r, s in kept["gate"]["candidates"].items())
    assert kept["gate"]["near_states"] == 2 and all(0 <= s <= 2 for s in kept["gate"]["candidates_near"].values())
    assert len(kept["dagger"]) == 1 and kept["labels"] > 0
    X, U = read_labels(path, tiny_run.system.n, tiny_run.system.m)  # saved for --refit
    assert X.shape == (kept["labels"], tiny_run.system.n) and np.all(np.abs(U) <= tiny_run.system.effort)
    run = ip.load_run(path)
    assert run.uses_recovery and isinstance(run.controller.fallback, RecoveryLaw)
    np.testing.assert_allclose(run.controller.fallback.inner, kept["inner_scale"] * run.controller.fallback.scale)
    x = uniform_states(run.system, 200, "domain", seed=5)
    u = run.controller(x)
    outside = run.controller.fallback.outside(x)
    assert outside.any()
    np.testing.assert_allclose(u[outside], run.controller.fallback.law(x[outside]), atol=1e-12)
    assert json.loads((path / "summary.json").read_text())["recovery"]["used"] is True

    dropped = recover(path, RecoveryConfig(**TINY, margin=5), progress=False)  # more than the 4 states: never kept
    assert not dropped["used"] and not (path / RECOVERY_FILE).exists()
    assert (path / RECOVERY_REFUSED_FILE).is_file()  # kept aside for --regate, never applied
    assert json.loads((path / "summary.json").read_text())["recovery"]["law_file"] == RECOVERY_REFUSED_FILE
    run = ip.load_run(path)
    assert not run.uses_recovery and not isinstance(run.controller.fallback, RecoveryLaw)


def _with_refused(tiny_run, tmp_path):
    """A copy of `tiny_run` whose last `recover` refused a (random) law, as recover leaves it."""
    path = tmp_path / "run"
    shutil.copytree(tiny_run.path, path)
    law = random_law(tiny_run.system, 0.25)
    np.savez(path / RECOVERY_REFUSED_FILE, **law.arrays())
    entry = {"used": False, "inner_scale": 0.25, "gate": {"states": 4}, "labels": 123, "law_file": RECOVERY_REFUSED_FILE}
    (path / "summary.json").write_text(json.dumps(json.loads((path / "summary.json").read_text()) | {"recovery": entry}))
    return path, law


def test_regate_judges_the_saved_law_again_without_fitting_and_keeps_it_exactly_when_its_gate_does(tiny_run, tmp_path, monkeypatch, capsys):
    path, law = _with_refused(tiny_run, tmp_path)

    def no_fit(*args, **kwargs):
        raise AssertionError("regate must not label or fit")

    monkeypatch.setattr(recovery_module, "collect_labels", no_fit)
    monkeypatch.setattr(recovery_module, "fit_recovery_law", no_fit)
    _short_gate(monkeypatch)
    kept = regate(path, RecoveryConfig(**TINY, margin=-4, half_loss=2), progress=False)  # kept whatever the gate sees
    assert kept["used"] and not kept["forced"] and kept["labels"] == 123 and kept["regated"]["from"]["used"] is False
    assert (path / RECOVERY_FILE).is_file() and not (path / RECOVERY_REFUSED_FILE).exists()
    fallback = ip.load_run(path).controller.fallback
    assert isinstance(fallback, RecoveryLaw)
    for a, b in zip(fallback.weights + fallback.biases, law.weights + law.biases):
        np.testing.assert_array_equal(a, b)  # the very law recover fitted, now applied at the gate's inner box
    np.testing.assert_allclose(fallback.inner, kept["inner_scale"] * fallback.scale)

    dropped = regate(path, RecoveryConfig(**TINY, margin=5), progress=False)  # more than the 4 states: never kept
    assert not dropped["used"] and not (path / RECOVERY_FILE).exists() and (path / RECOVERY_REFUSED_FILE).is_file()
    assert not ip.load_run(path).uses_recovery

    (tmp_path / "margin.toml").write_text("[recovery]\nmargin = 5\ngate_states = 4\nnear_states = 2\nconfirm_states = 2\njudge_T = 8.0\n")
    stale = json.loads((path / "summary.json").read_text())
    stale["recovery"]["governor_margin"] = 99.0  # an earlier entry's margin: the law kept now is judged afresh
    (path / "summary.json").write_text(json.dumps(stale))
    judged = []  # the margin each catch_margin call's law is governed at
    real = recovery_module.catch_margin
    monkeypatch.setattr(recovery_module, "catch_margin", lambda system, law, *a: judged.append(law.governor_margin) or real(system, law, *a))
    assert main(["recover", str(path), "--regate", "--config", str(tmp_path / "margin.toml"), "--keep"]) == 0
    assert "kept anyway (--keep)" in capsys.readouterr().out
    entry = json.loads((path / "summary.json").read_text())["recovery"]
    assert entry["used"] and entry["forced"] and entry["gate"]["used"] is False
    assert ip.load_run(path).uses_recovery
    assert judged == [ENERGY_MARGIN]
    assert ENERGY_MARGIN <= entry["governor_margin"] < 99.0 and ip.load_run(path).governor_margin == entry["governor_margin"]


def test_regate_without_a_saved_law_says_what_to_run_in_one_line(tiny_run, tmp_path, capsys):
    path = tmp_path / "run"
    shutil.copytree(tiny_run.path, path)
    assert main(["recover", str(path), "--regate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no recovery law to judge again" in err[0] and "idapbc-pin recover" in err[0]
    older = json.loads((path / "summary.json").read_text()) | {"recovery": {"used": False, "inner_scale": 0.25, "gate": {}}}
    (path / "summary.json").write_text(json.dumps(older))  # refused by a recover that kept no refused law
    assert main(["recover", str(path), "--regate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and RECOVERY_REFUSED_FILE in err[0] and "again" in err[0]


def _as_compare(fake):
    """A stand-in for `compare_laws` in the gate, from ``fake((system, law, x0)) -> (N,) bool`` on the
    gate's states in their order (half box, training box, near box). The gate's first run is the
    run's law from all of them; a later run from a part of them (a candidate from the near box first,
    then from the boxes) gets that part of the fake's answer; other states (the confirmation's) go
    to the fake as they are."""
    every = []

    def compare(system, runs, **_):
        for law, x0 in runs:
            if not every:
                every.append(x0)
            whole = every[0]
            at = np.flatnonzero((whole == x0[0]).all(axis=1)) if len(x0) < len(whole) else []
            if len(at) and np.array_equal(whole[at[0] : at[0] + len(x0)], x0):
                yield fake((system, law, whole))[at[0] : at[0] + len(x0)], None
            else:
                yield fake((system, law, x0)), None

    return compare


def plan_once(monkeypatch) -> None:
    """`collect_labels` plans each set of starts once per test: the tests that call `recover` on the
    same run several times claim what the gate keeps, and the starts, seeds and plans are the same
    each time (a call's plans are real; the later calls get copies of its labels)."""
    planned, collect = {}, recovery_module.collect_labels

    def once(system, x0, plan_seed, config, *args, **kwargs):
        key = (x0.tobytes(), plan_seed)
        if key not in planned:
            planned[key] = collect(system, x0, plan_seed, config, *args, **kwargs)
        return tuple(a.copy() if isinstance(a, np.ndarray) else a for a in planned[key])

    monkeypatch.setattr(recovery_module, "collect_labels", once)


def _short_gate(monkeypatch):
    """The gate's runs last 1 s instead of 20 s: these tests claim what is kept and where, and their
    margins decide whatever the counts (the gate's rule has tests of its own)."""
    monkeypatch.setattr(recovery_gate, "GATE_HORIZON", 1.0)  # read in this process: the workers get it with their jobs


def test_refit_fits_the_saved_labels_again_without_plans_and_the_same_seed_gives_the_same_law(tiny_run, tmp_path, monkeypatch):
    path, _ = _with_refused(tiny_run, tmp_path)
    system = tiny_run.system
    X = sample_domain(system, 300, seed=4)
    U = system.saturate(-wrap_angles(X - system.x_star, system.angle_mask) @ LQRController(system).K.T)
    save_labels(path, X, U)

    def no_plans(*args, **kwargs):
        raise AssertionError("refit must not search plans")

    monkeypatch.setattr(recovery_module, "collect_labels", no_plans)
    _short_gate(monkeypatch)
    config = RecoveryConfig(**TINY | {"steps": 200}, margin=-4, half_loss=2, fit_seed=1)  # kept whatever the gate sees
    entry = refit(path, config, progress=False)
    assert entry["used"] and entry["refit"]["fit_seed"] == 1 and entry["refit"]["labels"] == 300
    assert (path / RECOVERY_FILE).is_file() and not (path / RECOVERY_REFUSED_FILE).exists()
    expected, mse = fit_recovery_law(system, X, U, config.width, config.steps, seed=1)
    assert entry["refit"]["mse"] == mse
    fallback = ip.load_run(path).controller.fallback
    for a, b in zip(fallback.weights + fallback.biases, expected.weights + expected.biases):
        np.testing.assert_array_equal(a, b)
    other = refit(path, replace(config, fit_seed=2), progress=False)
    assert other["refit"]["fit_seed"] == other["fit_seed"] == 2
    assert not np.array_equal(ip.load_run(path).controller.fallback.weights[0], expected.weights[0])
    best = refit(path, replace(config, fit_seed=1, fits=2), progress=False)  # seeds 1 and 2, the gate keeps one
    assert best["fit_seed"] in (1, 2) and best["gate"]["fits"] and best["gate"]["fit"] == best["fit_seed"] - 1
    saved = json.loads((path / "summary.json").read_text())["recovery"]["gate"]
    assert [g["with_recovery"] for g in saved["fit_gates"]] == saved["fits"]  # both fits' gates on disk
    chosen, _ = fit_recovery_law(system, X, U, config.width, config.steps, seed=best["fit_seed"])
    np.testing.assert_array_equal(ip.load_run(path).controller.fallback.weights[0], chosen.weights[0])


def test_refit_in_the_residual_form_fits_corrections_to_the_run_s_own_inputs_and_the_run_applies_them(tiny_run, tmp_path, monkeypatch):
    path, _ = _with_refused(tiny_run, tmp_path)
    system, networks = tiny_run.system, tiny_run.controller.with_fallback(None)
    X = sample_domain(system, 300, seed=4)
    U = system.saturate(-wrap_angles(X - system.x_star, system.angle_mask) @ LQRController(system).K.T)
    save_labels(path, X, U)
    _short_gate(monkeypatch)
    config = RecoveryConfig(**TINY | {"steps": 200}, margin=-4, half_loss=2, fit_seed=1, form="residual")  # kept whatever the gate sees
    entry = refit(path, config, progress=False)
    assert entry["used"] and entry["config"]["form"] == "residual"
    run = ip.load_run(path)
    law = run.controller.fallback
    base = base_inputs(networks, X, system.effort)
    np.testing.assert_array_equal(base, system.saturate(networks(X)))
    expected, mse = fit_recovery_law(system, X, U, config.width, config.steps, seed=1, base=base)
    assert law.residual and entry["refit"]["mse"] == mse
    np.testing.assert_array_equal(law.weights[0], expected.weights[0])
    x = uniform_states(system, 300, "domain", seed=3)
    energy = networks.flow().energy
    np.testing.assert_allclose(run.controller(x), law.apply(x, networks(x), energy), atol=1e-12)
    (tmp_path / "direct.toml").write_text('[recovery]\nform = "direct"\nwidth = 8\nsteps = 20\nfits = 1\n'
                                          'gate_states = 4\nnear_states = 2\nconfirm_states = 2\njudge_T = 8.0\n')
    assert main(["recover", str(path), "--refit", "--config", str(tmp_path / "direct.toml"), "--workers", "1", "--keep"]) == 0
    assert not ip.load_run(path).controller.fallback.residual
    assert json.loads((path / "summary.json").read_text())["recovery"]["config"]["form"] == "direct"


def test_an_interrupted_recover_keeps_its_labels_and_refit_finishes_it(tiny_run, tmp_path, monkeypatch, capsys):
    path = tmp_path / "run"
    shutil.copytree(tiny_run.path, path)
    system = tiny_run.system
    X = sample_domain(system, 50, seed=6)
    U = system.saturate(-wrap_angles(X - system.x_star, system.angle_mask) @ LQRController(system).K.T)
    monkeypatch.setattr(recovery_module, "collect_labels", lambda *args, **kwargs: (X, U, 3, 0))  # the plans' hour, done

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(recovery_module, "dagger_round", interrupted)
    with pytest.raises(KeyboardInterrupt):
        recover(path, RecoveryConfig(**TINY), progress=True)
    said = capsys.readouterr().out
    assert "recover interrupted" in said and f"recover {path} --refit" in said
    X2, U2 = read_labels(path, system.n, system.m)
    np.testing.assert_array_equal(X2, X)
    np.testing.assert_array_equal(U2, U)
    assert "recovery" not in json.loads((path / "summary.json").read_text())
    _short_gate(monkeypatch)
    entry = refit(path, RecoveryConfig(**TINY, margin=-4, half_loss=2), progress=False)
    assert entry["used"] and entry["refit"]["labels"] == 50 and ip.load_run(path).uses_recovery


@pytest.mark.parametrize("damage", ["missing", "garbage", "shape"])
def test_refit_without_good_labels_says_what_to_run_in_one_line(tiny_run, tmp_path, capsys, damage):
    path, _ = _with_refused(tiny_run, tmp_path)
    before = (path / "summary.json").read_bytes()
    if damage == "garbage":
        (path / RECOVERY_LABELS_FILE).write_bytes(b"not a zip file")
    elif damage == "shape":
        save_labels(path, np.zeros((5, tiny_run.system.n + 1)), np.zeros((5, tiny_run.system.m)))
    assert main(["recover", str(path), "--refit"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and RECOVERY_LABELS_FILE in err[0] and "idapbc-pin recover" in err[0], err
    assert (path / "summary.json").read_bytes() == before and (path / RECOVERY_REFUSED_FILE).is_file()


def test_refit_and_regate_are_one_or_the_other(tiny_run, tmp_path, capsys):
    path, _ = _with_refused(tiny_run, tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(["recover", str(path), "--refit", "--regate"])
    assert exit_.value.code == 2 and "not allowed with" in capsys.readouterr().err


def _with_recovery(tiny_run, tmp_path):
    path = tmp_path / "run"
    shutil.copytree(tiny_run.path, path)
    law = random_law(tiny_run.system, 0.25)
    np.savez(path / RECOVERY_FILE, **law.arrays())
    summary = json.loads((path / "summary.json").read_text()) | {"recovery": {"used": True, "inner_scale": 0.25}}
    (path / "summary.json").write_text(json.dumps(summary))
    return path, law


def test_a_run_with_a_recovery_law_applies_it(tiny_run, tmp_path):
    path, law = _with_recovery(tiny_run, tmp_path)
    run = ip.load_run(path)
    x = uniform_states(run.system, 300, "domain", seed=3)
    np.testing.assert_allclose(run.controller(x), law.apply(x, tiny_run.controller.with_fallback(None)(x)), atol=1e-12)


@pytest.mark.parametrize("damage", ["missing", "truncated", "misshapen"])
def test_a_damaged_recovery_law_is_refused_at_load_with_one_line(tiny_run, tmp_path, capsys, damage):
    path, law = _with_recovery(tiny_run, tmp_path)
    target = path / RECOVERY_FILE
    if damage == "missing":
        target.unlink()
    elif damage == "truncated":
        target.write_bytes(target.read_bytes()[:200])
    else:
        np.savez(target, **(law.arrays() | {"W0": np.zeros((2, 2))}))
    with pytest.raises(DamagedFileError, match="recover"):
        ip.load_run(path)
    assert main(["simulate", str(path), "--n", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "recovery.npz" in err[0] and "Fix:" in err[0]


def test_an_input_without_a_limit_plans_within_the_largest_force_lqr_asks_on_the_box():
    """`plan_bound`: a limited input keeps its limit; an unlimited one gets the largest |u| of LQR over
    the training box's corners (where a linear law peaks), found here by evaluating LQR at all 2^n."""
    cartpole = ip.load_system("paper_cartpole")  # built-in: no limits; box centred on x*, u* = 0
    lo, hi = cartpole.domain
    corners = np.array(np.meshgrid(*zip(lo, hi))).reshape(cartpole.n, -1).T
    np.testing.assert_allclose(plan_bound(cartpole), np.abs(LQRController(cartpole)(corners)).max(axis=0), rtol=1e-12)
    assert planning_system(cartpole).effort == pytest.approx(plan_bound(cartpole)) and np.isinf(cartpole.effort).all()
    pendubot = ip.load_system("pendubot")
    assert planning_system(pendubot) is pendubot and plan_bound(pendubot) == pytest.approx(pendubot.effort)
    free = ip.load_system("pendubot", effort={"shoulder": np.inf})
    assert np.isfinite(plan_bound(free)).all() and plan_bound(free)[0] > pendubot.effort[0]


def test_recover_on_a_robot_without_limits_fits_a_law_within_the_plan_bound(tmp_path, monkeypatch):
    """`train --recover` on an actuator without an effort limit plans within `plan_bound`; the saved
    law's ū is that bound, while the robot itself stays unlimited."""
    _short_gate(monkeypatch)
    config, out = tmp_path / "tiny.toml", tmp_path / "runs"
    config.write_text("[train]\nwidth = 8\ndepth = 1\n")
    argv = ["train", "pendubot", "--effort", "shoulder=inf", "--fast", "--epochs", "2", "--config", str(config),
            "--evaluate", "0", "--out", str(out), "--recover", "never"]  # fmt: skip
    assert main(argv) == 0
    (run_dir,) = out.iterdir()
    entry = recover(run_dir, RecoveryConfig(**(TINY | {"start_box": "half", "starts": 8})), progress=False, keep=True)
    run = ip.load_run(run_dir)
    assert entry["used"] and np.isinf(run.system.effort).all()
    np.testing.assert_allclose(run.fallback.effort, plan_bound(run.system), rtol=1e-12)
    X, U = read_labels(run_dir, run.system.n, run.system.m)
    assert np.abs(U).max() <= plan_bound(run.system)[0] * (1 + 1e-12)


# ------------------------------------------------------------------ when `train` recovers on its own
_BINDS: dict = {}


def binds(system, box: str = "half") -> dict:
    """`limits_bind(system, box=box)`, computed once per robot, limits and box in this module: the
    test is deterministic (fixed states, LQR), and several tests ask it of the same robot."""
    key = (system.name, tuple(np.asarray(system.effort, float)), np.asarray(system.domain, float).tobytes(), box)
    if key not in _BINDS:
        _BINDS[key] = limits_bind(system, box=box)
    return dict(_BINDS[key])


def test_the_limits_bind_on_an_8_nm_shoulder_and_not_at_the_zoo_pendubots_20():
    """Saturated LQR loses ≥ 10 % of the half box to an 8 N·m shoulder, not to the URDF's 20 N·m;
    both leave a recovery law room (saturated LQR fails on ≥ 10 %), the cartpole's 50 N slider none."""
    weak = binds(ip.load_system("pendubot", effort={"shoulder": 8.0}))
    zoo = binds(ip.load_system("pendubot"))
    assert weak["binds"] and weak["unsaturated"] - weak["saturated"] >= BIND_POINTS * BIND_STATES / 100
    assert not zoo["binds"] and weak["unsaturated"] == zoo["unsaturated"]  # same states, same unsaturated LQR
    assert weak["room"] and zoo["room"] and BIND_STATES - zoo["saturated"] >= ROOM_POINTS * BIND_STATES / 100
    cartpole = binds(ip.load_system("cartpole"))
    assert not cartpole["room"] and cartpole["saturated"] > (100 - ROOM_POINTS) * BIND_STATES / 100


def test_where_the_half_box_leaves_no_room_the_training_box_is_tested_and_the_plans_start_there(tiny_run, tmp_path, monkeypatch, capsys):
    """The cartpole's 50 N slider leaves no room on the half box and room on the training box:
    `train --recover auto` then fits the recovery law from training-box starts."""
    cartpole = ip.load_system("cartpole")
    wide = binds(cartpole, box="domain")
    assert wide["room"] and BIND_STATES - wide["saturated"] >= ROOM_POINTS * BIND_STATES / 100
    asked = []
    monkeypatch.setattr(weak_actuators, "recover", lambda run, config, progress: asked.append(config.start_box) or {"used": False})
    monkeypatch.setattr(weak_actuators, "limits_bind", lambda system, box="half": {"half": binds(cartpole), "domain": wide}[box])
    assert auto_recover(tiny_run, "auto", RecoveryConfig(**TINY)) == {"used": False} and asked == ["domain"]
    printed = capsys.readouterr().out
    assert "no room there; testing the training box" in printed and "fitting a recovery law from training-box starts" in printed


def test_a_robot_without_limits_is_tested_with_lqr_itself_and_never_binds():
    """No limits: saturated and unsaturated LQR are the same law; the paper cartpole's LQR loses no
    half-box state and ≥ 10 % of its training box (room there), the mass-spring-damper's neither."""
    cartpole = ip.load_system("paper_cartpole")
    half, wide = binds(cartpole), binds(cartpole, box="domain")
    assert half["saturated"] == half["unsaturated"] == BIND_STATES and not half["room"] and not half["binds"]
    assert wide["saturated"] == wide["unsaturated"] and wide["room"] and not wide["binds"]
    msd = ip.load_system("paper_mass_spring_damper")
    assert not binds(msd)["room"] and not binds(msd, box="domain")["room"]


def test_auto_recovers_exactly_when_saturated_lqr_leaves_room(tiny_run, tmp_path, capsys, monkeypatch):
    _short_gate(monkeypatch)
    monkeypatch.setattr(weak_actuators, "limits_bind", lambda system, box="half": binds(system, box))
    path = tmp_path / "run"
    shutil.copytree(tiny_run.path, path)
    config = RecoveryConfig(**TINY, margin=-4)
    assert auto_recover(ip.load_run(path), "never", config) is None
    entry = auto_recover(ip.load_run(path), "auto", config)  # tiny_run: the 8 N·m pendubot
    printed = capsys.readouterr().out
    assert "(the limits bind)" in printed and "fitting a recovery law" in printed
    assert entry["used"] and (path / RECOVERY_FILE).is_file()
    strong = tmp_path / "strong"
    (tmp_path / "tiny.toml").write_text("[train]\nwidth = 8\ndepth = 1\n")
    main(["train", "reaction_wheel", "--fast", "--epochs", "2", "--config", str(tmp_path / "tiny.toml"), "--evaluate", "0", "--recover", "auto",
          "--out", str(strong)])
    printed = capsys.readouterr().out
    assert "(the limits do not bind)" in printed and "testing the training box" in printed and "no recovery law" in printed
    (run_dir,) = strong.iterdir()
    assert not (run_dir / RECOVERY_FILE).exists() and "recovery" not in json.loads((run_dir / "summary.json").read_text())
    with pytest.raises(IdapbcError, match="unknown recover mode"):
        auto_recover(ip.load_run(path), "sometimes", config)


class _Hidden:
    """An outer law with `reads_networks` hidden: the controller then computes the networks on every row."""

    def __init__(self, law):
        self.law = law

    def apply(self, x, u, energy=None):
        return self.law.apply(x, u, energy=energy)


def test_the_controller_computes_the_networks_only_where_its_outer_law_reads_them_and_applies_the_same_inputs(tiny_run):
    """`OuterLaw.reads_networks`: a direct recovery law reads the networks inside its inner box, a
    residual one or one with a level everywhere, a swing-up law inside its kept box where its inner
    law reads them; the inputs equal those computed over every row (NaN never reaches them)."""
    from idapbc_pin.trajectory.tracks import tracking_law, tvlqr_gains
    from tests.test_swing_tracks import _plan

    system, ctrl = tiny_run.system, tiny_run.controller
    x = np.concatenate([sample_domain(system, 300), system.x_star + 3 * (sample_domain(system, 300, seed=1) - system.x_star)])
    U, Z, _ = _plan(system)
    lo, hi = system.domain
    direct = random_law(system, 0.3)
    laws = [direct, random_law(system, 0.3, residual=True), direct.with_level(0.2),
            tracking_law(system, U, Z, tvlqr_gains(system, U, Z), 0.1, 0.5 * (hi - lo)).with_inner(direct)]
    for law in laws:
        reads = law.reads_networks(x)
        assert reads.shape == (len(x),) and (reads.all() if law is not direct and law is not laws[-1] else 0 < reads.mean() < 1)
        u = ctrl.with_fallback(law)(x)
        assert np.isfinite(u).all()
        np.testing.assert_allclose(u, ctrl.with_fallback(_Hidden(law))(x), rtol=0, atol=1e-9)
