"""Torque plans by iterative LQR (`trajectory.ilqr`, `trajectory.plans.plan_candidates`, `TrackThenLaw`)
and the finished chunks a killed recovery stage reads back (`trajectory.chunks`).

Claims:
* the plant's Jacobians in z = (q, v) equal Pinocchio's analytic ABA derivatives, and the knot map's
  (their exponential over a knot) are close to central differences of the plant's rollout;
* iLQR plans stay within the limits, never cost more than their warm start, and bring the plant's
  end state closer to x*; each problem's plan is the one it gets when solved alone;
* the settled end cost is paid per second over the plan's last seconds only, and a plan solved
  with it lies closer to x* over those seconds than one with the plain end cost;
* the rail term keeps a cart that starts fast toward the end of its rail on the rail, where a plan
  without it runs off; its gradient is that of its value;
* tracked iLQR candidates bring a pendubot with an 8 N·m shoulder to x* from half-box states saturated
  LQR loses, in the judge (Pinocchio's aba at 2 ms, the limits applied);
* a plan tracked with its input held over each knot applies one input per knot, U_0 from the plan's
  own start, and ends nearer the plan's end than the same plan tracked at every tick against the
  knot's start state; the reach plans get more iterations at three joints than at two;
* a problem that took no step keeps its Jacobians, and the plans are those of a solver that
  computes every problem's Jacobians at every iteration, to the bit;
* a chunk store gives back exactly what was written, and nothing for another key or a damaged file;
  a labelling step started again after an interruption plans only the chunks it had not finished,
  and ends with the labels of an uninterrupted step;
* kill -9 during the stage leaves a run that works with its own law, and `train --resume RUN`
  finishes the stage.
"""

from __future__ import annotations

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.model.angles import wrap_angles
from idapbc_pin.recovery import stage as stage_module
from idapbc_pin.trajectory import ilqr as ilqr_module
from idapbc_pin.trajectory.chunks import CHUNKS_DIR, ChunkStore, chunk_key
from idapbc_pin.trajectory.ilqr import (SPEED_WEIGHT, ILQRSettings, _knot_jacobians, _limit_terms, _state_limits, field_jacobians, ilqr_plans, plan_cost, plan_weights, rollout,
                                      settle_weights)
from idapbc_pin.errors import IdapbcError
from idapbc_pin.trajectory.plans import AUTO_ITERATIONS, PERIODS, PLAN_STEP, PlanSettings, TrackThenLaw, plan_bound, plan_candidates
from idapbc_pin.trajectory.tracks import KNOT, warm_starts
from idapbc_pin.model.resting import resting_configuration
from idapbc_pin.recovery.stage import RecoveryConfig, collect_labels
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.metrics import speed_limits, success
from idapbc_pin.sim.states import uniform_states


@pytest.fixture(scope="module")
def weak_pendubot():
    return ip.load_system("pendubot", effort={"shoulder": 8.0})


@pytest.fixture(scope="module")
def lost(weak_pendubot):
    """Half-box starts saturated LQR loses on the 8 N·m pendubot, with its inputs there."""
    system = weak_pendubot
    x0 = uniform_states(system, 40, "half", 11)
    traj = simulate(system, LQRController(system), x0, T=20.0, dt=PLAN_STEP)
    idx = np.flatnonzero(~success(traj, system))
    assert idx.size >= 4
    return x0[idx[:4]], traj.u[idx[:4]]


def test_the_field_jacobians_equal_pinocchio_s_aba_derivatives(weak_pendubot):
    """∂ż/∂z and ∂ż/∂u of ż = (v, a(q, v, B u)) by central differences of the pooled ABA, against
    Pinocchio's analytic computeABADerivatives (with the joints' damping τ − D v)."""
    import pinocchio as pin

    system = weak_pendubot
    plant = system.plant
    rng = np.random.default_rng(0)
    x = uniform_states(system, 3, "domain", 3)
    q, v = system.split(x)
    u = rng.uniform(-8, 8, (3, 1))
    J, G = field_jacobians(system, np.concatenate([q, v], axis=1), u)
    nq, B, D = system.nq, np.asarray(system.B), np.diag(plant.damping)
    for k in range(3):
        data = plant.model.createData()
        tau = B @ u[k] - plant.damping * v[k]
        da_dq, da_dv, Minv = (np.array(a) for a in pin.computeABADerivatives(plant.model, data, plant.config(q[k : k + 1])[0], v[k], tau))
        Minv = np.triu(Minv) + np.triu(Minv, 1).T
        np.testing.assert_allclose(J[k, :nq], np.hstack([np.zeros((nq, nq)), np.eye(nq)]), atol=0)
        np.testing.assert_allclose(J[k, nq:, :nq], da_dq, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(J[k, nq:, nq:], da_dv - Minv @ D, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(G[k, nq:], Minv @ B, rtol=1e-6, atol=1e-8)


def test_the_knot_map_s_jacobians_approximate_central_differences_of_the_rollout(weak_pendubot):
    system = weak_pendubot
    x = uniform_states(system, 3, "domain", 3)
    z = np.concatenate(system.split(x), axis=1)
    u, dt = np.array([[3.0], [-8.0], [0.0]]), 0.02
    A, B = _knot_jacobians(system, z, u, dt)
    step = lambda zs, us: rollout(system, zs, us[:, None, :], dt, 4)[:, 1]  # noqa: E731
    h = 1e-6
    A_fd = np.stack([(step(z + h * e, u) - step(z - h * e, u)) / (2 * h) for e in np.eye(system.n)], axis=-1)
    B_fd = (step(z, u + h) - step(z, u - h)) / (2 * h)
    # the field frozen at the knot's start: within a tenth of the largest entry over 20 ms (the line search judges on the true rollout)
    assert np.abs(A - A_fd).max() < 0.1 * np.abs(A_fd).max() and np.abs(B[:, :, 0] - B_fd).max() < 0.1 * np.abs(B_fd).max()


def test_ilqr_plans_stay_within_the_limits_and_improve_on_their_warm_start(weak_pendubot, lost):
    system = weak_pendubot
    x0, _ = lost
    bound, S, K, H = np.array([8.0]), LQRController(system).S, 50, 1.0
    U0 = np.zeros((len(x0), K, 1))
    settings = ILQRSettings(iterations=6)
    U, Z, gains, cost = ilqr_plans(system, x0, U0, bound, H, S, settings)
    assert U.shape == (len(x0), K, 1) and Z.shape == (len(x0), K + 1, system.n) and gains.shape == (len(x0), K, 1, system.n)
    assert np.abs(U).max() <= 8.0 + 1e-12 and np.isfinite(gains).all()
    z0 = np.concatenate(system.split(x0), axis=1)
    np.testing.assert_allclose(rollout(system, z0, U, H / K, settings.substeps), Z, atol=1e-9)
    Q, Sz, r = plan_weights(system, S, settings, bound)
    start = plan_cost(system, rollout(system, z0, U0, H / K, settings.substeps), U0, Q, Sz, r, H / K)
    assert np.all(cost <= start) and np.any(cost < 0.5 * start)
    alone = ilqr_plans(system, x0[1:2], U0[1:2], bound, H, S, settings)[0]
    np.testing.assert_allclose(alone, U[1:2], atol=1e-9)


def _reference_ilqr(system, x0, U0, bound, horizon, S, settings):
    """iLQR as written before the solver kept the Jacobians of problems that took no step: every
    iteration computes every problem's Jacobians."""
    N, K, m = U0.shape
    dt = horizon / K
    Q, Sz, r = plan_weights(system, S, settings, bound)
    U = np.clip(U0, -bound, bound)
    Z = rollout(system, np.concatenate(system.split(x0), axis=1), U, dt, settings.substeps)
    n, alphas, L = Z.shape[2], np.asarray(settings.alphas), len(settings.alphas)
    cost, mu = plan_cost(system, Z, U, Q, Sz, r, dt), np.full(N, settings.mu0)
    for it in range(settings.iterations + 1):
        A, B = _knot_jacobians(system, Z[:, :-1].reshape(-1, n), U.reshape(-1, m), dt)
        kff, gains, ok = ilqr_module._backward(system, Z, U, A.reshape(N, K, n, n), B.reshape(N, K, n, m), Q, Sz, r, dt, mu, bound)
        if it == settings.iterations:
            return U, Z, gains, cost
        rep = lambda a: np.repeat(a[:, None], L, 1).reshape((N * L,) + a.shape[1:])  # noqa: E731
        Zn, Un = ilqr_module._forward(system, rep(Z), rep(U), (alphas[None, :, None, None] * kff[:, None]).reshape(N * L, K, m), rep(gains), bound, dt, 1)
        cn = plan_cost(system, Zn, Un, Q, Sz, r, dt).reshape(N, L)
        best = np.argmin(cn, axis=1)
        better = ok & (cn[np.arange(N), best] < cost)
        idx = (np.arange(N) * L + best)[better]
        Z[better], U[better], cost[better] = Zn[idx], Un[idx], cn[better, best[better]]
        mu = np.where(better, np.maximum(mu / 4.0, 1e-8), np.minimum(mu * 10.0, 1e8))


def test_a_problem_that_took_no_step_keeps_its_jacobians_and_its_plan_is_unchanged(weak_pendubot, lost, monkeypatch):
    system = weak_pendubot
    x0, _ = lost
    bound, S, K, H = np.array([8.0]), LQRController(system).S, 40, 0.8
    U0 = np.concatenate([np.zeros((len(x0), K, 1)), np.full((len(x0), K, 1), 8.0)])
    x0 = np.concatenate([x0, x0])
    settings = ILQRSettings(iterations=10, alphas=(1.0, 0.3))
    expected = _reference_ilqr(system, x0, U0, bound, H, S, settings)
    rows = []
    jacobians = ilqr_module._knot_jacobians
    monkeypatch.setattr(ilqr_module, "_knot_jacobians", lambda s, z, u, dt: rows.append(len(z) // K) or jacobians(s, z, u, dt))
    got = ilqr_plans(system, x0, U0, bound, H, S, settings)
    assert sum(rows) < len(x0) * (settings.iterations + 1)  # some problem took no step and kept its Jacobians
    for a, b in zip(got, expected):
        assert np.array_equal(a, b)


def test_a_settled_plan_rests_nearer_x_star_over_its_last_seconds_than_a_plain_one(weak_pendubot, lost):
    system = weak_pendubot
    x0, _ = lost
    K, H, settle = 50, 1.0, 0.3
    sigma = settle_weights(K, H / K, settle)
    assert np.count_nonzero(sigma) == 15 and np.all(sigma[-15:] == 1.0 / settle) and not settle_weights(K, H / K, 0.0).any()
    S, bound, U0 = LQRController(system).S, np.array([8.0]), np.zeros((len(x0), K, 1))
    terms = {"q": 1.0, "end_box": 100.0}
    plain = ilqr_plans(system, x0, U0, bound, H, S, ILQRSettings(iterations=10, **terms))
    settled = ilqr_plans(system, x0, U0, bound, H, S, ILQRSettings(iterations=10, settle=settle, **terms))
    Q, E, r = plan_weights(system, S, ILQRSettings(**terms), bound)
    z_star = np.r_[system.x_star[: system.nq], np.zeros(system.nq)]
    # the cost the solver reports is the running cost plus σ-weighted end cost at each knot
    d = wrap_angles(settled[1] - z_star, np.asarray(system.angle_mask, bool))
    by_hand = 0.5 * (H / K) * (np.einsum("nki,ij,nkj->n", d[:, :-1], Q, d[:, :-1]) + np.einsum("k,nki,ij,nkj->n", sigma, d[:, :-1], E, d[:, :-1])
                               + np.einsum("nki,i,nki->n", settled[0], r, settled[0])) + 0.5 * np.einsum("ni,ij,nj->n", d[:, -1], E, d[:, -1])
    np.testing.assert_allclose(plan_cost(system, settled[1], settled[0], Q, E, r, H / K, sigma=sigma), by_hand, rtol=1e-12)
    np.testing.assert_allclose(settled[3], by_hand, rtol=1e-9)
    tail = lambda Z: np.abs(wrap_angles(Z[:, -16:] - z_star, np.asarray(system.angle_mask, bool))).max(axis=(1, 2))  # noqa: E731
    assert np.median(tail(settled[1])) < np.median(tail(plain[1]))


def test_the_rail_term_keeps_a_plan_on_the_rail_where_a_plan_without_it_runs_off():
    """The zoo cartpole's rail is ±5 m; a start at 4 m moving out at 4 m/s, pole near upright (30
    iterations: the first full steps run far out before the rail term pulls the plan back)."""
    system = ip.load_system("cartpole")
    x0 = system.state_from(np.array([[4.0, 0.3]]), np.array([[4.0, 0.0]]))
    S, U0 = LQRController(system).S, np.zeros((1, 100, 1))
    far = {rail: ilqr_plans(system, x0, U0, system.effort, 2.0, S, ILQRSettings(rail=rail, iterations=30))[1][0, :, 0].max() for rail in (0.0, 1e3)}
    assert far[0.0] > 5.0 and far[1e3] <= 5.0


def test_the_rail_and_speed_terms_gradient_is_that_of_their_value():
    system = ip.load_system("cartpole")  # rail ±5 m, slider (driven) 10 m/s, pole 30 rad/s (not driven)
    np.testing.assert_allclose(_state_limits(system, ILQRSettings())[1], [4.0, np.inf, np.inf, np.inf])  # the speed term is off by default
    rail = _state_limits(system, ILQRSettings(speed=SPEED_WEIGHT))
    np.testing.assert_allclose(rail[0], [-4.0, -np.inf, -9.0, -np.inf])  # ±5 m pulled in by a tenth of the range, 10 m/s by a tenth
    np.testing.assert_allclose(rail[1], [4.0, np.inf, 9.0, np.inf])
    z = np.random.default_rng(0).uniform(-12, 12, (50, 4))
    value, grad, hess = _limit_terms(z, rail)
    h = 1e-6
    fd = np.stack([(_limit_terms(z + h * e, rail)[0] - _limit_terms(z - h * e, rail)[0]) / (2 * h) for e in np.eye(4)], axis=1)
    np.testing.assert_allclose(grad, fd, atol=1e-5)
    inside = (np.abs(z[:, 0]) < 4.0) & (np.abs(z[:, 2]) < 9.0)
    assert (value > 0).sum() > 5 and np.all(value[inside] == 0.0) and np.all(grad[:, [1, 3]] == 0.0)
    np.testing.assert_array_equal(hess[:, 0] > 0, np.abs(z[:, 0]) > 4.0)
    np.testing.assert_array_equal(hess[:, 2] > 0, np.abs(z[:, 2]) > 9.0)
    assert _state_limits(ip.load_system("acrobot"), ILQRSettings()) is None and _state_limits(ip.load_system("acrobot"), ILQRSettings(speed=SPEED_WEIGHT)) is not None


def test_speed_limits_are_the_urdf_s_on_the_driven_joints_only():
    np.testing.assert_array_equal(speed_limits(ip.load_system("furuta")), [30.0, np.inf])  # the arm's motor; the pendulum is free
    np.testing.assert_array_equal(speed_limits(ip.load_system("acrobot")), [np.inf, 30.0])
    np.testing.assert_array_equal(speed_limits(ip.load_system("double_pendulum")), [30.0, 30.0])  # both joints driven
    np.testing.assert_array_equal(speed_limits(ip.load_system("paper_cartpole")), [np.inf, np.inf])  # a closed form: no URDF


def test_plans_from_hanging_keep_the_motor_near_its_rated_speed():
    # the zoo Furuta's light arm under 10 N·m: time-optimal swings whirl it far past its URDF 30 rad/s
    system = ip.load_system("furuta")
    x0 = np.concatenate([resting_configuration(system), np.zeros(system.nq)])[None]
    bound = 0.8 * plan_bound(system)
    K = int(round(1.5 / KNOT))
    W = warm_starts(K, bound, 0, periods=(1.0,), n_random=2)
    peaks = {}
    for weight in (0.0, SPEED_WEIGHT):
        U, Z, _, _ = ilqr_plans(system, np.repeat(x0, len(W), 0), W, bound, K * KNOT, LQRController(system).S, ILQRSettings(iterations=20, speed=weight))
        peaks[weight] = np.abs(Z[:, :, system.nq]).max(axis=1)  # the arm's peak planned speed, rad/s, per plan
    assert np.median(peaks[0.0]) > 1.5 * 30.0 and np.median(peaks[SPEED_WEIGHT]) <= 1.1 * 30.0


def test_tracked_ilqr_candidates_recover_states_saturated_lqr_loses(weak_pendubot, lost):
    system = weak_pendubot
    x0, failed_u = lost
    lqr, settings = LQRController(system), PlanSettings()
    starts, U, X, gains = plan_candidates(system, x0, failed_u, np.array([8.0]), settings)
    assert len(starts) == (2 + 2 * len(PERIODS)) * len(x0) and np.abs(U).max() <= 8.0 + 1e-12
    tracker = TrackThenLaw(U, X, gains, settings.knot_step, lqr, system)
    assert tracker.horizon == pytest.approx(settings.horizon)
    ok = success(simulate(system, tracker, starts, T=20.0, dt=PLAN_STEP), system).reshape(-1, len(x0))
    assert ok.any(0).sum() >= len(x0) // 2  # starts saturated LQR lost, brought to x* by a tracked plan, then LQR


def test_a_plan_held_over_each_knot_is_tracked_as_the_solver_rolled_it_out(weak_pendubot, lost):
    system = weak_pendubot
    x0, failed_u = lost
    settings = PlanSettings(horizon=1.0, ilqr_iterations=20)
    starts, U, Z, gains = plan_candidates(system, x0[:1], failed_u[:1], np.array([8.0]), settings)
    lqr, per_knot = LQRController(system), int(round(settings.knot_step / PLAN_STEP))
    ends = {}
    for hold in (True, False):
        tracker = TrackThenLaw(U, Z, gains, settings.knot_step, lqr, system, hold=hold)
        traj = simulate(system, tracker, starts, T=tracker.horizon, dt=PLAN_STEP)
        u = traj.u[:, : U.shape[1] * per_knot].reshape(len(starts), U.shape[1], per_knot, -1)
        if hold:
            np.testing.assert_array_equal(u, np.repeat(u[:, :, :1], per_knot, axis=2))  # one input per knot
            np.testing.assert_allclose(u[:, 0, 0], U[:, 0], atol=1e-12)  # on the plan at its start: no correction
        z_end = np.concatenate(system.split(traj.x[:, -1]), axis=1)
        ends[hold] = np.abs(wrap_angles(z_end - Z[:, -1], np.r_[system.angle_mask[: system.nq], np.zeros(system.nq, bool)])).max(1)
    assert np.median(ends[True]) < np.median(ends[False])


def test_the_reach_plans_get_more_iterations_at_three_joints_and_refuse_bad_step_sizes():
    auto = PlanSettings()
    assert auto.solver(ip.load_system("pendubot")).iterations == AUTO_ITERATIONS[0]
    assert auto.solver(ip.load_system("triple_pendulum")).iterations == AUTO_ITERATIONS[1] > AUTO_ITERATIONS[0]
    assert PlanSettings(ilqr_iterations=7).solver(ip.load_system("triple_pendulum")).iterations == 7
    for bad in ({"alphas": ()}, {"alphas": (1.0, 0.0)}, {"q": -1.0}, {"ilqr_iterations": -1}):
        with pytest.raises(IdapbcError, match="bad plan setting"):
            PlanSettings(**bad)


def test_a_chunk_store_gives_back_what_it_kept_and_nothing_else(tmp_path):
    store = ChunkStore(tmp_path)
    part = (np.arange(12.0).reshape(3, 4), np.ones((3, 1)), 2, 1)
    key = chunk_key(np.zeros((2, 4)), 7, PlanSettings())
    assert store.read("labels", 0, key) is None
    store.write("labels", 0, key, part)
    X, U, taught, recovered = store.read("labels", 0, key)
    np.testing.assert_array_equal(X, part[0]) and np.testing.assert_array_equal(U, part[1])
    assert (taught, recovered) == (2, 1)
    assert store.read("labels", 0, chunk_key(np.zeros((2, 4)), 8, PlanSettings())) is None  # another seed: planned again
    (tmp_path / CHUNKS_DIR / "labels-0.npz").write_bytes(b"not a zip")
    assert store.read("labels", 0, key) is None  # damaged: planned again
    store.clear()
    assert not (tmp_path / CHUNKS_DIR).exists()
    assert ChunkStore(None).read("labels", 0, key) is None


def test_a_labelling_step_started_again_plans_only_the_chunks_it_had_not_finished(weak_pendubot, tmp_path, monkeypatch):
    system = weak_pendubot
    x0 = uniform_states(system, 4, "half", 5)  # one start per chunk (fewer starts than LABEL_CHUNKS: as many chunks as starts)
    config = RecoveryConfig(workers=1, judge_T=8.0, plan=PlanSettings(horizon=0.5, ilqr_iterations=2))
    whole = collect_labels(system, x0, 3, config, progress=False)
    calls = []
    real = stage_module._label_chunk

    def chunk(job):
        calls.append(job[2])
        if len(calls) == 3:
            raise KeyboardInterrupt  # killed while the third chunk is planned
        return real(job)

    monkeypatch.setattr(stage_module, "_label_chunk", chunk)
    store = ChunkStore(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        collect_labels(system, x0, 3, config, progress=False, store=store)
    done = list(calls[:2])
    calls.clear()
    monkeypatch.setattr(stage_module, "_label_chunk", real)
    again = collect_labels(system, x0, 3, config, progress=False, store=store)
    for a, b in zip(whole[:2], again[:2]):
        np.testing.assert_array_equal(a, b)
    assert whole[2:] == again[2:]
    monkeypatch.setattr(stage_module, "_label_chunk", lambda job: calls.append(job[2]) or real(job))
    collect_labels(system, x0, 3, config, progress=False, store=store)
    assert calls == [] and len(done) == 2  # every chunk is read back now


TINY_TOML = """[recovery]
starts = 4
dagger = 0
width = 8
steps = 30
fits = 1
gate_states = 4
near_states = 2
confirm_states = 2
inner_scales = [0.25]
judge_T = 8.0
workers = 1

[recovery.plan]
horizon = 0.5
ilqr_iterations = 2
"""


def test_a_kill_during_the_stage_leaves_a_working_run_and_resume_finishes_the_stage(tmp_path, monkeypatch):
    """kill -9 while the recovery stage plans: the run still loads and runs its own law, its finished
    chunks are on disk, and `train --resume RUN` finishes the stage from them."""
    import os
    import signal
    import subprocess
    import sys
    import time

    system = ip.load_system("pendubot", effort={"shoulder": 8.0})
    run = ip.train(system, ip.TrainConfig.fast(epochs=5, width=8, depth=1, samples=64, dtype="float64"), out=tmp_path / "runs", progress=False)
    (tmp_path / "tiny.toml").write_text(TINY_TOML)
    chunks = run.path / CHUNKS_DIR
    proc = subprocess.Popen([sys.executable, "-m", "idapbc_pin.cli", "recover", str(run.path), "--config", str(tmp_path / "tiny.toml")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=os.environ | {"PYTHONWARNINGS": "ignore"})
    deadline = time.time() + 120
    while time.time() < deadline and not (chunks.is_dir() and any(chunks.glob("*.npz"))) and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, "the stage ended before a chunk was saved: nothing to kill"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    saved = sorted(p.name for p in chunks.glob("*.npz"))
    assert saved and len(saved) < 4  # one chunk per start
    killed = ip.load_run(run.path)  # the run still works with its own law
    assert not killed.uses_recovery and "recovery" not in killed.summary
    assert np.isfinite(killed.controller(uniform_states(system, 3, "half", 0))).all()
    main_args = ["train", "--resume", str(run.path), "--recover", "always", "--recover-config", str(tmp_path / "tiny.toml"), "--evaluate", "0"]
    from idapbc_pin.cli.main import main
    from idapbc_pin.recovery import gate

    monkeypatch.setattr(gate, "GATE_HORIZON", 1.0)  # the resumed stage's gate: that it runs is the claim, not its counts
    assert main(main_args) == 0
    resumed = ip.load_run(run.path)
    assert "recovery" in resumed.summary and not chunks.exists()  # the stage ran to its gate, and cleared its chunks


def test_every_ilqr_plan_on_the_cart_double_pendulum_gets_cheaper():
    """Six iterations from a zero input lower every plan's cost at least twofold on four half-box
    starts of the zoo's cart double pendulum. A backward pass that folds its regularisation μI into
    the value's Hessian makes V_xx indefinite there and takes no step at all (the cost stays put)."""
    system = ip.load_system("cart_double_pendulum")
    x0, S, U0 = uniform_states(system, 4, "half", 3), LQRController(system).S, np.zeros((4, 100, 1))
    start = ilqr_plans(system, x0, U0, system.effort, 2.0, S, ILQRSettings(iterations=0))[3]
    after = ilqr_plans(system, x0, U0, system.effort, 2.0, S, ILQRSettings(iterations=6))[3]
    assert np.all(after <= 0.5 * start)


def test_speed_limits_reach_every_plan_of_the_two_stages():
    """`speed_limits` turns the speed term on in the reach stage's solves and in the swing-up stage's
    label plans; off by default."""
    from idapbc_pin.recovery.config import SwingUpConfig
    from idapbc_pin.recovery.swing_stage import _labels_config

    furuta = ip.load_system("furuta")
    assert PlanSettings().solver(furuta).speed == 0.0 and PlanSettings(speed_limits=True).solver(furuta).speed == SPEED_WEIGHT
    assert _labels_config(SwingUpConfig()).plan.solver(furuta).speed == 0.0
    assert _labels_config(SwingUpConfig(speed_limits=True)).plan.solver(furuta).speed == SPEED_WEIGHT


def test_a_backward_pass_with_an_exactly_singular_quu_takes_no_step_and_raises_nothing():
    """Two inputs acting on one joint in the ratio 20 : 43, no input cost: Q_uu = c·(20, 43)ᵀ(20, 43) is
    exactly singular, which numpy's eigvalsh calls positive and its LU refuses ("Singular matrix")."""
    system = ip.load_system("arm_passive_middle")
    N, K, m, n = 2, 3, 2, system.n
    A = np.broadcast_to(np.eye(n), (N, K, n, n)).copy()
    B = np.zeros((N, K, n, m))
    B[:, :, 3, 0], B[:, :, 3, 1] = 20.0, 43.0
    Z, U = np.full((N, K + 1, n), 0.1), np.zeros((N, K, m))
    quu = np.array([[400.0, 860.0], [860.0, 1849.0]])
    with pytest.raises(np.linalg.LinAlgError):  # the premise
        np.linalg.inv(quu)
    kff, gains, ok = ilqr_module._backward(system, Z, U, A, B, np.zeros((n, n)), np.eye(n), np.zeros(m), 0.05, np.zeros(N), np.full(m, np.inf))
    assert not ok.any()  # a pass that broke down: the problem takes no step
    assert np.isfinite(kff).all() and np.isfinite(gains).all()


def test_plans_with_two_inputs_that_act_alike_stay_finite_and_never_cost_more_than_their_warm_start(monkeypatch):
    """The three-link arm's two motors made to act alike (the second's column of B twice the first's),
    no input cost, no regularisation: every plan comes back finite, within its limits, and no worse."""
    system = ip.load_system("arm_passive_middle")
    jacobians = ilqr_module._knot_jacobians

    def alike(s, z, u, dt):
        A, B = jacobians(s, z, u, dt)
        B = B.copy()
        B[..., 1] = 2.0 * B[..., 0]
        return A, B

    monkeypatch.setattr(ilqr_module, "_knot_jacobians", alike)
    x0 = system.x_star + uniform_states(system, 3, "half", 5) * 0.2
    U0 = np.zeros((3, 10, 2))
    settings = ILQRSettings(iterations=4, r=0.0, mu0=0.0)
    S = LQRController(system).S
    U, Z, gains, cost = ilqr_plans(system, x0, U0, system.effort, 0.5, S, settings)
    assert np.isfinite(U).all() and np.isfinite(Z).all() and np.isfinite(gains).all()
    assert np.all(np.abs(U) <= system.effort)
    Q, Sz, r = plan_weights(system, S, settings, system.effort)
    q0, v0 = system.split(x0)
    start = plan_cost(system, rollout(system, np.concatenate([q0, v0], 1), U0, 0.05, 1), U0, Q, Sz, r, 0.05)
    assert np.all(cost <= start)
