"""A certified sublevel set is invariant and inside the box, so the invariant share bounds it.

`idapbc_pin.evaluation.invariance` measures, by simulation, the share of the training box whose trajectory
reaches x* without ever leaving the box: the most any certificate of that closed loop (a sublevel
set inside the box on which V decreases) could cover.
"""

from __future__ import annotations

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.certificate.baseline import QuadraticLyapunov, certify_baseline
from idapbc_pin.certificate.vbox import verification_box
from idapbc_pin.control.baseline import LQRController
from idapbc_pin.sim.integrate import simulate
from idapbc_pin.evaluation.invariance import box_invariant_share, invariant_share, stays_inside
from idapbc_pin.sim.metrics import success
from idapbc_pin.sim.states import uniform_states

from .conftest import sample_domain


def _zero(system):
    return lambda x: np.zeros((np.atleast_2d(x).shape[0], system.m))


def test_the_upright_equilibrium_stays_inside_and_a_pendubot_left_alone_falls_out():
    system = ip.load_system("pendubot")
    x0 = np.stack([system.x_star, system.x_star + np.r_[0.3, 0.0, 0.0, 0.0]])
    traj = simulate(system, _zero(system), x0, T=3.0)
    assert stays_inside(traj, system).tolist() == [True, False]
    # independently: the falling shoulder passes the box's own bound on q1
    assert np.abs(traj.q[1, :, 0]).max() > system.domain[1][0]
    assert stays_inside(traj, system, scale=1e6).tolist() == [True, True]


def test_every_state_of_lqrs_certified_set_stays_in_the_box_and_reaches_x_star():
    """The certificate's claim, checked by simulation: the mass-spring-damper's LQR certificate
    covers a large share, and every sampled state inside it keeps to the box and converges."""
    system = ip.load_system("paper_mass_spring_damper")
    box = system.domain
    base = certify_baseline(system, box, box, np.random.default_rng(3))
    assert base.sublevel.covered_fraction > 0.3 and base.sublevel.confidence.passed
    x = sample_domain(system, 4000, seed=3)
    V = QuadraticLyapunov(LQRController(system).S, system.x_star, system.angle_mask).H_d(x)
    inside = x[V < base.sublevel.c][:300]
    traj = simulate(system, LQRController(system), inside, T=20.0)
    assert np.all(stays_inside(traj, system)) and np.all(success(traj, system))


def test_a_set_certified_in_a_wider_verification_box_stays_in_it_and_reaches_x_star():
    """A wider verification box never shrinks the certified set, and every sampled state of the set
    certified in 4× the box keeps to that box and converges."""
    system = ip.load_system("paper_mass_spring_damper")
    vbox = verification_box(system, 4.0)
    base = certify_baseline(system, vbox, system.domain, np.random.default_rng(3))
    assert base.sublevel.confidence.passed
    x = vbox[0] + (vbox[1] - vbox[0]) * np.random.default_rng(4).random((20000, 2))
    V = QuadraticLyapunov(LQRController(system).S, system.x_star, system.angle_mask).H_d(x)
    inside = x[V < base.sublevel.c]
    in_box = certify_baseline(system, system.domain, system.domain, np.random.default_rng(3))
    assert base.sublevel.c >= in_box.sublevel.c * (1 - 1e-9) and base.sublevel.c_boundary > in_box.sublevel.c_boundary
    traj = simulate(system, LQRController(system), inside[:300], T=20.0)
    assert np.all(stays_inside(traj, system, box=vbox)) and np.all(success(traj, system))


def test_the_certified_share_never_exceeds_the_invariant_share():
    system = ip.load_system("paper_mass_spring_damper")
    lqr = LQRController(system)
    share = invariant_share(system, {"LQR": lqr}, n=400, seed=5, scales=(1.0, 2.0))
    base = certify_baseline(system, system.domain, system.domain, np.random.default_rng(3))
    within_1, within_2 = share.inside["LQR"]
    # 400 states: a binomial standard error of at most 2.5 points; allow three of them
    assert base.sublevel.covered_fraction <= within_1 + 0.075
    assert within_1 <= within_2 <= share.success["LQR"]
    assert "never leaves 2× the box" in share.table()
    # the same ceiling in a verification box twice as wide, as certify measures it (rows stopped once at rest)
    wide = box_invariant_share(system, {"LQR": lqr}, verification_box(system, 2.0), n=400, seed=5)
    assert wide["LQR"] == pytest.approx(within_2, abs=0.01)


def test_a_scale_that_is_not_positive_is_refused():
    system = ip.load_system("paper_mass_spring_damper")
    traj = simulate(system, LQRController(system), system.x_star[None], T=0.1)
    with pytest.raises(ValueError, match="scale must be > 0"):
        stays_inside(traj, system, scale=0.0)


def test_rollouts_that_leave_the_box_or_converge_stop_with_the_verdicts_of_the_full_horizon():
    """`box_invariant_share` stops a row once it leaves the box, rests or enters the terminal set: the
    same share as full 20 s rollouts of the same states."""
    system = ip.load_system("furuta")  # its arm may spin out of any box and keep spinning
    lqr = LQRController(system)
    box = verification_box(system, scale=2.0)
    x0 = uniform_states(system, 24, "domain", 5)
    full = simulate(system, lqr, x0, T=20.0)
    expected = success(full, system) & stays_inside(full, system, box=box)
    cut = simulate(system, lqr, x0, T=20.0, stop_settled=True, stop_converged=True, stop_outside=box)
    np.testing.assert_array_equal(success(cut, system) & stays_inside(cut, system, box=box), expected)
    assert 0 < expected.sum() < len(x0) and not stays_inside(cut, system, box=box).all()
    assert box_invariant_share(system, {"LQR": lqr}, box, n=24, seed=5)["LQR"] == pytest.approx(expected.mean())
