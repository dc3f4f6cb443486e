"""The judge's RK4 step and control period: 2 ms, shortened only where a judged loop is too stiff for it at x*."""

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
def test_every_zoo_robot_and_paper_benchmark_is_judged_at_the_default_step(systems, name):
    """The automatic step never shortens on them: LQR's loop is slower than 250 1/s on all of them."""
    system = systems(name)
    assert judge_step(system, {"LQR": LQRController(system)}, 20.0) == DEFAULT_STEP


def _stiffer(system, factor):
    """LQR with its gain multiplied by `factor` around u*: the same loop, faster poles."""
    lqr = LQRController(system)
    return lambda x: lqr.u_star + factor * (np.atleast_2d(lqr(x)) - lqr.u_star)


def test_a_stiff_loop_gets_a_step_that_divides_the_horizon_and_keeps_rk4_stable(systems):
    law = {"stiff": _stiffer(systems("cartpole"), 30.0)}
    pole = loop_pole(systems("cartpole"), law["stiff"])
    assert 250.0 < pole < 500.0  # past POLE_STEP / DEFAULT_STEP, short of the shortest automatic step
    dt = judge_step(systems("cartpole"), law, 20.0)
    assert dt < DEFAULT_STEP and pole * dt <= POLE_STEP
    assert math.isclose(20.0 / dt, round(20.0 / dt), rel_tol=0, abs_tol=1e-9)
    assert judge_step(systems("cartpole"), law, 20.0, dt=0.01) == 0.01  # an explicit step is kept


def test_the_damped_erd_acrobot_is_slow_enough_for_the_default_step(stiff):
    """Its 152 1/s plant pole gives |λ|·dt = 0.3 at 2 ms: no shorter step is needed."""
    lqr = LQRController(stiff)
    assert 100.0 < loop_pole(stiff, lqr) < POLE_STEP / DEFAULT_STEP
    assert judge_step(stiff, {"LQR": lqr}, 20.0) == DEFAULT_STEP


def test_lqr_on_a_stiff_plant_no_longer_diverges_numerically_by_default(stiff):
    """At 10 ms, RK4 with the law at every stage blows up on the damped acrobot's fast mode and LQR
    "diverges" from most domain states; with the default step none of the same states diverge."""
    lqr = {"LQR": LQRController(stiff)}
    fixed = ip.roa(stiff, lqr, n=20, box="domain", seed=3, T=20.0, dt=0.01, hold=False)
    auto = ip.roa(stiff, lqr, n=20, box="domain", seed=3, T=20.0)
    assert fixed.dt == 0.01 and auto.dt == DEFAULT_STEP
    assert fixed.scores["LQR"].n_diverged >= 10
    assert auto.scores["LQR"].n_diverged == 0


def test_choosing_the_step_draws_nothing_from_a_noisy_controllers_generator(systems):
    """Same seed → same rollouts: linearising a controller with measurement noise goes through its
    noise-free version, so dt=None and the explicit default step give identical trajectories."""
    system = systems("cartpole")
    x0 = uniform_states(system, 3, "half", 0)

    def noisy():
        return MeasuredController(LQRController(system), model=system, noise=0.01, seed=5)

    a = ip.simulate(system, noisy(), x0, T=2.0)
    b = ip.simulate(system, noisy(), x0, T=2.0, dt=DEFAULT_STEP)
    np.testing.assert_array_equal(a.x, b.x)


def test_a_loop_stiffer_than_the_shortest_automatic_step_warns_and_names_the_fix(systems):
    system = systems("cartpole")
    lqr = LQRController(system)

    def harsh(x):  # LQR with a gain 1000× too large: poles of thousands of 1/s
        return lqr.u_star + 1000.0 * (np.atleast_2d(lqr(x)) - lqr.u_star)

    with pytest.warns(RuntimeWarning, match="--dt"):
        dt = judge_step(system, {"harsh": harsh}, 20.0)
    assert dt == pytest.approx(1e-3)  # MIN_AUTO_STEP, not the 0.1 ms the pole would ask for
    assert step_for_pole(float("nan"), 20.0) == DEFAULT_STEP  # a law that cannot be linearised keeps the default
