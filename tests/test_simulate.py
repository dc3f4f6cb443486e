"""Simulation, the DESIGN §4 metrics, the LQR baseline and ROA sampling.

The judge is the true plant integrated in (q, v); these tests hold it against the model's own
vector field in (q, p), against the exact solution of a linear system, and hold the metrics to
hand-made trajectories.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest
import scipy.linalg as sla

import idapbc_pin as ip
from idapbc_pin.sim.simulate import (
    LQRController,
    Trajectory,
    equilibrium_offset,
    evaluation_box,
    half_box,
    peak_input,
    roa,
    settling_time,
    simulate,
    success,
    uniform_states,
    wrap_angles,
)


@pytest.fixture(scope="module")
def systems():
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = ip.load_system(name)
        return cache[name]

    return get


def zero_ctrl(m):
    return lambda x: np.zeros((np.atleast_2d(x).shape[0], m))


def rk4_qp(f, x, T, h):
    """Plain RK4 of ẋ = f(x) in (q, p), the reference for the (q, v) judge."""
    for _ in range(int(round(T / h))):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


# ------------------------------------------------------------------ the judge is the plant
@pytest.mark.parametrize("name", ["cartpole", "paper_cartpole", "acrobot"])
def test_judge_in_q_v_agrees_with_f_in_q_p(systems, name):
    """With u = 0, integrating q̇ = v, v̇ = aba(q, v, 0) and mapping to p = M(q)v reproduces the flow
    of ẋ = f(x) in (q, p) (momenta, Coriolis and joint damping all consistent)."""
    system = systems(name)
    x0 = uniform_states(system, 6, "domain", seed=1)
    traj = simulate(system, zero_ctrl(system.m), x0, T=0.05, dt=0.0025)
    np.testing.assert_allclose(traj.x[:, 0], x0, rtol=0, atol=1e-12)  # (q, p) -> (q, v) -> (q, p)
    ref = rk4_qp(system.f, x0, 0.05, 5e-4)  # both discretisation errors ≲ 1e-10 here
    scale = 1.0 + np.abs(ref)
    assert np.max(np.abs(traj.x[:, -1] - ref) / scale) < 1e-8
    # and the state actually moved: the comparison is not vacuous
    assert np.max(np.abs(traj.x[:, -1] - x0)) > 1e-3


def test_recorded_momenta_match_state_from(systems):
    system = systems("acrobot")
    ctrl = LQRController(system)
    traj = simulate(system, ctrl, uniform_states(system, 3, "half", seed=2), T=0.2, dt=0.01)
    x = system.state_from(traj.q.reshape(-1, system.nq), traj.v.reshape(-1, system.nq))
    np.testing.assert_allclose(traj.x.reshape(-1, system.n), x, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ integrator order
@dataclass(frozen=True)
class LinearOscillator:
    """q̈ = −ω²q − c q̇ + u, unit mass (p = v): a duck-typed system with an exact solution."""

    omega: float = 2.0
    c: float = 0.3
    nq: int = 1
    n: int = 2
    m: int = 1
    name: str = "linear_oscillator"
    B: np.ndarray = field(default_factory=lambda: np.ones((1, 1)))
    x_star: np.ndarray = field(default_factory=lambda: np.zeros(2))
    angle_mask: np.ndarray = field(default_factory=lambda: np.zeros(2, bool))
    domain: tuple = (np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    plant: object = None

    def split(self, x):
        x = np.atleast_2d(x)
        return x[:, :1].copy(), x[:, 1:].copy()

    def state_from(self, q, v):
        return np.concatenate([q, v], axis=1)

    def forward_dynamics(self, q, v, tau):
        return -self.omega**2 * q - self.c * v + tau


GAIN = np.array([[1.5, 0.8]])  # u = −GAIN x


def exact_linear(system, x0, T):
    A_cl = np.array([[0.0, 1.0], [-system.omega**2 - GAIN[0, 0], -system.c - GAIN[0, 1]]])
    return x0 @ sla.expm(A_cl * T).T


def test_rk4_converges_at_order_4():
    system = LinearOscillator()
    x0 = np.array([[1.0, -0.5], [0.2, 0.7]])
    exact = exact_linear(system, x0, 2.0)
    errors = []
    for dt in (0.1, 0.05, 0.025):
        traj = simulate(system, lambda x: -x @ GAIN.T, x0, T=2.0, dt=dt)
        errors.append(np.abs(traj.x[:, -1] - exact).max())
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 14.0) & (ratios < 18.0)), ratios


def test_rk45_meets_its_tolerance():
    system = LinearOscillator()
    x0 = np.array([[1.0, -0.5], [0.2, 0.7]])
    traj = simulate(system, lambda x: -x @ GAIN.T, x0, T=2.0, dt=0.1, method="rk45", rtol=1e-9, atol=1e-12)
    assert np.abs(traj.x[:, -1] - exact_linear(system, x0, 2.0)).max() < 1e-7
    np.testing.assert_allclose(traj.t, np.arange(21) * 0.1, atol=1e-12)


# ------------------------------------------------------------------ LQR baseline
#: Initial offset on every angle (rad). The acrobot's LQR (Q = I, R = I) loses the upright state
#: from 0.05 rad on the shoulder (confirmed with scipy's DOP853 on ẋ = f + g u at rtol 1e-10):
#: its region of attraction is that small, so it starts at 0.02 rad.
SMALL_ANGLE = {"acrobot": 0.02, "cartpole": 0.05, "paper_cartpole": 0.05, "paper_double_pendulum": 0.05}


@pytest.mark.parametrize("name", sorted(SMALL_ANGLE))
def test_lqr_stabilises_linearisation_and_plant(systems, name):
    system = systems(name)
    ctrl = LQRController(system)
    assert np.all(ctrl.eigenvalues.real < 0.0)
    np.testing.assert_allclose(ctrl.eigenvalues, np.linalg.eigvals(ctrl.A - ctrl.Bx @ ctrl.K))
    x0 = system.x_star.copy()
    x0[: system.nq][system.angle_mask[: system.nq]] += SMALL_ANGLE[name]
    traj = simulate(system, ctrl, x0, T=10.0, dt=0.01)
    assert success(traj, system).tolist() == [True]
    assert settling_time(traj, system)[0] < 8.0
    assert equilibrium_offset(traj, system)[0] < 0.05


def test_lqr_holds_an_equilibrium_that_needs_input(systems):
    """The mass-spring-damper's x* = (0.5, 0) needs u* = (k + ½q*²)q* = 0.5625 N to stay put."""
    system = systems("paper_mass_spring_damper")
    ctrl = LQRController(system)
    np.testing.assert_allclose(ctrl.u_star, [0.5625])
    np.testing.assert_allclose(ctrl(system.x_star), [0.5625])
    traj = simulate(system, ctrl, system.x_star + [0.3, -0.2], T=20.0, dt=0.02)
    assert success(traj, system)[0] and equilibrium_offset(traj, system)[0] < 1e-3


def test_lqr_wraps_angles(systems):
    system = systems("paper_double_pendulum")
    ctrl = LQRController(system)
    x = np.array([[0.1, -0.2, 0.3, 0.4]])
    shifted = x + [2 * math.pi, -4 * math.pi, 0.0, 0.0]
    np.testing.assert_allclose(ctrl(shifted), ctrl(x), atol=1e-12)


# ------------------------------------------------------------------ divergence
def test_divergence_is_frozen_and_flagged(systems):
    system = systems("paper_double_pendulum")
    K = LQRController(system).K
    seen = []

    def destabilising(x):
        assert np.all(np.isfinite(x)), "controller called on a non-finite state"
        seen.append(np.abs(x).max())
        return x @ K.T  # u = +K x

    x0 = np.stack([system.x_star, system.x_star + [0.1, 0, 0, 0], system.x_star + [0, -0.1, 0.2, 0]])
    for method in ("rk4", "rk45"):
        traj = simulate(system, destabilising, x0, T=4.0, dt=0.02, method=method)
        assert traj.diverged.tolist() == [False, True, True]
        for a in (traj.x, traj.v, traj.u):
            assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(traj.x[0], np.broadcast_to(system.x_star, traj.x[0].shape))
        assert success(traj, system).tolist() == [True, False, False]
        assert np.isnan(settling_time(traj, system)[1:]).all()
        assert np.isnan(equilibrium_offset(traj, system)[1:]).all()
        # frozen: the diverged rows end at their last recorded value
        np.testing.assert_array_equal(traj.x[1:, -1], traj.x[1:, -2])


def test_nan_from_the_controller_stays_in_its_row(systems):
    system = systems("paper_cartpole")
    ctrl = LQRController(system)

    def sometimes_nan(x):
        u = ctrl(x)
        u[x[:, 1] > 0.15] = np.nan
        return u

    x0 = system.x_star + np.array([[0, 0.05, 0, 0], [0, 0.2, 0, 0]])
    traj = simulate(system, sometimes_nan, x0, T=3.0)
    assert traj.diverged.tolist() == [False, True]
    assert np.all(np.isfinite(traj.x)) and np.all(np.isfinite(traj.u))


# ------------------------------------------------------------------ saturation and recording
def test_saturation_clips_the_applied_input(systems):
    system = systems("paper_cartpole")
    traj = simulate(system, LQRController(system), system.x_star + [0, 0.3, 0, 0], T=1.0, saturation=2.0)
    assert peak_input(traj)[0] == pytest.approx(2.0)


def test_record_every_keeps_the_final_time():
    system = LinearOscillator()
    traj = simulate(system, lambda x: -x @ GAIN.T, np.array([1.0, 0.0]), T=1.0, dt=0.1, record_every=3)
    np.testing.assert_allclose(traj.t, [0.0, 0.3, 0.6, 0.9, 1.0])
    assert traj.x.shape == (1, 5, 2) and traj.u.shape == (1, 5, 1) and traj.q.shape == (1, 5, 1)
    full = simulate(system, lambda x: -x @ GAIN.T, np.array([1.0, 0.0]), T=1.0, dt=0.1)
    np.testing.assert_allclose(traj.x[0, -1], full.x[0, -1], rtol=0, atol=1e-15)


def test_bad_arguments_raise(systems):
    system = systems("paper_cartpole")
    ctrl = LQRController(system)
    with pytest.raises(ValueError, match="multiple"):
        simulate(system, ctrl, system.x_star, T=1.0, dt=0.3)
    with pytest.raises(ValueError, match="method"):
        simulate(system, ctrl, system.x_star, T=1.0, method="euler")
    with pytest.raises(ValueError, match="shape"):
        simulate(system, ctrl, np.zeros(3), T=1.0)
    with pytest.raises(ValueError, match="controller returned"):
        simulate(system, lambda x: np.zeros((x.shape[0], 3)), system.x_star, T=0.1)


# ------------------------------------------------------------------ metrics on hand-made trajectories
def constant_trajectory(system, q, v=None, T=5.0, dt=0.01, diverged=False):
    t = np.arange(int(round(T / dt)) + 1) * dt
    q = np.broadcast_to(np.asarray(q, float), (1, t.size, system.nq))
    v = np.zeros_like(q) if v is None else np.broadcast_to(np.asarray(v, float), q.shape)
    x = np.concatenate([q, v], axis=-1)  # p stands in for v here: metrics read q, v, x
    u = np.zeros((1, t.size, system.m))
    return Trajectory(t=t, x=x, q=x[..., : system.nq], v=np.array(v), u=u, diverged=np.array([diverged]))


def test_wrap_angles_to_minus_pi_pi():
    d = np.array([math.pi, -math.pi, 3 * math.pi, 2 * math.pi + 0.1, -0.2, 7.0])
    out = wrap_angles(d, np.ones(6, bool))
    np.testing.assert_allclose(out, [math.pi, math.pi, math.pi, 0.1, -0.2, 7.0 - 2 * math.pi], atol=1e-12)
    assert np.all((out > -math.pi) & (out <= math.pi))
    np.testing.assert_array_equal(wrap_angles(d, np.zeros(6, bool)), d)


def test_success_wraps_angles(systems):
    system = systems("paper_double_pendulum")
    assert success(constant_trajectory(system, [2 * math.pi, -4 * math.pi + 0.04]), system).tolist() == [True]
    assert success(constant_trajectory(system, [0.06, 0.0]), system).tolist() == [False]
    assert success(constant_trajectory(system, [0.0, 0.0], v=[0.0, 0.06]), system).tolist() == [False]
    assert success(constant_trajectory(system, [0.0, 0.0], diverged=True), system).tolist() == [False]


def test_success_does_not_wrap_linear_coordinates(systems):
    system = systems("paper_cartpole")  # q1 is the cart position (m)
    assert success(constant_trajectory(system, [0.0, 2 * math.pi]), system).tolist() == [True]
    assert success(constant_trajectory(system, [2 * math.pi, 0.0]), system).tolist() == [False]


def test_success_only_looks_at_the_last_window(systems):
    system = systems("paper_double_pendulum")
    traj = constant_trajectory(system, [0.0, 0.0])
    q = traj.q.copy()
    q[0, traj.t < 2.9, 0] = 1.0  # far away until t = 2.9 s, then at x* for the last 2.1 s
    x = np.concatenate([q, traj.v], axis=-1)
    moved = Trajectory(t=traj.t, x=x, q=x[..., :2], v=traj.v, u=traj.u, diverged=traj.diverged)
    assert success(moved, system)[0]
    assert settling_time(moved, system)[0] == pytest.approx(2.9)
    q[0, traj.t > 3.5, 0] = 1.0
    x = np.concatenate([q, traj.v], axis=-1)
    late = Trajectory(t=traj.t, x=x, q=x[..., :2], v=traj.v, u=traj.u, diverged=traj.diverged)
    assert not success(late, system)[0] and np.isnan(settling_time(late, system)[0])


def test_settling_time_offset_and_peak_on_a_decay(systems):
    system = systems("paper_double_pendulum")
    t = np.arange(1001) * 0.01
    q = np.stack([0.5 * np.exp(-t), np.zeros_like(t)], axis=-1)[None]
    v = np.stack([-0.5 * np.exp(-t), np.zeros_like(t)], axis=-1)[None]
    x = np.concatenate([q, v], axis=-1)
    u = (3.0 * np.cos(t))[None, :, None] * np.ones((1, 1, 2))
    traj = Trajectory(t=t, x=x, q=x[..., :2], v=v, u=u, diverged=np.array([False]))
    assert settling_time(traj, system)[0] == pytest.approx(math.ceil(100 * math.log(10)) / 100)
    window = t >= 8.0
    expected = np.linalg.norm(x[0, window].mean(axis=0))
    assert equilibrium_offset(traj, system)[0] == pytest.approx(expected)
    assert peak_input(traj)[0] == pytest.approx(3.0)


# ------------------------------------------------------------------ ROA
def test_half_box_is_half_the_domain_around_x_star(systems):
    system = systems("paper_mass_spring_damper")  # x* = (0.5, 0) is off-centre
    lo, hi = system.domain
    hlo, hhi = half_box(system)
    np.testing.assert_allclose(hhi - hlo, (hi - lo) / 2)
    np.testing.assert_allclose(system.x_star - hlo, (system.x_star - lo) / 2)
    np.testing.assert_allclose(hhi - system.x_star, (hi - system.x_star) / 2)
    np.testing.assert_allclose(evaluation_box(system, "half")[0], hlo)
    x = uniform_states(system, 500, "half", seed=3)
    assert np.all((x >= hlo) & (x <= hhi))
    np.testing.assert_array_equal(x, uniform_states(system, 500, "half", seed=3))


def test_roa_runs_every_controller_from_the_same_states(systems):
    system = systems("paper_double_pendulum")
    calls = {}

    def recording(name, ctrl):
        def wrapped(x):
            calls.setdefault(name, x.copy())
            return ctrl(x)

        return wrapped

    lqr_ctrl = LQRController(system)
    result = roa(
        system,
        {"lqr": recording("lqr", lqr_ctrl), "open loop": recording("open", zero_ctrl(system.m))},
        n=6,
        box="half",
        T=10.0,
        dt=0.02,
    )
    np.testing.assert_allclose(calls["lqr"], calls["open"])
    np.testing.assert_allclose(calls["lqr"], result.x0, atol=1e-12)
    np.testing.assert_array_equal(result.x0, uniform_states(system, 6, "half", seed=0))
    assert result["lqr"].success_rate == 1.0
    assert result["open loop"].success_rate == 0.0
    assert math.isnan(result["open loop"].median_settling_time)
    table = result.table()
    assert "lqr" in table and "open loop" in table and "100.0%" in table
