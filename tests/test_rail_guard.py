"""The rail guard: a law's input on a cart's rail, replaced by full braking where the cart could no
longer stop before the rail's end (`idapbc_pin.control.rail_guard`).

Claims:
* a cart pushed at full force towards an end stays on its rail with the guard, and leaves it without;
* the guard leaves a law's input alone at rest, moving inward, and far from the ends;
* its stopping rule agrees with a double integrator's closed form where the pole's pull is absent;
* systems without a rail driven by a limited input have no guard.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.rail_guard import GUARD_MARGIN, GUARD_SAFETY, RailGuard
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.sim.metrics import on_rail


@pytest.fixture(scope="module")
def cartpole():
    return ip.load_system("cartpole")


class _Push:
    """u = +ū on the cart whatever the state, optionally through the guard."""

    def __init__(self, system, guard=None):
        self.system, self.guard = system, guard

    def __call__(self, x):
        x = np.atleast_2d(x)
        u = np.tile(self.system.effort, (len(x), 1))
        return u if self.guard is None else self.guard.apply(x, u)


def test_a_cart_pushed_at_full_force_stays_on_its_rail_with_the_guard(cartpole):
    guard = RailGuard.of(cartpole)
    x0 = cartpole.state_from(np.array([[0.0, 0.0], [0.0, 2.0], [-4.0, np.pi]]), np.zeros((3, 2)))
    free = simulate(cartpole, _Push(cartpole), x0, T=6.0, dt=0.002)
    guarded = simulate(cartpole, _Push(cartpole, guard), x0, T=6.0, dt=0.002)
    assert not on_rail(free, cartpole).any()
    assert on_rail(guarded, cartpole).all()
    upper = cartpole.joints[0].upper
    assert np.asarray(guarded.q)[:, :, 0].max() > upper - 2 * GUARD_MARGIN * upper  # it brakes late, not early


def test_the_guard_leaves_the_input_alone_at_rest_moving_inward_and_far_from_the_ends(cartpole):
    guard = RailGuard.of(cartpole)
    q = np.array([[4.7, 0.3], [-4.7, -0.3], [0.0, 1.0], [1.0, 0.0]])
    v = np.array([[0.0, 0.0], [2.0, 0.0], [3.0, 0.0], [-2.0, 0.5]])  # at rest; inward; mid-rail
    u = np.array([[17.0], [-5.0], [40.0], [-30.0]])
    np.testing.assert_array_equal(guard.apply(cartpole.state_from(q, v), u), u)


def test_the_stopping_rule_is_a_double_integrators_with_the_pole_at_rest_upright(cartpole):
    """Pole upright at rest: gravity and the pole's pull vanish, so full braking decelerates the cart
    at a = ū (M⁻¹)₀₀ (M from Pinocchio's CRBA), and the guard brakes exactly from k v²/(2a) ≥ d."""
    guard = RailGuard.of(cartpole)
    a = float(cartpole.effort[0]) * np.linalg.inv(cartpole.mass_matrix(np.zeros((1, 2)))[0])[0, 0]
    end = guard.upper[0]
    speed = 4.0
    d_stop = GUARD_SAFETY * speed**2 / (2 * a)
    x = cartpole.state_from(np.array([[end - 1.01 * d_stop, 0.0], [end - 0.99 * d_stop, 0.0]]), np.array([[speed, 0.0], [speed, 0.0]]))
    q, v = cartpole.split(x)
    np.testing.assert_allclose(-cartpole.forward_dynamics(q, np.zeros_like(v), np.array([[-50.0, 0.0]] * 2))[:, 0], a, rtol=1e-9)
    assert guard.braking(x)[0][:, 0].tolist() == [False, True]
    np.testing.assert_array_equal(guard.apply(x, np.zeros((2, 1)))[:, 0], [0.0, -50.0])


@pytest.mark.parametrize("name", ["acrobot", "pendubot", "furuta", "reaction_wheel"])
def test_robots_without_a_rail_have_no_guard(name):
    assert RailGuard.of(ip.load_system(name)) is None
    assert ip.load_system("cartpole").joints[0].kind == "prismatic"


def test_a_rail_without_an_effort_limit_has_no_guard(cartpole):
    assert RailGuard.of(dataclasses.replace(cartpole, effort=[np.inf])) is None
