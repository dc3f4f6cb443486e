"""The robustness suite: plant variations against a closed form, the disturbed loop against the plain
one, the actuator, the delay, the pushes, the scoring rules, the speed filter and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest
import scipy.linalg
import torch

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.control.speed_filter import SpeedFilter, kalman_gain
from idapbc_pin.evaluation.robust_suite import SUITE_FILE, SUITE_TESTS, SuiteConfig, SuiteResult, push_profiles, suite_rows
from idapbc_pin.model.variations import GEAR, RowPlants, plant_families, varied_model
from idapbc_pin.sim.disturbed import Disturbances, actuate, pulse_torques, simulate_disturbed
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.states import uniform_states

REALAIGYM = "urdf/realaigym_double_pendulum.urdf"


@pytest.fixture(scope="module")
def pendubot():
    return ip.load_system(REALAIGYM, actuated=["shoulder"], target={"shoulder": np.pi})


def _parameters(model):
    """(m1, r1, I1, m2, r2, I2, l1) of a planar double pendulum about y: I about the joint axis."""
    out = []
    for jid in (1, 2):
        inertia = model.inertias[jid]
        c = np.array(inertia.lever)
        r = float(np.hypot(c[0], c[2]))
        out += [float(inertia.mass), r, float(np.array(inertia.inertia)[1, 1]) + float(inertia.mass) * r * r]
    return (*out, float(np.linalg.norm(model.jointPlacements[2].translation)))


def _closed_form(params, q, g=9.81):
    """M(q) (2, 2) and ∂U/∂q (2,) of a planar double pendulum hanging along −z at q = 0."""
    m1, r1, I1, m2, r2, I2, l1 = params
    c2 = np.cos(q[1])
    M = np.array([[I1 + I2 + m2 * l1 * l1 + 2 * m2 * l1 * r2 * c2, I2 + m2 * l1 * r2 * c2], [I2 + m2 * l1 * r2 * c2, I2]])
    s1, s12 = np.sin(q[0]), np.sin(q[0] + q[1])
    grav = np.array([g * (m1 * r1 + m2 * l1) * s1 + g * m2 * r2 * s12, g * m2 * r2 * s12])
    return M, grav


@pytest.mark.parametrize("kind,joint", [("m·r", 0), ("I", 0), ("m·r", 1), ("I", 1), ("m", 1)])
@pytest.mark.parametrize("scale", [0.8, 1.25])
def test_a_varied_link_is_the_closed_form_double_pendulum_with_that_one_parameter_changed(pendubot, kind, joint, scale):
    nominal = pendubot.plant.model
    lever, place = np.array(nominal.inertias[2].lever), np.array(nominal.jointPlacements[2].translation)
    assert abs(lever[0]) + abs(place[0]) < 1e-12  # levers along the links: the closed form's geometry
    params = list(_parameters(nominal))
    base = 3 * joint
    if kind == "m·r":
        params[base + 1] *= scale
    elif kind == "I":
        params[base + 2] *= scale
    else:
        params[base] *= scale
    model = varied_model(pendubot.plant, kind, joint, scale)
    data = model.createData()
    for q in np.random.default_rng(0).uniform(-np.pi, np.pi, (5, 2)):
        M, grav = _closed_form(params, q)
        np.testing.assert_allclose(pin.crba(model, data, q), M, rtol=0, atol=1e-12)
        np.testing.assert_allclose(pin.computeGeneralizedGravity(model, data, q), grav, rtol=0, atol=1e-12)


def test_the_rotor_adds_gear_squared_times_its_inertia_on_every_joint(pendubot):
    q = np.array([0.4, -1.1])
    nominal = pendubot.plant.model
    model = varied_model(pendubot.plant, "rotor", -1, 1e-4)
    diff = pin.crba(model, model.createData(), q) - pin.crba(nominal, nominal.createData(), q)
    np.testing.assert_allclose(diff, GEAR**2 * 1e-4 * np.eye(2), atol=1e-15)


def test_the_families_are_the_leaderboards_ten_on_a_double_pendulum(pendubot):
    names = [f.name for f in plant_families(pendubot.plant)]
    assert names == ["m·r shoulder", "I shoulder", "m·r elbow", "I elbow", "m elbow", "b shoulder", "cf shoulder", "b elbow", "cf elbow", "rotor"]
    cart = [f.name for f in plant_families(ip.load_system("cartpole").plant)]
    assert cart[:4] == ["m slider", "m·r hinge", "I hinge", "m hinge"]  # a cart has a mass only; the pole rides on it
    assert [f.kind for f in plant_families(ip.load_system("paper_cartpole").plant)] == ["b", "cf", "b", "cf"]  # a closed form: the joints


def test_row_plants_give_each_row_its_own_model_and_friction(pendubot):
    rng = np.random.default_rng(1)
    q, v, tau = rng.normal(size=(3, 2)), rng.normal(size=(3, 2)), rng.normal(size=(3, 2))
    varied = varied_model(pendubot.plant, "I", 1, 1.2)
    cf, b = np.zeros((3, 2)), np.zeros((3, 2))
    cf[2, 1], b[2, 0] = 0.2, 0.05
    rows = RowPlants(pendubot.plant, [None, varied, None], b, cf)
    a = rows.accel(q, v, tau)
    np.testing.assert_allclose(a[0], pendubot.plant.forward_dynamics(q[:1], v[:1], tau[:1])[0], atol=1e-12)
    np.testing.assert_allclose(a[1], pin.aba(varied, varied.createData(), q[1], v[1], tau[1]), atol=1e-12)
    friction = -b[2] * v[2] - cf[2] * np.arctan(100 * v[2])
    M = pendubot.mass_matrix(q[2])
    expected = pendubot.plant.forward_dynamics(q[2:], v[2:], tau[2:])[0] + np.linalg.solve(M, friction)
    np.testing.assert_allclose(a[2], expected, atol=1e-10)


def test_undisturbed_rows_follow_the_plain_simulation(pendubot):
    lqr = LQRController(pendubot)
    x0 = uniform_states(pendubot, 4, "half", 3)
    ref = simulate(pendubot, lqr, x0, T=0.5, dt=0.002)
    rows = RowPlants(pendubot.plant, [None] * 4, np.tile(pendubot.plant.damping, (4, 1)), np.zeros((4, 2)))
    end = simulate_disturbed(pendubot, rows, lqr, x0, Disturbances.none(4, 2), T=0.5, dt=0.002)
    np.testing.assert_allclose(end.q, ref.q[:, -1], atol=1e-9)
    np.testing.assert_allclose(end.v, ref.v[:, -1], atol=1e-9)


class _Recorder:
    """A law that applies nothing and keeps what it was shown."""

    def __init__(self):
        self.seen = []

    def __call__(self, x):
        self.seen.append(np.array(x))
        return np.zeros((len(x), 1))


def test_a_delayed_row_sees_the_state_of_that_many_ticks_before(pendubot):
    x0 = uniform_states(pendubot, 2, "half", 5)
    rows = RowPlants(pendubot.plant, [None] * 2, np.zeros((2, 2)), np.zeros((2, 2)))
    now, late = _Recorder(), _Recorder()
    simulate_disturbed(pendubot, rows, now, x0, Disturbances.none(2, 2), T=0.1, dt=0.002)
    dist = Disturbances(np.zeros(2), np.zeros(2), np.ones(2), np.array([0, 3]), np.zeros((2, 2, 0, 3)))
    simulate_disturbed(pendubot, rows, late, x0, dist, T=0.1, dt=0.002)
    now, late = np.stack(now.seen), np.stack(late.seen)
    np.testing.assert_allclose(late[:, 0], now[:, 0], atol=0)
    np.testing.assert_allclose(late[3:, 1], now[:-3, 1], atol=1e-12)
    np.testing.assert_allclose(late[:3, 1], np.repeat(now[:1, 1], 3, axis=0), atol=1e-12)  # the start before the first


def test_the_actuator_follows_a_step_at_its_responsiveness_and_clips():
    u, c = np.zeros((1, 1)), np.full((1, 1), 2.0)
    for j in range(1, 6):
        u = actuate(u, c, 0.5, 0.0, None)
        assert u[0, 0] == pytest.approx(2.0 * (1 - 0.5**j))
    assert actuate(np.zeros((1, 1)), c, 2.0, 0.0, np.array([3.0]))[0, 0] == 3.0  # overshoot clipped
    assert actuate(np.ones((1, 1)), np.full((1, 1), np.nan), 1.0, 0.0, None)[0, 0] == 0.0


def test_push_profiles_keep_their_spacing_widths_and_amplitudes():
    config = SuiteConfig()
    prof = push_profiles(np.random.default_rng(0), 50, 2, config)
    assert prof.shape == (50, 2, 3, 3)
    centres = np.sort(prof[..., 0].reshape(50, -1), axis=1)
    assert np.diff(centres, axis=1).min() >= config.spacing - 1e-12 and centres.max() <= config.T
    assert ((prof[..., 1] >= 0.05) & (prof[..., 1] <= 0.1)).all()
    assert ((np.abs(prof[..., 2]) >= 0.5) & (np.abs(prof[..., 2]) <= 5.0)).all() and (prof[..., 2] < 0).any() and (prof[..., 2] > 0).any()
    peak = pulse_torques(prof[:1, :, :1], prof[0, 0, 0, 0])
    assert peak[0, 0] == pytest.approx(prof[0, 0, 0, 2])


def test_pushes_on_the_actuated_joints_drop_only_the_others_pulses(pendubot):
    """As the leaderboard's simulator: the same draws, the unactuated joints' pulses never reach the robot."""
    every = suite_rows(pendubot, SuiteConfig(levels=3, repetitions=2, pushes=4))
    acted = suite_rows(pendubot, SuiteConfig(levels=3, repetitions=2, pushes=4, push_joints="actuated"))
    actuated = (np.abs(np.asarray(pendubot.B)) > 0).any(axis=1)
    assert actuated.sum() == 1
    a, e = acted.dist.pulses[acted.test == 5], every.dist.pulses[every.test == 5]
    assert (a[:, ~actuated, :, 2] == 0).all() and (e[:, ~actuated, :, 2] != 0).all()
    np.testing.assert_array_equal(a[:, actuated], e[:, actuated])
    np.testing.assert_array_equal(a[..., :2], e[..., :2])
    assert np.abs(pulse_torques(a[:, :, :], a[0, ~actuated, 0, 0][0]))[:, ~actuated].max() == 0.0
    with pytest.raises(ValueError, match="push_joints"):
        SuiteConfig(push_joints="elbow")


def test_the_scores_follow_the_leaderboards_rules(pendubot):
    config = SuiteConfig(levels=3, repetitions=4, pushes=2)
    rows = suite_rows(pendubot, config)
    assert rows.N == 10 * 3 + 2 * 3 * 4 + 3 + 3 + 2
    ok = np.zeros(rows.N, bool)
    ok[(rows.test == 0) & (rows.family == 0)] = True  # one family of ten
    noise = np.flatnonzero((rows.test == 1) & (rows.level == 0))
    ok[noise[:3]] = True  # 3 of 4: the level passes
    ok[np.flatnonzero((rows.test == 1) & (rows.level == 1))[:2]] = True  # 2 of 4: not more than half
    ok[(rows.test == 5)] = [True, False]
    res = SuiteResult(system="s", start="hanging", config=config, rows=rows, success={"law": ok})
    s = res.scores("law")
    assert s["model"] == pytest.approx(0.1) and s["speed noise"] == pytest.approx(1 / 3) and s["torque noise"] == 0.0
    assert s["pushes"] == 0.5 and s["overall"] == pytest.approx(np.mean([s[t] for t in SUITE_TESTS]))
    assert res.family_counts("law")["m·r shoulder"] == 3


def test_the_filters_gain_is_the_riccati_equations():
    dt, sq, sv, sa = 0.002, 1e-3, 0.5, 100.0
    F, H = np.array([[1, dt], [0, 1]]), np.eye(2)
    G = np.array([[dt * dt / 2], [dt]])
    R = np.diag([sq * sq, sv * sv])
    P = scipy.linalg.solve_discrete_are(F.T, H.T, sa * sa * G @ G.T, R)
    np.testing.assert_allclose(kalman_gain(dt, sq, sv, sa), P @ np.linalg.inv(P + R), rtol=1e-8)


def test_the_filter_follows_a_steady_motion_exactly_and_smooths_noise():
    f = SpeedFilter()
    t = np.arange(200) * f.dt
    v = np.array([1.5, -0.5])
    for k in range(200):
        out = f.update(v * t[k], v)
    np.testing.assert_allclose(out, v, atol=1e-12)
    rng = np.random.default_rng(0)
    f.reset()
    noisy = [f.update(v * t[k], v + 0.5 * rng.standard_normal(2)) for k in range(200)]
    assert np.std(np.array(noisy[100:]) - v) < 0.5 / 3  # the default settings cut white speed noise at least threefold


@pytest.fixture(scope="module")
def urdf_run(tmp_path_factory):
    torch.set_num_threads(1)
    system = ip.load_system("pendubot")
    return ip.train(system, ip.TrainConfig.fast(epochs=5, width=8, depth=1, samples=64), out=tmp_path_factory.mktemp("runs"), progress=False)


def test_the_robustness_command_runs_the_suite_beside_lqr_and_the_pump(urdf_run, cli):
    out = cli("robustness", urdf_run.path, "--levels", "2", "--repetitions", "2", "--pushes", "1", "--T", "0.1", "--workers", "1",
              "--push-joints", "actuated")
    assert out.returncode == 0, out.stderr
    assert "| NIDA-PBC |" in out.stdout and "| LQR |" in out.stdout and "model test" in out.stdout and "the actuated joints" in out.stdout
    data = json.loads((urdf_run.path / SUITE_FILE).read_text())
    assert data["config"]["push_joints"] == "actuated"
    assert data["start"] == "box" and set(data["scores"]) == {"NIDA-PBC", "NIDA-PBC + speed filter", "LQR", "energy pump + LQR"}
    assert len(data["rows"]["test"]) == 10 * 2 + 2 * 2 * 2 + 2 + 2 + 1
    assert all(set(s) == set(SUITE_TESTS) | {"overall"} for s in data["scores"].values())
