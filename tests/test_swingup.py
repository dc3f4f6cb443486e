"""The swing-up evaluation (DESIGN §4): where a robot rests, where its tip is, the energy pump, the
verdicts and the RealAIGym v2 score, each checked against an independent reference.

References: the RealAIGym double pendulum's closed form (design C.1, model 1.1; q = 0 hangs, upright
is (π, 0); the same numbers as tests/test_realaigym_urdf.py), the zoo's convention (every robot drawn
upright at q = 0, so a pendulum hangs at π), the cart-pole's closed-form pendulum energy, and hand
computations of the leaderboard criteria on a synthetic trajectory.
"""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np
import pytest

import idapbc_pin as ip
from idapbc_pin.control.energy_pump import EnergyPumpLaw, cyclic_coordinates
from idapbc_pin.sim.leaderboard import leaderboard_score
from idapbc_pin.evaluation.swingup import SwingupResult, evaluate_swingup, judge_swingup, swingup_states
from idapbc_pin.model.resting import resting_configuration, tip_height
from idapbc_pin.sim.metrics import speed_over_rating
from idapbc_pin.sim.trajectory import Trajectory

from .conftest import cart_out_and_back

URDF = Path(__file__).resolve().parents[1] / "urdf" / "realaigym_double_pendulum.urdf"

# RealAIGym design C.1, model 1.1 (I about the joint axis; no damping)
M1, M2 = 0.5234602302310271, 0.6255677234174437
L1, L2 = 0.2, 0.3
R1, R2 = 0.2, 0.25569305436052964
I1, I2 = 0.031887199591513114, 0.05086984812807257
G = 9.81
EFFORT = 6.0


@pytest.fixture(scope="module", params=["shoulder", "elbow"], ids=["pendubot", "acrobot"])
def realaigym(request):
    return ip.load_system(str(URDF), actuated=[request.param], target={"shoulder": math.pi})


@pytest.fixture(scope="module")
def realaigym_pendubot():
    return ip.load_system(str(URDF), actuated=["shoulder"], target={"shoulder": math.pi})


def ref_energy(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """H = ½ vᵀM v + U of the closed form, (K, 2) ×2 -> (K,), J."""
    c2 = np.cos(q[:, 1])
    h = M2 * L1 * R2 * c2
    m11, m12, m22 = I1 + I2 + M2 * L1**2 + 2 * h, I2 + h, I2
    kinetic = 0.5 * (m11 * v[:, 0] ** 2 + 2 * m12 * v[:, 0] * v[:, 1] + m22 * v[:, 1] ** 2)
    U = -M1 * G * R1 * np.cos(q[:, 0]) - M2 * G * (L1 * np.cos(q[:, 0]) + R2 * np.cos(q[:, 0] + q[:, 1]))
    return kinetic + U


# ====================================================================== resting configuration
def test_realaigym_rests_at_its_zero(realaigym):
    """q = 0 hangs both links straight down: the lowest potential, written as (0, 0) (not (2π, 0))."""
    np.testing.assert_allclose(resting_configuration(realaigym), [0.0, 0.0], atol=1e-6)


@pytest.mark.parametrize("name", ["pendubot", "acrobot", "double_pendulum"])
def test_zoo_arm_hangs_at_pi(name):
    """Zoo robots are drawn upright at q = 0, so the arm hangs at (π, 0); no random posture is lower."""
    system = ip.load_system(name)
    rest = resting_configuration(system)
    np.testing.assert_allclose(rest, [math.pi, 0.0], atol=1e-6)
    q = np.random.default_rng(1).uniform(-math.pi, math.pi, (400, 2))
    assert system.potential(rest) <= system.potential(q).min()


def test_cyclic_coordinates_keep_their_target():
    """A cart rests anywhere on its rail (kept at its target), a Furuta arm and a wheel keep x*'s angle."""
    cart = ip.load_system("cartpole", target={"slider": 0.5})
    np.testing.assert_allclose(resting_configuration(cart), [0.5, math.pi], atol=1e-6)
    np.testing.assert_allclose(resting_configuration(ip.load_system("furuta")), [0.0, math.pi], atol=1e-6)
    np.testing.assert_allclose(resting_configuration(ip.load_system("reaction_wheel")), [math.pi, 0.0], atol=1e-6)
    assert cyclic_coordinates(cart).tolist() == [True, False]
    assert cyclic_coordinates(ip.load_system("pendubot")).tolist() == [False, False]


# ====================================================================== tip height
def test_tip_height_matches_the_closed_form(realaigym):
    """h = −l1 cos q1 − l2 cos(q1 + q2) above the pivot (at the base's origin) at random q; the tip is
    link 2's far end l2 = 0.3 m (its visual rod), not 2·r2 (its centre of mass is off the middle)."""
    q = np.random.default_rng(0).uniform(-2 * math.pi, 2 * math.pi, (64, 2))
    expected = -L1 * np.cos(q[:, 0]) - L2 * np.cos(q[:, 0] + q[:, 1])
    np.testing.assert_allclose(tip_height(realaigym, q), expected, atol=1e-12)
    assert tip_height(realaigym, np.array([math.pi, 0.0])) == pytest.approx(L1 + L2, abs=1e-12)


def test_tip_height_of_zoo_robots():
    """Zoo double pendulum (upright convention, link 2 a uniform 0.9 m rod): l1 cos q1 + 0.9 cos(q1 + q2);
    the reaction wheel's tip is the wheel's centre, 0.5 m up the pendulum."""
    q = np.random.default_rng(2).uniform(-math.pi, math.pi, (16, 2))
    np.testing.assert_allclose(tip_height(ip.load_system("pendubot"), q), np.cos(q[:, 0]) + 0.9 * np.cos(q.sum(axis=1)), atol=1e-12)
    np.testing.assert_allclose(tip_height(ip.load_system("reaction_wheel"), q), 0.5 * np.cos(q[:, 0]), atol=1e-12)


def test_tip_test_needs_a_urdf():
    with pytest.raises(ip.IdapbcError, match="needs a URDF"):
        tip_height(ip.load_system("paper_cartpole"), np.zeros(2))


# ====================================================================== the energy pump
def test_pump_raises_the_hamiltonian_from_hanging(realaigym):
    """From exactly hanging (the kick starts it) the pump drives the closed-form energy to E* and
    keeps it there: its power u·v_a has the sign of E* − E at every sample away from the catch (Ė =
    u·v_a without damping), E climbs until it reaches E*, then stays within a band of it; |u| ≤ 6 N·m."""
    law = EnergyPumpLaw(realaigym)
    e_star = float(ref_energy(np.array([[math.pi, 0.0]]), np.zeros((1, 2)))[0])
    assert law.e_star == pytest.approx(e_star, abs=1e-9)
    traj = ip.simulate(realaigym, law, swingup_states(realaigym, n=1)[0], T=1.5, dt=0.002)
    q, v, u = traj.q[0], traj.v[0], traj.u[0]
    E = ref_energy(q, v)
    gap = e_star - E[0]
    assert np.abs(u).max() <= EFFORT + 1e-12
    pumping = ~law.near_target(traj.x[0])
    power = (u[:, 0] * (v @ np.asarray(realaigym.B))[:, 0])[pumping]
    assert np.all(power * (e_star - E[pumping]) >= -1e-9) and power.max() > 0
    reached = int(np.argmax(E >= e_star - 0.02 * gap))
    assert E[reached] >= e_star - 0.02 * gap
    assert np.all(np.diff(E[: reached + 1]) >= -1e-3 * gap)  # the held input lets E dip by rounding only
    assert np.abs(E[reached:] - e_star).max() <= 0.05 * gap


def test_cart_pump_raises_the_pendulum_energy():
    """Cart-pole (Åström & Furuta): the energy pumped is the pendulum's, ½ J θ̇² + m g l cos θ, in the
    direction −θ̇ cos θ; it rises from hanging, with the force within the 50 N limit."""
    system = ip.load_system("cartpole")
    law = EnergyPumpLaw(system)
    J, mgl = 0.00601125 + 0.2 * 0.3**2, 0.2 * G * 0.3
    rng = np.random.default_rng(3)
    q, v = rng.uniform(-3, 3, (8, 2)), rng.uniform(-3, 3, (8, 2))
    E, y = law.energy_and_direction(system.state_from(q, v))
    np.testing.assert_allclose(E, 0.5 * J * v[:, 1] ** 2 + mgl * np.cos(q[:, 1]), atol=1e-12)
    np.testing.assert_allclose(y[:, 0], -np.cos(q[:, 1]) * v[:, 1], atol=1e-12)
    traj = ip.simulate(system, law, swingup_states(system, n=1)[0], T=1.0, dt=0.002)
    E_t = 0.5 * J * traj.v[0, :, 1] ** 2 + mgl * np.cos(traj.q[0, :, 1])
    assert E_t.max() - E_t[0] > 0.9 * (law.e_star - law.e_rest)
    assert np.abs(traj.u).max() <= 50.0 + 1e-12


def test_pump_pickles_and_hands_over_to_lqr(realaigym_pendubot):
    """A worker process gets the same law; at x* it is the LQR law, saturated."""
    law = EnergyPumpLaw(realaigym_pendubot)
    x = swingup_states(realaigym_pendubot, n=4, seed=5)
    x = np.concatenate([x, np.asarray(realaigym_pendubot.x_star)[None] + 0.01])
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(law))(x), law(x))
    lqr = ip.LQRController(realaigym_pendubot)
    np.testing.assert_allclose(law(x[-1:]), np.clip(lqr(x[-1:]), -EFFORT, EFFORT), atol=0)


# ====================================================================== the v2 score and the verdicts
def test_v2_score_by_hand():
    """Criteria of a 5-sample trajectory, dt = 0.5 s, worked out by hand."""
    t = np.array([0.0, 0.5, 1.0, 1.5, 2.0])
    q = np.array([[0, 0], [1, 0], [3, 0], [2, 1], [2, 1]], float)
    v = np.array([[1, 2], [0, 1], [3, 0], [1, 1], [9, 9]], float)
    tau = np.array([[2, 0], [-1, 0], [4, 0], [0, 0], [5, 0]], float)
    s = leaderboard_score(t, q, v, tau, swingup_time=0.5)
    energy = abs(1 * 2) + abs(2 * -1) + abs(-1 * 4) + 0  # Σ|Δq·τ| with τ held over each step
    torque_cost = (4 + 1 + 16 + 0) * 0.5
    diffs = [-3, 5, -4, 5]  # Δτ of joint 1 (joint 2: all 0, std 0)
    smooth = math.sqrt(sum((d - 0.75) ** 2 for d in diffs) / 4)
    velocity_cost = (5 + 1 + 9 + 2) * 0.5  # the last sample's 9, 9 are not integrated
    assert (s.energy, s.torque_cost, s.velocity_cost) == (energy, torque_cost, velocity_cost)
    assert s.torque_smoothness == pytest.approx(smooth, rel=1e-12)
    terms = [0.5 / 20, energy / 60, torque_cost / 20, smooth / 0.1, velocity_cost / 400]
    assert s.success and s.score == pytest.approx(1 - sum(math.tanh(math.pi * c) for c in terms) / 5, rel=1e-12)
    for no in (math.nan, 2.0):  # never up, or up only at the last sample: no success, score 0
        s = leaderboard_score(t, q, v, tau, swingup_time=no)
        assert not s.success and s.score == 0.0


def test_tip_test_is_the_leaderboards_threshold(realaigym_pendubot):
    """A hand-made swing (q1 from 0 to π over 1 s, then held; u = t N·m): the swing-up time is the
    first sample with 0.5 cos(π − q1) ≥ 0.45 m, the leaderboard's 0.9 (l1 + l2) above the pivot; the
    energy is the left sum Σ π·0.002 · 0.002 k over the 500 moving steps, = 0.499 π J."""
    t = np.arange(0, 1501) * 0.002
    q1 = np.minimum(t, 1.0) * math.pi
    q = np.stack([q1, np.zeros_like(q1)], axis=1)[None]
    v = np.zeros_like(q)
    x = np.concatenate([q, v], axis=2)
    traj = Trajectory(t=t, x=x, q=q, v=v, u=t[None, :, None].copy(), diverged=np.zeros(1, bool))
    s = judge_swingup(realaigym_pendubot, traj)
    first = t[np.argmax(-0.5 * np.cos(q1) >= 0.45)]
    assert s.tip[0] and s.swingup_time[0] == pytest.approx(first, abs=1e-12)
    assert s.holds[0] and s.time_to_goal[0] == pytest.approx(t[np.argmax(np.abs(q1 - math.pi) <= 0.1)], abs=1e-12)
    assert s.energy[0] == pytest.approx(0.499 * math.pi, rel=1e-9) and s.hanging.energy == pytest.approx(0.499 * math.pi, rel=1e-9)
    assert s.peak_input[0] == pytest.approx(3.0) and s.peak_ratio[0] == pytest.approx(3.0 / EFFORT)


def test_the_peak_speed_is_read_against_every_joint_s_urdf_rating(realaigym_pendubot):
    """The RealAIGym URDF rates both joints at 20 rad/s, the passive elbow too (no joint of a real
    robot may pass its rating). A hand-made run with the shoulder at up to 30 rad/s and the free
    elbow at up to 100 rad/s: 5.0 (the elbow); after the first 0.5 s the peak is the same, read later."""
    t = np.arange(0, 501) * 0.002
    v = np.stack([30.0 * np.sin(np.pi * t), 100.0 * np.sin(np.pi * t)], axis=1)[None]
    q = np.zeros_like(v)
    traj = Trajectory(t=t, x=np.concatenate([q, v], axis=2), q=q, v=v, u=np.zeros((1, len(t), 1)), diverged=np.zeros(1, bool))
    s = judge_swingup(realaigym_pendubot, traj)
    assert s.speed_ratio[0] == pytest.approx(5.0, rel=1e-6) and s.late_speed_ratio[0] == pytest.approx(5.0, rel=1e-6)
    early = Trajectory(t=t, x=traj.x, q=q, v=v * (t < 0.5)[None, :, None], u=traj.u, diverged=traj.diverged)
    late = judge_swingup(realaigym_pendubot, early)
    assert late.speed_ratio[0] == pytest.approx(5.0 * np.sin(np.pi * 0.498), rel=1e-6) and late.late_speed_ratio[0] == 0.0
    result = SwingupResult("hand", traj.x[:, 0], T=1.0, dt=0.002, limits=True, scores={"hand": s})
    assert "median peak speed / rating" in result.table() and "| 5.00 |" in result.table()
    assert (speed_over_rating(ip.load_system("paper_cartpole"), np.ones((3, 2))) == 0).all()  # a closed form: no rating


def test_a_cart_that_leaves_its_rail_neither_holds_nor_passes_the_tip_test():
    """The zoo cartpole's rail is ±5 m (URDF limits). Two hand-made runs with the pole upright and still:
    the cart goes out to 4.9 m and back (holds, tip passed), or to 5.2 m and back (off the rail: both fail)."""
    system = ip.load_system("cartpole")
    lower, upper = system.joints[0].lower, system.joints[0].upper
    assert (lower, upper) == (-5.0, 5.0) and system.joints[0].kind == "prismatic"
    traj = cart_out_and_back([4.9, 5.2], T=5.0)
    s = judge_swingup(system, traj)
    np.testing.assert_array_equal(s.off_rail, [False, True])
    np.testing.assert_array_equal(s.holds, [True, False])
    np.testing.assert_array_equal(s.tip, [True, False])
    assert np.isnan(s.time_to_goal[1]) and s.to_dict()["off_rail"] == [False, True]
    result = SwingupResult(system="cartpole", states=traj.x[:, 0], T=5.0, dt=0.002, limits=True, scores={"hand": s})
    assert "| hand | 1/2 (1 off the rail) | 1/2 |" in result.table()


def test_doing_nothing_fails_and_lqr_at_the_target_holds(realaigym_pendubot):
    system = realaigym_pendubot
    zero = lambda x: np.zeros((np.shape(x)[0], 1))  # noqa: E731
    res = evaluate_swingup(system, {"zero": zero}, n=3, T=3.0)
    s = res.scores["zero"]
    assert not s.holds.any() and not s.tip.any() and s.hanging.score == 0.0
    assert "| zero | 0/3 | 0/3 |" in res.table() and res.to_dict()["scores"]["zero"]["hanging"]["score"] == 0.0
    x0 = np.asarray(system.x_star)[None] + np.array([[0, 0, 0, 0], [0.02, -0.02, 0.01, 0.0]])
    s = judge_swingup(system, ip.simulate(system, ip.LQRController(system), x0, T=3.0, dt=0.002))
    assert s.holds.all() and s.tip.all()
    np.testing.assert_array_equal(s.swingup_time, [0.0, 0.0])
    assert s.hanging.success and s.hanging.swingup_time == 0.0


# ====================================================================== start states
def test_swingup_states(realaigym_pendubot):
    system = realaigym_pendubot
    x = swingup_states(system, n=20, seed=4)
    assert x.shape == (20, 4)
    np.testing.assert_array_equal(x[0], [0.0, 0.0, 0.0, 0.0])
    q, v = system.split(x)
    assert np.abs(q).max() <= 0.1 and np.abs(v).max() <= 0.1 + 1e-12
    assert (np.abs(q[1:]) > 0).all() and (np.abs(v[1:]) > 0).all()  # the others are moved off rest
    np.testing.assert_array_equal(swingup_states(system, n=20, seed=4), x)
    assert not np.array_equal(swingup_states(system, n=20, seed=5), x)


def test_circle_states_start_at_rest_with_every_angle_anywhere_on_the_circle():
    """The first at rest hanging, the others at rest with each angle x*'s + U(−π, π); a cart stays at
    its resting place. Unknown start sets are refused with the valid ones."""
    system = ip.load_system("cartpole")
    x = swingup_states(system, n=400, seed=2, starts="circle")
    q, v = system.split(x)
    np.testing.assert_array_equal(q[0], resting_configuration(system))
    assert (v == 0).all() and (q[:, 0] == resting_configuration(system)[0]).all()
    dq = q[1:, 1] - system.x_star[1]
    assert np.abs(dq).max() < np.pi and dq.min() < -2.8 and dq.max() > 2.8  # the whole circle, not near hanging
    np.testing.assert_array_equal(swingup_states(system, n=400, seed=2, starts="circle"), x)
    with pytest.raises(ip.IdapbcError, match="unknown swing-up starts 'nowhere'.*hanging, circle, anywhere"):
        swingup_states(system, n=3, starts="nowhere")
