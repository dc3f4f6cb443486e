"""The speed and energy governor (`control.speed_governor`): its energy rate is the model's, it leaves
the law alone below its thresholds, never lets an input add energy where it acts, and stops a law
that pumps a whirl."""

from __future__ import annotations

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.speed_governor import ENERGY_MARGIN, SPEED_START, SpeedGovernor
from idapbc_pin.model.resting import resting_configuration
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.metrics import speed_over_rating
from idapbc_pin.sim.states import moving_states


@pytest.fixture(scope="module")
def systems():
    return {name: ip.load_system(name) for name in ("acrobot", "pendubot", "cartpole", "furuta", "reaction_wheel")}


@pytest.mark.parametrize("name", ["acrobot", "cartpole", "furuta", "reaction_wheel"])
def test_the_energy_rate_is_the_derivative_of_the_governed_energy_along_the_input(systems, name):
    """w = ∂Ė_g/∂u equals a finite difference of E_g(q, v + h (v̇(u = e_i) − v̇(u = 0))) / h, v̇ from
    the plant's forward dynamics: a lost term (the cyclic coupling, M⁻¹) would fail it."""
    system = systems[name]
    gov = SpeedGovernor.of(system)
    x = moving_states(system, 8, seed=1)
    q, v = system.split(x)
    e0, w = gov.energy(x)
    zero = system.forward_dynamics(q, v, np.zeros((8, system.nv)))
    h = 1e-7
    for i in range(system.m):
        unit = np.zeros((8, system.m))
        unit[:, i] = 1.0
        a = system.forward_dynamics(q, v, unit @ system.B.T) - zero
        e1, _ = gov.energy(system.state_from(q, v + h * a))
        np.testing.assert_allclose((e1 - e0) / h, w[:, i], rtol=1e-5, atol=1e-6 * np.abs(w).max())


def test_a_cyclic_actuated_joint_is_left_out_of_the_energy_and_a_chain_counts_every_joint(systems):
    assert SpeedGovernor.of(systems["cartpole"]).energy_rows.tolist() == [1]  # the pole, not the cart
    assert SpeedGovernor.of(systems["reaction_wheel"]).energy_rows.tolist() == [0]  # the pendulum, not the wheel
    assert SpeedGovernor.of(systems["acrobot"]).energy_rows.tolist() == [0, 1]
    assert SpeedGovernor.of(ip.load_system("paper_cartpole")) is None  # no finite effort: no braking torque


@pytest.mark.parametrize("name", ["acrobot", "pendubot", "cartpole", "furuta", "reaction_wheel"])
def test_below_both_thresholds_the_law_is_untouched(systems, name):
    """Near x* and near hanging, slowly moving, E_g < E* + margin·ΔE and every motor below its
    start: u comes back exactly."""
    system = systems[name]
    gov = SpeedGovernor.of(system)
    rng = np.random.default_rng(0)
    for q0 in (np.asarray(system.x_star)[: system.nq], resting_configuration(system)):
        q = q0 + rng.uniform(-0.1, 0.1, (50, system.nq))
        v = rng.uniform(-0.2, 0.2, (50, system.nq))
        x = system.state_from(q, v)
        s_e, s_v, _, _ = gov.shares(x)
        assert (s_e == 0).all() and (s_v == 0).all()
        u = rng.uniform(-1, 1, (50, system.m)) * system.effort
        np.testing.assert_array_equal(gov.apply(x, u), u)


@pytest.mark.parametrize("name", ["acrobot", "pendubot", "cartpole", "furuta", "reaction_wheel"])
def test_where_a_clause_acts_no_input_adds_energy_or_speed(systems, name):
    """From moving states (speeds up to the ratings) with random inputs: wherever the speed clause
    acts, no input speeds up the fastest joint (u_i c_i ≤ 0, c_i = v_k ∂v̇_k/∂u_i up to a positive
    scale, checked on the plant's own forward dynamics); wherever only the energy clause acts,
    u_i w_i ≤ 0; both after the limits' clip; at full share the input is the full braking one."""
    system = systems[name]
    gov = SpeedGovernor.of(system)
    x = moving_states(system, 400, seed=2)
    q, v = system.split(x)
    s_e, s_v, w, c = gov.shares(x)
    assert (s_e > 0).sum() > 20 and (s_v > 0).sum() > 20
    u = system.saturate(gov.apply(x, np.random.default_rng(3).uniform(-2, 2, (400, system.m)) * system.effort))
    k = np.argmax(np.abs(v) / gov.rating, axis=1)
    zero = system.forward_dynamics(q, v, np.zeros_like(v))
    for i in range(system.m):
        unit = np.zeros((400, system.m))
        unit[:, i] = 1.0
        reach = (system.forward_dynamics(q, v, unit @ system.B.T) - zero)[np.arange(400), k]  # ∂v̇_k/∂u_i
        assert (np.sign(c[:, i]) == np.sign(v[np.arange(400), k] * reach))[(s_v > 0) & (np.abs(c[:, i]) > 1e-9)].all()
    assert (u * c)[s_v > 0].max(initial=0.0) <= 1e-12
    assert (u * w)[(s_e > 0) & (s_v == 0)].max(initial=0.0) <= 1e-12
    full = (s_e == 1.0) & (s_v == 0) & (np.abs(w) >= 0.1).all(axis=1)
    assert full.any()
    np.testing.assert_allclose(u[full], -system.effort * np.sign(w[full]))


def test_a_passive_joint_past_its_rating_is_braked_through_the_coupling(systems):
    """The pendubot's passive elbow at 1.1 ratings, the posture otherwise at rest near hanging: the
    shoulder's input is the full braking one for the elbow (−ū sign(v_e (M⁻¹B)_e)), whatever the law asked."""
    system = systems["pendubot"]
    gov = SpeedGovernor.of(system)
    q = np.array([[0.3, -0.4]])
    v = np.array([[0.0, 1.1 * gov.rating[1]]])
    reach = np.linalg.solve(system.mass_matrix(q)[0], system.B)[1, 0]
    for asked in (-system.effort[0], 0.0, system.effort[0]):
        u = gov.apply(system.state_from(q, v), np.array([[asked]]))
        assert u[0, 0] == pytest.approx(-system.effort[0] * np.sign(v[0, 1] * reach))


def test_a_law_that_pumps_energy_is_stopped_and_the_motor_kept_near_its_rating(systems):
    """u = ū sign(v_a), a law that pumps energy into the acrobot without end, from hanging moving:
    alone it whirls past twice the elbow's rating; governed the speeds stay under 1.5 ratings after
    0.5 s and the energy ends within the governor's band above E*."""
    system = systems["acrobot"]
    gov = SpeedGovernor.of(system)
    pump = lambda x: system.effort * np.sign(system.split(np.atleast_2d(x))[1][:, [1]] + 1e-9)
    x0 = system.state_from(resting_configuration(system)[None], np.array([[0.5, 1.0]]))
    wild = simulate(system, pump, x0, T=6.0, dt=0.002)
    tame = simulate(system, lambda x: gov.apply(x, pump(x)), x0, T=6.0, dt=0.002)
    assert speed_over_rating(system, wild.v[0]).max() > 2.0
    late = tame.t >= 0.5
    assert speed_over_rating(system, tame.v[0, late]).max() < 1.5
    e_end = gov.energy(tame.x[0, -50:])[0]
    assert ((e_end - gov.e_star) / gov.delta_e <= ENERGY_MARGIN + 0.5 + 0.05).all()


def test_the_speed_clause_brakes_a_wheel_past_its_rating(systems):
    """A reaction wheel spinning at 1.1 ratings with the pendulum upright at rest: the wheel's input
    brakes it at full effort, whatever the law asked."""
    system = systems["reaction_wheel"]
    gov = SpeedGovernor.of(system)
    q = np.asarray(system.x_star)[None, : system.nq]
    v = np.array([[0.0, 1.1 * gov.rating[1]]])  # the wheel, joint 1
    x = system.state_from(q, v)
    u = gov.apply(x, np.array([[system.effort[0]]]))
    assert u[0, 0] == pytest.approx(-system.effort[0])
    v_slow = np.array([[0.0, 0.5 * SPEED_START * gov.rating[1]]])
    assert gov.apply(system.state_from(q, v_slow), np.array([[1.0]]))[0, 0] == 1.0
