"""The judge's RK4 step: 10 ms, shortened only where a judged loop is too stiff for it at x*."""

from __future__ import annotations

import math

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.evaluation.robustness import MeasuredController
from idapbc_pin.sim.states import uniform_states
from idapbc_pin.sim.step import DEFAULT_STEP, POLE_STEP, judge_step, loop_pole, step_for_pole

ZOO_AND_PAPER = ["acrobot", "cart_double_pendulum", "cartpole", "double_pendulum", "furuta", "pendubot", "reaction_wheel",
                 "paper_cartpole", "paper_double_pendulum", "paper_mass_spring_damper"]


@pytest.fixture(scope="module")
def stiff():
    """example-robot-data's damped acrobot: joint damping on light links puts a 152 1/s pole in the plant."""
    with pytest.warns(UserWarning, match="no <limit effort>"):
        return ip.load_system("erd:double_pendulum_simple", actuated=["joint2"])


@pytest.mark.parametrize("name", ["cartpole", "furuta", "paper_mass_spring_damper"])
def test_the_linearised_judged_loop_is_the_lqr_loop_a_minus_bk(systems, name):
    """Central differences of the judge's forward dynamics under LQR give the poles of A − BK
    (A, B from the system's own linearisation, an independent computation)."""
    system = systems(name)
    lqr = LQRController(system)
    A, B = system.linearization()
    exact = float(np.abs(np.linalg.eigvals(A - B @ lqr.K)).max())
    assert loop_pole(system, lqr) == pytest.approx(exact, rel=1e-6)


@pytest.mark.parametrize("name", ZOO_AND_PAPER)
def test_every_zoo_robot_and_paper_benchmark_is_judged_at_10_ms(systems, name):
    """The automatic step changes no published table: LQR's loop is slower than 50 1/s on all of them."""
    system = systems(name)
    assert judge_step(system, {"LQR": LQRController(system)}, 20.0) == DEFAULT_STEP


def test_a_stiff_loop_gets_a_step_that_divides_the_horizon_and_keeps_rk4_stable(stiff):
    lqr = LQRController(stiff)
    pole = loop_pole(stiff, lqr)
    assert pole > 100.0
    dt = judge_step(stiff, {"LQR": lqr}, 20.0)
    assert dt < DEFAULT_STEP and pole * dt <= POLE_STEP
    assert math.isclose(20.0 / dt, round(20.0 / dt), rel_tol=0, abs_tol=1e-9)
    assert judge_step(stiff, {"LQR": lqr}, 20.0, dt=0.01) == 0.01  # an explicit step is kept


def test_lqr_on_a_stiff_plant_no_longer_diverges_numerically_by_default(stiff):
    """At a fixed 10 ms, RK4 blows up on the damped acrobot's fast mode and LQR "diverges" from most
    domain states; with the default step none of the same states diverge."""
    lqr = {"LQR": LQRController(stiff)}
    fixed = ip.roa(stiff, lqr, n=20, box="domain", seed=3, T=20.0, dt=0.01)
    auto = ip.roa(stiff, lqr, n=20, box="domain", seed=3, T=20.0)
    assert fixed.dt == 0.01 and auto.dt < 0.01
    assert fixed.scores["LQR"].n_diverged >= 10
    assert auto.scores["LQR"].n_diverged == 0


def test_choosing_the_step_draws_nothing_from_a_noisy_controllers_generator(systems):
    """Same seed → same rollouts: linearising a controller with measurement noise goes through its
    noise-free version, so dt=None and the explicit 10 ms give identical trajectories."""
    system = systems("cartpole")
    x0 = uniform_states(system, 3, "half", 0)

    def noisy():
        return MeasuredController(LQRController(system), model=system, noise=0.01, seed=5)

    a = ip.simulate(system, noisy(), x0, T=2.0)
    b = ip.simulate(system, noisy(), x0, T=2.0, dt=0.01)
    np.testing.assert_array_equal(a.x, b.x)


def test_a_loop_stiffer_than_the_shortest_automatic_step_warns_and_names_the_fix(systems):
    system = systems("cartpole")
    lqr = LQRController(system)

    def harsh(x):  # LQR with a gain 1000× too large: poles of thousands of 1/s
        return lqr.u_star + 1000.0 * (np.atleast_2d(lqr(x)) - lqr.u_star)

    with pytest.warns(RuntimeWarning, match="--dt"):
        dt = judge_step(system, {"harsh": harsh}, 20.0)
    assert dt == pytest.approx(1e-3)  # MIN_AUTO_STEP, not the 0.1 ms the pole would ask for
    assert step_for_pole(float("nan"), 20.0) == DEFAULT_STEP  # a law that cannot be linearised keeps 10 ms
